//! Building arrow batches column by column — what stages use to emit
//! artifacts, and generators to emit recorded-run tables.

use std::sync::Arc;

use arrow::array::{
    Array, ArrayRef, Float32Array, Float64Array, Int32Array, Int64Array, Int8Array, StringArray,
};
use arrow::datatypes::{Field, Schema};
use arrow::record_batch::RecordBatch;

#[derive(Default)]
pub struct BatchBuilder {
    fields: Vec<Field>,
    columns: Vec<ArrayRef>,
}

impl BatchBuilder {
    pub fn new() -> Self {
        Self::default()
    }
    fn push(mut self, name: &str, col: ArrayRef) -> Self {
        self.fields
            .push(Field::new(name, col.data_type().clone(), false));
        self.columns.push(col);
        self
    }
    pub fn f64(self, name: &str, v: Vec<f64>) -> Self {
        self.push(name, Arc::new(Float64Array::from(v)))
    }
    pub fn f32(self, name: &str, v: Vec<f32>) -> Self {
        self.push(name, Arc::new(Float32Array::from(v)))
    }
    pub fn i32(self, name: &str, v: Vec<i32>) -> Self {
        self.push(name, Arc::new(Int32Array::from(v)))
    }
    pub fn i64(self, name: &str, v: Vec<i64>) -> Self {
        self.push(name, Arc::new(Int64Array::from(v)))
    }
    pub fn i8(self, name: &str, v: Vec<i8>) -> Self {
        self.push(name, Arc::new(Int8Array::from(v)))
    }
    pub fn str<S: AsRef<str>>(self, name: &str, v: &[S]) -> Self {
        let a: StringArray = v.iter().map(|s| Some(s.as_ref())).collect();
        self.push(name, Arc::new(a))
    }
    /// A nullable float column (None → null), for optional measurements.
    pub fn opt_f64(mut self, name: &str, v: Vec<Option<f64>>) -> Self {
        self.fields
            .push(Field::new(name, arrow::datatypes::DataType::Float64, true));
        self.columns.push(Arc::new(Float64Array::from(v)));
        self
    }
    /// A nullable text column (None → null).
    pub fn opt_str(mut self, name: &str, v: Vec<Option<&str>>) -> Self {
        self.fields
            .push(Field::new(name, arrow::datatypes::DataType::Utf8, true));
        self.columns.push(Arc::new(StringArray::from(v)));
        self
    }
    /// Keep an existing column (pass-through of extra columns).
    pub fn column(mut self, field: Field, col: ArrayRef) -> Self {
        self.fields.push(field);
        self.columns.push(col);
        self
    }
    pub fn build(self) -> RecordBatch {
        RecordBatch::try_new(Arc::new(Schema::new(self.fields)), self.columns)
            .expect("BatchBuilder: columns must have equal lengths")
    }
}

/// Read a float64 column out of a batch (artifacts written by sparkout).
pub fn batch_f64<'a>(batch: &'a RecordBatch, name: &str) -> crate::Result<&'a [f64]> {
    batch
        .column_by_name(name)
        .and_then(|c| c.as_any().downcast_ref::<Float64Array>())
        .map(|a| a.values().as_ref())
        .ok_or_else(|| crate::err!("artifact has no float64 column `{name}`"))
}

pub fn batch_i32<'a>(batch: &'a RecordBatch, name: &str) -> crate::Result<&'a [i32]> {
    batch
        .column_by_name(name)
        .and_then(|c| c.as_any().downcast_ref::<Int32Array>())
        .map(|a| a.values().as_ref())
        .ok_or_else(|| crate::err!("artifact has no int32 column `{name}`"))
}

pub fn batch_str(batch: &RecordBatch, name: &str) -> crate::Result<Vec<String>> {
    let a = batch
        .column_by_name(name)
        .and_then(|c| c.as_any().downcast_ref::<StringArray>())
        .ok_or_else(|| crate::err!("artifact has no utf8 column `{name}`"))?;
    Ok((0..a.len()).map(|i| a.value(i).to_string()).collect())
}

/// Read a whole Parquet file (artifacts sparkout wrote, or any small table),
/// with the same truthful errors as the contract readers.
pub fn read_parquet(path: &std::path::Path) -> crate::Result<RecordBatch> {
    let builder = super::parquet_file::open_parquet(path)?;
    Ok(super::parquet_file::read_all(path, builder)?)
}

/// Column names of a batch, in order (for "columns present: …" messages).
pub fn column_names(b: &RecordBatch) -> Vec<&str> {
    b.schema_ref()
        .fields()
        .iter()
        .map(|f| f.name().as_str())
        .collect()
}

/// A numeric column of an ad hoc table (a surface, a profile) as float64,
/// `None` for a null row. A missing column names the columns present; a
/// non-numeric one (text, a timestamp) is refused naming its type and what
/// the column should hold (`what`: "a surface column").
pub fn numeric_column(
    path: &std::path::Path,
    b: &RecordBatch,
    name: &str,
    what: &str,
) -> Result<Vec<Option<f64>>, crate::InputError> {
    use super::convert::{normalise, type_accepted, TimeOrigin};
    use arrow::array::AsArray;
    use arrow::datatypes::{DataType, Float64Type};
    let col = b.column_by_name(name).ok_or_else(|| {
        crate::InputError::new(
            path,
            format!(
                "no such column (columns present: {})",
                column_names(b).join(", ")
            ),
        )
        .column(name)
    })?;
    if !type_accepted(super::ColumnKind::F64, name, col.data_type())
        || matches!(col.data_type(), DataType::Timestamp(..))
    {
        return Err(crate::InputError::new(
            path,
            format!("wrong type {} ({what} is a number)", col.data_type()),
        )
        .column(name));
    }
    let f = normalise(path, name, col, &DataType::Float64, &TimeOrigin::TableStart)?;
    let f = f.as_primitive::<Float64Type>();
    Ok((0..f.len())
        .map(|i| f.is_valid(i).then(|| f.value(i)))
        .collect())
}

//! Validated, in-memory tables (everything but the AE log, which streams: see
//! `ae_stream`). A `Table` is an arrow `RecordBatch` whose contract columns
//! have been checked and normalised to their v1 types; extra columns are kept
//! untouched (CONTRACTS.md: "extra columns are kept and passed through").

use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow::array::{
    Array, ArrayRef, Float32Array, Float64Array, Int32Array, Int64Array, Int8Array, StringArray,
};
use arrow::datatypes::{DataType, Field, Schema};
use arrow::record_batch::RecordBatch;

pub(crate) use super::convert::type_accepted;
use super::convert::{earliest_unix_s, is_time_column, normalise, TimeOrigin};
pub(crate) use super::parquet_file::open_parquet;
use super::parquet_file::read_all;
use super::schema::{ColumnKind, TableSchema};
use crate::error::InputError;

#[derive(Debug, Clone)]
pub struct Table {
    path: PathBuf,
    batch: RecordBatch,
}

pub(crate) fn arrow_type(kind: ColumnKind) -> DataType {
    match kind {
        ColumnKind::F64 => DataType::Float64,
        ColumnKind::F32 => DataType::Float32,
        ColumnKind::I32 => DataType::Int32,
        ColumnKind::I64 => DataType::Int64,
        ColumnKind::I8 => DataType::Int8,
        ColumnKind::Utf8 => DataType::Utf8,
    }
}

/// Check the file's schema against the contract: required columns present,
/// known columns of an accepted type.
pub(crate) fn check_schema(
    path: &Path,
    schema: &TableSchema,
    file_schema: &Schema,
) -> Result<(), InputError> {
    for spec in schema.columns {
        match file_schema.field_with_name(spec.name) {
            Ok(field) => {
                if !type_accepted(spec.kind, spec.name, field.data_type()) {
                    return Err(InputError::new(
                        path,
                        format!(
                            "wrong type {} (the contract says {}; see docs/formats.md)",
                            field.data_type(),
                            spec.kind.label()
                        ),
                    )
                    .column(spec.name));
                }
            }
            Err(_) if spec.required => {
                let have: Vec<&str> = file_schema
                    .fields()
                    .iter()
                    .map(|f| f.name().as_str())
                    .collect();
                return Err(InputError::new(
                    path,
                    format!(
                        "required column missing from `{}` (columns present: {})",
                        schema.name,
                        have.join(", ")
                    ),
                )
                .column(spec.name));
            }
            Err(_) => {}
        }
    }
    Ok(())
}

/// First row (0-based, within `offset`) that is null, NaN or infinite.
pub(crate) fn first_non_finite(col: &dyn Array) -> Option<(usize, &'static str)> {
    if col.null_count() > 0 {
        let i = (0..col.len()).find(|&i| col.is_null(i)).unwrap_or(0);
        return Some((i, "null"));
    }
    let classify = |v: f64| if v.is_nan() { "NaN" } else { "infinite value" };
    if let Some(a) = col.as_any().downcast_ref::<Float64Array>() {
        return first_failing(a.values(), |v| v.is_finite()).map(|i| (i, classify(a.value(i))));
    }
    if let Some(a) = col.as_any().downcast_ref::<Float32Array>() {
        return first_failing(a.values(), |v| v.is_finite())
            .map(|i| (i, classify(a.value(i) as f64)));
    }
    None
}

/// The first index whose value fails `ok`. Scans in chunks whose test has
/// no early exit (so it vectorises), then finds the index inside the first
/// failing chunk: validating an AE log runs at memory speed, where a
/// `position` with a branch per sample cost a fifth of the ingest.
pub(crate) fn first_failing<T: Copy>(v: &[T], ok: impl Fn(T) -> bool) -> Option<usize> {
    const CHUNK: usize = 512;
    v.chunks(CHUNK).enumerate().find_map(|(c, chunk)| {
        let all_ok = chunk.iter().fold(true, |acc, &x| acc & ok(x));
        (!all_ok).then(|| c * CHUNK + chunk.iter().position(|&x| !ok(x)).unwrap_or(0))
    })
}

/// The first row whose time stamp is below its predecessor's.
pub(crate) fn first_decrease(t: &[f64]) -> Option<usize> {
    if t.len() < 2 {
        return None;
    }
    // Pairs (t[i], t[i+1]) as the slice shifted by one; a pair is fine
    // unless t[i+1] < t[i] (a NaN is the finite check's to report).
    let later = &t[1..];
    let ok_pairs = |c: usize, len: usize| {
        t[c..c + len]
            .iter()
            .zip(&later[c..c + len])
            .fold(true, |acc, (a, b)| {
                acc & ((*b >= *a) | a.is_nan() | b.is_nan())
            })
    };
    const CHUNK: usize = 512;
    let n = later.len();
    (0..n).step_by(CHUNK).find_map(|c| {
        let len = CHUNK.min(n - c);
        (!ok_pairs(c, len)).then(|| {
            c + 1
                + t[c..c + len]
                    .iter()
                    .zip(&later[c..c + len])
                    .position(|(a, b)| b < a)
                    .unwrap_or(0)
        })
    })
}

impl Table {
    /// Read and validate a whole table (not for AE logs: use `AeStream`).
    /// Timestamps in time columns count from the table's earliest one; a
    /// run's tables use [`Table::read_at`] with the run's start.
    pub fn read(path: &Path, schema: &TableSchema) -> Result<Table, InputError> {
        Self::read_at(path, schema, &TimeOrigin::TableStart)
    }

    /// Read and validate a whole table, timestamps measured from `origin`.
    pub fn read_at(
        path: &Path,
        schema: &TableSchema,
        origin: &TimeOrigin,
    ) -> Result<Table, InputError> {
        let builder = open_parquet(path)?;
        check_schema(path, schema, builder.schema())?;
        let batch = read_all(path, builder)?;
        Self::from_batch_at(path, schema, batch, origin)
    }

    /// Validate and normalise an in-memory batch against a schema.
    pub fn from_batch(
        path: &Path,
        schema: &TableSchema,
        batch: RecordBatch,
    ) -> Result<Table, InputError> {
        Self::from_batch_at(path, schema, batch, &TimeOrigin::TableStart)
    }

    /// [`Table::from_batch`] with timestamps measured from `origin`.
    pub fn from_batch_at(
        path: &Path,
        schema: &TableSchema,
        batch: RecordBatch,
        origin: &TimeOrigin,
    ) -> Result<Table, InputError> {
        check_schema(path, schema, &batch.schema())?;
        // One origin for every time column of the table, so t_start_s and
        // t_end_s stay comparable.
        let origin = match origin {
            TimeOrigin::TableStart => batch
                .schema()
                .fields()
                .iter()
                .zip(batch.columns())
                .filter(|(f, _)| is_time_column(f.name()) && schema.column(f.name()).is_some())
                .filter_map(|(_, c)| earliest_unix_s(c.as_ref()))
                .reduce(f64::min)
                .map_or(TimeOrigin::TableStart, TimeOrigin::UnixS),
            o => o.clone(),
        };
        if batch.num_rows() == 0 {
            return Err(InputError::new(
                path,
                format!(
                    "table `{}` is empty (a required table needs rows)",
                    schema.name
                ),
            ));
        }
        let mut fields = Vec::with_capacity(batch.num_columns());
        let mut columns: Vec<ArrayRef> = Vec::with_capacity(batch.num_columns());
        for (field, col) in batch.schema().fields().iter().zip(batch.columns()) {
            match schema.column(field.name()) {
                Some(spec) => {
                    let target = match spec.kind {
                        // Keep f32 signals f32 (memory), everything else canonical.
                        ColumnKind::F32 if col.data_type() == &DataType::Float32 => {
                            DataType::Float32
                        }
                        ColumnKind::F32 => DataType::Float64,
                        k => arrow_type(k),
                    };
                    let col = normalise(path, spec.name, col, &target, &origin)?;
                    if spec.required {
                        if let Some((row, what)) = first_non_finite(col.as_ref()) {
                            return Err(InputError::new(
                                path,
                                format!("{what} in a required column"),
                            )
                            .column(spec.name)
                            .row(row));
                        }
                    }
                    fields.push(Field::new(field.name(), target, !spec.required));
                    columns.push(col);
                }
                None => {
                    fields.push(field.as_ref().clone());
                    columns.push(col.clone());
                }
            }
        }
        let batch = RecordBatch::try_new(Arc::new(Schema::new(fields)), columns)
            .map_err(|e| InputError::new(path, format!("cannot assemble table: {e}")))?;
        super::plausible::check_batch(path, schema, &batch)?;
        let table = Table {
            path: path.to_path_buf(),
            batch,
        };
        if schema.monotonic_t_s {
            if let Some(t) = table.opt_f64("t_s") {
                if let Some(row) = first_decrease(t) {
                    return Err(InputError::new(
                        path,
                        format!(
                            "t_s decreases ({} after {}); timestamps must be non-decreasing",
                            t[row],
                            t[row - 1]
                        ),
                    )
                    .column("t_s")
                    .row(row));
                }
            }
        }
        Ok(table)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
    pub fn batch(&self) -> &RecordBatch {
        &self.batch
    }
    pub fn len(&self) -> usize {
        self.batch.num_rows()
    }
    pub fn is_empty(&self) -> bool {
        self.batch.num_rows() == 0
    }
    pub fn has(&self, column: &str) -> bool {
        self.batch.column_by_name(column).is_some()
    }
    fn missing(&self, column: &str) -> InputError {
        InputError::new(&self.path, "column missing").column(column)
    }
    fn col(&self, column: &str) -> Result<&ArrayRef, InputError> {
        self.batch
            .column_by_name(column)
            .ok_or_else(|| self.missing(column))
    }

    /// A float64 column's values (contract columns are normalised to f64).
    pub fn f64(&self, column: &str) -> Result<&[f64], InputError> {
        self.col(column)?
            .as_any()
            .downcast_ref::<Float64Array>()
            .map(|a| a.values().as_ref())
            .ok_or_else(|| InputError::new(&self.path, "expected float64").column(column))
    }
    pub fn opt_f64(&self, column: &str) -> Option<&[f64]> {
        self.f64(column).ok()
    }
    pub fn f32(&self, column: &str) -> Result<&[f32], InputError> {
        self.col(column)?
            .as_any()
            .downcast_ref::<Float32Array>()
            .map(|a| a.values().as_ref())
            .ok_or_else(|| InputError::new(&self.path, "expected float32").column(column))
    }
    pub fn i32(&self, column: &str) -> Result<&[i32], InputError> {
        self.col(column)?
            .as_any()
            .downcast_ref::<Int32Array>()
            .map(|a| a.values().as_ref())
            .ok_or_else(|| InputError::new(&self.path, "expected int32").column(column))
    }
    pub fn opt_i32(&self, column: &str) -> Option<&[i32]> {
        self.i32(column).ok()
    }
    pub fn i64(&self, column: &str) -> Result<&[i64], InputError> {
        self.col(column)?
            .as_any()
            .downcast_ref::<Int64Array>()
            .map(|a| a.values().as_ref())
            .ok_or_else(|| InputError::new(&self.path, "expected int64").column(column))
    }
    pub fn i8(&self, column: &str) -> Result<&[i8], InputError> {
        self.col(column)?
            .as_any()
            .downcast_ref::<Int8Array>()
            .map(|a| a.values().as_ref())
            .ok_or_else(|| InputError::new(&self.path, "expected int8").column(column))
    }
    /// A text column as string slices.
    pub fn str(&self, column: &str) -> Result<Vec<&str>, InputError> {
        let a = self
            .col(column)?
            .as_any()
            .downcast_ref::<StringArray>()
            .ok_or_else(|| InputError::new(&self.path, "expected utf8").column(column))?;
        Ok((0..a.len()).map(|i| a.value(i)).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The chunked scans find exactly the row a plain scan finds — at chunk
    /// boundaries, with NaN (a decrease only where `<` says so), and none.
    #[test]
    fn chunked_scans_agree_with_plain_ones() {
        let naive_decrease = |t: &[f64]| t.windows(2).position(|w| w[1] < w[0]).map(|i| i + 1);
        let naive_fail = |v: &[f64]| v.iter().position(|x| !x.is_finite());
        for n in [0usize, 1, 2, 511, 512, 513, 1024, 1500] {
            let base: Vec<f64> = (0..n).map(|i| i as f64 * 0.5).collect();
            assert_eq!(first_decrease(&base), None);
            assert_eq!(first_failing(&base, |x: f64| x.is_finite()), None);
            for at in [0usize, 1, 510, 511, 512, 513, 1023, 1499] {
                if at >= n {
                    continue;
                }
                let mut t = base.clone();
                t[at] = -1.0;
                assert_eq!(first_decrease(&t), naive_decrease(&t), "n {n} at {at}");
                let mut t = base.clone();
                t[at] = f64::NAN;
                assert_eq!(first_decrease(&t), naive_decrease(&t), "NaN, n {n} at {at}");
                assert_eq!(first_failing(&t, |x: f64| x.is_finite()), naive_fail(&t));
                t[at] = f64::INFINITY;
                assert_eq!(first_failing(&t, |x: f64| x.is_finite()), Some(at));
            }
        }
        let a = Float32Array::from(vec![1.0f32, 2.0, f32::NAN, f32::INFINITY]);
        assert_eq!(first_non_finite(&a), Some((2, "NaN")));
    }
}

//! diagnosis.parquet: one row per observation, built a slice at a time
//! as it is written, from the table's ids and the per-row results.

use std::collections::BTreeMap;
use std::sync::Arc;

use arrow::array::{ArrayRef, Float64Array, RecordBatch};
use arrow::datatypes::{DataType, Field, Schema};

use crate::observations::Table;
use crate::Result;

/// Rows of diagnosis.parquet per batch built and written: the text keys
/// exist for one slice at a time, never for the fleet (docs/scale.md).
pub const PER_ROW_SLICE: usize = 1 << 16;

/// diagnosis.parquet: [machine,] run, observable, gap, contrib_<key>…,
/// residual_after — one row per observation, in input order. Held as the
/// table's ids and the per-row numbers; the rows are built a slice at a
/// time as they are written ([`PerRow::write_parquet`]).
pub struct PerRow {
    /// The keys (ids and names; its covariates are gone).
    table: Table,
    gap: Vec<f64>,
    /// Each selected effect's contribution, in selection order.
    contrib: Vec<(String, Vec<f64>)>,
    residual: Vec<f64>,
    schema: Arc<Schema>,
}

impl PerRow {
    pub(crate) fn new(
        mut table: Table,
        gap: Vec<f64>,
        mut contrib: BTreeMap<String, Vec<f64>>,
        keys: &[String],
        residual: Vec<f64>,
    ) -> PerRow {
        table.covs = Box::new(crate::observations::InMemory::default());
        table.real_u = None;
        let mut fields = Vec::new();
        if table.has_machine {
            fields.push(Field::new("machine", DataType::Utf8, false));
        }
        fields.extend([
            Field::new("run", DataType::Utf8, false),
            Field::new("observable", DataType::Utf8, false),
            Field::new("gap", DataType::Float64, false),
        ]);
        let contrib: Vec<(String, Vec<f64>)> = keys
            .iter()
            .map(|k| {
                let c = contrib.remove(k).expect("a selected key has its column");
                fields.push(Field::new(format!("contrib_{k}"), DataType::Float64, false));
                (k.clone(), c)
            })
            .collect();
        fields.push(Field::new("residual_after", DataType::Float64, false));
        PerRow {
            table,
            gap,
            contrib,
            residual,
            schema: Arc::new(Schema::new(fields)),
        }
    }

    pub fn schema(&self) -> Arc<Schema> {
        self.schema.clone()
    }

    pub fn num_rows(&self) -> usize {
        self.gap.len()
    }

    /// Rows `r` as a batch.
    pub fn slice(&self, r: std::ops::Range<usize>) -> Result<RecordBatch> {
        let rows: Vec<usize> = r.clone().collect();
        let mut cols: Vec<ArrayRef> = Vec::new();
        if self.table.has_machine {
            cols.push(self.table.text_column("machine", &rows));
        }
        cols.push(self.table.text_column("run", &rows));
        cols.push(self.table.text_column("observable", &rows));
        let num = |v: &[f64]| Arc::new(Float64Array::from(v[r.clone()].to_vec())) as ArrayRef;
        cols.push(num(&self.gap));
        for (_, c) in &self.contrib {
            cols.push(num(c));
        }
        cols.push(num(&self.residual));
        Ok(RecordBatch::try_new(self.schema.clone(), cols)?)
    }

    /// The rows in slices of [`PER_ROW_SLICE`].
    pub fn batches(&self) -> impl Iterator<Item = Result<RecordBatch>> + '_ {
        (0..self.num_rows())
            .step_by(PER_ROW_SLICE)
            .map(|at| self.slice(at..(at + PER_ROW_SLICE).min(self.num_rows())))
    }

    /// Every row in one batch (small tables; tests).
    pub fn to_batch(&self) -> Result<RecordBatch> {
        self.slice(0..self.num_rows())
    }

    /// Writes diagnosis.parquet to `path` atomically, a slice at a time.
    pub fn write_parquet(&self, path: &std::path::Path) -> Result<()> {
        crate::contracts::write::write_parquet_batches_atomic(path, self.schema(), self.batches())
    }
}

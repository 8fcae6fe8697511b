//! Streaming reader of ae.parquet (CONTRACTS.md §1: 10⁶–10⁸ rows per run, read
//! row group by row group with bounded memory). Each chunk is validated as it
//! arrives: NaN/inf and non-monotonic `t_s` are reported with their global row.

use std::fs::File;
use std::path::{Path, PathBuf};

use arrow::array::{Array, Float32Array, Float64Array};
use arrow::compute::cast;
use arrow::datatypes::DataType;
use parquet::arrow::arrow_reader::ParquetRecordBatchReader;
use parquet::arrow::ProjectionMask;

use super::schema::AE;
use super::table::{check_schema, first_non_finite, open_parquet};
use crate::error::InputError;

/// One decoded slice of the AE log.
#[derive(Debug, Clone, Default)]
pub struct AeChunk {
    /// Row index of `t_s[0]` in the whole file.
    pub first_row: usize,
    pub t_s: Vec<f64>,
    pub ae_v: Vec<f32>,
}

/// Iterator over validated AE chunks. Memory is one batch (plus the decoder's
/// one row group), whatever the file size.
pub struct AeStream {
    path: PathBuf,
    reader: ParquetRecordBatchReader,
    next_row: usize,
    last_t_s: f64,
    total_rows: usize,
    failed: bool,
}

impl AeStream {
    /// Default rows per chunk: 256 Ki samples (≈3 MB decoded).
    pub const DEFAULT_BATCH_ROWS: usize = 1 << 18;

    pub fn open(path: &Path) -> Result<AeStream, InputError> {
        Self::open_with_batch(path, Self::DEFAULT_BATCH_ROWS)
    }

    pub fn open_with_batch(path: &Path, batch_rows: usize) -> Result<AeStream, InputError> {
        let builder = open_parquet(path)?;
        check_schema(path, &AE, builder.schema())?;
        let total_rows = builder.metadata().file_metadata().num_rows().max(0) as usize;
        if total_rows == 0 {
            return Err(InputError::new(
                path,
                "table `ae` is empty (a required table needs rows)",
            ));
        }
        let idx: Vec<usize> = ["t_s", "ae_v"]
            .iter()
            .map(|n| builder.schema().index_of(n).expect("checked above"))
            .collect();
        let mask = ProjectionMask::roots(builder.parquet_schema(), idx);
        let reader = builder
            .with_projection(mask)
            .with_batch_size(batch_rows.max(1))
            .build()
            .map_err(|e| InputError::new(path, format!("cannot decode Parquet: {e}")))?;
        Ok(AeStream {
            path: path.to_path_buf(),
            reader,
            next_row: 0,
            last_t_s: f64::NEG_INFINITY,
            total_rows,
            failed: false,
        })
    }

    /// Rows in the file (from the footer, before decoding anything).
    pub fn total_rows(&self) -> usize {
        self.total_rows
    }

    fn decode(&mut self, batch: arrow::record_batch::RecordBatch) -> Result<AeChunk, InputError> {
        let first_row = self.next_row;
        let t = batch.column_by_name("t_s").expect("projected");
        let v = batch.column_by_name("ae_v").expect("projected");
        for (name, col) in [("t_s", t), ("ae_v", v)] {
            if let Some((row, what)) = first_non_finite(col.as_ref()) {
                return Err(
                    InputError::new(&self.path, format!("{what} in a required column"))
                        .column(name)
                        .row(first_row + row),
                );
            }
            super::plausible::check_column(&self.path, "ae", name, col.as_ref(), first_row)?;
        }
        let t = cast(t, &DataType::Float64)
            .map_err(|e| InputError::new(&self.path, e.to_string()).column("t_s"))?;
        let v = cast(v, &DataType::Float32)
            .map_err(|e| InputError::new(&self.path, e.to_string()).column("ae_v"))?;
        let t_s = t
            .as_any()
            .downcast_ref::<Float64Array>()
            .expect("cast")
            .values()
            .to_vec();
        let ae_v = v
            .as_any()
            .downcast_ref::<Float32Array>()
            .expect("cast")
            .values()
            .to_vec();
        let mut prev = self.last_t_s;
        for (i, &ti) in t_s.iter().enumerate() {
            if ti < prev {
                return Err(InputError::new(
                    &self.path,
                    format!("t_s decreases ({ti} after {prev}); timestamps must be non-decreasing"),
                )
                .column("t_s")
                .row(first_row + i));
            }
            prev = ti;
        }
        self.last_t_s = prev;
        self.next_row += t_s.len();
        Ok(AeChunk {
            first_row,
            t_s,
            ae_v,
        })
    }
}

impl Iterator for AeStream {
    type Item = Result<AeChunk, InputError>;
    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        let item = match self.reader.next()? {
            Ok(batch) => self.decode(batch),
            Err(e) => Err(InputError::new(
                &self.path,
                format!(
                    "cannot decode a row group near row {} (truncated or corrupt file?): {e}",
                    self.next_row
                ),
            )),
        };
        if item.is_err() {
            self.failed = true;
        }
        Some(item)
    }
}

// `File` is the only reader we stream from; keep the type visible for docs.
#[allow(dead_code)]
type _Source = File;

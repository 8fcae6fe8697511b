//! Streaming reader of ae.parquet (CONTRACTS.md §1: 10⁶–10⁸ rows per run, read
//! row group by row group with bounded memory). Each chunk is validated as it
//! arrives: NaN/inf and non-monotonic `t_s` are reported with their global row.
//!
//! The same reader streams any single signal column of any Parquet file
//! (`sparkout stage ingest --ae FILE --column C`), with or without a time
//! column: without one, sample `i` is at `i / sample_rate_hz`.

use std::path::{Path, PathBuf};

use arrow::array::{Array, Float32Array, Float64Array};
use arrow::compute::cast;
use arrow::datatypes::DataType;
use parquet::arrow::arrow_reader::ParquetRecordBatchReader;
use parquet::arrow::ProjectionMask;
use parquet::file::metadata::ParquetMetaData;

use super::convert::{normalise, TimeOrigin};
use super::parquet_file::corrupt_page;
use super::schema::{ColumnKind, AE};
use super::table::{check_schema, first_non_finite, open_parquet, type_accepted};
use crate::error::InputError;

/// One decoded slice of the AE log.
#[derive(Debug, Clone, Default)]
pub struct AeChunk {
    /// Row index of `t_s[0]` in the whole file.
    pub first_row: usize,
    pub t_s: Vec<f64>,
    pub ae_v: Vec<f32>,
}

/// Where the time of each sample comes from.
#[derive(Debug, Clone)]
enum Clock {
    /// A time column (float seconds, or timestamps from an origin).
    Column(String, TimeOrigin),
    /// Sample `i` at `i / rate`.
    Rate(f64),
}

/// Iterator over validated AE chunks. Memory is one batch (plus the decoder's
/// one row group), whatever the file size.
pub struct AeStream {
    path: PathBuf,
    meta: std::sync::Arc<ParquetMetaData>,
    reader: ParquetRecordBatchReader,
    value: String,
    clock: Clock,
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
        Self::open_at(path, &TimeOrigin::TableStart, batch_rows)
    }

    /// ae.parquet of a run: timestamps in `t_s` measured from `origin`.
    pub fn open_at(
        path: &Path,
        origin: &TimeOrigin,
        batch_rows: usize,
    ) -> Result<AeStream, InputError> {
        let builder = open_parquet(path)?;
        check_schema(path, &AE, builder.schema())?;
        Self::build(
            path,
            builder,
            "ae_v",
            Clock::Column("t_s".into(), origin.clone()),
            batch_rows,
        )
    }

    /// Any numeric column of any Parquet file as a signal. Time from the
    /// `t_s` column when the file has one, else from `sample_rate_hz`.
    pub fn open_series(
        path: &Path,
        column: &str,
        sample_rate_hz: f64,
    ) -> Result<AeStream, InputError> {
        let builder = open_parquet(path)?;
        let schema = builder.schema().clone();
        let field = schema.field_with_name(column).map_err(|_| {
            let have: Vec<&str> = schema.fields().iter().map(|f| f.name().as_str()).collect();
            InputError::new(
                path,
                format!("no such column (columns present: {})", have.join(", ")),
            )
            .column(column)
        })?;
        if !type_accepted(ColumnKind::F32, column, field.data_type()) {
            return Err(InputError::new(
                path,
                format!("wrong type {} for a signal (a number)", field.data_type()),
            )
            .column(column));
        }
        let clock = match schema.field_with_name("t_s") {
            Ok(f) if type_accepted(ColumnKind::F64, "t_s", f.data_type()) && column != "t_s" => {
                Clock::Column("t_s".into(), TimeOrigin::TableStart)
            }
            _ => Clock::Rate(sample_rate_hz),
        };
        Self::build(path, builder, column, clock, Self::DEFAULT_BATCH_ROWS)
    }

    fn build(
        path: &Path,
        builder: parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder<std::fs::File>,
        value: &str,
        clock: Clock,
        batch_rows: usize,
    ) -> Result<AeStream, InputError> {
        let total_rows = builder.metadata().file_metadata().num_rows().max(0) as usize;
        if total_rows == 0 {
            return Err(InputError::new(
                path,
                "the signal table is empty (a required table needs rows)",
            ));
        }
        let mut idx = vec![builder.schema().index_of(value).expect("checked")];
        let clock = match clock {
            // Time as the origin of the whole file: the earliest timestamp is
            // not known before streaming, so the first one is used (t_s is
            // non-decreasing, so it is the earliest of a valid file).
            Clock::Column(t, o) => {
                idx.push(builder.schema().index_of(&t).expect("checked"));
                Clock::Column(t, o)
            }
            c => c,
        };
        let meta = builder.metadata().clone();
        let mask = ProjectionMask::roots(builder.parquet_schema(), idx);
        let reader = builder
            .with_projection(mask)
            .with_batch_size(batch_rows.max(1))
            .build()
            .map_err(|e| corrupt_page(path, &meta, 0, e))?;
        Ok(AeStream {
            path: path.to_path_buf(),
            meta,
            reader,
            value: value.to_string(),
            clock,
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
        let v = batch.column_by_name(&self.value).expect("projected");
        let bad = |name: &str, col: &dyn Array| {
            first_non_finite(col).map(|(row, what)| {
                InputError::new(&self.path, format!("{what} in a required column"))
                    .column(name)
                    .row(first_row + row)
            })
        };
        let v = cast(v, &DataType::Float32)
            .map_err(|e| InputError::new(&self.path, e.to_string()).column(&self.value))?;
        if let Some(e) = bad(&self.value, v.as_ref()) {
            return Err(e);
        }
        let ae_v = v
            .as_any()
            .downcast_ref::<Float32Array>()
            .expect("cast")
            .values()
            .to_vec();
        let t_s: Vec<f64> = match &mut self.clock {
            Clock::Rate(hz) => (0..ae_v.len())
                .map(|i| (first_row + i) as f64 / *hz)
                .collect(),
            Clock::Column(name, origin) => {
                let t = batch.column_by_name(name).expect("projected");
                if let (TimeOrigin::TableStart, DataType::Timestamp(..)) = (&*origin, t.data_type())
                {
                    // Fix the origin at the first timestamp, for every chunk.
                    if let Some(t0) = super::convert::earliest_unix_s(t.as_ref()) {
                        *origin = TimeOrigin::UnixS(t0);
                    }
                }
                let t =
                    normalise(&self.path, name, t, &DataType::Float64, origin).map_err(|e| {
                        let row = first_row + e.row.unwrap_or(0);
                        e.row(row)
                    })?;
                if let Some(e) = bad(name, t.as_ref()) {
                    return Err(e);
                }
                t.as_any()
                    .downcast_ref::<Float64Array>()
                    .expect("normalised")
                    .values()
                    .to_vec()
            }
        };
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
            Err(e) => Err(corrupt_page(&self.path, &self.meta, self.next_row, e)),
        };
        if item.is_err() {
            self.failed = true;
        }
        Some(item)
    }
}

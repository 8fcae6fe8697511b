//! Streaming reader of ae.parquet (CONTRACTS.md §1: 10⁶–10⁸ rows per run, read
//! row group by row group with bounded memory). Each chunk is validated as it
//! arrives: NaN/inf and non-monotonic `t_s` are reported with their global row.
//!
//! Decoding, not detection, is the slow part of AE ingest (the detector runs
//! at hundreds of M samples/s, one decoder thread at tens), so row groups are
//! decoded by a few dedicated threads ahead of the consumer: worker `w` of `K`
//! decodes row groups `w, w+K, …` in order into a channel of depth one, and
//! the consumer takes group `g` from worker `g mod K`. Chunks therefore arrive
//! in file order (identical results whatever K), and memory stays bounded at
//! about two batches per worker. The workers are plain threads, not rayon
//! tasks: the engine runs stages on rayon's pool, and a pool thread blocked
//! on a channel fed by tasks of the same pool could deadlock.

use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};

use arrow::array::{Array, Float32Array, Float64Array};
use arrow::compute::cast;
use arrow::datatypes::DataType;
use arrow::record_batch::RecordBatch;
use parquet::arrow::arrow_reader::{ArrowReaderMetadata, ParquetRecordBatchReaderBuilder};
use parquet::arrow::ProjectionMask;

use super::schema::AE;
use super::table::{check_schema, first_decrease, first_non_finite, open_parquet};
use crate::error::InputError;

/// One decoded slice of the AE log.
#[derive(Debug, Clone, Default)]
pub struct AeChunk {
    /// Row index of `t_s[0]` in the whole file.
    pub first_row: usize,
    pub t_s: Vec<f64>,
    pub ae_v: Vec<f32>,
}

/// What a decoder thread sends: a validated chunk, or the end of a row group.
enum Decoded {
    Chunk(Result<AeChunk, InputError>),
    GroupEnd,
}

/// Iterator over validated AE chunks. Memory is about two batches per decoder
/// thread, whatever the file size.
pub struct AeStream {
    path: PathBuf,
    /// One receiver per decoder thread; row group `g` comes from `g % K`.
    workers: Vec<Receiver<Decoded>>,
    row_groups: usize,
    current_group: usize,
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
        Self::open_with(path, batch_rows, default_decode_threads())
    }

    /// `decode_threads` row groups are decoded ahead in parallel (≥ 1).
    pub fn open_with(
        path: &Path,
        batch_rows: usize,
        decode_threads: usize,
    ) -> Result<AeStream, InputError> {
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
        // The footer is parsed once; every decoder thread reuses it.
        let metadata = ArrowReaderMetadata::try_new(builder.metadata().clone(), Default::default())
            .map_err(|e| InputError::new(path, format!("cannot decode Parquet: {e}")))?;
        let group_rows: Vec<usize> = builder
            .metadata()
            .row_groups()
            .iter()
            .map(|g| g.num_rows().max(0) as usize)
            .collect();
        let row_groups = group_rows.len();
        let first_rows: Vec<usize> = group_rows
            .iter()
            .scan(0usize, |acc, &n| {
                let first = *acc;
                *acc += n;
                Some(first)
            })
            .collect();
        let k = decode_threads.clamp(1, row_groups.max(1));
        let workers = (0..k)
            .map(|w| {
                let (tx, rx) = sync_channel(1);
                let job = DecodeJob {
                    path: path.to_path_buf(),
                    metadata: metadata.clone(),
                    mask: mask.clone(),
                    batch_rows: batch_rows.max(1),
                    groups: (w..row_groups).step_by(k).collect(),
                    first_rows: first_rows.clone(),
                };
                std::thread::Builder::new()
                    .name(format!("ae-decode-{w}"))
                    .spawn(move || job.run(&tx))
                    .map_err(|e| {
                        InputError::new(path, format!("cannot start a decoder thread: {e}"))
                    })?;
                Ok(rx)
            })
            .collect::<Result<Vec<_>, InputError>>()?;
        Ok(AeStream {
            path: path.to_path_buf(),
            workers,
            row_groups,
            current_group: 0,
            last_t_s: f64::NEG_INFINITY,
            total_rows,
            failed: false,
        })
    }

    /// Rows in the file (from the footer, before decoding anything).
    pub fn total_rows(&self) -> usize {
        self.total_rows
    }
}

/// Two threads per stream are enough to keep one consumer fed on the 2-core
/// machines this runs on; more only costs memory.
fn default_decode_threads() -> usize {
    std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(4)
}

/// The row groups one decoder thread owns.
struct DecodeJob {
    path: PathBuf,
    metadata: ArrowReaderMetadata,
    mask: ProjectionMask,
    batch_rows: usize,
    groups: Vec<usize>,
    first_rows: Vec<usize>,
}

impl DecodeJob {
    /// Decode and validate each owned row group in order. Stops at the first
    /// error (after sending it) or when the consumer has gone (send fails).
    fn run(self, tx: &SyncSender<Decoded>) {
        for &g in &self.groups {
            let mut row = self.first_rows[g];
            let reader = File::open(&self.path)
                .map_err(|e| InputError::new(&self.path, format!("cannot open: {e}")))
                .and_then(|file| {
                    ParquetRecordBatchReaderBuilder::new_with_metadata(file, self.metadata.clone())
                        .with_projection(self.mask.clone())
                        .with_row_groups(vec![g])
                        .with_batch_size(self.batch_rows)
                        .build()
                        .map_err(|e| decode_error(&self.path, row, e))
                });
            let reader = match reader {
                Ok(r) => r,
                Err(e) => {
                    let _ = tx.send(Decoded::Chunk(Err(e)));
                    return;
                }
            };
            for batch in reader {
                let chunk = batch
                    .map_err(|e| decode_error(&self.path, row, e))
                    .and_then(|b| to_chunk(&self.path, &b, row));
                let failed = chunk.is_err();
                if let Ok(c) = &chunk {
                    row += c.t_s.len();
                }
                if tx.send(Decoded::Chunk(chunk)).is_err() || failed {
                    return;
                }
            }
            if tx.send(Decoded::GroupEnd).is_err() {
                return;
            }
        }
    }
}

fn decode_error(path: &Path, row: usize, e: impl std::fmt::Display) -> InputError {
    InputError::new(
        path,
        format!("cannot decode a row group near row {row} (truncated or corrupt file?): {e}"),
    )
}

/// Validate one batch (finite values, `t_s` non-decreasing inside it) and
/// convert it to the chunk's native types.
fn to_chunk(path: &Path, batch: &RecordBatch, first_row: usize) -> Result<AeChunk, InputError> {
    let t = batch.column_by_name("t_s").expect("projected");
    let v = batch.column_by_name("ae_v").expect("projected");
    for (name, col) in [("t_s", t), ("ae_v", v)] {
        if let Some((row, what)) = first_non_finite(col.as_ref()) {
            return Err(
                InputError::new(path, format!("{what} in a required column"))
                    .column(name)
                    .row(first_row + row),
            );
        }
    }
    let t = cast(t, &DataType::Float64)
        .map_err(|e| InputError::new(path, e.to_string()).column("t_s"))?;
    let v = cast(v, &DataType::Float32)
        .map_err(|e| InputError::new(path, e.to_string()).column("ae_v"))?;
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
    if let Some(i) = first_decrease(&t_s) {
        return Err(decrease_error(path, first_row + i, t_s[i], t_s[i - 1]));
    }
    Ok(AeChunk {
        first_row,
        t_s,
        ae_v,
    })
}

fn decrease_error(path: &Path, row: usize, t: f64, prev: f64) -> InputError {
    InputError::new(
        path,
        format!("t_s decreases ({t} after {prev}); timestamps must be non-decreasing"),
    )
    .column("t_s")
    .row(row)
}

impl Iterator for AeStream {
    type Item = Result<AeChunk, InputError>;
    fn next(&mut self) -> Option<Self::Item> {
        while !self.failed && self.current_group < self.row_groups {
            let worker = &self.workers[self.current_group % self.workers.len()];
            let item = match worker.recv() {
                Ok(Decoded::GroupEnd) => {
                    self.current_group += 1;
                    continue;
                }
                Ok(Decoded::Chunk(Ok(c))) => match c.t_s.first() {
                    // Within a chunk the worker checked order; across chunks
                    // (and row groups) only the consumer can.
                    Some(&t0) if t0 < self.last_t_s => {
                        Err(decrease_error(&self.path, c.first_row, t0, self.last_t_s))
                    }
                    _ => {
                        self.last_t_s = c.t_s.last().copied().unwrap_or(self.last_t_s);
                        Ok(c)
                    }
                },
                Ok(Decoded::Chunk(Err(e))) => Err(e),
                Err(_) => Err(InputError::new(
                    &self.path,
                    format!(
                        "the decoder of row group {} stopped without a result (out of memory?)",
                        self.current_group
                    ),
                )),
            };
            self.failed = item.is_err();
            return Some(item);
        }
        None
    }
}

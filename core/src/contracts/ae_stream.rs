//! Streaming reader of ae.parquet (docs/formats.md §4: 10⁶–10⁸ rows per run, read
//! row group by row group with bounded memory). Each chunk is validated as it
//! arrives: NaN/inf and non-monotonic `t_s` are reported with their global row.
//!
//! Decoding, not detection, is the slow part of AE ingest (the detector runs
//! at hundreds of M samples/s, one decoder thread at tens), so row groups are
//! decoded by a few dedicated threads ahead of the consumer: worker `w` of `K`
//! decodes row groups `w, w+K, …` in order into a channel a row group's
//! worth of chunks deep, and the consumer takes group `g` from worker
//! `g mod K`. Chunks therefore arrive in file order (identical results
//! whatever K), and memory stays bounded at a few batches per worker. The
//! workers are plain threads, not rayon tasks: the engine runs stages on
//! rayon's pool, and a pool thread blocked on a channel fed by tasks of the
//! same pool could deadlock.
//!
//! The same reader streams any single signal column of any Parquet file
//! (`sparkout stage ingest --ae FILE --column C`), with or without a time
//! column: without one, sample `i` is at `i / sample_rate_hz`. Time columns
//! may hold timestamps (docs/formats.md §2), measured from a [`TimeOrigin`].

use super::input_file::InputFile;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};

use arrow::array::{Array, Float32Array, Float64Array};
use arrow::buffer::ScalarBuffer;
use arrow::compute::cast;
use arrow::datatypes::DataType;
use arrow::record_batch::RecordBatch;
use parquet::arrow::arrow_reader::{ArrowReaderMetadata, ParquetRecordBatchReaderBuilder};
use parquet::arrow::ProjectionMask;

use super::convert::{normalise, TimeOrigin};
use super::parquet_file::corrupt_page;
use super::schema::{ColumnKind, AE};
use super::table::{
    all_within, check_schema, first_decrease, first_non_finite, open_parquet, time_column_scan,
    type_accepted,
};
use crate::error::InputError;

/// One decoded slice of the AE log.
#[derive(Debug, Clone)]
pub struct AeChunk {
    /// Row index of `t_s[0]` in the whole file.
    pub first_row: usize,
    /// The decoded arrays' own buffers (no copy: a copy of every sample was
    /// 4 % of AE ingest).
    pub t_s: ScalarBuffer<f64>,
    pub ae_v: ScalarBuffer<f32>,
    /// The largest step `t_s[i + 1] − t_s[i]` inside the chunk (−∞ for a
    /// chunk of one sample), measured in the validation pass: a consumer
    /// looking for gaps need not scan a chunk whose largest step is small.
    pub max_step_s: f64,
}

/// Where the time of each sample comes from.
#[derive(Debug, Clone)]
enum Clock {
    /// A time column (float seconds, or timestamps from an origin).
    Column(String, TimeOrigin),
    /// Sample `i` at `i / rate`.
    Rate(f64),
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
        Self::open_at_with(path, &TimeOrigin::TableStart, batch_rows, decode_threads)
    }

    /// ae.parquet of a run: timestamps in `t_s` measured from `origin`.
    pub fn open_at(
        path: &Path,
        origin: &TimeOrigin,
        batch_rows: usize,
    ) -> Result<AeStream, InputError> {
        Self::open_at_with(path, origin, batch_rows, default_decode_threads())
    }

    fn open_at_with(
        path: &Path,
        origin: &TimeOrigin,
        batch_rows: usize,
        decode_threads: usize,
    ) -> Result<AeStream, InputError> {
        let builder = open_parquet(path)?;
        check_schema(path, &AE, builder.schema())?;
        let clock = Clock::Column("t_s".into(), origin.clone());
        Self::start(path, builder, "ae_v", clock, batch_rows, decode_threads)
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
        let threads = default_decode_threads();
        Self::start(
            path,
            builder,
            column,
            clock,
            Self::DEFAULT_BATCH_ROWS,
            threads,
        )
    }

    fn start(
        path: &Path,
        builder: ParquetRecordBatchReaderBuilder<InputFile>,
        value: &str,
        clock: Clock,
        batch_rows: usize,
        decode_threads: usize,
    ) -> Result<AeStream, InputError> {
        let total_rows = builder.metadata().file_metadata().num_rows().max(0) as usize;
        if total_rows == 0 {
            return Err(InputError::new(
                path,
                format!("table `{}` is empty (a required table needs rows)", {
                    if value == "ae_v" {
                        "ae"
                    } else {
                        value
                    }
                }),
            ));
        }
        let mut names = vec![value.to_string()];
        if let Clock::Column(t, _) = &clock {
            names.push(t.clone());
        }
        let idx: Vec<usize> = names
            .iter()
            .map(|n| builder.schema().index_of(n).expect("checked above"))
            .collect();
        let mask = ProjectionMask::roots(builder.parquet_schema(), idx);
        // Timestamps counted from the file's start: its first stamp (t_s is
        // non-decreasing), read before the workers split the row groups.
        let clock = match clock {
            Clock::Column(t, TimeOrigin::TableStart)
                if matches!(
                    builder
                        .schema()
                        .field_with_name(&t)
                        .map(|f| f.data_type().clone()),
                    Ok(DataType::Timestamp(..))
                ) =>
            {
                let t0 = first_timestamp(path, &t)?;
                Clock::Column(t, t0.map_or(TimeOrigin::TableStart, TimeOrigin::UnixS))
            }
            c => c,
        };
        // The footer is parsed once; every decoder thread reuses it.
        let metadata = ArrowReaderMetadata::try_new(builder.metadata().clone(), Default::default())
            .map_err(|e| corrupt_page(path, builder.metadata(), 0, e))?;
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
                let (tx, rx) = sync_channel(DECODE_AHEAD_CHUNKS);
                let job = DecodeJob {
                    path: path.to_path_buf(),
                    metadata: metadata.clone(),
                    mask: mask.clone(),
                    batch_rows: batch_rows.max(1),
                    groups: (w..row_groups).step_by(k).collect(),
                    first_rows: first_rows.clone(),
                    value: value.to_string(),
                    clock: clock.clone(),
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

/// Chunks a decoder thread may hold decoded ahead of the consumer. With one,
/// the worker whose row group is not being consumed stalls after two chunks
/// and the decoders sat idle 14 % of the time (perf stat: 1.72 of 2 CPUs);
/// a row group's worth (≈ 4 chunks of the default size) keeps both busy.
/// Memory: about (this + 1) chunks per decoder thread (≈ 3 MB each).
const DECODE_AHEAD_CHUNKS: usize = 4;

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
    value: String,
    clock: Clock,
}

/// The first value of a timestamp column, seconds since the epoch.
fn first_timestamp(path: &Path, column: &str) -> Result<Option<f64>, InputError> {
    let builder = open_parquet(path)?;
    let idx = builder.schema().index_of(column).expect("checked");
    let mask = ProjectionMask::roots(builder.parquet_schema(), [idx]);
    let meta = builder.metadata().clone();
    let mut reader = builder
        .with_projection(mask)
        .with_batch_size(1)
        .build()
        .map_err(|e| corrupt_page(path, &meta, 0, e))?;
    match super::parquet_file::next_batch(&mut reader) {
        Some(Ok(b)) => Ok(super::convert::earliest_unix_s(b.column(0).as_ref())),
        Some(Err(e)) => Err(corrupt_page(path, &meta, 0, e)),
        None => Ok(None),
    }
}

impl DecodeJob {
    /// Decode and validate each owned row group in order. Stops at the first
    /// error (after sending it) or when the consumer has gone (send fails).
    fn run(self, tx: &SyncSender<Decoded>) {
        let input = match InputFile::open(&self.path) {
            Ok(f) => f,
            Err(e) => {
                let e = InputError::new(&self.path, format!("cannot open: {e}"));
                let _ = tx.send(Decoded::Chunk(Err(e)));
                return;
            }
        };
        for &g in &self.groups {
            let mut row = self.first_rows[g];
            // The bytes of this row group's projected columns, mapped for
            // the time it is decoded (unmapped when its reader is dropped).
            let (lo, hi) = self
                .metadata
                .metadata()
                .row_group(g)
                .columns()
                .iter()
                .enumerate()
                .filter(|(leaf, _)| self.mask.leaf_included(*leaf))
                .map(|(_, c)| c.byte_range())
                .fold((u64::MAX, 0u64), |(lo, hi), (start, len)| {
                    (lo.min(start), hi.max(start.saturating_add(len)))
                });
            let reader = input
                .window(lo, hi.saturating_sub(lo) as usize)
                .map_err(|e| InputError::new(&self.path, format!("cannot open: {e}")))
                .and_then(|file| {
                    ParquetRecordBatchReaderBuilder::new_with_metadata(file, self.metadata.clone())
                        .with_projection(self.mask.clone())
                        .with_row_groups(vec![g])
                        .with_batch_size(self.batch_rows)
                        .build()
                        .map_err(|e| corrupt_page(&self.path, self.metadata.metadata(), row, e))
                });
            let mut reader = match reader {
                Ok(r) => r,
                Err(e) => {
                    let _ = tx.send(Decoded::Chunk(Err(e)));
                    return;
                }
            };
            while let Some(batch) = super::parquet_file::next_batch(&mut reader) {
                let chunk = batch
                    .map_err(|e| corrupt_page(&self.path, self.metadata.metadata(), row, e))
                    .and_then(|b| to_chunk(&self.path, &b, row, &self.value, &self.clock));
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

/// Validate one batch (finite values, time non-decreasing inside it) and
/// convert it to the chunk's native types.
///
/// Each column is first checked in one fused pass ([`all_within`],
/// [`time_column_scan`]); the separate checks run only on a column that
/// fails it, so errors name the same first failure as before while a valid
/// log is read once per column, not three times.
fn to_chunk(
    path: &Path,
    batch: &RecordBatch,
    first_row: usize,
    value: &str,
    clock: &Clock,
) -> Result<AeChunk, InputError> {
    let bad = |name: &str, col: &dyn Array| {
        first_non_finite(col).map(|(row, what)| {
            InputError::new(path, format!("{what} in a required column"))
                .column(name)
                .row(first_row + row)
        })
    };
    let v = batch.column_by_name(value).expect("projected");
    // The plausible range of the contract's `ae_v`; any other signal column
    // (`--column`) only has to be finite.
    let value_range = (value == "ae_v")
        .then(|| super::plausible::range_for(&super::schema::AE, value))
        .flatten()
        .map_or((f64::MIN, f64::MAX), |r| (r.lo, r.hi));
    let value_ok = v.null_count() == 0
        && v.as_any()
            .downcast_ref::<Float32Array>()
            .is_some_and(|a| all_within(a.values(), value_range.0, value_range.1));
    if !value_ok {
        if let Some(e) = bad(value, v.as_ref()) {
            return Err(e);
        }
        if value == "ae_v" {
            super::plausible::check_column(path, &super::schema::AE, value, v.as_ref(), first_row)?;
        }
    }
    let was_f32 = v.data_type() == &DataType::Float32;
    let v = cast(v, &DataType::Float32)
        .map_err(|e| InputError::new(path, e.to_string()).column(value))?;
    if !was_f32 {
        if let Some(e) = bad(value, v.as_ref()) {
            return Err(e); // a float64 beyond float32's range
        }
    }
    let ae_v = v
        .as_any()
        .downcast_ref::<Float32Array>()
        .expect("cast")
        .values()
        .clone();
    let (t_s, max_step_s): (ScalarBuffer<f64>, f64) = match clock {
        Clock::Rate(hz) => {
            let t: Vec<f64> = (0..ae_v.len())
                .map(|i| (first_row + i) as f64 / hz)
                .collect();
            let max_step_s = largest_step(&t);
            (t.into(), max_step_s)
        }
        Clock::Column(name, origin) => {
            let t = batch.column_by_name(name).expect("projected");
            let t = normalise(path, name, t, &DataType::Float64, origin).map_err(|e| {
                let row = first_row + e.row.unwrap_or(0);
                e.row(row)
            })?;
            let t_s = t
                .as_any()
                .downcast_ref::<Float64Array>()
                .expect("normalised");
            let range =
                super::plausible::range_for(&super::schema::AE, name).expect("t_s has a range");
            let scan = if t_s.null_count() == 0 {
                time_column_scan(t_s.values(), range.lo, range.hi)
            } else {
                None
            };
            let max_step_s = match scan {
                Some(m) => m,
                None => {
                    if let Some(e) = bad(name, t.as_ref()) {
                        return Err(e);
                    }
                    super::plausible::check_column(
                        path,
                        &super::schema::AE,
                        name,
                        t.as_ref(),
                        first_row,
                    )?;
                    if let Some(i) = first_decrease(t_s.values()) {
                        return Err(decrease_error(
                            path,
                            first_row + i,
                            t_s.value(i),
                            t_s.value(i - 1),
                        ));
                    }
                    // Unreachable while the fused scan and the separate
                    // checks agree; measured plainly if they ever do not.
                    largest_step(t_s.values())
                }
            };
            (t_s.values().clone(), max_step_s)
        }
    };
    Ok(AeChunk {
        first_row,
        t_s,
        ae_v,
        max_step_s,
    })
}

/// The largest step between neighbouring stamps (−∞ for fewer than two).
fn largest_step(t: &[f64]) -> f64 {
    t.windows(2)
        .map(|w| w[1] - w[0])
        .fold(f64::NEG_INFINITY, f64::max)
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

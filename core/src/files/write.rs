//! Atomic writers: every file goes to a temporary name beside its final name
//! and is renamed into place when complete (docs/formats.md §8), so a crash never
//! leaves a truncated artifact under a final name.

use std::fs::{self, File};
use std::io::Write;
use std::path::{Path, PathBuf};

use crate::Context;
use arrow::record_batch::RecordBatch;
use parquet::arrow::ArrowWriter;
use parquet::basic::{Compression, ZstdLevel};
use parquet::file::properties::{EnabledStatistics, WriterProperties};

use crate::error::Result;

/// Rows per Parquet row group in what sparkout writes (keeps readers streaming).
pub const ROW_GROUP_ROWS: usize = 1 << 17;

fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "artifact".into());
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

/// `create_dir_all` in a directory other threads write into and clean up:
/// a run that fails has its outputs removed, and its machine directory with
/// them once empty, which can fall between this call making the machine
/// directory and making a run directory inside it — NotFound — or between
/// `create_dir_all` finding the machine directory already there and
/// checking it is a directory — AlreadyExists for a path that is no longer
/// there. Either is the other run's cleanup, not a missing output directory
/// or a file in the way, so the creation is tried again (a bounded number
/// of times — a path under a dangling link is NotFound for ever, a file in
/// the way AlreadyExists for ever — then the error stands).
pub fn create_dir_all_shared(dir: &Path) -> Result<()> {
    use std::io::ErrorKind::{AlreadyExists, NotFound};
    let mut tries = 0;
    loop {
        match fs::create_dir_all(dir) {
            Ok(()) => return Ok(()),
            Err(e) if matches!(e.kind(), NotFound | AlreadyExists) && tries < 1_000 => tries += 1,
            Err(e) => {
                return Err(e).with_context(|| format!("cannot create {}", dir.display()));
            }
        }
    }
}

/// Write `bytes` to `path` atomically (temp + fsync + rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    if let Some(dir) = path.parent() {
        create_dir_all_shared(dir)?;
    }
    let tmp = temp_path(path);
    let result = (|| -> Result<()> {
        let mut f = File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        fs::rename(&tmp, path)?;
        Ok(())
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result.with_context(|| format!("cannot write {}", path.display()))
}

/// Pretty JSON, newline-terminated, atomically.
pub fn write_json_atomic(path: &Path, value: &impl serde::Serialize) -> Result<()> {
    let mut s = serde_json::to_string_pretty(value)?;
    s.push('\n');
    write_atomic(path, s.as_bytes())
}

/// zstd level 1: the fleet tables' compression was ≈ 5 % of `aggregate`'s
/// time at level 3; level 1 takes ≈ 3 % less CPU for files 1–4 % larger
/// (docs/benchmarks.md).
pub fn writer_properties(schema: &arrow::datatypes::Schema) -> WriterProperties {
    let mut b = WriterProperties::builder()
        .set_compression(Compression::ZSTD(
            ZstdLevel::try_new(1).expect("valid level"),
        ))
        .set_max_row_group_row_count(Some(ROW_GROUP_ROWS))
        .set_statistics_enabled(EnabledStatistics::Chunk)
        .set_created_by("sparkout".to_string());
    // Floats as byte-stream-split, no dictionary: measured signals (encoder
    // noise, AE) have no repeated values, and splitting the bytes lets zstd
    // compress the slowly varying exponent/high-mantissa bytes.
    for f in schema.fields() {
        if matches!(
            f.data_type(),
            arrow::datatypes::DataType::Float64 | arrow::datatypes::DataType::Float32
        ) {
            let col = parquet::schema::types::ColumnPath::from(f.name().as_str());
            b = b
                .set_column_dictionary_enabled(col.clone(), false)
                .set_column_encoding(col, parquet::basic::Encoding::BYTE_STREAM_SPLIT);
        }
    }
    b.build()
}

/// Write one batch as zstd Parquet, atomically.
pub fn write_parquet_atomic(path: &Path, batch: &RecordBatch) -> Result<()> {
    write_parquet_batches_atomic(path, batch.schema(), std::iter::once(Ok(batch.clone())))
}

/// Write a stream of batches (same schema) as one zstd Parquet file,
/// atomically: the big generators stream through this without holding the
/// whole table. Columns are encoded on the calling thread.
pub fn write_parquet_batches_atomic(
    path: &Path,
    schema: arrow::datatypes::SchemaRef,
    batches: impl IntoIterator<Item = Result<RecordBatch>>,
) -> Result<()> {
    write_parquet_stream_atomic(path, schema, batches, Encoding::OneThread)
}

/// Where a stream's columns are encoded and compressed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// On the calling thread: for writers that run beside other work
    /// (a run's stages in the worker pool, the join whose reader keeps
    /// the other core busy — there, idle pool threads spinning for work
    /// cost the reader more than the encoding gained).
    OneThread,
    /// Each batch's columns in parallel on the rayon pool: for a large
    /// table written while nothing else runs (diagnosis.parquet).
    ColumnsInParallel,
}

/// [`write_parquet_batches_atomic`] with the columns encoded as
/// `encoding` says; the same bytes either way.
pub fn write_parquet_stream_atomic(
    path: &Path,
    schema: arrow::datatypes::SchemaRef,
    batches: impl IntoIterator<Item = Result<RecordBatch>>,
    encoding: Encoding,
) -> Result<()> {
    if let Some(dir) = path.parent() {
        create_dir_all_shared(dir)?;
    }
    let tmp = temp_path(path);
    let result = (|| -> Result<()> {
        let file = File::create(&tmp)?;
        let props = writer_properties(&schema);
        let mut w = StreamWriter::try_new(file, schema, props, encoding)?;
        for b in batches {
            w.write(&b?)?;
        }
        let file = w.into_inner()?;
        file.sync_all()?;
        fs::rename(&tmp, path)?;
        Ok(())
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result.with_context(|| format!("cannot write {}", path.display()))
}

/// [`ArrowWriter`]'s file, byte for byte, its columns encoded on one
/// thread or, for [`Encoding::ColumnsInParallel`], each batch's columns
/// in parallel (rayon): the same row groups (cut at the properties' row
/// count, as `ArrowWriter::write` cuts them), each column's writer fed
/// the same leaves in the same order, the chunks appended in column
/// order. Encoding and compressing diagnosis.parquet (≈ 3·10⁷ rows at
/// 2 000 servo runs) was one core's work while the other waited. A batch
/// is encoded as it comes: nothing is held but the open row group's
/// encoded pages, as with `ArrowWriter`.
struct StreamWriter<W: Write + Send> {
    file: parquet::file::writer::SerializedFileWriter<W>,
    factory: parquet::arrow::arrow_writer::ArrowRowGroupWriterFactory,
    schema: arrow::datatypes::SchemaRef,
    max_rows: Option<usize>,
    encoding: Encoding,
    /// The open row group's column writers (one per leaf) and its rows.
    open: Option<(Vec<parquet::arrow::arrow_writer::ArrowColumnWriter>, usize)>,
}

impl<W: Write + Send> StreamWriter<W> {
    fn try_new(
        out: W,
        schema: arrow::datatypes::SchemaRef,
        props: WriterProperties,
        encoding: Encoding,
    ) -> Result<StreamWriter<W>> {
        // A byte limit cuts row groups by encoded size as they fill, which
        // this writer does not mirror; sparkout's properties set none.
        assert!(
            props.max_row_group_bytes().is_none(),
            "row groups are cut by rows only"
        );
        let max_rows = props.max_row_group_row_count();
        // ArrowWriter sets up the file (the schema's Arrow metadata, the
        // properties) and hands its writer over before any row is written.
        let (file, factory) =
            ArrowWriter::try_new(out, schema.clone(), Some(props))?.into_serialized_writer()?;
        Ok(StreamWriter {
            file,
            factory,
            schema,
            max_rows,
            encoding,
            open: None,
        })
    }

    fn write(&mut self, batch: &RecordBatch) -> Result<()> {
        let mut rest = batch.clone();
        while rest.num_rows() > 0 {
            if self.open.is_none() {
                let g = self.file.flushed_row_groups().len();
                self.open = Some((self.factory.create_column_writers(g)?, 0));
            }
            let (writers, rows) = self.open.as_mut().expect("opened");
            let fits = self.max_rows.map_or(rest.num_rows(), |m| m - *rows);
            let part = rest.slice(0, fits.min(rest.num_rows()));
            rest = rest.slice(part.num_rows(), rest.num_rows() - part.num_rows());
            let mut leaves = Vec::with_capacity(writers.len());
            for (field, column) in self.schema.fields().iter().zip(part.columns()) {
                leaves.extend(parquet::arrow::arrow_writer::compute_leaves(
                    field.as_ref(),
                    column,
                )?);
            }
            match self.encoding {
                Encoding::OneThread => writers
                    .iter_mut()
                    .zip(&leaves)
                    .try_for_each(|(w, leaf)| w.write(leaf))?,
                Encoding::ColumnsInParallel => {
                    use rayon::prelude::*;
                    writers
                        .par_iter_mut()
                        .zip(leaves.par_iter())
                        .try_for_each(|(w, leaf)| w.write(leaf))?
                }
            }
            *rows += part.num_rows();
            if self.max_rows.is_some_and(|m| *rows >= m) {
                self.flush()?;
            }
        }
        Ok(())
    }

    /// Closes the open row group: its columns' last pages are compressed
    /// in parallel, the chunks appended in column order.
    fn flush(&mut self) -> Result<()> {
        let Some((writers, _)) = self.open.take() else {
            return Ok(());
        };
        let chunks = match self.encoding {
            Encoding::OneThread => writers
                .into_iter()
                .map(|w| w.close())
                .collect::<std::result::Result<Vec<_>, _>>()?,
            Encoding::ColumnsInParallel => {
                use rayon::prelude::*;
                writers
                    .into_par_iter()
                    .map(|w| w.close())
                    .collect::<std::result::Result<Vec<_>, _>>()?
            }
        };
        let mut group = self.file.next_row_group()?;
        for chunk in chunks {
            chunk.append_to_row_group(&mut group)?;
        }
        group.close()?;
        Ok(())
    }

    fn into_inner(mut self) -> Result<W> {
        self.flush()?;
        Ok(self.file.into_inner()?)
    }
}

/// Whether a file name is one of [`temp_path`]'s: `.<name>.<pid>.tmp`.
pub(crate) fn is_temp_name(name: &str) -> bool {
    let Some(inner) = name.strip_prefix('.').and_then(|n| n.strip_suffix(".tmp")) else {
        return false;
    };
    match inner.rsplit_once('.') {
        Some((stem, pid)) => {
            !stem.is_empty() && !pid.is_empty() && pid.bytes().all(|b| b.is_ascii_digit())
        }
        None => false,
    }
}

/// Remove the temporary files a killed writer left under `dir` (at most
/// `depth` levels down). Only call this while holding the directory's batch
/// lock: a live writer's temp file looks the same. Returns what was removed.
pub fn remove_orphaned_temps(dir: &Path, depth: usize) -> Vec<PathBuf> {
    let mut removed = Vec::new();
    let Ok(entries) = fs::read_dir(dir) else {
        return removed;
    };
    let mut entries: Vec<_> = entries.filter_map(|e| e.ok()).collect();
    entries.sort_by_key(|e| e.file_name());
    for e in entries {
        let path = e.path();
        let Ok(ft) = e.file_type() else { continue };
        if ft.is_dir() {
            if depth > 0 {
                removed.extend(remove_orphaned_temps(&path, depth - 1));
            }
        } else if ft.is_file()
            && is_temp_name(&e.file_name().to_string_lossy())
            && fs::remove_file(&path).is_ok()
        {
            removed.push(path);
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    /// The stream writer writes ArrowWriter's bytes, its columns encoded
    /// on one thread or in parallel: row groups cut
    /// inside and between batches (an empty batch among them), text with
    /// a dictionary, byte-stream-split floats with nulls, and a struct
    /// whose two leaves are two column writers.
    #[test]
    fn columns_encoded_in_parallel_are_arrow_writers_bytes() {
        use arrow::array::{ArrayRef, Float64Array, Int32Array, StringArray, StructArray};
        use arrow::datatypes::{DataType, Field, Fields, Schema};
        use std::sync::Arc;
        let inner = Fields::from(vec![
            Field::new("a", DataType::Int32, false),
            Field::new("b", DataType::Float64, true),
        ]);
        let schema = Arc::new(Schema::new(vec![
            Field::new("run", DataType::Utf8, false),
            Field::new("x_mm", DataType::Float64, true),
            Field::new("pair", DataType::Struct(inner.clone()), false),
        ]));
        let batch = |from: usize, n: usize| {
            let run =
                StringArray::from_iter_values((from..from + n).map(|i| format!("r{}", i / 450)));
            let x = Float64Array::from_iter(
                (from..from + n).map(|i| (i % 7 != 3).then(|| (i as f64 * 0.37).sin() * 1e3)),
            );
            let a = Int32Array::from_iter_values((from..from + n).map(|i| (i % 11) as i32));
            let b =
                Float64Array::from_iter((from..from + n).map(|i| (i % 5 != 0).then_some(i as f64)));
            let pair = StructArray::new(
                inner.clone(),
                vec![Arc::new(a) as ArrayRef, Arc::new(b) as ArrayRef],
                None,
            );
            RecordBatch::try_new(
                schema.clone(),
                vec![Arc::new(run), Arc::new(x), Arc::new(pair)],
            )
            .unwrap()
        };
        let sizes = [300, 1000, 0, 2500, 700, 1];
        let mut batches = Vec::new();
        let mut at = 0;
        for n in sizes {
            batches.push(batch(at, n));
            at += n;
        }
        let props = || {
            let mut p = super::writer_properties(&schema).into_builder();
            p = p.set_max_row_group_row_count(Some(700));
            p.build()
        };
        let mut serial =
            super::ArrowWriter::try_new(Vec::new(), schema.clone(), Some(props())).unwrap();
        let ours = |encoding| {
            let mut w = super::StreamWriter::try_new(Vec::new(), schema.clone(), props(), encoding)
                .unwrap();
            for b in &batches {
                w.write(b).unwrap();
            }
            w.into_inner().unwrap()
        };
        for b in &batches {
            serial.write(b).unwrap();
        }
        let serial = serial.into_inner().unwrap();
        let parallel = ours(super::Encoding::ColumnsInParallel);
        assert!(
            ours(super::Encoding::OneThread) == serial,
            "one thread differs"
        );
        let groups = parquet::file::reader::FileReader::metadata(
            &parquet::file::serialized_reader::SerializedFileReader::new(bytes::Bytes::from(
                parallel.clone(),
            ))
            .unwrap(),
        )
        .num_row_groups();
        assert_eq!(groups, at.div_ceil(700));
        assert!(serial == parallel, "columns in parallel differ");
    }

    /// A run directory created while another run of the same machine
    /// fails over and over — its cleanup removing its own directory and
    /// then the machine directory whenever that is empty: creating the run
    /// directory never fails because the machine directory vanished.
    #[test]
    fn a_run_directory_survives_a_concurrent_cleanup_of_its_machine_directory() {
        let d = tempfile::tempdir().unwrap();
        let machine = d.path().join("m");
        let done = std::sync::atomic::AtomicBool::new(false);
        std::thread::scope(|s| {
            s.spawn(|| {
                let failing = machine.join("failing");
                // Bounded, so a failing assertion below cannot hang the scope.
                for _ in 0..200_000 {
                    if done.load(std::sync::atomic::Ordering::Relaxed) {
                        break;
                    }
                    super::create_dir_all_shared(&failing).unwrap();
                    let _ = std::fs::remove_dir(&failing);
                    let _ = std::fs::remove_dir(&machine);
                }
            });
            let run = machine.join("run");
            for _ in 0..3_000 {
                super::create_dir_all_shared(&run).unwrap();
                std::fs::remove_dir(&run).unwrap();
            }
            done.store(true, std::sync::atomic::Ordering::Relaxed);
        });
    }

    /// A file where a directory should be is an error, not a retry for
    /// ever: the bounded retries end and the error names the path.
    #[test]
    fn a_file_in_the_way_of_a_directory_is_an_error() {
        let d = tempfile::tempdir().unwrap();
        let file = d.path().join("m");
        std::fs::write(&file, b"not a directory").unwrap();
        let e = super::create_dir_all_shared(&file).unwrap_err().to_string();
        assert!(e.contains("cannot create") && e.contains("m"), "{e}");
        let e = super::create_dir_all_shared(&file.join("run"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("cannot create"), "{e}");
    }

    use super::*;

    #[test]
    fn temp_names_are_recognised() {
        let t = temp_path(Path::new("/x/ingest.parquet"));
        assert!(is_temp_name(&t.file_name().unwrap().to_string_lossy()));
        assert!(!is_temp_name("ingest.parquet"));
        assert!(!is_temp_name(".sparkout-cache.json"));
        assert!(!is_temp_name(".notes.tmp"));
        assert!(!is_temp_name(".a.12x.tmp"));
    }
}

//! Opening a Parquet file with errors that tell the truth (docs/formats.md,
//! "Parquet"): not Parquet at all, a truncated file, a footer that does not
//! decode, a codec sparkout cannot decode, and a data page that does not
//! decode are different messages, each naming the file. The checks before
//! decoding read only the footer, so a huge AE log costs nothing extra.

use std::path::Path;

use arrow::record_batch::RecordBatch;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use parquet::basic::Compression;
use parquet::file::metadata::ParquetMetaData;

use super::input_file::InputFile;
use crate::error::InputError;
use parquet::file::reader::Length;

/// Codecs this build decodes (every codec Parquet writers use by default:
/// pandas/pyarrow/Spark/DuckDB write snappy, polars zstd).
pub const SUPPORTED_CODECS: &str = "uncompressed, snappy, gzip, lz4 (raw and hadoop), brotli, zstd";

const MAGIC: &[u8; 4] = b"PAR1";
const MAGIC_ENCRYPTED: &[u8; 4] = b"PARE";

/// Open a Parquet file for reading: the footer is checked, the codecs of
/// every column chunk are known, and every column chunk lies inside the file.
pub fn open_parquet(path: &Path) -> Result<ParquetRecordBatchReaderBuilder<InputFile>, InputError> {
    let file =
        InputFile::open(path).map_err(|e| InputError::new(path, format!("cannot open: {e}")))?;
    let len = file.len();
    check_frame(path, &file, len)?;
    let builder = ParquetRecordBatchReaderBuilder::try_new(file).map_err(|e| {
        InputError::new(
            path,
            format!(
                "corrupt Parquet footer: the file is framed as Parquet but its metadata does not decode ({e})"
            ),
        )
    })?;
    check_codecs(path, builder.metadata())?;
    check_chunks_inside(path, builder.metadata(), len)?;
    Ok(builder)
}

/// `PAR1 … <footer> <footer length: u32 LE> PAR1`.
fn check_frame(path: &Path, file: &InputFile, len: u64) -> Result<(), InputError> {
    let io = |e: std::io::Error| InputError::new(path, format!("cannot read: {e}"));
    let mut head = [0u8; 4];
    if len >= 4 {
        head.copy_from_slice(&file.read_at(0, 4).map_err(io)?[..4]);
    }
    if len < 4 || (&head != MAGIC && &head != MAGIC_ENCRYPTED) {
        return Err(InputError::new(
            path,
            format!(
                "not a Parquet file ({len} bytes, no PAR1 marker at the start); sparkout reads Parquet tables (docs/formats.md)"
            ),
        ));
    }
    let mut tail = [0u8; 8];
    let framed = len >= 12 && {
        tail.copy_from_slice(&file.read_at(len - 8, 8).map_err(io)?[..8]);
        &tail[4..] == MAGIC || &tail[4..] == MAGIC_ENCRYPTED
    };
    if !framed {
        return Err(InputError::new(
            path,
            format!(
                "truncated Parquet file: it starts like Parquet but its {len} bytes do not end with the footer (PAR1); the copy or the write was cut short"
            ),
        ));
    }
    if &tail[4..] == MAGIC_ENCRYPTED {
        return Err(InputError::new(
            path,
            "encrypted Parquet (PARE footer) cannot be read: write it without encryption",
        ));
    }
    let footer_len = u32::from_le_bytes([tail[0], tail[1], tail[2], tail[3]]) as u64;
    if footer_len + 12 > len {
        return Err(InputError::new(
            path,
            format!(
                "truncated Parquet file: the footer claims {footer_len} bytes of metadata but the file has only {len} bytes"
            ),
        ));
    }
    Ok(())
}

/// A codec the parquet crate of this build cannot decode (LZO, or one added
/// to the format after this build) is named as such: the file is fine.
fn check_codecs(path: &Path, meta: &ParquetMetaData) -> Result<(), InputError> {
    for rg in meta.row_groups() {
        for c in rg.columns() {
            let codec = c.compression();
            let known = matches!(
                codec,
                Compression::UNCOMPRESSED
                    | Compression::SNAPPY
                    | Compression::GZIP(_)
                    | Compression::LZ4
                    | Compression::LZ4_RAW
                    | Compression::BROTLI(_)
                    | Compression::ZSTD(_)
            );
            if !known {
                let name = format!("{codec:?}");
                let name = name.split('(').next().unwrap_or("?");
                return Err(InputError::new(
                    path,
                    format!(
                        "unsupported compression codec {name} (the file is intact, but this build decodes only {SUPPORTED_CODECS}); rewrite it with one of those, e.g. pyarrow.parquet.write_table(t, f, compression=\"zstd\")"
                    ),
                )
                .column(c.column_path().string()));
            }
        }
    }
    Ok(())
}

/// Every column chunk's bytes lie before the footer: a file cut short and
/// then given a footer back (or a footer from another file) is truncated.
fn check_chunks_inside(path: &Path, meta: &ParquetMetaData, len: u64) -> Result<(), InputError> {
    for (g, rg) in meta.row_groups().iter().enumerate() {
        for c in rg.columns() {
            let start = c.dictionary_page_offset().unwrap_or(c.data_page_offset());
            let size = c.compressed_size();
            let end = start.checked_add(size);
            if start < 4 || size < 0 || end.is_none_or(|e| e as u64 > len) {
                return Err(InputError::new(
                    path,
                    format!(
                        "truncated Parquet file: row group {g} claims bytes {start}..{} but the file has only {len} bytes",
                        start.saturating_add(size)
                    ),
                )
                .column(c.column_path().string()));
            }
        }
    }
    Ok(())
}

/// The error of a batch that does not decode once the footer, codecs and
/// chunk ranges have been checked: a corrupt page. `row` is the first row of
/// the batch that failed (0-based over the file), and names its row group.
pub fn corrupt_page(
    path: &Path,
    meta: &ParquetMetaData,
    row: usize,
    e: impl std::fmt::Display,
) -> InputError {
    let mut first = 0usize;
    let mut group = 0usize;
    for (g, rg) in meta.row_groups().iter().enumerate() {
        let n = rg.num_rows().max(0) as usize;
        if row < first + n {
            group = g;
            break;
        }
        first += n;
        group = g;
    }
    InputError::new(
        path,
        format!(
            "corrupt data page in row group {group} (rows from {first}): the file's footer is intact but a page does not decode ({e})"
        ),
    )
    .row(row)
}

/// The next batch of a Parquet reader, with a panic inside the decoder
/// turned into an error. The parquet crate (60.1) panics on some corrupt
/// pages — fuzzing found "attempt to divide by zero" in its plain
/// byte-array dictionary decoder (fuzz/README.md) — and a corrupt user file
/// must reject its run, not abort the batch. The reader is not used again
/// after a panic (the caller stops at the first error).
pub fn next_batch<I>(reader: &mut I) -> Option<Result<RecordBatch, String>>
where
    I: Iterator<Item = Result<RecordBatch, arrow::error::ArrowError>>,
{
    quiet_decoder_panics();
    DECODING.with(|d| d.set(true));
    let next = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| reader.next()));
    DECODING.with(|d| d.set(false));
    match next {
        Ok(next) => next.map(|r| r.map_err(|e| e.to_string())),
        Err(payload) => {
            let msg = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            Some(Err(format!("the Parquet decoder failed: {msg}")))
        }
    }
}

thread_local! {
    /// Set while this thread is inside the parquet decoder (`next_batch`).
    static DECODING: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// A panic inside the decoder is reported as the file's error, so its
/// "thread panicked at …" and backtrace would only alarm the reader: a
/// process-wide hook (installed once, chaining to the previous one) stays
/// silent for those panics and passes every other panic on unchanged —
/// under cargo-fuzz that is libFuzzer's aborting hook, so any panic outside
/// the decoder is still a crash.
fn quiet_decoder_panics() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !DECODING.with(|d| d.get()) {
                previous(info);
            }
        }));
    });
}

/// The batches of a Parquet reader, each decoder failure (an error or a
/// panic, [`next_batch`]) a [`corrupt_page`] naming the row where it
/// happened; the reader stops at the first. `first_row`: the file row of
/// the reader's first row (a reader of selected row groups starts at its
/// first group).
pub struct CheckedBatches<'a, I> {
    path: &'a Path,
    meta: &'a ParquetMetaData,
    reader: I,
    row: usize,
    failed: bool,
}

pub fn checked_batches<'a, I>(
    path: &'a Path,
    meta: &'a ParquetMetaData,
    first_row: usize,
    reader: I,
) -> CheckedBatches<'a, I>
where
    I: Iterator<Item = Result<RecordBatch, arrow::error::ArrowError>>,
{
    CheckedBatches {
        path,
        meta,
        reader,
        row: first_row,
        failed: false,
    }
}

impl<I> Iterator for CheckedBatches<'_, I>
where
    I: Iterator<Item = Result<RecordBatch, arrow::error::ArrowError>>,
{
    type Item = Result<RecordBatch, InputError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        match next_batch(&mut self.reader)? {
            Ok(b) => {
                self.row += b.num_rows();
                Some(Ok(b))
            }
            Err(e) => {
                self.failed = true;
                Some(Err(corrupt_page(self.path, self.meta, self.row, e)))
            }
        }
    }
}

/// Decode every row group of an opened file into one batch; a batch that
/// does not decode is a [`corrupt_page`].
pub fn read_all(
    path: &Path,
    builder: ParquetRecordBatchReaderBuilder<InputFile>,
) -> Result<RecordBatch, InputError> {
    let schema = builder.schema().clone();
    let meta = builder.metadata().clone();
    let reader = builder
        .build()
        .map_err(|e| corrupt_page(path, &meta, 0, e))?;
    let batches = checked_batches(path, &meta, 0, reader).collect::<Result<Vec<_>, _>>()?;
    arrow::compute::concat_batches(&schema, &batches)
        .map_err(|e| InputError::new(path, format!("cannot assemble table: {e}")))
}

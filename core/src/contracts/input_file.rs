//! An input file on disk, or an object in a bucket read by ranged GETs
//!. Staging a remote fleet leaves each large Parquet input
//! in its bucket with a `<name>.remote.json` stub beside where the file would
//! be; every reader opens inputs through [`InputFile::open`], so a remote AE
//! log streams row group by row group with the same bounded memory as a
//! local one, and nothing else in the engine knows the difference.

use std::fs::File;
use std::io::Read;
use std::path::Path;

use bytes::Bytes;
use parquet::file::reader::{ChunkReader, Length};

use crate::storage::{RemoteObject, RemoteStub};

/// The first GET of a sequential read: a page header and, for a small page,
/// its data (served again from [`RemoteObject`]'s last range). Later GETs of
/// the same read double, up to [`REMOTE_READ_MAX`].
const REMOTE_READ_FIRST: u64 = 64 << 10;
const REMOTE_READ_MAX: u64 = 8 << 20;

pub enum InputFile {
    Local(File),
    /// A byte range of a local file mapped into memory
    /// ([`InputFile::window`]): reads inside it are slices of the mapping,
    /// not copies out of the page cache; reads outside go to the file.
    Mapped {
        file: File,
        start: u64,
        bytes: Bytes,
    },
    Remote(RemoteObject),
}

impl InputFile {
    /// The file at `path`, or the remote object its stub names.
    pub fn open(path: &Path) -> std::io::Result<InputFile> {
        match File::open(path) {
            Ok(f) => Ok(InputFile::Local(f)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                let stub_path = RemoteStub::path_for(path);
                if !stub_path.is_file() {
                    return Err(e);
                }
                let stub = RemoteStub::read(&stub_path)?;
                RemoteObject::open(&stub)
                    .map(InputFile::Remote)
                    .map_err(|e| std::io::Error::other(format!("{e:#}")))
            }
            Err(e) => Err(e),
        }
    }

    /// Another handle on the same input whose bytes `start..start + len`
    /// are mapped into memory when it is a local file. The AE stream's
    /// decoders read each page of a multi-GB log once; copying it out of the
    /// page cache (`read`) was a tenth of their time. One row
    /// group is mapped at a time, and unmapped when the handle is dropped,
    /// so the resident set stays bounded whatever the file size (a mapping
    /// of the whole file would count every page read as resident). Falls
    /// back to plain reads when the range cannot be mapped.
    ///
    /// The mapping assumes nobody truncates the file while it is read (a
    /// recorded log is written whole, then read); a file shortened under the
    /// reader would stop the process with SIGBUS instead of an error.
    pub fn window(&self, start: u64, len: usize) -> std::io::Result<InputFile> {
        Ok(match self {
            InputFile::Local(f) | InputFile::Mapped { file: f, .. } => {
                let file = f.try_clone()?;
                let in_file = start.saturating_add(len as u64) <= file.metadata()?.len();
                // SAFETY: a read-only mapping of a file we only read; see the
                // caveat above on files truncated while mapped.
                let mapped = (len > 0 && in_file)
                    .then(|| unsafe {
                        memmap2::MmapOptions::new()
                            .offset(start)
                            .len(len)
                            .map(&file)
                    })
                    .and_then(Result::ok);
                match mapped {
                    Some(m) => {
                        // Pages are read front to back, each once.
                        #[cfg(unix)]
                        let _ = m.advise(memmap2::Advice::Sequential);
                        InputFile::Mapped {
                            file,
                            start,
                            bytes: Bytes::from_owner(m),
                        }
                    }
                    None => InputFile::Local(file),
                }
            }
            InputFile::Remote(o) => InputFile::Remote(o.clone()),
        })
    }

    /// The mapped slice for `start..start + len`, if it lies in the window.
    fn mapped_slice(&self, start: u64, len: usize) -> Option<Bytes> {
        match self {
            InputFile::Mapped {
                start: w, bytes, ..
            } => {
                let lo = usize::try_from(start.checked_sub(*w)?).ok()?;
                (lo.checked_add(len)? <= bytes.len()).then(|| bytes.slice(lo..lo + len))
            }
            _ => None,
        }
    }

    /// Whether `path` is there to read: a file, or a stub standing for one.
    pub fn exists(path: &Path) -> bool {
        path.is_file() || RemoteStub::path_for(path).is_file()
    }

    /// `len` bytes from `start` (fewer only at the end of the file).
    pub fn read_at(&self, start: u64, len: usize) -> std::io::Result<Bytes> {
        if let Some(b) = self.mapped_slice(start, len) {
            return Ok(b);
        }
        match self {
            InputFile::Local(f) | InputFile::Mapped { file: f, .. } => {
                use std::io::{Seek, SeekFrom};
                let mut f = f.try_clone()?;
                f.seek(SeekFrom::Start(start))?;
                let mut buf = Vec::with_capacity(len);
                f.take(len as u64).read_to_end(&mut buf)?;
                Ok(buf.into())
            }
            InputFile::Remote(o) => o.get_range(start..start + len as u64),
        }
    }
}

impl Length for InputFile {
    fn len(&self) -> u64 {
        match self {
            InputFile::Local(f) | InputFile::Mapped { file: f, .. } => f.len(),
            InputFile::Remote(o) => o.len(),
        }
    }
}

/// Sequential reads of a remote object, a chunk per GET.
struct RemoteRead {
    object: RemoteObject,
    pos: u64,
    buf: Bytes,
    next_chunk: u64,
}

impl Read for RemoteRead {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        if self.buf.is_empty() {
            let want = (out.len() as u64).max(self.next_chunk);
            self.next_chunk = (self.next_chunk * 2).min(REMOTE_READ_MAX);
            self.buf = self.object.get_range(self.pos..self.pos + want)?;
            if self.buf.is_empty() {
                return Ok(0);
            }
        }
        let n = out.len().min(self.buf.len());
        out[..n].copy_from_slice(&self.buf[..n]);
        self.buf = self.buf.slice(n..);
        self.pos += n as u64;
        Ok(n)
    }
}

impl ChunkReader for InputFile {
    type T = Box<dyn Read + Send>;

    fn get_read(&self, start: u64) -> parquet::errors::Result<Self::T> {
        match self {
            InputFile::Local(f) | InputFile::Mapped { file: f, .. } => {
                Ok(Box::new(f.get_read(start)?))
            }
            InputFile::Remote(o) => Ok(Box::new(RemoteRead {
                object: o.clone(),
                pos: start,
                buf: Bytes::new(),
                next_chunk: REMOTE_READ_FIRST,
            })),
        }
    }

    fn get_bytes(&self, start: u64, length: usize) -> parquet::errors::Result<Bytes> {
        if let Some(b) = self.mapped_slice(start, length) {
            return Ok(b);
        }
        match self {
            InputFile::Local(f) | InputFile::Mapped { file: f, .. } => f.get_bytes(start, length),
            InputFile::Remote(o) => {
                let b = o.get_range(start..start + length as u64)?;
                if b.len() != length {
                    return Err(parquet::errors::ParquetError::EOF(format!(
                        "{}: expected {length} bytes at {start}, the object has {}",
                        o.url(),
                        o.len()
                    )));
                }
                Ok(b)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use arrow::array::{Float32Array, RecordBatch};
    use arrow::datatypes::{DataType, Field, Schema};
    use object_store::memory::InMemory;
    use object_store::{ObjectStore, ObjectStoreExt};
    use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
    use parquet::arrow::ArrowWriter;
    use parquet::file::properties::WriterProperties;
    use std::sync::Arc;

    /// One row group of a remote file is read by fetching about that row
    /// group's bytes — not the file: the ranged reads that keep a remote AE
    /// log's memory and traffic bounded.
    #[test]
    fn a_remote_row_group_is_read_by_ranged_gets() {
        let schema = Arc::new(Schema::new(vec![Field::new(
            "ae_v",
            DataType::Float32,
            false,
        )]));
        let props = WriterProperties::builder()
            .set_max_row_group_row_count(Some(50_000))
            .set_compression(parquet::basic::Compression::UNCOMPRESSED)
            .build();
        let mut bytes = Vec::new();
        let mut w = ArrowWriter::try_new(&mut bytes, schema.clone(), Some(props)).unwrap();
        let values: Vec<f32> = (0..400_000).map(|i| (i as f32 * 0.37).sin()).collect();
        let batch =
            RecordBatch::try_new(schema, vec![Arc::new(Float32Array::from(values.clone()))])
                .unwrap();
        w.write(&batch).unwrap();
        w.close().unwrap();
        let size = bytes.len() as u64;

        let store: Arc<dyn ObjectStore> = Arc::new(InMemory::new());
        let key = object_store::path::Path::from("fleet/r0/ae.parquet");
        crate::storage::block_on(store.put(&key, bytes.into())).unwrap();
        let object = RemoteObject::from_store(store, key, size, "memory:///fleet/r0/ae.parquet");
        let counter = object.clone();

        let builder = ParquetRecordBatchReaderBuilder::try_new(InputFile::Remote(object)).unwrap();
        assert_eq!(builder.metadata().num_row_groups(), 8);
        let reader = builder.with_row_groups(vec![5]).build().unwrap();
        let got: Vec<f32> = reader
            .flat_map(|b| {
                let b = b.unwrap();
                let a = b
                    .column(0)
                    .as_any()
                    .downcast_ref::<Float32Array>()
                    .unwrap()
                    .clone();
                a.values().to_vec()
            })
            .collect();
        assert_eq!(got, values[250_000..300_000]);
        let fetched = counter.bytes_fetched();
        // 1 of 8 row groups (200 kB of 1.6 MB) plus the footer.
        assert!(
            fetched < size / 4,
            "fetched {fetched} of {size} bytes for one row group"
        );
        assert!(fetched >= 200_000, "fetched {fetched}");
    }

    #[test]
    fn a_missing_file_without_a_stub_is_not_found() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("ae.parquet");
        assert!(!InputFile::exists(&p));
        let e = InputFile::open(&p).err().unwrap();
        assert_eq!(e.kind(), std::io::ErrorKind::NotFound);
    }

    /// A mapped window serves the bytes a plain read would, inside it (as
    /// slices of the mapping), outside it and straddling its edge (from the
    /// file), at an offset that is not page-aligned.
    #[test]
    fn a_mapped_window_reads_what_the_file_holds() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("log.bin");
        let data: Vec<u8> = (0..100_000u32).map(|i| (i * 7 % 251) as u8).collect();
        std::fs::write(&p, &data).unwrap();
        let file = InputFile::open(&p).unwrap();
        let w = file.window(5_000, 50_000).unwrap();
        assert!(matches!(w, InputFile::Mapped { .. }), "a local file maps");
        assert_eq!(w.len(), data.len() as u64);
        for (start, len) in [
            (5_000u64, 10usize),
            (20_001, 4_097),
            (54_990, 10),
            (0, 100),
            (54_990, 100),
            (99_000, 1_000),
        ] {
            let s = start as usize;
            assert_eq!(
                &w.get_bytes(start, len).unwrap()[..],
                &data[s..s + len],
                "{start}+{len}"
            );
            assert_eq!(&w.read_at(start, len).unwrap()[..], &data[s..s + len]);
        }
        assert!(w.mapped_slice(4_999, 2).is_none());
        assert!(w.mapped_slice(54_999, 2).is_none());
        assert!(w.mapped_slice(54_999, 1).is_some());
        // Beyond the file: not mapped, read as before.
        assert!(matches!(
            file.window(90_000, 20_000).unwrap(),
            InputFile::Local(_)
        ));
    }
}

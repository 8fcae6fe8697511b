//! An input file on disk, or an object in a bucket read by ranged GETs
//! (issue 18 item 2). Staging a remote fleet leaves each large Parquet input
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
    /// A local file mapped into memory ([`InputFile::open_mapped`]): page
    /// reads are slices of the mapping, not copies out of the page cache.
    Mapped(Bytes),
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

    /// Like [`InputFile::open`], but a local file is mapped into memory
    /// rather than read: the AE stream's decoder threads read each page of a
    /// multi-GB log once, and copying it out of the page cache (`read`) was
    /// a tenth of their time (issue 19). Falls back to reading when the file
    /// cannot be mapped (an empty file, some special file systems).
    ///
    /// The mapping assumes nobody truncates the file while it is read (a
    /// recorded log is written whole, then read); a file shortened under the
    /// reader would stop the process with SIGBUS instead of an error.
    pub fn open_mapped(path: &Path) -> std::io::Result<InputFile> {
        match Self::open(path)? {
            InputFile::Local(f) => {
                // SAFETY: read-only mapping of a file we only read; see the
                // caveat above on files truncated while mapped.
                match unsafe { memmap2::Mmap::map(&f) } {
                    Ok(m) => {
                        // Pages are read front to back, each once.
                        #[cfg(unix)]
                        let _ = m.advise(memmap2::Advice::Sequential);
                        Ok(InputFile::Mapped(Bytes::from_owner(m)))
                    }
                    Err(_) => Ok(InputFile::Local(f)),
                }
            }
            other => Ok(other),
        }
    }

    /// Another handle on the same input (a mapping or remote object is
    /// shared, a file handle duplicated).
    pub fn reopen(&self) -> std::io::Result<InputFile> {
        Ok(match self {
            InputFile::Local(f) => InputFile::Local(f.try_clone()?),
            InputFile::Mapped(b) => InputFile::Mapped(b.clone()),
            InputFile::Remote(o) => InputFile::Remote(o.clone()),
        })
    }

    /// Whether `path` is there to read: a file, or a stub standing for one.
    pub fn exists(path: &Path) -> bool {
        path.is_file() || RemoteStub::path_for(path).is_file()
    }

    /// `len` bytes from `start` (fewer only at the end of the file).
    pub fn read_at(&self, start: u64, len: usize) -> std::io::Result<Bytes> {
        match self {
            InputFile::Local(f) => {
                use std::io::{Seek, SeekFrom};
                let mut f = f.try_clone()?;
                f.seek(SeekFrom::Start(start))?;
                let mut buf = Vec::with_capacity(len);
                f.take(len as u64).read_to_end(&mut buf)?;
                Ok(buf.into())
            }
            InputFile::Mapped(b) => {
                let lo = (start as usize).min(b.len());
                Ok(b.slice(lo..(lo + len).min(b.len())))
            }
            InputFile::Remote(o) => o.get_range(start..start + len as u64),
        }
    }
}

impl Length for InputFile {
    fn len(&self) -> u64 {
        match self {
            InputFile::Local(f) => f.len(),
            InputFile::Mapped(b) => b.len() as u64,
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
            InputFile::Local(f) => Ok(Box::new(f.get_read(start)?)),
            InputFile::Mapped(b) => Ok(Box::new(b.get_read(start)?)),
            InputFile::Remote(o) => Ok(Box::new(RemoteRead {
                object: o.clone(),
                pos: start,
                buf: Bytes::new(),
                next_chunk: REMOTE_READ_FIRST,
            })),
        }
    }

    fn get_bytes(&self, start: u64, length: usize) -> parquet::errors::Result<Bytes> {
        match self {
            InputFile::Local(f) => f.get_bytes(start, length),
            InputFile::Mapped(b) => b.get_bytes(start, length),
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
}

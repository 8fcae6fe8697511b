//! One object read by ranged GETs, and the stub file that stands for it in a
//! staged run directory.

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use bytes::Bytes;
use object_store::path::Path as ObjectPath;
use object_store::{ObjectStore, ObjectStoreExt};
use serde::{Deserialize, Serialize};

use super::{block_on, RemotePrefix};

/// `ae.parquet` left remote is staged as `ae.parquet.remote.json`.
pub const REMOTE_STUB_SUFFIX: &str = ".remote.json";

/// What a stub file holds: where the object is, and which version of it was
/// listed (size and ETag identify the content for the cache key, so an
/// unchanged remote input keeps its stages cached without a download).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RemoteStub {
    /// The prefix URL the batch was given (`s3://bucket/fleet`).
    pub base_url: String,
    /// The object's path below it (`robot-7/r0001/ae.parquet`).
    pub rel: String,
    pub size: u64,
    pub e_tag: Option<String>,
}

impl RemoteStub {
    /// The stub that stands for `path`, if there is one.
    pub fn path_for(path: &Path) -> PathBuf {
        let mut s = path.as_os_str().to_owned();
        s.push(REMOTE_STUB_SUFFIX);
        PathBuf::from(s)
    }

    pub fn read(stub_path: &Path) -> std::io::Result<RemoteStub> {
        let text = std::fs::read(stub_path)?;
        serde_json::from_slice(&text).map_err(|e| {
            std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("not a sparkout remote stub ({e})"),
            )
        })
    }
}

/// A remote object opened for ranged reads. Cheap to clone (the store is
/// shared); counts the bytes it fetched so tests and logs can tell a ranged
/// read from a download.
#[derive(Clone)]
pub struct RemoteObject {
    store: Arc<dyn ObjectStore>,
    key: ObjectPath,
    size: u64,
    url: String,
    fetched: Arc<AtomicU64>,
    /// The last range fetched. A page is read as a small sequential read of
    /// its header then one `get_bytes` of its data (parquet's
    /// SerializedPageReader); the header read fetches ahead, so a small
    /// page's data comes from here without a second GET.
    last: Arc<Mutex<Option<(u64, Bytes)>>>,
}

impl std::fmt::Debug for RemoteObject {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({} bytes)", self.url, self.size)
    }
}

impl RemoteObject {
    /// Connect to the object a stub names. The store is built once per base
    /// URL and process (a batch opens hundreds of stubs).
    pub fn open(stub: &RemoteStub) -> crate::Result<RemoteObject> {
        let prefix = connected(&stub.base_url)?;
        Ok(RemoteObject {
            key: prefix.key(&stub.rel),
            store: prefix.store.clone(),
            size: stub.size,
            url: format!("{}/{}", stub.base_url, stub.rel),
            fetched: Arc::new(AtomicU64::new(0)),
            last: Arc::default(),
        })
    }

    /// An object of a store already at hand (tests; in-memory stores).
    pub fn from_store(store: Arc<dyn ObjectStore>, key: ObjectPath, size: u64, url: &str) -> Self {
        RemoteObject {
            store,
            key,
            size,
            url: url.to_string(),
            fetched: Arc::new(AtomicU64::new(0)),
            last: Arc::default(),
        }
    }

    pub fn len(&self) -> u64 {
        self.size
    }

    pub fn is_empty(&self) -> bool {
        self.size == 0
    }

    pub fn url(&self) -> &str {
        &self.url
    }

    /// Bytes fetched so far through this handle and its clones.
    pub fn bytes_fetched(&self) -> u64 {
        self.fetched.load(Ordering::Relaxed)
    }

    /// One ranged GET (clamped to the object's end).
    pub fn get_range(&self, range: Range<u64>) -> std::io::Result<Bytes> {
        let end = range.end.min(self.size);
        if range.start >= end {
            return Ok(Bytes::new());
        }
        let mut last = self.last.lock().unwrap_or_else(|p| p.into_inner());
        if let Some((at, b)) = last.as_ref() {
            if range.start >= *at && end <= at + b.len() as u64 {
                return Ok(b.slice((range.start - at) as usize..(end - at) as usize));
            }
        }
        let bytes = block_on(self.store.get_range(&self.key, range.start..end))
            .map_err(|e| std::io::Error::other(format!("{}: ranged read failed: {e}", self.url)))?;
        self.fetched
            .fetch_add(bytes.len() as u64, Ordering::Relaxed);
        *last = Some((range.start, bytes.clone()));
        Ok(bytes)
    }
}

/// Stores by base URL, built once per process.
fn connected(base_url: &str) -> crate::Result<RemotePrefix> {
    use std::collections::HashMap;
    use std::sync::Mutex;
    static STORES: Mutex<Option<HashMap<String, RemotePrefix>>> = Mutex::new(None);
    let mut g = STORES.lock().unwrap_or_else(|p| p.into_inner());
    let map = g.get_or_insert_with(HashMap::new);
    if let Some(p) = map.get(base_url) {
        return Ok(p.clone());
    }
    let p = RemotePrefix::connect(base_url)?;
    map.insert(base_url.to_string(), p.clone());
    Ok(p)
}

//! Content-hash cache (DESIGN.md "Caching"): a stage's key is blake3 over its
//! name and version, its config section, the run's run.toml and machine
//! config, the hashes of the raw tables it reads and the keys of the stages
//! that produced the artifacts it reads.

use std::collections::BTreeMap;
use std::fs::File;
use std::path::Path;

use crate::error::Result;

/// blake3 of a file's bytes, hex.
pub fn hash_file(path: &Path) -> Result<String> {
    let mut h = blake3::Hasher::new();
    let f = File::open(path)?;
    h.update_reader(f)?;
    Ok(h.finalize().to_hex().to_string())
}

/// The content key of an input table: blake3 of its bytes, or — for a
/// Parquet file left in object storage (`<name>.remote.json`) — of the
/// object's path, size and ETag, so an unchanged remote input keeps its
/// stages cached without being downloaded.
pub fn hash_input(path: &Path) -> Result<String> {
    if path.is_file() {
        return hash_file(path);
    }
    let stub = crate::storage::RemoteStub::read(&crate::storage::RemoteStub::path_for(path))?;
    let id = format!(
        "remote\n{}\n{}\n{}",
        stub.rel,
        stub.size,
        stub.e_tag.as_deref().unwrap_or("")
    );
    Ok(hash_bytes(id.as_bytes()))
}

pub fn hash_bytes(bytes: &[u8]) -> String {
    blake3::hash(bytes).to_hex().to_string()
}

/// Builds a cache key from labelled parts (labels keep parts from running
/// into each other).
#[derive(Default)]
pub struct KeyBuilder {
    h: blake3::Hasher,
}

impl KeyBuilder {
    pub fn new(kind: &str) -> Self {
        let mut k = KeyBuilder::default();
        k.part("kind", kind);
        k
    }
    pub fn part(&mut self, label: &str, value: &str) -> &mut Self {
        for s in [label, value] {
            self.h.update(&(s.len() as u64).to_le_bytes());
            self.h.update(s.as_bytes());
        }
        self
    }
    pub fn finish(&self) -> String {
        self.h.finalize().to_hex().to_string()
    }
}

/// What one stage left on disk for one run (the per-run cache file records
/// these; manifest.json repeats them).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StageRecord {
    pub stage: String,
    pub version: u32,
    pub key: String,
    /// Output file name → blake3 of its bytes.
    pub files: BTreeMap<String, String>,
    #[serde(default)]
    pub cached: bool,
}

/// `<out>/<machine>/<run>/.sparkout-cache.json`, written last in a run's
/// directory, so a killed batch never trusts a half-written run.
pub const RUN_CACHE_FILE: &str = ".sparkout-cache.json";

pub fn read_run_cache(dir: &Path) -> BTreeMap<String, StageRecord> {
    let p = dir.join(RUN_CACHE_FILE);
    std::fs::read(&p)
        .ok()
        .and_then(|b| serde_json::from_slice::<Vec<StageRecord>>(&b).ok())
        .map(|v| v.into_iter().map(|r| (r.stage.clone(), r)).collect())
        .unwrap_or_default()
}

/// A previous record is reusable when the key matches and every file it
/// lists is still there with the same content.
pub fn record_valid(dir: &Path, rec: &StageRecord, key: &str) -> bool {
    rec.key == key
        && rec.files.iter().all(|(name, hash)| {
            hash_file(&dir.join(name))
                .map(|h| &h == hash)
                .unwrap_or(false)
        })
}

//! Content-hash cache (docs/design.md §2.2): a stage's key is blake3 over its
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

pub use crate::outcome::StageRecord;

/// `<out>/<machine>/<run>/.sparkout-cache.json`, written last in a run's
/// directory, so a killed batch never trusts a half-written run.
pub use crate::files::RUN_CACHE_FILE;

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

/// Remove what sparkout wrote for one run under `run_dir`: the files its
/// cache file lists (each a plain file name in that directory), then the
/// cache file, then the directory and its machine directory if that left
/// them empty. Nothing else is touched: a file sparkout did not list — a
/// user's, or anything a hostile name could point at — stays. Returns the
/// files removed.
pub fn remove_run_outputs(run_dir: &Path) -> usize {
    let cache = run_dir.join(RUN_CACHE_FILE);
    let Ok(bytes) = std::fs::read(&cache) else {
        return 0;
    };
    let Ok(records) = serde_json::from_slice::<Vec<StageRecord>>(&bytes) else {
        tracing::warn!(
            "{} is not a sparkout cache file; nothing under {} was removed",
            cache.display(),
            run_dir.display()
        );
        return 0;
    };
    let mut removed = 0;
    for name in records.iter().flat_map(|r| r.files.keys()) {
        if crate::contracts::names::is_plain_file_name(name)
            && name != RUN_CACHE_FILE
            && std::fs::remove_file(run_dir.join(name)).is_ok()
        {
            removed += 1;
        }
    }
    if std::fs::remove_file(&cache).is_ok() {
        removed += 1;
    }
    // remove_dir only removes an empty directory.
    if std::fs::remove_dir(run_dir).is_ok() {
        if let Some(machine_dir) = run_dir.parent() {
            let _ = std::fs::remove_dir(machine_dir);
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn removes_only_listed_files() {
        let d = tempfile::tempdir().unwrap();
        let machine = d.path().join("m1");
        let run = machine.join("r1");
        std::fs::create_dir_all(&run).unwrap();
        std::fs::write(run.join("a.parquet"), b"x").unwrap();
        std::fs::write(run.join("users-notes.txt"), b"mine").unwrap();
        std::fs::write(d.path().join("outside.txt"), b"keep").unwrap();
        let rec = StageRecord {
            stage: "s".into(),
            version: 1,
            key: "k".into(),
            files: [
                ("a.parquet".to_string(), String::new()),
                ("../../outside.txt".to_string(), String::new()),
                ("/etc/hostname".to_string(), String::new()),
            ]
            .into(),
            cached: false,
        };
        std::fs::write(
            run.join(RUN_CACHE_FILE),
            serde_json::to_vec(&vec![rec]).unwrap(),
        )
        .unwrap();
        assert_eq!(remove_run_outputs(&run), 2);
        assert!(!run.join("a.parquet").exists());
        assert!(run.join("users-notes.txt").exists());
        assert!(d.path().join("outside.txt").exists());
        // Only the user's file is left: the directory stays.
        assert!(run.is_dir());
        std::fs::remove_file(run.join("users-notes.txt")).unwrap();
        std::fs::write(run.join(RUN_CACHE_FILE), b"[]").unwrap();
        remove_run_outputs(&run);
        assert!(!run.exists() && !machine.exists());
    }
}

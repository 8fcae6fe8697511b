//! Mirroring a remote prefix into a local directory (inputs) and publishing
//! a local directory to a remote prefix (outputs).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use futures::TryStreamExt;
use object_store::{ObjectMeta, ObjectStoreExt, PutPayload};
use serde::{Deserialize, Serialize};

use super::remote::{RemoteStub, REMOTE_STUB_SUFFIX};
use super::{block_on, RemotePrefix};
use crate::contracts::write::{is_temp_name, write_atomic};

/// Staging state: which version of each object the local copy is.
const STAGED_FILE: &str = ".sparkout-staged.json";
/// Publishing state: the blake3 of each file as last uploaded.
const PUBLISHED_FILE: &str = ".sparkout-published.json";
/// Uploads go here first, then are renamed into place.
const TMP_PREFIX: &str = ".sparkout-tmp";

#[derive(Debug, Default, Serialize, Deserialize, PartialEq, Clone)]
struct ObjectVersion {
    size: u64,
    e_tag: Option<String>,
    streamed: bool,
}

/// What [`stage_down`] did.
#[derive(Debug, Default, Clone)]
pub struct StageReport {
    pub downloaded: usize,
    pub downloaded_bytes: u64,
    pub unchanged: usize,
    /// Parquet files left remote (read by ranged GETs).
    pub streamed: usize,
    pub streamed_bytes: u64,
    pub removed: usize,
}

/// What [`publish`] did.
#[derive(Debug, Default, Clone)]
pub struct PublishReport {
    pub uploaded: usize,
    pub uploaded_bytes: u64,
    pub unchanged: usize,
}

fn list(remote: &RemotePrefix) -> Result<Vec<ObjectMeta>> {
    let mut all: Vec<ObjectMeta> = block_on(remote.store.list(Some(&remote.prefix)).try_collect())
        .with_context(|| {
            format!(
                "cannot list `{}` (check the bucket name, credentials and endpoint: AWS_*/GOOGLE_*/AZURE_* in the environment)",
                remote.url
            )
        })?;
    all.sort_by(|a, b| a.location.cmp(&b.location));
    Ok(all)
}

/// An object key below a prefix as a local path below `root`; a key with an
/// empty, `.` or `..` segment (or a separator of this system inside a
/// segment) would leave `root` and is refused.
fn local_path(root: &Path, rel: &str) -> Result<PathBuf> {
    let mut p = root.to_path_buf();
    for part in rel.split('/') {
        if !crate::contracts::names::is_plain_file_name(part) {
            anyhow::bail!(
                "object key `{rel}` has a segment `{part}` that is not a plain name; it would be written outside {} — not transferred",
                root.display()
            );
        }
        p.push(part);
    }
    Ok(p)
}

/// Mirror `remote` into `local`. Parquet objects of at least
/// `stream_min_bytes` (None: never) are not downloaded: a
/// `<name>.remote.json` stub stands in for each. Objects whose size and ETag
/// are those of the last staging are not fetched again; files staged before
/// whose object is gone are removed.
pub fn stage_down(
    remote: &RemotePrefix,
    local: &Path,
    stream_min_bytes: Option<u64>,
) -> Result<StageReport> {
    std::fs::create_dir_all(local)
        .with_context(|| format!("cannot create the staging directory {}", local.display()))?;
    let state_path = local.join(STAGED_FILE);
    let before: BTreeMap<String, ObjectVersion> = std::fs::read(&state_path)
        .ok()
        .and_then(|b| serde_json::from_slice(&b).ok())
        .unwrap_or_default();
    let objects = list(remote)?;
    if objects.is_empty() {
        anyhow::bail!(
            "`{}` holds no objects (upload the runs first, e.g. `sparkout sync runs/ {}`)",
            remote.url,
            remote.url
        );
    }
    let mut after = BTreeMap::new();
    let mut report = StageReport::default();
    for meta in objects {
        let Some(rel) = remote.relative(&meta.location) else {
            continue;
        };
        if rel
            .split('/')
            .any(|p| p.starts_with(TMP_PREFIX) || p == PUBLISHED_FILE)
        {
            continue;
        }
        let streamed =
            rel.ends_with(".parquet") && stream_min_bytes.is_some_and(|min| meta.size >= min);
        let version = ObjectVersion {
            size: meta.size,
            e_tag: meta.e_tag.clone(),
            streamed,
        };
        let path = local_path(local, &rel)?;
        let stub_path = RemoteStub::path_for(&path);
        let target = if streamed { &stub_path } else { &path };
        if before.get(&rel) == Some(&version) && target.is_file() {
            report.unchanged += 1;
            after.insert(rel, version);
            continue;
        }
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent)
                .with_context(|| format!("cannot create {}", parent.display()))?;
        }
        if streamed {
            let stub = RemoteStub {
                base_url: remote.url.clone(),
                rel: rel.clone(),
                size: meta.size,
                e_tag: meta.e_tag.clone(),
            };
            write_atomic(&stub_path, &serde_json::to_vec_pretty(&stub)?)?;
            let _ = std::fs::remove_file(&path);
            report.streamed += 1;
            report.streamed_bytes += meta.size;
        } else {
            let bytes = block_on(async { remote.store.get(&meta.location).await?.bytes().await })
                .with_context(|| format!("cannot download `{}/{rel}`", remote.url))?;
            write_atomic(&path, &bytes)?;
            let _ = std::fs::remove_file(&stub_path);
            report.downloaded += 1;
            report.downloaded_bytes += bytes.len() as u64;
        }
        after.insert(rel, version);
    }
    for (rel, v) in &before {
        if !after.contains_key(rel) {
            let Ok(path) = local_path(local, rel) else {
                continue;
            };
            let gone = if v.streamed {
                RemoteStub::path_for(&path)
            } else {
                path
            };
            if std::fs::remove_file(&gone).is_ok() {
                report.removed += 1;
            }
        }
    }
    write_atomic(&state_path, &serde_json::to_vec_pretty(&after)?)?;
    Ok(report)
}

/// Every file under `dir`, `/`-separated relative paths, sorted; lock files,
/// temp files and sparkout's own state files left out.
fn local_files(dir: &Path) -> Result<Vec<String>> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<String>) -> Result<()> {
        for e in std::fs::read_dir(dir).with_context(|| format!("cannot read {}", dir.display()))? {
            let e = e?;
            let name = e.file_name().to_string_lossy().into_owned();
            let ft = e.file_type()?;
            if ft.is_dir() {
                walk(root, &e.path(), out)?;
            } else if ft.is_file()
                && !is_temp_name(&name)
                && name != crate::engine::lock::LOCK_FILE
                && name != STAGED_FILE
                && name != PUBLISHED_FILE
                && !name.ends_with(REMOTE_STUB_SUFFIX)
            {
                let rel = e
                    .path()
                    .strip_prefix(root)
                    .expect("below root")
                    .to_path_buf();
                out.push(
                    rel.components()
                        .map(|c| c.as_os_str().to_string_lossy().into_owned())
                        .collect::<Vec<_>>()
                        .join("/"),
                );
            }
        }
        Ok(())
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out)?;
    out.sort();
    Ok(out)
}

/// Upload `local` to `remote`: each changed file under a temporary key,
/// renamed into place; `manifest.json` (the batch's last word) after all
/// others. Files unchanged since the last publish from this directory are
/// not sent again.
pub fn publish(local: &Path, remote: &RemotePrefix) -> Result<PublishReport> {
    let state_path = local.join(PUBLISHED_FILE);
    let before: BTreeMap<String, String> = std::fs::read(&state_path)
        .ok()
        .and_then(|b| serde_json::from_slice(&b).ok())
        .unwrap_or_default();
    let mut files = local_files(local)?;
    // The manifest last: a reader that starts from it never sees a batch
    // whose artifacts are still on their way.
    if let Some(i) = files.iter().position(|f| f == "manifest.json") {
        let m = files.remove(i);
        files.push(m);
    }
    let mut after = BTreeMap::new();
    let mut report = PublishReport::default();
    let tmp_root = format!("{TMP_PREFIX}/{}", std::process::id());
    for rel in files {
        let path = local_path(local, &rel)?;
        let bytes =
            std::fs::read(&path).with_context(|| format!("cannot read {}", path.display()))?;
        let hash = blake3::hash(&bytes).to_hex().to_string();
        if before.get(&rel) == Some(&hash) {
            report.unchanged += 1;
            after.insert(rel, hash);
            continue;
        }
        let tmp = remote.key(&format!("{tmp_root}/{rel}"));
        let key = remote.key(&rel);
        let n = bytes.len() as u64;
        block_on(async {
            remote.store.put(&tmp, PutPayload::from(bytes)).await?;
            remote.store.rename(&tmp, &key).await
        })
        .with_context(|| {
            format!(
                "cannot publish {} to `{}/{rel}`",
                path.display(),
                remote.url
            )
        })?;
        report.uploaded += 1;
        report.uploaded_bytes += n;
        after.insert(rel, hash);
    }
    write_atomic(&state_path, &serde_json::to_vec_pretty(&after)?)?;
    Ok(report)
}

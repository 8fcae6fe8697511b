//! Mirroring a remote prefix into a local directory (inputs) and publishing
//! a local directory to a remote prefix (outputs).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::{Context, Result};
use futures::TryStreamExt;
use object_store::{ObjectMeta, ObjectStoreExt, PutPayload};
use serde::{Deserialize, Serialize};

use super::remote::{RemoteStub, REMOTE_STUB_SUFFIX};
use super::{block_on, RemotePrefix};
use crate::files::write::{is_temp_name, write_atomic};

/// Staging state: which version of each object the local copy is.
const STAGED_FILE: &str = ".sparkout-staged.json";
/// The publish record (what the last publish to a prefix wrote), an object
/// under that prefix.
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
    /// Objects left out by the selection (another shard's runs): a stub
    /// records each one's size.
    pub not_fetched: usize,
}

/// What [`publish`] did.
#[derive(Debug, Default, Clone)]
pub struct PublishReport {
    pub uploaded: usize,
    pub uploaded_bytes: u64,
    pub unchanged: usize,
    /// Objects an earlier publish to the prefix wrote that this one no
    /// longer has, removed.
    pub removed: usize,
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

/// Does `remote` hold no object? (Only the first object is fetched.)
pub(super) fn holds_nothing(remote: &RemotePrefix) -> Result<bool> {
    let first = block_on(async { remote.store.list(Some(&remote.prefix)).try_next().await })
        .with_context(|| {
            format!(
                "cannot list `{}` (check the bucket name, credentials and endpoint: AWS_*/GOOGLE_*/AZURE_* in the environment)",
                remote.url
            )
        })?;
    Ok(first.is_none())
}

/// An object key below a prefix as a local path below `root`; a key with an
/// empty, `.` or `..` segment (or a separator of this system inside a
/// segment) would leave `root` and is refused.
fn local_path(root: &Path, rel: &str) -> Result<PathBuf> {
    let mut p = root.to_path_buf();
    for part in rel.split('/') {
        if !crate::files::names::is_plain_file_name(part) {
            crate::bail!(
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
    stage_down_selected(remote, local, stream_min_bytes, &|_| true)
}

/// [`stage_down`], fetching only the objects `fetch` selects (by path
/// below the prefix): every other object is staged as a stub that records
/// its size and ETag, so a shard sees the whole input's runs (to partition
/// them, by id or by size) but downloads only its own.
pub fn stage_down_selected(
    remote: &RemotePrefix,
    local: &Path,
    stream_min_bytes: Option<u64>,
    fetch: &dyn Fn(&str) -> bool,
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
        crate::bail!(
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
        let wanted = fetch(&rel);
        let streamed = !wanted
            || (rel.ends_with(".parquet") && stream_min_bytes.is_some_and(|min| meta.size >= min));
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
            if wanted {
                report.streamed += 1;
                report.streamed_bytes += meta.size;
            } else {
                report.not_fetched += 1;
            }
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
                && name != crate::files::LOCK_FILE
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

/// What a publish wrote, kept as an object beside what it wrote (so a
/// fresh node, or a second location, compares with the bucket itself and
/// never with a state file in the user's folder).
#[derive(Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PublishRecord {
    version: u32,
    objects: BTreeMap<String, PublishedObject>,
}

const PUBLISH_RECORD_VERSION: u32 = 1;

/// One object as this publish left it: the local content's blake3 and the
/// object's size and ETag as the bucket listed them after the upload.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
struct PublishedObject {
    blake3: String,
    size: u64,
    e_tag: Option<String>,
}

/// The record an earlier publish left under `remote`, if it is there and
/// readable (an unreadable one is treated as absent: everything is sent
/// again and nothing is removed).
fn read_record(remote: &RemotePrefix, listed: &BTreeMap<String, ObjectMeta>) -> PublishRecord {
    if !listed.contains_key(PUBLISHED_FILE) {
        return PublishRecord::default();
    }
    let key = remote.key(PUBLISHED_FILE);
    let got = block_on(async { remote.store.get(&key).await?.bytes().await });
    match got
        .ok()
        .and_then(|b| serde_json::from_slice::<PublishRecord>(&b).ok())
    {
        Some(r) if r.version == PUBLISH_RECORD_VERSION => r,
        _ => {
            tracing::warn!(
                "{}/{PUBLISHED_FILE} is not a publish record this sparkout reads: every file is uploaded again and no earlier object is removed",
                remote.url
            );
            PublishRecord::default()
        }
    }
}

/// The objects under `remote` by relative path (temporary keys left out).
fn listing(remote: &RemotePrefix) -> Result<BTreeMap<String, ObjectMeta>> {
    Ok(list(remote)?
        .into_iter()
        .filter_map(|m| {
            let rel = remote.relative(&m.location)?;
            (!rel.split('/').any(|p| p.starts_with(TMP_PREFIX))).then_some((rel, m))
        })
        .collect())
}

/// Put `bytes` under a temporary key and rename it to `rel`: the object
/// appears whole or not at all.
fn put_whole(remote: &RemotePrefix, tmp_root: &str, rel: &str, bytes: Vec<u8>) -> Result<()> {
    let tmp = remote.key(&format!("{tmp_root}/{rel}"));
    let key = remote.key(rel);
    block_on(async {
        remote.store.put(&tmp, PutPayload::from(bytes)).await?;
        remote.store.rename(&tmp, &key).await
    })
    .with_context(|| format!("cannot publish `{}/{rel}`", remote.url))?;
    Ok(())
}

/// Can this process write under `remote`? A small object is put under the
/// temporary prefix and removed again, so bad credentials or a read-only
/// bucket are found before a batch computes for an hour.
pub fn check_writable(remote: &RemotePrefix) -> Result<()> {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    let key = remote.key(&format!(
        "{TMP_PREFIX}/write-check-{}-{nanos}",
        std::process::id()
    ));
    block_on(async {
        remote
            .store
            .put(&key, PutPayload::from(b"sparkout write check".to_vec()))
            .await?;
        remote.store.delete(&key).await
    })
    .with_context(|| {
        format!(
            "cannot write under `{}` (check the bucket, the credentials' write permission and the endpoint: AWS_*/GOOGLE_*/AZURE_* in the environment); nothing was computed",
            remote.url
        )
    })
}

/// Rewrites a file's bytes before they are published (the manifest's local
/// paths become URLs); `None` leaves them as they are.
pub type Rewrite<'a> = &'a dyn Fn(&str, &[u8]) -> Option<Vec<u8>>;

/// Upload `local` to `remote`: each file whose content the bucket does not
/// already hold under a temporary key, renamed into place; `manifest.json`
/// (the batch's last word) after all others; then the objects an earlier
/// publish to this prefix wrote that this one no longer has are removed,
/// and last the record of what was published. What counts as "already
/// held" is decided against the bucket's listing (size and ETag of the
/// object as the record left it), so an object deleted or replaced behind
/// sparkout's back is sent again. Nothing is written outside `local`'s
/// own files.
pub fn publish(local: &Path, remote: &RemotePrefix, rewrite: Rewrite) -> Result<PublishReport> {
    let listed = listing(remote)?;
    let before = read_record(remote, &listed);
    let mut files = local_files(local)?;
    // The manifest last: a reader that starts from it never sees a batch
    // whose artifacts are still on their way.
    if let Some(i) = files.iter().position(|f| f == "manifest.json") {
        let m = files.remove(i);
        files.push(m);
    }
    let mut hashes = BTreeMap::new();
    let mut report = PublishReport::default();
    let tmp_root = format!("{TMP_PREFIX}/{}", std::process::id());
    for rel in &files {
        let path = local_path(local, rel)?;
        let bytes =
            std::fs::read(&path).with_context(|| format!("cannot read {}", path.display()))?;
        let bytes = rewrite(rel, &bytes).unwrap_or(bytes);
        let hash = blake3::hash(&bytes).to_hex().to_string();
        let held = match (before.objects.get(rel), listed.get(rel)) {
            (Some(was), Some(now)) => {
                was.blake3 == hash
                    && was.size == now.size
                    && (was.e_tag.is_none() || was.e_tag == now.e_tag)
            }
            _ => false,
        };
        hashes.insert(rel.clone(), hash);
        if held {
            report.unchanged += 1;
            continue;
        }
        let n = bytes.len() as u64;
        put_whole(remote, &tmp_root, rel, bytes)
            .with_context(|| format!("publishing {}", path.display()))?;
        report.uploaded += 1;
        report.uploaded_bytes += n;
    }
    // Only what an earlier publish to this very prefix wrote, and only
    // after the manifest is in place.
    for rel in before.objects.keys() {
        if hashes.contains_key(rel) || !listed.contains_key(rel) || rel == PUBLISHED_FILE {
            continue;
        }
        if local_path(local, rel).is_err() {
            continue;
        }
        let key = remote.key(rel);
        block_on(remote.store.delete(&key))
            .with_context(|| format!("cannot remove the stale `{}/{rel}`", remote.url))?;
        report.removed += 1;
    }
    let after = listing(remote)?;
    let record = PublishRecord {
        version: PUBLISH_RECORD_VERSION,
        objects: hashes
            .into_iter()
            .filter_map(|(rel, blake3)| {
                let m = after.get(&rel)?;
                Some((
                    rel,
                    PublishedObject {
                        blake3,
                        size: m.size,
                        e_tag: m.e_tag.clone(),
                    },
                ))
            })
            .collect(),
    };
    put_whole(
        remote,
        &tmp_root,
        PUBLISHED_FILE,
        serde_json::to_vec_pretty(&record)?,
    )?;
    Ok(report)
}

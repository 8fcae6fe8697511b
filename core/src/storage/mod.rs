//! Object storage for `--input`, `--out` and `--shards` (docs/scale.md
//! "Object storage"): `s3://`, `gs://`, `az://` (also `abfs://`,
//! `azure://`) through the `object_store` crate that arrow-rs and polars use;
//! `file://` is a local path.
//!
//! The engine itself knows only local directories (its cache, locks and
//! atomic renames are file-system operations), so a remote location is
//! bridged at the edges:
//! - **in** ([`stage_down`]): the objects under the prefix are mirrored into a
//!   local staging directory — small files downloaded (skipped when the
//!   object's size and ETag are unchanged since the last staging), and every
//!   Parquet file of at least [`stream_min_bytes`] left remote: a small
//!   `<name>.remote.json` stands in for it and readers fetch its pages by
//!   ranged GETs ([`crate::contracts::input_file`]), so an AE log of
//!   gigabytes streams row group by row group as from disk;
//! - **out** ([`publish`]): the batch writes into a local work directory and
//!   every file is then uploaded under a temporary key and renamed into place
//!   (an object appears whole or not at all), changed files only, and
//!   `manifest.json` last — a reader that starts from the manifest never sees
//!   a partial batch.
//!
//! Credentials and endpoints come from the standard environment
//! (`AWS_ACCESS_KEY_ID`, `AWS_SECRET_ACCESS_KEY`, `AWS_REGION`,
//! `AWS_ENDPOINT`, `AWS_ALLOW_HTTP`, `GOOGLE_SERVICE_ACCOUNT`,
//! `AZURE_STORAGE_ACCOUNT_NAME`, … as the `object_store` builders'
//! `from_env` read them).

mod remote;
mod sync;

pub use remote::{RemoteObject, RemoteStub, REMOTE_STUB_SUFFIX};
pub use sync::{
    check_writable, publish, stage_down, stage_down_selected, PublishReport, StageReport,
};

use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use crate::{bail, Context, Result};
use object_store::path::Path as ObjectPath;
use object_store::ObjectStore;

/// Where a batch reads or writes: a local directory or a prefix in a bucket.
#[derive(Debug, Clone)]
pub enum Location {
    Local(PathBuf),
    Remote(RemotePrefix),
}

/// A bucket and a key prefix, connected.
#[derive(Clone)]
pub struct RemotePrefix {
    /// The URL as the user wrote it, without a trailing slash.
    pub url: String,
    pub store: Arc<dyn ObjectStore>,
    pub prefix: ObjectPath,
}

impl std::fmt::Debug for RemotePrefix {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.url)
    }
}

/// The URL schemes read as object storage.
const SCHEMES: &[&str] = &["s3", "s3a", "gs", "az", "abfs", "abfss", "azure", "adl"];

/// Does this argument name object storage (`scheme://…`)?
pub fn is_url(arg: &Path) -> bool {
    arg.to_str()
        .and_then(|s| s.split_once("://"))
        .is_some_and(|(scheme, _)| scheme == "file" || SCHEMES.contains(&scheme))
}

/// An object-storage URL as `scheme://bucket/key/prefix` with its empty
/// segments (`//`, a trailing `/`) and `.` segments dropped; `None` for a
/// local path or a URL with a `..` segment (which object stores do not
/// resolve, so it can be compared with nothing).
fn url_segments(arg: &Path) -> Option<(String, Vec<String>)> {
    let s = arg.to_str()?;
    let (scheme, rest) = s.split_once("://")?;
    if scheme == "file" || !SCHEMES.contains(&scheme) {
        return None;
    }
    let segs: Vec<String> = rest
        .split('/')
        .filter(|p| !p.is_empty() && *p != ".")
        .map(str::to_string)
        .collect();
    (!segs.iter().any(|p| p == "..")).then(|| (scheme.to_string(), segs))
}

/// `--out` and `--input` as bucket URLs must be apart like local paths: an
/// output prefix equal to, inside or containing the input prefix is
/// refused (a publish would write among — or a clean-up delete — the
/// inputs). Local paths are checked by the engine.
pub fn check_remote_apart(input: &Path, out: &Path) -> Result<()> {
    let (Some((si, i)), Some((so, o))) = (url_segments(input), url_segments(out)) else {
        return Ok(());
    };
    if si != so {
        return Ok(());
    }
    let Some(why) = crate::files::names::overlap(&i, &o) else {
        return Ok(());
    };
    bail!(
        "--out {} {why} --input {}: sparkout writes and removes its own objects under --out, never among its inputs; choose an output prefix outside the input",
        out.display(),
        input.display()
    )
}

impl Location {
    /// A path, `file://PATH` or a bucket URL. An unknown `scheme://` is an
    /// error rather than a directory of that name.
    pub fn parse(arg: &Path) -> Result<Location> {
        let Some(s) = arg.to_str() else {
            return Ok(Location::Local(arg.to_path_buf()));
        };
        let Some((scheme, rest)) = s.split_once("://") else {
            return Ok(Location::Local(arg.to_path_buf()));
        };
        if scheme == "file" {
            return Ok(Location::Local(PathBuf::from(rest)));
        }
        if !SCHEMES.contains(&scheme) {
            bail!(
                "`{s}`: unknown storage scheme `{scheme}://` (sparkout reads local paths, file://, s3://, gs://, az://)"
            );
        }
        Ok(Location::Remote(RemotePrefix::connect(s)?))
    }
}

impl RemotePrefix {
    /// Build the store from the URL and the standard environment.
    pub fn connect(url: &str) -> Result<RemotePrefix> {
        let url = url.trim_end_matches('/').to_string();
        let parsed =
            url::Url::parse(&url).with_context(|| format!("`{url}` is not a valid URL"))?;
        let store: Arc<dyn ObjectStore> = match parsed.scheme() {
            "s3" | "s3a" => Arc::new(
                object_store::aws::AmazonS3Builder::from_env()
                    .with_url(url.as_str())
                    .build()
                    .with_context(|| store_hint(&url, "AWS_*"))?,
            ),
            "gs" => Arc::new(
                object_store::gcp::GoogleCloudStorageBuilder::from_env()
                    .with_url(url.as_str())
                    .build()
                    .with_context(|| store_hint(&url, "GOOGLE_*"))?,
            ),
            _ => Arc::new(
                object_store::azure::MicrosoftAzureBuilder::from_env()
                    .with_url(url.as_str())
                    .build()
                    .with_context(|| store_hint(&url, "AZURE_*"))?,
            ),
        };
        // The key prefix is the URL's path; Azure's `az://container/p`
        // and S3's `s3://bucket/p` both put the container in the host.
        let prefix = ObjectPath::from_url_path(parsed.path())
            .with_context(|| format!("`{url}`: the path is not a valid object key prefix"))?;
        Ok(RemotePrefix { url, store, prefix })
    }

    /// The object key of a path relative to this prefix (`/`-separated).
    pub fn key(&self, rel: &str) -> ObjectPath {
        let mut key = self.prefix.clone();
        for part in rel.split('/').filter(|p| !p.is_empty()) {
            key = key.join(part);
        }
        key
    }

    /// The path of a key below this prefix, `/`-separated.
    pub fn relative(&self, key: &ObjectPath) -> Option<String> {
        let parts: Vec<String> = key
            .prefix_match(&self.prefix)?
            .map(|p| p.as_ref().to_string())
            .collect();
        (!parts.is_empty()).then(|| parts.join("/"))
    }
}

fn store_hint(url: &str, env: &str) -> String {
    format!(
        "cannot configure object storage for `{url}`: set the credentials and endpoint in the environment ({env}; docs/scale.md)"
    )
}

/// The one runtime that drives object-store requests from sparkout's
/// blocking code (rayon workers and the main thread call [`block_on`]; none
/// of them is a runtime thread). Two workers: requests wait on the network,
/// not the CPU.
fn runtime() -> &'static tokio::runtime::Runtime {
    static RT: OnceLock<tokio::runtime::Runtime> = OnceLock::new();
    RT.get_or_init(|| {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("sparkout-object-store")
            .enable_all()
            .build()
            .expect("a tokio runtime for object storage")
    })
}

pub(crate) fn block_on<F: std::future::Future>(f: F) -> F::Output {
    runtime().block_on(f)
}

/// Parquet files at least this large stay remote and are read by ranged
/// GETs; smaller ones are downloaded. `SPARKOUT_STREAM_MIN_BYTES` overrides
/// (the tests use 0 so every Parquet input streams).
pub fn stream_min_bytes() -> u64 {
    std::env::var("SPARKOUT_STREAM_MIN_BYTES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(16 << 20)
}

/// The local directory that stands for a remote location: `--work DIR` when
/// given, else a directory under the system's temp dir named by a hash of
/// the URL and its role, so a re-run on the same node finds its cache.
pub fn work_dir(work: Option<&Path>, url: &str, role: &str) -> PathBuf {
    let name = format!(
        "{role}-{}",
        &blake3::hash(url.as_bytes()).to_hex().as_str()[..16]
    );
    match work {
        Some(w) => w.join(name),
        None => std::env::temp_dir().join("sparkout-work").join(name),
    }
}

/// `--input`/`--shards` as a local directory: a bucket prefix is staged
/// into the work directory first (large Parquet files left remote when
/// `stream` is set). Prints what staging did to stderr.
pub fn resolve_input(arg: &Path, work: Option<&Path>, role: &str, stream: bool) -> Result<PathBuf> {
    resolve_input_selected(arg, work, role, stream, None)
}

/// Which runs of a staged input a command processes: given the staged
/// directory with every run's `run.toml` (the rest as stubs), the run
/// directories to fetch. `sparkout run --shard` passes its partition, so a
/// shard downloads its own runs only.
pub type RunSelector<'a> = &'a dyn Fn(&Path) -> Result<Vec<PathBuf>>;

/// [`resolve_input`] that fetches only the runs `select` picks: first every
/// `run.toml` (and stubs with the size of everything else), then the
/// selected runs' files.
pub fn resolve_input_selected(
    arg: &Path,
    work: Option<&Path>,
    role: &str,
    stream: bool,
    select: Option<RunSelector>,
) -> Result<PathBuf> {
    let remote = match Location::parse(arg)? {
        Location::Local(p) => return Ok(p),
        Location::Remote(remote) => remote,
    };
    let local = work_dir(work, &remote.url, role);
    let min = stream.then(stream_min_bytes);
    let r = match select {
        None => stage_down(&remote, &local, min)?,
        Some(select) => {
            let is_spec = |rel: &str| rel == "run.toml" || rel.ends_with("/run.toml");
            stage_down_selected(&remote, &local, min, &is_spec)?;
            let mine: Vec<String> = select(&local)?
                .iter()
                .filter_map(|d| d.strip_prefix(&local).ok())
                .map(|d| {
                    d.components()
                        .map(|c| c.as_os_str().to_string_lossy().into_owned())
                        .collect::<Vec<_>>()
                        .join("/")
                })
                .collect();
            let in_mine = |rel: &str| {
                is_spec(rel)
                    || mine.iter().any(|d| {
                        d.is_empty()
                            || rel
                                .strip_prefix(d.as_str())
                                .is_some_and(|rest| rest.starts_with('/'))
                    })
            };
            stage_down_selected(&remote, &local, min, &in_mine)?
        }
    };
    eprintln!(
        "staged {} into {}: {} downloaded ({:.1} MB), {} unchanged, {} read in place by ranged GETs ({:.1} MB), {} of other shards' runs not fetched, {} removed",
        remote.url,
        local.display(),
        r.downloaded,
        r.downloaded_bytes as f64 / 1e6,
        r.unchanged,
        r.streamed,
        r.streamed_bytes as f64 / 1e6,
        r.not_fetched,
        r.removed
    );
    Ok(local)
}

/// `run --history` as a local directory: a bucket prefix is staged into
/// the work directory (an empty prefix is a first night: nothing to stage)
/// and returned with the [`Output`] that publishes the grown history back
/// after the night. Write access is checked before anything is computed.
/// One writer per history prefix: object storage has no lock, so two
/// nights appending to one bucket history at once would lose one's rows.
pub fn resolve_history(arg: &Path, work: Option<&Path>) -> Result<(PathBuf, Option<Output>)> {
    let remote = match Location::parse(arg)? {
        Location::Local(p) => return Ok((p, None)),
        Location::Remote(remote) => remote,
    };
    check_writable(&remote)?;
    let local = work_dir(work, &remote.url, "history");
    if sync::holds_nothing(&remote)? {
        std::fs::create_dir_all(&local)
            .with_context(|| format!("cannot create {}", local.display()))?;
        eprintln!("history {} is empty: this is its first night", remote.url);
    } else {
        let r = stage_down(&remote, &local, None)?;
        eprintln!(
            "staged the history {} into {}: {} downloaded, {} unchanged",
            remote.url,
            local.display(),
            r.downloaded,
            r.unchanged
        );
    }
    Ok((
        local.clone(),
        Some(Output {
            stands_for: vec![(local.clone(), remote.url.clone())],
            local,
            remote: Some(remote),
        }),
    ))
}

/// Where a command writes: the local directory, and the bucket prefix it is
/// published to afterwards ([`Output::publish`]).
pub struct Output {
    pub local: PathBuf,
    pub remote: Option<RemotePrefix>,
    /// Local directories that stand for URLs (the output's work directory,
    /// staged inputs): the published manifest names the URLs, not paths
    /// that exist only on the node that ran the batch.
    pub stands_for: Vec<(PathBuf, String)>,
}

impl Output {
    /// The output as a local directory; for a bucket, its work directory,
    /// after checking that this process may write there (before anything
    /// is computed).
    pub fn resolve(arg: &Path, work: Option<&Path>) -> Result<Output> {
        Ok(match Location::parse(arg)? {
            Location::Local(local) => Output {
                local,
                remote: None,
                stands_for: Vec::new(),
            },
            Location::Remote(remote) => {
                check_writable(&remote)?;
                let local = work_dir(work, &remote.url, "out");
                resume_from_bucket(&remote, &local)?;
                Output {
                    stands_for: vec![(local.clone(), remote.url.clone())],
                    local,
                    remote: Some(remote),
                }
            }
        })
    }

    /// Another local directory that stands for a URL (a staged input).
    pub fn staged(&mut self, local: &Path, url: &Path) {
        if is_url(url) {
            self.stands_for
                .push((local.to_path_buf(), url.display().to_string()));
        }
    }

    /// Upload the local directory when the output is remote; prints a line.
    pub fn publish(&self) -> Result<()> {
        if let Some(remote) = &self.remote {
            let rewrite = |rel: &str, bytes: &[u8]| -> Option<Vec<u8>> {
                // The manifest is what a reader of the bucket starts from;
                // shard.json keeps the node's paths (aggregate reads them).
                (rel == "manifest.json")
                    .then(|| paths_to_urls(bytes, &self.stands_for))
                    .flatten()
            };
            let r = publish(&self.local, remote, &rewrite)?;
            eprintln!(
                "published {} to {}: {} uploaded ({:.1} MB), {} unchanged, {} removed (written by an earlier publish, no longer produced)",
                self.local.display(),
                remote.url,
                r.uploaded,
                r.uploaded_bytes as f64 / 1e6,
                r.unchanged,
                r.removed
            );
        }
        Ok(())
    }
}

/// A fresh node (no work directory for this output yet) starts from what
/// an earlier publish to the prefix left — the per-run outputs and their
/// `.sparkout-cache.json` — so a shard re-run on another node resumes from
/// the cache instead of recomputing. A node that kept its work directory
/// uses it as it is.
fn resume_from_bucket(remote: &RemotePrefix, local: &Path) -> Result<()> {
    if local.exists() {
        return Ok(());
    }
    if sync::holds_nothing(remote)? {
        return Ok(());
    }
    let r = stage_down(remote, local, None)?;
    eprintln!(
        "resumed {} from {}: {} files ({:.1} MB) an earlier publish left (cached stages are not recomputed)",
        local.display(),
        remote.url,
        r.downloaded,
        r.downloaded_bytes as f64 / 1e6
    );
    Ok(())
}

/// A JSON document with every string that is a path under one of
/// `stands_for`'s directories replaced by the URL below the directory's
/// URL. `None` when the bytes are not JSON or nothing changes.
fn paths_to_urls(bytes: &[u8], stands_for: &[(PathBuf, String)]) -> Option<Vec<u8>> {
    fn walk(v: &mut serde_json::Value, map: &[(String, String)], changed: &mut bool) {
        match v {
            serde_json::Value::String(s) => {
                for (dir, url) in map {
                    if let Some(rest) = s.strip_prefix(dir.as_str()) {
                        if rest.is_empty() || rest.starts_with('/') {
                            *s = format!("{url}{rest}");
                            *changed = true;
                            break;
                        }
                    }
                }
            }
            serde_json::Value::Array(a) => a.iter_mut().for_each(|x| walk(x, map, changed)),
            serde_json::Value::Object(o) => o.values_mut().for_each(|x| walk(x, map, changed)),
            _ => {}
        }
    }
    let mut v: serde_json::Value = serde_json::from_slice(bytes).ok()?;
    // Longest directory first: a staged input under the work directory is
    // named by its own URL, not as a path below the output's.
    let mut map: Vec<(String, String)> = stands_for
        .iter()
        .map(|(d, u)| (d.display().to_string(), u.clone()))
        .collect();
    map.sort_by_key(|(d, _)| std::cmp::Reverse(d.len()));
    let mut changed = false;
    walk(&mut v, &map, &mut changed);
    if !changed {
        return None;
    }
    let mut out = serde_json::to_vec_pretty(&v).ok()?;
    out.push(b'\n');
    Some(out)
}

#[cfg(test)]
mod apart_tests {
    use super::*;

    #[test]
    fn remote_prefixes_apart() {
        let p = |s: &str| PathBuf::from(s);
        assert!(check_remote_apart(&p("s3://b/fleet"), &p("s3://b/fleet/")).is_err());
        assert!(check_remote_apart(&p("s3://b/fleet"), &p("s3://b/fleet/out")).is_err());
        assert!(check_remote_apart(&p("s3://b/fleet/in"), &p("s3://b//fleet")).is_err());
        assert!(check_remote_apart(&p("s3://b/fleet"), &p("s3://b/fleet-out")).is_ok());
        assert!(check_remote_apart(&p("s3://b/fleet"), &p("s3://c/fleet")).is_ok());
        assert!(check_remote_apart(&p("s3://b/fleet"), &p("gs://b/fleet")).is_ok());
        assert!(check_remote_apart(&p("s3://b/fleet"), &p("/tmp/out")).is_ok());
    }
}

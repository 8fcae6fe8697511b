//! Scale-out (docs/design.md §8): runs are independent until the
//! fleet diagnosis, so a nightly batch splits into `n` shards by run —
//! `sparkout run --shard i/n` processes its share of the runs exactly as a
//! single-node `run` would and writes `shard.json` instead of the fleet
//! steps — and `sparkout aggregate --shards DIR... --out DIR` gathers the
//! shards' run outputs and runs the fleet steps once. Scheduling belongs to
//! an existing engine (deploy/slurm, deploy/k8s), never to sparkout.
//!
//! The partition is a pure function of the input: every shard computes the
//! same assignment on its own, with no coordinator.

use std::path::{Path, PathBuf};

use crate::{bail, Context};
use serde::{Deserialize, Serialize};

use super::{Failure, RunResult};
use crate::contracts::{write_json_atomic, RunSpec};
use crate::error::Result;

/// Version of shard.json (2: the night's input and machine configs are
/// fingerprinted, and each shard says how many items it was assigned; 3:
/// the night's run set and each shard's share of it are listed).
pub const SHARD_VERSION: u32 = 3;

/// The file a shard writes in its output directory.
pub const SHARD_FILE: &str = "shard.json";

/// How runs are spread over shards.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Balance {
    /// By a hash of (machine, run): stable when runs are added or removed
    /// (a run keeps its shard), balanced in count.
    Hash,
    /// Greedy by input bytes (largest first onto the lightest shard): even
    /// work when run sizes differ widely (AE logs), but a new run can move
    /// others.
    Size,
}

/// `--shard i/n` (0-based i).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ShardSpec {
    pub index: usize,
    pub count: usize,
    pub balance: Balance,
}

impl ShardSpec {
    /// Parses `i/n` with 0 ≤ i < n.
    pub fn parse(text: &str, balance: Balance) -> std::result::Result<ShardSpec, String> {
        let (i, n) = text.split_once('/').ok_or_else(|| {
            format!("--shard `{text}`: expected i/n, e.g. 0/4 (shards count from 0)")
        })?;
        let index: usize = i
            .trim()
            .parse()
            .map_err(|_| format!("--shard `{text}`: `{i}` is not a whole number"))?;
        let count: usize = n
            .trim()
            .parse()
            .map_err(|_| format!("--shard `{text}`: `{n}` is not a whole number"))?;
        if count == 0 || index >= count {
            return Err(format!(
                "--shard `{text}`: need 0 ≤ i < n (shards count from 0: 0/{c} … {last}/{c})",
                c = count.max(1),
                last = count.max(1) - 1
            ));
        }
        Ok(ShardSpec {
            index,
            count,
            balance,
        })
    }
}

/// The key a run is partitioned by: its (machine, run) id when run.toml
/// reads, else its directory (such a run fails in whichever shard owns it).
fn run_key(dir: &Path) -> String {
    match RunSpec::load(dir) {
        Ok(spec) => format!("{}\u{1f}{}", spec.machine, spec.id),
        Err(_) => format!("dir\u{1f}{}", dir.display()),
    }
}

/// Shard of a key under `Balance::Hash`: blake3, so the assignment does not
/// depend on the platform, the Rust version or the order runs were found.
fn hash_shard(key: &str, count: usize) -> usize {
    let h = blake3::hash(key.as_bytes());
    let mut first = [0u8; 8];
    first.copy_from_slice(&h.as_bytes()[..8]);
    (u64::from_le_bytes(first) % count as u64) as usize
}

/// Input bytes of a run directory; a Parquet file left in object storage
/// counts with the size its stub records, not the stub's own.
fn dir_bytes(dir: &Path) -> u64 {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    entries
        .flatten()
        .map(|e| match e.metadata() {
            Ok(m) if m.is_dir() => dir_bytes(&e.path()),
            Ok(m) => {
                let name = e.file_name();
                if name
                    .to_str()
                    .is_some_and(|n| n.ends_with(crate::storage::REMOTE_STUB_SUFFIX))
                {
                    crate::storage::RemoteStub::read(&e.path())
                        .map(|s| s.size)
                        .unwrap_or(m.len())
                } else {
                    m.len()
                }
            }
            Err(_) => 0,
        })
        .sum()
}

/// The run directories (sorted) this shard owns.
pub fn select_runs(run_dirs: &[PathBuf], shard: &ShardSpec) -> Vec<PathBuf> {
    let keys: Vec<String> = run_dirs.iter().map(|d| run_key(d)).collect();
    let owner: Vec<usize> = match shard.balance {
        Balance::Hash => keys.iter().map(|k| hash_shard(k, shard.count)).collect(),
        Balance::Size => {
            // Longest-processing-time first: largest run onto the shard with
            // the fewest bytes so far (runs of equal size in key order),
            // within 4/3 of the optimal makespan.
            let mut order: Vec<(u64, &str, usize)> = run_dirs
                .iter()
                .zip(&keys)
                .enumerate()
                .map(|(i, (d, k))| (dir_bytes(d), k.as_str(), i))
                .collect();
            order.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(b.1)));
            // Equal loads (e.g. runs of one size) go to the shard with the
            // fewest runs, so equal runs spread evenly.
            let mut load = vec![(0u64, 0usize); shard.count];
            let mut owner = vec![0; run_dirs.len()];
            for (bytes, _, i) in order {
                let s = (0..shard.count)
                    .min_by_key(|&s| (load[s], s))
                    .expect("count ≥ 1");
                load[s].0 += bytes;
                load[s].1 += 1;
                owner[i] = s;
            }
            owner
        }
    };
    run_dirs
        .iter()
        .zip(owner)
        .filter(|(_, o)| *o == shard.index)
        .map(|(d, _)| d.clone())
        .collect()
}

/// Whether this shard lists a failure found before any run was processed
/// (a directory without run.toml, a duplicate id): each such failure is
/// listed by exactly one shard.
pub fn owns_failure(f: &Failure, shard: &ShardSpec) -> bool {
    hash_shard(&format!("failure\u{1f}{}", f.run_dir), shard.count) == shard.index
}

/// shard.json: what `aggregate` needs from one shard.
#[derive(Debug, Serialize, Deserialize)]
pub struct ShardManifest {
    pub version: u32,
    pub kind: String,
    pub shard: usize,
    pub shards: usize,
    pub balance: Balance,
    pub sparkout_version: String,
    pub input_root: String,
    /// The local directory this shard read the input from (the input
    /// itself, or where it was staged): the runs' directories are below it,
    /// and `aggregate` orders runs by their path relative to it, as one
    /// node orders them, whatever directory each node staged into.
    #[serde(default)]
    pub input_dir: String,
    /// The batch's whole config: every shard of one night must agree.
    pub config: serde_json::Value,
    pub config_source: String,
    /// blake3 over every run directory and listed directory the shard's
    /// discovery found (paths relative to the input): shards of one night
    /// saw the same input, or a stale shard from another night is refused.
    pub input_fingerprint: String,
    /// How many items (runs and listed directories) the whole night has,
    /// and how many of them this shard was assigned: the shards' assigned
    /// counts must add up to the night's.
    pub night_items: usize,
    pub assigned_items: usize,
    /// The night's run set as this shard listed it when it started (runs
    /// and listed directories, relative to the input, sorted; with
    /// `--snapshot`, the snapshot's), and the part of it this shard was
    /// assigned: `aggregate` checks that the shares partition the night
    /// and names any run missing or doubled.
    pub night_runs: Vec<String>,
    pub assigned_runs: Vec<String>,
    /// [`crate::contracts::MachineResolver::fingerprint`]: every shard must
    /// have resolved machines from the same configs.
    pub machines_fingerprint: String,
    pub runs: Vec<RunResult>,
    pub failures: Vec<Failure>,
}

/// The fingerprint of what discovery found under `root`.
pub fn input_fingerprint(root: &Path, found: &crate::contracts::Discovery) -> String {
    let rel = |p: &Path| {
        p.strip_prefix(root)
            .unwrap_or(p)
            .to_string_lossy()
            .into_owned()
    };
    let mut key = super::cache::KeyBuilder::new("shard-input");
    for r in &found.runs {
        key.part("run", &rel(r));
    }
    for s in &found.skipped {
        key.part("listed", &rel(&s.dir));
    }
    key.finish()
}

impl ShardManifest {
    pub fn write(out: &Path, m: &ShardManifest) -> Result<()> {
        write_json_atomic(&out.join(SHARD_FILE), m)
    }

    pub fn read(dir: &Path) -> Result<ShardManifest> {
        let path = dir.join(SHARD_FILE);
        let bytes = std::fs::read(&path).with_context(|| {
            format!(
                "{} is not a finished shard: cannot read {} (run `sparkout run --shard i/n --out {}` to completion first)",
                dir.display(),
                path.display(),
                dir.display()
            )
        })?;
        let m: ShardManifest = serde_json::from_slice(&bytes)
            .with_context(|| format!("{}: not a sparkout shard manifest", path.display()))?;
        if m.version != SHARD_VERSION {
            bail!(
                "{}: shard manifest version {} (this sparkout reads {SHARD_VERSION})",
                path.display(),
                m.version
            );
        }
        Ok(m)
    }
}

/// The shards of one night, checked: same count, every index exactly once,
/// same input root and config.
pub fn check_shards(dirs: &[PathBuf], manifests: &[ShardManifest]) -> Result<()> {
    let Some(first) = manifests.first() else {
        bail!("aggregate needs at least one shard directory (--shards DIR...)");
    };
    let mut seen: Vec<Option<&PathBuf>> = vec![None; first.shards];
    for (dir, m) in dirs.iter().zip(manifests) {
        // Another release computes a run's outputs its own way: a night
        // of mixed versions is not what one node of either would write.
        if m.sparkout_version != env!("CARGO_PKG_VERSION") {
            bail!(
                "{} was made by sparkout {}, this aggregate is sparkout {}: re-run the shard with this version (every shard and the aggregate of a night use one version)",
                dir.display(),
                m.sparkout_version,
                env!("CARGO_PKG_VERSION")
            );
        }
        if m.shard >= m.shards {
            bail!(
                "{}: shard {}/{} is not a shard index (0 ≤ i < n)",
                dir.join(SHARD_FILE).display(),
                m.shard,
                m.shards
            );
        }
        if m.balance != first.balance {
            bail!(
                "{} was split with --balance {:?} but {} with --balance {:?}: the two splits assign runs differently, so runs would be lost or doubled — re-run every shard with one --balance",
                dir.display(),
                m.balance,
                dirs[0].display(),
                first.balance
            );
        }
        if m.input_fingerprint != first.input_fingerprint || m.night_items != first.night_items {
            bail!(
                "{} and {} saw different inputs ({} vs {} runs and listed directories under {}): one of them is stale (another night's, or its input changed since) — re-run it",
                dirs[0].display(),
                dir.display(),
                first.night_items,
                m.night_items,
                m.input_root
            );
        }
        if m.machines_fingerprint != first.machines_fingerprint {
            bail!(
                "{} and {} resolved machines from different machine configs (--machines, ./configs/machines or SPARKOUT_MACHINES differ): shards of one night must use the same ones",
                dirs[0].display(),
                dir.display()
            );
        }
        if m.shards != first.shards {
            bail!(
                "{} is shard {}/{} but {} is shard {}/{}: shards of different splits cannot be aggregated",
                dir.display(),
                m.shard,
                m.shards,
                dirs[0].display(),
                first.shard,
                first.shards
            );
        }
        if m.input_root != first.input_root || m.config != first.config {
            bail!(
                "{} and {} were run with different {} — shards of one night must share --input and config",
                dirs[0].display(),
                dir.display(),
                if m.input_root != first.input_root {
                    format!("inputs ({} vs {})", first.input_root, m.input_root)
                } else {
                    "configs".to_string()
                }
            );
        }
        if let Some(other) = seen[m.shard] {
            bail!(
                "shard {}/{} appears twice: {} and {}",
                m.shard,
                m.shards,
                other.display(),
                dir.display()
            );
        }
        seen[m.shard] = Some(dir);
    }
    let missing: Vec<String> = seen
        .iter()
        .enumerate()
        .filter(|(_, s)| s.is_none())
        .map(|(i, _)| format!("{i}/{}", first.shards))
        .collect();
    if !missing.is_empty() {
        bail!(
            "missing shard(s) {}: aggregate needs all {} shards of the night",
            missing.join(", "),
            first.shards
        );
    }
    if let Some(m) = manifests.iter().find(|m| m.night_runs != first.night_runs) {
        bail!(
            "{} and shard {}/{} listed different run sets for the night: one of them is stale — re-run it",
            dirs[0].display(),
            m.shard,
            m.shards
        );
    }
    let mut owner: std::collections::BTreeMap<&str, &PathBuf> = std::collections::BTreeMap::new();
    for (dir, m) in dirs.iter().zip(manifests) {
        for r in &m.assigned_runs {
            if let Some(other) = owner.insert(r.as_str(), dir) {
                bail!(
                    "run {r} was assigned to two shards ({} and {}): re-run every shard with the same sparkout, input and --balance",
                    other.display(),
                    dir.display()
                );
            }
        }
    }
    let missing: Vec<&str> = first
        .night_runs
        .iter()
        .map(String::as_str)
        .filter(|r| !owner.contains_key(r))
        .collect();
    if !missing.is_empty() {
        bail!(
            "{} run(s) of the night were assigned to no shard (first: {}): re-run every shard with the same sparkout, input and --balance",
            missing.len(),
            missing[..missing.len().min(5)].join(", ")
        );
    }
    if let Some(extra) = owner.keys().find(|r| {
        first
            .night_runs
            .binary_search_by(|n| n.as_str().cmp(r))
            .is_err()
    }) {
        bail!(
            "run {extra} was processed by a shard but is not in the night's run set: a shard is stale — re-run it"
        );
    }
    let assigned: usize = manifests.iter().map(|m| m.assigned_items).sum();
    if assigned != first.night_items {
        bail!(
            "the shards were assigned {assigned} items in all, but the night has {}: runs would be lost or doubled — re-run every shard with the same sparkout, input and --balance",
            first.night_items
        );
    }
    let mut ids = std::collections::BTreeMap::new();
    for (dir, m) in dirs.iter().zip(manifests) {
        for r in &m.runs {
            if let Some(other) = ids.insert((r.machine.clone(), r.run.clone()), dir) {
                bail!(
                    "run {}/{} is in two shards ({} and {})",
                    r.machine,
                    r.run,
                    other.display(),
                    dir.display()
                );
            }
        }
    }
    Ok(())
}

/// Puts a run's output directory from a shard into the aggregate output
/// (to a temporary name, then renamed: a reader never sees half a run).
/// Files are hard-linked where the shard lies on the same file system — a
/// fleet's run folders are gigabytes (docs/scale.md) and sparkout never
/// rewrites a file in place (it writes a temporary file and renames it over
/// the old one), so a re-run shard cannot change the aggregate's files —
/// and copied otherwise (another file system). A symbolic link is refused:
/// sparkout writes none there, and following one would carry a file from
/// outside the shard into the output (and into the bucket it is published
/// to).
pub fn copy_run_dir(from: &Path, to: &Path) -> Result<()> {
    if from == to {
        return Ok(());
    }
    let parent = to.parent().expect("a run dir has a machine dir above it");
    std::fs::create_dir_all(parent)?;
    let tmp = parent.join(format!(
        ".{}.{}.tmp",
        to.file_name().and_then(|n| n.to_str()).unwrap_or("run"),
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&tmp);
    if let Err(e) = link_or_copy_tree(from, &tmp) {
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(e)
            .with_context(|| format!("cannot copy {} to {}", from.display(), to.display()));
    }
    // Only what sparkout wrote there before; a directory still holding
    // other files is not replaced (the rename fails and says so).
    super::cache::remove_run_outputs(to);
    std::fs::rename(&tmp, to).with_context(|| {
        format!(
            "cannot put the shard's run at {} (a directory with files sparkout did not write is in the way?)",
            to.display()
        )
    })?;
    Ok(())
}

fn link_or_copy_tree(from: &Path, to: &Path) -> std::io::Result<()> {
    std::fs::create_dir_all(to)?;
    for e in std::fs::read_dir(from)? {
        let e = e?;
        let dst = to.join(e.file_name());
        let kind = e.file_type()?;
        if kind.is_symlink() {
            return Err(std::io::Error::other(format!(
                "{} is a symbolic link, which sparkout never writes in a run's outputs: remove it, or re-run the shard",
                e.path().display()
            )));
        } else if kind.is_dir() {
            link_or_copy_tree(&e.path(), &dst)?;
        } else if std::fs::hard_link(e.path(), &dst).is_err() {
            std::fs::copy(e.path(), dst)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn run_dirs_are_linked_and_a_rerun_shard_leaves_them_alone() {
        let root = std::env::temp_dir().join(format!("sparkout-link-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let from = root.join("shard/m/r1");
        std::fs::create_dir_all(from.join("plots")).unwrap();
        std::fs::write(from.join("report.json"), b"night 1").unwrap();
        std::fs::write(from.join("plots/a.svg"), b"<svg/>").unwrap();
        let to = root.join("agg/m/r1");
        copy_run_dir(&from, &to).unwrap();
        assert_eq!(std::fs::read(to.join("report.json")).unwrap(), b"night 1");
        assert_eq!(std::fs::read(to.join("plots/a.svg")).unwrap(), b"<svg/>");
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            let ino = |p: &Path| std::fs::metadata(p).unwrap().ino();
            assert_eq!(ino(&from.join("report.json")), ino(&to.join("report.json")));
        }
        // The shard re-run writes as sparkout does (a new file renamed over
        // the old): the aggregate keeps what it gathered.
        sparkout_core::files::write::write_atomic(&from.join("report.json"), b"night 2").unwrap();
        assert_eq!(std::fs::read(to.join("report.json")).unwrap(), b"night 1");
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn shard_specs_are_checked() {
        assert!(ShardSpec::parse("0/4", Balance::Hash).is_ok());
        assert!(ShardSpec::parse("3/4", Balance::Hash).is_ok());
        for bad in ["4/4", "1/0", "x/2", "2", "-1/3"] {
            assert!(ShardSpec::parse(bad, Balance::Hash).is_err(), "{bad}");
        }
    }

    #[test]
    fn every_run_lands_in_exactly_one_shard() {
        let dirs: Vec<PathBuf> = (0..200)
            .map(|i| PathBuf::from(format!("/nonexistent/m{}/r{i:04}", i % 3)))
            .collect();
        for balance in [Balance::Hash, Balance::Size] {
            let mut all: Vec<PathBuf> = Vec::new();
            let mut sizes = Vec::new();
            for index in 0..4 {
                let s = ShardSpec {
                    index,
                    count: 4,
                    balance,
                };
                let mine = select_runs(&dirs, &s);
                sizes.push(mine.len());
                all.extend(mine);
            }
            all.sort();
            let mut want = dirs.clone();
            want.sort();
            assert_eq!(all, want, "{balance:?}");
            // 200 runs over 4 shards: none empty, none with half of them.
            assert!(sizes.iter().all(|&n| n > 20 && n < 100), "{sizes:?}");
        }
    }
}

//! The night's input snapshot: the run set listed when the night starts.
//!
//! Shards of one night may start minutes apart while runs keep arriving.
//! Without a common list, a shard started later sees more runs than one
//! started earlier and `aggregate` must refuse the night as "different
//! inputs". `sparkout snapshot --input DIR --out FILE` lists the night's
//! runs once; every `run --snapshot FILE` (sharded or not) processes exactly
//! that list: runs that arrived later are left for the next night (and
//! said so), a listed run that has gone is a failure of the night.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use crate::{bail, Context};
use serde::{Deserialize, Serialize};

use crate::contracts::{write_json_atomic, Discovery, Skipped};
use crate::error::Result;

/// The version of a snapshot file.
pub const SNAPSHOT_VERSION: u32 = 1;

/// A night's run set, paths relative to the input root with `/`
/// separators (so nodes that staged the input into different directories
/// agree).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NightSnapshot {
    pub version: u32,
    pub kind: String,
    /// The input as given (a directory or a bucket URL): for the reader.
    pub input: String,
    /// Run directories (with a run.toml), sorted.
    pub runs: Vec<String>,
    /// Directories discovery listed without processing them (no run.toml,
    /// unreadable, a link leading outside): each is a failure of the night.
    pub listed: Vec<String>,
}

/// `p` relative to `root`, `/`-separated ("." for the root itself).
pub fn relative(root: &Path, p: &Path) -> String {
    let rel = p.strip_prefix(root).unwrap_or(p);
    let parts: Vec<String> = rel
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    if parts.is_empty() {
        ".".to_string()
    } else {
        parts.join("/")
    }
}

impl NightSnapshot {
    /// The snapshot of what discovery found under `root`.
    pub fn of(input: &str, root: &Path, found: &Discovery) -> NightSnapshot {
        let mut runs: Vec<String> = found.runs.iter().map(|r| relative(root, r)).collect();
        let mut listed: Vec<String> = found
            .skipped
            .iter()
            .map(|s| relative(root, &s.dir))
            .collect();
        runs.sort();
        runs.dedup();
        listed.sort();
        listed.dedup();
        NightSnapshot {
            version: SNAPSHOT_VERSION,
            kind: "sparkout.snapshot".into(),
            input: input.to_string(),
            runs,
            listed,
        }
    }

    pub fn write(&self, path: &Path) -> Result<()> {
        write_json_atomic(path, self)
    }

    pub fn read(path: &Path) -> Result<NightSnapshot> {
        let bytes = std::fs::read(path).with_context(|| {
            format!(
                "cannot read the night's snapshot {} (write it with `sparkout snapshot --input DIR --out {}` when the night starts)",
                path.display(),
                path.display()
            )
        })?;
        let s: NightSnapshot = serde_json::from_slice(&bytes)
            .with_context(|| format!("{}: not a sparkout night snapshot", path.display()))?;
        if s.kind != "sparkout.snapshot" || s.version != SNAPSHOT_VERSION {
            bail!(
                "{}: a {} file of version {} (this sparkout reads sparkout.snapshot version {SNAPSHOT_VERSION})",
                path.display(),
                s.kind,
                s.version
            );
        }
        for p in s.runs.iter().chain(&s.listed) {
            if p.split('/').any(|c| c == ".." || c.is_empty()) || p.starts_with('/') {
                bail!(
                    "{}: `{p}` is not a path below the input (no `..`, no absolute path)",
                    path.display()
                );
            }
        }
        Ok(s)
    }

    /// Discovery restricted to this snapshot: what it lists and discovery
    /// found is kept; a listed run that has gone becomes a listed
    /// (skipped) directory, so the night names it as a failure; runs found
    /// but not listed arrived after the night started and are returned
    /// apart, for the next night.
    pub fn restrict(
        &self,
        root: &Path,
        found: Discovery,
        file: &Path,
    ) -> (Discovery, Vec<PathBuf>) {
        let runs: BTreeSet<&str> = self.runs.iter().map(String::as_str).collect();
        let listed: BTreeSet<&str> = self.listed.iter().map(String::as_str).collect();
        let mut late = Vec::new();
        let mut seen = BTreeSet::new();
        let mut kept = Discovery::default();
        for r in found.runs {
            let rel = relative(root, &r);
            if runs.contains(rel.as_str()) {
                seen.insert(rel);
                kept.runs.push(r);
            } else {
                late.push(r);
            }
        }
        for s in found.skipped {
            let rel = relative(root, &s.dir);
            if listed.contains(rel.as_str()) || runs.contains(rel.as_str()) {
                seen.insert(rel);
                kept.skipped.push(s);
            }
        }
        for gone in runs.iter().chain(&listed) {
            if !seen.contains(*gone) {
                let dir = if *gone == "." {
                    root.to_path_buf()
                } else {
                    root.join(gone)
                };
                kept.skipped.push(Skipped {
                    file: dir.join("run.toml"),
                    dir,
                    why: format!(
                        "listed in the night's snapshot {} but no longer under the input (moved or deleted after the night started)",
                        file.display()
                    ),
                });
            }
        }
        kept.skipped.sort();
        (kept, late)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn found(root: &Path, runs: &[&str], skipped: &[&str]) -> Discovery {
        Discovery {
            runs: runs.iter().map(|r| root.join(r)).collect(),
            skipped: skipped
                .iter()
                .map(|s| Skipped {
                    dir: root.join(s),
                    file: root.join(s),
                    why: "no run.toml".into(),
                })
                .collect(),
        }
    }

    #[test]
    fn a_snapshot_keeps_its_runs_leaves_late_ones_and_names_gone_ones() {
        let root = Path::new("/in");
        let snap = NightSnapshot::of("/in", root, &found(root, &["m/b", "m/a"], &["m/x"]));
        assert_eq!(snap.runs, vec!["m/a", "m/b"]);
        assert_eq!(snap.listed, vec!["m/x"]);
        // Later: m/a gone, m/c arrived, m/x still listed.
        let (kept, late) = snap.restrict(
            root,
            found(root, &["m/b", "m/c"], &["m/x"]),
            Path::new("snap.json"),
        );
        assert_eq!(kept.runs, vec![root.join("m/b")]);
        assert_eq!(late, vec![root.join("m/c")]);
        let gone: Vec<_> = kept.skipped.iter().map(|s| s.dir.clone()).collect();
        assert_eq!(gone, vec![root.join("m/a"), root.join("m/x")]);
        assert!(
            kept.skipped[0].why.contains("snap.json"),
            "{:?}",
            kept.skipped[0]
        );
    }

    #[test]
    fn relative_paths_are_slash_separated_and_the_root_is_a_dot() {
        assert_eq!(relative(Path::new("/a"), Path::new("/a/b/c")), "b/c");
        assert_eq!(relative(Path::new("/a"), Path::new("/a")), ".");
    }

    #[test]
    fn a_snapshot_naming_a_path_outside_the_input_is_refused() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("s.json");
        let mut s = NightSnapshot::of("x", Path::new("/in"), &Discovery::default());
        s.runs.push("../elsewhere".into());
        s.write(&p).unwrap();
        let e = NightSnapshot::read(&p).unwrap_err().to_string();
        assert!(e.contains("not a path below the input"), "{e}");
    }
}

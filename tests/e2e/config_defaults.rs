//! configs/nightly.toml against the code's defaults (issue 14 item 2): the
//! values nightly.toml writes for a stage must be what the stage does with no
//! section at all, or the two silently disagree. A small fleet of every
//! generator is run twice — with the built-in nightly.toml and with a config
//! that has no stage sections — and every per-run artifact and summary must
//! be byte-identical. A third run that changes one value proves the
//! comparison sees a difference.

use crate::common::sparkout;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

fn ok(out: &std::process::Output) {
    assert!(
        out.status.success(),
        "exit {:?}\nstdout:\n{}\nstderr:\n{}",
        out.status.code(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Every per-run stage output (artifacts and summaries) under `out`, by
/// path relative to it; caches, manifests and fleet outputs left out (they
/// hold the config's cache keys or depend on them only through these).
fn stage_outputs(out: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut files = BTreeMap::new();
    let mut stack = vec![out.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            let rel = p.strip_prefix(out).unwrap().to_path_buf();
            if p.is_dir() {
                if rel != Path::new("fleet") {
                    stack.push(p);
                }
                continue;
            }
            let name = p.file_name().unwrap().to_string_lossy().to_string();
            let top_level = rel.components().count() == 1;
            if !top_level
                && (name.ends_with(".parquet") || name.ends_with(".json"))
                && !name.starts_with(".sparkout")
            {
                files.insert(rel, std::fs::read(&p).unwrap());
            }
        }
    }
    files
}

fn differing(a: &BTreeMap<PathBuf, Vec<u8>>, b: &BTreeMap<PathBuf, Vec<u8>>) -> Vec<String> {
    let mut d: Vec<String> = a
        .iter()
        .filter(|(k, v)| b.get(*k) != Some(*v))
        .map(|(k, _)| k.display().to_string())
        .collect();
    d.extend(
        b.keys()
            .filter(|k| !a.contains_key(*k))
            .map(|k| k.display().to_string()),
    );
    d
}

#[test]
fn nightly_toml_writes_the_code_defaults() {
    let dir = tempfile::tempdir().unwrap();
    let runs = dir.path().join("runs");
    for g in sparkout_datasets::all_generators() {
        if g.demo().is_none() {
            continue;
        }
        let mut args = vec!["generate", g.name(), "--runs", "2", "--seed", "3"];
        args.extend(["--out", runs.to_str().unwrap()]);
        if g.name() == "robot" {
            args.extend(["--ae-rate-hz", "100000"]);
        }
        ok(&sparkout(&args));
    }
    // nightly.toml without any plugin's stage sections.
    let mut bare: toml::Table = sparkout_pipeline::engine::config::NIGHTLY_TOML
        .parse()
        .unwrap();
    let plugins: Vec<&str> = sparkout_plugins::all_plugins()
        .iter()
        .map(|p| p.name())
        .collect();
    let mut removed = 0;
    for p in &plugins {
        removed += bare.remove(*p).is_some() as usize;
    }
    assert!(
        removed >= 4,
        "nightly.toml has sections of {removed} plugins"
    );
    let bare_path = dir.path().join("bare.toml");
    std::fs::write(&bare_path, toml::to_string(&bare).unwrap()).unwrap();

    let run = |out: &str, extra: &[&str]| -> BTreeMap<PathBuf, Vec<u8>> {
        let out = dir.path().join(out);
        let mut args = vec!["run", "--input", runs.to_str().unwrap()];
        args.extend(["--out", out.to_str().unwrap()]);
        args.extend(extra);
        ok(&sparkout(&args));
        stage_outputs(&out)
    };
    let nightly = run("nightly", &[]);
    let defaults = run("defaults", &["--config", bare_path.to_str().unwrap()]);
    assert!(nightly.len() > 50, "{} stage outputs", nightly.len());
    let d = differing(&nightly, &defaults);
    assert!(
        d.is_empty(),
        "nightly.toml and the code's defaults disagree: these outputs differ: {d:?}"
    );
    // The comparison sees a changed value.
    let changed = run(
        "changed",
        &[
            "--config",
            bare_path.to_str().unwrap(),
            "--set",
            "gantry.polish_plan.tolerance_mm=0.002",
        ],
    );
    let d = differing(&defaults, &changed);
    assert!(
        d.iter().any(|f| f.contains("polish_plan")),
        "changing tolerance_mm changed nothing: {d:?}"
    );
}

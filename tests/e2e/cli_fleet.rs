//! End to end through the `sparkout` binary: cache, config-key invalidation,
//! determinism, isolation, atomicity, validate-input, exit codes.

use crate::common;
use common::sparkout;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn ok(out: &Output) -> String {
    let s = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        out.status.success(),
        "exit {:?}\nstdout:\n{s}\nstderr:\n{}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
    s
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// A small generated robot fleet (low AE rate keeps it fast in debug).
fn fleet(dir: &Path, runs: usize, seed: u64) -> PathBuf {
    let root = dir.join("runs");
    ok(&sparkout(&[
        "generate",
        "robot",
        "--runs",
        &runs.to_string(),
        "--seed",
        &seed.to_string(),
        "--out",
        p(&root),
        "--ae-rate-hz",
        "100000",
    ]));
    root
}

fn manifest(out: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(out.join("manifest.json")).unwrap()).unwrap()
}

/// Every file under `dir` (relative path → bytes), skipping the manifest and
/// cache bookkeeping (they record cached/computed, which differs by design).
fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(base: &Path, d: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for e in std::fs::read_dir(d).unwrap() {
            let e = e.unwrap().path();
            if e.is_dir() {
                walk(base, &e, out);
            } else {
                let rel = e.strip_prefix(base).unwrap().to_string_lossy().to_string();
                if rel.ends_with("manifest.json") || rel.ends_with(".sparkout-cache.json") {
                    continue;
                }
                out.insert(rel, std::fs::read(&e).unwrap());
            }
        }
    }
    let mut m = BTreeMap::new();
    walk(dir, dir, &mut m);
    m
}

fn stage_cached(m: &serde_json::Value) -> BTreeMap<String, bool> {
    let mut out = BTreeMap::new();
    for r in m["runs"].as_array().unwrap() {
        for s in r["stages"].as_array().unwrap() {
            out.insert(
                format!(
                    "{}/{}",
                    r["run"].as_str().unwrap(),
                    s["stage"].as_str().unwrap()
                ),
                s["cached"].as_bool().unwrap(),
            );
        }
    }
    for s in m["fleet"].as_array().unwrap() {
        out.insert(
            format!("fleet/{}", s["stage"].as_str().unwrap()),
            s["cached"].as_bool().unwrap(),
        );
    }
    out
}

#[test]
fn second_run_is_fully_cached_and_one_key_recomputes_only_its_readers() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), 3, 11);
    let out = d.path().join("out");
    let first = ok(&sparkout(&["run", "--input", p(&root), "--out", p(&out)]));
    assert!(first.contains("3 runs ok, 0 rejected"), "{first}");
    for f in [
        "manifest.json",
        "failures.json",
        "fleet/report.html",
        "fleet/diagnosis.json",
        "fleet/observations.parquet",
    ] {
        assert!(out.join(f).is_file(), "missing {f}");
    }
    let failures: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("failures.json")).unwrap()).unwrap();
    assert_eq!(failures, serde_json::json!([]));

    let second = ok(&sparkout(&["run", "--input", p(&root), "--out", p(&out)]));
    assert!(second.contains("0 computed"), "{second}");
    assert!(second.contains("everything cached"), "{second}");
    let m = manifest(&out);
    assert_eq!(m["stages_computed"], 0);
    assert!(stage_cached(&m).values().all(|c| *c));

    // One key of one stage: that stage and what reads its outputs recompute,
    // nothing upstream of it does.
    ok(&sparkout(&[
        "run",
        "--input",
        p(&root),
        "--out",
        p(&out),
        "--set",
        "robot.datum.reject_k=5.5",
    ]));
    let c = stage_cached(&manifest(&out));
    for run in ["r0000", "r0001", "r0002"] {
        assert!(c[&format!("{run}/ingest")], "ingest should stay cached");
        assert!(
            c[&format!("{run}/repeatability")],
            "repeatability should stay cached"
        );
        assert!(c[&format!("{run}/cycle")], "cycle should stay cached");
        assert!(!c[&format!("{run}/datum")], "datum reads the changed key");
    }
}

#[test]
fn same_seed_gives_byte_identical_artifacts() {
    let d = tempfile::tempdir().unwrap();
    let a = fleet(&d.path().join("a"), 2, 5);
    let b = fleet(&d.path().join("b"), 2, 5);
    assert_eq!(files(&a), files(&b), "generated fleets differ");
    let (oa, ob) = (d.path().join("oa"), d.path().join("ob"));
    ok(&sparkout(&[
        "run",
        "--input",
        p(&a),
        "--out",
        p(&oa),
        "--jobs",
        "1",
    ]));
    ok(&sparkout(&[
        "run",
        "--input",
        p(&b),
        "--out",
        p(&ob),
        "--jobs",
        "2",
    ]));
    let (fa, fb) = (files(&oa), files(&ob));
    assert_eq!(fa.keys().collect::<Vec<_>>(), fb.keys().collect::<Vec<_>>());
    for (k, v) in &fa {
        if k.ends_with("report.html") {
            continue; // reports name the input paths, which differ here
        }
        assert!(v == &fb[k], "{k} differs between identical runs");
    }
    let c = fleet(&d.path().join("c"), 2, 6);
    assert_ne!(
        files(&a),
        files(&c),
        "a different seed must give different data"
    );
}

#[test]
fn one_bad_run_is_isolated_and_named() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), 3, 21);
    // Break r0001: its plan names a face that does not exist... simplest
    // contract break: a truncated motion log.
    let bad = root.join("kr16-lab").join("r0001");
    let motion = bad.join("motion.parquet");
    let bytes = std::fs::read(&motion).unwrap();
    std::fs::write(&motion, &bytes[..bytes.len() / 3]).unwrap();
    // And r0002 claims an unknown plugin.
    let toml = root.join("kr16-lab").join("r0002").join("run.toml");
    let text = std::fs::read_to_string(&toml)
        .unwrap()
        .replace("plugin = \"robot\"", "plugin = \"lathe\"");
    std::fs::write(&toml, text).unwrap();

    let out = d.path().join("out");
    let o = sparkout(&["run", "--input", p(&root), "--out", p(&out)]);
    assert_eq!(
        o.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let failures: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("failures.json")).unwrap()).unwrap();
    let f = failures.as_array().unwrap();
    assert_eq!(f.len(), 2, "{failures:#}");
    let by_run: BTreeMap<&str, &serde_json::Value> =
        f.iter().map(|x| (x["run"].as_str().unwrap(), x)).collect();
    assert!(by_run["r0001"]["file"]
        .as_str()
        .unwrap()
        .ends_with("motion.parquet"));
    assert!(by_run["r0002"]["error"]
        .as_str()
        .unwrap()
        .contains("unknown plugin `lathe`"));
    assert!(out.join("kr16-lab/r0000/report.html").is_file());
    assert!(
        !out.join("kr16-lab/r0001").exists(),
        "nothing of a rejected run is written"
    );
    assert!(!out.join("kr16-lab/r0002").exists());
    assert!(out.join("manifest.json").is_file());

    // validate-input sees the same problems and writes nothing.
    let v = sparkout(&["validate-input", p(&root)]);
    assert_eq!(v.status.code(), Some(2));
    let text = String::from_utf8_lossy(&v.stdout);
    assert!(text.contains("motion.parquet"), "{text}");
    assert!(text.contains("lathe"), "{text}");
}

#[test]
fn validate_input_is_clean_on_a_generated_fleet() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), 2, 3);
    let v = sparkout(&["validate-input", p(&root)]);
    let s = ok(&v);
    assert!(s.contains("2 runs checked: 2 clean"), "{s}");
}

#[test]
fn a_killed_batch_leaves_only_complete_artifacts() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), 4, 8);
    let out = d.path().join("out");
    for delay_ms in [150u64, 400, 900] {
        let mut child = Command::new(env!("CARGO_BIN_EXE_sparkout"))
            .args(["run", "--input", p(&root), "--out", p(&out)])
            .env("SPARKOUT_LOG", "warn")
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(delay_ms));
        let _ = child.kill();
        let _ = child.wait();
        // Every artifact under its final name is complete.
        for (rel, bytes) in files(&out) {
            if rel.ends_with(".parquet") {
                assert!(
                    bytes.len() > 8 && &bytes[bytes.len() - 4..] == b"PAR1",
                    "{rel} is truncated"
                );
                sparkout_pipeline::contracts::read_parquet(&out.join(&rel)).unwrap();
            }
            if rel.ends_with(".json") {
                serde_json::from_slice::<serde_json::Value>(&bytes)
                    .unwrap_or_else(|e| panic!("{rel} is not complete JSON: {e}"));
            }
        }
    }
    // And the batch resumes to a correct, complete result.
    let s = ok(&sparkout(&["run", "--input", p(&root), "--out", p(&out)]));
    assert!(s.contains("4 runs ok"), "{s}");
}

#[test]
fn usage_and_config_errors_exit_1() {
    let o = sparkout(&[
        "run",
        "--input",
        "/nonexistent",
        "--out",
        "/tmp/x",
        "--set",
        "robot.nostage.k=1",
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("nostage"));
    let o = sparkout(&["frobnicate"]);
    assert_eq!(o.status.code(), Some(1));
    let o = sparkout(&["--help"]);
    assert_eq!(o.status.code(), Some(0));
}

/// Every generator's runs carry a valid, increasing `[run].started` past a
/// day of runs: a form fleet's clock once counted hours past 23 (run 54 of
/// a 100-run fleet started at "24:00", and 46 of its runs were rejected),
/// a guide-way's, a gantry's and a mill's wrapped back to their first start.
#[test]
fn generated_runs_start_at_valid_increasing_times_past_a_day() {
    let d = tempfile::tempdir().unwrap();
    for (what, runs) in [
        ("form", "60"),
        ("guideway", "70"),
        ("gantry", "30"),
        ("mill", "290"),
    ] {
        let root = d.path().join(what);
        ok(&sparkout(&[
            "generate",
            what,
            "--runs",
            runs,
            "--seed",
            "1",
            "--out",
            p(&root),
        ]));
        let mut dirs = sparkout_pipeline::contracts::discover_runs(&root).unwrap();
        dirs.sort();
        assert_eq!(dirs.len().to_string(), runs, "{what}");
        let started: Vec<String> = dirs
            .iter()
            .map(|dir| {
                let spec = sparkout_pipeline::contracts::RunSpec::load(dir)
                    .unwrap_or_else(|e| panic!("{what}: {e}"));
                spec.started.clone().expect("a generated run has a start")
            })
            .collect();
        assert!(
            started.windows(2).all(|w| w[0] < w[1]),
            "{what}: starts not increasing: {started:?}"
        );
    }
}

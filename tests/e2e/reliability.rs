//! Nothing lost, nothing silent — every run accounted for, one
//! batch per --out, resumable per stage, bounded --jobs, `generate` that
//! does not overwrite, checked effect parameters.

use std::path::{Path, PathBuf};
use std::process::Output;

use crate::common::{sparkout, text};

/// A small guideway fleet (the quickest plugin to generate and run).
fn fleet(dir: &Path, runs: usize) -> PathBuf {
    let root = dir.join("runs");
    let g = sparkout(&[
        "generate",
        "guideway",
        "--runs",
        &runs.to_string(),
        "--seed",
        "5",
        "--out",
        root.to_str().unwrap(),
    ]);
    assert!(g.status.success(), "{}", text(&g));
    root
}

fn run_dirs(root: &Path) -> Vec<PathBuf> {
    sparkout_pipeline::contracts::discover_runs(root).unwrap()
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
    }
}

fn run(input: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "run",
        "--input",
        input.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend(extra);
    sparkout(&args)
}

fn failures(out: &Path) -> Vec<serde_json::Value> {
    serde_json::from_slice::<Vec<serde_json::Value>>(
        &std::fs::read(out.join("failures.json")).unwrap(),
    )
    .unwrap()
}

#[test]
fn duplicate_run_ids_are_rejected_naming_both_directories() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), 2);
    let first = &run_dirs(&root)[0];
    // Same run.toml (same machine and id) in a second directory.
    let twin = first.with_file_name("r0000-copy");
    copy_dir(first, &twin);
    for jobs in ["1", "2"] {
        let out = d.path().join(format!("out{jobs}"));
        let o = run(&root, &out, &["--jobs", jobs]);
        assert_eq!(o.status.code(), Some(2), "{}", text(&o));
        let f = failures(&out);
        let dup: Vec<&serde_json::Value> = f
            .iter()
            .filter(|x| x["error"].as_str().unwrap().contains("duplicate run id"))
            .collect();
        assert_eq!(dup.len(), 2, "--jobs {jobs}: {f:?}");
        for x in &dup {
            let e = x["error"].as_str().unwrap();
            assert!(
                e.contains(first.to_str().unwrap()) && e.contains(twin.to_str().unwrap()),
                "{e}"
            );
        }
        let s = String::from_utf8_lossy(&o.stdout);
        assert!(s.contains("1 runs ok, 2 rejected"), "{s}");
        // Neither twin's outputs exist: one would be the other's.
        let machine = dup[0]["machine"].as_str().unwrap();
        assert!(!out.join(machine).join("r0000").exists());
    }
    let v = sparkout(&["validate-input", root.to_str().unwrap()]);
    assert_eq!(v.status.code(), Some(2), "{}", text(&v));
    assert!(
        String::from_utf8_lossy(&v.stdout).contains("duplicate run id"),
        "{}",
        text(&v)
    );
}

#[test]
fn directory_without_run_toml_is_listed_as_skipped() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), 2);
    let first = &run_dirs(&root)[0];
    let orphan = first.with_file_name("r0099");
    copy_dir(first, &orphan);
    std::fs::remove_file(orphan.join("run.toml")).unwrap();
    let out = d.path().join("out");
    let o = run(&root, &out, &[]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let f = failures(&out);
    assert_eq!(f.len(), 1, "{f:?}");
    assert_eq!(f[0]["run_dir"].as_str(), orphan.to_str());
    let e = f[0]["error"].as_str().unwrap();
    assert!(e.contains("skipped") && e.contains("no run.toml"), "{e}");
    assert!(String::from_utf8_lossy(&o.stdout).contains("r0099"));
    let v = sparkout(&["validate-input", root.to_str().unwrap()]);
    assert_eq!(v.status.code(), Some(2), "{}", text(&v));
    assert!(String::from_utf8_lossy(&v.stdout).contains("no run.toml"));
    // An --out inside --input is refused before any work (a rejected run's
    // clean-up must never reach the input), and nothing is written there.
    let inner = root.join("out");
    std::fs::remove_dir_all(&orphan).unwrap();
    let o = run(&root, &inner, &[]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(text(&o).contains("is inside --input"), "{}", text(&o));
    assert!(!inner.exists());
}

#[test]
fn table_that_is_a_directory_rejects_the_run() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), 2);
    let first = &run_dirs(&root)[0];
    std::fs::create_dir_all(first.join("ae.parquet/part=0")).unwrap();
    let out = d.path().join("out");
    let o = run(&root, &out, &[]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let f = failures(&out);
    assert_eq!(f.len(), 1, "{f:?}");
    assert!(f[0]["file"].as_str().unwrap().ends_with("ae.parquet"));
    assert!(f[0]["error"].as_str().unwrap().contains("directory"));
}

#[test]
fn generate_refuses_to_overwrite_without_force() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), 2);
    let again = sparkout(&[
        "generate",
        "guideway",
        "--runs",
        "2",
        "--out",
        root.to_str().unwrap(),
    ]);
    assert_eq!(again.status.code(), Some(1), "{}", text(&again));
    assert!(String::from_utf8_lossy(&again.stderr).contains("--force"));
    // Another plugin into the same root is a mixed fleet, not an overwrite.
    let mill = sparkout(&[
        "generate",
        "mill",
        "--runs",
        "1",
        "--out",
        root.to_str().unwrap(),
    ]);
    assert!(mill.status.success(), "{}", text(&mill));
    let forced = sparkout(&[
        "generate",
        "guideway",
        "--runs",
        "2",
        "--out",
        root.to_str().unwrap(),
        "--force",
    ]);
    assert!(forced.status.success(), "{}", text(&forced));
    let obs = d.path().join("obs.parquet");
    let args = ["generate", "observations", "--runs", "2", "--out"];
    let mut a: Vec<&str> = args.to_vec();
    a.push(obs.to_str().unwrap());
    assert!(sparkout(&a).status.success());
    let o = sparkout(&a);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    a.push("--force");
    assert!(sparkout(&a).status.success());
}

#[test]
fn effect_parameters_must_be_finite_and_in_range() {
    let d = tempfile::tempdir().unwrap();
    for bad in [
        "drift:t_s=amplitude_mm=nan",
        "drift:t_s=amplitude_mm=inf",
        "drift:t_s=tau_s=0",
        "offset=offset_mm=1e300",
    ] {
        let obs = d.path().join("obs.parquet");
        let o = sparkout(&[
            "generate",
            "observations",
            "--runs",
            "2",
            "--out",
            obs.to_str().unwrap(),
            "--effect",
            bad,
        ]);
        assert_eq!(o.status.code(), Some(1), "{bad}: {}", text(&o));
        assert!(!obs.exists(), "{bad} wrote a file");
    }
}

#[test]
fn jobs_is_clamped_to_the_cores() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), 1);
    let o = run(&root, &d.path().join("out"), &["--jobs", "100000"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("cores available"),
        "{}",
        text(&o)
    );
}

#[test]
fn one_batch_per_out_and_stale_locks_are_taken_over() {
    use sparkout_pipeline::engine::lock::{host_name, BatchLock, LOCK_FILE};
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), 1);
    let out = d.path().join("out");
    // A live batch: this test process holds the lock.
    let held = BatchLock::acquire(&out).unwrap();
    let o = run(&root, &out, &[]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("another sparkout batch") && e.contains(&std::process::id().to_string()),
        "{e}"
    );
    assert!(!out.join("manifest.json").exists());
    drop(held);
    // A killed batch's lock file (nobody holds the lock): taken over.
    std::fs::write(
        out.join(LOCK_FILE),
        format!(
            "pid=4294967295
host={}
",
            host_name()
        ),
    )
    .unwrap();
    let o = run(&root, &out, &[]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    assert!(String::from_utf8_lossy(&o.stderr).contains("no longer running"));
    assert!(!out.join(LOCK_FILE).exists(), "lock released at the end");
    // A holder killed with SIGKILL and not yet reaped (a zombie): its lock
    // is free at once, no waiting for the reaper.
    let mut holder = std::process::Command::new("flock")
        .args([
            "-x",
            "-o",
            out.join(LOCK_FILE).to_str().unwrap(),
            "sleep",
            "60",
        ])
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(300));
    let o = run(&root, &out, &[]);
    assert_eq!(o.status.code(), Some(1), "held by flock: {}", text(&o));
    holder.kill().unwrap(); // SIGKILL; not waited for: a zombie
    std::thread::sleep(std::time::Duration::from_millis(100));
    let o = run(&root, &out, &[]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    holder.wait().unwrap();
    // A lock written on another host is never taken over automatically.
    std::fs::write(out.join(LOCK_FILE), "pid=1\nhost=elsewhere.example\n").unwrap();
    let o = run(&root, &out, &[]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(
        text(&o).contains("never taken over automatically"),
        "{}",
        text(&o)
    );
}

#[test]
fn killed_batch_resumes_per_stage_and_leaves_no_temp_files() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), 1);
    let out = d.path().join("out");
    // Like a kill -9 right after the first stage of the run completed.
    let killed = std::process::Command::new(env!("CARGO_BIN_EXE_sparkout"))
        .args([
            "run",
            "--input",
            root.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .env("SPARKOUT_LOG", "warn")
        .env("SPARKOUT_FAULT_ABORT_AFTER_STAGE", "separate")
        .output()
        .unwrap();
    assert!(!killed.status.success(), "{}", text(&killed));
    let run_out = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.is_dir() && p.file_name().unwrap() != "fleet")
        .expect("the machine's output dir")
        .join("r0000");
    assert!(run_out.join("separate.json").is_file());
    // A temp file a kill left behind mid-write.
    let orphan = run_out.join(".predictor.parquet.4242.tmp");
    std::fs::write(&orphan, b"half a file").unwrap();
    let o = run(&root, &out, &[]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let s = String::from_utf8_lossy(&o.stdout);
    assert!(
        !s.contains(", 0 cached"),
        "the completed stage was recomputed: {s}"
    );
    assert!(!orphan.exists(), "orphaned temp file left behind");
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("manifest.json")).unwrap()).unwrap();
    let stages = manifest["runs"][0]["stages"].as_array().unwrap();
    let sep = stages.iter().find(|s| s["stage"] == "separate").unwrap();
    assert_eq!(sep["cached"], true, "{stages:?}");
    assert!(stages
        .iter()
        .filter(|s| s["stage"] != "separate")
        .all(|s| s["cached"] == false));
}

/// The replay example of docs/replay.md works on generated robot runs (their motion
/// stays inside the default envelope), impossible fault specs are refused,
/// and the default binary says how to get SocketCAN.
#[test]
fn replay_as_documented() {
    let d = tempfile::tempdir().unwrap();
    let root = d.path().join("runs");
    let g = sparkout(&[
        "generate",
        "robot",
        "--runs",
        "2",
        "--seed",
        "1",
        "--ae-rate-hz",
        "200000",
        "--out",
        root.to_str().unwrap(),
    ]);
    assert!(g.status.success(), "{}", text(&g));
    for run in run_dirs(&root) {
        let o = sparkout(&["replay", "--run", run.to_str().unwrap(), "--bus", "sim"]);
        assert_eq!(o.status.code(), Some(0), "{}: {}", run.display(), text(&o));
    }
    let run = run_dirs(&root)[0].clone();
    let run_s = run.to_str().unwrap();
    for (fault, needle) in [
        ("emcy@1s:9", "not one of the drives"),
        ("heartbeat@1s:4", "not one of the drives"),
        ("emcy@99999s", "after the end"),
        ("sigint@99999s", "after the end"),
    ] {
        let o = sparkout(&[
            "replay",
            "--run",
            run_s,
            "--bus",
            "sim",
            "--sim-fault",
            fault,
        ]);
        assert_eq!(o.status.code(), Some(1), "{fault}: {}", text(&o));
        assert!(
            String::from_utf8_lossy(&o.stderr).contains(needle),
            "{fault}: {}",
            text(&o)
        );
    }
    if !cfg!(feature = "socketcan") {
        let o = sparkout(&["replay", "--run", run_s, "--bus", "socketcan:can0"]);
        assert_eq!(o.status.code(), Some(1), "{}", text(&o));
        assert!(
            String::from_utf8_lossy(&o.stderr).contains("--features socketcan"),
            "{}",
            text(&o)
        );
    }
}

/// Config typos are errors naming the key and what is known (item 3).
#[test]
fn config_typos_are_never_silent() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), 1);
    let out = d.path().join("out");
    for (set, needle) in [
        ("guidewy.separate.method=lsq", "unknown section `guidewy`"),
        ("robotx.ingest.k_sigma=8", "unknown section `robotx`"),
        ("report.titel=x", "[report]: unknown key `titel`"),
        (
            "pipeline.stagez=[\"x\"]",
            "[pipeline]: unknown key `stagez`",
        ),
        // A wrong type is an error naming the key, not its default.
        ("report.title=5", "[report]: key `title`"),
        ("pipeline.stages=\"observe\"", "[pipeline]: key `stages`"),
        ("diagnose.folds=\"five\"", "[diagnose]: key `folds`"),
    ] {
        let o = run(&root, &out, &["--set", set]);
        assert_eq!(o.status.code(), Some(1), "{set}: {}", text(&o));
        assert!(
            String::from_utf8_lossy(&o.stderr).contains(needle),
            "{set}: {}",
            text(&o)
        );
    }
    let cfg = d.path().join("nightly.toml");
    std::fs::write(&cfg, "[robotx.ingest]\nk_sigma = 8\n").unwrap();
    let o = run(&root, &out, &["--config", cfg.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(String::from_utf8_lossy(&o.stderr).contains("robotx"));
}

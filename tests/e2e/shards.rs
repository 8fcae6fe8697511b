//! `sparkout run --shard i/n` + `sparkout aggregate` give
//! the same fleet outputs, byte for byte, as one `sparkout run`; a killed
//! shard resumes from its cache; bad shard sets are refused by name.

use std::path::{Path, PathBuf};
use std::process::Output;

use super::common::{ok, sparkout};

const FLEET_OUTPUTS: [&str; 7] = [
    "fleet/observations.parquet",
    "fleet/diagnosis.json",
    "fleet/diagnosis.parquet",
    "fleet/report.html",
    "index.html",
    "failures.json",
    "manifest.json",
];

/// Two machine types, so the partition and the join cross plugins.
fn fleet(dir: &Path) -> PathBuf {
    let root = dir.join("runs");
    let r = root.to_str().unwrap();
    ok(sparkout(&[
        "generate",
        "servo",
        "--runs",
        "4",
        "--seed",
        "3",
        "--out",
        r,
        "--effect",
        "servo_lag=k_s=0.004",
    ]));
    ok(sparkout(&[
        "generate", "mill", "--runs", "3", "--seed", "4", "--out", r,
    ]));
    root
}

fn shard(root: &Path, out: &Path, spec: &str, extra: &[&str]) -> Output {
    let mut args = vec![
        "run",
        "--input",
        root.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--shard",
        spec,
    ];
    args.extend(extra);
    sparkout(&args)
}

fn aggregate(shards: &[PathBuf], out: &Path) -> Output {
    let mut args = vec!["aggregate", "--out", out.to_str().unwrap(), "--shards"];
    args.extend(shards.iter().map(|s| s.to_str().unwrap()));
    sparkout(&args)
}

fn read_outputs(out: &Path) -> Vec<(String, Vec<u8>)> {
    FLEET_OUTPUTS
        .iter()
        .map(|f| {
            let bytes = std::fs::read(out.join(f)).unwrap_or_else(|e| panic!("{f}: {e}"));
            (f.to_string(), bytes)
        })
        .collect()
}

fn assert_same(a: &[(String, Vec<u8>)], b: &[(String, Vec<u8>)], what: &str) {
    for ((name, x), (_, y)) in a.iter().zip(b) {
        assert!(x == y, "{name} differs: {what}");
    }
}

#[test]
fn one_shard_four_shards_and_a_plain_run_write_identical_fleet_outputs() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path());
    // Every variant writes to the same --out (paths appear in the outputs).
    let out = d.path().join("out");
    ok(sparkout(&[
        "run",
        "--input",
        root.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]));
    let plain = read_outputs(&out);
    std::fs::remove_dir_all(&out).unwrap();

    let one = d.path().join("one");
    ok(shard(&root, &one, "0/1", &[]));
    ok(aggregate(std::slice::from_ref(&one), &out));
    assert_same(&plain, &read_outputs(&out), "1 shard vs plain run");
    std::fs::remove_dir_all(&out).unwrap();

    for balance in ["hash", "size"] {
        let shards: Vec<PathBuf> = (0..4)
            .map(|i| d.path().join(format!("{balance}{i}")))
            .collect();
        let mut runs = 0;
        for (i, s) in shards.iter().enumerate() {
            let text = ok(shard(&root, s, &format!("{i}/4"), &["--balance", balance]));
            assert!(s.join("shard.json").is_file());
            assert!(!s.join("fleet").exists(), "a shard runs no fleet step");
            let m: serde_json::Value =
                serde_json::from_slice(&std::fs::read(s.join("shard.json")).unwrap()).unwrap();
            runs += m["runs"].as_array().unwrap().len();
            assert!(text.contains(&format!("shard {i}/4")), "{text}");
        }
        assert_eq!(runs, 7, "{balance}: every run in exactly one shard");
        ok(aggregate(&shards, &out));
        assert_same(
            &plain,
            &read_outputs(&out),
            &format!("4 shards ({balance}) vs plain run"),
        );
        std::fs::remove_dir_all(&out).unwrap();
    }
}

#[test]
fn a_killed_shard_resumes_from_its_cache() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path());
    let s0 = d.path().join("s0");
    // Like a kill -9 right after the first servo stage of a run completed.
    let killed = std::process::Command::new(env!("CARGO_BIN_EXE_sparkout"))
        .args([
            "run",
            "--input",
            root.to_str().unwrap(),
            "--out",
            s0.to_str().unwrap(),
            "--shard",
            "0/1",
            "--jobs",
            "1",
        ])
        .env("SPARKOUT_LOG", "warn")
        .env("SPARKOUT_FAULT_ABORT_AFTER_STAGE", "follow")
        .output()
        .unwrap();
    assert!(!killed.status.success());
    assert!(
        !s0.join("shard.json").exists(),
        "no shard.json after a kill"
    );
    let again = ok(shard(&root, &s0, "0/1", &[]));
    assert!(
        !again.contains(", 0 cached"),
        "the completed stage was recomputed: {again}"
    );
    let out = d.path().join("out");
    ok(aggregate(&[s0], &out));
    assert!(out.join("fleet/diagnosis.json").is_file());
}

#[test]
fn incomplete_or_mixed_shard_sets_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path());
    let (a, b, c) = (d.path().join("a"), d.path().join("b"), d.path().join("c"));
    ok(shard(&root, &a, "0/2", &[]));
    ok(shard(&root, &b, "1/2", &[]));
    ok(shard(&root, &c, "0/3", &[]));
    let out = d.path().join("out");
    let err = |o: Output| {
        assert!(!o.status.success());
        String::from_utf8_lossy(&o.stderr).to_string()
    };
    let e = err(aggregate(std::slice::from_ref(&a), &out));
    assert!(e.contains("missing shard(s) 1/2"), "{e}");
    let e = err(aggregate(&[a.clone(), a.clone(), b.clone()], &out));
    assert!(e.contains("appears twice"), "{e}");
    let e = err(aggregate(&[a.clone(), c.clone()], &out));
    assert!(e.contains("different splits"), "{e}");
    let e = err(aggregate(&[a.clone(), d.path().join("nowhere")], &out));
    assert!(e.contains("is not a finished shard"), "{e}");
    assert!(!out.exists(), "a refused aggregate left its output folder");
    let e = err(shard(&root, &a, "2/2", &[]));
    assert!(e.contains("0 ≤ i < n"), "{e}");
    assert!(!out.join("manifest.json").exists());
    // A shard another release made.
    let older = d.path().join("older");
    ok(shard(&root, &older, "0/2", &[]));
    let file = older.join("shard.json");
    let text = std::fs::read_to_string(&file).unwrap();
    let mut m: serde_json::Value = serde_json::from_str(&text).unwrap();
    m["sparkout_version"] = "0.0.1".into();
    std::fs::write(&file, serde_json::to_vec(&m).unwrap()).unwrap();
    let e = err(aggregate(&[older.clone(), b.clone()], &out));
    assert!(e.contains("sparkout 0.0.1") && e.contains("re-run"), "{e}");
    // An output inside a shard would mix with its files (around one too:
    // `names::check_out_apart` refuses both directions); the shard's own
    // directory is allowed (`aggregate --help`).
    let inside = a.join("agg");
    let e = err(aggregate(&[a.clone(), b.clone()], &inside));
    assert!(e.contains("--shards"), "{e}");
    assert!(!inside.join("manifest.json").exists());
    ok(aggregate(&[a.clone(), b.clone()], &a));
    assert!(a.join("manifest.json").is_file());
}

#[test]
fn shards_that_would_lose_or_double_a_run_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path());
    let out = d.path().join("out");
    let err = |o: Output| {
        assert!(!o.status.success());
        String::from_utf8_lossy(&o.stderr).to_string()
    };
    // Mixed balance: each split on its own is whole, together they are not.
    let (h0, s1) = (d.path().join("h0"), d.path().join("s1"));
    ok(shard(&root, &h0, "0/2", &["--balance", "hash"]));
    ok(shard(&root, &s1, "1/2", &["--balance", "size"]));
    let e = err(aggregate(&[h0.clone(), s1.clone()], &out));
    assert!(e.contains("--balance"), "{e}");
    // A stale shard: last night's shard 1, then a run arrives, tonight's
    // re-run of shard 1 is killed before it finishes.
    let s1 = d.path().join("n1");
    ok(shard(&root, &s1, "1/2", &[]));
    arrive(&root, "xfyz-mill/r0000", "r0099");
    let h0 = d.path().join("n0");
    ok(shard(&root, &h0, "0/2", &[]));
    let e = err(aggregate(&[h0.clone(), s1.clone()], &out));
    assert!(
        e.contains("saw different inputs") && e.contains("stale"),
        "{e}"
    );
    // The re-run removes the stale shard.json first: a kill leaves none.
    let killed = std::process::Command::new(env!("CARGO_BIN_EXE_sparkout"))
        .args(["run", "--input", root.to_str().unwrap(), "--out"])
        .arg(&s1)
        .args(["--shard", "1/2", "--jobs", "1"])
        .env("SPARKOUT_LOG", "warn")
        .env("SPARKOUT_FAULT_ABORT_AFTER_STAGE", "follow")
        .output()
        .unwrap();
    // Killed (by the fault injection) when this shard holds a servo run.
    if killed.status.code().is_none() {
        assert!(
            !s1.join("shard.json").exists(),
            "a stale shard.json survived"
        );
        let e = err(aggregate(&[h0.clone(), s1.clone()], &out));
        assert!(e.contains("is not a finished shard"), "{e}");
    }
    // Different machine configs between shards.
    let machines = d.path().join("machines");
    std::fs::create_dir_all(&machines).unwrap();
    let m1 = d.path().join("m1");
    ok(shard(
        &root,
        &m1,
        "1/2",
        &["--machines", machines.to_str().unwrap()],
    ));
    let e = err(aggregate(&[h0.clone(), m1.clone()], &out));
    assert!(e.contains("different machine configs"), "{e}");
    assert!(!out.join("manifest.json").exists());
}

/// A fleet under `dir` and its two shards `dir/a` (0/2) and `dir/b` (1/2).
fn two_shards(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let root = fleet(dir);
    let (a, b) = (dir.join("a"), dir.join("b"));
    ok(shard(&root, &a, "0/2", &[]));
    ok(shard(&root, &b, "1/2", &[]));
    (root, a, b)
}

/// A shard whose outputs changed after it ran: a run folder gone is
/// refused naming the shard, the run and what to re-run; a symbolic link
/// in a run folder is refused naming it, and nothing it points to is
/// carried into the output.
#[test]
fn a_shard_whose_run_outputs_were_tampered_with_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let (root, a, b) = two_shards(d.path());
    let out = d.path().join("out");
    let err = |o: Output| {
        assert!(!o.status.success());
        String::from_utf8_lossy(&o.stderr).to_string()
    };
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(a.join("shard.json")).unwrap()).unwrap();
    let first = &manifest["runs"][0];
    let (machine, run) = (
        first["machine"].as_str().unwrap(),
        first["run"].as_str().unwrap(),
    );
    let run_dir = a.join(machine).join(run);
    // A name that is a path, refused as the runs are gathered (the output
    // folder already made is removed again: it is empty).
    let renamed = d.path().join("renamed");
    ok(shard(&root, &renamed, "0/2", &[]));
    let file = renamed.join("shard.json");
    let mut m: serde_json::Value = serde_json::from_slice(&std::fs::read(&file).unwrap()).unwrap();
    m["runs"][0]["machine"] = "../escape".into();
    std::fs::write(&file, serde_json::to_vec(&m).unwrap()).unwrap();
    let e = err(aggregate(&[renamed, b.clone()], &out));
    assert!(e.contains("../escape") && e.contains("plain name"), "{e}");
    assert!(!out.exists(), "a refused aggregate left its output folder");
    // A link to a file outside the shard.
    let secret = d.path().join("secret.txt");
    std::fs::write(&secret, b"not for the bucket").unwrap();
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(&secret, run_dir.join("extra.txt")).unwrap();
        let e = err(aggregate(&[a.clone(), b.clone()], &out));
        assert!(
            e.contains("extra.txt") && e.contains("symbolic link") && e.contains("shard.json"),
            "{e}"
        );
        std::fs::remove_file(run_dir.join("extra.txt")).unwrap();
        let litter: Vec<PathBuf> = super::common::files_under(&out)
            .into_iter()
            .filter(|p| p.to_string_lossy().contains(".tmp"))
            .collect();
        assert!(
            litter.is_empty(),
            "a half-copied run left behind: {litter:?}"
        );
    }
    // The run folder gone.
    std::fs::remove_dir_all(&run_dir).unwrap();
    let e = err(aggregate(&[a.clone(), b.clone()], &out));
    assert!(
        e.contains(&format!("run {machine}/{run} is listed"))
            && e.contains("is missing")
            && e.contains("re-run shard 0/2"),
        "{e}"
    );
    assert!(!out.join("manifest.json").exists());
    let mut found = Vec::new();
    for e in super::common::files_under(&out) {
        if std::fs::read(&e).ok().as_deref() == Some(b"not for the bucket".as_slice()) {
            found.push(e);
        }
    }
    assert!(found.is_empty(), "carried into the output: {found:?}");
}

/// `aggregate` says which observable it is diagnosing (a large fleet's
/// take minutes each), in order, each once.
#[test]
fn aggregate_reports_each_observable_as_it_is_diagnosed() {
    let d = tempfile::tempdir().unwrap();
    let (_, a, b) = two_shards(d.path());
    let out = d.path().join("out");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_sparkout"))
        .args(["aggregate", "--out", out.to_str().unwrap(), "--shards"])
        .args([&a, &b])
        .env("SPARKOUT_LOG", "info")
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success() || o.status.code() == Some(2), "{log}");
    let diagnosis: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("fleet/diagnosis.json")).unwrap()).unwrap();
    let names: Vec<&str> = diagnosis["observables"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n.as_str().unwrap())
        .collect();
    let said: Vec<&str> = log
        .lines()
        .filter_map(|l| l.split("diagnosing the sim-to-real gap: ").nth(1))
        .collect();
    let want: Vec<String> = names
        .iter()
        .enumerate()
        .map(|(k, n)| format!("{n} ({} of {})", k + 1, names.len()))
        .collect();
    assert_eq!(said, want, "{log}");
}

/// Copies run `from` to a new run `id` beside it (a run arriving mid-night).
fn arrive(root: &Path, from: &str, id: &str) -> PathBuf {
    let first = root.join(from);
    let late = first.with_file_name(id);
    std::fs::create_dir_all(&late).unwrap();
    for e in std::fs::read_dir(&first).unwrap() {
        let e = e.unwrap().path();
        std::fs::copy(&e, late.join(e.file_name().unwrap())).unwrap();
    }
    let old = format!("\"{}\"", first.file_name().unwrap().to_str().unwrap());
    let t = std::fs::read_to_string(late.join("run.toml")).unwrap();
    std::fs::write(late.join("run.toml"), t.replace(&old, &format!("\"{id}\""))).unwrap();
    late
}

/// The night's snapshot: shards started before and after a run arrives
/// partition the same run set, the late run is left for the next night,
/// and the result equals one node over the snapshot; a shard.json whose
/// share overlaps another's is refused naming the run.
#[test]
fn shards_of_one_snapshot_agree_however_late_they_start() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path());
    let snap = d.path().join("night.json");
    let text = ok(sparkout(&[
        "snapshot",
        "--input",
        root.to_str().unwrap(),
        "--out",
        snap.to_str().unwrap(),
    ]));
    assert!(text.contains("7 run(s)"), "{text}");
    let s = snap.to_str().unwrap();
    // One --out for both (paths appear in the outputs).
    let out = d.path().join("out");
    ok(sparkout(&[
        "run",
        "--input",
        root.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--snapshot",
        s,
    ]));
    let single = read_outputs(&out);
    std::fs::remove_dir_all(&out).unwrap();
    let (s0, s1) = (d.path().join("s0"), d.path().join("s1"));
    ok(shard(&root, &s0, "0/2", &["--snapshot", s]));
    arrive(&root, "xfyz-mill/r0000", "r0099");
    let late = ok(shard(&root, &s1, "1/2", &["--snapshot", s]));
    assert!(
        late.contains("arrived after the night's snapshot"),
        "{late}"
    );
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(s1.join("shard.json")).unwrap()).unwrap();
    assert_eq!(m["night_runs"].as_array().unwrap().len(), 7, "{m}");
    assert!(!m["night_runs"].to_string().contains("r0099"), "{m}");
    ok(aggregate(&[s0.clone(), s1.clone()], &out));
    assert_same(
        &single,
        &read_outputs(&out),
        "one node and two shards over one snapshot",
    );
    assert!(!out.join("xfyz-mill/r0099").exists());
    // A share that overlaps another shard's is named.
    let path = s1.join("shard.json");
    let mut m: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    let theirs: serde_json::Value =
        serde_json::from_slice(&std::fs::read(s0.join("shard.json")).unwrap()).unwrap();
    let stolen = theirs["assigned_runs"][0].as_str().unwrap().to_string();
    m["assigned_runs"]
        .as_array_mut()
        .unwrap()
        .push(stolen.clone().into());
    std::fs::write(&path, serde_json::to_vec(&m).unwrap()).unwrap();
    let o = aggregate(&[s0, s1], &d.path().join("out2"));
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains(&stolen) && e.contains("two shards"), "{e}");
    // A run listed in the snapshot and gone is a failure of the night.
    std::fs::remove_dir_all(root.join("xfyz-mill/r0001")).unwrap();
    let gone = d.path().join("gone");
    let o = sparkout(&[
        "run",
        "--input",
        root.to_str().unwrap(),
        "--out",
        gone.to_str().unwrap(),
        "--snapshot",
        s,
    ]);
    let f = std::fs::read_to_string(gone.join("failures.json")).unwrap();
    assert!(
        f.contains("r0001") && f.contains("no longer under the input"),
        "{f} {o:?}"
    );
}

/// A run's observations that cannot be read when the fleet's table is
/// joined (here: a shard's file damaged after the shard finished) fail the
/// night naming the file, and leave no joined table, finished or partial.
#[test]
fn a_run_unreadable_at_the_join_leaves_no_joined_table() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path());
    let a = d.path().join("a");
    ok(shard(&root, &a, "0/1", &[]));
    let damaged = std::fs::read_dir(a.join("servo-mill"))
        .unwrap()
        .map(|e| e.unwrap().path().join("observations.parquet"))
        .filter(|p| p.is_file())
        .max()
        .expect("a servo run with observations");
    std::fs::write(&damaged, b"PAR1 not a parquet file PAR1").unwrap();
    let out = d.path().join("out");
    let o = aggregate(std::slice::from_ref(&a), &out);
    let e = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(!o.status.success(), "{e}");
    let run = damaged
        .parent()
        .unwrap()
        .file_name()
        .unwrap()
        .to_str()
        .unwrap();
    assert!(e.contains(run) && e.contains("observations.parquet"), "{e}");
    let fleet_dir = out.join("fleet");
    let left: Vec<String> = std::fs::read_dir(&fleet_dir)
        .map(|rd| {
            rd.map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    assert!(
        !left.iter().any(|n| n.contains("observations.parquet")),
        "{left:?}"
    );
}

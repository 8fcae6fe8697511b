//! Hostile and careless input: names that are paths, outputs that overlap
//! the input, nested, deep, unreadable and linked-out directories, unknown
//! config keys, an existing bus log, markup in values that reach a report.
//! None may escape `--out`, delete or overwrite a byte outside it, or inject
//! into a page.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Output;

use crate::common::{sparkout, text};

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// A small mill fleet (three runs).
fn fleet(dir: &Path, plugin: &str, runs: usize) -> PathBuf {
    let root = dir.join("runs");
    let g = sparkout(&[
        "generate",
        plugin,
        "--runs",
        &runs.to_string(),
        "--seed",
        "1",
        "--out",
        p(&root),
    ]);
    assert!(g.status.success(), "{}", text(&g));
    root
}

/// Every file under `dir` with its bytes' length and a checksum of them.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, (u64, u64)> {
    fn walk(d: &Path, out: &mut BTreeMap<PathBuf, (u64, u64)>) {
        for e in std::fs::read_dir(d).unwrap() {
            let e = e.unwrap().path();
            if e.is_symlink() {
                out.insert(e, (0, 0));
            } else if e.is_dir() {
                walk(&e, out);
            } else {
                let b = std::fs::read(&e).unwrap();
                let sum = b.iter().fold(1469598103934665603u64, |h, &x| {
                    (h ^ x as u64).wrapping_mul(1099511628211)
                });
                out.insert(e, (b.len() as u64, sum));
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, &mut out);
    out
}

/// A generated paired-observations table with a drift effect.
fn observations(dir: &Path, runs: &str) -> PathBuf {
    let obs = dir.join("obs.parquet");
    let g = sparkout(&[
        "generate",
        "observations",
        "--runs",
        runs,
        "--seed",
        "3",
        "--out",
        p(&obs),
        "--effect",
        "drift:t_s=amplitude_mm=0.02,tau_s=600",
    ]);
    assert!(g.status.success(), "{}", text(&g));
    obs
}

fn run(input: &Path, out: &Path) -> Output {
    sparkout(&["run", "--input", p(input), "--out", p(out)])
}

fn failures(out: &Path) -> Vec<serde_json::Value> {
    serde_json::from_slice(&std::fs::read(out.join("failures.json")).unwrap()).unwrap()
}

fn set_run_toml(run_dir: &Path, from: &str, to: &str) {
    let f = run_dir.join("run.toml");
    let t = std::fs::read_to_string(&f).unwrap();
    assert!(t.contains(from), "{t}");
    std::fs::write(&f, t.replacen(from, to, 1)).unwrap();
}

#[test]
fn traversal_names_are_refused_and_nothing_outside_out_is_touched() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), "mill", 3);
    let run1 = root.join("xfyz-mill/r0001");
    set_run_toml(&run1, "id = \"r0001\"", "id = \".\"");
    set_run_toml(&run1, "machine = \"xfyz-mill\"", "machine = \"..\"");
    // An unrelated folder beside the fleet.
    let beside = d.path().join("beside");
    std::fs::create_dir(&beside).unwrap();
    std::fs::write(beside.join("keep.txt"), b"not sparkout's").unwrap();
    let before_in = snapshot(&root);
    let before_beside = snapshot(&beside);
    let out = d.path().join("out");
    let o = run(&root, &out);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert_eq!(snapshot(&root), before_in, "the input changed");
    assert_eq!(snapshot(&beside), before_beside, "a folder beside changed");
    let f = failures(&out);
    assert_eq!(f.len(), 1, "{f:?}");
    let e = f[0]["error"].as_str().unwrap();
    assert!(e.contains("[run].id `.`"), "{e}");
    assert_eq!(f[0]["column"], "run.id");
    // The other two runs were processed.
    assert!(out.join("xfyz-mill/r0000/report.html").is_file());
    assert!(out.join("xfyz-mill/r0002/report.html").is_file());
    // Every other shape of a path in a name.
    set_run_toml(&run1, "id = \".\"", "id = \"r0001\"");
    for bad in [
        "a/b",
        "../x",
        "/etc",
        ".hidden",
        "a b",
        "x\\u0000y",
        "<b>x</b>",
    ] {
        let t = std::fs::read_to_string(run1.join("run.toml")).unwrap();
        let t = t.replacen("machine = \"..\"", &format!("machine = \"{bad}\""), 1);
        std::fs::write(run1.join("run.toml"), &t).unwrap();
        let v = sparkout(&["validate-input", p(&root)]);
        assert_eq!(v.status.code(), Some(2), "{bad}: {}", text(&v));
        assert!(text(&v).contains("[run].machine"), "{bad}: {}", text(&v));
        let t = t.replacen(&format!("machine = \"{bad}\""), "machine = \"..\"", 1);
        std::fs::write(run1.join("run.toml"), t).unwrap();
    }
}

#[test]
fn markup_quoted_by_an_error_is_escaped_on_the_index_page() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), "guideway", 2);
    let runs = sparkout_pipeline::contracts::discover_runs(&root).unwrap();
    let evil = "<img src=x onerror=alert(1)>";
    let t = std::fs::read_to_string(runs[0].join("run.toml")).unwrap();
    let t = t.replacen("plugin = \"guideway\"", &format!("plugin = \"{evil}\""), 1);
    std::fs::write(runs[0].join("run.toml"), t).unwrap();
    let out = d.path().join("out");
    let o = run(&root, &out);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(failures(&out)[0]["error"].as_str().unwrap().contains(evil));
    let index = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(
        !index.contains("<img src=x"),
        "unescaped markup on the index"
    );
    assert!(
        index.contains("&lt;img src=x"),
        "the error is shown, escaped"
    );
}

#[test]
fn out_equal_to_inside_or_containing_input_is_refused_before_any_work() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), "guideway", 2);
    let before = snapshot(&root);
    let cases: [(PathBuf, PathBuf, &str); 4] = [
        (root.clone(), root.clone(), "is the same directory as"),
        (root.clone(), root.join("xx/out"), "is inside"),
        (root.clone(), d.path().to_path_buf(), "contains"),
        (root.clone(), root.join("."), "is the same directory as"),
    ];
    for (input, out, why) in cases {
        let o = run(&input, &out);
        assert_eq!(o.status.code(), Some(1), "{}", text(&o));
        assert!(text(&o).contains(why), "{}", text(&o));
        assert_eq!(snapshot(&root), before, "--out {}", out.display());
    }
    // A link to the input is the input.
    let link = d.path().join("link");
    std::os::unix::fs::symlink(&root, &link).unwrap();
    let o = run(&root, &link);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert_eq!(snapshot(&root), before);
}

#[test]
fn a_rejected_run_removes_only_what_sparkout_wrote() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), "guideway", 2);
    let out = d.path().join("out");
    let o = run(&root, &out);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let runs = sparkout_pipeline::contracts::discover_runs(&root).unwrap();
    let spec = sparkout_pipeline::contracts::RunSpec::load(&runs[0]).unwrap();
    let run_out = out.join(&spec.machine).join(&spec.id);
    assert!(run_out.join("report.html").is_file());
    // A user's note in the run's output, then the run turns bad.
    std::fs::write(run_out.join("my-notes.txt"), b"mine").unwrap();
    std::fs::write(runs[0].join("run.toml"), b"not = [valid").unwrap();
    let o = run(&root, &out);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    // The run.toml no longer parses, so nothing is removed for it at all;
    // make it parse but fail a stage instead.
    std::fs::write(
        runs[0].join("run.toml"),
        format!(
            "[run]\nid = \"{}\"\nmachine = \"{}\"\nplugin = \"nosuch\"\n",
            spec.id, spec.machine
        ),
    )
    .unwrap();
    let o = run(&root, &out);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(!run_out.join("report.html").exists(), "sparkout's files go");
    assert!(run_out.join("my-notes.txt").is_file(), "the user's stays");
}

#[test]
fn nested_and_deep_runs_are_accounted_for() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), "guideway", 3);
    let runs = sparkout_pipeline::contracts::discover_runs(&root).unwrap();
    assert_eq!(runs.len(), 3);
    // One run moved five levels deep: still found, outputs as usual.
    let deep = root.join("site/line/cell/bay/extra");
    std::fs::create_dir_all(&deep).unwrap();
    let moved = deep.join(runs[1].file_name().unwrap());
    std::fs::rename(&runs[1], &moved).unwrap();
    // One run inside another run's directory: an error naming both.
    let nested = runs[0].join("inner");
    std::fs::rename(&runs[2], &nested).unwrap();
    let out = d.path().join("out");
    let o = run(&root, &out);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let f = failures(&out);
    assert_eq!(f.len(), 1, "{f:?}");
    let e = f[0]["error"].as_str().unwrap();
    assert!(e.contains(p(&nested)) && e.contains(p(&runs[0])), "{e}");
    let spec = sparkout_pipeline::contracts::RunSpec::load(&moved).unwrap();
    assert!(out
        .join(&spec.machine)
        .join(&spec.id)
        .join("report.html")
        .is_file());
    let v = sparkout(&["validate-input", p(&root)]);
    assert_eq!(v.status.code(), Some(2), "{}", text(&v));
    assert!(text(&v).contains("is inside run directory"), "{}", text(&v));
}

#[test]
fn links_out_of_the_input_are_refused_by_name() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), "guideway", 2);
    let elsewhere = d.path().join("elsewhere");
    let other = fleet(&elsewhere, "guideway", 1);
    let runs = sparkout_pipeline::contracts::discover_runs(&root).unwrap();
    // A machine directory linked to another fleet, and a table linked out.
    let link = root.join("linked-machine");
    std::os::unix::fs::symlink(&other, &link).unwrap();
    let table = std::fs::read_dir(&runs[0])
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "parquet"))
        .unwrap();
    let outside_copy = d.path().join("outside.parquet");
    std::fs::rename(&table, &outside_copy).unwrap();
    std::os::unix::fs::symlink(&outside_copy, &table).unwrap();
    let out = d.path().join("out");
    let o = run(&root, &out);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let f = failures(&out);
    let all: String = f.iter().map(|x| x["error"].to_string()).collect();
    assert!(
        all.contains(p(&link)) && all.contains("outside the input"),
        "{all}"
    );
    assert!(all.contains(p(&table)), "{all}");
    assert_eq!(f.len(), 2, "{f:?}");
}

/// As root every directory is readable: run the binary as `nobody` (with
/// setpriv) so a directory without permissions is unreadable to it.
#[test]
fn an_unreadable_directory_is_listed_and_the_batch_goes_on() {
    use std::os::unix::fs::PermissionsExt;
    let d = tempfile::tempdir().unwrap();
    std::fs::set_permissions(d.path(), std::fs::Permissions::from_mode(0o777)).unwrap();
    let root = fleet(d.path(), "guideway", 2);
    let runs = sparkout_pipeline::contracts::discover_runs(&root).unwrap();
    let locked = runs[0].parent().unwrap().join("locked");
    std::fs::create_dir(&locked).unwrap();
    std::fs::set_permissions(&locked, std::fs::Permissions::from_mode(0o000)).unwrap();
    // Everything else readable and writable to whoever runs the binary.
    std::process::Command::new("chmod")
        .args(["-R", "a+rwX", p(&root)])
        .status()
        .unwrap();
    std::fs::set_permissions(&locked, std::fs::Permissions::from_mode(0o000)).unwrap();
    let is_root = std::process::Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0");
    let bin = env!("CARGO_BIN_EXE_sparkout");
    let out = d.path().join("out");
    let mut cmd = if is_root {
        let mut c = std::process::Command::new("setpriv");
        c.args([
            "--reuid=65534",
            "--regid=65534",
            "--clear-groups",
            "--",
            bin,
        ]);
        c
    } else {
        std::process::Command::new(bin)
    };
    let o = cmd
        .args(["run", "--input", p(&root), "--out", p(&out)])
        .env("SPARKOUT_LOG", "warn")
        .output()
        .unwrap();
    if is_root && String::from_utf8_lossy(&o.stderr).contains("ermission denied") && !out.exists() {
        eprintln!(
            "SKIPPED: the binary cannot be run as nobody here: {}",
            text(&o)
        );
        return;
    }
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let f = failures(&out);
    assert_eq!(f.len(), 1, "{f:?}");
    assert_eq!(f[0]["run_dir"].as_str(), Some(p(&locked)));
    assert!(
        f[0]["error"]
            .as_str()
            .unwrap()
            .contains("cannot list directory"),
        "{f:?}"
    );
    assert!(text(&o).contains("2 runs ok"), "{}", text(&o));
}

#[test]
fn unknown_config_keys_and_a_machines_file_are_refused_everywhere() {
    let d = tempfile::tempdir().unwrap();
    let obs = observations(d.path(), "4");
    let diag_out = d.path().join("diag");
    let o = sparkout(&[
        "diagnose",
        p(&obs),
        "--out",
        p(&diag_out),
        "--set",
        "mil.kinematic.x=1",
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(text(&o).contains("mil"), "{}", text(&o));
    let o = sparkout(&["validate", "--quick", "--set", "mil.x.y=1"]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    // The research option's cells: at least two, and not with --nights
    // (whose fleets it does not touch).
    for args in [&["--cells", "1"][..], &["--cells", "8", "--nights"][..]] {
        let o = sparkout(&[&["validate", "--quick"][..], args].concat());
        assert_eq!(o.status.code(), Some(1), "{args:?}: {}", text(&o));
        assert!(text(&o).contains("--cells"), "{args:?}: {}", text(&o));
    }
    let cfg = d.path().join("c.toml");
    std::fs::write(&cfg, "[nosuch]\nx = 1\n").unwrap();
    let o = sparkout(&[
        "diagnose",
        p(&obs),
        "--out",
        p(&diag_out),
        "--config",
        p(&cfg),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(text(&o).contains("nosuch"), "{}", text(&o));
    let root = fleet(d.path(), "guideway", 1);
    let o = sparkout(&[
        "run",
        "--input",
        p(&root),
        "--out",
        p(&d.path().join("out")),
        "--machines",
        p(&cfg),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(text(&o).contains("not a directory"), "{}", text(&o));
}

#[test]
fn markup_in_an_observable_name_is_escaped_in_the_report() {
    use arrow::array::{Array, StringArray};
    use std::sync::Arc;
    let d = tempfile::tempdir().unwrap();
    let obs = observations(d.path(), "6");
    let batch = sparkout_pipeline::contracts::read_parquet(&obs).unwrap();
    let idx = batch.schema().index_of("observable").unwrap();
    let n = batch.column(idx).len();
    let evil = "<script>alert(1)</script>&\"'";
    let mut cols = batch.columns().to_vec();
    cols[idx] = Arc::new(StringArray::from(vec![evil; n]));
    let batch = arrow::record_batch::RecordBatch::try_new(batch.schema(), cols).unwrap();
    let hostile = d.path().join("hostile.parquet");
    sparkout_pipeline::contracts::write_parquet_atomic(&hostile, &batch).unwrap();
    let out = d.path().join("diag");
    let o = sparkout(&["diagnose", p(&hostile), "--out", p(&out)]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(!html.contains("<script>"), "unescaped markup in the report");
    assert!(
        html.contains("&lt;script&gt;"),
        "the name is shown, escaped"
    );
}

#[test]
fn a_bus_log_is_never_overwritten() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), "robot", 1);
    let run = sparkout_pipeline::contracts::discover_runs(&root).unwrap()[0].clone();
    let log = d.path().join("recorded.log");
    std::fs::write(&log, b"(0000000000.000000) can0 000#8000\n").unwrap();
    let before = std::fs::read(&log).unwrap();
    let o = sparkout(&[
        "replay",
        "--run",
        p(&run),
        "--bus",
        &format!("log:{}", p(&log)),
    ]);
    assert_ne!(o.status.code(), Some(0), "{}", text(&o));
    assert!(text(&o).contains("never overwritten"), "{}", text(&o));
    assert_eq!(std::fs::read(&log).unwrap(), before);
}

#[test]
fn hostile_names_in_a_shard_manifest_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), "guideway", 2);
    let shard = d.path().join("shard0");
    let o = sparkout(&[
        "run",
        "--input",
        p(&root),
        "--out",
        p(&shard),
        "--shard",
        "0/1",
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let mf = shard.join("shard.json");
    let mut m: serde_json::Value = serde_json::from_slice(&std::fs::read(&mf).unwrap()).unwrap();
    m["runs"][0]["machine"] = "..".into();
    m["runs"][0]["run"] = "..".into();
    std::fs::write(&mf, serde_json::to_vec(&m).unwrap()).unwrap();
    let beside = snapshot(d.path().join("runs").as_path());
    let out = d.path().join("agg");
    let o = sparkout(&["aggregate", "--shards", p(&shard), "--out", p(&out)]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(text(&o).contains("[run].machine `..`"), "{}", text(&o));
    assert_eq!(snapshot(d.path().join("runs").as_path()), beside);
}

#[test]
fn a_table_declaring_a_huge_footer_is_refused_not_allocated() {
    let d = tempfile::tempdir().unwrap();
    let root = fleet(d.path(), "guideway", 2);
    let runs = sparkout_pipeline::contracts::discover_runs(&root).unwrap();
    let table = std::fs::read_dir(&runs[0])
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "parquet"))
        .unwrap();
    // The footer length (the 4 bytes before the closing magic) claims
    // almost 2 GiB of metadata in a file of a few kB.
    let mut bytes = std::fs::read(&table).unwrap();
    let n = bytes.len();
    bytes[n - 8..n - 4].copy_from_slice(&0x7FFF_FFF0u32.to_le_bytes());
    std::fs::write(&table, &bytes).unwrap();
    let out = d.path().join("out");
    let o = run(&root, &out);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let f = failures(&out);
    assert_eq!(f.len(), 1, "{f:?}");
    assert_eq!(f[0]["file"].as_str(), Some(p(&table)), "{f:?}");
}

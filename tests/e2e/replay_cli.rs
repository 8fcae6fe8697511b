//! `sparkout replay` end to end: a full replay on the simulated drives that
//! records back a run `validate-input` accepts, the log backend read by
//! python-can and decoded by cantools, faults ending non-zero with the
//! reason, and bad input refused before anything is sent.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::sparkout;
use sparkout_pipeline::contracts::schema::MOTION;
use sparkout_pipeline::contracts::{write_atomic, write_parquet_atomic, BatchBuilder, Table};

/// A small robot run: 2 s of a smooth path at 1 kHz, a few probe points
/// (what the robot plugin needs besides motion).
fn tiny_run(root: &Path, with_motion: bool) -> PathBuf {
    let dir = root.join("kr16-lab").join("r0001");
    std::fs::create_dir_all(&dir).unwrap();
    write_atomic(
        &dir.join("run.toml"),
        b"[run]\nid = \"r0001\"\nmachine = \"kr16-lab\"\nplugin = \"robot\"\nstarted = \"2026-11-20T08:00:00Z\"\n\n[process]\nfeed_mm_s = 20.0\n",
    )
    .unwrap();
    if with_motion {
        let n = 2001;
        let t: Vec<f64> = (0..n).map(|i| i as f64 * 1e-3).collect();
        let w = 2.0 * std::f64::consts::PI * 0.5;
        let b = BatchBuilder::new()
            .f64("t_s", t.clone())
            .f64(
                "cmd_x_mm",
                t.iter().map(|t| 100.0 + 10.0 * (w * t).sin()).collect(),
            )
            .f64("cmd_y_mm", t.iter().map(|t| 50.0 + 20.0 * t).collect())
            .f64("cmd_z_mm", vec![-5.0; n])
            .f64("feed_mm_s", vec![20.0; n])
            .i32("segment", (0..n as i32).map(|i| i / 500).collect());
        write_parquet_atomic(&dir.join("motion.parquet"), &b.build()).unwrap();
    }
    // Three points on each of the three faces, not collinear: a run whose
    // datum fits, so `sparkout run` (and so validate-input) accepts it.
    let faces = ["xy", "xy", "xy", "yz", "yz", "yz", "zx", "zx", "zx"];
    let (u, v) = ([0.0, 10.0, 0.0], [0.0, 0.0, 10.0]);
    let mut pts: Vec<[f64; 3]> = Vec::new();
    for k in 0..3 {
        pts.push([5.0 + u[k], 5.0 + v[k], 0.001]); // xy: z = 0
    }
    for k in 0..3 {
        pts.push([0.002, 5.0 + u[k], -5.0 - v[k]]); // yz: x = 0
    }
    for k in 0..3 {
        pts.push([5.0 + u[k], -0.001, -5.0 - v[k]]); // zx: y = 0
    }
    let m = pts.len();
    let col = |a: usize, noisy: bool| -> Vec<f64> {
        pts.iter()
            .map(|p| if noisy { p[a] } else { p[a].round() })
            .collect()
    };
    let b = BatchBuilder::new()
        .f64("t_s", (0..m).map(|i| 0.2 * (i + 1) as f64).collect())
        .str("face", &faces)
        .i32("point", (0..m as i32).map(|i| i % 3).collect())
        .i32("trial", vec![0; m])
        .str("method", &vec!["mechanical"; m])
        .f64("approach_mm_s", vec![10.0; m])
        .f64("nom_x_mm", col(0, false))
        .f64("nom_y_mm", col(1, false))
        .f64("nom_z_mm", col(2, false))
        .f64("x_mm", col(0, true))
        .f64("y_mm", col(1, true))
        .f64("z_mm", col(2, true));
    write_parquet_atomic(&dir.join("probe.parquet"), &b.build()).unwrap();
    dir
}

/// A compensation Parquet with t_s and the given columns.
fn compensation(path: &Path, cols: &[(&str, Vec<f64>)]) {
    let mut b = BatchBuilder::new();
    for (name, v) in cols {
        b = b.f64(name, v.clone());
    }
    write_parquet_atomic(path, &b.build()).unwrap();
}

fn comp_t() -> Vec<f64> {
    (0..=20).map(|i| i as f64 * 0.1).collect()
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

#[test]
fn replay_on_sim_streams_everything_and_records_a_valid_run() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tiny_run(tmp.path(), true);
    let comp = tmp.path().join("comp.parquet");
    let t = comp_t();
    let dz: Vec<f64> = t.iter().map(|t| 0.02 * t).collect();
    compensation(
        &comp,
        &[
            ("t_s", t.clone()),
            ("dz_mm", dz),
            ("dx_mm", vec![0.01; t.len()]),
        ],
    );
    let out = tmp.path().join("replayed");
    let o = sparkout(&[
        "replay",
        "--run",
        run.to_str().unwrap(),
        "--compensation",
        comp.to_str().unwrap(),
        "--bus",
        "sim",
        "--record",
        out.to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stderr));
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(r["completed"], true);
    assert_eq!(r["reached_operation_enabled"], true);
    assert_eq!(r["cycles_planned"], 501); // 2 s at 4 ms, both ends
    assert_eq!(r["cycles_streamed"], 501);
    assert_eq!(r["recorded_rows"], 501);
    assert!(r["max_following_mm"].as_f64().unwrap() < 0.5);

    // The recorded run is a run: validate-input accepts it.
    let v = sparkout(&["validate-input", out.to_str().unwrap()]);
    assert_eq!(
        v.status.code(),
        Some(0),
        "{}{}",
        text(&v.stdout),
        text(&v.stderr)
    );
    assert!(text(&v.stdout).contains("1 clean"), "{}", text(&v.stdout));
    let m = Table::read(&out.join("motion.parquet"), &MOTION).unwrap();
    assert_eq!(m.len(), 501);
    let (t, cx, ax, cz) = (
        m.f64("t_s").unwrap(),
        m.f64("cmd_x_mm").unwrap(),
        m.f64("act_x_mm").unwrap(),
        m.f64("cmd_z_mm").unwrap(),
    );
    assert!((t[1] - t[0] - 0.004).abs() < 1e-12);
    for k in [0, 250, 500] {
        // cmd = source path + compensation (to the count), act follows it.
        let w = 2.0 * std::f64::consts::PI * 0.5;
        assert!(
            (cx[k] - (100.0 + 10.0 * (w * t[k]).sin() + 0.01)).abs() < 2e-4,
            "x at {k}"
        );
        assert!((cz[k] - (-5.0 + 0.02 * t[k])).abs() < 2e-4, "z at {k}");
        assert!((ax[k] - cx[k]).abs() < 0.5);
    }
    assert!(m.has("segment") && m.has("feed_mm_s"));
    let toml_text = std::fs::read_to_string(out.join("run.toml")).unwrap();
    assert!(toml_text.contains("id = \"r0001-replay\""), "{toml_text}");
    assert!(toml_text.contains("outcome = \"completed\""), "{toml_text}");
    assert!(out.join("probe.parquet").is_file());

    // A second replay into the same directory is refused (no overwrite).
    let again = sparkout(&[
        "replay",
        "--run",
        run.to_str().unwrap(),
        "--bus",
        "sim",
        "--record",
        out.to_str().unwrap(),
    ]);
    assert_eq!(again.status.code(), Some(1));
}

#[test]
fn an_injected_fault_ends_non_zero_with_the_reason() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tiny_run(tmp.path(), true);
    for (fault, says) in [
        ("emcy@0.5s:2", "EMCY from node 2"),
        ("heartbeat@0.5s:3", "heartbeat of node 3"),
        ("busoff@0.7s", "bus-off"),
        ("following@0.5s:1", "following error on axis x"),
        ("refuse:1", "refused the transition"),
        ("sigint@0.3s", "interrupted (SIGINT)"),
    ] {
        let out = tmp
            .path()
            .join(format!("rec-{}", fault.replace([':', '@', '.'], "_")));
        let o = sparkout(&[
            "replay",
            "--run",
            run.to_str().unwrap(),
            "--bus",
            "sim",
            "--sim-fault",
            fault,
            "--record",
            out.to_str().unwrap(),
            "--json",
        ]);
        assert_eq!(o.status.code(), Some(2), "{fault}: {}", text(&o.stderr));
        assert!(
            text(&o.stderr).contains(says),
            "{fault}: {}",
            text(&o.stderr)
        );
        let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(r["completed"], false);
        let (d, q) = (
            r["detected_s"].as_f64().unwrap(),
            r["quick_stop_s"].as_f64().unwrap(),
        );
        assert!(
            q - d <= 0.008 + 1e-9,
            "{fault}: quick stop {q} after detection {d}"
        );
        if fault != "refuse:1" {
            // What the drives did until the stop is still a valid recorded run.
            let toml_text = std::fs::read_to_string(out.join("run.toml")).unwrap();
            assert!(toml_text.contains("outcome = \"quick stop:"), "{toml_text}");
            let v = sparkout(&["validate-input", out.to_str().unwrap()]);
            assert_eq!(v.status.code(), Some(0), "{}", text(&v.stdout));
        }
    }
}

#[test]
fn bad_input_is_refused_before_anything_is_sent() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tiny_run(tmp.path(), true);
    let no_motion = tiny_run(&tmp.path().join("other"), false);
    let t = comp_t();
    let no_t = tmp.path().join("no_t.parquet");
    compensation(&no_t, &[("time", t.clone()), ("dx_mm", vec![0.0; t.len()])]);
    let unknown = tmp.path().join("unknown.parquet");
    compensation(
        &unknown,
        &[
            ("t_s", t.clone()),
            ("dx_mm", vec![0.0; t.len()]),
            ("dw_mm", vec![0.0; t.len()]),
        ],
    );
    let big = tmp.path().join("big.parquet");
    compensation(&big, &[("t_s", t.clone()), ("dy_mm", vec![2.0; t.len()])]);
    let mut nan = vec![0.0; t.len()];
    nan[7] = f64::NAN;
    let nan_file = tmp.path().join("nan.parquet");
    compensation(&nan_file, &[("t_s", t.clone()), ("dx_mm", nan)]);
    let run_s = run.to_str().unwrap();
    let log = tmp.path().join("never.log");
    let bus = format!("log:{}", log.display());
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec!["--compensation", no_t.to_str().unwrap()],
            "column `t_s`",
        ),
        (
            vec!["--compensation", unknown.to_str().unwrap()],
            "unknown axis `dw_mm`",
        ),
        (
            vec!["--compensation", nan_file.to_str().unwrap()],
            "column `dx_mm`, row 7",
        ),
        (
            vec!["--compensation", big.to_str().unwrap()],
            "|compensation| 2.0000 mm > max 0.5 mm",
        ),
        (vec!["--cycle-ms", "0.5"], "at least 1 ms"),
        (vec!["--max-step-mm", "0"], "--max-step-mm = 0"),
        (vec!["--max-comp-mm=-1"], "--max-comp-mm = -1"),
        (vec!["--max-following-mm", "0"], "--max-following-mm = 0"),
        (vec!["--sim-fault", "explode@1s"], "unknown fault"),
    ];
    for (extra, says) in cases {
        let mut args = vec!["replay", "--run", run_s, "--bus", bus.as_str()];
        args.extend(extra.iter().copied());
        let o = sparkout(&args);
        assert_eq!(o.status.code(), Some(1), "{extra:?}: {}", text(&o.stderr));
        assert!(
            text(&o.stderr).contains(says),
            "{extra:?}: {}",
            text(&o.stderr)
        );
        assert!(
            !log.exists(),
            "{extra:?}: a log was written, so frames were sent"
        );
    }
    let o = sparkout(&[
        "replay",
        "--run",
        no_motion.to_str().unwrap(),
        "--bus",
        bus.as_str(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        text(&o.stderr).contains("motion.parquet"),
        "{}",
        text(&o.stderr)
    );
    assert!(!log.exists());
    let o = sparkout(&["replay", "--run", run_s, "--bus", "can0"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(text(&o.stderr).contains("sim, log:FILE or socketcan:IFACE"));
}

#[test]
fn dry_run_opens_no_hardware_and_prints_what_would_be_sent() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tiny_run(tmp.path(), true);
    let o = sparkout(&[
        "replay",
        "--run",
        run.to_str().unwrap(),
        "--bus",
        "socketcan:can9",
        "--dry-run",
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stderr));
    let s = text(&o.stdout);
    assert!(
        s.contains("dry run:") && s.contains("frames would be sent"),
        "{s}"
    );
    assert!(
        s.contains("can0 000#8000"),
        "NMT pre-operational first: {s}"
    );
    assert!(s.contains("can0 080#"), "SYNC: {s}");
    assert!(s.contains("socketcan:can9 not opened"), "{s}");
}

#[test]
fn log_backend_is_read_by_python_can_and_decoded_by_cantools() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tiny_run(tmp.path(), true);
    let log = tmp.path().join("replay.log");
    let o = sparkout(&[
        "replay",
        "--run",
        run.to_str().unwrap(),
        "--bus",
        &format!("log:{}", log.display()),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stderr));
    let lines = std::fs::read_to_string(&log).unwrap();
    assert!(
        lines.lines().count() > 501 * 7,
        "every cycle: 3 RPDO + SYNC + 3 TPDO"
    );
    assert!(
        lines.starts_with("(0000000000.000000) can0 000#8000\n"),
        "{}",
        &lines[..80]
    );

    let have = Command::new("python3")
        .args(["-c", "import can, cantools"])
        .output();
    if !have.map(|o| o.status.success()).unwrap_or(false) {
        eprintln!("SKIPPED interop check: python3 with python-can and cantools not available (pip install python-can cantools)");
        return;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let check = Command::new("python3")
        .arg(root.join("tests/interop/check_candump.py"))
        .arg(&log)
        .arg(root.join("configs/can/cia402_pdo.dbc"))
        .output()
        .unwrap();
    assert!(
        check.status.success(),
        "{}{}",
        text(&check.stdout),
        text(&check.stderr)
    );
    eprintln!("{}", text(&check.stdout).trim());
    assert!(text(&check.stdout).contains("SYNC every 4.000 ms"));
}

/// What `replay --record` writes is a run `validate-input` and `run` accept,
/// for every machine type whose runs replay can drive (those with
/// motion.parquet): a robot run probed by AE (no probe table: ae + motion +
/// plan), a servo run and a gantry run, as the generators make them.
#[test]
fn a_recorded_run_is_accepted_for_every_machine_type_replay_drives() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("runs");
    for (plugin, extra) in [
        ("robot", &["--ae-rate-hz", "200000"][..]),
        ("servo", &[][..]),
        ("gantry", &[][..]),
    ] {
        let mut args = vec!["generate", plugin, "--runs", "2", "--seed", "2"];
        args.extend(extra);
        args.extend(["--out", root.to_str().unwrap()]);
        let g = sparkout(&args);
        assert!(g.status.success(), "{plugin}: {}", text(&g.stderr));
    }
    let runs = sparkout_pipeline::contracts::discover_runs(&root).unwrap();
    let pick = |plugin: &str, without: Option<&str>| -> PathBuf {
        runs.iter()
            .find(|d| {
                std::fs::read_to_string(d.join("run.toml"))
                    .unwrap()
                    .contains(&format!("plugin = \"{plugin}\""))
                    && without.is_none_or(|t| !d.join(t).exists())
            })
            .unwrap_or_else(|| panic!("no {plugin} run"))
            .clone()
    };
    let sources = [
        ("robot", pick("robot", Some("probe.parquet"))),
        ("servo", pick("servo", None)),
        ("gantry", pick("gantry", None)),
    ];
    let recorded = tmp.path().join("recorded");
    for (plugin, src) in &sources {
        assert!(src.join("motion.parquet").is_file(), "{plugin}");
        let out = recorded.join(plugin).join("replayed");
        let o = sparkout(&[
            "replay",
            "--run",
            src.to_str().unwrap(),
            "--bus",
            "sim",
            "--cycle-ms",
            "1",
            "--max-step-mm",
            "50",
            "--max-step-change-mm",
            "50",
            "--max-following-mm",
            "50",
            "--sim-max-speed-mm-s",
            "100000",
            "--record",
            out.to_str().unwrap(),
        ]);
        assert_eq!(o.status.code(), Some(0), "{plugin}: {}", text(&o.stderr));
        let v = sparkout(&["validate-input", out.to_str().unwrap()]);
        assert_eq!(
            v.status.code(),
            Some(0),
            "{plugin}: {}{}",
            text(&v.stdout),
            text(&v.stderr)
        );
    }
    // `run` over all of them: none rejected.
    let o = sparkout(&[
        "run",
        "--input",
        recorded.to_str().unwrap(),
        "--out",
        tmp.path().join("out").to_str().unwrap(),
    ]);
    let failures = std::fs::read_to_string(tmp.path().join("out/failures.json")).unwrap();
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}{}{failures}",
        text(&o.stdout),
        text(&o.stderr)
    );
}

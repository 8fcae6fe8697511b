//! Form plugin through the binary (`form` half): `stage segment
//! --run … --json` and its sweep, the tool-path artifacts, the run-less
//! CLDATA programs, and bad inputs that name file, column and row while the
//! rest of a batch goes on.

use crate::common;
use common::sparkout;

use std::path::{Path, PathBuf};

use sparkout_pipeline::contracts::{
    read_parquet, write_atomic, write_parquet_atomic, BatchBuilder,
};
use sparkout_plugins::form::shapes::{ellipse_r, sample, TangentCam};

fn generate(root: &Path, runs: &str, seed: &str) -> PathBuf {
    let g = sparkout(&[
        "generate",
        "form",
        "--runs",
        runs,
        "--seed",
        seed,
        "--out",
        root.to_str().unwrap(),
    ]);
    assert!(g.status.success(), "{}", String::from_utf8_lossy(&g.stderr));
    root.join("form-grinder")
}

fn json_of(out: &std::process::Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// `sparkout stage segment --run DIR --r-max-mm 175 --range-mm 50
/// --segments N --json`: N segments tiling 125–175 mm, each with its
/// nominal at the middle; the overall maximum error falls as N grows (the
/// cam run has straight flanks, so this also runs the curvature on flats).
#[test]
fn segment_json_and_sweep() {
    let d = tempfile::tempdir().unwrap();
    let fleet = generate(&d.path().join("runs"), "2", "7");
    let cam = fleet.join("r0001");
    let mut last = f64::INFINITY;
    for n in [1usize, 2, 5, 10] {
        let ns = n.to_string();
        let v = json_of(&sparkout(&[
            "stage",
            "segment",
            "--run",
            cam.to_str().unwrap(),
            "--r-max-mm",
            "175",
            "--range-mm",
            "50",
            "--segments",
            &ns,
            "--json",
        ]));
        let segs = v["segments"].as_array().unwrap();
        assert_eq!(segs.len(), n);
        let w = 50.0 / n as f64;
        for (k, s) in segs.iter().enumerate() {
            let hi = 175.0 - k as f64 * w;
            assert!((s["r_max_mm"].as_f64().unwrap() - hi).abs() < 1e-9);
            assert!((s["r_min_mm"].as_f64().unwrap() - (hi - w)).abs() < 1e-9);
            assert!((s["nominal_mm"].as_f64().unwrap() - (hi - w / 2.0)).abs() < 1e-9);
            assert!(s["max_error_mm"].as_f64().unwrap() > 0.0);
        }
        let m = v["max_error_mm"].as_f64().unwrap();
        let seg_max = segs
            .iter()
            .map(|s| s["max_error_mm"].as_f64().unwrap())
            .fold(0.0, f64::max);
        assert_eq!(m, seg_max);
        assert!(m < last, "max error must fall with N: {m} after {last}");
        last = m;
        // The sweep in the same summary agrees at this N.
        let sw = v["sweep"].as_array().unwrap();
        assert_eq!(sw.len(), 10);
        assert!((sw[n - 1]["max_error_mm"].as_f64().unwrap() - m).abs() < 1e-12);
    }
    // A flag the stage does not know is a config error naming the key.
    let bad = sparkout(&[
        "stage",
        "segment",
        "--run",
        cam.to_str().unwrap(),
        "--segmentz",
        "3",
    ]);
    assert!(!bad.status.success());
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        err.contains("segmentz") && err.contains("form.segment"),
        "{err}"
    );
}

/// `--out` writes the tool paths (X, Z, A, C per point per segment) as
/// Parquet; the DAG's `form_cldata` turns them into CLDATA lines; the
/// run-less form writes one `.cls` program per segment.
#[test]
fn toolpath_parquet_and_cldata_programs() {
    let d = tempfile::tempdir().unwrap();
    let fleet = generate(&d.path().join("runs"), "1", "8");
    let run = fleet.join("r0000");
    let out = d.path().join("seg");
    let s = sparkout(&[
        "stage",
        "segment",
        "--run",
        run.to_str().unwrap(),
        "--segments",
        "3",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(s.status.success(), "{}", String::from_utf8_lossy(&s.stderr));
    let tp = read_parquet(&out.join("toolpath.parquet")).unwrap();
    assert_eq!(tp.num_rows(), 3 * 360);
    for c in [
        "segment",
        "nominal_mm",
        "phi_rad",
        "x_mm",
        "z_mm",
        "a_rad",
        "c_rad",
    ] {
        assert!(tp.column_by_name(c).is_some(), "toolpath has no {c}");
    }
    let c = sparkout(&[
        "stage",
        "form_cldata",
        "--run",
        run.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(c.status.success(), "{}", String::from_utf8_lossy(&c.stderr));
    assert!(
        read_parquet(&out.join("cldata.parquet"))
            .unwrap()
            .num_rows()
            > 3 * 360
    );

    let cls = d.path().join("cls");
    let v = json_of(&sparkout(&[
        "stage",
        "form_cldata",
        "--profile",
        run.join("profile.parquet").to_str().unwrap(),
        "--r-max-mm",
        "175",
        "--range-mm",
        "50",
        "--segments",
        "4",
        "--cldata-dir",
        cls.to_str().unwrap(),
        "--json",
    ]));
    assert_eq!(v["segments"].as_array().unwrap().len(), 4);
    for k in 1..=4 {
        let text = std::fs::read_to_string(cls.join(format!("segment_{k:02}.cls"))).unwrap();
        assert_eq!(
            text.lines().filter(|l| l.starts_with("GOTO /")).count(),
            360
        );
        assert!(text.starts_with("PARTNO") && text.ends_with("FINI\n"));
    }
}

/// A run directory with a hand-made profile.parquet.
fn bad_run(root: &Path, id: &str, phi: Vec<f64>, r: Vec<f64>, measured_wheel_mm: f64) -> PathBuf {
    let dir = root.join("form-grinder").join(id);
    std::fs::create_dir_all(&dir).unwrap();
    let n = phi.len();
    let mut state = vec!["design"; n];
    state.extend(vec!["measured"; n]);
    let wheel: Vec<Option<f64>> = (0..2 * n)
        .map(|k| (k >= n).then_some(measured_wheel_mm))
        .collect();
    let b = BatchBuilder::new()
        .str("state", &state)
        .f64("phi_rad", phi.iter().chain(&phi).copied().collect())
        .f64("r_mm", r.iter().chain(&r).copied().collect())
        .opt_f64("wheel_radius_mm", wheel)
        .build();
    write_parquet_atomic(&dir.join("profile.parquet"), &b).unwrap();
    let toml = format!("[run]\nid = \"{id}\"\nmachine = \"form-grinder\"\nplugin = \"form\"\n\n[process]\nnominal_wheel_radius_mm = 170.0\n");
    write_atomic(&dir.join("run.toml"), toml.as_bytes()).unwrap();
    dir
}

fn stage_error(run: &Path) -> String {
    let o = sparkout(&["stage", "observe", "--run", run.to_str().unwrap(), "--json"]);
    assert!(
        !o.status.success(),
        "expected a bad-input error for {}",
        run.display()
    );
    String::from_utf8_lossy(&o.stderr).to_string()
}

/// Bad inputs, each a clear error naming file, column and row; in a batch
/// the bad runs are listed in failures.json and the good one goes on.
#[test]
fn bad_inputs_name_file_column_row() {
    let d = tempfile::tempdir().unwrap();
    let root = d.path().join("runs");
    let cam = TangentCam {
        base: 40.0,
        nose: 14.0,
        lift_centre: 36.0,
    };
    let (phi, r) = sample(200, |p| cam.r(p));

    // φ not strictly increasing: design row 57 repeats row 56's angle.
    let mut p2 = phi.clone();
    p2[57] = p2[56];
    let e = stage_error(&bad_run(&root, "dup_phi", p2, r.clone(), 170.0));
    assert!(
        e.contains("profile.parquet")
            && e.contains("column `phi_rad`")
            && e.contains("row 57")
            && e.contains("strictly increasing"),
        "{e}"
    );

    // Too few points for the curvature (window of 9).
    let e = stage_error(&bad_run(
        &root,
        "few",
        phi[..6].to_vec(),
        r[..6].to_vec(),
        170.0,
    ));
    assert!(
        e.contains("profile.parquet") && e.contains("column `phi_rad`") && e.contains("at least 9"),
        "{e}"
    );

    // A measured wheel radius outside the usable range 125–175 mm: the
    // first measured row (file row 200) is named.
    let e = stage_error(&bad_run(
        &root,
        "small_wheel",
        phi.clone(),
        r.clone(),
        120.0,
    ));
    assert!(
        e.contains("profile.parquet")
            && e.contains("column `wheel_radius_mm`")
            && e.contains("row 200")
            && e.contains("usable range"),
        "{e}"
    );

    // The batch: three bad runs rejected, the good one diagnosed.
    bad_run(&root, "good", phi, r, 170.0);
    let out = d.path().join("out");
    let o = sparkout(&[
        "run",
        "--input",
        root.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(
        o.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let f: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("failures.json")).unwrap()).unwrap();
    let text = f.to_string();
    for id in ["dup_phi", "few", "small_wheel"] {
        assert!(text.contains(id), "{id} missing from failures: {text}");
    }
    assert!(!text.contains("\"good\""), "{text}");
    assert!(out.join("form-grinder/good/observations.parquet").is_file());
    let html = std::fs::read_to_string(out.join("form-grinder/good/report.html")).unwrap();
    assert!(
        html.contains("Profile error against φ per segment") && html.contains("<svg"),
        "report lacks the per-segment profile error chart"
    );
    assert!(!out
        .join("form-grinder/dup_phi/observations.parquet")
        .exists());
}

/// Measured points between the design points: observe interpolates the
/// design (cubic Hermite with the fitted slopes), so a part ground exactly
/// to the design with the nominal wheel shows no gap (≪ 1 µm).
#[test]
fn observe_interpolates_between_design_points() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("form-grinder/mid");
    std::fs::create_dir_all(&dir).unwrap();
    let (phi, r) = sample(180, |p| ellipse_r(p, 50.0, 40.0));
    let mid: Vec<f64> = phi
        .iter()
        .map(|p| p + std::f64::consts::PI / 180.0)
        .collect();
    let n = phi.len();
    let mut state = vec!["design"; n];
    state.extend(vec!["measured"; n]);
    let b = BatchBuilder::new()
        .str("state", &state)
        .f64("phi_rad", phi.iter().chain(&mid).copied().collect())
        .f64(
            "r_mm",
            r.iter()
                .copied()
                .chain(mid.iter().map(|p| ellipse_r(*p, 50.0, 40.0)))
                .collect(),
        )
        .opt_f64(
            "wheel_radius_mm",
            (0..2 * n).map(|k| (k >= n).then_some(170.0)).collect(),
        )
        .build();
    write_parquet_atomic(&dir.join("profile.parquet"), &b).unwrap();
    let toml = "[run]\nid = \"mid\"\nmachine = \"form-grinder\"\nplugin = \"form\"\n\n[process]\nnominal_wheel_radius_mm = 170.0\n";
    write_atomic(&dir.join("run.toml"), toml.as_bytes()).unwrap();
    let out = d.path().join("obs");
    let o = sparkout(&[
        "stage",
        "observe",
        "--run",
        dir.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let obs = read_parquet(&out.join("observations.parquet")).unwrap();
    let f = |c: &str| {
        sparkout_pipeline::contracts::batch_f64(&obs, c)
            .unwrap()
            .to_vec()
    };
    let (sim, real) = (f("sim"), f("real"));
    assert_eq!(sim.len(), n);
    let worst = sim
        .iter()
        .zip(&real)
        .map(|(s, r)| (r - s).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-5, "largest gap {worst} mm");
    assert!(sim.iter().all(|s| s.abs() < 1e-12));
}

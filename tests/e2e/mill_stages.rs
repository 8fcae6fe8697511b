//! The `mill` plugin through the binary: the `kinematics` stage identifies
//! the generated machine's errors within their reported uncertainty with a
//! held-out residual at the noise; unidentifiable configurations and bad
//! tracker points are errors that say what is wrong and where.

use crate::common;
use common::sparkout;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use arrow::array::{Array, Float64Array, Int32Array, StringArray};
use sparkout_pipeline::contracts::{read_parquet, write_parquet_atomic, BatchBuilder};

/// One generated mill run; returns its directory.
fn generate(root: &Path, seed: u64, runs: usize) -> PathBuf {
    let g = sparkout(&[
        "generate",
        "mill",
        "--runs",
        &runs.to_string(),
        "--seed",
        &seed.to_string(),
        "--out",
        root.to_str().unwrap(),
    ]);
    assert!(g.status.success(), "{}", String::from_utf8_lossy(&g.stderr));
    root.join("xfyz-mill/r0000")
}

fn kinematics(run: &Path, out: Option<&Path>) -> std::process::Output {
    let mut args = vec![
        "stage",
        "kinematics",
        "--run",
        run.to_str().unwrap(),
        "--json",
    ];
    if let Some(o) = out {
        args.extend(["--out", o.to_str().unwrap()]);
    }
    sparkout(&args)
}

fn f64s(b: &arrow::record_batch::RecordBatch, name: &str) -> Vec<f64> {
    b.column_by_name(name)
        .unwrap()
        .as_any()
        .downcast_ref::<Float64Array>()
        .unwrap()
        .values()
        .to_vec()
}

fn i32s(b: &arrow::record_batch::RecordBatch, name: &str) -> Vec<i32> {
    b.column_by_name(name)
        .unwrap()
        .as_any()
        .downcast_ref::<Int32Array>()
        .unwrap()
        .values()
        .to_vec()
}

#[test]
fn identification_recovers_the_generated_errors_within_their_uncertainty() {
    let d = tempfile::tempdir().unwrap();
    let run = generate(&d.path().join("runs"), 11, 1);
    let out = d.path().join("out");
    let o = kinematics(&run, Some(&out));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    for k in [
        "params",
        "fit_rms_mm",
        "holdout_rms_mm",
        "before_rms_mm",
        "after_rms_mm",
    ] {
        assert!(s[k].is_number(), "{k} missing: {s:#}");
    }
    // 21 functions of degree 3 in the gauge of chain::min_order + 3
    // squareness + 6 tracker frame.
    assert_eq!(s["params"], 60);
    let truth: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("truth.json")).unwrap()).unwrap();
    let noise = truth["noise_mm"].as_f64().unwrap();
    let truth: BTreeMap<String, f64> = truth["params"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            (
                p["name"].as_str().unwrap().to_string(),
                p["value"].as_f64().unwrap(),
            )
        })
        .collect();
    let p = read_parquet(&out.join("kinematic_params.parquet")).unwrap();
    let names = p
        .column_by_name("name")
        .unwrap()
        .as_any()
        .downcast_ref::<StringArray>()
        .unwrap()
        .clone();
    let (value, sigma) = (f64s(&p, "value"), f64s(&p, "sigma"));
    assert_eq!(names.len(), 60);
    let mut worst = (0.0, String::new());
    for i in 0..names.len() {
        let name = names.value(i);
        let t = truth[name];
        let z = (value[i] - t).abs() / sigma[i];
        assert!(
            z <= 4.0,
            "{name}: estimate {} true {t} σ {} ({z:.1}σ)",
            value[i],
            sigma[i]
        );
        if z > worst.0 {
            worst = (z, name.to_string());
        }
    }
    // Not trivially exact either: the noise shows in the estimates.
    assert!(worst.0 > 0.5, "worst deviation {worst:?}");
    // Residuals at the noise: 3-D RMS of isotropic noise σ is √3·σ.
    let floor = 3f64.sqrt() * noise;
    let hold = s["holdout_rms_mm"].as_f64().unwrap();
    let fit = s["fit_rms_mm"].as_f64().unwrap();
    assert!(
        (0.75..1.35).contains(&(hold / floor)),
        "held-out RMS {hold} vs noise {floor}"
    );
    assert!((0.75..1.2).contains(&(fit / floor)), "fit RMS {fit}");
    // Compensation removes the volumetric error down to about the noise.
    let (before, after) = (
        s["before_rms_mm"].as_f64().unwrap(),
        s["after_rms_mm"].as_f64().unwrap(),
    );
    assert!(before > 2.5 * after, "before {before} after {after}");
    assert!(after < 1.3 * floor, "after {after}");
    // The replay-shaped compensation: t_s strictly increasing, dx/dy/dz.
    let c = read_parquet(&out.join("compensation_path.parquet")).unwrap();
    let t = f64s(&c, "t_s");
    assert!(t.windows(2).all(|w| w[1] > w[0]));
    assert_eq!(f64s(&c, "dz_mm").len(), t.len());
    // The per-axis table covers each travel.
    let tab = read_parquet(&out.join("compensation_table.parquet")).unwrap();
    let pos = f64s(&tab, "pos_mm");
    assert!(pos.contains(&0.0) && pos.contains(&600.0) && pos.contains(&300.0));
}

/// Rewrites a run's tracker.parquet through `edit` (columns by name).
fn edit_tracker(run: &Path, edit: impl Fn(&mut BTreeMap<String, Vec<f64>>, &mut Vec<i32>)) {
    let b = read_parquet(&run.join("tracker.parquet")).unwrap();
    let mut point = i32s(&b, "point");
    let mut cols: BTreeMap<String, Vec<f64>> =
        ["x_mm", "y_mm", "z_mm", "mx_mm", "my_mm", "mz_mm", "t_s"]
            .iter()
            .map(|c| (c.to_string(), f64s(&b, c)))
            .collect();
    edit(&mut cols, &mut point);
    let n = point.len();
    let mut out = BatchBuilder::new().i32("point", point);
    for (k, v) in cols {
        out = out.f64(&k, v);
    }
    // Keep tool and trial for the rows left.
    out = out
        .i32("tool", i32s(&b, "tool")[..n].to_vec())
        .i32("trial", i32s(&b, "trial")[..n].to_vec());
    write_parquet_atomic(&run.join("tracker.parquet"), &out.build()).unwrap();
}

fn stage_error(run: &Path) -> String {
    let o = kinematics(run, None);
    assert!(!o.status.success(), "expected an error");
    String::from_utf8_lossy(&o.stderr).to_string()
}

#[test]
fn unidentifiable_configurations_are_errors_not_fits() {
    let d = tempfile::tempdir().unwrap();
    let root = d.path().join("runs");
    let run = generate(&root, 12, 1);
    let pristine = std::fs::read(run.join("tracker.parquet")).unwrap();

    // Too few points.
    edit_tracker(&run, |c, p| {
        p.truncate(15);
        c.values_mut().for_each(|v| v.truncate(15));
    });
    let e = stage_error(&run);
    assert!(
        e.contains("too few points") && e.contains("tracker.parquet"),
        "{e}"
    );

    // All points on one plane (z fixed).
    std::fs::write(run.join("tracker.parquet"), &pristine).unwrap();
    edit_tracker(&run, |c, _| c.get_mut("z_mm").unwrap().fill(150.0));
    let e = stage_error(&run);
    assert!(e.contains("one plane"), "{e}");

    // One tool offset: the spindle carriage's rotations cannot be seen.
    std::fs::write(run.join("tracker.parquet"), &pristine).unwrap();
    let b = read_parquet(&run.join("tracker.parquet")).unwrap();
    let mut cols = BatchBuilder::new();
    for f in b.schema().fields() {
        if f.name() == "tool" {
            continue;
        }
        cols = cols.column(
            f.as_ref().clone(),
            b.column_by_name(f.name()).unwrap().clone(),
        );
    }
    write_parquet_atomic(&run.join("tracker.parquet"), &cols.build()).unwrap();
    let e = stage_error(&run);
    assert!(
        e.contains("rank-deficient") && e.contains("ez_z") && e.contains("tool offset"),
        "{e}"
    );
}

#[test]
fn bad_tracker_points_name_file_column_and_row_and_the_batch_goes_on() {
    let d = tempfile::tempdir().unwrap();
    let root = d.path().join("runs");
    generate(&root, 13, 3);
    let nan_run = root.join("xfyz-mill/r0000");
    let dup_run = root.join("xfyz-mill/r0001");
    edit_tracker(&nan_run, |c, _| c.get_mut("my_mm").unwrap()[7] = f64::NAN);
    edit_tracker(&dup_run, |_, p| p[12] = p[3]);

    let e = stage_error(&nan_run);
    assert!(
        e.contains("tracker.parquet") && e.contains("`my_mm`") && e.contains("row 7"),
        "{e}"
    );
    let e = stage_error(&dup_run);
    assert!(
        e.contains("tracker.parquet")
            && e.contains("`point`")
            && e.contains("row 12")
            && e.contains("duplicated point id"),
        "{e}"
    );

    // In a batch: both rejected with those messages, the third run goes on.
    let out = d.path().join("out");
    let r = sparkout(&[
        "run",
        "--input",
        root.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        !r.status.success(),
        "a batch with rejected runs must say so"
    );
    let failures = std::fs::read_to_string(out.join("failures.json")).unwrap();
    assert!(
        failures.contains("row 7") && failures.contains("duplicated point id"),
        "{failures}"
    );
    assert!(out
        .join("xfyz-mill/r0002/kinematic_params.parquet")
        .is_file());
    assert!(!out.join("xfyz-mill/r0000").exists());
}

#[test]
fn observations_pair_measured_and_modelled_deviations_and_leave_absent_covariates_out() {
    let d = tempfile::tempdir().unwrap();
    let run = generate(&d.path().join("runs"), 14, 1);
    let observe = |out: &Path| {
        let o = sparkout(&[
            "stage",
            "observe",
            "--run",
            run.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--json",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        read_parquet(&out.join("observations.parquet")).unwrap()
    };
    let with = observe(&d.path().join("with"));
    let n = with.num_rows();
    assert_eq!(n % 3, 0);
    for c in ["sim", "real", "x_mm", "y_mm", "z_mm", "t_s", "temp_c"] {
        assert!(with.column_by_name(c).is_some(), "{c}");
    }
    // The gap is the identification residual: at the noise (2 µm) in x and y.
    let (sim, real) = (f64s(&with, "sim"), f64s(&with, "real"));
    let gap_rms = |r: std::ops::Range<usize>| {
        (r.clone().map(|i| (real[i] - sim[i]).powi(2)).sum::<f64>() / r.len() as f64).sqrt()
    };
    assert!(
        gap_rms(0..n / 3) < 0.003,
        "tracker_dx gap {}",
        gap_rms(0..n / 3)
    );
    // sim carries the machine's volumetric error, not zero.
    assert!(sim.iter().map(|s| s.abs()).fold(0.0, f64::max) > 0.005);
    // No thermal log: temp_c is left out (docs/formats.md §7), t_s stays.
    std::fs::remove_file(run.join("thermal.parquet")).unwrap();
    let without = observe(&d.path().join("without"));
    assert!(without.column_by_name("temp_c").is_none());
    assert!(without.column_by_name("t_s").is_some());
    assert_eq!(without.num_rows(), n);
}

//! The ad hoc paths through the binary: `stage` (with a run and run-less),
//! `generate observations` → `diagnose`, `validate --quick`.

use crate::common;
use common::sparkout;

use std::process::Output;

fn json(out: &Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("stdout is JSON")
}

#[test]
fn runless_cycle_reproduces_the_thesis_sequence() {
    let v = json(&sparkout(&[
        "stage",
        "cycle",
        "--weld-mm",
        "2.27",
        "--rough",
        "7",
        "--finish",
        "2",
        "--spark",
        "2",
        "--doc-rough",
        "0.3",
        "--doc-finish",
        "0.1",
        "--first-cut",
        "0.2",
        "--json",
    ]));
    assert!((v["alpha_first_pass"].as_f64().unwrap() - 0.5).abs() < 1e-9);
    let cuts: Vec<f64> = v["passes"]
        .as_array()
        .unwrap()
        .iter()
        .take(7)
        .map(|p| p["predicted_cut_mm"].as_f64().unwrap())
        .collect();
    let thesis = [0.200, 0.2667, 0.2889, 0.2963, 0.2988, 0.2996, 0.2999];
    for (c, t) in cuts.iter().zip(thesis) {
        assert!((c - t).abs() < 6e-5, "{cuts:?}");
    }
    assert!((v["remaining_after_mm"]["rough"].as_f64().unwrap() - 0.3199).abs() < 1e-3);
}

#[test]
fn runless_datum_intersects_three_planes() {
    let v = json(&sparkout(&[
        "stage",
        "datum",
        "--planes",
        "0,0,1,12.5;1,0,0,-20;0,1,0,-13",
        "--json",
    ]));
    let d: Vec<f64> = v["datum_mm"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    let want = [20.0, 13.0, -12.5];
    for (a, b) in d.iter().zip(want) {
        assert!((a - b).abs() < 1e-9, "{d:?}");
    }
    // Nearly parallel planes: an error, not a wild number.
    let o = sparkout(&[
        "stage",
        "datum",
        "--planes",
        "0,0,1,1;0,0.0001,1,2;0,1,0,-13",
        "--json",
    ]);
    assert!(!o.status.success());
}

#[test]
fn stage_with_a_run_writes_its_artifacts() {
    let d = tempfile::tempdir().unwrap();
    let root = d.path().join("runs");
    let g = sparkout(&[
        "generate",
        "robot",
        "--runs",
        "1",
        "--seed",
        "4",
        "--out",
        root.to_str().unwrap(),
        "--ae-rate-hz",
        "100000",
    ]);
    assert!(g.status.success());
    let run = root.join("kr16-lab/r0000");
    let out = d.path().join("st");
    let v = json(&sparkout(&[
        "stage",
        "repeatability",
        "--run",
        run.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--json",
    ]));
    assert!(v["groups"].as_array().unwrap().len() >= 2);
    assert!(out.join("repeatability.parquet").is_file());
    // Unknown stage: a clear error.
    let o = sparkout(&["stage", "nosuch", "--run", run.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("no stage `nosuch`"));
}

#[test]
fn generated_observations_are_diagnosed() {
    let d = tempfile::tempdir().unwrap();
    let obs = d.path().join("obs.parquet");
    let g = sparkout(&[
        "generate",
        "observations",
        "--runs",
        "8",
        "--seed",
        "3",
        "--out",
        obs.to_str().unwrap(),
        "--effect",
        "drift:t_s=amplitude_mm=0.02,tau_s=600",
    ]);
    assert!(g.status.success(), "{}", String::from_utf8_lossy(&g.stderr));
    let out = d.path().join("diag");
    let v = json(&sparkout(&[
        "diagnose",
        obs.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--json",
    ]));
    assert_eq!(v["version"], 1);
    assert_eq!(v["selected"][0], "drift:t_s");
    let tau = v["effects"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["selected"] == true)
        .unwrap()["params"]["tau_s"]
        .as_f64()
        .unwrap();
    assert!((tau - 600.0).abs() < 200.0, "tau {tau}");
    for f in [
        "diagnosis.json",
        "diagnosis.parquet",
        "augmented_model.json",
        "report.html",
    ] {
        assert!(out.join(f).is_file(), "{f}");
    }
}

/// observations v1.1 `unit`: one observable with two units is refused with
/// the file, column and row; a consistent `unit` is carried into
/// per_observable.
#[test]
fn observation_units_are_checked_and_reported() {
    use std::sync::Arc;
    let d = tempfile::tempdir().unwrap();
    let write = |name: &str, units: Vec<Option<&str>>| {
        let n = units.len();
        let batch = arrow::record_batch::RecordBatch::try_from_iter([
            (
                "run",
                Arc::new(arrow::array::StringArray::from(
                    (0..n).map(|i| format!("r{}", i % 4)).collect::<Vec<_>>(),
                )) as arrow::array::ArrayRef,
            ),
            (
                "observable",
                Arc::new(arrow::array::StringArray::from(vec!["velocity_error_x"; n])),
            ),
            ("unit", Arc::new(arrow::array::StringArray::from(units))),
            (
                "sim",
                Arc::new(arrow::array::Float64Array::from(vec![0.0; n])),
            ),
            (
                "real",
                Arc::new(arrow::array::Float64Array::from(
                    (0..n)
                        .map(|i| 0.01 * ((i * 7919) % 13) as f64)
                        .collect::<Vec<_>>(),
                )),
            ),
            (
                "t_s",
                Arc::new(arrow::array::Float64Array::from(
                    (0..n).map(|i| i as f64).collect::<Vec<_>>(),
                )),
            ),
        ])
        .unwrap();
        let p = d.path().join(name);
        let mut w = parquet::arrow::ArrowWriter::try_new(
            std::fs::File::create(&p).unwrap(),
            batch.schema(),
            None,
        )
        .unwrap();
        w.write(&batch).unwrap();
        w.close().unwrap();
        p
    };
    let mut mixed = vec![Some("mm/s"); 40];
    mixed[17] = Some("mm");
    let bad = write("mixed.parquet", mixed);
    let o = sparkout(&[
        "diagnose",
        bad.to_str().unwrap(),
        "--out",
        d.path().join("o1").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("mixed.parquet") && err.contains("`unit`") && err.contains("row 17"),
        "{err}"
    );
    let good = write("good.parquet", vec![Some("mm/s"); 40]);
    let v = json(&sparkout(&[
        "diagnose",
        good.to_str().unwrap(),
        "--out",
        d.path().join("o2").to_str().unwrap(),
        "--json",
    ]));
    assert_eq!(v["per_observable"][0]["unit"], "mm/s", "{v:#}");
}

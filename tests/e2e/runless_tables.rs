//! Run-less forms for a single table:
//! `stage flatness --surface FILE` and `stage ingest --ae FILE`, on
//! fixtures written by pyarrow and pandas (datasets/fixtures/adhoc, made by
//! datasets/fixtures/make_fixtures.py). The expected flatness comes from
//! numpy least squares and scipy's LP solver (HiGHS), not from sparkout.

use std::path::PathBuf;

use crate::common::sparkout;

fn adhoc(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("datasets/fixtures/adhoc")
        .join(name)
}

fn expected() -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(adhoc("expected.json")).unwrap()).unwrap()
}

fn json_ok(args: &[&str]) -> serde_json::Value {
    let o = sparkout(args);
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&o.stdout).expect("stdout is JSON")
}

fn assert_flatness(got: &serde_json::Value, want: &serde_json::Value) {
    assert_eq!(got["n"], want["n"], "{got}");
    for k in ["least_squares_mm", "min_zone_mm"] {
        let (g, w) = (got[k].as_f64().unwrap(), want[k].as_f64().unwrap());
        // Two LP solvers agree to rounding; 1 nm is far below any gauge.
        assert!((g - w).abs() < 1e-6 * w.max(1e-3), "{k}: {g} vs {w}");
    }
    assert!(got["min_zone_mm"].as_f64() <= got["least_squares_mm"].as_f64());
    let keys: Vec<&String> = got.as_object().unwrap().keys().collect();
    // `areal`: ISO 25178-2 heights and spikes (tests/e2e/metrology.rs).
    assert_eq!(keys, ["areal", "least_squares_mm", "min_zone_mm", "n"]);
}

#[test]
fn flatness_of_an_xyz_table_in_micrometres_with_foreign_column_names() {
    let f = adhoc("surface_xyz_um.parquet");
    let got = json_ok(&[
        "stage",
        "flatness",
        "--surface",
        f.to_str().unwrap(),
        "--x",
        "X",
        "--y",
        "Y",
        "--z",
        "height_um",
        "--unit-scale",
        "0.001",
        "--json",
    ]);
    assert_flatness(&got, &expected()["surface_xyz_um"]);
}

#[test]
fn flatness_of_a_gridded_map_with_holes() {
    let f = adhoc("surface_grid.parquet");
    let got = json_ok(&[
        "stage",
        "flatness",
        "--surface",
        f.to_str().unwrap(),
        "--json",
    ]);
    assert_flatness(&got, &expected()["surface_grid"]);
}

#[test]
fn flatness_errors_name_the_file_and_column() {
    let f = adhoc("surface_xyz_um.parquet");
    let o = sparkout(&[
        "stage",
        "flatness",
        "--surface",
        f.to_str().unwrap(),
        "--x",
        "X",
        "--y",
        "Y",
        "--z",
        "note",
        "--json",
    ]);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("surface_xyz_um.parquet") && e.contains("`note`"),
        "{e}"
    );
    let o = sparkout(&[
        "stage",
        "flatness",
        "--surface",
        f.to_str().unwrap(),
        "--x",
        "X",
        "--y",
        "nope",
        "--z",
        "height_um",
    ]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("`nope`"));
}

#[test]
fn ingest_finds_the_bursts_of_any_signal_column() {
    let want = &expected()["ae_series"];
    let fs = want["sample_rate_hz"].as_f64().unwrap();
    let f = adhoc("ae_series.parquet");
    let got = json_ok(&[
        "stage",
        "ingest",
        "--ae",
        f.to_str().unwrap(),
        "--sample-rate-hz",
        &fs.to_string(),
        "--column",
        "sensor_ch2",
        "--json",
    ]);
    let keys: Vec<&String> = got.as_object().unwrap().keys().collect();
    assert_eq!(keys, ["contacts", "params", "threshold", "warnings"]);
    // A raw voltage (it goes negative): an RMS envelope over 1 ms, no warning.
    assert_eq!(got["params"]["signal"], "raw", "{got}");
    assert_eq!(got["params"]["signal_from"], "guessed from the signal");
    assert_eq!(
        got["warnings"].as_array().map(|w| w.len()),
        Some(0),
        "{got}"
    );
    let threshold = got["threshold"].as_f64().unwrap();
    let contacts = got["contacts"].as_array().unwrap();
    let onsets: Vec<f64> = want["onsets_s"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(contacts.len(), onsets.len(), "{got}");
    let burst_s = want["burst_s"].as_f64().unwrap();
    for (c, t0) in contacts.iter().zip(&onsets) {
        let (s, e, peak) = (
            c["start_s"].as_f64().unwrap(),
            c["end_s"].as_f64().unwrap(),
            c["peak"].as_f64().unwrap(),
        );
        // Onset within the 1 ms RMS window (+ dwell) of the burst's start.
        assert!(s >= t0 - 1e-4 && s <= t0 + 2e-3, "start {s} vs {t0}");
        assert!(e > s && e <= t0 + burst_s + 5e-3, "end {e}");
        assert!(peak > threshold, "{peak} <= {threshold}");
    }
    // A pure-noise channel has no contact: an empty list, not an error.
    let quiet = json_ok(&[
        "stage",
        "ingest",
        "--ae",
        f.to_str().unwrap(),
        "--sample-rate-hz",
        &fs.to_string(),
        "--column",
        "noise_v",
        "--json",
    ]);
    assert_eq!(quiet["contacts"].as_array().unwrap().len(), 0, "{quiet}");
}

#[test]
fn ingest_errors_name_the_file_and_column() {
    let f = adhoc("ae_series.parquet");
    let o = sparkout(&[
        "stage",
        "ingest",
        "--ae",
        f.to_str().unwrap(),
        "--sample-rate-hz",
        "50000",
        "--column",
        "ch9",
    ]);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("ae_series.parquet") && e.contains("`ch9`"),
        "{e}"
    );
    let o = sparkout(&["stage", "ingest", "--ae", f.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("--sample-rate-hz"));
}

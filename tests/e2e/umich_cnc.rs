//! The public UMich CNC mill set end to end through the
//! binary — all 18 experiments of the committed sample imported with the
//! built-in `umich_cnc` mapping, run through the servo plugin and the fleet
//! diagnosis. Pins what was verified by hand (docs/servo.md "UMich CNC"): which
//! effect is named per axis and the range of its parameter — not exact
//! floats, so the diagnosis stays free to improve.

use crate::common::{self, sparkout};

use std::path::Path;

fn sample_files() -> Vec<String> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("datasets/samples/umich_cnc");
    let mut v: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.to_string_lossy().ends_with(".csv.gz"))
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

fn per<'a>(d: &'a serde_json::Value, observable: &str) -> &'a serde_json::Value {
    d["per_observable"]
        .as_array()
        .unwrap()
        .iter()
        .find(|o| o["observable"] == observable)
        .unwrap_or_else(|| panic!("no observable {observable}"))
}

fn selected<'a>(d: &'a serde_json::Value, observable: &str, key: &str) -> &'a serde_json::Value {
    d["effects"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| {
            e["observable"] == observable
                && e["selected"].as_bool() == Some(true)
                && format!(
                    "{}:{}",
                    e["name"].as_str().unwrap(),
                    e["covariate"].as_str().unwrap_or("")
                ) == key
        })
        .unwrap_or_else(|| panic!("{key} not selected on {observable}: {}", per(d, observable)))
}

#[test]
fn umich_cnc_imports_and_diagnoses_every_axis() {
    let files = sample_files();
    assert_eq!(files.len(), 18, "{files:?}");
    let d = tempfile::tempdir().unwrap();
    let runs = d.path().join("runs");
    let out = d.path().join("out");
    let mut args = vec!["import"];
    args.extend(files.iter().map(|s| s.as_str()));
    args.extend(["--mapping", "umich_cnc", "--out", runs.to_str().unwrap()]);
    let o = sparkout(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        std::fs::read_dir(runs.join("umich-cnc")).unwrap().count(),
        18
    );
    let diag: serde_json::Value = common::run_fleet_diagnosis(&runs, &out);
    for axis in ["x", "y", "z"] {
        // Positions are logged to three significant figures (1 mm / 0.1 mm
        // steps): the following-error gap is at that resolution, and the
        // diagnosis says so instead of fitting rounding noise.
        let obs = format!("following_error_{axis}");
        let p = per(&diag, &obs);
        assert_eq!(p["runs"], 18, "{p}");
        assert_eq!(p["gap_above_noise"], false, "{obs}: {p}");
        assert!(p["noise_floor_mm"].as_f64().unwrap() > 0.1, "{p}");
        // The finer velocity signals carry the servo's departure from the
        // model: actual velocity ∝ commanded velocity, a few per cent high
        // — a scale of the velocity signal, not the rate of a lag, so
        // named by its shape (`lag` of the catalogue, not `servo_lag`,
        // which on a velocity error is k·a).
        let obs = format!("velocity_error_{axis}");
        let p = per(&diag, &obs);
        assert_eq!(p["gap_above_noise"], true, "{obs}: {p}");
        let k = selected(&diag, &obs, "lag:cmd_v_mm_s")["params"]["k"]
            .as_f64()
            .unwrap();
        assert!((0.02..0.10).contains(&k), "{obs}: lag k {k}");
        // Each axis' effective lag (follow stage): ≈ 8 ms, a quarter of
        // the default model's 33 ms.
        let mut lags: Vec<f64> = std::fs::read_dir(out.join("umich-cnc"))
            .unwrap()
            .filter_map(|e| {
                let f = e.unwrap().path().join("follow.json");
                let j: serde_json::Value = serde_json::from_slice(&std::fs::read(f).ok()?).ok()?;
                j["axes"][axis]["effective_lag_s"].as_f64()
            })
            .collect();
        assert_eq!(lags.len(), 18);
        lags.sort_by(f64::total_cmp);
        let median = lags[9];
        assert!(
            (0.005..0.012).contains(&median),
            "{axis}: median lag {median} s"
        );
    }
    for axis in ["x", "y"] {
        // Acceleration-proportional velocity error, negative: the actual
        // velocity trails the commanded velocity's changes — on a velocity
        // error the form of a lag (the rate of k·v), named servo_lag.
        let obs = format!("velocity_error_{axis}");
        let k = selected(&diag, &obs, "servo_lag:cmd_a_mm_s2")["params"]["k"]
            .as_f64()
            .unwrap();
        assert!((-0.01..-0.002).contains(&k), "{obs}: servo_lag k {k} s");
    }
}

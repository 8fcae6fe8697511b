//! Issue 7 (form), end to end through the binary: a generated form fleet
//! with one injected effect, run through `sparkout run`, gets that effect
//! named first in out/fleet/diagnosis.json with a positive held-out shrink;
//! an effect-free fleet gets no effect named.

mod common;
use common::sparkout;

use std::path::Path;

fn diagnose_fleet(dir: &Path, seed: u64, effect: Option<&str>) -> serde_json::Value {
    let root = dir.join("runs");
    let out = dir.join("out");
    let seed = seed.to_string();
    let mut args = vec![
        "generate",
        "form",
        "--runs",
        "9",
        "--seed",
        &seed,
        "--out",
        root.to_str().unwrap(),
    ];
    if let Some(e) = effect {
        args.extend(["--effect", e]);
    }
    let g = sparkout(&args);
    assert!(g.status.success(), "{}", String::from_utf8_lossy(&g.stderr));
    let r = sparkout(&[
        "run",
        "--input",
        root.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        r.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&r.stdout),
        String::from_utf8_lossy(&r.stderr)
    );
    serde_json::from_slice(&std::fs::read(out.join("fleet/diagnosis.json")).unwrap()).unwrap()
}

fn first_selected(d: &serde_json::Value) -> String {
    d["selected"]
        .as_array()
        .and_then(|a| a.first())
        .and_then(|s| s.as_str())
        .unwrap_or("")
        .to_string()
}

fn shrink_of(d: &serde_json::Value, key: &str) -> f64 {
    d["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["selected"].as_bool() == Some(true))
        .find(|e| match e["covariate"].as_str() {
            Some(c) => format!("{}:{c}", e["name"].as_str().unwrap()) == key,
            None => e["name"].as_str() == Some(key),
        })
        .and_then(|e| e["shrink"].as_f64())
        .unwrap_or(f64::NAN)
}

/// Wheel wear between dressings: the plugin's physically named composite
/// (wear on the volume removed since the last dressing) comes first.
#[test]
fn wheel_wear_between_dressings_is_named_first() {
    let d = tempfile::tempdir().unwrap();
    let diag = diagnose_fleet(d.path(), 41, Some("wheel_wear"));
    let first = first_selected(&diag);
    assert_eq!(
        first, "wheel_wear:removed_mm3",
        "selected {}",
        diag["selected"]
    );
    let shrink = shrink_of(&diag, &first);
    assert!(shrink > 0.5, "held-out shrink {shrink}: {diag:#}");
    // The wear rate is recovered: the generator's default 1.5e-5 mm/mm³.
    let k = diag["effects"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["name"] == "wheel_wear")
        .and_then(|e| e["params"]["k"].as_f64())
        .unwrap();
    assert!((k / 1.5e-5 - 1.0).abs() < 0.1, "k = {k}");
    // The whole selection's held-out gap is near the measurement noise.
    let un = diag["unexplained"]["rms_mm"].as_f64().unwrap();
    assert!(
        un < 0.3 * diag["gap"]["rms_mm"].as_f64().unwrap(),
        "{diag:#}"
    );
}

/// Work-spindle run-out (periodic in φ) is named as periodic in phi_rad.
#[test]
fn runout_is_named_periodic_in_phi() {
    let d = tempfile::tempdir().unwrap();
    let diag = diagnose_fleet(d.path(), 42, Some("runout"));
    let first = first_selected(&diag);
    assert_eq!(first, "periodic:phi_rad", "selected {}", diag["selected"]);
    assert!(shrink_of(&diag, &first) > 0.5, "{diag:#}");
}

#[test]
fn effect_free_form_fleet_names_nothing() {
    let d = tempfile::tempdir().unwrap();
    let diag = diagnose_fleet(d.path(), 43, None);
    assert_eq!(diag["selected"], serde_json::json!([]), "{diag:#}");
}

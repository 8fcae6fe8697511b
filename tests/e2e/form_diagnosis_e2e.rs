//! End to end through the binary: a generated form fleet
//! with one injected effect, run through `sparkout run`, gets that effect
//! named first in out/fleet/diagnosis.json with a positive held-out shrink;
//! an effect-free fleet gets no effect named.

use crate::common;
use common::{diagnose_generated_fleet, first_selected, shrink_of};

use std::path::Path;

/// Wheel wear between dressings: the plugin's physically named composite
/// (wear on the volume removed since the last dressing) comes first.
fn diagnose_fleet(dir: &Path, seed: u64, effect: Option<&str>) -> serde_json::Value {
    diagnose_generated_fleet(dir, "form", 9, seed, effect, &[])
}

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

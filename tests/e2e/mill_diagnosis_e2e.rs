//! End to end through the binary: a generated mill fleet with one
//! injected effect outside the identified 21-error model, run through
//! `sparkout run`, gets that effect named first in the fleet's
//! diagnosis.json with a held-out shrink; an effect-free fleet gets none.

use crate::common;
use common::{diagnose_generated_fleet, first_selected, selected_entry};

use std::path::Path;

fn diagnose_fleet(dir: &Path, seed: u64, effect: Option<&str>) -> serde_json::Value {
    diagnose_generated_fleet(dir, "mill", 6, seed, effect, &[])
}

#[test]
fn thermal_growth_is_named_first() {
    let d = tempfile::tempdir().unwrap();
    let diag = diagnose_fleet(d.path(), 21, Some("thermal_growth"));
    let first = first_selected(&diag);
    // Physically one thing: growth that follows the warm-up in time
    // (the mill's `thermal_growth` = drift on t_s) or, since the spindle
    // sensor warms with it, the catalogue's expansion with temperature.
    assert!(
        first == "thermal_growth:t_s" || first == "thermal:temp_c",
        "expected thermal growth first, got {first:?}; selected {}",
        diag["selected"]
    );
    let e = selected_entry(&diag, &first)
        .unwrap_or_else(|| panic!("no selected entry {first}: {diag:#}"));
    assert_eq!(e["observable"], "tracker_dz", "{e:#}");
    assert!(e["shrink"].as_f64().unwrap() > 0.3, "{e:#}");
    if first == "thermal_growth:t_s" {
        let tau = e["params"]["tau_s"].as_f64().unwrap();
        assert!((300.0..1200.0).contains(&tau), "τ {tau} (true 600 s)");
    } else {
        // 0.025 mm of growth while temp_c (the mean of the spindle sensor,
        // +6 °C, and the bed sensor, steady) rises by 3 °C.
        let k = e["params"]["k"].as_f64().unwrap();
        assert!((0.006..0.011).contains(&k), "k {k} mm/°C (true ≈ 0.0083)");
    }
}

#[test]
fn waviness_beyond_the_polynomial_degree_is_named_periodic_in_x() {
    let d = tempfile::tempdir().unwrap();
    let diag = diagnose_fleet(d.path(), 22, Some("x_waviness"));
    assert_eq!(
        first_selected(&diag),
        "periodic:x_mm",
        "{}",
        diag["selected"]
    );
    let e = selected_entry(&diag, "periodic:x_mm").expect("periodic:x_mm selected");
    let lambda = e["params"]["lambda"].as_f64().unwrap();
    assert!((lambda - 75.0).abs() < 5.0, "λ {lambda} (true 75 mm)");
    assert!(e["shrink"].as_f64().unwrap() > 0.2, "{e:#}");
}

#[test]
fn effect_free_mill_fleet_names_nothing() {
    let d = tempfile::tempdir().unwrap();
    let diag = diagnose_fleet(d.path(), 23, None);
    assert_eq!(diag["selected"], serde_json::json!([]), "{diag:#}");
}

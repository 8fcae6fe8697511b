//! End to end through the binary: a generated gantry fleet
//! with one injected (unmodelled) effect, run through `sparkout run`, gets
//! that effect named first in the fleet's diagnosis.json with a held-out
//! shrink; an effect-free fleet gets no effect named.

use crate::common;
use common::{diagnose_generated_fleet, first_selected, shrink_of};

use std::path::Path;

fn diagnose_fleet(dir: &Path, seed: u64, effect: Option<&str>) -> serde_json::Value {
    diagnose_generated_fleet(dir, "gantry", 6, seed, effect, &[])
}

#[test]
fn thermal_bow_is_named_first() {
    let d = tempfile::tempdir().unwrap();
    let diag = diagnose_fleet(d.path(), 51, Some("thermal_bow"));
    let first = first_selected(&diag);
    assert!(
        first.starts_with("thermal_bow:"),
        "expected thermal_bow first, got {first:?}; selected {}",
        diag["selected"]
    );
    assert!(shrink_of(&diag, &first) > 0.2, "{diag:#}");
}

#[test]
fn raster_end_pressure_is_named_first() {
    let d = tempfile::tempdir().unwrap();
    let diag = diagnose_fleet(d.path(), 52, Some("raster_end_pressure"));
    let first = first_selected(&diag);
    assert!(
        first.starts_with("raster_end_pressure:"),
        "expected raster_end_pressure first, got {first:?}; selected {}",
        diag["selected"]
    );
    assert!(shrink_of(&diag, &first) > 0.2, "{diag:#}");
}

#[test]
fn effect_free_fleet_names_nothing() {
    let d = tempfile::tempdir().unwrap();
    let diag = diagnose_fleet(d.path(), 53, None);
    assert_eq!(diag["selected"], serde_json::json!([]), "{diag:#}");
}

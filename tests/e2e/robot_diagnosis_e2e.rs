//! End to end through the binary: a generated robot fleet
//! with one injected (unmodelled) effect, run through `sparkout run`, gets
//! that effect named first in the fleet's diagnosis.json with a held-out
//! shrink; an effect-free fleet gets no effect named.

use crate::common;
use common::{diagnose_generated_fleet, first_selected, shrink_of};

use std::path::Path;

fn diagnose_fleet(dir: &Path, seed: u64, effect: Option<&str>) -> serde_json::Value {
    diagnose_generated_fleet(dir, "robot", 8, seed, effect, &["--ae-rate-hz", "100000"])
}

#[test]
fn wheel_wear_is_named_first() {
    let d = tempfile::tempdir().unwrap();
    let diag = diagnose_fleet(d.path(), 31, Some("wheel_wear"));
    let first = first_selected(&diag);
    // The catalogue's name: the form plugin's `wheel_wear` composite is
    // scoped to the form grinder's observables.
    assert!(
        first == "wear:removed_mm3",
        "expected wear first, got {first:?}; selected {}",
        diag["selected"]
    );
    assert!(shrink_of(&diag, &first) > 0.2, "{diag:#}");
}

#[test]
fn trigger_latency_is_named_first() {
    let d = tempfile::tempdir().unwrap();
    let diag = diagnose_fleet(d.path(), 32, Some("trigger_latency"));
    let first = first_selected(&diag);
    // The robot's own composite replaces the catalogue `lag` on the
    // approach speed for the robot's observables.
    assert!(
        first.starts_with("trigger_latency:"),
        "expected trigger latency first, got {first:?}; selected {}",
        diag["selected"]
    );
    assert!(shrink_of(&diag, &first) > 0.2, "{diag:#}");
}

#[test]
fn effect_free_fleet_names_nothing() {
    let d = tempfile::tempdir().unwrap();
    let diag = diagnose_fleet(d.path(), 33, None);
    assert_eq!(diag["selected"], serde_json::json!([]), "{diag:#}");
}

/// A compliance that grows with the depth of cut also shortens the first
/// pass, from which the model's α is calibrated: the gap is the loss seen
/// through that calibration (docs/models.md §1.4), which the robot's
/// `depth_compliance` models — named, with the generator's k = 0.2 /mm
/// inside its interval. The loss's own form k·δ′² left the gap to
/// `drift:t_s` / `periodic:t_s` / `wear:removed_mm3` before.
#[test]
fn depth_compliance_is_named_first_with_its_k() {
    let d = tempfile::tempdir().unwrap();
    let diag = diagnose_fleet(d.path(), 34, Some("compliance"));
    let first = first_selected(&diag);
    assert_eq!(
        first, "depth_compliance:compliance_response_mm2",
        "selected {}",
        diag["selected"]
    );
    assert!(shrink_of(&diag, &first) > 0.5, "{diag:#}");
    let e = common::selected_entry(&diag, &first).unwrap();
    let k = &e["intervals"]["k"];
    let (lo, hi) = (k["lo"].as_f64().unwrap(), k["hi"].as_f64().unwrap());
    assert!(lo < 0.2 && 0.2 < hi, "k interval {lo} … {hi}: {e:#}");
}

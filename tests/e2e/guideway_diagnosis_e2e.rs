//! End to end through the binary: a generated guide-way
//! fleet with one injected effect (thermal deformation growing with the
//! infeed count; a table reversal error), run through `sparkout run`, gets
//! that effect named first in the fleet's diagnosis.json, with a held-out
//! shrink.

use crate::common;
use common::{diagnose_generated_fleet, first_selected, shrink_of};

use std::path::Path;

fn diagnose_fleet(dir: &Path, seed: u64, effect: &str) -> serde_json::Value {
    diagnose_generated_fleet(dir, "guideway", 6, seed, Some(effect), &[])
}

#[test]
fn thermal_growth_with_infeed_count_is_named_first() {
    let d = tempfile::tempdir().unwrap();
    let diag = diagnose_fleet(d.path(), 41, "thermal_infeed");
    let first = first_selected(&diag);
    assert_eq!(
        first, "thermal_infeed:infeed_count",
        "selected {}",
        diag["selected"]
    );
    assert!(shrink_of(&diag, &first) > 0.3, "{diag:#}");
}

#[test]
fn table_reversal_error_is_named_first() {
    let d = tempfile::tempdir().unwrap();
    let diag = diagnose_fleet(d.path(), 42, "reversal");
    let first = first_selected(&diag);
    assert_eq!(first, "backlash:dir", "selected {}", diag["selected"]);
    assert!(shrink_of(&diag, &first) > 0.3, "{diag:#}");
}

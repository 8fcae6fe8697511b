//! Issue 6 item 6, end to end through the binary: a generated guide-way
//! fleet with one injected effect (thermal deformation growing with the
//! infeed count; a table reversal error), run through `sparkout run`, gets
//! that effect named first in the fleet's diagnosis.json, with a held-out
//! shrink.

mod common;
use common::sparkout;

use std::path::Path;

fn diagnose_fleet(dir: &Path, seed: u64, effect: &str) -> serde_json::Value {
    let root = dir.join("runs");
    let out = dir.join("out");
    let seed = seed.to_string();
    let g = sparkout(&[
        "generate",
        "guideway",
        "--runs",
        "6",
        "--seed",
        &seed,
        "--out",
        root.to_str().unwrap(),
        "--effect",
        effect,
    ]);
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

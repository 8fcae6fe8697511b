//! Issue 5 item 8, end to end through the binary: a generated gantry fleet
//! with one injected (unmodelled) effect, run through `sparkout run`, gets
//! that effect named first in the fleet's diagnosis.json with a held-out
//! shrink; an effect-free fleet gets no effect named.

mod common;
use common::sparkout;

use std::path::Path;

fn diagnose_fleet(dir: &Path, seed: u64, effect: Option<&str>) -> serde_json::Value {
    let root = dir.join("runs");
    let out = dir.join("out");
    let seed = seed.to_string();
    let mut args = vec![
        "generate",
        "gantry",
        "--runs",
        "6",
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
            None => e["name"].as_str().unwrap() == key,
        })
        .and_then(|e| e["shrink"].as_f64())
        .unwrap_or(f64::NAN)
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

//! Issue 3 item 8, end to end through the binary: a generated robot fleet
//! with one injected (unmodelled) effect, run through `sparkout run`, gets
//! that effect named first in the fleet's diagnosis.json with a held-out
//! shrink; an effect-free fleet gets no effect named.

mod common;
use common::sparkout;

use std::path::Path;

fn diagnose_fleet(dir: &Path, seed: u64, effect: Option<&str>) -> serde_json::Value {
    let root = dir.join("runs");
    let out = dir.join("out");
    let runs = "8";
    let seed = seed.to_string();
    let mut args = vec![
        "generate",
        "robot",
        "--runs",
        runs,
        "--seed",
        &seed,
        "--out",
        root.to_str().unwrap(),
        "--ae-rate-hz",
        "100000",
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

/// The selected effect's held-out shrink, from its `effects` entry.
fn shrink_of(d: &serde_json::Value, key: &str) -> f64 {
    d["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["selected"].as_bool() == Some(true))
        .find(|e| {
            let k = match e["covariate"].as_str() {
                Some(c) => format!("{}:{c}", e["name"].as_str().unwrap()),
                None => e["name"].as_str().unwrap().to_string(),
            };
            k == key
        })
        .and_then(|e| e["shrink"].as_f64())
        .unwrap_or(f64::NAN)
}

#[test]
fn wheel_wear_is_named_first() {
    let d = tempfile::tempdir().unwrap();
    let diag = diagnose_fleet(d.path(), 31, Some("wheel_wear"));
    let first = first_selected(&diag);
    // `wheel_wear` is the form plugin's composite name for the same
    // catalogue wear on removed_mm3 (plugin composites apply fleet-wide).
    assert!(
        first == "wear:removed_mm3" || first == "wheel_wear:removed_mm3",
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
    // Physically one thing: a lag in the approach speed along the normal
    // (catalogue `lag`, or the robot's composite `trigger_latency`).
    assert!(
        first.starts_with("trigger_latency:") || first.starts_with("lag:approach"),
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

//! Confounding said out loud, through the binary: line-start heights of
//! raster scans on a warming sample (`sparkout generate raster`) carry a
//! thermal effect while the line position advances with the temperature in
//! every run. The diagnosis must say that a position effect explains these
//! runs as well (`indistinguishable_from`, printed), and that x_mm and
//! temp_c move together, with advice. On runs that vary scan direction and
//! start time (`raster-varied`) the same effect is named alone, without
//! the note.

use crate::common::sparkout;

use std::path::Path;

/// Generates `what` with a thermal effect and diagnoses it: diagnosis.json
/// and what `sparkout diagnose` printed.
fn diagnose_raster(dir: &Path, what: &str, seed: u64) -> (serde_json::Value, String) {
    let obs = dir.join("obs.parquet");
    let seed = seed.to_string();
    let g = sparkout(&[
        "generate",
        what,
        "--runs",
        "4",
        "--seed",
        &seed,
        "--effect",
        "thermal:temp_c=k=0.002",
        "--out",
        obs.to_str().unwrap(),
    ]);
    assert!(g.status.success(), "{}", String::from_utf8_lossy(&g.stderr));
    let out = dir.join("d");
    let d = sparkout(&[
        "diagnose",
        obs.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(d.status.success(), "{}", String::from_utf8_lossy(&d.stderr));
    let json = std::fs::read_to_string(out.join("diagnosis.json")).unwrap();
    (
        serde_json::from_str(&json).unwrap(),
        String::from_utf8_lossy(&d.stdout).into_owned(),
    )
}

fn selected_entries(d: &serde_json::Value) -> Vec<&serde_json::Value> {
    d["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["selected"].as_bool() == Some(true))
        .collect()
}

fn key(e: &serde_json::Value) -> String {
    match e["covariate"].as_str() {
        Some(c) => format!("{}:{c}", e["name"].as_str().unwrap()),
        None => e["name"].as_str().unwrap().to_string(),
    }
}

#[test]
fn a_raster_whose_position_moves_with_temperature_reports_the_confounding() {
    for seed in [1, 2] {
        let dir = tempfile::tempdir().unwrap();
        let (d, printed) = diagnose_raster(dir.path(), "raster", seed);
        let sel = selected_entries(&d);
        assert_eq!(sel.len(), 1, "seed {seed}: {:#}", d["per_observable"]);
        let e = sel[0];
        let rivals: Vec<String> = e["indistinguishable_from"]
            .as_array()
            .unwrap_or_else(|| panic!("seed {seed}: no rivals listed: {e:#}"))
            .iter()
            .map(|r| r.as_str().unwrap().to_string())
            .collect();
        // Both explanations are on the table: the thermal one and one of
        // position, whichever the held-out scores happened to rank first.
        let mut both = rivals.clone();
        both.push(key(e));
        assert!(
            both.iter().any(|k| k == "thermal:temp_c"),
            "seed {seed}: {both:?}"
        );
        assert!(
            both.iter().any(|k| k.ends_with(":x_mm")),
            "seed {seed}: {both:?}"
        );
        let col = d["per_observable"][0]["collinear"]
            .as_array()
            .unwrap_or_else(|| panic!("seed {seed}: no collinearity: {:#}", d["per_observable"]));
        let with_x = col.iter().any(|c| {
            c["moves_with"]["x_mm"]
                .as_f64()
                .is_some_and(|r| r.abs() >= 0.95)
                || c["moves_with"]["temp_c"]
                    .as_f64()
                    .is_some_and(|r| r.abs() >= 0.95)
        });
        assert!(with_x, "seed {seed}: {col:?}");
        assert!(
            printed.contains("on these runs indistinguishable from"),
            "{printed}"
        );
        assert!(printed.contains("vary the scan direction"), "{printed}");
    }
}

#[test]
fn runs_that_vary_direction_and_start_time_name_the_thermal_effect_alone() {
    for seed in [1, 2] {
        let dir = tempfile::tempdir().unwrap();
        let (d, printed) = diagnose_raster(dir.path(), "raster-varied", seed);
        let per = &d["per_observable"][0];
        assert_eq!(per["selected"][0], "thermal:temp_c", "seed {seed}: {per:#}");
        for e in selected_entries(&d) {
            assert!(
                e.get("indistinguishable_from").is_none(),
                "seed {seed}: {e:#}"
            );
        }
        assert!(per.get("collinear").is_none(), "seed {seed}: {per:#}");
        assert!(!printed.contains("indistinguishable"), "{printed}");
        assert!(!printed.contains("Note:"), "{printed}");
    }
}

/// Observations written by pyarrow (datasets/fixtures/make_staggered_wear.py):
/// a wheel wear on runs whose passes start at two offsets ≈ 330 s apart.
/// A periodic on t_s once lined the offsets up and followed the wear
/// within each run better than the wear's own line (clipped spark-out cuts
/// bend it); bounded by one run's span, the wear is named, with the
/// rival that also passed on a covariate moving with the removed volume.
#[test]
fn a_wear_on_runs_starting_a_cycle_apart_is_named_wear_with_its_rival() {
    let obs = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("datasets/fixtures/adhoc/staggered_wear_observations.parquet");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("d");
    let d = sparkout(&[
        "diagnose",
        obs.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let printed = String::from_utf8_lossy(&d.stdout).into_owned();
    assert!(d.status.success(), "{}", String::from_utf8_lossy(&d.stderr));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("diagnosis.json")).unwrap())
            .unwrap();
    assert_eq!(json["selected"][0], "wear:removed_mm3", "{printed}");
    let periodic = json["effects"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| key(e) == "periodic:t_s")
        .expect("periodic:t_s scored");
    let lambda = periodic["params"]["lambda"].as_f64().unwrap();
    assert!(lambda <= 240.0 + 1e-9, "λ = {lambda} s");
    assert!(
        printed.contains("Also passing on covariates that move with removed_mm3 within every run: wear:pass (held-out"),
        "{printed}"
    );
    assert!(
        printed.contains("Note: removed_mm3 moves with"),
        "{printed}"
    );
}

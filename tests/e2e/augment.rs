//! The generic part of `sparkout run --augment`: `sparkout run --augment` adds the
//! effects of an earlier night's diagnosis to the sim side of tonight's
//! observations and reports the plain vs augmented gap on runs the model was
//! not fitted on (fleet/augment.json, fleet page verdicts).

use std::path::Path;

use super::common::{ok, sparkout};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `runs` runs of `plugin` with `effect`; the last `tonight` of them moved
/// into a second root (new run ids of the same machine: tonight's runs).
fn two_nights(dir: &Path, plugin: &str, machine: &str, effect: &str, runs: usize, tonight: usize) {
    let all = dir.join("all");
    ok(sparkout(&[
        "generate",
        plugin,
        "--runs",
        &runs.to_string(),
        "--seed",
        "11",
        "--out",
        s(&all),
        "--effect",
        effect,
    ]));
    let (a, b) = (dir.join("A").join(machine), dir.join("B").join(machine));
    std::fs::create_dir_all(&a).unwrap();
    std::fs::create_dir_all(&b).unwrap();
    for i in 0..runs {
        let id = format!("r{i:04}");
        let to = if i < runs - tonight { &a } else { &b };
        std::fs::rename(all.join(machine).join(&id), to.join(&id)).unwrap();
    }
}

/// `sparkout run` over `dir/<input>` into `dir/<out>`, with `--augment
/// model` when given; returns the output directory.
fn night(dir: &Path, input: &str, out: &str, model: Option<&Path>) -> std::path::PathBuf {
    let (input, out_dir) = (dir.join(input), dir.join(out));
    let mut args = vec!["run", "--input", s(&input), "--out", s(&out_dir)];
    if let Some(m) = model {
        args.extend(["--augment", s(m)]);
    }
    ok(sparkout(&args));
    out_dir
}

/// A float column of a run's artifact (`<out>/<machine>/<run>/<file>`).
fn artifact_col(out: &Path, run: &str, file: &str, column: &str) -> Vec<f64> {
    let b = sparkout_pipeline::contracts::batch::read_parquet(&out.join(run).join(file)).unwrap();
    sparkout_pipeline::contracts::batch_f64(&b, column)
        .unwrap()
        .to_vec()
}

fn augment_json(out: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(out.join("fleet/augment.json")).expect("augment.json"))
        .unwrap()
}

fn entry<'a>(a: &'a serde_json::Value, observable: &str) -> &'a serde_json::Value {
    a["entries"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["observable"] == observable)
        .unwrap_or_else(|| panic!("no augment entry for {observable}: {a:#}"))
}

#[test]
fn last_nights_effects_shrink_tonights_gap_on_held_out_runs() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    two_nights(dir, "form", "form-grinder", "wheel_wear", 10, 4);
    let out_a = night(dir, "A", "outA", None);
    let model = out_a.join("fleet/augmented_model.json");
    let m: serde_json::Value = serde_json::from_slice(&std::fs::read(&model).unwrap()).unwrap();
    assert_eq!(m["fitted_on_runs"].as_array().unwrap().len(), 6, "{m:#}");
    let out_b = night(dir, "B", "outB", Some(&model));
    let a = augment_json(&out_b);
    let e = entry(&a, "profile_error");
    assert_eq!(e["held_out"], true, "{e:#}");
    assert_eq!(e["runs"], 4, "{e:#}");
    assert_eq!(e["effects"][0], "wheel_wear:removed_mm3", "{e:#}");
    let (plain, aug) = (
        e["heldout_rms_plain"].as_f64().unwrap(),
        e["heldout_rms_augmented"].as_f64().unwrap(),
    );
    assert!(aug < 0.3 * plain, "augmented {aug} vs plain {plain}");
    // The wear entered the form grinder's physics (the worn wheel), not an
    // added term: listed as such, and tonight's compensation is the worn
    // wheel's — its centre moved in along the normal by the fitted wear,
    // which grows with the volume removed along the profile.
    assert_eq!(e["in_physics"][0], "wheel_wear:removed_mm3", "{e:#}");
    let page = std::fs::read_to_string(out_b.join("fleet/report.html")).unwrap();
    assert!(
        page.contains(
            "Augmented simulator (+ wheel_wear:removed_mm3), on 4 runs it was not fitted on"
        ),
        "no augmented verdict on the fleet page"
    );
    assert!(page.contains("Re-simulated in the plugin's physics: wheel_wear:removed_mm3"));
    let comp = |out: &Path| {
        let col = |c: &str| artifact_col(out, "form-grinder/r0009", "compensation.parquet", c);
        (col("dx_mm"), col("dy_mm"))
    };
    let (dx1, dy1) = comp(&out_b);
    let summary: serde_json::Value = serde_json::from_slice(
        &std::fs::read(out_b.join("form-grinder/r0009/profile_error.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(
        summary["augmented"]["in_physics"], "wheel_wear:removed_mm3",
        "{summary:#}"
    );
    let wear_max = summary["augmented"]["wear_max_mm"].as_f64().unwrap();

    // A night without --augment drops the comparison (no stale figures).
    night(dir, "B", "outB", None);
    assert!(!out_b.join("fleet/augment.json").exists());
    let page = std::fs::read_to_string(out_b.join("fleet/report.html")).unwrap();
    assert!(!page.contains("Augmented simulator"));
    // ... and its compensation is the known wheel's again: the augmented
    // one had moved the centre by up to the fitted wear (a few µm).
    let (dx0, dy0) = comp(&out_b);
    let moved: Vec<f64> = (0..dx0.len())
        .map(|i| (dx1[i] - dx0[i]).hypot(dy1[i] - dy0[i]))
        .collect();
    let most = moved.iter().fold(0.0f64, |m, v| m.max(*v));
    assert!(
        (most - wear_max).abs() < 1e-9 && most > 1e-3,
        "centre moved by up to {most} mm, fitted wear up to {wear_max} mm"
    );
    assert!(moved.last() > moved.first(), "wear grows along the profile");
}

#[test]
fn servo_lag_from_last_night_applies_to_tonight() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    two_nights(dir, "servo", "servo-mill", "servo_lag=k_s=0.004", 8, 3);
    let out_a = night(dir, "A", "outA", None);
    let out_b = night(
        dir,
        "B",
        "outB",
        Some(&out_a.join("fleet/augmented_model.json")),
    );
    let a = augment_json(&out_b);
    let e = entry(&a, "following_error_x");
    assert_eq!(e["held_out"], true, "{e:#}");
    let (plain, aug) = (
        e["heldout_rms_plain"].as_f64().unwrap(),
        e["heldout_rms_augmented"].as_f64().unwrap(),
    );
    assert!(aug < 0.3 * plain, "augmented {aug} vs plain {plain}");
}

/// A plugin composite that is a product of forms — the gantry's
/// `thermal_bow` = bow(y_mm)·drift(t_s) — is replayed from last night's
/// fit (it used to be listed as not applied).
#[test]
fn a_product_of_forms_from_last_night_applies_to_tonight() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    two_nights(dir, "gantry", "aplm-gantry", "thermal_bow", 8, 3);
    let out_a = night(dir, "A", "outA", None);
    let model = out_a.join("fleet/augmented_model.json");
    let m: serde_json::Value = serde_json::from_slice(&std::fs::read(&model).unwrap()).unwrap();
    let bow = m["effects"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["key"] == "thermal_bow:y_mm,t_s")
        .unwrap_or_else(|| panic!("thermal_bow not selected: {m:#}"));
    assert_eq!(
        bow["form"],
        serde_json::Value::Null,
        "a product has no single form"
    );
    assert_eq!(bow["linear"]["factors"][0]["form"], "bow", "{bow:#}");
    assert_eq!(bow["linear"]["factors"][1]["form"], "drift", "{bow:#}");
    let out_b = night(dir, "B", "outB", Some(&model));
    let a = augment_json(&out_b);
    assert_eq!(a["not_applied"], serde_json::json!([]), "{a:#}");
    let e = entry(&a, "surface_z");
    assert_eq!(e["held_out"], true, "{e:#}");
    assert_eq!(e["effects"][0], "thermal_bow:y_mm,t_s", "{e:#}");
    // In the gantry's physics: the removal re-simulated with the bridge's
    // pressure loss (gantry/augment.rs), not an added term.
    assert_eq!(e["in_physics"][0], "thermal_bow:y_mm,t_s", "{e:#}");
    let (plain, aug) = (
        e["heldout_rms_plain"].as_f64().unwrap(),
        e["heldout_rms_augmented"].as_f64().unwrap(),
    );
    assert!(aug < 0.5 * plain, "augmented {aug} vs plain {plain}");

    // The compensation path replay sends lowers the tool by the bridge's
    // lift: never raised, lowered by up to the lift the removal reports.
    let out_p = night(dir, "B", "outP", None);
    let run = "aplm-gantry/r0007";
    let dz = |out: &Path| artifact_col(out, run, "compensation_path.parquet", "dz_mm");
    let (da, dp) = (dz(&out_b), dz(&out_p));
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out_b.join(run).join("matrices.json")).unwrap())
            .unwrap();
    let lift = m["augmented"]["bridge_lift_max_mm"].as_f64().unwrap();
    assert!(lift > 1e-3, "{m:#}");
    let lowered: Vec<f64> = da.iter().zip(&dp).map(|(a, p)| p - a).collect();
    assert!(
        lowered.iter().all(|l| *l >= -1e-12),
        "the tool is never raised"
    );
    let most = lowered.iter().fold(0.0f64, |a, b| a.max(*b));
    assert!(
        (most - lift).abs() < 0.05 * lift,
        "lowered by up to {most}, lift {lift}"
    );
}

/// The guide-way grinder's thermal growth per infeed enters g of the
/// compensation F (and the re-simulated motion error), not an added term.
#[test]
fn thermal_growth_from_last_night_enters_the_guideway_compensation() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    two_nights(dir, "guideway", "guideway-grinder", "thermal_infeed", 8, 3);
    let out_a = night(dir, "A", "outA", None);
    let model = out_a.join("fleet/augmented_model.json");
    let out_b = night(dir, "B", "outB", Some(&model));
    let out_p = night(dir, "B", "outP", None);
    let a = augment_json(&out_b);
    let e = entry(&a, "motion_error");
    assert_eq!(e["in_physics"][0], "thermal_infeed:infeed_count", "{e:#}");
    assert_eq!(e["held_out"], true, "{e:#}");
    let (plain, aug) = (
        e["heldout_rms_plain"].as_f64().unwrap(),
        e["heldout_rms_augmented"].as_f64().unwrap(),
    );
    assert!(aug < 0.7 * plain, "augmented {aug} vs plain {plain}");

    // g = κ·(infeed_count − 1) with the fleet's κ (injected 0.4 µm per
    // infeed): the command differs from the plain night's by exactly
    // (κ_fleet − κ_run)·(count − 1), count from f = −infeed·(count − 1).
    let run = "guideway-grinder/r0007";
    let summary = |out: &Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(out.join(run).join("compensation.json")).unwrap())
            .unwrap()
    };
    let (sa, sp) = (summary(&out_b), summary(&out_p));
    let k_fleet = sa["augmented"]["k_mm_per_infeed"].as_f64().unwrap();
    assert!((k_fleet - 4e-4).abs() < 1.2e-4, "κ = {k_fleet}: {sa:#}");
    let k_run = sp["fit"]["thermal_k_mm_per_infeed"].as_f64().unwrap();
    assert_eq!(
        sa["augmented"]["k_mm_per_infeed_run_fit"].as_f64(),
        Some(k_run)
    );
    let infeed = sa["infeed_mm"].as_f64().unwrap();
    assert!(infeed > 0.0, "{sa:#}");
    let col = |out: &Path, c: &str| artifact_col(out, run, "compensation.parquet", c);
    let (ga, gp, f) = (
        col(&out_b, "g_mm"),
        col(&out_p, "g_mm"),
        col(&out_b, "f_mm"),
    );
    let mut grew = false;
    for i in 0..ga.len() {
        let count_less_1 = -f[i] / infeed;
        let want = (k_fleet - k_run) * count_less_1;
        assert!(
            (ga[i] - gp[i] - want).abs() < 1e-9,
            "row {i}: {} vs {want}",
            ga[i] - gp[i]
        );
        grew |= count_less_1 > 0.5;
    }
    assert!(grew, "the run has more than one infeed");
}

/// The mill's spindle growth: tracker_dz re-simulated with it, and taken
/// out of the compensation path replay sends.
#[test]
fn spindle_growth_from_last_night_leaves_the_mill_compensation_path() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    two_nights(dir, "mill", "xfyz-mill", "thermal_growth", 8, 3);
    let out_a = night(dir, "A", "outA", None);
    let model = out_a.join("fleet/augmented_model.json");
    let out_b = night(dir, "B", "outB", Some(&model));
    let out_p = night(dir, "B", "outP", None);
    let a = augment_json(&out_b);
    let e = entry(&a, "tracker_dz");
    // Named in time or, with the spindle sensor logged, as thermal:temp_c
    // (the sensor warms with the spindle): either is the spindle's growth.
    let named = e["in_physics"][0].as_str().unwrap_or_default();
    assert!(
        named == "thermal_growth:t_s" || named == "thermal:temp_c",
        "{e:#}"
    );
    let (plain, aug) = (
        e["heldout_rms_plain"].as_f64().unwrap(),
        e["heldout_rms_augmented"].as_f64().unwrap(),
    );
    assert!(aug < 0.7 * plain, "augmented {aug} vs plain {plain}");
    let run = "xfyz-mill/r0007";
    let col = |out: &Path, c: &str| artifact_col(out, run, "compensation_path.parquet", c);
    let k: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out_b.join(run).join("kinematics.json")).unwrap())
            .unwrap();
    let g_max = k["augmented"]["growth_max_mm"].as_f64().unwrap();
    assert!(g_max > 5e-3, "{k:#}");
    // dz lowered by the growth, which rises with time; dx, dy untouched.
    let taken: Vec<f64> = col(&out_p, "dz_mm")
        .iter()
        .zip(col(&out_b, "dz_mm"))
        .map(|(p, a)| p - a)
        .collect();
    assert!((taken.iter().fold(0.0f64, |m, v| m.max(v.abs())) - g_max).abs() < 1e-12);
    assert!(taken.last() > taken.first(), "growth rises while measuring");
    assert_eq!(col(&out_p, "dx_mm"), col(&out_b, "dx_mm"));
}

#[test]
fn a_bad_augmented_model_is_refused_before_anything_runs() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    ok(sparkout(&[
        "generate",
        "servo",
        "--runs",
        "2",
        "--seed",
        "1",
        "--out",
        s(&dir.join("runs")),
    ]));
    let bad = dir.join("model.json");
    for (text, field) in [
        (
            r#"{"version": 1, "kind": "something.else", "effects": []}"#,
            "kind",
        ),
        (
            r#"{"version": 1, "kind": "sparkout.augmented_model", "effects": [{"observable": "x", "key": "lag:v", "form": "nonsense"}]}"#,
            "effects[0].form",
        ),
        (
            r#"{"version": 1, "kind": "sparkout.augmented_model", "effects": [{"observable": "x", "key": "lag:v", "form": "lag", "params": {"k": "fast"}}]}"#,
            "effects[0].params.k",
        ),
    ] {
        std::fs::write(&bad, text).unwrap();
        let out = dir.join("out");
        let o = sparkout(&[
            "run",
            "--input",
            s(&dir.join("runs")),
            "--out",
            s(&out),
            "--augment",
            s(&bad),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert!(
            err.contains("model.json") && err.contains(&format!("field `{field}`")),
            "{err}"
        );
        assert!(
            !out.join("manifest.json").exists(),
            "ran despite a bad model"
        );
    }
}

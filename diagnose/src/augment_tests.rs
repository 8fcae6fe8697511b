//! The augmented model (sparkout-core `augment`) against the diagnosis that
//! fills it: every selected effect replays exactly as it was fitted.

use crate::augment::*;
use crate::contracts::BatchBuilder;
use crate::effect::{catalogue_effect, product, Kind};
use arrow::array::RecordBatch;

/// Two observables: `surface_z` carries a product of forms (the
/// gantry's bow(y)·drift(t)), `probe_z` a catalogue drift on t_s; 1 µm
/// noise.
fn table() -> RecordBatch {
    let mut normal = crate::tests::normal_rng(99);
    let mut noise = move || 1e-3 * normal();
    let (mut run, mut obs, mut real, mut y, mut t) = (vec![], vec![], vec![], vec![], vec![]);
    for r in 0..8 {
        for i in 0..150 {
            let (yi, ti) = ((i % 15) as f64 * 7.0, i as f64 * 4.0);
            let bow = 4.0 * yi * (98.0 - yi) / (98.0f64 * 98.0);
            run.push(format!("r{r}"));
            obs.push("surface_z");
            real.push(0.02 * bow * (1.0 - (-ti / 200.0).exp()) + noise());
            y.push(Some(yi));
            t.push(Some(ti));
            run.push(format!("r{r}"));
            obs.push("probe_z");
            real.push(0.01 * (1.0 - (-ti / 150.0).exp()) + noise());
            y.push(None);
            t.push(Some(ti));
        }
    }
    let n = real.len();
    BatchBuilder::new()
        .str("run", &run.iter().map(String::as_str).collect::<Vec<_>>())
        .str("observable", &obs)
        .f64("sim", vec![0.0; n])
        .f64("real", real)
        .opt_f64("y_mm", y)
        .opt_f64("t_s", t)
        .build()
}

fn entry<'a>(v: &'a AugmentReport, observable: &str) -> &'a AugmentEntry {
    v.entries
        .iter()
        .find(|e| e.observable == observable)
        .unwrap_or_else(|| panic!("no entry for {observable}: {v:#?}"))
}

/// The augmented model replays every selected effect exactly as the
/// diagnosis fitted it — a product of forms too (it used to be "not
/// applied") — and for a catalogue effect the replay equals the
/// contract form evaluated from its reported parameters.
#[test]
fn every_linear_effect_replays_and_agrees_with_its_contract_form() {
    let batch = table();
    let bow = product(
        "thermal_bow",
        catalogue_effect(Kind::Bow, &["y_mm"]),
        catalogue_effect(Kind::Drift, &["t_s"]),
    )
    .unwrap();
    let out = crate::diagnose(&batch, &Default::default(), &[bow]).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("augmented_model.json");
    std::fs::write(&path, serde_json::to_vec(&out.augmented_model).unwrap()).unwrap();
    let model = AugmentedModel::load(&path).unwrap();
    let keys: Vec<&str> = model.effects.iter().map(|e| e.key.as_str()).collect();
    assert!(keys.contains(&"thermal_bow:y_mm,t_s"), "{keys:?}");
    assert!(keys.iter().any(|k| k.starts_with("drift:t_s")), "{keys:?}");
    assert!(
        model.effects.iter().all(|e| e.linear.is_some()),
        "{model:#?}"
    );

    let v = evaluate(&model, &batch).unwrap();
    assert_eq!(v.not_applied, [], "{v:#?}");
    for o in ["surface_z", "probe_z"] {
        let e = entry(&v, o);
        let aug = e.heldout_rms_augmented;
        // In-sample here (every run was fitted on): what is left is the
        // 1 µm noise.
        assert!(aug < 1.2e-3, "{o}: augmented {aug} {e:#?}");
        assert!(e.shrink > 0.8, "{e:#?}");
    }

    // The catalogue drift from its contract parameters instead.
    let mut by_form = model.clone();
    for e in &mut by_form.effects {
        if e.kind == Some(Kind::Drift) {
            e.linear = None;
        }
    }
    let w = evaluate(&by_form, &batch).unwrap();
    let (a, b) = (
        entry(&v, "probe_z").heldout_rms_augmented,
        entry(&w, "probe_z").heldout_rms_augmented,
    );
    assert!(
        (a - b).abs() <= 1e-9 * a.max(1e-12),
        "replay {a} vs form {b}"
    );

    // A product without its `linear` block (an old model) is listed as
    // not applied, saying why.
    let mut old = model.clone();
    old.effects.iter_mut().for_each(|e| e.linear = None);
    let x = evaluate(&old, &batch).unwrap();
    assert!(
        x.not_applied
            .iter()
            .any(|n| n.effect == "thermal_bow:y_mm,t_s" && n.why.contains("re-run the diagnosis")),
        "{x:#?}"
    );
}

/// augmented_model.json and augment.json: written, read back through
/// the same type, equal; null numbers are None/NaN, and the file keeps
/// its alphabetical field order.
#[test]
fn the_model_and_the_report_round_trip_through_their_types() {
    let batch = table();
    let out = crate::diagnose(&batch, &Default::default(), &[]).unwrap();
    let m = &out.augmented_model;
    assert!(!m.effects.is_empty());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("augmented_model.json");
    sparkout_core::files::write::write_json_atomic(&path, m).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    let back: AugmentedModelFile =
        sparkout_core::files::json::parse_json(&path, text.as_bytes()).unwrap();
    assert_eq!(
        sparkout_core::files::json::reads_back_whole(&back, text.as_bytes()),
        None
    );
    assert_eq!(back.effects.len(), m.effects.len());
    // Alphabetical, as the hand-built JSON of earlier versions was.
    let keys = |t: &str| -> Vec<usize> {
        [
            "\"applies_as\"",
            "\"effects\"",
            "\"fitted_on_runs\"",
            "\"kind\"",
            "\"version\"",
        ]
        .iter()
        .map(|k| t.find(k).unwrap())
        .collect()
    };
    assert!(keys(&text).windows(2).all(|w| w[0] < w[1]), "{text}");

    let model = AugmentedModel::load(&path).unwrap();
    let report = evaluate(&model, &batch).unwrap();
    let rpath = dir.path().join("augment.json");
    sparkout_core::files::write::write_json_atomic(&rpath, &report).unwrap();
    let read = AugmentReport::read(&rpath).unwrap();
    let text = std::fs::read(&rpath).unwrap();
    assert_eq!(
        sparkout_core::files::json::reads_back_whole(&read, &text),
        None
    );
    assert_eq!(read.entries.len(), report.entries.len());
    // A NaN figure (no row measured) is null in the file, NaN again.
    let mut r = report.clone();
    r.entries[0].shrink = f64::NAN;
    r.entries[0].unit = Some("mm/s".into());
    sparkout_core::files::write::write_json_atomic(&rpath, &r).unwrap();
    let text = std::fs::read_to_string(&rpath).unwrap();
    assert!(text.contains("\"shrink\": null") && text.contains("\"unit\": \"mm/s\""));
    let read = AugmentReport::read(&rpath).unwrap();
    assert!(read.entries[0].shrink.is_nan());
    assert_eq!(read.entries[0].unit.as_deref(), Some("mm/s"));
}

/// A model from before `form`, `linear` and `fitted_on_runs` still
/// loads; a wrong field is named.
#[test]
fn an_old_model_loads_and_a_bad_one_names_its_field() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.json");
    std::fs::write(
        &path,
        r#"{"version": 1, "kind": "sparkout.augmented_model", "effects": [
            {"observable": "probe_z", "key": "drift:t_s", "covariate": "t_s",
             "params": {"amplitude_mm": 0.01, "tau_s": 150.0}, "offset_mm": null}]}"#,
    )
    .unwrap();
    let m = AugmentedModel::load(&path).unwrap();
    assert_eq!(m.effects[0].covariates, ["t_s"]);
    assert!(m.effects[0].kind.is_none() && m.effects[0].linear.is_none());
    assert!(m.fitted_on.is_empty() && m.effects[0].offset_mm == 0.0);
    std::fs::write(
        &path,
        r#"{"version": 1, "kind": "sparkout.augmented_model", "effects": [
            {"observable": "x", "key": "lag:v", "form": "lag", "params": {"k": null}}]}"#,
    )
    .unwrap();
    let e = AugmentedModel::load(&path).unwrap_err().to_string();
    assert!(e.contains("field `effects[0].params.k`"), "{e}");
    std::fs::write(
        &path,
        r#"{"version": 2, "kind": "sparkout.augmented_model"}"#,
    )
    .unwrap();
    let e = AugmentedModel::load(&path).unwrap_err().to_string();
    assert!(e.contains("field `version`: expected 1"), "{e}");
}

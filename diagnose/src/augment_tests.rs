//! The augmented model (sparkout-core `augment`) against the diagnosis that
//! fills it: every selected effect replays exactly as it was fitted.

use crate::augment::{evaluate, AugmentedModel};
use crate::contracts::BatchBuilder;
use crate::effect::Kind;
use crate::effect::{catalogue_effect, product};
use arrow::array::RecordBatch;
use serde_json::{json, Value};

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

fn entry<'a>(v: &'a Value, observable: &str) -> &'a Value {
    v["entries"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["observable"] == observable)
        .unwrap_or_else(|| panic!("no entry for {observable}: {v:#}"))
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
    assert_eq!(v["not_applied"], json!([]), "{v:#}");
    for o in ["surface_z", "probe_z"] {
        let e = entry(&v, o);
        let aug = e["heldout_rms_augmented"].as_f64().unwrap();
        // In-sample here (every run was fitted on): what is left is the
        // 1 µm noise.
        assert!(aug < 1.2e-3, "{o}: augmented {aug} {e:#}");
        assert!(e["shrink"].as_f64().unwrap() > 0.8, "{e:#}");
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
        entry(&v, "probe_z")["heldout_rms_augmented"]
            .as_f64()
            .unwrap(),
        entry(&w, "probe_z")["heldout_rms_augmented"]
            .as_f64()
            .unwrap(),
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
    let na = x["not_applied"].as_array().unwrap();
    assert!(
        na.iter().any(|n| n["effect"] == "thermal_bow:y_mm,t_s"
            && n["why"].as_str().unwrap().contains("re-run the diagnosis")),
        "{x:#}"
    );
}

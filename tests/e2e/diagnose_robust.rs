//! The diagnosis's robustness on generated observation tables: composites scoped to
//! their plugin's observables, an interval on every selected parameter,
//! and spikes that do not move the diagnosis.

use std::sync::Arc;

use arrow::array::{ArrayRef, Float64Array, RecordBatch, StringArray};
use arrow::datatypes::{DataType, Field, Schema};
use rand::{Rng, SeedableRng};
use sparkout_datasets::observations::{generate, write_parquet, ObsFleetConfig};
use sparkout_pipeline::diagnose::augment::AugmentedModel;
use sparkout_pipeline::diagnose::{
    catalogue_effect, composite, diagnose, diagnose_scoped, DiagnoseConfig, Diagnosis, Effect,
    EffectScope, Kind,
};
use sparkout_pipeline::EffectSpec;

use crate::common::sparkout;

const DRIFT: &str = "drift:t_s=amplitude_mm=0.01,tau_s=500";

fn fleet(runs: usize, seed: u64, effects: &[&str]) -> RecordBatch {
    let cfg = ObsFleetConfig {
        runs,
        seed,
        ..Default::default()
    };
    let e: Vec<EffectSpec> = effects.iter().map(|s| s.parse().unwrap()).collect();
    generate(&cfg, &e).unwrap()
}

fn replace_f64(b: &RecordBatch, name: &str, v: Vec<f64>) -> RecordBatch {
    let s = b.schema();
    let i = s.index_of(name).unwrap();
    let mut cols: Vec<ArrayRef> = b.columns().to_vec();
    cols[i] = Arc::new(Float64Array::from(v));
    RecordBatch::try_new(s, cols).unwrap()
}

fn f64s(b: &RecordBatch, name: &str) -> Vec<f64> {
    b.column_by_name(name)
        .unwrap()
        .as_any()
        .downcast_ref::<Float64Array>()
        .unwrap()
        .values()
        .to_vec()
}

fn selected<'a>(d: &'a Diagnosis, key: &str) -> &'a sparkout_pipeline::diagnose::EffectEntry {
    d.effects
        .iter()
        .find(|e| e.selected && e.key() == key)
        .unwrap_or_else(|| panic!("{key} not selected: {:?}", d.selected))
}

#[test]
fn every_selected_parameter_has_an_interval_that_holds_the_truth() {
    let b = fleet(6, 21, &[DRIFT]);
    let d = diagnose(&b, &DiagnoseConfig::default(), &[])
        .unwrap()
        .diagnosis;
    let e = selected(&d, "drift:t_s");
    let iv = e.intervals.as_ref().expect("intervals");
    for (k, truth) in [("amplitude_mm", 0.01), ("tau_s", 500.0)] {
        let i = &iv[k];
        assert!(
            i.se > 0.0 && i.lo < e.params[k] && e.params[k] < i.hi,
            "{k}: {i:?}"
        );
        assert!(
            i.lo <= truth && truth <= i.hi,
            "{k}: truth {truth} outside {i:?}"
        );
        assert!(i.se_folds.is_some(), "{k}: no fold check");
    }
    assert!(iv.contains_key("offset_mm"));
    let [lo, hi] = e.shrink_interval.expect("shrink interval");
    let s = e.shrink.unwrap();
    assert!(lo <= s && s <= hi && hi - lo < 0.5, "{lo} {s} {hi}");
    // The report prints value ± se with the unit.
    let text = e.params_text().join("; ");
    assert!(
        text.contains("tau_s = ") && text.contains(" ± ") && text.contains(" s"),
        "{text}"
    );
}

#[test]
fn one_percent_of_30_sigma_spikes_do_not_move_the_diagnosis() {
    let clean = fleet(6, 22, &[DRIFT]);
    let real = f64s(&clean, "real");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let mut spiky = real.clone();
    let mut n_spikes = 0;
    for r in spiky.iter_mut() {
        if rng.random::<f64>() < 0.01 {
            *r += if rng.random::<bool>() { 0.03 } else { -0.03 }; // ±30σ
            n_spikes += 1;
        }
    }
    let spiky = replace_f64(&clean, "real", spiky);
    let cfg = DiagnoseConfig::default();
    let a = diagnose(&clean, &cfg, &[]).unwrap().diagnosis;
    let out_b = diagnose(&spiky, &cfg, &[]).unwrap();
    let b = &out_b.diagnosis;
    assert_eq!(
        a.selected.first(),
        b.selected.first(),
        "{:?} vs {:?}",
        a.selected,
        b.selected
    );
    let (ea, eb) = (selected(&a, "drift:t_s"), selected(b, "drift:t_s"));
    for k in ["amplitude_mm", "tau_s"] {
        let ib = &eb.intervals.as_ref().unwrap()[k];
        assert!(
            ib.lo <= ea.params[k] && ea.params[k] <= ib.hi,
            "{k}: spike-free {} outside the spiky interval {ib:?}",
            ea.params[k]
        );
    }
    let (pa, pb) = (&a.per_observable[0], &b.per_observable[0]);
    assert!(pa.outliers.is_none(), "{:?}", pa.outliers);
    let out = pb.outliers.as_ref().expect("outliers reported");
    assert!(
        out.n as f64 >= 0.8 * n_spikes as f64 && out.n <= n_spikes + 2,
        "{} outliers for {n_spikes} spikes",
        out.n
    );
    assert!(
        (pb.shrink - pa.shrink).abs() < 0.05,
        "robust shrink {} vs spike-free {}",
        pb.shrink,
        pa.shrink
    );
    let plain = pb.shrink_plain.expect("plain shrink");
    assert!(plain < pb.shrink, "plain {plain} robust {}", pb.shrink);

    // A trimmed row's contribution is the reported all-runs fit's
    // prediction as augmented_model.json replays it — to rounding (seen:
    // 6·10⁻¹⁶), not a refit that lands on a slightly different θ — while
    // every other row carries a held-out prediction, from the fold that
    // left it out (seen: ≥ 4·10⁻⁷ away).
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("augmented_model.json");
    std::fs::write(&path, serde_json::to_vec(&out_b.augmented_model).unwrap()).unwrap();
    let model = AugmentedModel::load(&path).unwrap();
    let drift = model
        .effects_for(&pb.observable)
        .find(|e| e.key == "drift:t_s")
        .expect("drift:t_s in the model");
    let all_runs = drift.predict(&[f64s(&spiky, "t_s")]).expect("replays");
    let rows = out_b.per_row.to_batch().unwrap();
    // Every row's gap, trimmed or kept, is its own real − sim, in input order.
    let (spiky_real, sim, gap) = (
        f64s(&spiky, "real"),
        f64s(&spiky, "sim"),
        f64s(&rows, "gap"),
    );
    assert_eq!(gap.len(), spiky_real.len());
    for i in 0..gap.len() {
        assert_eq!(
            gap[i].to_bits(),
            (spiky_real[i] - sim[i]).to_bits(),
            "row {i}"
        );
    }
    let contrib = f64s(&rows, "contrib_drift:t_s");
    let rel = |i: usize| (contrib[i] - all_runs[i]).abs() / all_runs[i].abs().max(1e-300);
    let spiked: Vec<usize> = (0..real.len())
        .filter(|&i| f64s(&spiky, "real")[i] != real[i])
        .collect();
    let close = |i: usize| rel(i) <= 1e-12;
    let at_spikes = spiked.iter().filter(|&&i| close(i)).count();
    let elsewhere = (0..real.len()).filter(|&i| close(i)).count() - at_spikes;
    assert!(
        at_spikes + 2 >= out.n && elsewhere <= 2,
        "{at_spikes} of {} trimmed spikes and {elsewhere} other rows carry the all-runs fit",
        out.n
    );
}

/// A composite given for observable `profile_error` does not rename the
/// catalogue effect on `surface_z`; scoped to `surface_z` it does.
#[test]
fn composites_apply_only_to_their_observables() {
    let b = fleet(6, 23, &[DRIFT]);
    let effects: Vec<Box<dyn Effect>> = vec![composite(
        "spindle_warmup",
        catalogue_effect(Kind::Drift, &["t_s"]),
    )];
    let other = vec!["profile_error".to_string()];
    let mine = vec!["surface_z".to_string()];
    let cfg = DiagnoseConfig::default();
    let other_scope = EffectScope {
        plugin: "test",
        observables: Some(other.as_slice()),
        effects: &effects,
    };
    let d = diagnose_scoped(&b, &cfg, &[other_scope]).unwrap().diagnosis;
    assert_eq!(d.selected.first().map(String::as_str), Some("drift:t_s"));
    let mine_scope = EffectScope {
        plugin: "test",
        observables: Some(mine.as_slice()),
        effects: &effects,
    };
    let d = diagnose_scoped(&b, &cfg, &[mine_scope]).unwrap().diagnosis;
    assert_eq!(
        d.selected.first().map(String::as_str),
        Some("spindle_warmup:t_s")
    );
}

/// `sparkout diagnose` on a foreign table: catalogue names only unless
/// `--plugin`; `--config` and `--set` reach the diagnosis.
#[test]
fn cli_diagnose_scopes_plugins_and_honours_config() {
    let d = tempfile::tempdir().unwrap();
    let obs = d.path().join("obs.parquet");
    // A foreign table: observable `bore_dia`, wear on removed_mm3.
    let b = fleet(6, 24, &["wear:removed_mm3=k=1e-5"]);
    let n = b.num_rows();
    let s = b.schema();
    let i = s.index_of("observable").unwrap();
    let mut cols: Vec<ArrayRef> = b.columns().to_vec();
    cols[i] = Arc::new(StringArray::from(vec!["bore_dia"; n]));
    let fields: Vec<Field> = s
        .fields()
        .iter()
        .map(|f| {
            if f.name() == "observable" {
                Field::new("observable", DataType::Utf8, false)
            } else {
                f.as_ref().clone()
            }
        })
        .collect();
    let b = RecordBatch::try_new(Arc::new(Schema::new(fields)), cols).unwrap();
    write_parquet(&b, &obs).unwrap();
    let run = |extra: &[&str]| -> serde_json::Value {
        let out = d.path().join("out");
        let mut args = vec![
            "diagnose",
            obs.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--json",
        ];
        args.extend(extra);
        let o = sparkout(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let plain = run(&[]);
    assert_eq!(
        plain["selected"][0], "wear:removed_mm3",
        "{}",
        plain["selected"]
    );
    let form = run(&["--plugin", "form"]);
    assert_eq!(
        form["selected"][0], "wheel_wear:removed_mm3",
        "{}",
        form["selected"]
    );
    let set = run(&["--set", "diagnose.folds=3"]);
    assert_eq!(set["cv"]["folds"], 3);
    let cfg = d.path().join("c.toml");
    std::fs::write(&cfg, "[diagnose]\nfolds = 4\n").unwrap();
    let c = run(&["--config", cfg.to_str().unwrap()]);
    assert_eq!(c["cv"]["folds"], 4);
    // The flag wins over the config.
    let f = run(&["--config", cfg.to_str().unwrap(), "--folds", "2"]);
    assert_eq!(f["cv"]["folds"], 2);
    // A misspelt key is an error naming it.
    let bad = sparkout(&[
        "diagnose",
        obs.to_str().unwrap(),
        "--out",
        d.path().join("o2").to_str().unwrap(),
        "--set",
        "diagnose.fold=3",
    ]);
    assert_eq!(bad.status.code(), Some(1));
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        err.contains("fold") && err.contains("known: folds"),
        "{err}"
    );
}

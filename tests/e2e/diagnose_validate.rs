//! Gap diagnosis on fleets whose effect is withheld: a subset of
//! `sparkout validate` small enough for the debug test suite, and the bad
//! input / determinism cases. Library APIs only (no CLI binary).

use std::sync::Arc;

use arrow::array::{ArrayRef, Float64Array, RecordBatch, StringArray};
use arrow::datatypes::{DataType, Field, Schema};
use sparkout_datasets::observations::{generate, write_parquet, ObsFleetConfig};
use sparkout_datasets::validate::{self, ValidateConfig};
use sparkout_pipeline::diagnose::{diagnose, read_observations, DiagnoseConfig};
use sparkout_pipeline::EffectSpec;

fn fleet(runs: usize, seed: u64, effects: &[&str]) -> RecordBatch {
    let cfg = ObsFleetConfig {
        runs,
        seed,
        ..Default::default()
    };
    let e: Vec<EffectSpec> = effects.iter().map(|s| s.parse().unwrap()).collect();
    generate(&cfg, &e).unwrap()
}

#[test]
fn validation_subset_meets_the_bar() {
    let mut cfg = ValidateConfig::new(true, 11);
    cfg.snrs = vec![3.0, 10.0];
    cfg.fleets_per_case = 1;
    // Every catalogue case (15) at SNR 3 and 10, one fleet each.
    cfg.effects = None;
    cfg.free_fleets = 6;
    cfg.ooc_fleets = 1;
    let r = validate::run(&cfg).unwrap();
    let text = validate::render_text(&r);
    println!("{text}");
    // validation.json reads back through the type that wrote it.
    let json = serde_json::to_string_pretty(&r).unwrap();
    let back: validate::ValidationReport = serde_json::from_str(&json).unwrap();
    assert_eq!(
        sparkout_pipeline::files::json::reads_back_whole(&back, json.as_bytes()),
        None
    );
    assert!(text.contains("confusion matrix"));
    assert!(
        r.accuracy_snr_ge3 >= 0.9,
        "top-1 accuracy {}",
        r.accuracy_snr_ge3
    );
    assert!(
        r.false_alarm_rate <= 0.1,
        "false alarms {}",
        r.false_alarm_rate
    );
    assert!(
        r.shrink_over_oracle_snr_ge3 >= 0.8,
        "shrink / oracle {}",
        r.shrink_over_oracle_snr_ge3
    );
    // Measured on this seed (docs/diagnosis.md
    // "Validation"): spikes do not change the verdict, the robust shrink
    // matches the spike-free oracle, and an effect on one of three machines
    // is localised to it.
    assert_eq!(r.spike_fleets, 2);
    assert_eq!(r.spike_named_rate, Some(1.0), "{text}");
    assert_eq!(r.spike_interval_coverage, Some(1.0), "{text}");
    let robust = r.spike_robust_shrink_over_oracle.unwrap();
    assert!(
        robust > 0.9 && robust < 1.1,
        "robust shrink / oracle {robust}"
    );
    assert_eq!(r.one_machine_localised_rate, Some(1.0), "{text}");
    assert_eq!(r.one_machine_named_rate, Some(1.0), "{text}");
    assert_eq!(r.two_effects_fleets, 2);
    assert!(r.two_effects_all_named_rate.unwrap() >= 0.5, "{text}");
    assert!(r.two_effects_shrink_over_oracle.unwrap() > 0.9, "{text}");
}

#[test]
fn nan_in_real_is_rejected_naming_the_row() {
    let b = fleet(2, 1, &[]);
    let mut real: Vec<f64> = b
        .column_by_name("real")
        .unwrap()
        .as_any()
        .downcast_ref::<Float64Array>()
        .unwrap()
        .values()
        .to_vec();
    real[7] = f64::NAN;
    let idx = b.schema().index_of("real").unwrap();
    let mut cols = b.columns().to_vec();
    cols[idx] = Arc::new(Float64Array::from(real));
    let bad = RecordBatch::try_new(b.schema(), cols).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("observations.parquet");
    write_parquet(&bad, &path).unwrap();
    let err = read_observations(&path).unwrap_err();
    let ie = err.input().expect("an InputError");
    assert_eq!(ie.column.as_deref(), Some("real"));
    assert_eq!(ie.row, Some(7));
    assert!(ie.to_string().contains("observations.parquet"));
    // The in-memory entry point rejects it too.
    let err = diagnose(&bad, &DiagnoseConfig::default(), &[])
        .err()
        .unwrap();
    assert_eq!(err.input().unwrap().row, Some(7));
}

#[test]
fn single_run_uses_blocked_folds() {
    let b = fleet(1, 2, &["drift:t_s=amplitude_mm=0.01,tau_s=400"]);
    let d = diagnose(&b, &DiagnoseConfig::default(), &[])
        .unwrap()
        .diagnosis;
    assert_eq!(d.cv.by, "blocked_within_run");
    assert!(
        d.notes
            .iter()
            .any(|n| n == "single run: blocked folds within the run"),
        "{:?}",
        d.notes
    );
}

fn with_column(b: &RecordBatch, name: &str, v: Vec<f64>) -> RecordBatch {
    let mut fields: Vec<Field> = b
        .schema()
        .fields()
        .iter()
        .map(|f| f.as_ref().clone())
        .collect();
    fields.push(Field::new(name, DataType::Float64, false));
    let mut cols = b.columns().to_vec();
    cols.push(Arc::new(Float64Array::from(v)));
    RecordBatch::try_new(Arc::new(Schema::new(fields)), cols).unwrap()
}

#[test]
fn constant_covariate_is_skipped_and_said() {
    let b = fleet(3, 3, &["scale:x_mm=k=3e-4"]);
    let b = with_column(&b, "z_mm", vec![12.5; b.num_rows()]);
    let d = diagnose(&b, &DiagnoseConfig::default(), &[])
        .unwrap()
        .diagnosis;
    assert!(
        d.notes
            .iter()
            .any(|n| n == "constant covariate z_mm skipped"),
        "{:?}",
        d.notes
    );
    assert!(d
        .effects
        .iter()
        .all(|e| e.covariate.as_deref() != Some("z_mm")));
    assert_eq!(d.selected.first().map(String::as_str), Some("scale:x_mm"));
}

#[test]
fn no_covariates_diagnoses_the_offset_only() {
    let n = 600;
    let run: Vec<String> = (0..n).map(|i| format!("r{}", i % 6)).collect();
    let sim: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin() * 0.01).collect();
    // offset 0.005 mm + deterministic pseudo-noise of ~1 µm
    let real: Vec<f64> = sim
        .iter()
        .enumerate()
        .map(|(i, s)| s + 0.005 + 0.001 * ((i as f64 * 12.9898).sin() * 43758.5453).fract())
        .collect();
    let cols: Vec<ArrayRef> = vec![
        Arc::new(StringArray::from(run)),
        Arc::new(StringArray::from(vec!["cut_depth"; n])),
        Arc::new(Float64Array::from(sim)),
        Arc::new(Float64Array::from(real)),
    ];
    let schema = Schema::new(vec![
        Field::new("run", DataType::Utf8, false),
        Field::new("observable", DataType::Utf8, false),
        Field::new("sim", DataType::Float64, false),
        Field::new("real", DataType::Float64, false),
    ]);
    let b = RecordBatch::try_new(Arc::new(schema), cols).unwrap();
    let d = diagnose(&b, &DiagnoseConfig::default(), &[])
        .unwrap()
        .diagnosis;
    assert!(
        d.notes.iter().any(|n| n == "no covariates: offset only"),
        "{:?}",
        d.notes
    );
    assert_eq!(d.effects.len(), 1);
    assert_eq!(d.effects[0].name, "offset");
    assert!(d.effects[0].covariate.is_none());
    assert_eq!(d.selected, vec!["offset".to_string()]);
}

#[test]
fn gap_at_noise_selects_nothing() {
    let b = fleet(4, 5, &[]);
    let d = diagnose(&b, &DiagnoseConfig::default(), &[])
        .unwrap()
        .diagnosis;
    assert!(d.selected.is_empty(), "{:?}", d.selected);
    assert!(
        d.notes.iter().any(|n| n == "no gap above noise"),
        "{:?}",
        d.notes
    );
    assert_eq!(d.noise_floor_source, "replicates");
    assert!((d.gap.noise_floor_mm - 0.001).abs() < 0.0002);
    // every candidate still scored
    assert!(d.effects.len() > 10);
    assert!(d.effects.iter().all(|e| !e.selected));
}

#[test]
fn same_seed_gives_byte_identical_json_and_per_row_columns() {
    let b = fleet(
        4,
        6,
        &[
            "drift:t_s=amplitude_mm=0.01,tau_s=500",
            "backlash:dir=b_mm=0.006",
        ],
    );
    let cfg = DiagnoseConfig {
        seed: 42,
        ..Default::default()
    };
    let a = diagnose(&b, &cfg, &[]).unwrap();
    let c = diagnose(&b, &cfg, &[]).unwrap();
    let ja = serde_json::to_string_pretty(&a.diagnosis).unwrap();
    let jc = serde_json::to_string_pretty(&c.diagnosis).unwrap();
    assert_eq!(ja, jc);
    assert_eq!(a.augmented_model, c.augmented_model);
    // v1 contract fields
    let v: serde_json::Value = serde_json::from_str(&ja).unwrap();
    for k in [
        "version",
        "observables",
        "gap",
        "where",
        "effects",
        "selected",
        "unexplained",
    ] {
        assert!(v.get(k).is_some(), "{k}");
    }
    for k in ["rms_mm", "max_abs_mm", "noise_floor_mm", "n"] {
        assert!(v["gap"].get(k).is_some(), "gap.{k}");
    }
    let e0 = &v["effects"][0];
    for k in [
        "name",
        "covariate",
        "params",
        "cv_rms_before_mm",
        "cv_rms_after_mm",
        "shrink",
        "p_value",
        "selected",
    ] {
        assert!(e0.get(k).is_some(), "effects[].{k}");
    }
    let sel = &a.diagnosis.selected;
    assert!(
        sel.contains(&"drift:t_s".to_string()) && sel.contains(&"backlash:dir".to_string()),
        "{sel:?}"
    );
    // per-row table
    let pr = &a.per_row.to_batch().unwrap();
    assert_eq!(pr.num_rows(), b.num_rows());
    let names: Vec<String> = pr
        .schema()
        .fields()
        .iter()
        .map(|f| f.name().clone())
        .collect();
    for want in [
        "run",
        "observable",
        "gap",
        "contrib_drift:t_s",
        "contrib_backlash:dir",
        "residual_after",
    ] {
        assert!(names.iter().any(|n| n == want), "{want} in {names:?}");
    }
    let col = |n: &str| {
        pr.column_by_name(n)
            .unwrap()
            .as_any()
            .downcast_ref::<Float64Array>()
            .unwrap()
            .values()
            .to_vec()
    };
    let (g, r) = (col("gap"), col("residual_after"));
    let cs: Vec<Vec<f64>> = sel.iter().map(|k| col(&format!("contrib_{k}"))).collect();
    for i in 0..g.len() {
        let s: f64 = cs.iter().map(|c| c[i]).sum::<f64>() + r[i];
        assert!((s - g[i]).abs() < 1e-12);
    }
    assert!(a.report_html.starts_with("<section") && a.report_html.contains("<svg"));
    assert!(!a.report_html.contains("<script"));
    assert!(a.diagnosis.unexplained.rms_mm < 0.5 * a.diagnosis.gap.rms_mm);
}

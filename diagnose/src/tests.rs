//! Unit tests of the fitters: every catalogue effect recovers its own
//! parameters from clean synthetic data (with an offset added).

use std::collections::BTreeMap;

use super::effect::{catalogue_effect, shape_value, EffectData, Kind};

fn grid(n: usize, lo: f64, hi: f64) -> Vec<f64> {
    (0..n)
        .map(|i| lo + (hi - lo) * ((i * 7919) % n) as f64 / (n - 1) as f64)
        .collect()
}

fn check(kind: Kind, covs: &[&str], cols: &[Vec<f64>], truth: &[(&str, f64)], tol: &[(&str, f64)]) {
    let params: BTreeMap<String, f64> = truth.iter().map(|(k, v)| (k.to_string(), *v)).collect();
    let y0 = shape_value(kind, &params, &cols[0], cols.get(1).map(|c| c.as_slice()));
    let offset = 0.003;
    let y: Vec<f64> = y0.iter().map(|v| v + offset).collect();
    let mut x = EffectData::new(cols[0].len());
    for (c, v) in covs.iter().zip(cols) {
        x.push(c, v);
    }
    let e = catalogue_effect(kind, covs);
    let f = e.fit(&x, &y).unwrap();
    let p = f.params();
    for (k, t) in tol {
        let want = params[*k];
        let got = p[*k];
        assert!(
            (got - want).abs() <= t * want.abs().max(1e-12),
            "{}: {k} = {got}, want {want} (all: {p:?})",
            kind.name()
        );
    }
    let pred = f.predict(&x);
    let off = f.offset_mm();
    let rms = (pred
        .iter()
        .zip(&y)
        .map(|(p, y)| (p + off - y).powi(2))
        .sum::<f64>()
        / y.len() as f64)
        .sqrt();
    assert!(
        rms < 1e-4 * y0.iter().fold(1e-12f64, |m, v| m.max(v.abs())),
        "{}: rms {rms}",
        kind.name()
    );
}

#[test]
fn linear_effects_recover_their_gain() {
    let x = grid(400, -50.0, 150.0);
    check(
        Kind::Scale,
        &["x_mm"],
        std::slice::from_ref(&x),
        &[("k", 2e-4)],
        &[("k", 1e-6)],
    );
    check(
        Kind::Lag,
        &["feed_mm_s"],
        &[grid(300, 10.0, 90.0)],
        &[("k", 1e-4)],
        &[("k", 1e-6)],
    );
    check(
        Kind::Inertia,
        &["a_mm_s2"],
        &[grid(300, -500.0, 500.0)],
        &[("k", 3e-6)],
        &[("k", 1e-6)],
    );
    check(
        Kind::Wear,
        &["removed_mm3"],
        &[grid(300, 0.0, 9e4)],
        &[("k", 1e-7)],
        &[("k", 1e-6)],
    );
    check(
        Kind::Compliance,
        &["force_n"],
        &[grid(300, 20.0, 200.0)],
        &[("k", 5e-5)],
        &[("k", 1e-6)],
    );
    check(
        Kind::Thermal,
        &["temp_c"],
        &[grid(300, 19.0, 24.0)],
        &[("k", 2e-3), ("t0_c", 20.0)],
        &[("k", 1e-6)],
    );
    let dir: Vec<f64> = (0..300)
        .map(|i| if i % 3 == 0 { 1.0 } else { -1.0 })
        .collect();
    check(
        Kind::Backlash,
        &["dir"],
        &[dir],
        &[("b_mm", 0.004)],
        &[("b_mm", 1e-6)],
    );
    check(
        Kind::Bow,
        &["y_mm"],
        std::slice::from_ref(&x),
        &[("amplitude_mm", 0.01), ("c0", -50.0), ("c1", 150.0)],
        &[("amplitude_mm", 1e-6)],
    );
    let y = grid(400, 0.0, 80.0);
    check(
        Kind::Squareness,
        &["x_mm", "y_mm"],
        &[x, y],
        &[("k", 1e-6)],
        &[("k", 1e-6)],
    );
}

#[test]
fn nonlinear_effects_recover_theta() {
    let t = grid(1500, 0.0, 3600.0);
    check(
        Kind::Drift,
        &["t_s"],
        std::slice::from_ref(&t),
        &[("amplitude_mm", 0.02), ("tau_s", 600.0)],
        &[("amplitude_mm", 1e-3), ("tau_s", 1e-3)],
    );
    let x = grid(1000, 0.0, 200.0);
    check(
        Kind::Periodic,
        &["x_mm"],
        std::slice::from_ref(&x),
        &[
            ("amplitude_mm", 0.005),
            ("lambda", 23.0),
            ("phase_rad", 0.7),
        ],
        &[
            ("amplitude_mm", 1e-3),
            ("lambda", 1e-4),
            ("phase_rad", 1e-3),
        ],
    );
    check(
        Kind::Periodic,
        &["t_s"],
        &[t],
        &[
            ("amplitude_mm", 0.005),
            ("lambda", 900.0),
            ("phase_rad", -1.2),
        ],
        &[
            ("amplitude_mm", 1e-3),
            ("lambda", 1e-4),
            ("phase_rad", 1e-3),
        ],
    );
    let d = grid(800, 0.0, 100.0);
    check(
        Kind::Edge,
        &["path_end_mm"],
        &[d],
        &[("k_mm", 0.01), ("lambda_mm", 6.0)],
        &[("k_mm", 1e-3), ("lambda_mm", 1e-3)],
    );
}

#[test]
fn catalogue_follows_contract_kinds() {
    let covs: Vec<String> = [
        "x_mm",
        "y_mm",
        "t_s",
        "feed_mm_s",
        "a_mm_s2",
        "dir",
        "removed_mm3",
        "pass",
        "force_n",
        "path_end_mm",
        "temp_c",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let keys: Vec<String> = super::catalogue(&covs).iter().map(|e| e.key()).collect();
    for k in [
        "offset",
        "scale:x_mm",
        "bow:y_mm",
        "periodic:x_mm",
        "periodic:t_s",
        "drift:t_s",
        "lag:feed_mm_s",
        "inertia:a_mm_s2",
        "backlash:dir",
        "wear:removed_mm3",
        "wear:pass",
        "compliance:force_n",
        "edge:path_end_mm",
        "thermal:temp_c",
        "squareness:x_mm,y_mm",
    ] {
        assert!(keys.contains(&k.to_string()), "{k} missing from {keys:?}");
    }
    assert!(!keys.contains(&"scale:t_s".to_string()));
    // inertia, not lag, for accelerations
    assert!(!keys.contains(&"lag:a_mm_s2".to_string()));
}

#[test]
fn product_composite_fits() {
    let y = grid(600, 0.0, 100.0);
    let t: Vec<f64> = (0..600).map(|i| i as f64 * 5.0).collect();
    let bow = shape_value(
        Kind::Bow,
        &[
            ("amplitude_mm".to_string(), 1.0),
            ("c0".into(), 0.0),
            ("c1".into(), 100.0),
        ]
        .into_iter()
        .collect(),
        &y,
        None,
    );
    let drift = shape_value(
        Kind::Drift,
        &[("amplitude_mm".to_string(), 0.01), ("tau_s".into(), 700.0)]
            .into_iter()
            .collect(),
        &t,
        None,
    );
    let g: Vec<f64> = bow.iter().zip(&drift).map(|(a, b)| a * b + 0.001).collect();
    let e = super::product(
        "thermal_bow",
        catalogue_effect(Kind::Bow, &["y_mm"]),
        catalogue_effect(Kind::Drift, &["t_s"]),
    )
    .unwrap();
    assert_eq!(e.key(), "thermal_bow:y_mm,t_s");
    let x = EffectData::new(600).with("y_mm", &y).with("t_s", &t);
    let f = e.fit(&x, &g).unwrap();
    let tau = f.params()["b.tau_s"];
    assert!((tau - 700.0).abs() < 1.0, "tau {tau}");
}

/// The fleet's `selected` list is ordered by the signal each effect
/// explains (in noise-variance units, summed over observables), not by the
/// observables' names: a small effect on `a_small` comes after a large one
/// on `b_large`.
#[test]
fn selected_effects_are_ordered_by_explained_signal() {
    use crate::contracts::BatchBuilder;
    let runs = 8;
    let per = 60;
    let mut normal = normal_rng(12345);
    let (mut run, mut obs, mut sim, mut real, mut x, mut removed, mut t) =
        (vec![], vec![], vec![], vec![], vec![], vec![], vec![]);
    for r in 0..runs {
        for i in 0..per {
            let xi = (i as f64 / per as f64) * 100.0;
            // a_small: scale on x_mm, 4 µm across the range vs 1 µm noise.
            run.push(format!("r{r}"));
            obs.push("a_small".to_string());
            sim.push(0.0);
            real.push(4e-5 * xi + 1e-3 * normal());
            x.push(Some(xi));
            removed.push(None);
            t.push(Some(i as f64));
            // b_large: wear on removed_mm3, 50 µm vs 1 µm noise.
            let vol = (i as f64) * 100.0;
            run.push(format!("r{r}"));
            obs.push("b_large".to_string());
            sim.push(0.0);
            real.push(-5e-2 * vol / (per as f64 * 100.0) + 1e-3 * normal());
            x.push(None);
            removed.push(Some(vol));
            t.push(Some(i as f64));
        }
    }
    let batch = BatchBuilder::new()
        .str("run", &run.iter().map(|s| s.as_str()).collect::<Vec<_>>())
        .str(
            "observable",
            &obs.iter().map(|s| s.as_str()).collect::<Vec<_>>(),
        )
        .f64("sim", sim)
        .f64("real", real)
        .opt_f64("x_mm", x)
        .opt_f64("removed_mm3", removed)
        .opt_f64("t_s", t)
        .build();
    let out = super::diagnose(&batch, &super::DiagnoseConfig::default(), &[]).unwrap();
    let sel = &out.diagnosis.selected;
    assert!(sel.len() >= 2, "{sel:?}");
    assert!(
        sel[0].starts_with("wear") || sel[0].starts_with("scale:removed"),
        "{sel:?}"
    );
    assert!(sel.iter().any(|k| k.ends_with("x_mm")), "{sel:?}");
}

/// A seeded standard normal (an LCG through Box–Muller): the diagnosis
/// tests' noise.
pub(crate) fn normal_rng(seed: u64) -> impl FnMut() -> f64 {
    let mut rng = seed;
    move || {
        let mut u = || {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((rng >> 11) as f64 + 0.5) / ((1u64 << 53) as f64)
        };
        let (a, b) = (u(), u());
        (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
    }
}

/// The periodic scan's rotated features (MODELS-free: angle addition) are
/// the directly computed ones at every grid value, anchors and rotations
/// alike; a grid that is not uniform in frequency is computed directly.
#[test]
fn periodic_grid_features_rotate_to_the_direct_ones() {
    use super::effect::{features_each, CovStats};
    let x_mm: Vec<f64> = (0..5000)
        .map(|i| 0.37 * i as f64 + 0.01 * (i % 7) as f64)
        .collect();
    let x = EffectData::new(x_mm.len()).with("x_mm", &x_mm);
    let form = catalogue_effect(Kind::Periodic, &["x_mm"])
        .linear_form()
        .unwrap();
    let frame = vec![CovStats::from_values(&x_mm)];
    let tr = form.theta(&frame).unwrap();
    assert!(tr.grid.len() > 100, "{} grid values", tr.grid.len());
    let check_grid = |grid: &[f64]| {
        let mut direct: Vec<Vec<Vec<f64>>> = Vec::new();
        let mut buf = vec![Vec::new(); 2];
        features_each(form.as_ref(), &frame, &x, grid, &mut buf, &mut |_, f| {
            direct.push(f.to_vec());
            Ok(())
        })
        .unwrap();
        let mut worst = 0.0f64;
        form.features_grid(&frame, &x, grid, &mut buf, &mut |gi, f| {
            for (a, b) in f.iter().zip(&direct[gi]) {
                for (u, v) in a.iter().zip(b) {
                    worst = worst.max((u - v).abs());
                }
            }
            Ok(())
        })
        .unwrap();
        worst
    };
    let worst = check_grid(&tr.grid);
    assert!(worst < 1e-10, "rotated features off by {worst}");
    let uneven: Vec<f64> = tr.grid.iter().map(|t| t * t).collect();
    assert_eq!(check_grid(&uneven[..40]), 0.0);
}

/// A non-finite figure is written as `null` and reads back as NaN.
#[test]
fn a_null_figure_in_diagnosis_json_reads_as_nan() {
    let g: super::GapSummary = serde_json::from_str(
        r#"{"rms_mm": null, "max_abs_mm": 1.5, "noise_floor_mm": 0.25, "n": 3}"#,
    )
    .unwrap();
    assert!(g.rms_mm.is_nan());
    assert_eq!((g.max_abs_mm, g.noise_floor_mm, g.n), (1.5, 0.25, 3));
    let back = serde_json::to_value(&g).unwrap();
    assert!(back["rms_mm"].is_null());
}

/// The covariates of a Float64 column without nulls are the input batch's
/// own buffer (a fleet's covariates are most of the diagnosis' memory);
/// one with nulls is copied with NaN where null.
#[test]
fn covariates_share_the_input_buffer_and_nulls_read_as_nan() {
    use std::sync::Arc;

    use arrow::array::{ArrayRef, Float64Array, RecordBatch, StringArray};

    use super::observations::{validate_observations, Table};

    let n = 6;
    let s = |v: &str| Arc::new(StringArray::from(vec![v; n])) as ArrayRef;
    let f = |v: Vec<Option<f64>>| Arc::new(Float64Array::from(v)) as ArrayRef;
    let x_mm: Vec<Option<f64>> = (0..n).map(|i| Some(i as f64)).collect();
    let mut temp_c: Vec<Option<f64>> = (0..n).map(|i| Some(20.0 + i as f64)).collect();
    temp_c[2] = None;
    let batch = RecordBatch::try_from_iter([
        ("run", s("r0")),
        ("observable", s("z")),
        ("sim", f(vec![Some(0.0); n])),
        ("real", f(vec![Some(0.001); n])),
        ("temp_c", f(temp_c)),
        ("x_mm", f(x_mm)),
    ])
    .unwrap();
    let valid = validate_observations(&batch, std::path::Path::new("obs.parquet")).unwrap();
    let table = Table::from_batch(&valid).unwrap();
    let input = valid
        .column_by_name("x_mm")
        .unwrap()
        .as_any()
        .downcast_ref::<Float64Array>()
        .unwrap()
        .values()
        .as_ptr();
    assert_eq!(
        table.values.column("x_mm").unwrap().as_ptr(),
        input,
        "x_mm was copied"
    );
    let t = table.values.column("temp_c").unwrap();
    assert!(t[2].is_nan() && t[3] == 23.0, "{t:?}");
}

/// Two machines whose runs share ids (r0…r7), two observables: `a_um` in
/// µm with a scale error on m2 alone, `b` a velocity without `x_mm`.
fn two_machine_fleet() -> arrow::array::RecordBatch {
    two_machine_fleet_of(120)
}

/// [`two_machine_fleet`] with `points` rows per run and observable.
fn two_machine_fleet_of(points: usize) -> arrow::array::RecordBatch {
    use crate::contracts::BatchBuilder;
    let mut normal = normal_rng(11);
    let (mut machine, mut run, mut obs, mut unit) = (vec![], vec![], vec![], vec![]);
    let (mut real, mut x, mut t) = (vec![], vec![], vec![]);
    for m in ["m1", "m2"] {
        for r in 0..8 {
            for i in 0..points {
                let xi = (i * 37 % points) as f64;
                for o in ["a_um", "b"] {
                    machine.push(m);
                    run.push(format!("r{r}"));
                    obs.push(o);
                    t.push(Some(i as f64 * 0.1));
                    if o == "a_um" {
                        // µm, a scale error on m2 only.
                        let k = if m == "m2" { 0.05 } else { 0.0 };
                        unit.push(Some("um"));
                        real.push(k * xi + 0.3 * normal());
                        x.push(Some(xi));
                    } else {
                        // A velocity: no x for this observable.
                        unit.push(Some("mm/s"));
                        real.push(1e-3 * (0.2 * i as f64).sin() + 1e-4 * normal());
                        x.push(None);
                    }
                }
            }
        }
    }
    let n = real.len();
    BatchBuilder::new()
        .str("machine", &machine)
        .str("run", &run)
        .str("observable", &obs)
        .opt_str("unit", unit)
        .f64("sim", vec![0.0; n])
        .f64("real", real)
        .opt_f64("x_mm", x)
        .opt_f64("t_s", t)
        .build()
}

/// The diagnosis lets its input's text and sim/real columns go once the
/// rows are indexed, and rebuilds a batch from the table where a later
/// step needs one (the per-machine diagnoses): a batch rebuilt from all
/// rows must diagnose exactly as its input — units converted, nulls in a
/// covariate kept, keys as written, two machines whose runs share ids.
#[test]
fn a_batch_rebuilt_from_the_table_diagnoses_as_its_input() {
    use crate::observations::{validate_observations, Table};
    let batch = two_machine_fleet();
    let n = batch.num_rows();
    let cfg = super::DiagnoseConfig::default();
    let direct = super::diagnose(&batch, &cfg, &[]).unwrap();
    let valid = validate_observations(&batch, std::path::Path::new("obs.parquet")).unwrap();
    let table = Table::from_batch(&valid).unwrap();
    let every: Vec<usize> = (0..n).collect();
    // The keys come back as written.
    for k in ["machine", "run", "observable"] {
        let want = arrow::compute::cast(
            batch.column_by_name(k).unwrap(),
            &arrow::datatypes::DataType::Utf8,
        )
        .unwrap();
        assert_eq!(&table.text_column(k, &every), &want, "{k}");
    }
    let rebuilt = table.rebuild(&every).unwrap();
    let again = super::diagnose(&rebuilt, &cfg, &[]).unwrap();
    assert_eq!(
        serde_json::to_string(&direct.diagnosis).unwrap(),
        serde_json::to_string(&again.diagnosis).unwrap()
    );
    assert_eq!(
        direct.per_row.to_batch().unwrap(),
        again.per_row.to_batch().unwrap()
    );
    // The fixture does exercise what it is meant to: a converted unit and
    // an effect localised to one machine.
    let po = &direct.diagnosis.per_observable;
    assert_eq!(
        (po[0].observable.as_str(), po[0].unit.as_str()),
        ("a_um", "mm")
    );
    assert_eq!(po[1].unit, "mm/s");
    assert!(
        direct
            .diagnosis
            .machine_effects
            .iter()
            .any(|e| e.machine == "m2"),
        "{:#?}",
        direct.diagnosis.where_
    );
}

/// Every number of two JSON documents within `rel` of each other, all else
/// equal; the path of the first difference otherwise.
fn json_close(a: &serde_json::Value, b: &serde_json::Value, rel: f64, path: &str) {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            assert!(
                (x - y).abs() <= rel * x.abs().max(y.abs()),
                "{path}: {x} vs {y}"
            );
        }
        (Value::Array(x), Value::Array(y)) => {
            assert_eq!(x.len(), y.len(), "{path}: lengths");
            for (i, (x, y)) in x.iter().zip(y).enumerate() {
                json_close(x, y, rel, &format!("{path}[{i}]"));
            }
        }
        (Value::Object(x), Value::Object(y)) => {
            let keys = |o: &serde_json::Map<String, Value>| o.keys().cloned().collect::<Vec<_>>();
            assert_eq!(keys(x), keys(y), "{path}: keys");
            for (k, v) in x {
                json_close(v, &y[k], rel, &format!("{path}.{k}"));
            }
        }
        _ => assert_eq!(a, b, "{path}"),
    }
}

/// A table whose rows are in no particular order (shuffled, as a writer
/// that does not sort may leave them) diagnoses as the same rows in run
/// order: the same effects, notes and figures but for the last digits
/// that sums in another order move. Its key columns, stretches of a row
/// or two, are held a value per row (`run_length.rs`) — what made such a
/// table slow — and read the same.
#[test]
fn a_shuffled_table_diagnoses_as_the_table_in_run_order() {
    use crate::observations::{validate_observations, Table};
    let batch = two_machine_fleet_of(600);
    let n = batch.num_rows();
    let mut perm: Vec<u32> = (0..n as u32).collect();
    {
        use rand::{seq::SliceRandom, SeedableRng};
        perm.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(7));
    }
    let shuffled =
        arrow::compute::take_record_batch(&batch, &arrow::array::UInt32Array::from(perm)).unwrap();
    let valid = validate_observations(&shuffled, std::path::Path::new("obs.parquet")).unwrap();
    let table = Table::from_batch(&valid).unwrap();
    assert!(table.run.is_held_as_rows() && table.obs.is_held_as_rows());
    let in_order = Table::from_batch(
        &validate_observations(&batch, std::path::Path::new("obs.parquet")).unwrap(),
    )
    .unwrap();
    assert!(!in_order.run.is_held_as_rows());
    // Gathered by run unit, then time in total order, then table row.
    // The covariates in memory and in a column file (put in order there,
    // a column at a time): the same rows, values and constants.
    let scratch = tempfile::tempdir().unwrap();
    for oi in 0..table.obs_names.len() {
        let gather = |max_bytes| {
            let mut notes = super::Notes::default();
            let o = crate::gather::gather_within(
                &table,
                oi,
                Some(scratch.path()),
                max_bytes,
                &mut notes,
            )
            .unwrap();
            (o, notes.into_vec())
        };
        let ((o, notes), (f, file_notes)) = (gather(usize::MAX), gather(0));
        assert!(!o.cols.in_a_file() && f.cols.in_a_file());
        assert_eq!(notes, file_notes);
        assert_eq!(
            (&o.rows, &o.run_ranges, &o.run_machine),
            (&f.rows, &f.run_ranges, &f.run_machine)
        );
        // A machine per run range: each row's, as the table has it.
        assert_eq!(o.machine_of_rows(), table.machine.at(&o.rows));
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&o.gap), bits(&f.gap));
        assert_eq!(o.names(), f.names());
        for ((c, a), (_, b)) in o.cols.frames().zip(f.cols.frames()) {
            assert_eq!(a, b, "{c}");
            assert_eq!(
                bits(&o.cols.column(c).unwrap()),
                bits(&f.cols.column(c).unwrap()),
                "{c}"
            );
        }
        let run = table.run.at(&o.rows);
        let t = o.cols.column("t_s").unwrap();
        for p in 1..o.n() {
            let key = |p: usize| (run[p], crate::effect::total_order_key(t[p]), o.rows[p]);
            assert!(key(p - 1) < key(p), "row {p} of {}", o.name);
        }
    }
    let cfg = super::DiagnoseConfig::default();
    let a = super::diagnose(&batch, &cfg, &[]).unwrap();
    let b = super::diagnose(&shuffled, &cfg, &[]).unwrap();
    let json = |d: &super::DiagnosisOutput| serde_json::to_value(&d.diagnosis).unwrap();
    json_close(&json(&a), &json(&b), 1e-7, "diagnosis");
    assert!(
        a.diagnosis
            .machine_effects
            .iter()
            .any(|e| e.machine == "m2"),
        "the fixture has an effect to find"
    );
}

/// [`two_machine_fleet`] with a `temp_c` covariate of the given values.
fn with_temp_c(v: Vec<Option<f64>>) -> arrow::array::RecordBatch {
    use arrow::array::{Float64Array, RecordBatch};
    use arrow::datatypes::{DataType, Field, Schema};
    use std::sync::Arc;
    let b = two_machine_fleet();
    let mut fields: Vec<Arc<Field>> = b.schema().fields().iter().cloned().collect();
    let mut cols = b.columns().to_vec();
    fields.push(Arc::new(Field::new("temp_c", DataType::Float64, true)));
    cols.push(Arc::new(Float64Array::from(v)));
    RecordBatch::try_new(Arc::new(Schema::new(fields)), cols).unwrap()
}

/// `b` written to `path` with the writer settings `props`.
fn write_with(
    path: &std::path::Path,
    b: &arrow::array::RecordBatch,
    props: parquet::file::properties::WriterProperties,
) {
    let f = std::fs::File::create(path).unwrap();
    let mut w = parquet::arrow::ArrowWriter::try_new(f, b.schema(), Some(props)).unwrap();
    w.write(b).unwrap();
    w.close().unwrap();
}

/// The fleet's diagnosis reads its observations file one observable at a
/// time: the same document and per-row table as the file read whole, over
/// several row groups (some skipped for a machine's own diagnosis), with a
/// covariate that is null on every row (dropped, with its note).
#[test]
fn the_file_read_per_observable_diagnoses_as_the_file_read_whole() {
    let n = two_machine_fleet().num_rows();
    let b = with_temp_c(vec![None; n]);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("observations.parquet");
    let props = parquet::file::properties::WriterProperties::builder()
        .set_max_row_group_row_count(Some(700))
        .build();
    write_with(&path, &b, props);
    let cfg = crate::config_check::Checked::check(super::DiagnoseConfig::default()).unwrap();
    let whole =
        super::diagnose_checked(crate::contracts::read_parquet(&path).unwrap(), &cfg, &[]).unwrap();
    let by_observable =
        super::diagnose_observations_file(&path, &cfg, &[], None, None, &|_| {}).unwrap();
    let json = |d: &super::DiagnosisOutput| serde_json::to_string(&d.diagnosis).unwrap();
    assert_eq!(json(&whole), json(&by_observable));
    assert_eq!(
        whole.per_row.to_batch().unwrap(),
        by_observable.per_row.to_batch().unwrap()
    );
    // The same with the covariates spilled per observable as the rows
    // stream past (in two pieces), and the keys indexed as they pass
    // instead of read back from the file; the spill goes with the
    // diagnosis.
    let spill_dir = dir.path().join(".spill");
    let mut spill = crate::observations_file::RowValueSpill::create(&spill_dir, &b.schema())
        .unwrap()
        .indexing(&path);
    spill.push(&b.slice(0, 1000), &path).unwrap();
    spill.push(&b.slice(1000, n - 1000), &path).unwrap();
    let spilled = spill.finish().unwrap();
    assert!(
        spilled.index.is_some(),
        "the rows were not indexed as they passed"
    );
    // …and with the per-row results on disk until written, read back a
    // slice at a time (the observables' rows interleaved in each slice).
    let results_dir = dir.path().join(".results");
    let from_spill = super::diagnose_observations_file(
        &path,
        &cfg,
        &[],
        Some(spilled),
        Some(&results_dir),
        &|_| {},
    )
    .unwrap();
    assert_eq!(json(&whole), json(&from_spill));
    assert_eq!(
        whole.per_row.to_batch().unwrap(),
        from_spill.per_row.to_batch().unwrap()
    );
    assert!(!spill_dir.exists(), "the spill outlived the diagnosis");
    assert!(results_dir.is_dir());
    let written = dir.path().join("diagnosis.parquet");
    from_spill.per_row.write_parquet(&written).unwrap();
    assert_eq!(
        crate::contracts::read_parquet(&written).unwrap(),
        whole.per_row.to_batch().unwrap()
    );
    // Slices of 700 rows: each observable's cursor carries on across them.
    let slices: Vec<arrow::array::RecordBatch> = from_spill
        .per_row
        .batches_of(700)
        .collect::<crate::Result<_>>()
        .unwrap();
    assert!(slices.len() > 3);
    assert_eq!(
        arrow::compute::concat_batches(&slices[0].schema(), &slices).unwrap(),
        whole.per_row.to_batch().unwrap()
    );
    drop(from_spill);
    assert!(!results_dir.exists(), "the results outlived the output");
    assert!(
        whole.diagnosis.notes.iter().any(|n| n.contains("temp_c")),
        "{:?}",
        whole.diagnosis.notes
    );
    assert!(!whole.diagnosis.machine_effects.is_empty());
}

/// A NaN covariate in the observations file is refused naming the file,
/// the column and the row, as when the file is read whole.
#[test]
fn a_nan_covariate_in_the_file_names_file_column_and_row() {
    let mut v = vec![Some(1.0); two_machine_fleet().num_rows()];
    v[1234] = Some(f64::NAN);
    let b = with_temp_c(v);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("observations.parquet");
    crate::contracts::write_parquet_atomic(&path, &b).unwrap();
    let cfg = crate::config_check::Checked::check(super::DiagnoseConfig::default()).unwrap();
    let e = super::diagnose_observations_file(&path, &cfg, &[], None, None, &|_| {})
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("observations.parquet")
            && e.contains("temp_c")
            && e.contains("1234")
            && e.contains("NaN"),
        "{e}"
    );
    // …and by the spill, naming the file the rows came from.
    let mut spill =
        crate::observations_file::RowValueSpill::create(&dir.path().join(".spill"), &b.schema())
            .unwrap();
    let e = spill
        .push(&b, std::path::Path::new("runs/r3/observations.parquet"))
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("runs/r3/observations.parquet") && e.contains("temp_c") && e.contains("1234"),
        "{e}"
    );
}

/// Rows the index refuses (an implausible `real`) still spill — the spill
/// checks only the covariates — but give the index up: the diagnosis
/// indexes the file itself and refuses it naming the file's row, as
/// without a spill.
#[test]
fn rows_the_index_refuses_leave_the_file_to_name_them() {
    use arrow::array::{Array, Float64Array, RecordBatch};
    use std::sync::Arc;
    let b = two_machine_fleet();
    let i = b.schema().index_of("real").unwrap();
    let real = b.column(i).as_any().downcast_ref::<Float64Array>().unwrap();
    let mut v: Vec<f64> = real.values().to_vec();
    v[1234] = 1.0e9;
    let mut cols = b.columns().to_vec();
    cols[i] = Arc::new(Float64Array::from(v));
    let b = RecordBatch::try_new(b.schema(), cols).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("observations.parquet");
    crate::contracts::write_parquet_atomic(&path, &b).unwrap();
    let mut spill =
        crate::observations_file::RowValueSpill::create(&dir.path().join(".spill"), &b.schema())
            .unwrap()
            .indexing(&path);
    spill.push(&b.slice(0, 1000), &path).unwrap();
    spill
        .push(&b.slice(1000, b.num_rows() - 1000), &path)
        .unwrap();
    let spilled = spill.finish().unwrap();
    assert!(spilled.index.is_none());
    let cfg = crate::config_check::Checked::check(super::DiagnoseConfig::default()).unwrap();
    let e = super::diagnose_observations_file(&path, &cfg, &[], Some(spilled), None, &|_| {})
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("observations.parquet") && e.contains("real") && e.contains("1234"),
        "{e}"
    );
}

/// The fleet's keys are indexed batch by batch: parts that meet machines,
/// runs and observables in another order than the whole give the table
/// the whole would (names sorted, ids renumbered, run units in (machine,
/// run) order).
#[test]
fn a_table_built_in_parts_is_the_whole_table() {
    use crate::observations::{validate_observations, Table, TableParts};
    let b = validate_observations(&two_machine_fleet(), std::path::Path::new("o.parquet")).unwrap();
    let n = b.num_rows();
    // Reversed, so the first part meets m2, r7 and `b` first.
    let back = arrow::array::UInt32Array::from_iter_values((0..n as u32).rev());
    let b = arrow::compute::take_record_batch(&b, &back).unwrap();
    let whole = Table::from_batch(&b).unwrap();
    let mut parts = TableParts::new(std::path::Path::new("o.parquet"));
    let cuts = [0, 100, 2500, n];
    let mut built = Vec::new();
    for w in cuts.windows(2).rev() {
        built.push(Table::from_batch(&b.slice(w[0], w[1] - w[0])).unwrap());
    }
    // Rows follow table order: the parts front to back; the first alone
    // sees one machine and one run.
    for t in built.into_iter().rev() {
        parts.push(t).unwrap();
    }
    let t = parts.finish().unwrap();
    assert_eq!(t.n, whole.n);
    assert_eq!(t.machine_names, whole.machine_names);
    assert_eq!(t.obs_names, whole.obs_names);
    assert_eq!(t.obs_units, whole.obs_units);
    assert_eq!(t.run_names, whole.run_names);
    assert_eq!(t.run_bare, whole.run_bare);
    assert_eq!(t.run, whole.run);
    assert_eq!(t.machine, whole.machine);
    assert_eq!(t.obs, whole.obs);
    assert_eq!(t.gap_sums, whole.gap_sums);
    assert_eq!(t.has_machine, whole.has_machine);
}

/// The file read batch by batch accepts what the whole read accepts (text
/// written as large_utf8 or dictionary, as polars and pandas write it) and
/// gives the same diagnosis; a covariate page that does not decode is the
/// file's error naming the page's row group, not a crash.
#[test]
fn the_file_read_in_batches_accepts_foreign_types_and_names_a_corrupt_covariate_page() {
    use arrow::array::RecordBatch;
    use arrow::datatypes::{DataType, Field, Schema};
    use std::sync::Arc;
    let b = with_temp_c(
        (0..two_machine_fleet().num_rows())
            .map(|i| Some(20.0 + (i % 7) as f64))
            .collect(),
    );
    let dict = DataType::Dictionary(Box::new(DataType::Int32), Box::new(DataType::Utf8));
    let mut fields: Vec<Arc<Field>> = Vec::new();
    let mut cols = Vec::new();
    for (f, c) in b.schema().fields().iter().zip(b.columns()) {
        let to = match f.name().as_str() {
            "run" | "machine" => DataType::LargeUtf8,
            "observable" => dict.clone(),
            _ => f.data_type().clone(),
        };
        cols.push(arrow::compute::cast(c, &to).unwrap());
        fields.push(Arc::new(Field::new(f.name(), to, f.is_nullable())));
    }
    let foreign = RecordBatch::try_new(Arc::new(Schema::new(fields)), cols).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("foreign.parquet");
    let props = parquet::file::properties::WriterProperties::builder()
        .set_max_row_group_row_count(Some(1000))
        .set_compression(parquet::basic::Compression::UNCOMPRESSED)
        .set_dictionary_enabled(false)
        .build();
    write_with(&path, &foreign, props);
    let cfg = crate::config_check::Checked::check(super::DiagnoseConfig::default()).unwrap();
    let whole =
        super::diagnose_checked(super::read_observations(&path).unwrap(), &cfg, &[]).unwrap();
    let file = super::index_observations_file(&path).unwrap();
    assert_eq!(file.observables(), ["a_um", "b"]);
    let by_file = super::diagnose_indexed(file, &cfg, &[], None, None, &|_| {}).unwrap();
    let json = |d: &super::DiagnosisOutput| serde_json::to_string(&d.diagnosis).unwrap();
    assert_eq!(json(&whole), json(&by_file));
    assert_eq!(
        whole.per_row.to_batch().unwrap(),
        by_file.per_row.to_batch().unwrap()
    );
    // Garbage over the page header of temp_c's third row group.
    let meta = parquet::file::reader::FileReader::metadata(
        &parquet::file::reader::SerializedFileReader::new(std::fs::File::open(&path).unwrap())
            .unwrap(),
    )
    .clone();
    let g = meta.row_group(2);
    let leaf = (0..g.num_columns())
        .find(|&j| g.column(j).column_path().string() == "temp_c")
        .unwrap();
    let at = g.column(leaf).data_page_offset() as usize;
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[at..at + 24].fill(0xFF);
    std::fs::write(&path, bytes).unwrap();
    let e = super::diagnose_observations_file(&path, &cfg, &[], None, None, &|_| {})
        .err()
        .unwrap();
    assert!(e.input().is_some(), "{e:#}");
    let e = format!("{e:#}");
    assert!(
        e.contains("foreign.parquet") && e.contains("corrupt data page in row group 2"),
        "{e}"
    );
}

/// A removed volume that rises with time in every run (concave: the wheel
/// cuts less as the part shrinks) carries a wear gap; a curve on time
/// follows it nearly as well and also passes the held-out test. The rival
/// is named beside the selected effect with its held-out RMS and the
/// collinearity note, though the scores tell the two apart; with
/// `confound_share` = 1 only rivals that score as well would be.
#[test]
fn a_passing_rival_on_a_covariate_moving_with_the_selected_one_is_named() {
    use crate::contracts::BatchBuilder;
    let mut normal = normal_rng(7);
    let (mut run, mut real, mut removed, mut t) = (vec![], vec![], vec![], vec![]);
    for r in 0..12 {
        for i in 0..60 {
            let ti = i as f64 * 4.0 + r as f64;
            let vol = 100.0 * i as f64 - 0.6 * (i * i) as f64;
            run.push(format!("r{r:02}"));
            real.push(-1e-5 * vol + 2e-3 * normal());
            removed.push(Some(vol));
            t.push(Some(ti));
        }
    }
    let n = real.len();
    let batch = BatchBuilder::new()
        .str("run", &run.iter().map(|s| s.as_str()).collect::<Vec<_>>())
        .str("observable", &vec!["cut_depth"; n])
        .f64("sim", vec![0.0; n])
        .f64("real", real)
        .opt_f64("removed_mm3", removed)
        .opt_f64("t_s", t)
        .build();
    let explained = |confound_share: f64| {
        let cfg = super::DiagnoseConfig {
            confound_share,
            ..Default::default()
        };
        let d = super::diagnose(&batch, &cfg, &[]).unwrap().diagnosis;
        let o = &d.per_observable[0];
        let text = crate::document::explained_by(o, &d.effects);
        (d.clone(), text)
    };
    let (d, text) = explained(super::DiagnoseConfig::default().confound_share);
    let o = &d.per_observable[0];
    assert_eq!(o.selected, vec!["wear:removed_mm3".to_string()], "{text}");
    let confounds: Vec<&String> = o.collinear.iter().flat_map(|c| &c.confounds).collect();
    assert!(
        confounds.iter().any(|k| k.ends_with(":t_s")),
        "{confounds:?}: {text}"
    );
    // Each with its held-out RMS of the selected effect's round.
    for c in &o.collinear {
        for k in &c.confounds {
            assert!(
                c.confound_rms.get(k).is_some_and(|r| *r > 0.0),
                "{k}: {:?}",
                c.confound_rms
            );
        }
    }
    assert!(
        text.contains("Also passing on covariates that move with removed_mm3 within every run: ")
            && text.contains("(held-out ")
            && text.contains("Note: removed_mm3 moves with t_s"),
        "{text}"
    );
    // The fleet report's table says the same.
    assert!(
        crate::report::section(&d).contains(&crate::html::esc(&text)),
        "the report's 'explained by' column"
    );
    let (_, strict) = explained(1.0);
    assert!(!strict.contains("Also passing"), "{strict}");
}

/// Time counts from each run's start: a cycle longer than any run is never
/// seen whole. Runs whose passes start at two offsets 330 s apart, each
/// 240 s long, with a wear gap that bends as it nears the cut (clipped):
/// the periodic candidate on t_s is fitted with λ no longer than one
/// run's span — before, λ ≈ 330 s lined the two offsets up and let part
/// of one cycle follow the wear in every run.
#[test]
fn a_periodic_on_time_is_never_longer_than_a_run() {
    use crate::contracts::BatchBuilder;
    let mut normal = normal_rng(3);
    let (mut run, mut real, mut sim, mut removed, mut t) = (vec![], vec![], vec![], vec![], vec![]);
    for r in 0..40 {
        let start = if r % 2 == 0 { 360.0 } else { 690.0 } + (r % 5) as f64;
        let mut vol = 0.0;
        for i in 0..11 {
            let model = if i < 7 { 0.3 } else { 0.1 / (i - 6) as f64 };
            let cut = (model - 1e-4 * vol).max(0.0);
            run.push(format!("r{r:02}"));
            sim.push(model);
            real.push(cut + 3e-3 * normal());
            removed.push(Some(vol));
            t.push(Some(start + 24.0 * i as f64));
            vol += 100.0 * cut;
        }
    }
    let n = real.len();
    let batch = BatchBuilder::new()
        .str("run", &run.iter().map(|s| s.as_str()).collect::<Vec<_>>())
        .str("observable", &vec!["cut_depth"; n])
        .f64("sim", sim)
        .f64("real", real)
        .opt_f64("removed_mm3", removed)
        .opt_f64("t_s", t)
        .build();
    let d = super::diagnose(&batch, &super::DiagnoseConfig::default(), &[])
        .unwrap()
        .diagnosis;
    let periodic = d
        .effects
        .iter()
        .find(|e| e.key() == "periodic:t_s")
        .expect("periodic:t_s scored");
    let lambda = periodic.params["lambda"];
    assert!(lambda <= 240.0 + 1e-9, "λ = {lambda} s: {:?}", d.selected);
    assert_eq!(d.selected, vec!["wear:removed_mm3".to_string()]);
}

/// A selected effect's rivals are in parentheses, so a rival selected in a
/// later round reads as the next effect, not as a second rival
/// ("drift:t_s — … from periodic:t_s, periodic:t_s" before).
#[test]
fn rivals_of_one_selected_effect_are_set_apart_from_the_next() {
    let one = crate::document::with_rivals("drift:t_s", &["periodic:t_s".to_string()]);
    assert_eq!(
        one,
        "drift:t_s (on these runs indistinguishable from periodic:t_s)"
    );
    assert_eq!(crate::document::with_rivals("wear:pass", &[]), "wear:pass");
}

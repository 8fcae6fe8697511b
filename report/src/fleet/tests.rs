use super::*;
use crate::diagnose::augment::{AugmentEntry, AugmentReport, NotApplied};
use crate::fleet_data::{binned_means, grid_means};
use serde_json::Value;

/// An `effects` entry: its required fields, then `fields` over them.
fn effect(fields: Value) -> EffectEntry {
    let mut e = serde_json::json!({"name": "", "observable": "o", "params": {}, "param_units": {},
        "n_params": 0, "selected": false, "step": 1});
    e.as_object_mut()
        .unwrap()
        .extend(fields.as_object().unwrap().clone());
    serde_json::from_value(e).unwrap()
}

/// A `per_observable` entry: its required fields, then `fields` over them.
fn summary(fields: Value) -> ObservableSummary {
    let mut p = serde_json::json!({"observable": "", "unit": "mm", "n": 0, "runs": 0,
        "rms_mm": null, "noise_floor_mm": null, "noise_floor_source": "replicates",
        "gap_above_noise": false, "p_value": null, "selected": [], "cv_rms_before_mm": null,
        "cv_rms_after_mm": null, "shrink": null, "stop_reason": ""});
    p.as_object_mut()
        .unwrap()
        .extend(fields.as_object().unwrap().clone());
    serde_json::from_value(p).unwrap()
}

#[test]
fn velocity_errors_are_shown_in_mm_per_s_and_positions_in_um() {
    assert_eq!(
        unit_of_observable("velocity_error_x").show(0.25),
        "0.250 mm/s"
    );
    assert_eq!(unit_of_observable("cut_depth").show(0.0145), "14.5 µm");
    assert_eq!(unit_of_observable("cut_depth").show(f64::NAN), "—");
}

#[test]
fn losers_say_why() {
    let winners: BTreeMap<usize, (String, f64)> = [(1, ("wear:removed_mm3".into(), 0.74))].into();
    let lost = effect(
        serde_json::json!({"name": "drift", "covariate": "t_s", "shrink": 0.2, "p_value": 0.001, "step": 1, "selected": false}),
    );
    assert!(why_lost(&lost, &winners, "").contains("wear:removed_mm3 shrank the held-out gap more"));
    let worse =
        effect(serde_json::json!({"name": "drift", "shrink": -0.1, "step": 1, "selected": false}));
    assert!(why_lost(&worse, &winners, "").starts_with("held-out gap not smaller"));
    let skipped = effect(
        serde_json::json!({"name": "drift", "skipped_reason": "no t_s column", "selected": false}),
    );
    assert_eq!(why_lost(&skipped, &winners, ""), "not tried: no t_s column");
}

#[test]
fn selected_parameters_carry_their_interval_and_unit() {
    let e = effect(
        serde_json::json!({"name": "wear", "covariate": "removed_mm3", "params": {"k": -9.35e-5},
        "intervals": {"k": {"se": 0.9e-5, "lo": -1.22e-4, "hi": -6.5e-5, "from": "pooled"}}}),
    );
    let p = effect_params_text(&e);
    assert_eq!(p.len(), 1);
    assert!(
        p[0].contains("±") && p[0].contains("nm/mm³") && p[0].contains("95 %"),
        "{}",
        p[0]
    );
}

/// A 4 × 4 grid whose gap alternates sign within each cell (±0.03 mm on
/// the left half, ±0.001 mm on the right), and a held-out gap of
/// ±0.005 mm everywhere: a mean per cell would show zero.
fn alternating_field() -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
    let (mut x, mut y, mut gap, mut res) = (vec![], vec![], vec![], vec![]);
    for i in 0..4 {
        for j in 0..4 {
            for sign in [1.0, -1.0] {
                x.push(i as f64 * 10.0);
                y.push(j as f64 * 10.0);
                gap.push(sign * if i < 2 { 0.03 } else { 0.001 });
                res.push(sign * 0.005);
            }
        }
    }
    (x, y, gap, res)
}

/// The maps of rows at hand: their mean gap² and residual² per cell.
fn rms_maps(
    (x, y): (&[f64], &[f64]),
    (gap, res): (&[f64], &[f64]),
    regions: &[[(f64, f64); 2]],
    scale: f64,
) -> RmsMaps {
    let sq = |v: &[f64]| v.iter().map(|g| g * g).collect::<Vec<f64>>();
    let (g2, r2) = (sq(gap), sq(res));
    maps_of_cells(&grid_means(x, y, &[&g2, &r2], MAP_BINS), regions, scale)
}

#[test]
fn maps_show_the_rms_of_an_alternating_gap_and_outline_only_before() {
    let (x, y, gap, res) = alternating_field();
    // A significant region over the left half, its bounds off the grid.
    let regions = [[(-3.0, -2.0), (12.0, 31.0)]];
    let m = rms_maps((&x, &y), (&gap, &res), &regions, 1000.0);
    let at = |cells: &[(f64, f64, f64)], p: (f64, f64)| {
        cells.iter().find(|c| (c.0, c.1) == p).map(|c| c.2).unwrap()
    };
    assert!((at(&m.before, (0.0, 0.0)) - 30.0).abs() < 1e-9);
    assert!((at(&m.before, (30.0, 30.0)) - 1.0).abs() < 1e-9);
    assert!((at(&m.after, (0.0, 0.0)) - 5.0).abs() < 1e-9);
    // Outlined: exactly the 8 cells of the left half, at cell centres.
    let want: Vec<(f64, f64)> = [0.0, 10.0]
        .iter()
        .flat_map(|&a| [0.0, 10.0, 20.0, 30.0].map(|b| (a, b)))
        .collect();
    assert_eq!(m.outlined, want);
    let html = render_maps(&m, "velocity_error_z", "µm", true);
    let maps: Vec<&str> = html.split("</svg><svg").collect();
    assert_eq!(maps.len(), 2, "two maps");
    assert_eq!(maps[0].matches("class=\"outline\"").count(), 1);
    assert!(!maps[1].contains("class=\"outline\""), "after map outlined");
    // The outline contour: 2 × 4 cells have 12 outer unit edges.
    let path = maps[0].split("class=\"outline\" d=\"").nth(1).unwrap();
    let d = &path[..path.find('"').unwrap()];
    assert_eq!(d.matches('M').count(), 12, "{d}");
    // One colour scale: both bars end at the before map's 30 µm.
    for map in &maps {
        assert!(map.contains(">30.0</text>"), "{map}");
    }
}

#[test]
fn at_a_glance_thumbnails_are_readable() {
    assert!(MINI_SIZE.0 >= 120);
    let bars = mini_bars(0.03, 0.01, 0.005);
    assert!(
        bars.contains(&format!("width=\"{}\"", MINI_SIZE.0)),
        "{bars}"
    );
}

fn glance_of(augment: Option<&AugmentReport>) -> String {
    let per = [
        summary(
            serde_json::json!({"observable": "a", "rms_mm": 0.01, "noise_floor_mm": 0.005,
            "gap_above_noise": true, "selected": ["drift:t_s"], "cv_rms_after_mm": 0.006, "shrink": 0.4}),
        ),
        summary(
            serde_json::json!({"observable": "b", "rms_mm": 0.1, "noise_floor_mm": 0.001,
            "gap_above_noise": true, "selected": []}),
        ),
        summary(
            serde_json::json!({"observable": "d", "rms_mm": 0.001, "noise_floor_mm": 0.0011,
            "gap_above_noise": false, "selected": []}),
        ),
        summary(
            serde_json::json!({"observable": "c", "rms_mm": 0.002, "noise_floor_mm": 0.0019,
            "gap_above_noise": false, "selected": []}),
        ),
    ];
    let per_obs: BTreeMap<&str, &ObservableSummary> =
        per.iter().map(|p| (p.observable.as_str(), p)).collect();
    let mut tree = Tree::new();
    tree.entry("form").or_default().insert(
        "m1".to_string(),
        ["a", "b", "c", "d"].map(String::from).to_vec(),
    );
    glance_table(&tree, &per_obs, None, augment)
}

#[test]
fn glance_rows_rank_by_gap_over_floor_and_the_floor_is_one_line() {
    let html = glance_of(None);
    // b (100×) before a (2×); c and d at their floor: no row, one line.
    let (a, b) = (
        html.find("href=\"#m1--a\"").unwrap(),
        html.find("href=\"#m1--b\"").unwrap(),
    );
    assert!(b < a, "{html}");
    assert!(
        html.contains("<td>100×</td>") && html.contains("<td>2.0×</td>"),
        "{html}"
    );
    assert!(!html.contains("<tr><td><a href=\"#m1--c\""), "{html}");
    assert_eq!(html.matches("<tr class=\"floor\">").count(), 1, "{html}");
    assert!(
        html.contains("at noise floor</span>: <a href=\"#m1--c\">c</a>, <a href=\"#m1--d\">d</a> <span class=\"note\">(form / m1)</span>"),
        "{html}"
    );
    // No --augment: no column, and the note says how to get it.
    assert!(!html.contains("<th class=\"why\">last night's model"));
    assert!(html.contains("--augment"));
}

#[test]
fn last_nights_model_on_tonights_runs_is_a_column_with_augment() {
    let augment = AugmentReport {
        applies_as: String::new(),
        entries: vec![AugmentEntry {
            effects: vec!["drift:t_s".into()],
            held_out: true,
            heldout_rms_augmented: 0.002,
            heldout_rms_plain: 0.01,
            in_physics: Vec::new(),
            machine: "m1".into(),
            observable: "a".into(),
            rows: 10,
            runs: 2,
            shrink: 0.8,
            unit: Some("mm".into()),
        }],
        kind: crate::diagnose::augment::AUGMENT_KIND.into(),
        model: "m.json".into(),
        not_applied: vec![NotApplied {
            observable: "b".into(),
            effect: "lag:feed_mm_s".into(),
            why: "tonight's observations lack its covariate (feed_mm_s)".into(),
        }],
        version: 1,
    };
    let html = glance_of(Some(&augment));
    assert!(html.contains("<th class=\"why\">last night's model on tonight's runs</th>"));
    let row = |o: &str| {
        html.split(&format!("href=\"#m1--{o}\""))
            .nth(1)
            .and_then(|r| r.split("</tr>").next())
            .unwrap()
            .to_string()
    };
    assert!(
        row("a").contains("10.0 µm → <b>2.00 µm</b></td>"),
        "{}",
        row("a")
    );
    assert!(
        row("b").contains(
            "title=\"lag:feed_mm_s: tonight's observations lack its covariate (feed_mm_s)\">—"
        ),
        "{}",
        row("b")
    );
    // The floor line spans the extra column.
    assert!(html.contains("<td colspan=\"10\">"), "{html}");
}

/// A diagnosis document around `per` (the figures read `per_observable`).
fn diagnosis_of(per: &[ObservableSummary]) -> Diagnosis {
    serde_json::from_value(serde_json::json!({
        "version": 1, "observables": [], "gap": {"rms_mm": 0.0, "max_abs_mm": 0.0,
        "noise_floor_mm": 0.0, "n": 0}, "where": [], "effects": [], "selected": [],
        "unexplained": {"rms_mm": 0.0, "share": 0.0, "where": []},
        "noise_floor_source": "replicates",
        "cv": {"folds": 5, "by": "run", "test": "", "seed": 0},
        "per_observable": per, "notes": []
    }))
    .unwrap()
}

fn write_parquet(path: &std::path::Path, b: &arrow::array::RecordBatch, group_rows: usize) {
    let props = parquet::file::properties::WriterProperties::builder()
        .set_max_row_group_row_count(Some(group_rows))
        .build();
    let mut w = parquet::arrow::ArrowWriter::try_new(
        std::fs::File::create(path).unwrap(),
        b.schema(),
        Some(props),
    )
    .unwrap();
    w.write(b).unwrap();
    w.close().unwrap();
}

/// The figures summed as the two fleet tables stream past (different row
/// groups, so the diagnosis's batches are cut to the observations') are
/// those of each group's rows at hand: the same cells, bins and means, bit
/// for bit — with missing values, -0.0 beside 0.0, a covariate with few
/// distinct values and one with many, and an observable without "after".
/// A diagnosis whose runs do not line up with the rows is refused.
#[test]
fn figures_read_as_the_rows_stream_are_the_figures_of_the_rows_at_hand() {
    use arrow::array::{ArrayRef, Float64Array, RecordBatch, StringArray};
    use std::sync::Arc;
    let n = 100_003usize;
    let (mut machine, mut run, mut obs) = (Vec::new(), Vec::new(), Vec::new());
    let (mut x, mut y, mut v, mut gap, mut res) = (vec![], vec![], vec![], vec![], vec![]);
    for i in 0..n {
        let r = i / 500;
        machine.push(format!("m{}", r % 2));
        run.push(format!("r{r:04}"));
        let o = if i % 500 < 250 { "a" } else { "b" };
        obs.push(o);
        let xi = match (i % 37, i % 101) {
            (_, 0) => f64::NAN,
            (0, _) if i % 2 == 1 => -0.0,
            (k, _) => k as f64,
        };
        x.push(xi);
        y.push(((i / 7) % 23) as f64 * 1.5);
        v.push(if i % 53 == 0 {
            f64::NAN
        } else {
            (i as f64 * 0.013).sin() * 100.0
        });
        let g = 0.001 * (i % 37) as f64 + 1e-5 * v[i].max(0.0) + 1e-4 * (i % 5) as f64;
        gap.push(g);
        res.push(if o == "a" { g * 0.1 } else { f64::NAN });
    }
    let text = |v: &[String]| Arc::new(StringArray::from(v.to_vec())) as ArrayRef;
    let num = |v: &[f64]| Arc::new(Float64Array::from(v.to_vec())) as ArrayRef;
    let contrib_v: Vec<f64> = v.iter().map(|v| 0.5e-5 * v).collect();
    let contrib_x: Vec<f64> = x.iter().map(|x| 2e-4 * x).collect();
    let observations = RecordBatch::try_from_iter([
        ("machine", text(&machine)),
        ("run", text(&run)),
        (
            "observable",
            Arc::new(StringArray::from(obs.clone())) as ArrayRef,
        ),
        ("sim", num(&vec![0.0; n])),
        ("real", num(&gap)),
        ("x_mm", num(&x)),
        ("y_mm", num(&y)),
        ("v_mm_s", num(&v)),
    ])
    .unwrap();
    let diagnosis_rows = |run: &[String]| {
        RecordBatch::try_from_iter([
            ("run", text(run)),
            ("gap", num(&gap)),
            ("contrib_drift:v_mm_s", num(&contrib_v)),
            ("contrib_scale:x_mm", num(&contrib_x)),
            ("residual_after", num(&res)),
        ])
        .unwrap()
    };
    let dir = tempfile::tempdir().unwrap();
    let (op, dp) = (
        dir.path().join("obs.parquet"),
        dir.path().join("diag.parquet"),
    );
    write_parquet(&op, &observations, 30_000);
    write_parquet(&dp, &diagnosis_rows(&run), 45_000);
    let per = [
        summary(serde_json::json!({"observable": "a", "selected": ["drift:v_mm_s", "scale:x_mm"]})),
        summary(serde_json::json!({"observable": "b", "selected": ["scale:x_mm"]})),
    ];
    let d = diagnosis_of(&per);
    let bins = Bins {
        map: MAP_BINS,
        mini_map: MINI_MAP_BINS,
        curve: CURVE_BINS,
        mini_curve: MINI_CURVE_BINS,
    };
    let figs = FleetFigures::load(&op, Some((&dp, &d)), bins).unwrap();
    assert_eq!(figs.groups.len(), 4);
    for ((m, o), fig) in &figs.groups {
        let idx: Vec<usize> = (0..n)
            .filter(|&i| &machine[i] == m && obs[i] == o)
            .collect();
        let at = |v: &[f64]| idx.iter().map(|&i| v[i]).collect::<Vec<f64>>();
        let (gx, gy, gg, gr) = (at(&x), at(&y), at(&gap), at(&res));
        let sq = |v: &[f64]| v.iter().map(|g| g * g).collect::<Vec<f64>>();
        let want_map = grid_means(&gx, &gy, &[&sq(&gg), &sq(&gr)], MAP_BINS);
        assert_eq!(
            format!("{:?}", fig.map.as_ref().unwrap()),
            format!("{want_map:?}")
        );
        let want_mini = grid_means(&gx, &gy, &[&sq(&gg), &sq(&gr)], MINI_MAP_BINS);
        assert_eq!(
            format!("{:?}", fig.mini_map.as_ref().unwrap()),
            format!("{want_mini:?}")
        );
        // Against the named effect's covariate: the gap less the others.
        let (c, fit, partial) = if o == "a" {
            // (a missing contribution subtracts nothing)
            let p: Vec<f64> = idx
                .iter()
                .map(|&i| {
                    gap[i]
                        - if contrib_x[i].is_finite() {
                            contrib_x[i]
                        } else {
                            0.0
                        }
                })
                .collect();
            (at(&v), at(&contrib_v), p)
        } else {
            (at(&x), at(&contrib_x), gg.clone())
        };
        let want = binned_means(&c, &[&partial, &fit, &gr, &gg], CURVE_BINS);
        assert_eq!(
            format!("{:?}", fig.curve.as_ref().unwrap()),
            format!("{want:?}")
        );
        let want = binned_means(&c, &[&partial, &fit, &gr, &gg], MINI_CURVE_BINS);
        assert_eq!(
            format!("{:?}", fig.mini_curve.as_ref().unwrap()),
            format!("{want:?}")
        );
        assert!(fig.has_fit);
        assert_eq!(fig.has_after, o == "a");
    }
    // Each run's RMS before and after, from the same pass: every run of
    // every group, its row count and its sums of squares.
    assert_eq!(figs.per_run.len(), figs.groups.len());
    for ((m, o), runs) in &figs.per_run {
        let mut want: BTreeMap<&str, (usize, f64, f64)> = BTreeMap::new();
        for i in (0..n).filter(|&i| &machine[i] == m && obs[i] == o) {
            let e = want.entry(run[i].as_str()).or_default();
            *e = (e.0 + 1, e.1 + gap[i] * gap[i], e.2 + res[i] * res[i]);
        }
        assert_eq!(runs.len(), want.len(), "{m}/{o}");
        for (got, (r, (k, g2, r2))) in runs.iter().zip(&want) {
            assert_eq!((got.run.as_str(), got.n), (*r, *k));
            let before = (g2 / *k as f64).sqrt();
            assert!((got.before - before).abs() <= 1e-12 * before, "{m}/{o}/{r}");
            let after = (r2 / *k as f64).sqrt();
            assert!(got.after.is_nan() == after.is_nan(), "{m}/{o}/{r}");
            assert!(after.is_nan() || (got.after - after).abs() <= 1e-12 * after);
        }
    }
    // A few distinct x: the cells are the values (0, not -0).
    let fig = &figs.groups[&("m0".to_string(), "b".to_string())];
    let xs: std::collections::BTreeSet<String> = fig
        .curve
        .as_ref()
        .unwrap()
        .iter()
        .map(|c| format!("{}", c.0))
        .collect();
    assert_eq!(xs.len(), 37);
    assert!(xs.contains("0") && !xs.contains("-0"));
    // A run that does not line up.
    let mut shifted = run.clone();
    shifted[80_000] = "r9999".into();
    write_parquet(&dp, &diagnosis_rows(&shifted), 45_000);
    let e = FleetFigures::load(&op, Some((&dp, &d)), bins)
        .err()
        .unwrap();
    assert!(format!("{e}").contains("do not line up"), "{e}");
}

/// The verdict line says what the runs cannot rule out: the rivals
/// indistinguishable from the named effect, the rivals that also passed on
/// a covariate moving with its own, and what to change.
#[test]
fn the_verdict_names_rivals_and_confounded_causes() {
    let po = summary(serde_json::json!({"observable": "cut_depth", "unit": "mm",
        "rms_mm": 0.014, "noise_floor_mm": 0.003, "gap_above_noise": true,
        "selected": ["wear:removed_mm3"], "cv_rms_before_mm": 0.014, "cv_rms_after_mm": 0.0036,
        "shrink": 0.74,
        "collinear": [{"covariate": "removed_mm3", "moves_with": {"t_s": 0.988}, "vif": 50.0,
            "advice": "removed_mm3 moves with t_s (r = 0.988) within every run",
            "confounds": ["periodic:t_s", "wear:pass"], "confound_rms": {"wear:pass": 0.00412}}]}));
    let mut d = diagnosis_of(std::slice::from_ref(&po));
    d.effects = vec![
        effect(
            serde_json::json!({"name": "wear", "covariate": "removed_mm3",
            "observable": "cut_depth", "selected": true, "params": {"k": -9e-5},
            "indistinguishable_from": ["periodic:t_s"]}),
        ),
        effect(serde_json::json!({"name": "wear", "covariate": "pass",
            "observable": "cut_depth", "selected": false})),
    ];
    let v = verdict(&d, &po, &[], "kr16");
    assert!(
        v.contains("<b>wear:removed_mm3</b> (on these runs indistinguishable from periodic:t_s)"),
        "{v}"
    );
    // The indistinguishable rival is not listed again.
    assert!(
        v.contains("Also passing on covariates that move with removed_mm3 within every run: wear:pass (held-out 4.12 µm).")
            && !v.contains("periodic:t_s (held-out"),
        "{v}"
    );
    assert!(v.contains("Note: removed_mm3 moves with t_s"), "{v}");
    // Without confounds: no caution.
    let mut plain = po.clone();
    plain.collinear[0].confounds.clear();
    let v = verdict(&d, &plain, &[], "kr16");
    assert!(!v.contains("Also passing") && !v.contains("Note:"), "{v}");
}

//! Report sections of a gantry run: heat maps of Γ_static,
//! Γ_dynamic and each body's share; flatness before and after; the polish
//! plan (dwell map, predicted flatness, loud warning when it would make the
//! surface worse); selective against raster time.

use sparkout_pipeline::contracts::{batch_f64, batch_str};
use sparkout_pipeline::report::svg::{
    bar_chart, heat, heatmap, shared_vmax, xy_chart, Heat, Mark, Series,
};
use sparkout_pipeline::report::{esc, fmt_um, table, warning, Verdict};
use sparkout_pipeline::{ArtifactStore, ReportSection, Run};

use super::machine::BODIES;
use super::matrices::MatricesSummary;
use super::polish_plan::PolishPlanSummary;
use crate::typed_summary::{finite, read};

fn um(v: f64) -> String {
    fmt_um(Some(v), 1)
}

fn cells(b: &arrow::record_batch::RecordBatch, col: &str) -> Option<Vec<(f64, f64, f64)>> {
    let (x, y, v) = (
        batch_f64(b, "x_mm").ok()?,
        batch_f64(b, "y_mm").ok()?,
        batch_f64(b, col).ok()?,
    );
    Some((0..x.len()).map(|k| (x[k], y[k], v[k] * 1e3)).collect())
}

fn matrices(a: &ArtifactStore, s: Option<&MatricesSummary>) -> Option<ReportSection> {
    let st = a.get("static_matrix").ok()??;
    let dy = a.get("dynamic_matrix").ok()??;
    let mut html = String::new();
    if let Some(s) = s {
        html.push_str(&format!(
            "<p>Cutting force (Qin) {:.1} N, travelling moment {:.0} N·mm, path velocity {:.0} mm/s; max |Γ_static| {} µm, max |Γ_dynamic| {} µm, dynamic − static up to {} µm ({} series terms at most).</p>",
            s.cut_force_n,
            s.moment_n_mm,
            s.path_velocity_mm_s,
            um(s.gamma_static_max_mm),
            um(s.gamma_dynamic_max_mm),
            um(s.dynamic_minus_static_max_mm),
            s.series_terms_max,
        ));
        let share = |m: &std::collections::BTreeMap<String, f64>, b: &str| {
            um(m.get(b).copied().unwrap_or(f64::NAN))
        };
        let rows: Vec<Vec<String>> = BODIES
            .iter()
            .map(|b| {
                vec![
                    b.to_string(),
                    share(&s.static_share_max_mm, b),
                    share(&s.dynamic_share_max_mm, b),
                ]
            })
            .collect();
        html.push_str(&table(
            &[
                "body",
                "max |static share| (µm)",
                "max |dynamic share| (µm)",
            ],
            &rows,
        ));
    }
    html.push_str(&heatmap(
        "Γ_static = τ_static − τ_pattern",
        &cells(&st, "value_mm")?,
        "µm",
    ));
    html.push_str(&heatmap(
        "Γ_dynamic = τ_dynamic − τ_pattern",
        &cells(&dy, "value_mm")?,
        "µm",
    ));
    for b in BODIES {
        html.push_str(&heatmap(
            &format!("{b}'s share of τ_dynamic"),
            &cells(&dy, &format!("{b}_mm"))?,
            "µm",
        ));
    }
    Some(ReportSection {
        title: "Compensation matrices".into(),
        html,
    })
}

fn flatness(a: &ArtifactStore) -> Option<ReportSection> {
    let f = a.get("flatness").ok()??;
    let st = batch_str(&f, "state").ok()?;
    let ls = batch_f64(&f, "least_squares_mm").ok()?;
    let mz = batch_f64(&f, "min_zone_mm").ok()?;
    let rows: Vec<Vec<String>> = (0..st.len())
        .map(|k| vec![esc(&st[k]), um(ls[k]), um(mz[k])])
        .collect();
    let mut html = table(
        &["state", "least squares PV (µm)", "minimum zone (µm)"],
        &rows,
    );
    let bars: Vec<(String, f64)> = (0..st.len())
        .map(|k| (st[k].clone(), mz[k] * 1e3))
        .collect();
    html.push_str(&bar_chart("Minimum-zone flatness by state", "µm", &bars));
    Some(ReportSection {
        title: "Flatness before and after".into(),
        html,
    })
}

fn polish(a: &ArtifactStore, s: Option<&PolishPlanSummary>) -> Option<ReportSection> {
    let p = a.get("polish_plan").ok()??;
    let s = s?;
    let (x, y, d) = (
        batch_f64(&p, "x_mm").ok()?,
        batch_f64(&p, "y_mm").ok()?,
        batch_f64(&p, "dwell_s").ok()?,
    );
    let fl = &s.flatness;
    let mut html = String::new();
    if let Some(w) = &s.warning {
        html.push_str(&warning(w));
    }
    // The plan's purpose is a flatter surface: say so loudly when its own
    // prediction is not (minimum zone, the flatness the drawing states).
    if let (Some(before), Some(after)) = (
        finite(fl.before.min_zone_mm),
        finite(fl.selective.min_zone_mm),
    ) {
        if after > before {
            html.push_str(&warning(&format!(
                "this polishing plan makes the surface less flat: minimum zone {} → {} µm predicted. Do not run it; check the tool influence and removal calibration.",
                um(before),
                um(after)
            )));
        }
    }
    html.push_str(&format!(
        "<p>Dwell-time optimisation (verdict: <b>{}</b>): {} dwell positions, {:.1} s dwell + {:.1} s lifted travel = <b>{:.1} s</b>, against <b>{:.1} s</b> for a raster of the same removal ({:.2} sweeps; ratio {:.2}). {} points ({:.1} % of the area) stood more than {} µm above the least-squares plane. Selective polishing stops paying off at a zone of {} of the area (by sweeping the zone).</p>",
        esc(&s.verdict),
        s.placements,
        s.dwell_s,
        s.travel_s,
        s.selective_s,
        s.raster_s,
        s.raster_sweeps,
        s.ratio,
        s.zone_points,
        100.0 * s.zone_area_fraction,
        um(s.tolerance_mm),
        s.breakeven_area_fraction.and_then(finite).map(|v| format!("{:.0} %", 100.0 * v)).unwrap_or_else(|| "— (never within the sweep)".into()),
    ));
    html.push_str(&table(
        &["surface", "least squares (µm)", "minimum zone (µm)"],
        &[
            vec![
                "after grinding (plan input)".into(),
                um(fl.before.least_squares_mm),
                um(fl.before.min_zone_mm),
            ],
            vec![
                "after selective polishing (predicted)".into(),
                um(fl.selective.least_squares_mm),
                um(fl.selective.min_zone_mm),
            ],
            vec![
                "after raster of the same removal (predicted)".into(),
                um(fl.raster.least_squares_mm),
                um(fl.raster.min_zone_mm),
            ],
        ],
    ));
    if let Some(surf) = a.get("polish_surface").ok().flatten() {
        // Before and after on one colour scale, so the eye compares them.
        let before = cells(&surf, "above_plane_mm").unwrap_or_default();
        let after = cells(&surf, "after_mm").unwrap_or_default();
        let vmax = shared_vmax([before.as_slice(), after.as_slice()]);
        let diverging = before.iter().chain(&after).any(|c| c.2 < 0.0);
        for (title, c) in [
            (
                "Height above the least-squares plane (the plan's input)",
                &before,
            ),
            (
                "Predicted after selective polishing (dwell ⊛ tool influence)",
                &after,
            ),
        ] {
            if !c.is_empty() {
                let mut h = Heat::new(title, c, "µm");
                h.vmax = Some(vmax);
                h.diverging = diverging;
                html.push_str(&heat(&h));
            }
        }
    }
    if !x.is_empty() {
        let c: Vec<(f64, f64, f64)> = (0..x.len()).map(|k| (x[k], y[k], d[k])).collect();
        html.push_str(&heatmap("Dwell per tool-centre position", &c, "s"));
    }
    html.push_str(&bar_chart(
        "Selective vs raster polishing time",
        "s",
        &[
            ("selective".into(), finite(s.selective_s).unwrap_or(0.0)),
            ("raster".into(), finite(s.raster_s).unwrap_or(0.0)),
        ],
    ));
    // A point that could not be computed (`null`) is not drawn.
    let sweep: Vec<(f64, f64)> = s
        .sweep
        .iter()
        .filter_map(|p| Some((100.0 * finite(p.area_fraction)?, 100.0 * finite(p.ratio)?)))
        .collect();
    // Both axes in percent: a fraction and a ratio read with a unit.
    let one: Vec<(f64, f64)> = vec![(0.0, 100.0), (100.0, 100.0)];
    html.push_str(&xy_chart(
        "Selective / raster time against the zone's area fraction",
        "zone area (% of the surface)",
        "selective time (% of raster)",
        &[
            Series {
                name: "selective / raster",
                points: &sweep,
                mark: Mark::Line,
            },
            Series {
                name: "breakeven",
                points: &one,
                mark: Mark::Line,
            },
        ],
    ));
    Some(ReportSection {
        title: "Selective polishing plan".into(),
        html,
    })
}

pub fn sections(_run: &Run, a: &ArtifactStore) -> Vec<ReportSection> {
    [
        matrices(a, read::<MatricesSummary>(a, "matrices").as_ref()),
        flatness(a),
        polish(a, read::<PolishPlanSummary>(a, "polish_plan").as_ref()),
    ]
    .into_iter()
    .flatten()
    .collect()
}

/// The verdict: minimum-zone flatness of the last topography state (the
/// finished surface) against the one before it (the input of the last
/// step: after grinding, for a polished surface), the tolerance,
/// and the polish plan's prediction for it when a plan was made.
pub fn verdicts(run: &Run, a: &ArtifactStore) -> Vec<Verdict> {
    let Some(f) = a.get("flatness").ok().flatten() else {
        return Vec::new();
    };
    let (Ok(st), Ok(mz)) = (batch_str(&f, "state"), batch_f64(&f, "min_zone_mm")) else {
        return Vec::new();
    };
    let Some(last) = st.len().checked_sub(1) else {
        return Vec::new();
    };
    let label = |s: &str| s.replace('_', " ");
    let mut v = Verdict::new(
        "flatness (minimum zone)",
        "µm",
        &label(&st[last]),
        mz[last] * 1e3,
    )
    .limit("flatness_um", run.tolerance("flatness_um"));
    if last > 0 {
        v = v.before(&label(&st[last - 1]), mz[last - 1] * 1e3);
    }
    vec![v]
}

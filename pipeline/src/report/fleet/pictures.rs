//! The pictures of one (machine, observable): gap maps before and after,
//! the gap against the named covariate with the fitted curve, per-run RMS,
//! and the at-a-glance thumbnails.

use super::*;
use crate::report::svg::spacing;

/// `where` tiles over x_mm,y_mm of an observable: rectangles to outline.
pub(super) fn xy_tiles(d: &Value, observable: &str, scale_pad: (f64, f64)) -> Vec<[(f64, f64); 2]> {
    d.get("where")
        .and_then(|w| w.as_array())
        .into_iter()
        .flatten()
        .filter(|c| s(c, "observable") == observable && s(c, "covariate") == "x_mm,y_mm")
        .filter_map(|c| {
            let lo = c.get("lo")?.as_array()?;
            let hi = c.get("hi")?.as_array()?;
            let (x0, y0) = (lo.first()?.as_f64()?, lo.get(1)?.as_f64()?);
            let (x1, y1) = (hi.first()?.as_f64()?, hi.get(1)?.as_f64()?);
            Some([
                (x0 - scale_pad.0, y0 - scale_pad.1),
                (x1 + scale_pad.0, y1 + scale_pad.1),
            ])
        })
        .collect()
}

/// Where: the gap map over the workpiece, before and (held out) after the
/// selected effects, the significant cells outlined. Returns the maps and
/// whether any cell is outlined.
fn where_maps(
    d: Option<&Value>,
    rows: &FleetRows,
    idx: &[usize],
    observable: &str,
    u: &Unit,
    (gap, res): (&[f64], &[f64]),
    has_after: bool,
) -> (String, bool) {
    let mut h = String::new();
    let (Some(x), Some(y)) = (rows.values("x_mm", idx), rows.values("y_mm", idx)) else {
        return (String::new(), false);
    };
    let cells = grid_means(&x, &y, &[gap, res], MAP_BINS);
    let before: Vec<(f64, f64, f64)> = cells.iter().map(|c| (c.0, c.1, c.2[0] * u.scale)).collect();
    let after: Vec<(f64, f64, f64)> = cells.iter().map(|c| (c.0, c.1, c.2[1] * u.scale)).collect();
    let vmax = shared_vmax([before.as_slice(), after.as_slice()]);
    let pad = (
        spacing(before.iter().map(|c| c.0)) / 2.0,
        spacing(before.iter().map(|c| c.1)) / 2.0,
    );
    let pad = (
        if pad.0.is_finite() { pad.0 } else { 0.5 },
        if pad.1.is_finite() { pad.1 } else { 0.5 },
    );
    let tiles = d.map(|d| xy_tiles(d, observable, pad)).unwrap_or_default();
    let t1 = format!("{observable}: gap, mean per cell");
    let mut hm = Heat::new(&t1, &before, &u.shown);
    hm.vmax = Some(vmax);
    hm.diverging = true;
    hm.outlines = &tiles;
    h.push_str(&heat(&hm));
    if has_after {
        let t2 = format!("{observable}: held-out gap after the selected effects");
        let mut ha = Heat::new(&t2, &after, &u.shown);
        ha.vmax = Some(vmax);
        ha.diverging = true;
        ha.outlines = &tiles;
        h.push_str(&heat(&ha));
    }
    (h, !tiles.is_empty())
}

/// Which: the gap (less the other selected effects) against the named
/// effect's covariate, with its fitted curve and the held-out gap after.
fn which_curve(
    po: Option<&Value>,
    rows: &FleetRows,
    idx: &[usize],
    observable: &str,
    u: &Unit,
    (gap, res): (&[f64], &[f64]),
) -> String {
    let has_after = res.iter().any(|r| r.is_finite());
    let mut h = String::new();
    let named = po
        .and_then(|p| p.get("selected"))
        .and_then(|x| x.as_array())
        .and_then(|a| a.first())
        .and_then(|x| x.as_str());
    if let Some(k) = named {
        let cov = curve_covariate(k);
        let others: Vec<String> = po
            .and_then(|p| p.get("selected"))
            .and_then(|x| x.as_array())
            .into_iter()
            .flatten()
            .filter_map(|x| x.as_str())
            .filter(|o| *o != k)
            .map(|o| format!("contrib_{o}"))
            .collect();
        let c = rows.values(cov, idx);
        let fit = rows.values(&format!("contrib_{k}"), idx);
        if let (Some(c), Some(fit)) = (c, fit) {
            // Partial gap: the gap less the other selected effects, so the
            // named effect's curve is drawn against what it has to explain.
            let mut partial = gap.to_vec();
            for o in &others {
                if let Some(v) = rows.values(o, idx) {
                    for (p, x) in partial.iter_mut().zip(&v) {
                        if x.is_finite() {
                            *p -= x;
                        }
                    }
                }
            }
            let b = binned_means(&c, &[&partial, &fit, res], CURVE_BINS);
            let pick = |k: usize| -> Vec<(f64, f64)> {
                b.iter().map(|(x, m)| (*x, m[k] * u.scale)).collect()
            };
            let (pg, pf, pr) = (pick(0), pick(1), pick(2));
            let gap_name = if others.is_empty() {
                "gap (mean per bin)".to_string()
            } else {
                "gap less the other effects (mean per bin)".to_string()
            };
            let fit_name = format!("{k} fitted on all runs");
            let mut series = vec![
                Series {
                    name: &gap_name,
                    points: &pg,
                    mark: Mark::Points,
                },
                Series {
                    name: &fit_name,
                    points: &pf,
                    mark: Mark::Line,
                },
            ];
            if has_after {
                series.push(Series {
                    name: "held-out gap after (mean per bin)",
                    points: &pr,
                    mark: Mark::Points,
                });
            }
            h.push_str(&xy_chart_sized(
                &format!("{observable} against {cov}"),
                cov,
                &format!("gap ({})", u.shown),
                &series,
                (720, 380),
            ));
        }
    }
    h
}

/// Fewer runs than this: their RMS in a small table instead of a chart
/// (a handful of points reads better as numbers, and weighs less).
pub(super) const MIN_RUNS_CHARTED: usize = 8;

/// How far for a few runs: each run's gap RMS and held-out RMS after, as
/// a table, with the noise floor.
fn how_far_table(po: Option<&Value>, runs: &[RunRms], observable: &str, u: &Unit) -> String {
    let floor = po.map(|p| f(p, "noise_floor_mm")).unwrap_or(f64::NAN);
    let mut h = format!(
        "<p class=\"note\">{}: RMS per run, before and held-out after (noise floor {})</p><table class=\"runs\"><thead><tr><th>run</th><th>gap RMS</th><th>held-out after</th></tr></thead><tbody>",
        esc(observable),
        u.show(floor)
    );
    for r in runs {
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{}</td></tr>",
            esc(&r.run),
            u.show(r.before),
            u.show(r.after)
        );
    }
    h.push_str("</tbody></table>");
    h
}

/// How far: each run's gap RMS before and held-out RMS after, beside the
/// noise floor.
fn how_far_runs(
    po: Option<&Value>,
    runs: Option<&Vec<RunRms>>,
    observable: &str,
    u: &Unit,
) -> String {
    let mut h = String::new();
    if let Some(runs) = runs.filter(|r| !r.is_empty()) {
        // Many runs: consecutive groups, each its pooled RMS (Σ n·rms² /
        // Σ n), so the chart's size does not grow with the fleet.
        let all = runs;
        let grouped = group_runs(runs, MAX_RUN_POINTS);
        let runs = &grouped;
        let before: Vec<(f64, f64)> = runs
            .iter()
            .enumerate()
            .map(|(i, r)| (i as f64, r.before * u.scale))
            .collect();
        let after: Vec<(f64, f64)> = runs
            .iter()
            .enumerate()
            .map(|(i, r)| (i as f64, r.after * u.scale))
            .collect();
        let floor = po
            .map(|p| f(p, "noise_floor_mm") * u.scale)
            .unwrap_or(f64::NAN);
        let fl: Vec<(f64, f64)> = if floor.is_finite() {
            vec![(0.0, floor), ((runs.len() - 1) as f64, floor)]
        } else {
            Vec::new()
        };
        let first = all.first().map(|r| r.run.as_str()).unwrap_or("");
        let last = all.last().map(|r| r.run.as_str()).unwrap_or("");
        let x_label = if grouped.len() < all.len() {
            format!(
                "runs {first} … {last} in id order, groups of {}",
                all.len().div_ceil(MAX_RUN_POINTS)
            )
        } else {
            format!("run ({first} … {last}, in id order)")
        };
        h.push_str(&xy_chart_sized(
            &format!("{observable}: RMS per run, before and held-out after"),
            &x_label,
            &format!("RMS ({})", u.shown),
            &[
                Series {
                    name: "gap RMS before",
                    points: &before,
                    mark: Mark::Points,
                },
                Series {
                    name: "held-out RMS after",
                    points: &after,
                    mark: Mark::Points,
                },
                Series {
                    name: "noise floor",
                    points: &fl,
                    mark: Mark::Line,
                },
            ],
            (720, 320),
        ));
    }
    h
}

/// The pictures of one (machine, observable).
pub(super) fn pictures(
    d: Option<&Value>,
    po: Option<&Value>,
    rows: &FleetRows,
    idx: &[usize],
    runs: Option<&Vec<RunRms>>,
    observable: &str,
) -> String {
    let u = unit_of(
        observable,
        po.and_then(|p| p.get("unit")).and_then(|x| x.as_str()),
    );
    let mut h = String::from("<div class=\"figs\">");
    let gap = FleetRows::at(&rows.gap, idx);
    let res = FleetRows::at(&rows.residual, idx);
    let has_after = res.iter().any(|r| r.is_finite());
    // Nothing selected: the gap after is the gap before; one map.
    let selected = po
        .and_then(|p| p.get("selected"))
        .and_then(|x| x.as_array())
        .is_some_and(|a| !a.is_empty());
    let (maps, outlined) = where_maps(
        d,
        rows,
        idx,
        observable,
        &u,
        (&gap, &res),
        has_after && selected,
    );
    h.push_str(&maps);
    h.push_str(&which_curve(po, rows, idx, observable, &u, (&gap, &res)));
    let few = runs.filter(|r| !r.is_empty() && r.len() < MIN_RUNS_CHARTED);
    if has_after && few.is_none() {
        h.push_str(&how_far_runs(po, runs, observable, &u));
    }
    h.push_str("</div>");
    if let (true, Some(runs)) = (has_after, few) {
        h.push_str(&how_far_table(po, runs, observable, &u));
    }
    if outlined {
        h.push_str("<p class=\"note\">Outlined on the maps: cells where the gap is significantly above the noise floor.</p>");
    }
    h
}

/// The covariate an effect's curve is drawn against. A 2-D covariate
/// (thermal_bow:y_mm,t_s): the map shows the positions, the curve the other.
pub(super) fn curve_covariate(effect_key: &str) -> &str {
    let covs: Vec<&str> = effect_key
        .split_once(':')
        .map(|(_, c)| c.split(',').collect())
        .unwrap_or_default();
    covs.iter()
        .find(|c| !matches!(**c, "x_mm" | "y_mm"))
        .or(covs.first())
        .copied()
        .unwrap_or("")
}

/// Cells per axis of the at-a-glance gap map thumbnail.
pub(super) const MINI_MAP_BINS: usize = 8;
/// Bins of the at-a-glance curve thumbnail.
pub(super) const MINI_CURVE_BINS: usize = 16;

/// "Where" and "which" as thumbnails for the at-a-glance table (the
/// answers above the fold): the gap map over x/y when the rows have
/// positions, and the gap against the named effect's covariate.
pub(super) fn glance_pictures(
    rows: Option<&FleetRows>,
    machine: &str,
    observable: &str,
    named: Option<&str>,
) -> String {
    let Some(rows) = rows else {
        return String::new();
    };
    let Some(idx) = rows
        .groups
        .get(&(machine.to_string(), observable.to_string()))
    else {
        return String::new();
    };
    let gap = FleetRows::at(&rows.gap, idx);
    let mut out = String::new();
    if let (Some(x), Some(y)) = (rows.values("x_mm", idx), rows.values("y_mm", idx)) {
        let cells: Vec<(f64, f64, f64)> = grid_means(&x, &y, &[&gap], MINI_MAP_BINS)
            .into_iter()
            .map(|c| (c.0, c.1, c.2[0]))
            .collect();
        out.push_str(&mini_heat(&cells, 48, 34));
    }
    if let Some(k) = named {
        let cov = curve_covariate(k);
        if let Some(c) = rows.values(cov, idx) {
            let pts: Vec<(f64, f64)> = binned_means(&c, &[&gap], MINI_CURVE_BINS)
                .into_iter()
                .map(|(x, m)| (x, m[0]))
                .collect();
            if !out.is_empty() {
                out.push(' ');
            }
            out.push_str(&mini_curve(
                &pts,
                64,
                34,
                &format!("gap of {observable} against {cov}"),
            ));
        }
    }
    out
}

/// "How far" as a picture for the at-a-glance table: the gap RMS (grey),
/// the held-out RMS after (green) and the noise floor (black tick), on
/// the row's own scale.
pub(super) fn mini_bars(rms: f64, after: f64, floor: f64) -> String {
    let top = [rms, after, floor]
        .into_iter()
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    if top <= 0.0 {
        return String::new();
    }
    let w = |v: f64| if v.is_finite() { 72.0 * v / top } else { 0.0 };
    let mut s = format!(
        r##"<svg class="mini" width="78" height="18" role="img" aria-label="gap, after, noise floor"><rect x="0" y="2" width="{:.1}" height="6" fill="#999"/>"##,
        w(rms)
    );
    if after.is_finite() {
        let _ = write!(
            s,
            r##"<rect x="0" y="10" width="{:.1}" height="6" fill="#2a7"/>"##,
            w(after)
        );
    }
    if floor.is_finite() {
        let _ = write!(
            s,
            r##"<line x1="{x:.1}" x2="{x:.1}" y1="0" y2="18" stroke="#000" stroke-width="1.5"/>"##,
            x = w(floor)
        );
    }
    s.push_str("</svg>");
    s
}

/// At most this many points per series of the per-run chart.
pub(super) const MAX_RUN_POINTS: usize = 60;

/// Runs in consecutive groups of equal size, at most `max` groups, each
/// with its pooled RMS; the runs themselves when there are few.
pub(super) fn group_runs(runs: &[RunRms], max: usize) -> Vec<RunRms> {
    if runs.len() <= max {
        return runs.to_vec();
    }
    let k = runs.len().div_ceil(max);
    runs.chunks(k)
        .map(|c| {
            let n: usize = c.iter().map(|r| r.n).sum();
            let pool = |g: &dyn Fn(&RunRms) -> f64| {
                (c.iter().map(|r| r.n as f64 * g(r).powi(2)).sum::<f64>() / n.max(1) as f64).sqrt()
            };
            RunRms {
                run: format!("{}–{}", c[0].run, c[c.len() - 1].run),
                n,
                before: pool(&|r| r.before),
                after: pool(&|r| r.after),
            }
        })
        .collect()
}

/// Every covariate the pictures draw: positions and the covariates of
/// the selected effects.
pub(super) fn covariates_drawn(d: Option<&Value>) -> Vec<String> {
    let mut c: BTreeSet<String> = ["x_mm".to_string(), "y_mm".to_string()].into();
    for k in d
        .and_then(|d| d.get("selected"))
        .and_then(|s| s.as_array())
        .into_iter()
        .flatten()
        .filter_map(|x| x.as_str())
    {
        if let Some((_, cov)) = k.split_once(':') {
            c.extend(cov.split(',').map(String::from));
        }
    }
    c.into_iter().collect()
}

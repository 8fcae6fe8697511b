//! The pictures of one (machine, observable): gap maps before and after,
//! the gap against the named covariate with the fitted curve, per-run RMS,
//! and the at-a-glance thumbnails.

use super::*;
use crate::svg::{xy_chart_with, XyExtras};

/// `where` regions over x_mm,y_mm of an observable: [(x0, y0), (x1, y1)].
pub(super) fn xy_tiles(d: &Diagnosis, observable: &str) -> Vec<[(f64, f64); 2]> {
    d.where_
        .iter()
        .filter(|c| c.observable == observable && c.covariate == "x_mm,y_mm")
        .filter_map(|c| {
            // An x/y tile's bounds are [x, y] pairs (a 1-D cell's are numbers).
            let (lo, hi) = (c.lo.as_point()?, c.hi.as_point()?);
            let finite = |x: f64| x.is_finite().then_some(x);
            let (x0, y0) = (finite(*lo.first()?)?, finite(*lo.get(1)?)?);
            let (x1, y1) = (finite(*hi.first()?)?, finite(*hi.get(1)?)?);
            Some([(x0.min(x1), y0.min(y1)), (x0.max(x1), y0.max(y1))])
        })
        .collect()
}

/// The cells of a gap map, in the unit shown: the gap's RMS per cell
/// before and the held-out gap's RMS after, and the centres of the cells
/// to outline.
pub(super) struct RmsMaps {
    pub before: Vec<(f64, f64, f64)>,
    pub after: Vec<(f64, f64, f64)>,
    pub outlined: Vec<(f64, f64)>,
}

/// [`RmsMaps`] from the mean gap² and held-out residual² per cell: the
/// RMS, not the mean gap — a mean would cancel an effect whose sign
/// alternates within a cell (a reversal spike, a ripple), so the map shows
/// how large the gap is, not its average.
pub(super) fn maps_of_cells(cells: &Cells, regions: &[[(f64, f64); 2]], scale: f64) -> RmsMaps {
    let pick = |k: usize| -> Vec<(f64, f64, f64)> {
        cells
            .iter()
            .map(|c| (c.0, c.1, c.2[k].sqrt() * scale))
            .collect()
    };
    let before = pick(0);
    let outlined = cells_in_regions(&before, regions);
    RmsMaps {
        after: pick(1),
        before,
        outlined,
    }
}

/// The map cells a region covers: those whose centre lies inside it, or,
/// for a region smaller than a cell, the cell nearest its centre.
pub(super) fn cells_in_regions(
    cells: &[(f64, f64, f64)],
    regions: &[[(f64, f64); 2]],
) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = Vec::new();
    for [lo, hi] in regions {
        let inside: Vec<(f64, f64)> = cells
            .iter()
            .filter(|c| c.2.is_finite())
            .filter(|c| (lo.0..=hi.0).contains(&c.0) && (lo.1..=hi.1).contains(&c.1))
            .map(|c| (c.0, c.1))
            .collect();
        if inside.is_empty() {
            out.push(((lo.0 + hi.0) / 2.0, (lo.1 + hi.1) / 2.0));
        } else {
            out.extend(inside);
        }
    }
    out.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    out.dedup();
    out
}

/// The before map (significant cells outlined) and, when there is one,
/// the after map on the before map's colour scale, without outlines: the
/// significance is the before gap's.
pub(super) fn render_maps(m: &RmsMaps, observable: &str, unit: &str, has_after: bool) -> String {
    let vmax = if has_after {
        shared_vmax([m.before.as_slice(), m.after.as_slice()])
    } else {
        shared_vmax([m.before.as_slice()])
    };
    let t1 = format!("{observable}: gap RMS per cell, before");
    let mut hm = Heat::new(&t1, &m.before, unit);
    hm.vmax = Some(vmax);
    hm.diverging = false;
    hm.outlined = &m.outlined;
    let mut h = heat(&hm);
    if has_after {
        let t2 = format!("{observable}: held-out gap RMS per cell, after");
        let mut ha = Heat::new(&t2, &m.after, unit);
        ha.vmax = Some(vmax);
        ha.diverging = false;
        h.push_str(&heat(&ha));
    }
    h
}

/// Where: the gap's RMS per cell over the workpiece, before and (held out)
/// after the selected effects, on one colour scale, the cells of the
/// significant regions outlined on the before map. Returns the maps and
/// whether any cell is outlined.
fn where_maps(
    d: Option<&Diagnosis>,
    fig: &GroupFigures,
    observable: &str,
    u: &Unit,
    has_after: bool,
) -> (String, bool) {
    let Some(cells) = &fig.map else {
        return (String::new(), false);
    };
    let tiles = d.map(|d| xy_tiles(d, observable)).unwrap_or_default();
    let m = maps_of_cells(cells, &tiles, u.scale);
    (
        render_maps(&m, observable, &u.shown, has_after),
        !m.outlined.is_empty(),
    )
}

/// Which: the gap (less the other selected effects) against the named
/// effect's covariate, with its fitted curve and the held-out gap after.
fn which_curve(
    po: Option<&ObservableSummary>,
    fig: &GroupFigures,
    observable: &str,
    u: &Unit,
) -> String {
    let has_after = fig.has_after;
    let mut h = String::new();
    let selected: &[String] = po.map_or(&[], |p| &p.selected);
    let named = selected.first().map(String::as_str);
    if let Some(k) = named {
        let cov = curve_covariate(k);
        let others = selected.iter().any(|o| o != k);
        if let (Some(b), true) = (&fig.curve, fig.has_fit) {
            // Partial gap: the gap less the other selected effects, so the
            // named effect's curve is drawn against what it has to explain.
            let pick = |k: usize| -> Vec<(f64, f64)> {
                b.iter().map(|(x, m)| (*x, m[k] * u.scale)).collect()
            };
            let (pg, pf, pr) = (pick(0), pick(1), pick(2));
            let gap_name = if !others {
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
fn how_far_table(
    po: Option<&ObservableSummary>,
    runs: &[RunRms],
    observable: &str,
    u: &Unit,
) -> String {
    let floor = po.map_or(f64::NAN, |p| p.noise_floor_mm);
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
    po: Option<&ObservableSummary>,
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
        let floor = po.map_or(f64::NAN, |p| p.noise_floor_mm * u.scale);
        let fl: Vec<(f64, f64)> = if floor.is_finite() {
            vec![(0.0, floor), ((runs.len() - 1) as f64, floor)]
        } else {
            Vec::new()
        };
        // The x axis is ticked with run ids (a group's first–last).
        let names: Vec<String> = runs.iter().map(|r| r.run.clone()).collect();
        let x_label = if grouped.len() < all.len() {
            format!(
                "run, in id order, groups of {}",
                all.len().div_ceil(MAX_RUN_POINTS)
            )
        } else {
            "run, in id order".to_string()
        };
        h.push_str(&xy_chart_with(
            &format!("{observable}: RMS per run, before and held-out after"),
            (&x_label, &format!("RMS ({})", u.shown)),
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
            &XyExtras {
                x_names: &names,
                ..Default::default()
            },
        ));
    }
    h
}

/// The pictures of one (machine, observable).
pub(super) fn pictures(
    d: Option<&Diagnosis>,
    po: Option<&ObservableSummary>,
    fig: &GroupFigures,
    runs: Option<&Vec<RunRms>>,
    observable: &str,
) -> String {
    let u = unit_of(observable, po.map(|p| p.unit.as_str()));
    let mut h = String::from("<div class=\"figs\">");
    let has_after = fig.has_after;
    // Nothing selected: the gap after is the gap before; one map.
    let selected = po.is_some_and(|p| !p.selected.is_empty());
    let (maps, outlined) = where_maps(d, fig, observable, &u, has_after && selected);
    h.push_str(&maps);
    h.push_str(&which_curve(po, fig, observable, &u));
    let few = runs.filter(|r| !r.is_empty() && r.len() < MIN_RUNS_CHARTED);
    if has_after && few.is_none() {
        h.push_str(&how_far_runs(po, runs, observable, &u));
    }
    h.push_str("</div>");
    if let (true, Some(runs)) = (has_after, few) {
        h.push_str(&how_far_table(po, runs, observable, &u));
    }
    if outlined {
        h.push_str("<p class=\"note\">Outlined on the before map: the cells of the regions where the gap is significantly above the noise floor. Both maps show the RMS per cell on one colour scale.</p>");
    }
    h
}

/// Cells per axis of the at-a-glance gap map thumbnail.
pub(super) const MINI_MAP_BINS: usize = 8;
/// Size in px of the at-a-glance thumbnails: wide enough to read a
/// region or a curve's shape at 100 % zoom.
pub(super) const MINI_SIZE: (u32, u32) = (120, 80);
/// Bins of the at-a-glance curve thumbnail.
pub(super) const MINI_CURVE_BINS: usize = 16;

/// "Where" and "which" as thumbnails for the at-a-glance table (the
/// answers above the fold): the gap map over x/y when the rows have
/// positions, and the gap against the named effect's covariate.
pub(super) fn glance_pictures(
    figs: Option<&FleetFigures>,
    machine: &str,
    observable: &str,
    named: Option<&str>,
) -> String {
    let Some(fig) = figs.and_then(|f| f.groups.get(&(machine.to_string(), observable.to_string())))
    else {
        return String::new();
    };
    let mut out = String::new();
    if let Some(cells) = &fig.mini_map {
        let cells: Vec<(f64, f64, f64)> = cells.iter().map(|c| (c.0, c.1, c.2[0].sqrt())).collect();
        out.push_str(&mini_heat(
            &cells,
            MINI_SIZE,
            false,
            &format!("gap RMS of {observable} over x and y (darker: larger)"),
        ));
    }
    if let (Some(k), Some(curve)) = (named, &fig.mini_curve) {
        let cov = curve_covariate(k);
        // The curve's fourth series is the gap.
        let pts: Vec<(f64, f64)> = curve.iter().map(|(x, m)| (*x, m[3])).collect();
        if !out.is_empty() {
            out.push(' ');
        }
        out.push_str(&mini_curve(
            &pts,
            MINI_SIZE.0,
            MINI_SIZE.1,
            &format!("gap of {observable} against {cov}"),
        ));
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
    let w = |v: f64| if v.is_finite() { 116.0 * v / top } else { 0.0 };
    let mut s = format!(
        r##"<svg class="mini" width="{W}" height="32" role="img" aria-label="gap, after, noise floor"><rect x="0" y="3" width="{:.1}" height="12" fill="#999"/>"##,
        w(rms),
        W = MINI_SIZE.0
    );
    if after.is_finite() {
        let _ = write!(
            s,
            r##"<rect x="0" y="17" width="{:.1}" height="12" fill="#2a7"/>"##,
            w(after)
        );
    }
    if floor.is_finite() {
        let _ = write!(
            s,
            r##"<line x1="{x:.1}" x2="{x:.1}" y1="0" y2="32" stroke="#000" stroke-width="2"/>"##,
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

//! The fleet page (issue 16 item 1): machine type → machine → observable.
//! Per observable one verdict line — gap against its own noise floor in
//! its own unit, the named effect with its parameter and interval, the
//! held-out shrink — then the pictures: the gap map over x/y before and
//! after the selected effects, the gap against the named effect's
//! covariate with the fitted curve, and each run's held-out RMS. No number
//! is pooled across observables of different scales (the touch probe's
//! noise would swamp every real gap). Candidates stay, folded.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write;

use serde_json::Value;

use super::fleet_data::{binned_means, grid_means, per_run_rms, FleetRows, RunRms};
use super::svg::{heat, mini_curve, mini_heat, shared_vmax, xy_chart_sized, Heat, Mark, Series};
use super::{esc, page, title_of};
use crate::diagnose::intervals::{format_pm, unit_of as param_unit};
use crate::engine::FleetOutcome;

/// Grid cells per axis of a gap map, and bins of a covariate curve: the
/// page's size stays bounded whatever the number of rows.
const MAP_BINS: usize = 16;
const CURVE_BINS: usize = 40;

/// An observable's unit and how it is shown: gaps in mm are shown in µm;
/// `velocity_error_*` is a velocity (mm/s, MODELS.md servo §), shown in
/// mm/s.
pub struct Unit {
    /// The unit of the data (`mm` or `mm/s`).
    pub data: String,
    /// The unit shown.
    pub shown: String,
    /// Shown = data × scale.
    pub scale: f64,
}

/// The unit an observable's numbers are in: `per_observable[].unit` of
/// diagnosis.json (observations v1.1 `unit` column) when given, else "mm"
/// — except `velocity_error_*`, which is mm/s even in a table written
/// before the unit column existed.
pub fn unit_of(observable: &str, unit: Option<&str>) -> Unit {
    match unit {
        Some("mm") => unit_of_observable("mm"),
        Some("mm/s") => unit_of_observable("velocity_error"),
        Some(other) => Unit {
            data: other.to_string(),
            shown: other.to_string(),
            scale: 1.0,
        },
        None => unit_of_observable(observable),
    }
}

/// By name alone (velocity_error_* is mm/s, everything else mm).
pub fn unit_of_observable(observable: &str) -> Unit {
    if observable.starts_with("velocity_error") {
        Unit {
            data: "mm/s".into(),
            shown: "mm/s".into(),
            scale: 1.0,
        }
    } else {
        Unit {
            data: "mm".into(),
            shown: "µm".into(),
            scale: 1e3,
        }
    }
}

impl Unit {
    /// A data value shown with three significant digits and its unit.
    pub fn show(&self, v: f64) -> String {
        if !v.is_finite() {
            return "—".into();
        }
        format!("{} {}", super::svg::tick(v * self.scale), self.shown)
    }
}

fn f(v: &Value, k: &str) -> f64 {
    v.get(k).and_then(|x| x.as_f64()).unwrap_or(f64::NAN)
}

fn s<'a>(v: &'a Value, k: &str) -> &'a str {
    v.get(k).and_then(|x| x.as_str()).unwrap_or("")
}

fn key_of(e: &Value) -> String {
    match e.get("covariate").and_then(|c| c.as_str()) {
        Some(c) => format!("{}:{c}", s(e, "name")),
        None => s(e, "name").to_string(),
    }
}

/// `k = 1.50e-5 ± 0.08e-5 mm/mm³ (95 % −… … …)` for each parameter of a
/// selected effect (diagnosis.json `effects[].intervals`).
fn params_text(e: &Value) -> Vec<String> {
    // An `effects` entry names its covariate; a `machine_effects` entry
    // spells it inside `effect` (name:covariate).
    let cov = e.get("covariate").and_then(|c| c.as_str()).or_else(|| {
        e.get("effect")
            .and_then(|x| x.as_str())
            .and_then(|k| k.split_once(':').map(|(_, c)| c))
    });
    let mut out = Vec::new();
    for (k, v) in e
        .get("params")
        .and_then(|p| p.as_object())
        .into_iter()
        .flatten()
    {
        let Some(v) = v.as_f64() else { continue };
        let unit = param_unit(k, cov);
        let iv = e.pointer(&format!("/intervals/{k}"));
        // Frame constants of a form (centre, span) come with a zero-width
        // interval: they were not fitted, so they are not a finding.
        if iv.is_some_and(|iv| f(iv, "se") == 0.0 && f(iv, "lo") == f(iv, "hi")) {
            continue;
        }
        match iv {
            Some(iv)
                if [v, f(iv, "se"), f(iv, "lo"), f(iv, "hi")]
                    .iter()
                    .all(|x| x.is_finite()) =>
            {
                out.push(format!(
                    "{k} = {} {unit} (95 % {:.3e} … {:.3e})",
                    format_pm(v, f(iv, "se")),
                    f(iv, "lo"),
                    f(iv, "hi")
                ))
            }
            _ if v.is_finite() => out.push(format!("{k} = {v:.3e} {unit}")),
            _ => {}
        }
    }
    out
}

/// A p-value as text ("—" when there is none).
fn pval(p: f64) -> String {
    if p.is_finite() {
        format!("{p:.1e}")
    } else {
        "—".into()
    }
}

/// Why a candidate was not selected, from its entry and the observable's.
fn why_lost(e: &Value, winners: &BTreeMap<usize, (String, f64)>, stop: &str) -> String {
    if let Some(r) = e.get("skipped_reason").and_then(|r| r.as_str()) {
        return format!("not tried: {r}");
    }
    if e.get("selected").and_then(|x| x.as_bool()) == Some(true) {
        return format!("selected (step {})", e["step"]);
    }
    let shrink = f(e, "shrink");
    let p = pval(f(e, "p_value"));
    let step = e.get("step").and_then(|x| x.as_u64()).unwrap_or(1) as usize;
    if !shrink.is_finite() {
        return "no held-out score".into();
    }
    if shrink <= 0.0 {
        return format!("held-out gap not smaller (shrink {shrink:.2})");
    }
    if let Some((w, ws)) = winners.get(&step) {
        return format!(
            "step {step}: {w} shrank the held-out gap more ({} vs {shrink:.2}; p = {p})",
            super::fmt_fixed(Some(*ws), 2)
        );
    }
    format!("not significant or selection stopped (p = {p}; {stop})")
}

/// The folded candidate ranking of one observable, best first.
fn candidates(d: &Value, observable: &str, stop: &str, u: &Unit) -> String {
    let mut es: Vec<&Value> = d
        .get("effects")
        .and_then(|e| e.as_array())
        .into_iter()
        .flatten()
        .filter(|e| s(e, "observable") == observable)
        .collect();
    if es.is_empty() {
        return String::new();
    }
    let winners: BTreeMap<usize, (String, f64)> = es
        .iter()
        .filter(|e| e.get("selected").and_then(|x| x.as_bool()) == Some(true))
        .map(|e| {
            (
                e.get("step").and_then(|x| x.as_u64()).unwrap_or(1) as usize,
                (key_of(e), f(e, "shrink")),
            )
        })
        .collect();
    // Selected first (in order), then by held-out RMS after, skipped last.
    let rank = |e: &Value| {
        let sel = e.get("selected").and_then(|x| x.as_bool()) == Some(true);
        let skipped = e.get("skipped_reason").map(|r| !r.is_null()) == Some(true);
        let after = f(e, "cv_rms_after_mm");
        (
            if sel {
                0
            } else if skipped {
                2
            } else {
                1
            },
            if sel { f(e, "step") } else { after },
        )
    };
    es.sort_by(|a, b| {
        let (ra, rb) = (rank(a), rank(b));
        ra.0.cmp(&rb.0)
            .then(ra.1.total_cmp(&rb.1))
            .then(key_of(a).cmp(&key_of(b)))
    });
    let mut h = format!(
        "<details><summary>All {} candidates for {}, ranked, and why each lost</summary><table><thead><tr><th>effect</th><th>held-out RMS before ({})</th><th>after ({})</th><th>shrink</th><th>p</th><th>verdict</th></tr></thead><tbody>",
        es.len(),
        esc(observable),
        u.shown,
        u.shown
    );
    for e in es {
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td class=\"why\">{}</td></tr>",
            esc(&key_of(e)),
            super::svg::tick(f(e, "cv_rms_before_mm") * u.scale),
            super::svg::tick(f(e, "cv_rms_after_mm") * u.scale),
            super::fmt_fixed(Some(f(e, "shrink")), 2),
            super::fmt_fixed(Some(f(e, "p_value")), 4),
            esc(&why_lost(e, &winners, stop))
        );
    }
    h.push_str("</tbody></table></details>");
    h
}

/// augment.json entries (written by the augmentation step when it ran).
fn augment_entries(out_dir: &std::path::Path) -> Vec<Value> {
    std::fs::read(out_dir.join("fleet").join("augment.json"))
        .ok()
        .and_then(|b| serde_json::from_slice::<Value>(&b).ok())
        .and_then(|v| v.get("entries").and_then(|o| o.as_array()).cloned())
        .unwrap_or_default()
}

/// The verdict line of one observable (the diagnosis is per observable,
/// pooled over the machines that carry it).
fn verdict(d: &Value, po: &Value, augment: &[Value], machine: &str) -> String {
    let obs = s(po, "observable");
    let u = unit_of(obs, po.get("unit").and_then(|x| x.as_str()));
    let (rms, floor) = (f(po, "rms_mm"), f(po, "noise_floor_mm"));
    let mut v = format!(
        "Gap RMS <b>{}</b> against a noise floor of {} ({})",
        u.show(rms),
        u.show(floor),
        esc(s(po, "noise_floor_source"))
    );
    let above = po.get("gap_above_noise").and_then(|x| x.as_bool()) == Some(true);
    if above && floor > 0.0 && rms.is_finite() {
        let _ = write!(v, ", {:.1}× the floor", rms / floor);
    }
    v.push_str(". ");
    let selected: Vec<&str> = po
        .get("selected")
        .and_then(|x| x.as_array())
        .map(|a| a.iter().filter_map(|x| x.as_str()).collect())
        .unwrap_or_default();
    if !above {
        v.push_str("<span class=\"ok\">At the noise floor: nothing to explain.</span>");
    } else if selected.is_empty() {
        let _ = write!(
            v,
            "<span class=\"bad\">Not explained</span>: {}.",
            esc(s(po, "stop_reason"))
        );
    } else {
        let effects: Vec<&Value> = d
            .get("effects")
            .and_then(|e| e.as_array())
            .into_iter()
            .flatten()
            .filter(|e| {
                s(e, "observable") == obs
                    && e.get("selected").and_then(|x| x.as_bool()) == Some(true)
            })
            .collect();
        let mut named = Vec::new();
        for k in &selected {
            let e = effects.iter().find(|e| key_of(e) == *k);
            let mut t = format!("<b>{}</b>", esc(k));
            if let Some(e) = e {
                let p = params_text(e);
                if !p.is_empty() {
                    let _ = write!(t, " with {}", esc(&p.join(", ")));
                }
                // The machines disagree: this machine's own fit.
                if let Some(own) = e
                    .get("per_machine")
                    .and_then(|m| m.as_array())
                    .and_then(|m| m.iter().find(|x| s(x, "machine") == machine))
                {
                    let ps: Vec<String> = own
                        .get("params")
                        .and_then(|p| p.as_object())
                        .into_iter()
                        .flatten()
                        .filter_map(|(k, v)| {
                            v.as_f64()
                                .filter(|x| x.is_finite())
                                .map(|x| format!("{k} = {x:.3e}"))
                        })
                        .collect();
                    let _ = write!(
                        t,
                        " (machines differ; {} alone: {})",
                        esc(machine),
                        esc(&ps.join(", "))
                    );
                }
            }
            named.push(t);
        }
        let _ = write!(v, "Explained by {}. ", named.join("; then "));
        let si = po
            .get("shrink_interval")
            .and_then(|x| x.as_array())
            .and_then(|a| {
                let lo = a
                    .first()
                    .and_then(|x| x.as_f64())
                    .filter(|x| x.is_finite())?;
                let hi = a
                    .get(1)
                    .and_then(|x| x.as_f64())
                    .filter(|x| x.is_finite())?;
                Some(format!(" (95 % {lo:.2}–{hi:.2})"))
            })
            .unwrap_or_default();
        let _ = write!(
            v,
            "Held-out RMS {} → <b>{}</b>, shrink <b>{}</b>{si}.",
            u.show(f(po, "cv_rms_before_mm")),
            u.show(f(po, "cv_rms_after_mm")),
            super::fmt_fixed(Some(f(po, "shrink")), 2)
        );
    }
    // Effects named on this machine's rows alone (diagnosis.json
    // machine_effects): the pooled fit may miss what only one machine has.
    for me in d
        .get("machine_effects")
        .and_then(|m| m.as_array())
        .into_iter()
        .flatten()
        .filter(|me| s(me, "observable") == obs && s(me, "machine") == machine)
    {
        let p = params_text(me);
        let _ = write!(
            v,
            " <span class=\"bad\">This machine alone</span>: <b>{}</b>{}, held-out shrink {} over its {} runs.",
            esc(s(me, "effect")),
            if p.is_empty() {
                String::new()
            } else {
                format!(" with {}", esc(&p.join(", ")))
            },
            super::fmt_fixed(Some(f(me, "shrink")), 2),
            me.get("runs").and_then(|x| x.as_u64()).unwrap_or(0)
        );
    }
    for a in augment.iter().filter(|a| {
        s(a, "observable") == obs
            && a.get("machine")
                .and_then(|m| m.as_str())
                .is_none_or(|m| m == machine)
    }) {
        let au = a.get("unit").and_then(|x| x.as_str()).unwrap_or(&u.data);
        let scale = if au == u.data { u.scale } else { 1.0 };
        let shown = if au == u.data { u.shown.as_str() } else { au };
        let held = a.get("held_out").and_then(|x| x.as_bool()) == Some(true);
        let _ = write!(
            v,
            " Augmented simulator (+ {}), on {} {}: gap {} {shown} plain → <b>{} {shown}</b> augmented.",
            esc(&a
                .get("effects")
                .and_then(|e| e.as_array())
                .map(|e| e.iter().filter_map(|x| x.as_str()).collect::<Vec<_>>().join(", "))
                .unwrap_or_default()),
            a.get("runs").and_then(|x| x.as_u64()).unwrap_or(0),
            if held {
                "runs it was not fitted on"
            } else {
                "runs it was fitted on (in-sample: no other run tonight)"
            },
            super::svg::tick(f(a, "heldout_rms_plain") * scale),
            super::svg::tick(f(a, "heldout_rms_augmented") * scale),
        );
    }
    v
}

/// `where` tiles over x_mm,y_mm of an observable: rectangles to outline.
fn xy_tiles(d: &Value, observable: &str, scale_pad: (f64, f64)) -> Vec<[(f64, f64); 2]> {
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

/// Smallest spacing of distinct values (a grid's cell size).
fn spacing(v: impl Iterator<Item = f64>) -> f64 {
    let mut u: Vec<f64> = v.filter(|x| x.is_finite()).collect();
    u.sort_by(f64::total_cmp);
    u.dedup();
    u.windows(2)
        .map(|w| w[1] - w[0])
        .fold(f64::INFINITY, f64::min)
        .min(1e300)
}

/// The pictures of one (machine, observable).
fn pictures(
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
    let mut outlined = false;
    let gap = FleetRows::at(&rows.gap, idx);
    let res = FleetRows::at(&rows.residual, idx);
    let has_after = res.iter().any(|r| r.is_finite());
    // 1. Where: the gap map over the workpiece.
    if let (Some(x), Some(y)) = (rows.values("x_mm", idx), rows.values("y_mm", idx)) {
        let cells = grid_means(&x, &y, &[&gap, &res], MAP_BINS);
        let before: Vec<(f64, f64, f64)> =
            cells.iter().map(|c| (c.0, c.1, c.2[0] * u.scale)).collect();
        let after: Vec<(f64, f64, f64)> =
            cells.iter().map(|c| (c.0, c.1, c.2[1] * u.scale)).collect();
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
        outlined = !tiles.is_empty();
    }
    // 2. Which: the gap against the named effect's covariate.
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
            let mut partial = gap.clone();
            for o in &others {
                if let Some(v) = rows.values(o, idx) {
                    for (p, x) in partial.iter_mut().zip(&v) {
                        if x.is_finite() {
                            *p -= x;
                        }
                    }
                }
            }
            let b = binned_means(&c, &[&partial, &fit, &res], CURVE_BINS);
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
    // 3. How far: each run's RMS before and held-out after.
    if let Some(runs) = runs.filter(|r| !r.is_empty() && has_after) {
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
    h.push_str("</div>");
    if outlined {
        h.push_str("<p class=\"note\">Outlined on the maps: cells where the gap is significantly above the noise floor.</p>");
    }
    h
}

/// The covariate an effect's curve is drawn against. A 2-D covariate
/// (thermal_bow:y_mm,t_s): the map shows the positions, the curve the other.
fn curve_covariate(effect_key: &str) -> &str {
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
const MINI_MAP_BINS: usize = 8;
/// Bins of the at-a-glance curve thumbnail.
const MINI_CURVE_BINS: usize = 16;

/// "Where" and "which" as thumbnails for the at-a-glance table (issue 16:
/// the answers above the fold): the gap map over x/y when the rows have
/// positions, and the gap against the named effect's covariate.
fn glance_pictures(
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
fn mini_bars(rms: f64, after: f64, floor: f64) -> String {
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
const MAX_RUN_POINTS: usize = 60;

/// Runs in consecutive groups of equal size, at most `max` groups, each
/// with its pooled RMS; the runs themselves when there are few.
fn group_runs(runs: &[RunRms], max: usize) -> Vec<RunRms> {
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
fn covariates_drawn(d: Option<&Value>) -> Vec<String> {
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

fn anchor(parts: &[&str]) -> String {
    parts
        .iter()
        .map(|p| {
            p.chars()
                .map(|c| if c.is_ascii_alphanumeric() { c } else { '-' })
                .collect::<String>()
        })
        .collect::<Vec<_>>()
        .join("--")
}

/// The fleet report.
pub fn fleet_page(
    cfg: &toml::Table,
    outcome: &FleetOutcome,
    diagnosis: Option<&Value>,
    diagnosis_html: Option<&str>,
) -> String {
    let out = &outcome.out_dir;
    let fleet_dir = out.join("fleet");
    let mut body = String::from(
        "<nav><a href=\"../index.html\">← index: every run, every output, the night's failures</a></nav>",
    );
    // Machine → type (plugin), and the runs per machine.
    let mut type_of: BTreeMap<&str, &str> = BTreeMap::new();
    let mut runs_of: BTreeMap<&str, usize> = BTreeMap::new();
    for r in &outcome.runs {
        type_of.insert(&r.machine, &r.plugin);
        *runs_of.entry(&r.machine).or_default() += 1;
    }
    let _ = write!(
        body,
        "<p>{} runs on {} machines processed",
        outcome.runs.len(),
        runs_of.len()
    );
    if outcome.failures.is_empty() {
        body.push_str(", none rejected.</p>");
    } else {
        let _ = write!(
            body,
            "; <a class=\"bad\" href=\"../index.html#failures\"><b>{} rejected</b></a>.</p>",
            outcome.failures.len()
        );
    }
    let per_obs: BTreeMap<&str, &Value> = diagnosis
        .and_then(|d| d.get("per_observable"))
        .and_then(|p| p.as_array())
        .into_iter()
        .flatten()
        .map(|p| (s(p, "observable"), p))
        .collect();
    let obs_file = fleet_dir.join("observations.parquet");
    let diag_file = fleet_dir.join("diagnosis.parquet");
    let rows = if obs_file.is_file() {
        match FleetRows::load(
            &obs_file,
            diagnosis.map(|_| diag_file.as_path()),
            &covariates_drawn(diagnosis),
        ) {
            Ok(r) => Some(r),
            Err(e) => {
                let _ = write!(
                    body,
                    "<p class=\"warn\">The gap pictures are missing: {}</p>",
                    esc(&format!("{e:#}"))
                );
                None
            }
        }
    } else {
        None
    };
    let per_run = if diagnosis.is_some() && diag_file.is_file() {
        per_run_rms(&diag_file).unwrap_or_default()
    } else {
        BTreeMap::new()
    };
    let augment = augment_entries(out);
    // Type → machine → observables (from the rows; the diagnosis's
    // observables when the rows could not be read).
    let mut tree: BTreeMap<&str, BTreeMap<String, Vec<String>>> = BTreeMap::new();
    if let Some(r) = &rows {
        for (m, o) in r.groups.keys() {
            let t = type_of.get(m.as_str()).copied().unwrap_or("—");
            tree.entry(t)
                .or_default()
                .entry(m.clone())
                .or_default()
                .push(o.clone());
        }
    } else {
        for (o, p) in &per_obs {
            for m in p
                .get("machines")
                .and_then(|m| m.as_array())
                .into_iter()
                .flatten()
                .filter_map(|m| m.as_str())
            {
                let t = type_of.get(m).copied().unwrap_or("—");
                tree.entry(t)
                    .or_default()
                    .entry(m.to_string())
                    .or_default()
                    .push(o.to_string());
            }
        }
    }
    // At a glance: one row per (machine, observable), each in its own unit.
    if !tree.is_empty() {
        body.push_str("<h2>At a glance</h2><table class=\"glance\"><thead><tr><th>type / machine / observable</th><th>gap RMS</th><th>noise floor</th><th class=\"why\">named effect</th><th>where · which</th><th>held-out after</th><th>shrink</th><th>how far</th></tr></thead><tbody>");
        for (t, machines) in &tree {
            for (m, obs) in machines {
                for o in obs {
                    let p = per_obs.get(o.as_str());
                    let u = unit_of(o, p.and_then(|p| p.get("unit")).and_then(|x| x.as_str()));
                    let pf = |k: &str| p.map(|p| f(p, k)).unwrap_or(f64::NAN);
                    let above = p
                        .and_then(|p| p.get("gap_above_noise"))
                        .and_then(|x| x.as_bool())
                        == Some(true);
                    let sel = p
                        .and_then(|p| p.get("selected"))
                        .and_then(|x| x.as_array())
                        .map(|a| {
                            a.iter()
                                .filter_map(|x| x.as_str())
                                .collect::<Vec<_>>()
                                .join(", ")
                        })
                        .unwrap_or_default();
                    let named = if !above {
                        "<span class=\"ok\">at noise floor</span>".to_string()
                    } else if sel.is_empty() {
                        "<span class=\"bad\">not explained</span>".to_string()
                    } else {
                        esc(&sel)
                    };
                    let _ = write!(
                        body,
                        "<tr><td><a href=\"#{}\">{} / {} / {}</a></td><td>{}</td><td>{}</td><td class=\"why\">{}</td><td class=\"thumbs\">{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                        anchor(&[m, o]),
                        esc(t),
                        esc(m),
                        esc(o),
                        u.show(pf("rms_mm")),
                        u.show(pf("noise_floor_mm")),
                        named,
                        if above {
                            glance_pictures(
                                rows.as_ref(),
                                m,
                                o,
                                (!sel.is_empty()).then(|| sel.split(", ").next().unwrap_or("")),
                            )
                        } else {
                            String::new()
                        },
                        if above && !sel.is_empty() { u.show(pf("cv_rms_after_mm")) } else { "—".into() },
                        if above && !sel.is_empty() { super::fmt_fixed(Some(100.0 * pf("shrink")), 0) + " %" } else { "—".into() },
                        mini_bars(
                            pf("rms_mm"),
                            if above && !sel.is_empty() { pf("cv_rms_after_mm") } else { f64::NAN },
                            pf("noise_floor_mm")
                        ),
                    );
                }
            }
        }
        body.push_str("</tbody></table><p class=\"note\">where: the gap map over the workpiece (red: real above sim, blue: below); which: the mean gap against the named effect's covariate; how far: gap RMS (grey), held-out RMS after the named effects (green), noise floor (black tick). Each row on its own scale; the full pictures are in the observable's section.</p>");
    }
    if let Some(d) = diagnosis {
        let notes: Vec<&str> = d
            .get("notes")
            .and_then(|n| n.as_array())
            .into_iter()
            .flatten()
            .filter_map(|n| n.as_str())
            .collect();
        if !notes.is_empty() {
            let _ = write!(
                body,
                "<details><summary>Diagnosis notes ({}): skipped covariates, trimmed outliers</summary><ul class=\"notes\">",
                notes.len()
            );
            for n in notes {
                let _ = write!(body, "<li>{}</li>", esc(n));
            }
            body.push_str("</ul></details>");
        }
    }
    for (t, machines) in &tree {
        let _ = write!(body, "<h2>Machine type {}</h2>", esc(t));
        for (m, obs) in machines {
            let _ = write!(
                body,
                "<h3>Machine {} <span class=\"note\">({} runs)</span></h3>",
                esc(m),
                runs_of.get(m.as_str()).copied().unwrap_or(0)
            );
            for o in obs {
                let p = per_obs.get(o.as_str()).copied();
                let u = unit_of(o, p.and_then(|p| p.get("unit")).and_then(|x| x.as_str()));
                let _ = write!(
                    body,
                    "<section class=\"obs\" id=\"{}\"><h4>{} <span class=\"note\">({})</span></h4>",
                    anchor(&[m, o]),
                    esc(o),
                    u.data
                );
                if let (Some(d), Some(p)) = (diagnosis, p) {
                    let _ = write!(
                        body,
                        "<p class=\"verdict\">{}</p>",
                        verdict(d, p, &augment, m)
                    );
                }
                if let Some(r) = &rows {
                    if let Some(idx) = r.groups.get(&(m.clone(), o.clone())) {
                        body.push_str(&pictures(
                            diagnosis,
                            p,
                            r,
                            idx,
                            per_run.get(&(m.clone(), o.clone())),
                            o,
                        ));
                    }
                }
                if let (Some(d), Some(p)) = (diagnosis, p) {
                    body.push_str(&candidates(d, o, s(p, "stop_reason"), &u));
                }
                body.push_str("</section>");
            }
        }
    }
    if let Some(h) = diagnosis_html {
        body.push_str("<details class=\"appendix\"><summary>Diagnosis tables (every observable: where, which, per machine, unexplained)</summary>");
        body.push_str(h);
        body.push_str("</details>");
    }
    page(&title_of(cfg, "sparkout fleet report"), &body)
}

#[cfg(test)]
mod tests {
    use super::*;

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
        let winners: BTreeMap<usize, (String, f64)> =
            [(1, ("wear:removed_mm3".into(), 0.74))].into();
        let lost = serde_json::json!({"name": "drift", "covariate": "t_s", "shrink": 0.2, "p_value": 0.001, "step": 1, "selected": false});
        assert!(
            why_lost(&lost, &winners, "").contains("wear:removed_mm3 shrank the held-out gap more")
        );
        let worse =
            serde_json::json!({"name": "drift", "shrink": -0.1, "step": 1, "selected": false});
        assert!(why_lost(&worse, &winners, "").starts_with("held-out gap not smaller"));
        let skipped = serde_json::json!({"name": "drift", "skipped_reason": "no t_s column", "selected": false});
        assert_eq!(why_lost(&skipped, &winners, ""), "not tried: no t_s column");
    }

    #[test]
    fn selected_parameters_carry_their_interval_and_unit() {
        let e = serde_json::json!({"name": "wear", "covariate": "removed_mm3", "params": {"k": -9.35e-5},
            "intervals": {"k": {"se": 0.9e-5, "lo": -1.22e-4, "hi": -6.5e-5}}});
        let p = params_text(&e);
        assert_eq!(p.len(), 1);
        assert!(
            p[0].contains("±") && p[0].contains("mm/mm³") && p[0].contains("95 %"),
            "{}",
            p[0]
        );
    }
}

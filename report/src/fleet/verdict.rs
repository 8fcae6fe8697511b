//! The verdict line of one (machine, observable) and its candidates table:
//! the gap in the observable's unit, the named effect with its parameters
//! and intervals, the held-out shrink, the augmented simulator's gap.

use super::*;
use crate::diagnose::augment::{AugmentEntry, AugmentReport};
use crate::diagnose::document::{caution_sentences, rivals_text};
use crate::diagnose::intervals::ParamInterval;

/// An observable's unit and how it is shown: gaps in mm are shown in µm;
/// `velocity_error_*` is a velocity (mm/s, docs/models.md §7), shown in
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
    /// A data value shown with three significant digits and its unit; a
    /// length in nm, µm or mm by its magnitude (a 2 nm gap is not
    /// "0.00200 µm").
    pub fn show(&self, v: f64) -> String {
        if !v.is_finite() {
            return "—".into();
        }
        if self.data == "mm" {
            return crate::units::format::show_length(v);
        }
        crate::units::format::show_in(v, &self.data)
    }
}

/// `k = 4.92 ± 0.08 ms (95 % 4.76 … 5.07 ms)` for each parameter of an
/// effect (diagnosis.json `effects[].intervals` when it has them), in the
/// unit an engineer reads it in (units::format). The offset is not shown.
pub(super) fn params_text(
    params: &BTreeMap<String, f64>,
    intervals: Option<&BTreeMap<String, ParamInterval>>,
    cov: Option<&str>,
    param_units: &BTreeMap<String, String>,
) -> Vec<String> {
    use crate::units::format::{param_unit, show_param};
    // The offset is in the gap's unit (mm/s for a velocity); a diagnosis
    // written before `param_units` is in mm.
    let gap_unit = param_units.get("offset_mm").map_or("mm", String::as_str);
    let mut out = Vec::new();
    for (k, &v) in params {
        let unit = param_unit(k, cov, gap_unit);
        let iv = intervals.and_then(|i| i.get(k));
        // Frame constants of a form (centre, span) come with a zero-width
        // interval: they were not fitted, so they are not a finding.
        if iv.is_some_and(|iv| iv.se == 0.0 && iv.lo == iv.hi) {
            continue;
        }
        match iv {
            Some(iv) if [v, iv.se, iv.lo, iv.hi].iter().all(|x| x.is_finite()) => {
                out.push(show_param(k, v, Some((iv.se, iv.lo, iv.hi)), &unit))
            }
            _ if v.is_finite() => out.push(show_param(k, v, None, &unit)),
            _ => {}
        }
    }
    out
}

/// [`params_text`] of a diagnosis.json `effects` entry.
pub(super) fn effect_params_text(e: &EffectEntry) -> Vec<String> {
    params_text(
        &e.params,
        e.intervals.as_ref(),
        e.covariate.as_deref(),
        &e.param_units,
    )
}

/// A p-value as text ("—" when there is none).
pub(super) fn pval(p: f64) -> String {
    crate::units::format::show_p(p)
}

/// Why a candidate was not selected, from its entry and the observable's.
pub(super) fn why_lost(
    e: &EffectEntry,
    winners: &BTreeMap<usize, (String, f64)>,
    stop: &str,
) -> String {
    if let Some(r) = &e.skipped_reason {
        return format!("not tried: {r}");
    }
    if e.selected {
        return format!("selected (step {})", e.step);
    }
    let shrink = e.shrink.unwrap_or(f64::NAN);
    let p = pval(e.p_value.unwrap_or(f64::NAN));
    let step = e.step;
    if !shrink.is_finite() {
        return "no held-out score".into();
    }
    if shrink <= 0.0 {
        return format!("held-out gap not smaller (shrink {shrink:.2})");
    }
    if let Some((w, ws)) = winners.get(&step) {
        return format!(
            "step {step}: {w} shrank the held-out gap more ({} vs {shrink:.2}; p = {p})",
            super::super::fmt_fixed(Some(*ws), 2)
        );
    }
    format!("not significant or selection stopped (p = {p}; {stop})")
}

/// The folded candidate ranking of one observable, best first.
pub(super) fn candidates(d: &Diagnosis, observable: &str, stop: &str, u: &Unit) -> String {
    let nan = |x: Option<f64>| x.unwrap_or(f64::NAN);
    let mut es: Vec<&EffectEntry> = d
        .effects
        .iter()
        .filter(|e| e.observable == observable)
        .collect();
    if es.is_empty() {
        return String::new();
    }
    let winners: BTreeMap<usize, (String, f64)> = es
        .iter()
        .filter(|e| e.selected)
        .map(|e| (e.step, (e.key(), nan(e.shrink))))
        .collect();
    // Selected first (in order), then by held-out RMS after, skipped last.
    let rank = |e: &EffectEntry| {
        let sel = e.selected;
        let skipped = e.skipped_reason.is_some();
        let after = nan(e.cv_rms_after_mm);
        (
            if sel {
                0
            } else if skipped {
                2
            } else {
                1
            },
            if sel { e.step as f64 } else { after },
        )
    };
    es.sort_by(|a, b| {
        let (ra, rb) = (rank(a), rank(b));
        ra.0.cmp(&rb.0)
            .then(ra.1.total_cmp(&rb.1))
            .then(a.key().cmp(&b.key()))
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
            esc(&e.key()),
            super::super::svg::tick(nan(e.cv_rms_before_mm) * u.scale),
            super::super::svg::tick(nan(e.cv_rms_after_mm) * u.scale),
            super::super::fmt_fixed(e.shrink, 2),
            super::super::fmt_fixed(e.p_value, 4),
            esc(&why_lost(e, &winners, stop))
        );
    }
    h.push_str("</tbody></table></details>");
    h
}

/// fleet/augment.json (written by the augmentation step when `run
/// --augment` ran), read through its type; none when absent or unreadable.
pub(super) fn augment_file(out_dir: &std::path::Path) -> Option<AugmentReport> {
    let path = out_dir.join("fleet").join("augment.json");
    if !path.is_file() {
        return None;
    }
    AugmentReport::read(&path)
        .map_err(|e| tracing::warn!("fleet report without the augmented simulator: {e:#}"))
        .ok()
}

/// augment.json's entries (none without it).
pub(super) fn augment_entries(augment: Option<&AugmentReport>) -> &[AugmentEntry] {
    augment.map_or(&[], |a| a.entries.as_slice())
}

/// The augmented simulator's lines of a verdict (`fleet/augment.json`
/// entries for this observable and machine).
fn augment_lines(augment: &[AugmentEntry], obs: &str, machine: &str, u: &Unit) -> String {
    let mut v = String::new();
    for a in augment
        .iter()
        .filter(|a| a.observable == obs && a.machine == machine)
    {
        let au = a.unit.as_deref().unwrap_or(&u.data);
        let scale = if au == u.data { u.scale } else { 1.0 };
        let shown = if au == u.data { u.shown.as_str() } else { au };
        let _ = write!(
            v,
            " Augmented simulator (+ {}), on {} {}: gap {} {shown} plain → <b>{} {shown}</b> augmented.",
            esc(&a.effects.join(", ")),
            a.runs,
            if a.held_out {
                "runs it was not fitted on"
            } else {
                "runs it was fitted on (in-sample: no other run tonight)"
            },
            super::super::svg::tick(a.heldout_rms_plain * scale),
            super::super::svg::tick(a.heldout_rms_augmented * scale),
        );
        if !a.in_physics.is_empty() {
            let _ = write!(
                v,
                " Re-simulated in the plugin's physics: {} (its compensation too).",
                esc(&a.in_physics.join(", "))
            );
        }
    }
    v
}

/// The verdict line of one observable (the diagnosis is per observable,
/// pooled over the machines that carry it).
pub(super) fn verdict(
    d: &Diagnosis,
    po: &ObservableSummary,
    augment: &[AugmentEntry],
    machine: &str,
) -> String {
    let obs = po.observable.as_str();
    let u = unit_of(obs, Some(&po.unit));
    let (rms, floor) = (po.rms_mm, po.noise_floor_mm);
    let mut v = format!(
        "Gap RMS <b>{}</b> against a noise floor of {} ({})",
        u.show(rms),
        u.show(floor),
        esc(&po.noise_floor_source)
    );
    let above = po.gap_above_noise;
    if above && floor > 0.0 && rms.is_finite() {
        let _ = write!(v, ", {:.1}× the floor", rms / floor);
    }
    v.push_str(". ");
    let selected = &po.selected;
    if !above {
        v.push_str("<span class=\"ok\">At the noise floor: nothing to explain.</span>");
    } else if selected.is_empty() {
        let _ = write!(
            v,
            "<span class=\"bad\">Not explained</span>: {}.",
            esc(&po.stop_reason)
        );
    } else {
        let effects: Vec<&EffectEntry> = d
            .effects
            .iter()
            .filter(|e| e.observable == obs && e.selected)
            .collect();
        let mut named = Vec::new();
        for k in selected {
            let e = effects.iter().find(|e| e.key() == *k);
            let mut t = format!("<b>{}</b>", esc(k));
            if let Some(r) = e.and_then(|e| rivals_text(&e.indistinguishable_from)) {
                let _ = write!(t, " ({})", esc(&r));
            }
            if let Some(e) = e {
                let p = effect_params_text(e);
                if !p.is_empty() {
                    let _ = write!(t, " with {}", esc(&p.join(", ")));
                }
                // The machines disagree: this machine's own fit.
                if let Some(own) = e
                    .per_machine
                    .as_ref()
                    .and_then(|m| m.iter().find(|x| x.machine == machine))
                {
                    // In the units of the pooled fit's parameters.
                    let ps = params_text(&own.params, None, e.covariate.as_deref(), &e.param_units);
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
        // What these runs cannot rule out: another cause on a covariate
        // that moves with the named one's (docs/models.md §8.6).
        for s in caution_sentences(po, &d.effects) {
            let _ = write!(v, "<span class=\"bad\">{}</span> ", esc(&s));
        }
        let si = po
            .shrink_interval
            .filter(|[lo, hi]| lo.is_finite() && hi.is_finite())
            .map(|[lo, hi]| format!(" (95 % {lo:.2}–{hi:.2})"))
            .unwrap_or_default();
        let _ = write!(
            v,
            "Held-out RMS {} → <b>{}</b>, shrink <b>{}</b>{si}.",
            u.show(po.cv_rms_before_mm),
            u.show(po.cv_rms_after_mm),
            super::super::fmt_fixed(Some(po.shrink), 2)
        );
    }
    // Effects named on this machine's rows alone (diagnosis.json
    // machine_effects): the pooled fit may miss what only one machine has.
    for me in d
        .machine_effects
        .iter()
        .filter(|me| me.observable == obs && me.machine == machine)
    {
        // A `machine_effects` entry spells its covariate inside `effect`
        // (name:covariate).
        let cov = me.effect.split_once(':').map(|(_, c)| c);
        let p = params_text(&me.params, me.intervals.as_ref(), cov, &me.param_units);
        let _ = write!(
            v,
            " <span class=\"bad\">This machine alone</span>: <b>{}</b>{}, held-out shrink {} over its {} runs.",
            esc(&me.effect),
            if p.is_empty() {
                String::new()
            } else {
                format!(" with {}", esc(&p.join(", ")))
            },
            super::super::fmt_fixed(me.shrink, 2),
            me.runs
        );
    }
    v.push_str(&augment_lines(augment, obs, machine, &u));
    v
}

//! The at-a-glance table: one row per (machine, observable) above its
//! noise floor, ranked by gap over floor; those at their floor, one line
//! per machine; with `--augment`, last night's model on tonight's runs.

use super::*;
use crate::diagnose::augment::AugmentReport;

/// Gap RMS over noise floor of an observable (NaN when either is unknown).
pub(super) fn gap_over_floor(p: Option<&ObservableSummary>) -> f64 {
    let (rms, floor) = p.map_or((f64::NAN, f64::NAN), |p| (p.rms_mm, p.noise_floor_mm));
    if floor > 0.0 {
        rms / floor
    } else {
        f64::NAN
    }
}

/// The diagnosis found the observable's gap not above its noise floor
/// (`gap_above_noise`). Unknown when the observable was not diagnosed.
pub(super) fn at_noise_floor(p: Option<&ObservableSummary>) -> bool {
    p.is_some_and(|p| !p.gap_above_noise)
}

/// "116×", "1.1×", or "—".
fn times(r: f64) -> String {
    if !r.is_finite() {
        "—".into()
    } else if r >= 10.0 {
        format!("{r:.0}×")
    } else {
        format!("{r:.1}×")
    }
}

/// Largest gap over noise floor first (unknown last), then by name.
/// `key` gives an item's gap over floor and its name.
fn by_gap_over_floor<T>(v: &mut [T], key: impl Fn(&T) -> (f64, String)) {
    v.sort_by(|a, b| {
        let ((ra, ka), (rb, kb)) = (key(a), key(b));
        // NaN sorts last; larger first.
        let rank = |r: f64| if r.is_finite() { -r } else { f64::INFINITY };
        rank(ra).total_cmp(&rank(rb)).then(ka.cmp(&kb))
    });
}

/// A machine's observables for its section: above the floor (largest gap
/// over floor first), and those at their noise floor.
pub(super) fn split_at_floor<'a>(
    obs: &'a [String],
    per_obs: &BTreeMap<&str, &ObservableSummary>,
) -> (Vec<&'a String>, Vec<&'a String>) {
    let mut v: Vec<&String> = obs.iter().collect();
    by_gap_over_floor(&mut v, |o| {
        (
            gap_over_floor(per_obs.get(o.as_str()).copied()),
            o.to_string(),
        )
    });
    let (live, mut flat): (Vec<&String>, Vec<&String>) = v
        .into_iter()
        .partition(|o| !at_noise_floor(per_obs.get(o.as_str()).copied()));
    // Nothing to rank at the floor: by name.
    flat.sort();
    (live, flat)
}

/// "Last night's model on tonight's runs" of one row: the held-out gap of
/// the plain simulator → the simulator augmented with the model's effects
/// (fleet/augment.json), or why there is none.
fn augment_cell(augment: &AugmentReport, o: &str, m: &str, u: &Unit) -> String {
    let entry = augment
        .entries
        .iter()
        .find(|a| a.observable == o && (a.machine.is_empty() || a.machine == m));
    let Some(a) = entry else {
        let why = augment
            .not_applied
            .iter()
            .filter(|n| n.observable == o)
            .map(|n| format!("{}: {}", n.effect, n.why))
            .collect::<Vec<_>>();
        let why = if why.is_empty() {
            "the model has no effect for this observable".to_string()
        } else {
            why.join("; ")
        };
        return format!("<span title=\"{}\">—</span>", esc(&why));
    };
    let au = a.unit.as_deref().unwrap_or(&u.data);
    let show = |v: f64| {
        if au == u.data {
            u.show(v)
        } else {
            format!("{} {au}", crate::svg::tick(v))
        }
    };
    format!(
        "{} → <b>{}</b>{}",
        show(a.heldout_rms_plain),
        show(a.heldout_rms_augmented),
        if a.held_out {
            String::new()
        } else {
            " <span class=\"note\">in-sample</span>".into()
        }
    )
}

/// "At a glance": one row per (machine, observable), each in its own
/// unit, the largest gap over noise floor first; the observables at their
/// noise floor, one line per machine. With `--augment`, the held-out gap
/// of last night's model on tonight's runs.
pub(super) fn glance_table(
    tree: &Tree,
    per_obs: &BTreeMap<&str, &ObservableSummary>,
    rows: Option<&FleetFigures>,
    augment: Option<&AugmentReport>,
) -> String {
    if tree.is_empty() {
        return String::new();
    }
    // (type, machine, observable), ranked; and per (type, machine) the
    // observables at their floor.
    let mut ranked: Vec<(&str, &str, &str)> = Vec::new();
    let mut floor: Vec<((&str, &str), Vec<&str>)> = Vec::new();
    for (t, machines) in tree {
        for (m, obs) in machines {
            let (live, flat) = split_at_floor(obs, per_obs);
            ranked.extend(live.iter().map(|o| (*t, m.as_str(), o.as_str())));
            if !flat.is_empty() {
                floor.push(((*t, m.as_str()), flat.iter().map(|o| o.as_str()).collect()));
            }
        }
    }
    by_gap_over_floor(&mut ranked, |(t, m, o)| {
        (
            gap_over_floor(per_obs.get(o).copied()),
            format!("{t}\u{0}{m}\u{0}{o}"),
        )
    });
    let cols = if augment.is_some() { 10 } else { 9 };
    let mut body = format!(
        "<h2>At a glance</h2><table class=\"glance\"><thead><tr><th>type / machine / observable</th><th>gap ÷ floor</th><th>gap RMS</th><th>noise floor</th><th class=\"why\">named effect</th><th>where · which</th><th>held-out after</th><th>shrink</th>{}<th>how far</th></tr></thead><tbody>",
        if augment.is_some() {
            "<th class=\"why\">last night's model on tonight's runs</th>"
        } else {
            ""
        }
    );
    for (t, m, o) in ranked {
        let p = per_obs.get(o).copied();
        let u = unit_of(o, p.map(|p| p.unit.as_str()));
        let pf = |k: fn(&ObservableSummary) -> f64| p.map_or(f64::NAN, k);
        let above = p.is_some_and(|p| p.gap_above_noise);
        let sel = p.map(|p| p.selected.join(", ")).unwrap_or_default();
        let named = if p.is_none() {
            "not diagnosed".to_string()
        } else if !above {
            "<span class=\"ok\">at noise floor</span>".to_string()
        } else if sel.is_empty() {
            "<span class=\"bad\">not explained</span>".to_string()
        } else {
            esc(&sel)
        };
        let explained = above && !sel.is_empty();
        let _ = write!(
            body,
            "<tr><td><a href=\"#{}\">{} / {} / {}</a></td><td>{}</td><td>{}</td><td>{}</td><td class=\"why\">{}</td><td class=\"thumbs\">{}</td><td>{}</td><td>{}</td>{}<td>{}</td></tr>",
            anchor(&[m, o]),
            esc(t),
            esc(m),
            esc(o),
            times(gap_over_floor(p)),
            u.show(pf(|p| p.rms_mm)),
            u.show(pf(|p| p.noise_floor_mm)),
            named,
            if above {
                glance_pictures(
                    rows,
                    m,
                    o,
                    (!sel.is_empty()).then(|| sel.split(", ").next().unwrap_or("")),
                )
            } else {
                String::new()
            },
            if explained { u.show(pf(|p| p.cv_rms_after_mm)) } else { "—".into() },
            if explained { crate::fmt_fixed(Some(100.0 * pf(|p| p.shrink)), 0) + " %" } else { "—".into() },
            augment
                .map(|a| format!("<td class=\"why\">{}</td>", augment_cell(a, o, m, &u)))
                .unwrap_or_default(),
            mini_bars(
                pf(|p| p.rms_mm),
                if explained { pf(|p| p.cv_rms_after_mm) } else { f64::NAN },
                pf(|p| p.noise_floor_mm)
            ),
        );
    }
    for ((t, m), obs) in &floor {
        let names: Vec<String> = obs
            .iter()
            .map(|o| format!("<a href=\"#{}\">{}</a>", anchor(&[m, o]), esc(o)))
            .collect();
        let _ = write!(
            body,
            "<tr class=\"floor\"><td colspan=\"{cols}\"><span class=\"ok\">at noise floor</span>: {} <span class=\"note\">({} / {})</span></td></tr>",
            names.join(", "),
            esc(t),
            esc(m)
        );
    }
    body.push_str("</tbody></table><p class=\"note\">Ranked by gap ÷ noise floor, largest first; observables whose gap is not above their noise floor share one line per machine. where: the gap RMS per cell over the workpiece (darker: larger); which: the mean gap against the named effect's covariate; how far: gap RMS (grey), held-out RMS after the named effects (green), noise floor (black tick). Each row on its own scale; the full pictures are in the observable's section.");
    match augment {
        Some(_) => body.push_str(" Last night's model on tonight's runs: the held-out gap of the plain simulator → the simulator with the effects of the model given to <code>--augment</code> (<code>fleet/augment.json</code>), on runs it was not fitted on unless marked in-sample; — where the model has no effect for the observable (hover for why)."),
        None => body.push_str(" With <code>sparkout run --augment</code> last night's <code>fleet/augmented_model.json</code>, a column adds that model's gap on tonight's runs."),
    }
    body.push_str("</p>");
    body
}

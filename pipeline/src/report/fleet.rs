//! The fleet page: machine type → machine → observable.
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
use crate::engine::FleetOutcome;

mod verdict;
pub use verdict::*;
mod pictures;
use pictures::*;

/// Grid cells per axis of a gap map, and bins of a covariate curve: the
/// page's size stays bounded whatever the number of rows.
const MAP_BINS: usize = 16;
const CURVE_BINS: usize = 40;

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

/// Type → machine → observables: the page's outline.
type Tree<'a> = BTreeMap<&'a str, BTreeMap<String, Vec<String>>>;

/// The page's outline from the rows (the diagnosis's observables when the
/// rows could not be read).
fn machine_tree<'a>(
    rows: Option<&FleetRows>,
    per_obs: &BTreeMap<&str, &Value>,
    type_of: &BTreeMap<&str, &'a str>,
) -> Tree<'a> {
    let mut tree = Tree::new();
    if let Some(r) = rows {
        for (m, o) in r.groups.keys() {
            let t = type_of.get(m.as_str()).copied().unwrap_or("—");
            tree.entry(t)
                .or_default()
                .entry(m.clone())
                .or_default()
                .push(o.clone());
        }
    } else {
        for (o, p) in per_obs {
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
    tree
}

/// "At a glance": one row per (machine, observable), each in its own unit.
fn glance_table(tree: &Tree, per_obs: &BTreeMap<&str, &Value>, rows: Option<&FleetRows>) -> String {
    if tree.is_empty() {
        return String::new();
    }
    let mut body = String::from("<h2>At a glance</h2><table class=\"glance\"><thead><tr><th>type / machine / observable</th><th>gap RMS</th><th>noise floor</th><th class=\"why\">named effect</th><th>where · which</th><th>held-out after</th><th>shrink</th><th>how far</th></tr></thead><tbody>");
    for (t, machines) in tree {
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
                            rows,
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
    body.push_str("</tbody></table><p class=\"note\">where: the gap RMS per cell over the workpiece (darker: larger); which: the mean gap against the named effect's covariate; how far: gap RMS (grey), held-out RMS after the named effects (green), noise floor (black tick). Each row on its own scale; the full pictures are in the observable's section.</p>");
    body
}

/// The diagnosis's notes (skipped covariates, trimmed outliers), folded.
fn diagnosis_notes(d: &Value) -> String {
    let notes: Vec<&str> = d
        .get("notes")
        .and_then(|n| n.as_array())
        .into_iter()
        .flatten()
        .filter_map(|n| n.as_str())
        .collect();
    if notes.is_empty() {
        return String::new();
    }
    let mut body = format!(
        "<details><summary>Diagnosis notes ({}): skipped covariates, trimmed outliers</summary><ul class=\"notes\">",
        notes.len()
    );
    for n in notes {
        let _ = write!(body, "<li>{}</li>", esc(n));
    }
    body.push_str("</ul></details>");
    body
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
    let tree = machine_tree(rows.as_ref(), &per_obs, &type_of);
    body.push_str(&glance_table(&tree, &per_obs, rows.as_ref()));
    if let Some(d) = diagnosis {
        body.push_str(&diagnosis_notes(d));
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
mod tests;

//! The fleet page: machine type → machine → observable.
//! Per observable one verdict line — gap against its own noise floor in
//! its own unit, the named effect with its parameter and interval, the
//! held-out shrink — then the pictures: the gap map over x/y before and
//! after the selected effects, the gap against the named effect's
//! covariate with the fitted curve, and each run's held-out RMS. No number
//! is pooled across observables of different scales (the touch probe's
//! noise would swamp every real gap). Candidates stay, folded.

use std::collections::BTreeMap;
use std::fmt::Write;

use super::fleet_data::{curve_covariate, Bins, Cells, FleetFigures, GroupFigures, RunRms};
use super::svg::{heat, mini_curve, mini_heat, shared_vmax, xy_chart_sized, Heat, Mark, Series};
use super::{esc, page, title_of};
use crate::diagnose::{Diagnosis, EffectEntry, ObservableSummary};
use crate::outcome::FleetOutcome;

mod verdict;
pub use verdict::*;
mod pictures;
use pictures::*;
mod glance;
use glance::*;

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
    rows: Option<&FleetFigures>,
    per_obs: &BTreeMap<&str, &ObservableSummary>,
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
            for m in &p.machines {
                let t = type_of.get(m.as_str()).copied().unwrap_or("—");
                tree.entry(t)
                    .or_default()
                    .entry(m.clone())
                    .or_default()
                    .push(o.to_string());
            }
        }
    }
    tree
}

/// The diagnosis tables, folded at the end of the page, without their
/// every-candidate ranking (each observable's section has it).
fn appendix(diagnosis_html: &str) -> String {
    let h = crate::diagnose::report::EVERY_CANDIDATE_HEADING;
    let trimmed = diagnosis_html.find(h).and_then(|a| {
        let b = diagnosis_html[a + h.len()..].find("<h3>")? + a + h.len();
        Some(format!(
            "{}<h3>Which</h3><p class=\"note\">Every candidate of an observable above its noise floor is ranked in that observable's section (folded); all of them are in <a href=\"diagnosis.json\">diagnosis.json</a>.</p>{}",
            &diagnosis_html[..a],
            &diagnosis_html[b..]
        ))
    });
    format!(
        "<details class=\"appendix\"><summary>Diagnosis tables (every observable: where, per machine, unexplained)</summary>{}</details>",
        trimmed.as_deref().unwrap_or(diagnosis_html)
    )
}

/// The diagnosis's notes (skipped covariates, trimmed outliers), folded.
fn diagnosis_notes(d: &Diagnosis) -> String {
    let notes = &d.notes;
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
    cfg: &super::ReportConfig,
    outcome: &FleetOutcome,
    diagnosis: Option<&Diagnosis>,
    diagnosis_html: Option<&str>,
) -> String {
    let out = &outcome.out_dir;
    let fleet_dir = out.join("fleet");
    let mut body = String::from(
        "<nav><a href=\"../index.html\">← index: every run, every output, the night's failures</a></nav>",
    );
    // First: the night's date and news (as on the index).
    body.push_str(&super::news::banner(outcome, "../"));
    // Machine → type (plugin), and the runs per machine.
    let mut type_of: BTreeMap<&str, &str> = BTreeMap::new();
    let mut runs_of: BTreeMap<&str, usize> = BTreeMap::new();
    for r in &outcome.runs {
        type_of.insert(&r.machine, &r.plugin);
        *runs_of.entry(&r.machine).or_default() += 1;
    }
    let per_obs: BTreeMap<&str, &ObservableSummary> = diagnosis
        .into_iter()
        .flat_map(|d| &d.per_observable)
        .map(|p| (p.observable.as_str(), p))
        .collect();
    let obs_file = fleet_dir.join(crate::files::OBSERVATIONS_FILE);
    let diag_file = fleet_dir.join("diagnosis.parquet");
    let rows = if obs_file.is_file() {
        match FleetFigures::load(
            &obs_file,
            diagnosis.map(|d| (diag_file.as_path(), d)),
            Bins {
                map: MAP_BINS,
                mini_map: MINI_MAP_BINS,
                curve: CURVE_BINS,
                mini_curve: MINI_CURVE_BINS,
            },
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
    let augment_file = augment_file(out);
    let augment = augment_entries(augment_file.as_ref());
    let tree = machine_tree(rows.as_ref(), &per_obs, &type_of);
    body.push_str(&glance_table(
        &tree,
        &per_obs,
        rows.as_ref(),
        augment_file.as_ref(),
    ));
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
            let (live, flat) = split_at_floor(obs, &per_obs);
            for o in live {
                let p = per_obs.get(o.as_str()).copied();
                let u = unit_of(o, p.map(|p| p.unit.as_str()));
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
                        verdict(d, p, augment, m)
                    );
                }
                if let Some(r) = &rows {
                    if let Some(fig) = r.groups.get(&(m.clone(), o.clone())) {
                        body.push_str(&pictures(
                            diagnosis,
                            p,
                            fig,
                            r.per_run.get(&(m.clone(), o.clone())),
                            o,
                        ));
                    }
                }
                if let (Some(d), Some(p)) = (diagnosis, p) {
                    body.push_str(&candidates(d, o, &p.stop_reason, &u));
                }
                body.push_str("</section>");
            }
            // At the noise floor: nothing to explain, so no pictures and no
            // candidates; each verdict line, folded under one line.
            if let (Some(d), false) = (diagnosis, flat.is_empty()) {
                let _ = write!(
                    body,
                    "<details class=\"floor\"><summary>At the noise floor, nothing to explain: {}</summary>",
                    esc(&flat.iter().map(|o| o.as_str()).collect::<Vec<_>>().join(", "))
                );
                for o in flat {
                    let Some(p) = per_obs.get(o.as_str()).copied() else {
                        continue;
                    };
                    let u = unit_of(o, Some(&p.unit));
                    let _ = write!(
                        body,
                        "<section class=\"obs\" id=\"{}\"><h4>{} <span class=\"note\">({})</span></h4><p class=\"verdict\">{}</p></section>",
                        anchor(&[m, o]),
                        esc(o),
                        u.data,
                        verdict(d, p, augment, m)
                    );
                }
                body.push_str("</details>");
            }
        }
    }
    if let Some(h) = diagnosis_html {
        body.push_str(&appendix(h));
    }
    page(&title_of(cfg, "sparkout fleet report"), &body)
}

#[cfg(test)]
mod tests;

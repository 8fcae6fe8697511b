//! Self-contained HTML reports (inline SVG, no network, no JavaScript) per run
//! and for the fleet. Plugins contribute sections; the diagnosis contributes
//! its own. Same inputs → same bytes (no timestamps).

pub mod gap_table;
pub mod svg;

use std::collections::BTreeMap;
use std::fmt::Write;

use crate::engine::FleetOutcome;
use crate::traits::{ReportSection, Run};

/// Bump when the report layout changes (cache key of report steps).
pub const REPORT_VERSION: u32 = 2;

/// HTML-escape text.
pub fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A number for a report: mm shown with µm resolution, NaN as "—".
pub fn fmt_mm(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.4}")
    } else {
        "—".into()
    }
}

/// A number with `digits` decimals; absent, NaN or ±∞ as "—" (a report
/// cell says "not computable" rather than printing NaN).
pub fn fmt_fixed(x: Option<f64>, digits: usize) -> String {
    x.filter(|v| v.is_finite())
        .map(|v| format!("{v:.digits$}"))
        .unwrap_or_else(|| "—".into())
}

/// Millimetres shown in micrometres with `digits` decimals (what an
/// engineer reads off a report; artifacts stay in mm).
pub fn fmt_um(mm: Option<f64>, digits: usize) -> String {
    fmt_fixed(mm.map(|v| v * 1e3), digits)
}

/// A simple table: header and rows of already-formatted cells.
pub fn table(header: &[&str], rows: &[Vec<String>]) -> String {
    let mut s = String::from("<table><thead><tr>");
    for h in header {
        let _ = write!(s, "<th>{}</th>", esc(h));
    }
    s.push_str("</tr></thead><tbody>");
    for r in rows {
        s.push_str("<tr>");
        for c in r {
            let _ = write!(s, "<td>{}</td>", esc(c));
        }
        s.push_str("</tr>");
    }
    s.push_str("</tbody></table>");
    s
}

const STYLE: &str = "body{font-family:system-ui,sans-serif;margin:2em;max-width:1100px;color:#222}\
h1{font-size:1.5em}h2{font-size:1.2em;border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}\
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:right;font-variant-numeric:tabular-nums}\
th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}.bad{color:#b00}.ok{color:#070}\
.note{color:#555;font-size:.9em}pre{background:#f6f6f6;padding:.5em;overflow-x:auto}";

fn page(title: &str, body: &str) -> String {
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title><style>{STYLE}</style></head><body>\n<h1>{t}</h1>\n{body}\n</body></html>\n",
        t = esc(title)
    )
}

fn title_of(cfg: &toml::Table, default: &str) -> String {
    cfg.get("title")
        .and_then(|v| v.as_str())
        .unwrap_or(default)
        .to_string()
}

/// A run's report: header, each plugin section, then every stage's summary.
pub fn run_page(
    cfg: &toml::Table,
    run: &Run,
    summaries: &BTreeMap<String, serde_json::Value>,
    sections: &[ReportSection],
) -> String {
    let mut body = String::new();
    let _ = write!(
        body,
        "<p>Run <b>{}</b> of machine <b>{}</b> (plugin <code>{}</code>, machine config from {}){}.</p>",
        esc(&run.spec.id),
        esc(&run.spec.machine),
        esc(&run.spec.plugin),
        esc(&run.machine.source),
        run.spec
            .started
            .as_ref()
            .map(|s| format!(", started {}", esc(s)))
            .unwrap_or_default()
    );
    for s in sections {
        let _ = write!(
            body,
            "<section><h2>{}</h2>\n{}\n</section>\n",
            esc(&s.title),
            s.html
        );
    }
    body.push_str("<section><h2>Stage summaries (JSON)</h2>");
    for (stage, v) in summaries {
        let _ = write!(
            body,
            "<h3>{}</h3><pre>{}</pre>",
            esc(stage),
            esc(&serde_json::to_string_pretty(v).unwrap_or_default())
        );
    }
    body.push_str("</section>");
    page(
        &format!(
            "{} — {}/{}",
            title_of(cfg, "sparkout report"),
            run.spec.machine,
            run.spec.id
        ),
        &body,
    )
}

/// One observable's line of a diagnosis, as the fleet report and the CLI
/// summary show it.
#[derive(Debug, Clone)]
pub struct ObservableSummary {
    pub observable: String,
    /// The unit of the numbers below ("mm" for a v1 diagnosis).
    pub unit: String,
    pub rms_mm: f64,
    pub noise_floor_mm: f64,
    /// The selected effects, or why none was.
    pub explained_by: String,
    pub after_mm: f64,
    pub shrink: f64,
}

/// The `per_observable` entries of a diagnosis.json.
pub fn observable_summaries(diagnosis: &serde_json::Value) -> Vec<ObservableSummary> {
    let per = diagnosis.get("per_observable").and_then(|p| p.as_array());
    per.into_iter()
        .flatten()
        .map(|o| {
            let f = |k: &str| o.get(k).and_then(|x| x.as_f64()).unwrap_or(f64::NAN);
            let sel: Vec<&str> = o
                .get("selected")
                .and_then(|s| s.as_array())
                .map(|a| a.iter().filter_map(|x| x.as_str()).collect())
                .unwrap_or_default();
            ObservableSummary {
                observable: o
                    .get("observable")
                    .and_then(|x| x.as_str())
                    .unwrap_or("?")
                    .to_string(),
                unit: o
                    .get("unit")
                    .and_then(|x| x.as_str())
                    .unwrap_or("mm")
                    .to_string(),
                rms_mm: f("rms_mm"),
                noise_floor_mm: f("noise_floor_mm"),
                explained_by: if sel.is_empty() {
                    o.get("stop_reason")
                        .and_then(|x| x.as_str())
                        .unwrap_or("no effect selected")
                        .to_string()
                } else {
                    format!("explained by {}", sel.join(", "))
                },
                after_mm: f("cv_rms_after_mm"),
                shrink: f("shrink"),
            }
        })
        .collect()
}

/// The fleet report: runs, failures, the gap per run and observable, the
/// diagnosis section.
pub fn fleet_page(
    cfg: &toml::Table,
    outcome: &FleetOutcome,
    diagnosis: Option<&serde_json::Value>,
    diagnosis_html: Option<&str>,
) -> String {
    let mut body = String::new();
    let _ = write!(
        body,
        "<p>{} runs processed, {} rejected.</p>",
        outcome.runs.len(),
        outcome.failures.len()
    );
    if let Some(d) = diagnosis {
        let sel = d
            .get("selected")
            .and_then(|s| s.as_array())
            .map(|a| {
                a.iter()
                    .filter_map(|v| v.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            })
            .unwrap_or_default();
        let rms = d
            .pointer("/gap/rms_mm")
            .and_then(|v| v.as_f64())
            .unwrap_or(f64::NAN);
        let after = d
            .pointer("/unexplained/rms_mm")
            .and_then(|v| v.as_f64())
            .unwrap_or(f64::NAN);
        let _ = write!(
            body,
            "<p><b>Sim-to-real gap, all observables:</b> RMS {} mm; {}; held-out RMS after the selected effects {} mm.</p>",
            fmt_mm(rms),
            if sel.is_empty() {
                "no effect selected".to_string()
            } else {
                format!("explained by <b>{}</b>", esc(&sel))
            },
            fmt_mm(after)
        );
    }
    if let Some(d) = diagnosis {
        // Per observable first: each has its own noise floor and effects,
        // and a small observable's shrink is invisible in the fleet total.
        let rows: Vec<Vec<String>> = observable_summaries(d)
            .iter()
            .map(|o| {
                vec![
                    o.observable.clone(),
                    fmt_mm(o.rms_mm),
                    fmt_mm(o.noise_floor_mm),
                    o.explained_by.clone(),
                    fmt_mm(o.after_mm),
                    format!("{:.0} %", 100.0 * o.shrink),
                ]
            })
            .collect();
        body.push_str(&table(
            &[
                "observable",
                "gap RMS (mm)",
                "noise floor (mm)",
                "explained by",
                "held-out RMS after (mm)",
                "shrink",
            ],
            &rows,
        ));
    }
    body.push_str("<h2>Runs</h2>");
    // Grouped by machine (issue 12): sorted by (machine, run).
    let mut runs: Vec<&crate::engine::RunResult> = outcome.runs.iter().collect();
    runs.sort_by(|a, b| (&a.machine, &a.run).cmp(&(&b.machine, &b.run)));
    let rows: Vec<Vec<String>> = runs
        .iter()
        .map(|r| {
            vec![
                r.machine.clone(),
                r.run.clone(),
                r.plugin.clone(),
                r.computed().to_string(),
                r.cached().to_string(),
            ]
        })
        .collect();
    body.push_str(&table(
        &[
            "machine",
            "run",
            "plugin",
            "stages computed",
            "stages cached",
        ],
        &rows,
    ));
    if !outcome.failures.is_empty() {
        body.push_str("<h2 class=\"bad\">Rejected runs</h2>");
        let rows: Vec<Vec<String>> = outcome
            .failures
            .iter()
            .map(|f| {
                vec![
                    f.machine.clone().unwrap_or_default(),
                    f.run.clone().unwrap_or_default(),
                    f.run_dir.clone(),
                    f.stage.clone().unwrap_or_default(),
                    f.error.clone(),
                ]
            })
            .collect();
        body.push_str(&table(
            &["machine", "run", "run directory", "stage", "error"],
            &rows,
        ));
    }
    let obs = outcome.out_dir.join("fleet").join("observations.parquet");
    if obs.is_file() {
        match gap_table::gap_by_run_observable(&obs) {
            Ok((true, rows)) => {
                body.push_str("<h2>Gap by machine, run and observable</h2>");
                body.push_str(&table(
                    &[
                        "machine",
                        "run",
                        "observable",
                        "n",
                        "mean gap (mm)",
                        "RMS gap (mm)",
                    ],
                    &rows,
                ));
            }
            Ok((false, rows)) => {
                body.push_str("<h2>Gap by run and observable</h2>");
                body.push_str(&table(
                    &["run", "observable", "n", "mean gap (mm)", "RMS gap (mm)"],
                    &rows,
                ));
            }
            Err(e) => {
                let _ = write!(
                    body,
                    "<p class=\"bad\">gap table unavailable: {}</p>",
                    esc(&e.to_string())
                );
            }
        }
    }
    if let Some(h) = diagnosis_html {
        body.push_str(h);
    }
    page(&title_of(cfg, "sparkout fleet report"), &body)
}

//! out/index.html: the night's news first (its date, trend alerts,
//! rejected and FAIL/CHECK runs), then its failures, then the
//! fleet page, the trend page when the history exists, every run page and
//! every JSON/Parquet output — a new user finds everything in one click.
//! Links are relative, so the output directory can be copied or served.

use std::collections::BTreeMap;
use std::fmt::Write;
use std::path::Path;

use super::{esc, page, title_of};
use crate::outcome::{FleetOutcome, RunResult};

pub use crate::trend::TREND_PAGE;

fn size_text(path: &Path) -> String {
    match std::fs::metadata(path) {
        Ok(m) if m.len() >= 1 << 20 => format!("{:.1} MB", m.len() as f64 / (1 << 20) as f64),
        Ok(m) => format!("{:.0} kB", (m.len() as f64 / 1024.0).ceil()),
        Err(_) => String::new(),
    }
}

/// JSON and Parquet files directly in `dir`, sorted by name.
fn data_files(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| e.path().is_file())
        .filter_map(|e| e.file_name().to_str().map(String::from))
        .filter(|n| (n.ends_with(".json") || n.ends_with(".parquet")) && !n.starts_with('.'))
        .collect();
    v.sort();
    v
}

fn file_links(base: &str, names: &[String], dir: &Path) -> String {
    let mut s = String::from("<ul class=\"files\">");
    for n in names {
        let _ = write!(
            s,
            "<li><a href=\"{b}{n}\">{n}</a> <span class=\"note\">{}</span></li>",
            size_text(&dir.join(n)),
            b = esc(base),
            n = esc(n)
        );
    }
    s.push_str("</ul>");
    s
}

/// A run's outputs as the stage records list them (Parquet, JSON).
fn run_files(r: &RunResult) -> Vec<String> {
    let mut v: Vec<String> = r
        .stages
        .iter()
        .flat_map(|s| s.files.keys().cloned())
        .filter(|n| n.ends_with(".json") || n.ends_with(".parquet"))
        .collect();
    v.sort();
    v.dedup();
    v
}

/// The index page of an output root.
pub fn index_page(cfg: &super::ReportConfig, outcome: &FleetOutcome) -> String {
    let out = &outcome.out_dir;
    // 0. The night's news: its date, trend alerts, rejected and FAIL/CHECK runs.
    let mut body = super::news::banner(outcome, "");
    // 1. The night's failures, first.
    body.push_str("<section id=\"failures\">");
    if outcome.failures.is_empty() {
        let _ = write!(
            body,
            "<h2 class=\"ok\">Failures of the night: none</h2><p>All {} runs went through. <a href=\"failures.json\">failures.json</a></p>",
            outcome.runs.len()
        );
    } else {
        let _ = write!(
            body,
            "<h2 class=\"bad\">Failures of the night: {} rejected run{}</h2><div class=\"warn\">Each rejected run is listed with the file, column and row at fault and what to do next; nothing of it is in the outputs below. <a href=\"failures.json\">failures.json</a></div>",
            outcome.failures.len(),
            if outcome.failures.len() == 1 { "" } else { "s" }
        );
        body.push_str("<table><thead><tr><th>machine / run</th><th>stage</th><th>where</th><th>error</th></tr></thead><tbody>");
        for f in &outcome.failures {
            let who = match (&f.machine, &f.run) {
                (Some(m), Some(r)) => format!("{m} / {r}"),
                _ => f.run_dir.clone(),
            };
            let at: Vec<String> = [
                f.file.clone(),
                f.column.as_ref().map(|c| format!("column {c}")),
                f.row.map(|r| format!("row {r}")),
            ]
            .into_iter()
            .flatten()
            .collect();
            let _ = write!(
                body,
                "<tr><td>{}</td><td>{}</td><td class=\"why\">{}</td><td class=\"why\">{}</td></tr>",
                esc(&who),
                esc(f.stage.as_deref().unwrap_or("before any stage")),
                esc(&at.join(", ")),
                esc(&f.error)
            );
        }
        body.push_str("</tbody></table>");
    }
    body.push_str("</section>");
    // 2. The fleet: its page, the trend, its outputs.
    body.push_str("<h2>Fleet</h2><ul>");
    if out.join("fleet").join("report.html").is_file() || outcome.report.is_some() {
        body.push_str("<li><a href=\"fleet/report.html\"><b>Fleet report</b></a>: per machine type, machine and observable, where the gap is, which effect explains it and how far</li>");
    }
    if out.join(TREND_PAGE).is_file() {
        let _ = write!(
            body,
            "<li><a href=\"{TREND_PAGE}\"><b>Trend</b></a>: the diagnosis night after night</li>"
        );
    }
    body.push_str("<li><a href=\"manifest.json\">manifest.json</a>: configuration, every run and stage with its cache key</li></ul>");
    let fleet_files = data_files(&out.join("fleet"));
    if !fleet_files.is_empty() {
        body.push_str("<h3>Fleet outputs</h3>");
        body.push_str(&file_links("fleet/", &fleet_files, &out.join("fleet")));
    }
    // 3. Every run, by machine type and machine.
    let mut tree: BTreeMap<(&str, &str), Vec<&RunResult>> = BTreeMap::new();
    for r in &outcome.runs {
        tree.entry((&r.plugin, &r.machine)).or_default().push(r);
    }
    let _ = write!(body, "<h2 id=\"runs\">Runs ({})</h2>", outcome.runs.len());
    for ((plugin, machine), mut runs) in tree {
        runs.sort_by(|a, b| a.run.cmp(&b.run));
        // Small machines open; a machine with many runs stays folded so
        // the page stays short.
        let _ = write!(
            body,
            "<details id=\"{}\"{}><summary><b>{}</b> ({}): {} runs</summary><table><thead><tr><th>run</th><th>status</th><th>report</th><th>outputs</th></tr></thead><tbody>",
            super::news::runs_anchor(machine),
            if runs.len() <= 20 { " open" } else { "" },
            esc(machine),
            esc(plugin),
            runs.len()
        );
        for r in runs {
            let base = format!("{}/{}/", r.machine, r.run);
            let files: Vec<String> = run_files(r)
                .iter()
                .map(|n| format!("<a href=\"{}{n}\">{n}</a>", esc(&base), n = esc(n)))
                .collect();
            // The run page's verdict word (verdict.json beside it).
            let status = super::verdict::RunVerdict::read(Path::new(&r.out_dir))
                .map(|v| v.cell())
                .unwrap_or_else(|| "—".into());
            let _ = write!(
                body,
                "<tr><td>{}</td><td>{status}</td><td><a href=\"{}report.html\">report</a></td><td class=\"why\">{}</td></tr>",
                esc(&r.run),
                esc(&base),
                files.join(" · ")
            );
        }
        body.push_str("</tbody></table></details>");
    }
    page(&format!("{} — index", title_of(cfg, "sparkout")), &body)
}

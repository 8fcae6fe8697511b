//! sparkout-report: self-contained HTML reports (inline SVG, no network, no JavaScript) per run
//! and for the fleet. Plugins contribute sections; the diagnosis contributes
//! its own. Same inputs → same bytes (no timestamps).

// Typed errors (sparkout-core `error`) by the names every page uses.
#[allow(unused_imports)]
pub(crate) use sparkout_core::{bail, err, Context, Error, Result};

pub mod fleet;
pub mod fleet_data;
pub mod index;
pub mod news;
pub mod svg;
pub mod trend;
// The verdict's rules and box sit below the plugin interface (a plugin
// returns verdicts), in sparkout-core's `verdict`; the report shows them.
pub use sparkout_core::verdict;
// The crates below, by the module names the pages use (`crate::contracts`…).
pub(crate) use sparkout_core::{
    config_check, contracts, error, files, html, outcome, traits, units, InputError,
};
pub(crate) use sparkout_diagnose as diagnose;

pub use fleet::fleet_page;
pub use index::index_page;
pub use verdict::{verdict_box, Status, Verdict};

use std::fmt::Write;

use crate::diagnose::Diagnosis;
use crate::traits::{ReportSection, Run};

/// Bump when the report layout changes (cache key of report steps).
pub const REPORT_VERSION: u32 = 10;

pub use crate::html::esc;

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

/// One stylesheet for every page: readable at 100 % zoom, charts scaled
/// to the column (nothing wider than the viewport), wide tables scroll in
/// their own box, and an A4 print layout.
const STYLE: &str = "body{font-family:system-ui,sans-serif;margin:1.5em auto;max-width:1200px;padding:0 1em;color:#222;line-height:1.4}\
h1{font-size:1.5em}h2{font-size:1.25em;border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}h3{font-size:1.1em;margin-top:1.5em}h4{font-size:1em;margin:1em 0 .3em}\
table{border-collapse:collapse;margin:.5em 0;display:block;max-width:100%;overflow-x:auto}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:right;font-variant-numeric:tabular-nums}\
th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}td{white-space:nowrap}td.why,th.why{text-align:left;white-space:normal;min-width:12em}.glance td:first-child{white-space:normal;min-width:11em}.glance td.why{min-width:9em}.glance{font-size:95%}.bad{color:#b00}.ok{color:#070}\
.note{color:#555;font-size:.9em}pre{background:#f6f6f6;padding:.5em;overflow-x:auto;max-width:100%}\
svg.chart{display:block;max-width:100%;height:auto;margin:.4em 0}.figs{display:flex;flex-wrap:wrap;gap:.5em}.figs svg.chart{flex:1 1 520px;max-width:720px}\
.warn{border:2px solid #b00;background:#fff4f4;color:#700;padding:.5em .8em;margin:.6em 0;font-weight:600}\
.verdict{background:#f4f8ff;border-left:4px solid #2a6ebb;padding:.4em .7em}.check{color:#a60}nav{margin-bottom:1em}a{color:#1a5fb4}\
details{margin:.5em 0}summary{cursor:pointer;color:#1a5fb4}ul.files{columns:3 16em}\
@media print{@page{size:A4;margin:12mm}body{max-width:none;margin:0;padding:0;font-size:10pt}nav{display:none}\
h2,h3,h4{break-after:avoid}h2~h2{break-before:page}svg.chart,table,.verdict,.warn{break-inside:avoid}.figs{display:block}.figs svg.chart{max-width:100%}\
details>summary{color:#222}a{color:#222;text-decoration:none}}";

/// A self-contained HTML page: inline style, no script, no network.
pub(crate) fn page(title: &str, body: &str) -> String {
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><meta name=\"viewport\" content=\"width=device-width,initial-scale=1\"><title>{t}</title><style>{STYLE}</style></head><body>\n<h1>{t}</h1>\n{body}\n</body></html>\n",
        t = esc(title)
    )
}

/// A warning box for a result that contradicts its purpose (a polishing
/// plan that worsens flatness, a fit far above its noise floor, a badly
/// conditioned datum). `text` is escaped.
pub fn warning(text: &str) -> String {
    format!(
        "<div class=\"warn\" role=\"alert\">Warning: {}</div>",
        esc(text)
    )
}

/// A warning when a fit's residual RMS is more than `factor` × the noise
/// floor it should reach (the model misses something).
pub fn warn_fit_above_floor(what: &str, rms_mm: f64, floor_mm: f64, factor: f64) -> Option<String> {
    (rms_mm.is_finite() && floor_mm.is_finite() && floor_mm > 0.0 && rms_mm > factor * floor_mm)
        .then(|| {
            warning(&format!(
                "{what}: residual RMS {:.1} µm is {:.1}× the noise floor of {:.1} µm — the model misses a systematic effect; check the fleet diagnosis before using its result.",
                rms_mm * 1e3,
                rms_mm / floor_mm,
                floor_mm * 1e3
            ))
        })
}

/// `[report]` of the pipeline config: what the report pages take from it,
/// read and checked once when the engine is built and handed to each page
/// typed.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReportConfig {
    /// The pages' title (each page has its own default).
    pub title: Option<String>,
}

impl crate::config_check::Section for ReportConfig {}

fn title_of(cfg: &ReportConfig, default: &str) -> String {
    cfg.title.as_deref().unwrap_or(default).to_string()
}

/// A run's report: header, the verdict, each plugin section, then a link
/// to every stage's summary (`stages`: the stages that wrote one).
pub fn run_page(
    cfg: &ReportConfig,
    run: &Run,
    stages: &[String],
    verdicts: &[Verdict],
    sections: &[ReportSection],
) -> String {
    let mut body = String::from(
        "<nav><a href=\"../../index.html\">← index</a> · <a href=\"../../fleet/report.html\">fleet report</a></nav>",
    );
    let _ = write!(
        body,
        "<p>Run <b>{}</b> of machine <b>{}</b> (plugin <code>{}</code>, machine config from {}){}.</p>",
        esc(&run.spec.id),
        esc(&run.spec.machine),
        esc(&run.spec.plugin),
        esc(&run.machine.provenance()),
        run.spec
            .started
            .as_ref()
            .map(|s| format!(", started {}", esc(s)))
            .unwrap_or_default()
    );
    // First screen: what a process engineer decides on.
    body.push_str(&verdict_box(verdicts));
    for s in sections {
        let _ = write!(
            body,
            "<section><h2>{}</h2>\n{}\n</section>\n",
            esc(&s.title),
            s.html
        );
    }
    // Raw stage summaries stay files beside the page (`<stage>.json`),
    // linked, not dumped inline.
    body.push_str("<section><h2>Stage outputs</h2><ul class=\"files\">");
    for stage in stages {
        let _ = write!(
            body,
            "<li><a href=\"{f}\">{f}</a></li>",
            f = esc(&format!("{stage}.json"))
        );
    }
    body.push_str("</ul></section>");
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
pub fn observable_summaries(diagnosis: &Diagnosis) -> Vec<ObservableSummary> {
    diagnosis
        .per_observable
        .iter()
        .map(|o| ObservableSummary {
            observable: o.observable.clone(),
            unit: o.unit.clone(),
            rms_mm: o.rms_mm,
            noise_floor_mm: o.noise_floor_mm,
            explained_by: crate::diagnose::document::explained_by(o, &diagnosis.effects),
            after_mm: o.cv_rms_after_mm,
            shrink: o.shrink,
        })
        .collect()
}

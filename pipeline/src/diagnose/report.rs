//! The diagnosis section of the fleet report (docs/design.md §10):
//! self-contained HTML, inline SVG, no script, no network.

use std::fmt::Write;

use super::Diagnosis;
use crate::html::esc;
use crate::units::format::show_p;

/// Millimetres at micrometre resolution (what an engineer reads), with
/// scientific notation only for values below that.
fn num(x: Option<f64>) -> String {
    match x {
        Some(v) => general(v),
        None => "—".into(),
    }
}

/// A number in plain notation when it is of a readable size.
fn general(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 || (1e-3..1e5).contains(&a) {
        format!("{v:.4}")
    } else {
        format!("{v:.3e}")
    }
}

fn json_num(v: &serde_json::Value) -> String {
    match v {
        serde_json::Value::Number(n) => format!("{:.4}", n.as_f64().unwrap_or(f64::NAN)),
        serde_json::Value::Array(a) => {
            let parts: Vec<String> = a.iter().map(json_num).collect();
            format!("({})", parts.join(", "))
        }
        serde_json::Value::String(t) => esc(t),
        other => esc(&other.to_string()),
    }
}

/// The effect ranking as horizontal bars: held-out RMS after each candidate
/// against the RMS before (the dashed line), best first.
fn ranking_svg(d: &Diagnosis) -> String {
    let rows: Vec<_> = d
        .effects
        .iter()
        .filter(|e| e.cv_rms_after_mm.is_some())
        .take(24)
        .collect();
    if rows.is_empty() {
        return String::new();
    }
    let vmax = rows
        .iter()
        .flat_map(|e| [e.cv_rms_after_mm, e.cv_rms_before_mm])
        .flatten()
        .fold(0.0f64, f64::max)
        .max(1e-300);
    let (w, left, bar_h) = (640.0, 220.0, 16.0);
    let h = 20.0 + rows.len() as f64 * (bar_h + 4.0);
    let scale = (w - left - 20.0) / vmax;
    let mut s = format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="11">"#
    );
    for (i, e) in rows.iter().enumerate() {
        let y = 10.0 + i as f64 * (bar_h + 4.0);
        let after = e.cv_rms_after_mm.unwrap_or(0.0) * scale;
        let before = e.cv_rms_before_mm.unwrap_or(0.0) * scale;
        let label = match &e.covariate {
            Some(c) => format!("{}:{} [{}]", e.name, c, e.observable),
            None => format!("{} [{}]", e.name, e.observable),
        };
        let color = if e.selected { "#2a7" } else { "#99a" };
        let _ = write!(
            s,
            r##"<text x="{tx}" y="{ty}" text-anchor="end">{label}</text><rect x="{left}" y="{y}" width="{after:.1}" height="{bar_h}" fill="{color}"/><line x1="{bx:.1}" x2="{bx:.1}" y1="{y}" y2="{y2}" stroke="#c33" stroke-dasharray="3,2"/>"##,
            tx = left - 6.0,
            ty = y + bar_h - 4.0,
            label = esc(&label),
            bx = left + before,
            y2 = y + bar_h,
        );
    }
    s.push_str("</svg>");
    s
}

/// The heading of the every-candidate ranking (the fleet page leaves
/// that part out: each observable's section ranks its own candidates).
pub const EVERY_CANDIDATE_HEADING: &str = "<h3>Which: every candidate, held-out</h3>";

/// The `<section>` of the fleet report.
pub fn section(d: &Diagnosis) -> String {
    let mut s = String::from(r#"<section class="diagnosis"><h2>Sim-to-real gap diagnosis</h2>"#);
    // No pooled gap or "share unexplained" across observables: their
    // scales differ (a touch probe's noise would swamp every real gap). Each observable against its own floor, in its own row.
    s.push_str("<table><tr><th>observable</th><th>n</th><th>gap RMS mm</th><th>noise floor mm</th><th>held-out RMS after mm</th><th>shrink</th><th>selected or why not</th></tr>");
    for o in &d.per_observable {
        let _ = write!(
            s,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.2}</td><td>{}</td></tr>",
            esc(&o.observable),
            o.n,
            num(Some(o.rms_mm)),
            num(Some(o.noise_floor_mm)),
            num(Some(o.cv_rms_after_mm)),
            o.shrink,
            esc(&if o.selected.is_empty() {
                o.stop_reason.clone()
            } else {
                o.selected.join(", ")
            })
        );
    }
    s.push_str("</table>");
    let _ = write!(
        s,
        "<p>Selected: <b>{}</b>. Cross-validation: {} folds by {}; {}.</p>",
        if d.selected.is_empty() {
            "none".to_string()
        } else {
            esc(&d.selected.join(", "))
        },
        d.cv.folds,
        esc(&d.cv.by),
        esc(&d.cv.test)
    );
    if !d.notes.is_empty() {
        s.push_str("<ul class=\"notes\">");
        for n in &d.notes {
            let _ = write!(s, "<li>{}</li>", esc(n));
        }
        s.push_str("</ul>");
    }
    s.push_str("<h3>Where</h3>");
    if d.where_.is_empty() {
        s.push_str("<p>No cell of covariate space is significantly above the noise floor.</p>");
    } else {
        s.push_str("<table><tr><th>observable</th><th>covariate</th><th>lo</th><th>hi</th><th>n</th><th>RMS mm</th><th>share</th><th>p</th></tr>");
        for c in d.where_.iter().take(20) {
            let _ = write!(
                s,
                "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.3}</td><td>{}</td></tr>",
                esc(&c.observable),
                esc(&c.covariate),
                json_num(&c.lo),
                json_num(&c.hi),
                c.n,
                num(Some(c.rms_mm)),
                c.share,
                show_p(c.p_value)
            );
        }
        s.push_str("</table>");
    }
    s.push_str(EVERY_CANDIDATE_HEADING);
    s.push_str(&ranking_svg(d));
    s.push_str("<table><tr><th>effect</th><th>observable</th><th>before mm</th><th>after mm</th><th>shrink</th><th>p</th><th>selected</th><th>params</th></tr>");
    for e in &d.effects {
        // Selected effects: every parameter with its standard error.
        let params: Vec<String> = if e.intervals.is_some() {
            e.params_text()
        } else {
            e.params
                .iter()
                .map(|(k, v)| format!("{k}={}", general(*v)))
                .collect()
        };
        let name = match &e.covariate {
            Some(c) => format!("{}:{}", e.name, c),
            None => e.name.clone(),
        };
        let _ = write!(
            s,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            esc(&name),
            esc(&e.observable),
            num(e.cv_rms_before_mm),
            num(e.cv_rms_after_mm),
            match (e.shrink, e.shrink_interval) {
                (Some(v), Some([lo, hi])) => format!("{v:.3} [{lo:.3}, {hi:.3}]"),
                (Some(v), None) => format!("{v:.3}"),
                _ => "—".into(),
            },
            e.p_value.map(show_p).unwrap_or_else(|| "—".into()),
            if e.selected { "yes" } else { "" },
            esc(&e.skipped_reason.clone().unwrap_or_else(|| params.join(", ")))
        );
    }
    s.push_str("</table>");
    per_machine_table(d, &mut s);
    s.push_str("<h3>Unexplained</h3>");
    if d.unexplained.where_.is_empty() {
        s.push_str("<p>No cell remains significantly above the noise floor.</p>");
    } else {
        s.push_str("<table><tr><th>observable</th><th>covariate</th><th>lo</th><th>hi</th><th>RMS before mm</th><th>RMS after mm</th><th>shrink</th></tr>");
        for c in d.unexplained.where_.iter().take(20) {
            let _ = write!(
                s,
                "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                esc(&c.observable),
                esc(&c.covariate),
                json_num(&c.lo),
                json_num(&c.hi),
                num(c.rms_before_mm),
                num(Some(c.rms_mm)),
                c.shrink.map(|v| format!("{v:.3}")).unwrap_or_else(|| "—".into())
            );
        }
        s.push_str("</table>");
    }
    s.push_str("</section>");
    s
}

/// Selected effects whose machines disagree: each machine's own fit.
fn per_machine_table(d: &Diagnosis, s: &mut String) {
    let rows: Vec<_> = d
        .effects
        .iter()
        .filter_map(|e| e.per_machine.as_ref().map(|m| (e, m)))
        .collect();
    if rows.is_empty() {
        return;
    }
    s.push_str("<h3>Per machine: the machines disagree</h3><table><tr><th>effect</th><th>observable</th><th>machine</th><th>runs</th><th>n</th><th>params</th><th>offset mm</th><th>p (one effect for all)</th></tr>");
    for (e, fits) in rows {
        let name = match &e.covariate {
            Some(c) => format!("{}:{}", e.name, c),
            None => e.name.clone(),
        };
        for f in fits {
            let params: Vec<String> = f
                .params
                .iter()
                .map(|(k, v)| format!("{k}={}", general(*v)))
                .collect();
            let _ = write!(
                s,
                "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                esc(&name),
                esc(&e.observable),
                esc(&f.machine),
                f.runs,
                f.n,
                esc(&params.join(", ")),
                num(f.offset_mm),
                e.machines_differ_p
                    .map(show_p)
                    .unwrap_or_else(|| "—".into())
            );
        }
    }
    s.push_str("</table>");
}

//! The diagnosis section of the fleet report (docs/design.md §10):
//! self-contained HTML, inline SVG, no script, no network.

use std::fmt::Write;

use std::collections::BTreeMap;

use super::document::{param_text, CellBound};
use super::Diagnosis;
use crate::html::esc;
use crate::units::format::{
    covariate_unit, group_unit, plain_number, show_group_in, show_p, Dims, ParamUnit,
};

/// Each observable's figures (gap, noise floor, RMS before and after, a
/// cell's RMS) in one display unit, the smallest in which its gap RMS
/// stays below 1000 (units::format::show_group): µm for a gap in mm of
/// micrometres, mm/s for a velocity error, the observable's own unit
/// otherwise — so the rows of one observable compare digit by digit
/// across every table of the section.
struct Figures(BTreeMap<String, (String, f64)>);

impl Figures {
    fn of(d: &Diagnosis) -> Figures {
        Figures(
            d.per_observable
                .iter()
                .map(|o| {
                    let unit = ParamUnit::of(Dims::of_unit(&o.unit));
                    let max = o.rms_mm.max(o.noise_floor_mm).max(o.cv_rms_before_mm);
                    (o.observable.clone(), group_unit(max, &unit))
                })
                .collect(),
        )
    }
    /// `14.5 µm`, or "—" when absent.
    fn show(&self, observable: &str, x: Option<f64>) -> String {
        let Some(v) = x.filter(|v| v.is_finite()) else {
            return "—".into();
        };
        match self.0.get(observable) {
            Some((name, f)) if name.is_empty() => plain_number(v * f, 3),
            Some((name, f)) => format!("{} {name}", plain_number(v * f, 3)),
            // An observable without a summary: its numbers are in mm.
            None => crate::units::format::show_length(v),
        }
    }
}

/// A cell's bounds in the covariate's unit, both in one (`0 … 300 mm`,
/// not `0 nm … 300 mm`); an x/y tile's corners as `(x, y)` with each
/// coordinate in its own unit; a machine id as written.
fn bounds(covariate: &str, lo: &CellBound, hi: &CellBound) -> (String, String) {
    match (lo, hi) {
        (CellBound::Number(a), CellBound::Number(b)) if a.is_finite() && b.is_finite() => {
            number_bounds(covariate, [*a, *b])
        }
        (CellBound::Point(a), CellBound::Point(b)) if a.len() == b.len() => {
            // An x/y tile: `x_mm,y_mm` names the two coordinates.
            let covs: Vec<&str> = covariate.split(',').collect();
            let (l, h): (Vec<String>, Vec<String>) = a
                .iter()
                .zip(b)
                .enumerate()
                .map(|(i, (x, y))| {
                    let cov = covs.get(i).copied().unwrap_or(covariate);
                    if x.is_finite() && y.is_finite() {
                        number_bounds(cov, [*x, *y])
                    } else {
                        (esc(&number_text(*x)), esc(&number_text(*y)))
                    }
                })
                .unzip();
            (format!("({})", l.join(", ")), format!("({})", h.join(", ")))
        }
        _ => (as_text(lo), as_text(hi)),
    }
}

/// A 1-D cell's bounds in the covariate's unit.
fn number_bounds(covariate: &str, v: [f64; 2]) -> (String, String) {
    let unit = covariate_unit(covariate);
    // A count or index without a unit (`segment`, `pass`) as an
    // integer.
    if unit.canonical() == "1" && v.iter().all(|x| x.fract() == 0.0 && x.abs() < 1e15) {
        return (format!("{:.0}", v[0]), format!("{:.0}", v[1]));
    }
    let [l, h] = <[String; 2]>::try_from(show_group_in(&v, &unit)).expect("two figures");
    (l, h)
}

/// A number as diagnosis.json writes it (`null` when not finite).
fn number_text(x: f64) -> String {
    CellBound::Number(x).json_text()
}

fn as_text(v: &CellBound) -> String {
    match v {
        CellBound::Label(t) => esc(t),
        other => esc(&other.json_text()),
    }
}

/// A shrink (1 − after/before) with three decimals, "0.000" for a zero
/// that rounding made negative.
fn shrink(v: f64) -> String {
    let s = format!("{v:.3}");
    if s == "-0.000" {
        "0.000".into()
    } else {
        s
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
    let fig = Figures::of(d);
    let mut s = String::from(r#"<section class="diagnosis"><h2>Sim-to-real gap diagnosis</h2>"#);
    // No pooled gap or "share unexplained" across observables: their
    // scales differ (a touch probe's noise would swamp every real gap). Each observable against its own floor, in its own row.
    s.push_str("<table><tr><th>observable</th><th>n</th><th>gap RMS</th><th>noise floor</th><th>held-out RMS after</th><th>shrink</th><th>explained by, or why not</th></tr>");
    for o in &d.per_observable {
        let _ = write!(
            s,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            esc(&o.observable),
            o.n,
            fig.show(&o.observable, Some(o.rms_mm)),
            fig.show(&o.observable, Some(o.noise_floor_mm)),
            fig.show(&o.observable, Some(o.cv_rms_after_mm)),
            shrink(o.shrink),
            esc(&crate::document::explained_by(o, &d.effects))
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
        s.push_str("<table><tr><th>observable</th><th>covariate</th><th>lo</th><th>hi</th><th>n</th><th>RMS</th><th>share</th><th>p</th></tr>");
        for c in d.where_.iter().take(20) {
            let (lo, hi) = bounds(&c.covariate, &c.lo, &c.hi);
            let _ = write!(
                s,
                "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.3}</td><td>{}</td></tr>",
                esc(&c.observable),
                esc(&c.covariate),
                lo,
                hi,
                c.n,
                fig.show(&c.observable, Some(c.rms_mm)),
                c.share,
                show_p(c.p_value)
            );
        }
        s.push_str("</table>");
    }
    s.push_str(EVERY_CANDIDATE_HEADING);
    s.push_str(&ranking_svg(d));
    s.push_str("<table><tr><th>effect</th><th>observable</th><th>held-out RMS before</th><th>after</th><th>shrink</th><th>p</th><th>selected</th><th>params</th></tr>");
    for e in &d.effects {
        // Selected effects: every parameter with its standard error.
        let params: Vec<String> = if e.intervals.is_some() {
            e.params_text()
        } else {
            e.params
                .iter()
                .map(|(k, v)| param_text(k, *v, None, e.covariate.as_deref(), &e.gap_unit))
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
            fig.show(&e.observable, e.cv_rms_before_mm),
            fig.show(&e.observable, e.cv_rms_after_mm),
            match (e.shrink, e.shrink_interval) {
                (Some(v), Some([lo, hi])) => {
                    format!("{} [{}, {}]", shrink(v), shrink(lo), shrink(hi))
                }
                (Some(v), None) => shrink(v),
                _ => "—".into(),
            },
            e.p_value.map(show_p).unwrap_or_else(|| "—".into()),
            if e.selected { "yes" } else { "" },
            esc(&e.skipped_reason.clone().unwrap_or_else(|| params.join(", ")))
        );
    }
    s.push_str("</table>");
    per_machine_table(d, &fig, &mut s);
    s.push_str("<h3>Unexplained</h3>");
    if d.unexplained.where_.is_empty() {
        s.push_str("<p>No cell remains significantly above the noise floor.</p>");
    } else {
        s.push_str("<table><tr><th>observable</th><th>covariate</th><th>lo</th><th>hi</th><th>RMS before</th><th>RMS after</th><th>shrink</th></tr>");
        for c in d.unexplained.where_.iter().take(20) {
            let (lo, hi) = bounds(&c.covariate, &c.lo, &c.hi);
            let _ = write!(
                s,
                "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                esc(&c.observable),
                esc(&c.covariate),
                lo,
                hi,
                fig.show(&c.observable, c.rms_before_mm),
                fig.show(&c.observable, Some(c.rms_mm)),
                c.shrink.map(shrink).unwrap_or_else(|| "—".into())
            );
        }
        s.push_str("</table>");
    }
    s.push_str("</section>");
    s
}

/// Selected effects whose machines disagree: each machine's own fit.
fn per_machine_table(d: &Diagnosis, fig: &Figures, s: &mut String) {
    let rows: Vec<_> = d
        .effects
        .iter()
        .filter_map(|e| e.per_machine.as_ref().map(|m| (e, m)))
        .collect();
    if rows.is_empty() {
        return;
    }
    s.push_str("<h3>Per machine: the machines disagree</h3><table><tr><th>effect</th><th>observable</th><th>machine</th><th>runs</th><th>n</th><th>params</th><th>offset</th><th>p (one effect for all)</th></tr>");
    for (e, fits) in rows {
        let name = match &e.covariate {
            Some(c) => format!("{}:{}", e.name, c),
            None => e.name.clone(),
        };
        for f in fits {
            let params: Vec<String> = f
                .params
                .iter()
                .map(|(k, v)| param_text(k, *v, None, e.covariate.as_deref(), &e.gap_unit))
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
                fig.show(&e.observable, f.offset_mm),
                e.machines_differ_p
                    .map(show_p)
                    .unwrap_or_else(|| "—".into())
            );
        }
    }
    s.push_str("</table>");
}

//! trend.html: the alerts, latest night first, each linking to its chart;
//! then the parameters over nights grouped by machine (the fleet-wide fits
//! first) and observable, one full-width chart per parameter: the nights'
//! dates on x, the value in the parameter's engineer unit on y, the 95 %
//! interval as a shaded band, and a ring on each night an alert was
//! raised on that series.

use std::collections::BTreeMap;
use std::fmt::Write;

use super::{Alert, Trend, TrendSeries};
use crate::units::format::{display_unit, effect_param_unit};
use crate::{esc, page, svg};

/// Width and height in px of a trend chart (the page's full width).
const CHART_PX: (u32, u32) = (1160, 320);

/// The anchor of a (machine, observable) group: `trend-<machine>-<observable>`,
/// `trend-fleet-<observable>` for the fleet-wide fits. Other pages link to
/// exactly this.
pub fn trend_anchor(machine: Option<&str>, observable: &str) -> String {
    format!(
        "trend-{}-{}",
        id_part(machine.unwrap_or("fleet")),
        id_part(observable)
    )
}

/// An id fragment: ASCII letters, digits and `_` kept, anything else `-`.
pub fn id_part(s: &str) -> String {
    s.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' {
                c
            } else {
                '-'
            }
        })
        .collect()
}

/// Whether an alert is about a series: same observable, machine and
/// effect, and the same parameter (an alert without one, appeared or
/// disappeared, is about every parameter of the effect).
fn alert_on(a: &Alert, s: &TrendSeries) -> bool {
    a.observable == s.observable
        && a.machine == s.machine
        && a.effect == s.effect
        && a.param.as_deref().is_none_or(|p| p == s.param)
}

/// The parameter's display unit over a series: its name (or the unit as
/// written when the gap's unit is not converted) and the factor.
fn series_unit(s: &TrendSeries) -> (String, f64) {
    let size = s
        .points
        .iter()
        .map(|p| p.value.abs())
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    match effect_param_unit(&s.effect, &s.param, &s.unit) {
        Some(u) => display_unit(size, &u),
        None => (String::new(), 1.0),
    }
}

/// One chart: a parameter over nights.
fn chart(t: &Trend, s: &TrendSeries, alerts: &[&Alert]) -> String {
    let index: BTreeMap<&str, f64> = t
        .nights
        .iter()
        .enumerate()
        .map(|(i, n)| (n.as_str(), i as f64))
        .collect();
    let (unit, f) = series_unit(s);
    let at = |n: &str| index.get(n).copied();
    let value: Vec<(f64, f64)> = s
        .points
        .iter()
        .filter(|p| p.value.is_finite())
        .filter_map(|p| Some((at(&p.night)?, p.value * f)))
        .collect();
    let band = svg::band_outline(
        &s.points
            .iter()
            .filter_map(|p| Some((at(&p.night)?, p.lo95? * f, p.hi95? * f)))
            .collect::<Vec<_>>(),
    );
    // A ring on the alert's night, at that night's value (or, for an
    // effect that disappeared, at the last value before it).
    let rings: Vec<(f64, f64, String)> = alerts
        .iter()
        .filter_map(|a| {
            let x = at(&a.night)?;
            let y = value.iter().rev().find(|p| p.0 <= x).or(value.first())?.1;
            Some((x, y, format!("#{} {}", a.rank, a.kind)))
        })
        .collect();
    let mut series = Vec::new();
    if band.len() >= 3 {
        series.push(svg::Series {
            name: "95 % interval",
            points: &band,
            mark: svg::Mark::Band,
        });
    }
    series.push(svg::Series {
        name: "value",
        points: &value,
        mark: svg::Mark::Points,
    });
    let y_label = if unit.is_empty() {
        s.param.clone()
    } else {
        format!("{} ({unit})", s.param)
    };
    svg::xy_chart_with(
        &format!("{} {}", s.effect, s.param),
        ("night", &y_label),
        &series,
        CHART_PX,
        &svg::XyExtras {
            x_names: &t.nights,
            rings: &rings,
        },
    )
}

/// The alerts, latest night first, by rank within a night; each links to
/// the chart group of its series.
fn alert_list(t: &Trend) -> String {
    if t.alerts.is_empty() {
        return "<p>None: no material effect appeared, disappeared or moved beyond its night-to-night spread.</p>\n".into();
    }
    let mut alerts: Vec<&Alert> = t.alerts.iter().collect();
    alerts.sort_by(|a, b| b.night.cmp(&a.night).then(a.rank.cmp(&b.rank)));
    let mut body = String::from("<ul class=\"alerts\">\n");
    for a in alerts {
        let _ = writeln!(
            body,
            "<li><a href=\"#{}\"><b>{} #{}</b> {}</a>: {}</li>",
            esc(&trend_anchor(a.machine.as_deref(), &a.observable)),
            esc(&a.night),
            a.rank,
            esc(&a.kind),
            esc(&a.message)
        );
    }
    body.push_str("</ul>\n");
    body
}

/// trend.html.
pub fn trend_page(t: &Trend) -> String {
    let mut body = String::new();
    let _ = writeln!(
        body,
        "<p>{} night(s): {} … {}.</p>",
        t.nights.len(),
        esc(t.nights.first().map_or("", |s| s.as_str())),
        esc(t.nights.last().map_or("", |s| s.as_str()))
    );
    body.push_str("<h2>Alerts</h2>\n");
    body.push_str(&alert_list(t));
    if !t.events.is_empty() {
        body.push_str("<h2>Events (each starts a new baseline)</h2>\n<ul>\n");
        for e in &t.events {
            let _ = writeln!(
                body,
                "<li><b>{}</b> {} {}: {}</li>",
                esc(&e.night),
                esc(&e.kind),
                esc(if e.machine.is_empty() {
                    "fleet"
                } else {
                    &e.machine
                }),
                esc(&e.note)
            );
        }
        body.push_str("</ul>\n");
    }
    for n in &t.notes {
        let _ = writeln!(body, "<p class=\"note\">{}</p>", esc(n));
    }
    let _ = writeln!(body, "<p><small>Rule: {}</small></p>", esc(&t.rule));
    body.push_str("<h2>Parameters over nights</h2>\n<p class=\"note\">Grouped by machine (fleet-wide fits first), then observable. Each chart: the parameter each night in its unit, the 95 % interval shaded, a red ring on the nights an alert was raised on it.</p>\n");
    // Machine (None = fleet first) → observable → series.
    let mut groups: BTreeMap<(Option<&str>, &str), Vec<&TrendSeries>> = BTreeMap::new();
    for s in &t.series {
        groups
            .entry((s.machine.as_deref(), s.observable.as_str()))
            .or_default()
            .push(s);
    }
    let mut machine_seen: Option<Option<&str>> = None;
    for ((machine, observable), series) in groups {
        if machine_seen != Some(machine) {
            let _ = writeln!(
                body,
                "<h3>{}</h3>",
                esc(&machine.map_or("Fleet-wide fits".to_string(), |m| format!("Machine {m}")))
            );
            machine_seen = Some(machine);
        }
        let _ = writeln!(
            body,
            "<section class=\"trend\" id=\"{}\"><h4>{}</h4>",
            esc(&trend_anchor(machine, observable)),
            esc(observable)
        );
        for s in series {
            let on: Vec<&Alert> = t.alerts.iter().filter(|a| alert_on(a, s)).collect();
            body.push_str(&chart(t, s, &on));
            body.push('\n');
        }
        body.push_str("</section>\n");
    }
    page("sparkout trend across nights", &body)
}

#[cfg(test)]
mod tests {
    use super::super::{Point, TrendConfig};
    use super::*;

    fn point(night: &str, v: f64) -> Point {
        Point {
            night: night.into(),
            value: v,
            se: Some(0.1e-5),
            lo95: Some(v - 0.2e-5),
            hi95: Some(v + 0.2e-5),
            material: true,
        }
    }

    fn alert(night: &str, rank: usize, machine: Option<&str>) -> Alert {
        Alert {
            rank,
            kind: "moved".into(),
            observable: "cut_depth".into(),
            unit: "mm".into(),
            effect: "wear:removed_mm3".into(),
            machine: machine.map(String::from),
            machines: vec!["form-1".into()],
            param: Some("k".into()),
            night: night.into(),
            from_night: night.into(),
            nights: 1,
            since: None,
            value: None,
            baseline: None,
            spread: None,
            size: None,
            gap_rms: None,
            fraction_of_gap: None,
            z: None,
            p_value: None,
            p_holm: None,
            tests: 1,
            score: 0.0,
            message: format!("message {night} {rank}"),
        }
    }

    fn sample() -> Trend {
        let nights: Vec<String> = (1..=4).map(|d| format!("2026-11-0{d}")).collect();
        let series = |machine: Option<&str>| TrendSeries {
            observable: "cut_depth".into(),
            unit: "mm".into(),
            effect: "wear:removed_mm3".into(),
            machine: machine.map(String::from),
            param: "k".into(),
            points: nights
                .iter()
                .zip([1.0e-5, 1.01e-5, 0.99e-5, 1.4e-5])
                .map(|(n, v)| point(n, v))
                .collect(),
        };
        Trend {
            version: super::super::TREND_VERSION,
            kind: "sparkout.trend".into(),
            nights: nights.clone(),
            rule: "r".into(),
            settings: TrendConfig::default(),
            events: vec![],
            notes: vec![],
            tests_per_night: BTreeMap::new(),
            series: vec![series(Some("form-1")), series(None)],
            alerts: vec![
                alert("2026-11-02", 1, None),
                alert("2026-11-04", 2, Some("form-1")),
                alert("2026-11-04", 1, None),
            ],
        }
    }

    #[test]
    fn charts_have_dates_a_band_units_and_alert_rings() {
        let html = trend_page(&sample());
        for n in ["2026-11-01", "2026-11-04"] {
            assert!(
                html.contains("class=\"xtick\"") && html.contains(&format!(">{n}</text>")),
                "{n}"
            );
        }
        assert!(!html.contains("night (0 = first)"));
        assert!(html.contains("<polygon"), "band");
        // The wear rate in nm/mm³ on the y label.
        assert!(html.contains("k (nm/mm³)"), "{html}");
        // Fleet chart: two alerts; form-1's chart: one.
        assert_eq!(html.matches("class=\"ring\"").count(), 3);
        // Groups: fleet first, then the machine; anchors as other pages
        // link to them.
        let fleet = html.find("id=\"trend-fleet-cut_depth\"").unwrap();
        let machine = html.find("id=\"trend-form-1-cut_depth\"").unwrap();
        assert!(fleet < machine);
    }

    #[test]
    fn alerts_are_listed_latest_night_first_then_by_rank_and_link_to_their_chart() {
        let html = trend_page(&sample());
        let order: Vec<usize> = [
            "message 2026-11-04 1",
            "message 2026-11-04 2",
            "message 2026-11-02 1",
        ]
        .iter()
        .map(|m| html.find(m).unwrap())
        .collect();
        assert!(order.windows(2).all(|w| w[0] < w[1]), "{order:?}");
        assert!(html.contains("<a href=\"#trend-form-1-cut_depth\"><b>2026-11-04 #2</b>"));
        assert!(html.contains("<a href=\"#trend-fleet-cut_depth\"><b>2026-11-04 #1</b>"));
    }
}

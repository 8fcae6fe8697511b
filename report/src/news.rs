//! The night's news, first on the index and on the fleet page (one
//! function, both pages): the night's date, its trend alerts as trend.json
//! ranks them — machine, observable, effect, old → new in engineer units,
//! the share of the gap the change moves, each linked to its trend chart
//! and its runs — the night's events, the rejected runs and the runs whose
//! verdict is FAIL or CHECK. Lists are capped ("and N more"): the page
//! below has the rest.

use std::collections::BTreeMap;
use std::fmt::Write;
use std::path::Path;

use super::esc;
use super::trend::page::id_part;
use super::trend::TREND_PAGE;
use super::trend::{read_trend, trend_anchor, Alert, Trend};
use super::verdict::RunVerdict;
use crate::outcome::{FleetOutcome, Night, RunResult};
use crate::units::format::{param_unit, show, show_in};

/// At most this many alerts in the banner (the trend page has them all).
pub const MAX_ALERTS: usize = 5;
/// At most this many rejected runs, and run links per machine.
pub const MAX_RUNS: usize = 8;
/// At most this many lines of FAIL/CHECK runs (one per status and machine).
pub const MAX_LINES: usize = 8;

/// The id of a machine's runs on the index.
pub fn runs_anchor(machine: &str) -> String {
    format!("runs-{}", id_part(machine))
}

/// The trend of the output root, if `sparkout run --history` wrote one.
fn trend_of(out: &Path) -> Option<Trend> {
    read_trend(&out.join("trend").join("trend.json")).ok()
}

/// The covariate of an effect key (`wear:removed_mm3` → `removed_mm3`).
fn covariate_of(effect: &str) -> Option<&str> {
    effect.split_once(':').map(|(_, c)| c)
}

/// "old → new" of an alert in the parameter's engineer unit (a lag in ms,
/// a wear rate in nm/mm³), with the relative change; for an effect that
/// appeared or disappeared, "absent → present" and what it explains.
fn change_text(a: &Alert) -> String {
    match (a.kind.as_str(), a.baseline, a.value) {
        ("moved", Some(old), Some(new)) => {
            let u = param_unit(
                a.param.as_deref().unwrap_or(""),
                covariate_of(&a.effect),
                &a.unit,
            );
            let rel = if old != 0.0 {
                format!(" ({:+.0} %)", 100.0 * (new - old) / old.abs())
            } else {
                String::new()
            };
            format!(
                "{} → <b>{}</b>{rel}",
                esc(&show(old, &u)),
                esc(&show(new, &u))
            )
        }
        ("appeared", ..) => "absent → <b>present</b>".into(),
        ("disappeared", ..) => "present → <b>absent</b>".into(),
        (kind, ..) => esc(kind),
    }
}

/// "moves 49 % of the gap (7.18 µm of 14.6 µm)".
fn share_text(a: &Alert) -> String {
    match (a.fraction_of_gap, a.size, a.gap_rms) {
        (Some(f), Some(s), Some(g)) => format!(
            "moves <b>{:.0} %</b> of the gap ({} of {})",
            100.0 * f,
            esc(&show_in(s, &a.unit)),
            esc(&show_in(g, &a.unit))
        ),
        (Some(f), ..) => format!("moves <b>{:.0} %</b> of the gap", 100.0 * f),
        _ => "share of the gap unknown".into(),
    }
}

/// One alert line: machine, observable, effect, old → new, share of the
/// gap, links to its trend chart and its runs. `base` leads from the page
/// to the output root ("" on the index, "../" on the fleet page).
fn alert_line(a: &Alert, base: &str) -> String {
    let machines: Vec<&str> = match &a.machine {
        Some(m) => vec![m.as_str()],
        None => a.machines.iter().map(|m| m.as_str()).collect(),
    };
    let who = if machines.is_empty() {
        "the fleet".to_string()
    } else {
        machines.join(", ")
    };
    let param = a
        .param
        .as_deref()
        .map(|p| format!(" {}", esc(p)))
        .unwrap_or_default();
    let runs: Vec<String> = machines
        .iter()
        .map(|m| {
            format!(
                "<a href=\"{base}index.html#{}\">runs of {}</a>",
                runs_anchor(m),
                esc(m)
            )
        })
        .collect();
    let mut s = format!(
        "<b>{}</b> · {} · <b>{}</b>{param} {}: {} — {} · <a href=\"{base}{TREND_PAGE}#{}\">trend chart</a>",
        esc(&who),
        esc(&a.observable),
        esc(&a.effect),
        esc(&a.kind),
        change_text(a),
        share_text(a),
        trend_anchor(a.machine.as_deref(), &a.observable),
    );
    for r in runs {
        let _ = write!(s, " · {r}");
    }
    s
}

/// The heading's date and how it was known.
fn date_text(night: &Night) -> (String, String) {
    match (&night.date, night.given) {
        (Some(d), true) => (format!("Night {}", esc(d)), "given with --night".into()),
        (Some(d), false) => (
            format!("Night {}", esc(d)),
            match &night.first {
                Some(f) => format!("dated from the runs: recorded {} … {}", esc(f), esc(d)),
                None => "dated from the runs' start".into(),
            },
        ),
        (None, _) => (
            "Night of unknown date".into(),
            "no run states <code>[run].started</code> and no <code>--night</code> was given".into(),
        ),
    }
}

/// The trend part: the heading and the ranked alerts with the night's
/// events, or why there are none.
fn trend_part(t: Option<&Trend>, night: &Night, base: &str) -> (String, String, String) {
    let (date, dated) = date_text(night);
    let on = |t: &Trend| {
        night
            .date
            .as_deref()
            .filter(|d| t.nights.iter().any(|n| n == d))
            .map(str::to_string)
    };
    let Some((t, n)) = t.and_then(|t| on(t).map(|n| (t, n))) else {
        let why = match t {
            Some(t) => format!(
                "The <a href=\"{base}{TREND_PAGE}\">trend</a> has no entry for this night (its latest: {}).",
                esc(t.nights.last().map_or("none", |s| s.as_str()))
            ),
            None => "No trend: with <code>sparkout run --history DIR</code> each night's diagnosis is kept and compared with the nights before.".into(),
        };
        return (
            format!("<h2>{date}</h2>"),
            dated,
            format!("<p class=\"note\">{why}</p>"),
        );
    };
    let alerts: Vec<&Alert> = t.alerts_on(&n).collect();
    let tests = t.tests_per_night.get(&n).copied().unwrap_or(0);
    let mut s = String::new();
    let head = if alerts.is_empty() {
        let _ = write!(
            s,
            "<p>{tests} parameter tests against each series' own baseline, false alarms controlled over the night (Holm). <a href=\"{base}{TREND_PAGE}\">Trend</a></p>"
        );
        format!("<h2 class=\"ok\">{date}: no trend alert</h2>")
    } else {
        s.push_str("<ol>");
        for a in alerts.iter().take(MAX_ALERTS) {
            let _ = write!(s, "<li>{}</li>", alert_line(a, base));
        }
        s.push_str("</ol>");
        if alerts.len() > MAX_ALERTS {
            let _ = write!(
                s,
                "<p>and {} more on the <a href=\"{base}{TREND_PAGE}\">trend page</a>.</p>",
                alerts.len() - MAX_ALERTS
            );
        }
        format!(
            "<h2 class=\"bad\">{date}: {} trend alert{}, biggest change first</h2>",
            alerts.len(),
            if alerts.len() == 1 { "" } else { "s" }
        )
    };
    let events: Vec<_> = t.events.iter().filter(|e| e.night == n).collect();
    if !events.is_empty() {
        s.push_str("<p>Events of the night (each starts a new baseline):</p><ul>");
        for e in events {
            let _ = write!(
                s,
                "<li>{} on {}{}</li>",
                esc(&e.kind),
                esc(if e.machine.is_empty() {
                    "the fleet"
                } else {
                    &e.machine
                }),
                if e.note.is_empty() {
                    String::new()
                } else {
                    format!(": {}", esc(&e.note))
                }
            );
        }
        s.push_str("</ul>");
    }
    (head, dated, s)
}

/// The runs part: rejected runs, then the runs whose verdict is FAIL or
/// CHECK (FAIL first), each with its first reason and a link to its page.
fn runs_part(outcome: &FleetOutcome, base: &str) -> String {
    let verdicts: Vec<(&RunResult, RunVerdict)> = outcome
        .runs
        .iter()
        .filter_map(|r| Some((r, RunVerdict::read(Path::new(&r.out_dir))?)))
        .collect();
    let count = |w: &str| verdicts.iter().filter(|(_, v)| v.status == w).count();
    let (fail, check, ok) = (count("FAIL"), count("CHECK"), count("OK"));
    let rejected = outcome.failures.len();
    let machines: std::collections::BTreeSet<&str> =
        outcome.runs.iter().map(|r| r.machine.as_str()).collect();
    let mut s = format!(
        "<p><b>{} run{}</b> on {} machine{}: <b class=\"{}\">{fail} FAIL</b>, <b class=\"{}\">{check} CHECK</b>, {ok} OK{}; <b class=\"{}\">{rejected} rejected</b>.</p>",
        outcome.runs.len() + rejected,
        if outcome.runs.len() + rejected == 1 { "" } else { "s" },
        machines.len(),
        if machines.len() == 1 { "" } else { "s" },
        if fail > 0 { "bad" } else { "ok" },
        if check > 0 { "check" } else { "ok" },
        match outcome.runs.len() - verdicts.len() {
            0 => String::new(),
            n => format!(", {n} without a verdict"),
        },
        if rejected > 0 { "bad" } else { "ok" },
    );
    if rejected > 0 {
        s.push_str("<ul class=\"rejected\">");
        for f in outcome.failures.iter().take(MAX_RUNS) {
            let who = match (&f.machine, &f.run) {
                (Some(m), Some(r)) => format!("{m} / {r}"),
                _ => f.run_dir.clone(),
            };
            let first = f.error.lines().next().unwrap_or("");
            let _ = write!(
                s,
                "<li><b class=\"bad\">rejected</b> {} — {}: {}</li>",
                esc(&who),
                esc(f.stage.as_deref().unwrap_or("before any stage")),
                esc(&shorten(first, 160))
            );
        }
        if rejected > MAX_RUNS {
            let _ = write!(s, "<li>and {} more</li>", rejected - MAX_RUNS);
        }
        let _ = write!(
            s,
            "</ul><p class=\"note\">File, column and row of each: <a href=\"{base}index.html#failures\">failures of the night</a>.</p>"
        );
    }
    // FAIL before CHECK; one line per status and machine, its runs linked
    // and the first reason of its first run.
    let mut lines: BTreeMap<(bool, &str), Vec<&(&RunResult, RunVerdict)>> = BTreeMap::new();
    for rv in &verdicts {
        if rv.1.status == "FAIL" || rv.1.status == "CHECK" {
            lines
                .entry((rv.1.status != "FAIL", rv.0.machine.as_str()))
                .or_default()
                .push(rv);
        }
    }
    if !lines.is_empty() {
        s.push_str("<ul class=\"verdicts\">");
        let mut left = fail + check;
        for (k, ((check_only, machine), mut runs)) in lines.into_iter().enumerate() {
            if k == MAX_LINES {
                let _ = write!(
                    s,
                    "<li>and {left} more: <a href=\"{base}index.html#runs\">every run's status</a></li>"
                );
                break;
            }
            left -= runs.len();
            runs.sort_by(|a, b| a.0.run.cmp(&b.0.run));
            let links: Vec<String> = runs
                .iter()
                .take(MAX_RUNS)
                .map(|(r, _)| {
                    format!(
                        "<a href=\"{base}{}/{}/report.html\">{}</a>",
                        esc(&r.machine),
                        esc(&r.run),
                        esc(&r.run)
                    )
                })
                .collect();
            let more = match runs.len().saturating_sub(MAX_RUNS) {
                0 => String::new(),
                n => format!(" and {n} more"),
            };
            let (word, class) = if check_only {
                ("CHECK", "check")
            } else {
                ("FAIL", "bad")
            };
            let first = &runs[0];
            let _ = write!(
                s,
                "<li><b class=\"{class}\">{word}</b> {} ({} run{}): {}{more} — {}: {}</li>",
                esc(machine),
                runs.len(),
                if runs.len() == 1 { "" } else { "s" },
                links.join(" · "),
                esc(&first.0.run),
                esc(&shorten(
                    first.1.reasons.first().map_or("", |x| x.as_str()),
                    160
                ))
            );
        }
        s.push_str("</ul>");
    }
    s
}

/// `text` cut to at most `max` characters, with "…" when cut.
fn shorten(text: &str, max: usize) -> String {
    if text.chars().count() <= max {
        return text.to_string();
    }
    let mut s: String = text.chars().take(max - 1).collect();
    s.push('…');
    s
}

/// The banner both pages open with (`<section id="news">`). `base` leads
/// from the page to the output root: "" for the index, "../" for the
/// fleet page.
pub fn banner(outcome: &FleetOutcome, base: &str) -> String {
    let trend = trend_of(&outcome.out_dir);
    let (head, dated, alerts) = trend_part(trend.as_ref(), &outcome.night, base);
    format!(
        "<section id=\"news\" class=\"news\">{head}<p class=\"note\">{dated}.</p>{alerts}{}</section>",
        runs_part(outcome, base)
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn alert() -> Alert {
        Alert {
            rank: 1,
            kind: "moved".into(),
            observable: "profile_error".into(),
            unit: "mm".into(),
            effect: "wheel_wear:removed_mm3".into(),
            machine: None,
            machines: vec!["form-1".into()],
            param: Some("k".into()),
            night: "2026-11-03".into(),
            from_night: "2026-11-03".into(),
            nights: 1,
            since: Some("2026-11-01".into()),
            value: Some(3.0e-5),
            baseline: Some(1.5e-5),
            spread: Some(7.5e-7),
            size: Some(0.00718),
            gap_rms: Some(0.01455),
            fraction_of_gap: Some(0.4935),
            z: Some(16.0),
            p_value: Some(0.0),
            p_holm: Some(0.0),
            tests: 2,
            score: 0.49,
            message: String::new(),
        }
    }

    #[test]
    fn an_alert_reads_in_engineer_units_and_links_its_chart_and_runs() {
        let line = alert_line(&alert(), "../");
        assert!(
            line.contains("<b>form-1</b> · profile_error · <b>wheel_wear:removed_mm3</b> k moved"),
            "{line}"
        );
        assert!(
            line.contains("15.0 nm/mm³ → <b>30.0 nm/mm³</b> (+100 %)"),
            "{line}"
        );
        assert!(
            line.contains("moves <b>49 %</b> of the gap (7.18 µm of 14.6 µm)"),
            "{line}"
        );
        assert!(
            line.contains("href=\"../trend/trend.html#trend-fleet-profile_error\""),
            "{line}"
        );
        assert!(
            line.contains("href=\"../index.html#runs-form-1\""),
            "{line}"
        );
        let lag = Alert {
            effect: "servo_lag:cmd_v_mm_s".into(),
            param: Some("k_s".into()),
            baseline: Some(0.004),
            value: Some(0.008),
            ..alert()
        };
        assert!(
            alert_line(&lag, "").contains("4.00 ms → <b>8.00 ms</b>"),
            "{}",
            alert_line(&lag, "")
        );
    }

    #[test]
    fn a_night_without_a_date_says_so() {
        let (d, why) = date_text(&Night::default());
        assert_eq!(d, "Night of unknown date");
        assert!(why.contains("[run].started"));
        let (d, why) = date_text(&Night {
            date: Some("2026-11-20".into()),
            first: Some("2026-11-01".into()),
            given: false,
        });
        assert_eq!(d, "Night 2026-11-20");
        assert!(why.contains("2026-11-01 … 2026-11-20"), "{why}");
    }
}

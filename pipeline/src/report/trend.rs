//! The trend across nights (issue 13 item 5): each night's diagnosis is
//! appended to a fleet history — a Parquet dataset partitioned by night,
//! `<history>/night=YYYY-MM-DD/diagnosis.parquet` — and `sparkout trend`
//! reads it back: each selected effect's parameters over nights with their
//! 95 % intervals, per machine where the diagnosis fitted one, and alerts
//! for a monitoring system (trend.json) when an effect appears, disappears
//! or moves beyond its interval.
//!
//! Alert rule (docs/diagnosis.md "History and trend"): a parameter moved
//! between nights a and b when |p_b − p_a| > 1.96·√(se_a² + se_b²) — the two
//! estimates' 95 % intervals of the difference exclude zero. It is tested
//! against the previous night and against the first night of the history
//! (a slow drift that no single night shows).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{bail, Context};
use arrow::array::{Array, AsArray, Float64Array, RecordBatch, StringArray};
use arrow::datatypes::{DataType, Field, Float64Type, Schema};
use serde::Serialize;

use super::{esc, page, svg};
use crate::contracts::{write_atomic, write_json_atomic, write_parquet_atomic};
use crate::error::Result;

/// Version of trend.json.
pub const TREND_VERSION: u32 = 1;

/// z of a two-sided 95 % interval.
const Z95: f64 = 1.96;

/// One history row: a parameter of a selected effect on one night, or — with
/// an empty `effect` — the observable itself (so a night that diagnosed an
/// observable and selected nothing tells "disappeared" from "not measured").
#[derive(Debug, Clone, PartialEq)]
pub struct HistoryRow {
    pub night: String,
    pub observable: String,
    pub unit: String,
    /// `name:covariate`, or "" for the observable row.
    pub effect: String,
    /// A machine's own fit, or "" for the fleet-wide fit.
    pub machine: String,
    pub param: String,
    pub value: f64,
    pub se: f64,
    pub lo95: f64,
    pub hi95: f64,
    pub shrink: f64,
    pub gap_rms: f64,
    pub noise_floor: f64,
    pub n_runs: f64,
}

/// `YYYY-MM-DD`, checked.
pub fn check_night(night: &str) -> Result<()> {
    let b = night.as_bytes();
    let ok = b.len() == 10
        && b[4] == b'-'
        && b[7] == b'-'
        && b.iter()
            .enumerate()
            .all(|(i, c)| i == 4 || i == 7 || c.is_ascii_digit())
        && (1..=12).contains(&night[5..7].parse::<u32>().unwrap_or(0))
        && (1..=31).contains(&night[8..10].parse::<u32>().unwrap_or(0));
    if !ok {
        bail!("night `{night}`: expected a date YYYY-MM-DD, e.g. 2026-11-25");
    }
    Ok(())
}

fn f(v: &serde_json::Value, k: &str) -> f64 {
    v.get(k).and_then(|x| x.as_f64()).unwrap_or(f64::NAN)
}

/// The rows of one night's diagnosis.json.
pub fn rows_of(diagnosis: &serde_json::Value, night: &str) -> Vec<HistoryRow> {
    let mut rows = Vec::new();
    let per: BTreeMap<&str, &serde_json::Value> = diagnosis
        .get("per_observable")
        .and_then(|p| p.as_array())
        .into_iter()
        .flatten()
        .filter_map(|o| Some((o.get("observable")?.as_str()?, o)))
        .collect();
    let unit_of = |o: &str| -> String {
        per.get(o)
            .and_then(|p| p.get("unit"))
            .and_then(|u| u.as_str())
            .unwrap_or("mm")
            .to_string()
    };
    for (o, p) in &per {
        rows.push(HistoryRow {
            night: night.into(),
            observable: o.to_string(),
            unit: unit_of(o),
            effect: String::new(),
            machine: String::new(),
            param: String::new(),
            value: f64::NAN,
            se: f64::NAN,
            lo95: f64::NAN,
            hi95: f64::NAN,
            shrink: f(p, "shrink"),
            gap_rms: f(p, "rms_mm"),
            noise_floor: f(p, "noise_floor_mm"),
            n_runs: f(p, "runs"),
        });
    }
    let effects = diagnosis.get("effects").and_then(|e| e.as_array());
    for e in effects.into_iter().flatten() {
        if e.get("selected").and_then(|s| s.as_bool()) != Some(true) {
            continue;
        }
        let obs = e.get("observable").and_then(|x| x.as_str()).unwrap_or("");
        let name = e.get("name").and_then(|x| x.as_str()).unwrap_or("");
        let key = match e.get("covariate").and_then(|c| c.as_str()) {
            Some(c) => format!("{name}:{c}"),
            None => name.to_string(),
        };
        let p = per.get(obs);
        let base =
            |machine: &str, param: &str, value: f64, iv: Option<&serde_json::Value>| HistoryRow {
                night: night.into(),
                observable: obs.into(),
                unit: unit_of(obs),
                effect: key.clone(),
                machine: machine.into(),
                param: param.into(),
                value,
                se: iv.map_or(f64::NAN, |i| f(i, "se")),
                lo95: iv.map_or(f64::NAN, |i| f(i, "lo")),
                hi95: iv.map_or(f64::NAN, |i| f(i, "hi")),
                shrink: f(e, "shrink"),
                gap_rms: p.map_or(f64::NAN, |p| f(p, "rms_mm")),
                noise_floor: p.map_or(f64::NAN, |p| f(p, "noise_floor_mm")),
                n_runs: p.map_or(f64::NAN, |p| f(p, "runs")),
            };
        let params = e.get("params").and_then(|p| p.as_object());
        let intervals = e.get("intervals");
        for (k, v) in params.into_iter().flatten() {
            let iv = intervals.and_then(|i| i.get(k));
            rows.push(base("", k, v.as_f64().unwrap_or(f64::NAN), iv));
        }
        // A machine's own fit, where the diagnosis reports one.
        let per_machine = e.get("per_machine").and_then(|m| m.as_array());
        for m in per_machine.into_iter().flatten() {
            let machine = m.get("machine").and_then(|x| x.as_str()).unwrap_or("");
            let mparams = m.get("params").and_then(|p| p.as_object());
            for (k, v) in mparams.into_iter().flatten() {
                let se = m
                    .get("se")
                    .and_then(|s| s.get(k))
                    .and_then(|s| s.as_f64())
                    .unwrap_or(f64::NAN);
                let value = v.as_f64().unwrap_or(f64::NAN);
                let mut r = base(machine, k, value, None);
                r.se = se;
                r.lo95 = value - Z95 * se;
                r.hi95 = value + Z95 * se;
                rows.push(r);
            }
        }
    }
    rows
}

fn batch_of(rows: &[HistoryRow]) -> Result<RecordBatch> {
    let text = |g: fn(&HistoryRow) -> &str| -> Arc<dyn Array> {
        Arc::new(StringArray::from_iter_values(rows.iter().map(g)))
    };
    let num = |g: fn(&HistoryRow) -> f64| -> Arc<dyn Array> {
        // NaN is "no value": null in the file (no non-finite number is
        // ever written, issue 15).
        Arc::new(Float64Array::from_iter(rows.iter().map(|r| {
            let v = g(r);
            v.is_finite().then_some(v)
        })))
    };
    let columns: Vec<(&str, Arc<dyn Array>)> = vec![
        ("night", text(|r| &r.night)),
        ("observable", text(|r| &r.observable)),
        ("unit", text(|r| &r.unit)),
        ("effect", text(|r| &r.effect)),
        ("machine", text(|r| &r.machine)),
        ("param", text(|r| &r.param)),
        ("value", num(|r| r.value)),
        ("se", num(|r| r.se)),
        ("lo95", num(|r| r.lo95)),
        ("hi95", num(|r| r.hi95)),
        ("shrink", num(|r| r.shrink)),
        ("gap_rms", num(|r| r.gap_rms)),
        ("noise_floor", num(|r| r.noise_floor)),
        ("n_runs", num(|r| r.n_runs)),
    ];
    let schema = Schema::new(
        columns
            .iter()
            .map(|(n, a)| {
                Field::new(
                    *n,
                    a.data_type().clone(),
                    a.data_type() == &DataType::Float64,
                )
            })
            .collect::<Vec<_>>(),
    );
    Ok(RecordBatch::try_new(
        Arc::new(schema),
        columns.into_iter().map(|(_, a)| a).collect(),
    )?)
}

/// Appends (or replaces, atomically) one night's partition.
pub fn append_night(history: &Path, night: &str, diagnosis: &serde_json::Value) -> Result<PathBuf> {
    check_night(night)?;
    let dir = history.join(format!("night={night}"));
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let path = dir.join("diagnosis.parquet");
    write_parquet_atomic(&path, &batch_of(&rows_of(diagnosis, night))?)?;
    Ok(path)
}

/// Every night of a history, oldest first.
pub fn read_history(history: &Path) -> Result<Vec<HistoryRow>> {
    let mut nights: Vec<(String, PathBuf)> = Vec::new();
    let entries = std::fs::read_dir(history).with_context(|| {
        format!(
            "cannot read the history {} (written by `sparkout run --history DIR`)",
            history.display()
        )
    })?;
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        if let Some(night) = name.strip_prefix("night=") {
            if check_night(night).is_ok() {
                nights.push((night.to_string(), e.path().join("diagnosis.parquet")));
            }
        }
    }
    nights.sort();
    if nights.is_empty() {
        bail!(
            "{} holds no night=YYYY-MM-DD/diagnosis.parquet: append nights with `sparkout run --history {}`",
            history.display(),
            history.display()
        );
    }
    let mut rows = Vec::new();
    for (night, path) in nights {
        let batch = crate::contracts::parquet_file::open_parquet(&path)
            .and_then(|b| crate::contracts::parquet_file::read_all(&path, b))?;
        let text = |name: &str| -> Result<Vec<String>> {
            let a = batch.column_by_name(name).ok_or_else(|| {
                crate::InputError::new(&path, "missing history column").column(name)
            })?;
            let a = arrow::compute::cast(a, &DataType::Utf8)?;
            Ok(a.as_string::<i32>()
                .iter()
                .map(|s| s.unwrap_or("").to_string())
                .collect())
        };
        let num = |name: &str| -> Result<Vec<f64>> {
            let a = batch.column_by_name(name).ok_or_else(|| {
                crate::InputError::new(&path, "missing history column").column(name)
            })?;
            let a = arrow::compute::cast(a, &DataType::Float64)?;
            Ok(a.as_primitive::<Float64Type>()
                .iter()
                .map(|v| v.unwrap_or(f64::NAN))
                .collect())
        };
        let (obs, unit, effect, machine, param) = (
            text("observable")?,
            text("unit")?,
            text("effect")?,
            text("machine")?,
            text("param")?,
        );
        let (value, se, lo, hi) = (num("value")?, num("se")?, num("lo95")?, num("hi95")?);
        let (shrink, gap, floor, runs) = (
            num("shrink")?,
            num("gap_rms")?,
            num("noise_floor")?,
            num("n_runs")?,
        );
        for i in 0..batch.num_rows() {
            rows.push(HistoryRow {
                night: night.clone(),
                observable: obs[i].clone(),
                unit: unit[i].clone(),
                effect: effect[i].clone(),
                machine: machine[i].clone(),
                param: param[i].clone(),
                value: value[i],
                se: se[i],
                lo95: lo[i],
                hi95: hi[i],
                shrink: shrink[i],
                gap_rms: gap[i],
                noise_floor: floor[i],
                n_runs: runs[i],
            });
        }
    }
    Ok(rows)
}

#[derive(Debug, Clone, Serialize)]
pub struct Point {
    pub night: String,
    pub value: f64,
    pub se: Option<f64>,
    pub lo95: Option<f64>,
    pub hi95: Option<f64>,
}

#[derive(Debug, Clone, Serialize)]
pub struct TrendSeries {
    pub observable: String,
    pub unit: String,
    pub effect: String,
    /// null: the fleet-wide fit.
    pub machine: Option<String>,
    pub param: String,
    pub points: Vec<Point>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Alert {
    /// "appeared", "disappeared" or "moved".
    pub kind: String,
    pub observable: String,
    pub effect: String,
    pub machine: Option<String>,
    pub param: Option<String>,
    pub night: String,
    /// The night compared with (previous or first).
    pub since: Option<String>,
    pub value: Option<f64>,
    pub since_value: Option<f64>,
    /// |Δ| / √(se_a² + se_b²).
    pub z: Option<f64>,
    pub message: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct Trend {
    pub version: u32,
    pub kind: String,
    pub nights: Vec<String>,
    pub rule: String,
    pub series: Vec<TrendSeries>,
    pub alerts: Vec<Alert>,
}

fn opt(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

/// Series and alerts of a history.
pub fn trend(rows: &[HistoryRow]) -> Trend {
    let nights: Vec<String> = rows
        .iter()
        .map(|r| r.night.clone())
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    // Which observables each night diagnosed, and which effects it selected.
    let mut diagnosed: BTreeMap<&str, BTreeSet<&str>> = BTreeMap::new();
    let mut selected: BTreeMap<(&str, &str), BTreeSet<&str>> = BTreeMap::new();
    type Key = (String, String, String, String);
    let mut series: BTreeMap<Key, (String, Vec<&HistoryRow>)> = BTreeMap::new();
    for r in rows {
        if r.effect.is_empty() {
            diagnosed.entry(&r.night).or_default().insert(&r.observable);
            continue;
        }
        selected
            .entry((&r.observable, &r.effect))
            .or_default()
            .insert(&r.night);
        series
            .entry((
                r.observable.clone(),
                r.effect.clone(),
                r.machine.clone(),
                r.param.clone(),
            ))
            .or_insert_with(|| (r.unit.clone(), Vec::new()))
            .1
            .push(r);
    }
    let mut alerts = Vec::new();
    // Appeared / disappeared: between consecutive nights that both
    // diagnosed the observable.
    for ((obs, effect), on) in &selected {
        for w in nights.windows(2) {
            let (a, b) = (w[0].as_str(), w[1].as_str());
            let both = diagnosed.get(a).is_some_and(|s| s.contains(obs))
                && diagnosed.get(b).is_some_and(|s| s.contains(obs));
            if !both {
                continue;
            }
            let (was, is) = (on.contains(a), on.contains(b));
            if was != is {
                let kind = if is { "appeared" } else { "disappeared" };
                alerts.push(Alert {
                    kind: kind.into(),
                    observable: obs.to_string(),
                    effect: effect.to_string(),
                    machine: None,
                    param: None,
                    night: b.into(),
                    since: Some(a.into()),
                    value: None,
                    since_value: None,
                    z: None,
                    message: format!("{effect} on {obs} {kind} on {b} (not so on {a})"),
                });
            }
        }
    }
    let mut out_series = Vec::new();
    for ((obs, effect, machine, param), (unit, pts)) in &series {
        let points: Vec<Point> = pts
            .iter()
            .map(|r| Point {
                night: r.night.clone(),
                value: r.value,
                se: opt(r.se),
                lo95: opt(r.lo95),
                hi95: opt(r.hi95),
            })
            .collect();
        // Moved: each night against the previous one and the first one.
        for (i, p) in points.iter().enumerate().skip(1) {
            let mut compare = vec![&points[i - 1]];
            if i > 1 {
                compare.push(&points[0]);
            }
            for q in compare {
                let (Some(sa), Some(sb)) = (q.se, p.se) else {
                    continue;
                };
                let scale = (sa * sa + sb * sb).sqrt();
                if scale.is_nan() || scale <= 0.0 || !p.value.is_finite() || !q.value.is_finite() {
                    continue;
                }
                let z = (p.value - q.value).abs() / scale;
                if z > Z95 {
                    let who = if machine.is_empty() {
                        String::new()
                    } else {
                        format!(" on machine {machine}")
                    };
                    alerts.push(Alert {
                        kind: "moved".into(),
                        observable: obs.clone(),
                        effect: effect.clone(),
                        machine: (!machine.is_empty()).then(|| machine.clone()),
                        param: Some(param.clone()),
                        night: p.night.clone(),
                        since: Some(q.night.clone()),
                        value: Some(p.value),
                        since_value: Some(q.value),
                        z: Some(z),
                        message: format!(
                            "{effect} {param} on {obs}{who} moved from {:.4e} ({}) to {:.4e} ({}): {z:.1} standard errors of the difference",
                            q.value, q.night, p.value, p.night
                        ),
                    });
                }
            }
        }
        out_series.push(TrendSeries {
            observable: obs.clone(),
            unit: unit.clone(),
            effect: effect.clone(),
            machine: (!machine.is_empty()).then(|| machine.clone()),
            param: param.clone(),
            points,
        });
    }
    alerts.sort_by(|a, b| {
        (&a.night, &a.kind, &a.observable, &a.effect, &a.since).cmp(&(
            &b.night,
            &b.kind,
            &b.observable,
            &b.effect,
            &b.since,
        ))
    });
    Trend {
        version: TREND_VERSION,
        kind: "sparkout.trend".into(),
        nights,
        rule: format!(
            "moved: |p_b − p_a| > {Z95}·√(se_a² + se_b²) against the previous and the first night; appeared/disappeared: selected on one of two consecutive nights that both diagnosed the observable"
        ),
        series: out_series,
        alerts,
    }
}

/// trend.html: alerts first, then each parameter over nights with its 95 %
/// interval (value, lower and upper bound as three lines; night index on x).
pub fn trend_page(t: &Trend) -> String {
    let mut body = String::new();
    body.push_str(&format!(
        "<p>{} night(s): {} … {}.</p>\n",
        t.nights.len(),
        esc(t.nights.first().map_or("", |s| s.as_str())),
        esc(t.nights.last().map_or("", |s| s.as_str()))
    ));
    body.push_str("<h2>Alerts</h2>\n");
    if t.alerts.is_empty() {
        body.push_str(
            "<p>None: no effect appeared, disappeared or moved beyond its interval.</p>\n",
        );
    } else {
        body.push_str("<ul class=\"alerts\">\n");
        for a in &t.alerts {
            body.push_str(&format!(
                "<li><b>{}</b> {}: {}</li>\n",
                esc(&a.night),
                esc(&a.kind),
                esc(&a.message)
            ));
        }
        body.push_str("</ul>\n");
    }
    body.push_str(&format!("<p><small>Rule: {}</small></p>\n", esc(&t.rule)));
    body.push_str("<h2>Parameters over nights</h2>\n");
    let index: BTreeMap<&str, f64> = t
        .nights
        .iter()
        .enumerate()
        .map(|(i, n)| (n.as_str(), i as f64))
        .collect();
    for s in &t.series {
        let pts = |g: fn(&Point) -> Option<f64>| -> Vec<(f64, f64)> {
            s.points
                .iter()
                .filter_map(|p| Some((index[p.night.as_str()], g(p)?)))
                .collect()
        };
        let value = pts(|p| opt(p.value));
        let lo = pts(|p| p.lo95);
        let hi = pts(|p| p.hi95);
        let who = s
            .machine
            .as_deref()
            .map_or("fleet".to_string(), |m| format!("machine {m}"));
        let title = format!("{} {} on {} ({who})", s.effect, s.param, s.observable);
        body.push_str(&svg::xy_chart_sized(
            &title,
            "night (0 = first)",
            &s.param,
            &[
                svg::Series {
                    name: "value",
                    points: &value,
                    mark: svg::Mark::Points,
                },
                svg::Series {
                    name: "95 % low",
                    points: &lo,
                    mark: svg::Mark::Line,
                },
                svg::Series {
                    name: "95 % high",
                    points: &hi,
                    mark: svg::Mark::Line,
                },
            ],
            (640, 300),
        ));
        body.push('\n');
    }
    page("sparkout trend across nights", &body)
}

/// Reads a history, writes `out/trend.json` and `out/trend.html`.
pub fn write_trend(history: &Path, out: &Path) -> Result<Trend> {
    let t = trend(&read_history(history)?);
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    write_atomic(&out.join("trend.html"), trend_page(&t).as_bytes())?;
    write_json_atomic(&out.join("trend.json"), &t)?;
    Ok(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn night(n: &str, k: f64, se: f64) -> serde_json::Value {
        serde_json::json!({
            "per_observable": [{"observable": "cut_depth", "unit": "mm", "rms_mm": 0.01,
                                "noise_floor_mm": 0.002, "runs": 8, "shrink": 0.7}],
            "effects": [{"name": "wear", "covariate": "removed_mm3", "observable": "cut_depth",
                         "selected": true, "shrink": 0.7, "params": {"k": k},
                         "intervals": {"k": {"se": se, "lo": k - 1.96 * se, "hi": k + 1.96 * se}}}],
            "night": n
        })
    }

    #[test]
    fn nights_are_dates() {
        assert!(check_night("2026-11-25").is_ok());
        for bad in [
            "2026-13-01",
            "26-11-25",
            "2026/11/25",
            "yesterday",
            "2026-11-2x",
        ] {
            assert!(check_night(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_drift_beyond_the_interval_alerts_and_noise_does_not() {
        let mut rows = Vec::new();
        for (i, k) in [1.0e-5, 1.01e-5, 0.99e-5].iter().enumerate() {
            rows.extend(rows_of(
                &night("", *k, 0.05e-5),
                &format!("2026-11-0{}", i + 1),
            ));
        }
        assert!(trend(&rows).alerts.is_empty(), "{:?}", trend(&rows).alerts);
        rows.extend(rows_of(&night("", 1.5e-5, 0.05e-5), "2026-11-04"));
        let t = trend(&rows);
        let moved: Vec<&Alert> = t.alerts.iter().filter(|a| a.kind == "moved").collect();
        assert!(!moved.is_empty(), "{:?}", t.alerts);
        assert!(moved.iter().all(|a| a.night == "2026-11-04"));
        // The effect vanishing from a night that still diagnosed it.
        let mut gone = night("", 1.0e-5, 0.05e-5);
        gone["effects"][0]["selected"] = serde_json::json!(false);
        rows.extend(rows_of(&gone, "2026-11-05"));
        let t = trend(&rows);
        assert!(t
            .alerts
            .iter()
            .any(|a| a.kind == "disappeared" && a.night == "2026-11-05"));
    }
}

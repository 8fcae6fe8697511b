//! The alert rule (docs/diagnosis.md "History and trend").
//!
//! *Moved.* Each (observable, effect, machine, parameter) series is compared
//! with its own baseline: the nights since the series' last event or last
//! alert, on which the effect was material. The baseline's level and its
//! night-to-night spread τ are estimated from those nights —
//! DerSimonian–Laird's between-night variance over the within-night
//! standard errors (the unweighted moment estimate when a night has no
//! standard error) — and τ is never taken below `min_relative_spread` of the
//! level: that floor is the whole spread of a short history (one or two
//! nights cannot estimate one) and keeps a real process's few-per-cent
//! wander from alarming. The mean of the last r nights (r = 1 …
//! `window_nights`, all after the baseline) is tested against the level
//! with z = (x̄ − μ̂) / √(Σse²/r² + τ²/r + var μ̂): one night catches a large
//! step, three catch a smaller one that persists.
//!
//! *Appeared / disappeared.* An effect is present on a night when it is
//! selected and material (not minor, and it explains at least `min_share`
//! of the observable's held-out gap), absent when not selected; it changes
//! state only after `persist_nights` consecutive diagnosed nights agree, so
//! an effect that flickers never alerts.
//!
//! *Per night,* every test (each series and window, each confirmed change of
//! state with its selection p-value) is one of a family: Holm's step-down
//! keeps the chance of any false alert on a stationary night at `alpha`.
//!
//! *Rank.* An alert's size is how much of the observable's gap the change
//! moves, in the observable's unit (moved: the relative change of the
//! parameter times the RMS the effect explains, linear in the parameter;
//! appeared/disappeared: the RMS the effect explains) and as a fraction of
//! the gap. Alerts of a night are ordered by score = fraction ·
//! min(1, |z| / z_full), largest first.

use std::collections::{BTreeMap, BTreeSet};

use serde::{Deserialize, Serialize};

use crate::units::format::{effect_param_unit, show, show_as_written, show_in, show_p};
use statrs::distribution::{ContinuousCDF, Normal};

use super::events::Event;
use super::history::HistoryRow;
use super::{Alert, Point, Trend, TrendSeries, TREND_VERSION};
use crate::config_check::{check_settings, read_section, Check, Section};
use crate::error::Result;

/// `[trend]`: the alert rule's settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrendConfig {
    /// Family-wise false-alarm rate per night (Holm over the night's tests).
    pub alpha: f64,
    /// Smallest night-to-night spread assumed, as a fraction of the
    /// baseline level: the spread of a short history, a floor after.
    pub min_relative_spread: f64,
    /// Consecutive nights an effect must hold before it appears or
    /// disappears.
    pub persist_nights: usize,
    /// Share of the observable's held-out gap an effect must explain to be
    /// material (only material effects appear, disappear or move).
    pub min_share: f64,
    /// Longest run of recent nights whose mean is tested against the
    /// baseline (detects smaller steps that persist).
    pub window_nights: usize,
    /// An alert with |z| at or above this counts its whole size in the rank.
    pub z_full: f64,
}

impl Default for TrendConfig {
    fn default() -> Self {
        TrendConfig {
            alpha: 0.01,
            min_relative_spread: 0.05,
            persist_nights: 2,
            min_share: 0.1,
            window_nights: 3,
            z_full: 5.0,
        }
    }
}

impl Section for TrendConfig {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("alpha", Check::Probability),
        ("min_relative_spread", Check::NonNegative),
        ("persist_nights", Check::WholeIn(1, 30)),
        ("min_share", Check::NonNegative),
        ("window_nights", Check::WholeIn(1, 30)),
        ("z_full", Check::Positive),
    ];
}

impl TrendConfig {
    /// `[trend]` → settings, checked (unknown keys and bad values name the key).
    pub fn from_toml(section: &toml::Table) -> Result<TrendConfig> {
        read_section(section)
    }
    /// Settings built in code, held to the section's checks.
    pub fn check(&self) -> Result<()> {
        check_settings(self)
    }
    fn rule_text(&self) -> String {
        format!(
            "moved: the mean of the last 1–{w} nights against the baseline since the last event or alert, z = (x̄ − μ̂)/√(Σse²/r² + τ²/r + var μ̂), τ² = DerSimonian–Laird between-night variance, τ ≥ {rho}·|μ̂|; appeared/disappeared: selected and explaining ≥ {share} of the gap (or not selected) on {p} consecutive nights; per night Holm at family-wise α = {a}; rank: fraction of the gap · min(1, |z|/{zf})",
            w = self.window_nights,
            rho = self.min_relative_spread,
            share = self.min_share,
            p = self.persist_nights,
            a = self.alpha,
            zf = self.z_full,
        )
    }
}

/// A baseline's level, between-night variance and the variance of the level.
struct Baseline {
    mean: f64,
    tau2: f64,
    var_mean: f64,
}

/// Level and spread of baseline nights (`se` NaN: unknown, taken as 0).
fn baseline(values: &[f64], se: &[f64], rho: f64) -> Option<Baseline> {
    let k = values.len();
    if k == 0 {
        return None;
    }
    let s2: Vec<f64> = se
        .iter()
        .map(|s| if s.is_finite() { s * s } else { 0.0 })
        .collect();
    let plain = values.iter().sum::<f64>() / k as f64;
    let tau2_est = if k < 2 {
        0.0
    } else if s2.iter().all(|s| *s > 0.0) {
        // DerSimonian–Laird.
        let w: Vec<f64> = s2.iter().map(|s| 1.0 / s).collect();
        let sw: f64 = w.iter().sum();
        let sw2: f64 = w.iter().map(|w| w * w).sum();
        let mu_fe = w.iter().zip(values).map(|(w, v)| w * v).sum::<f64>() / sw;
        let q: f64 = w
            .iter()
            .zip(values)
            .map(|(w, v)| w * (v - mu_fe) * (v - mu_fe))
            .sum();
        ((q - (k as f64 - 1.0)) / (sw - sw2 / sw)).max(0.0)
    } else {
        // Moments, unweighted: sample variance less the mean within-night
        // variance.
        let var = values
            .iter()
            .map(|v| (v - plain) * (v - plain))
            .sum::<f64>()
            / (k - 1) as f64;
        (var - s2.iter().sum::<f64>() / k as f64).max(0.0)
    };
    let tau2 = tau2_est.max((rho * plain).powi(2));
    let w: Vec<f64> = s2.iter().map(|s| 1.0 / (s + tau2)).collect();
    if w.iter().any(|w| !w.is_finite()) {
        return None; // no spread at all: nothing to test against
    }
    let sw: f64 = w.iter().sum();
    let mean = w.iter().zip(values).map(|(w, v)| w * v).sum::<f64>() / sw;
    Some(Baseline {
        mean,
        tau2,
        var_mean: 1.0 / sw,
    })
}

fn two_sided_p(z: f64) -> f64 {
    let n = Normal::new(0.0, 1.0).expect("standard normal");
    (2.0 * (1.0 - n.cdf(z.abs()))).clamp(0.0, 1.0)
}

fn z_of_p(p: f64) -> f64 {
    let n = Normal::new(0.0, 1.0).expect("standard normal");
    if !p.is_finite() {
        return f64::NAN;
    }
    n.inverse_cdf(1.0 - (p.max(1e-300) / 2.0).min(0.5))
}

/// Holm's step-down over a family of p-values: the adjusted p-value of
/// each (reject when ≤ alpha).
pub fn holm(p: &[f64]) -> Vec<f64> {
    let m = p.len();
    let mut order: Vec<usize> = (0..m).collect();
    order.sort_by(|a, b| p[*a].total_cmp(&p[*b]).then(a.cmp(b)));
    let mut adj = vec![1.0; m];
    let mut running: f64 = 0.0;
    for (i, &k) in order.iter().enumerate() {
        running = running.max(((m - i) as f64 * p[k]).min(1.0));
        adj[k] = running;
    }
    adj
}

/// One test of a night: a series' recent window, or a confirmed change of
/// an effect's state.
struct Test {
    kind: &'static str,
    obs: String,
    unit: String,
    effect: String,
    machine: String,
    /// The machines the change is on.
    machines: Vec<String>,
    param: Option<String>,
    /// Series index (moved) — one alert per series and night.
    series: Option<usize>,
    /// First night of the change (of the window, or of the run of nights).
    from: String,
    /// First night of the baseline compared with.
    since: Option<String>,
    nights: usize,
    baseline_nights: usize,
    value: Option<f64>,
    baseline: Option<f64>,
    spread: Option<f64>,
    z: f64,
    p: f64,
    size: Option<f64>,
    gap: Option<f64>,
}

fn opt(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

/// Series and ranked alerts of a history. `events` are every deliberate
/// change known (file, flags); config changes between nights are added.
pub fn trend(
    rows: &[HistoryRow],
    events: &[Event],
    notes: Vec<String>,
    cfg: &TrendConfig,
) -> Trend {
    let nights: Vec<String> = rows
        .iter()
        .map(|r| r.night.clone())
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    let mut events: Vec<Event> = events.to_vec();
    events.extend(config_changes(rows, &nights));
    events.sort();
    events.dedup();

    // Per night: the observables diagnosed (their row) and, per
    // (observable, effect), the fleet-wide rows of a selected/minor effect.
    let mut observed: BTreeMap<(&str, &str), &HistoryRow> = BTreeMap::new();
    let mut machines_of: BTreeMap<&str, Vec<String>> = BTreeMap::new();
    let mut effect_rows: BTreeMap<(&str, &str), BTreeMap<&str, &HistoryRow>> = BTreeMap::new();
    type Key = (String, String, String, String);
    let mut series: BTreeMap<Key, (String, Vec<&HistoryRow>)> = BTreeMap::new();
    for r in rows {
        if r.effect.is_empty() {
            observed.insert((&r.night, &r.observable), r);
            let ms = machines_of.entry(&r.observable).or_default();
            for m in r.machines.split(',').filter(|m| !m.is_empty()) {
                if !ms.iter().any(|x| x == m) {
                    ms.push(m.to_string());
                }
            }
            continue;
        }
        if r.machine.is_empty() {
            effect_rows
                .entry((&r.observable, &r.effect))
                .or_default()
                .entry(&r.night)
                .or_insert(r);
        }
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
    let material = |r: &HistoryRow| -> bool {
        if r.minor {
            return false;
        }
        let share = r.explained_rms / r.gap_rms;
        !share.is_finite() || share >= cfg.min_share
    };
    let is_material = |obs: &str, effect: &str, night: &str| -> bool {
        effect_rows
            .get(&(obs, effect))
            .and_then(|m| m.get(night))
            .is_some_and(|r| material(r))
    };
    let no_machines: Vec<String> = Vec::new();
    // The latest night ≤ `night` at which an event resets this series.
    let reset_at = |obs: &str, machine: &str, night: &str| -> Option<String> {
        let ms = machines_of.get(obs).unwrap_or(&no_machines);
        events
            .iter()
            .filter(|e| e.night.as_str() <= night && e.resets(machine, ms))
            .map(|e| e.night.clone())
            .max()
    };

    let on_machines = |obs: &str, machine: &str| -> Vec<String> {
        if machine.is_empty() {
            machines_of.get(obs).cloned().unwrap_or_default()
        } else {
            vec![machine.to_string()]
        }
    };
    let keys: Vec<&Key> = series.keys().collect();
    // Per series: the first night of its current baseline after an alert.
    let mut alert_start: Vec<Option<String>> = vec![None; keys.len()];
    // Per (observable, effect): established state, current run (state,
    // nights, first night), last reset applied.
    struct State {
        state: Option<bool>,
        run: Option<(bool, usize, String)>,
        reset: Option<String>,
    }
    let mut states: BTreeMap<(&str, &str), State> = effect_rows
        .keys()
        .map(|k| {
            (
                *k,
                State {
                    state: None,
                    run: None,
                    reset: None,
                },
            )
        })
        .collect();
    let mut alerts: Vec<Alert> = Vec::new();
    let mut tests_per_night: BTreeMap<String, usize> = BTreeMap::new();
    for night in &nights {
        let mut tests: Vec<Test> = Vec::new();
        // Moved.
        for (si, key) in keys.iter().enumerate() {
            let (obs, effect, machine, param) = key;
            let (unit, pts) = &series[*key];
            let start = [alert_start[si].clone(), reset_at(obs, machine, night)]
                .into_iter()
                .flatten()
                .max();
            let pts: Vec<&&HistoryRow> = pts
                .iter()
                .filter(|r| {
                    r.night.as_str() <= night.as_str()
                        && start.as_deref().is_none_or(|s| r.night.as_str() >= s)
                        && r.value.is_finite()
                        && is_material(obs, effect, &r.night)
                })
                .collect();
            if pts.last().is_none_or(|r| r.night != *night) {
                continue;
            }
            let gap = observed
                .get(&(night.as_str(), obs.as_str()))
                .map_or(f64::NAN, |o| o.gap_rms);
            for r in 1..=cfg.window_nights.min(pts.len().saturating_sub(1)) {
                let (base, recent) = pts.split_at(pts.len() - r);
                let values: Vec<f64> = base.iter().map(|p| p.value).collect();
                let ses: Vec<f64> = base.iter().map(|p| p.se).collect();
                let Some(b) = baseline(&values, &ses, cfg.min_relative_spread) else {
                    continue;
                };
                let rf = r as f64;
                let xbar = recent.iter().map(|p| p.value).sum::<f64>() / rf;
                let se2: f64 = recent
                    .iter()
                    .map(|p| if p.se.is_finite() { p.se * p.se } else { 0.0 })
                    .sum();
                let var = se2 / (rf * rf) + b.tau2 / rf + b.var_mean;
                if var.is_nan() || var <= 0.0 {
                    continue;
                }
                let z = (xbar - b.mean) / var.sqrt();
                let explained: Vec<f64> = base
                    .iter()
                    .map(|p| p.explained_rms)
                    .filter(|e| e.is_finite())
                    .collect();
                let size = (!explained.is_empty() && b.mean != 0.0).then(|| {
                    (xbar - b.mean).abs() / b.mean.abs() * explained.iter().sum::<f64>()
                        / explained.len() as f64
                });
                tests.push(Test {
                    kind: "moved",
                    obs: obs.clone(),
                    unit: unit.clone(),
                    effect: effect.clone(),
                    machine: machine.clone(),
                    machines: on_machines(obs, machine),
                    param: Some(param.clone()),
                    series: Some(si),
                    from: recent[0].night.clone(),
                    since: Some(base[0].night.clone()),
                    nights: r,
                    baseline_nights: base.len(),
                    value: Some(xbar),
                    baseline: Some(b.mean),
                    spread: Some(b.tau2.sqrt()),
                    z,
                    p: two_sided_p(z),
                    size: size.and_then(opt),
                    gap: opt(gap),
                });
            }
        }
        // Appeared / disappeared.
        for ((obs, effect), st) in states.iter_mut() {
            let Some(o) = observed.get(&(night.as_str(), *obs)) else {
                continue; // not diagnosed tonight: no evidence either way
            };
            if let Some(reset) = reset_at(obs, "", night) {
                if st.reset.as_deref() != Some(reset.as_str()) {
                    st.state = None;
                    st.run = None;
                    st.reset = Some(reset);
                }
            }
            let row = effect_rows
                .get(&(*obs, *effect))
                .and_then(|m| m.get(night.as_str()));
            let status = match row {
                None => Some(false),
                Some(r) if material(r) => Some(true),
                Some(_) => None, // selected but not material: neither
            };
            let Some(s) = status else {
                st.run = None;
                continue;
            };
            st.run = match st.run.take() {
                Some((rs, n, first)) if rs == s => Some((rs, n + 1, first)),
                _ => Some((s, 1, night.clone())),
            };
            let (_, n, first) = st.run.clone().expect("set above");
            if n < cfg.persist_nights {
                continue;
            }
            match st.state {
                None => st.state = Some(s),
                Some(prev) if prev != s => {
                    st.state = Some(s);
                    // Its significance: the selection test on the nights it
                    // held (appeared), or on the last night it was present.
                    let held: Vec<&HistoryRow> = effect_rows
                        .get(&(*obs, *effect))
                        .map(|m| {
                            m.iter()
                                .filter(|(n, _)| {
                                    (!s || **n >= first.as_str()) && **n <= night.as_str()
                                })
                                .map(|(_, r)| *r)
                                .collect()
                        })
                        .unwrap_or_default();
                    let p = if s {
                        held.iter().map(|r| r.p_value).fold(f64::NAN, f64::max)
                    } else {
                        held.last().map_or(f64::NAN, |r| r.p_value)
                    };
                    let explained = held.last().map_or(f64::NAN, |r| r.explained_rms);
                    let unit = held.last().map_or(o.unit.clone(), |r| r.unit.clone());
                    let p = if p.is_finite() { p } else { 0.0 };
                    tests.push(Test {
                        kind: if s { "appeared" } else { "disappeared" },
                        obs: obs.to_string(),
                        unit,
                        effect: effect.to_string(),
                        machine: String::new(),
                        machines: on_machines(obs, ""),
                        param: None,
                        series: None,
                        from: first.clone(),
                        since: None,
                        nights: n,
                        baseline_nights: 0,
                        value: None,
                        baseline: None,
                        spread: None,
                        z: z_of_p(p),
                        p,
                        size: opt(explained),
                        gap: opt(o.gap_rms),
                    });
                }
                Some(_) => {}
            }
        }
        tests_per_night.insert(night.clone(), tests.len());
        let adj = holm(&tests.iter().map(|t| t.p).collect::<Vec<_>>());
        // One alert per series: its most significant window.
        let mut best: BTreeMap<usize, usize> = BTreeMap::new();
        let mut changes: Vec<usize> = Vec::new();
        for (i, t) in tests.iter().enumerate() {
            if adj[i] > cfg.alpha {
                continue;
            }
            match t.series {
                Some(si) => {
                    let e = best.entry(si).or_insert(i);
                    if t.z.abs() > tests[*e].z.abs() {
                        *e = i;
                    }
                }
                None => changes.push(i),
            }
        }
        let m = tests.len();
        for i in best.values().chain(&changes) {
            let t = &tests[*i];
            if let Some(si) = t.series {
                // The series compares with its new level from here on.
                alert_start[si] = Some(t.from.clone());
            }
            alerts.push(alert_of(t, night, adj[*i], m, cfg));
        }
    }
    // Newest night first; within a night by score, largest first.
    alerts.sort_by(|a, b| {
        b.night
            .cmp(&a.night)
            .then(b.score.total_cmp(&a.score))
            .then(
                (&a.kind, &a.observable, &a.effect, &a.machine, &a.param).cmp(&(
                    &b.kind,
                    &b.observable,
                    &b.effect,
                    &b.machine,
                    &b.param,
                )),
            )
    });
    let mut rank = 0;
    for i in 0..alerts.len() {
        rank = if i > 0 && alerts[i - 1].night == alerts[i].night {
            rank + 1
        } else {
            1
        };
        alerts[i].rank = rank;
    }
    let out_series = series
        .iter()
        .map(|((obs, effect, machine, param), (unit, pts))| TrendSeries {
            observable: obs.clone(),
            unit: unit.clone(),
            effect: effect.clone(),
            machine: (!machine.is_empty()).then(|| machine.clone()),
            param: param.clone(),
            points: pts
                .iter()
                .filter(|r| r.value.is_finite())
                .map(|r| Point {
                    night: r.night.clone(),
                    value: r.value,
                    se: opt(r.se),
                    lo95: opt(r.lo95),
                    hi95: opt(r.hi95),
                    material: is_material(obs, effect, &r.night),
                })
                .collect(),
        })
        .collect();
    Trend {
        version: TREND_VERSION,
        kind: "sparkout.trend".into(),
        nights,
        rule: cfg.rule_text(),
        settings: cfg.clone(),
        events,
        notes,
        tests_per_night,
        series: out_series,
        alerts,
    }
}

/// A gap in the observable's unit: nm/µm/mm (or mm/s) by magnitude for
/// the units sparkout converts from, three significant digits otherwise.
fn gap_text(v: f64, unit: &str) -> String {
    match unit {
        "mm" | "mm/s" => show_in(v, unit),
        _ => show_as_written(v, unit),
    }
}

/// `= 0.012` or `< 0.001`.
fn p_text(p: f64) -> String {
    let s = show_p(p);
    if s.starts_with('<') {
        s
    } else {
        format!("= {s}")
    }
}

fn alert_of(t: &Test, night: &str, p_adj: f64, m: usize, cfg: &TrendConfig) -> Alert {
    let fraction = match (t.size, t.gap) {
        (Some(s), Some(g)) if g > 0.0 => Some(s / g),
        _ => None,
    };
    let weight = if t.z.is_finite() {
        (t.z.abs() / cfg.z_full).min(1.0)
    } else {
        1.0
    };
    let score = fraction.unwrap_or(0.0) * weight;
    let who = match t.machines.as_slice() {
        [m] => format!(" on machine {m}"),
        _ => String::new(),
    };
    let size_text = match (t.size, fraction) {
        (Some(s), Some(f)) => format!("{} = {:.0} % of the gap", gap_text(s, &t.unit), 100.0 * f),
        _ => "size unknown".into(),
    };
    // Parameter values in the parameter's engineer unit, one for all three.
    let pu = effect_param_unit(&t.effect, t.param.as_deref().unwrap_or(""), &t.unit);
    let param_text = |v: f64| match &pu {
        Some(u) => show(v, u),
        None => show_as_written(v, ""),
    };
    let message = match t.kind {
        "moved" => {
            let (v, b) = (t.value.unwrap_or(f64::NAN), t.baseline.unwrap_or(f64::NAN));
            format!(
                "{} {} on {}{who} moved {:+.0} % ({} → {}; {} night(s) from {} against {} baseline night(s) from {}, spread ±{}): {size_text}; z = {:.1}, Holm p {} over {m} tests",
                t.effect,
                t.param.as_deref().unwrap_or(""),
                t.obs,
                100.0 * (v - b) / b.abs(),
                param_text(b),
                param_text(v),
                t.nights,
                t.from,
                t.baseline_nights,
                t.since.as_deref().unwrap_or("?"),
                param_text(t.spread.unwrap_or(f64::NAN)),
                t.z,
                p_text(p_adj)
            )
        }
        kind => format!(
            "{} on {}{who} {kind} (held {} nights from {}): {size_text}; Holm p {} over {m} tests",
            t.effect,
            t.obs,
            t.nights,
            t.from,
            p_text(p_adj)
        ),
    };
    Alert {
        rank: 0,
        kind: t.kind.into(),
        observable: t.obs.clone(),
        unit: t.unit.clone(),
        effect: t.effect.clone(),
        machine: (!t.machine.is_empty()).then(|| t.machine.clone()),
        machines: t.machines.clone(),
        param: t.param.clone(),
        night: night.into(),
        from_night: t.from.clone(),
        nights: t.nights,
        since: t.since.clone(),
        value: t.value.and_then(opt),
        baseline: t.baseline.and_then(opt),
        spread: t.spread.and_then(opt),
        size: t.size,
        gap_rms: t.gap,
        fraction_of_gap: fraction.and_then(opt),
        z: opt(t.z),
        p_value: opt(t.p),
        p_holm: opt(p_adj),
        tests: m,
        score,
        message,
    }
}

/// A night whose settings (or the sparkout models behind them: stage and
/// diagnosis versions, the plugins' effects) differ from the night before
/// is a config event.
fn config_changes(rows: &[HistoryRow], nights: &[String]) -> Vec<Event> {
    let mut config: BTreeMap<&str, &str> = BTreeMap::new();
    for r in rows {
        if !r.config.is_empty() {
            config.entry(&r.night).or_insert(&r.config);
        }
    }
    let mut out = Vec::new();
    for w in nights.windows(2) {
        if let (Some(a), Some(b)) = (config.get(w[0].as_str()), config.get(w[1].as_str())) {
            if a != b {
                out.push(Event {
                    night: w[1].clone(),
                    machine: String::new(),
                    kind: "config".into(),
                    note: format!(
                        "settings or sparkout's models differ from {}'s ({a} → {b})",
                        w[0]
                    ),
                    source: "history".into(),
                });
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn holm_adjusts_step_down() {
        let adj = holm(&[0.01, 0.04, 0.03, 0.5]);
        assert!((adj[0] - 0.04).abs() < 1e-12);
        assert!((adj[2] - 0.09).abs() < 1e-12);
        assert!((adj[1] - 0.09).abs() < 1e-12, "monotone: {adj:?}");
        assert!((adj[3] - 0.5).abs() < 1e-12);
    }

    #[test]
    fn baseline_spread_is_between_night_and_floored() {
        // Nights far apart relative to their se: τ² ≈ sample variance.
        let v = [1.0, 1.2, 0.8, 1.1, 0.9];
        let b = baseline(&v, &[0.001; 5], 0.0).unwrap();
        assert!((b.tau2 - 0.025).abs() < 0.002, "{}", b.tau2);
        // Nights that agree within se: τ² = 0, so the floor holds.
        let b = baseline(&[1.0, 1.0001, 0.9999], &[0.01; 3], 0.05).unwrap();
        assert!((b.tau2.sqrt() - 0.05).abs() < 1e-6);
        // One night: the floor alone.
        let b = baseline(&[2.0], &[f64::NAN], 0.05).unwrap();
        assert!((b.tau2.sqrt() - 0.1).abs() < 1e-12);
        assert!(baseline(&[0.0], &[f64::NAN], 0.05).is_none());
    }
}

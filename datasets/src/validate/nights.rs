//! `sparkout validate --nights`: the trend's alert rule measured on
//! generated nights. A night-fleet is four machines, each with its own
//! observable and dominant effect (and the servo with a weak secondary
//! effect that comes and goes); each night draws new runs (new seeds) from
//! the same effects, is diagnosed as `sparkout run` diagnoses a fleet, and
//! goes into a history whose trend is computed as `run --history` does.
//! Sequences: stationary (every alert is false), a step of 20, 40 or 100 %
//! in the form machine's wear rate (the dominant effect of its
//! observable), a gradual drift of that rate, and a step at a recorded
//! wheel change (an event: no alert expected).

use std::collections::BTreeMap;
use std::fmt::Write;
use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sparkout_pipeline::config_check::Checked;
use sparkout_pipeline::diagnose::{diagnose_checked, DiagnoseConfig, Diagnosis};
use sparkout_pipeline::report::trend::{rows_of, trend, Event, HistoryRow, TrendConfig};
use sparkout_pipeline::{EffectSpec, Result};

use super::mix;
use crate::observations::{
    apply_effect, layout, noise, scale_spec, scale_to_snr, to_batch, ObsFleetConfig,
};

/// The machines of a night-fleet: (machine, observable, effect, SNR).
/// The first is the one whose effect steps and drifts.
pub const NIGHT_FLEET: [(&str, &str, &str, f64); 5] = [
    ("form-1", "profile_error", "wear:removed_mm3", 10.0),
    ("servo-1", "following_error", "drift:t_s", 10.0),
    ("servo-1", "following_error", "periodic:x_mm", 1.5),
    ("gantry-1", "bow_z", "thermal:temp_c", 10.0),
    ("guideway-1", "straightness", "bow:y_mm", 10.0),
];

/// The stepped series.
const STEP_OBSERVABLE: &str = "profile_error";
const STEP_EFFECT: &str = "wear:removed_mm3";

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct NightsConfig {
    pub quick: bool,
    pub seed: u64,
    /// Stationary sequences and their nights.
    pub stationary_sequences: usize,
    pub stationary_nights: usize,
    /// Relative step sizes, and sequences per size.
    pub step_sizes: Vec<f64>,
    pub step_sequences: usize,
    /// Nights before the change, and after it (steps, drifts, events).
    pub before_nights: usize,
    pub after_nights: usize,
    /// Drift: relative growth of the wear rate per night; sequences.
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub drift_per_night: f64,
    pub drift_sequences: usize,
    /// Event sequences: a 100 % step at a recorded wheel change.
    pub event_sequences: usize,
    pub fleet: ObsFleetConfig,
    pub diagnose: DiagnoseConfig,
    pub trend: TrendConfig,
}

impl NightsConfig {
    /// The full run, or `--quick` (a stationary sequence, a 40 % step and
    /// an event: what the test suite runs).
    pub fn new(quick: bool, seed: u64) -> Self {
        NightsConfig {
            quick,
            seed,
            stationary_sequences: if quick { 1 } else { 12 },
            stationary_nights: if quick { 6 } else { 8 },
            step_sizes: if quick {
                vec![0.4]
            } else {
                vec![0.2, 0.4, 1.0]
            },
            step_sequences: if quick { 1 } else { 6 },
            before_nights: if quick { 4 } else { 5 },
            after_nights: if quick { 2 } else { 4 },
            drift_per_night: 0.05,
            drift_sequences: if quick { 0 } else { 6 },
            event_sequences: 1.max(if quick { 1 } else { 6 }),
            fleet: ObsFleetConfig {
                runs: 4,
                ..ObsFleetConfig::default()
            },
            diagnose: DiagnoseConfig::default(),
            trend: TrendConfig::default(),
        }
    }
}

/// An alert as the harness scores it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AlertBrief {
    /// Night index in the sequence (0 = first).
    pub night: usize,
    pub rank: usize,
    pub kind: String,
    pub observable: String,
    pub effect: String,
    pub param: Option<String>,
    pub fraction_of_gap: Option<f64>,
    pub z: Option<f64>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SequenceResult {
    /// "stationary", "step", "drift" or "event".
    pub kind: String,
    /// Step size, or drift per night (relative).
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub size: f64,
    pub seed: u64,
    pub nights: usize,
    /// Night index of the change (none: stationary).
    pub change_night: Option<usize>,
    pub alerts: Vec<AlertBrief>,
    /// Nights from the change to the first alert on the stepped series
    /// (0: the night it happens).
    pub delay_nights: Option<usize>,
    /// That alert was rank 1 of its night.
    pub first_of_night: Option<bool>,
    /// Alerts that are not the stepped series' change (every alert of a
    /// stationary sequence; of an event sequence, every alert).
    pub false_alerts: usize,
    /// Nights that could alert (all but the first).
    pub tested_nights: usize,
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub seconds: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StepSummary {
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub size: f64,
    pub sequences: usize,
    pub detected: usize,
    /// Detected on the night of the step / within three nights.
    pub same_night: usize,
    pub within_three: usize,
    pub first_of_night: usize,
    pub delay_median: Option<usize>,
    pub delay_max: Option<usize>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct NightsReport {
    pub config: NightsConfig,
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub seconds: f64,
    pub stationary_night_fleets: usize,
    pub stationary_tested: usize,
    pub stationary_false_alerts: usize,
    /// Alerts per 100 stationary night-fleets that could alert.
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub false_alerts_per_100: f64,
    pub steps: Vec<StepSummary>,
    pub drift: Option<StepSummary>,
    pub event_sequences: usize,
    /// Alerts on event sequences (a deliberate change: none expected).
    pub event_alerts: usize,
    /// False alerts on step and drift sequences (other series, or before
    /// the change).
    pub other_false_alerts: usize,
    pub results: Vec<SequenceResult>,
}

struct Sequence {
    kind: &'static str,
    size: f64,
    seed: u64,
    nights: usize,
    change: Option<usize>,
}

impl Sequence {
    /// The stepped effect's factor on night `n`.
    fn factor(&self, n: usize) -> f64 {
        match (self.kind, self.change) {
            ("drift", Some(c)) if n >= c => 1.0 + self.size * (n - c + 1) as f64,
            ("step" | "event", Some(c)) if n >= c => 1.0 + self.size,
            _ => 1.0,
        }
    }
}

/// Night `n` of a sequence as a date (consecutive days from 2026-01-01).
fn date(n: usize) -> String {
    const DAYS: [usize; 12] = [31, 28, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31];
    let mut d = n % 365;
    let mut m = 0;
    while d >= DAYS[m] {
        d -= DAYS[m];
        m += 1;
    }
    format!("2026-{:02}-{:02}", m + 1, d + 1)
}

/// Each machine's effect, sized once (on a reference layout) so that every
/// night carries the same effect and only the runs change.
fn fleet_specs(cfg: &NightsConfig) -> Result<Vec<EffectSpec>> {
    NIGHT_FLEET
        .iter()
        .enumerate()
        .map(|(i, (_, _, effect, snr))| {
            let l = layout(&ObsFleetConfig {
                seed: mix(cfg.seed, 7000 + i as u64, 0, 0),
                ..cfg.fleet.clone()
            })?;
            let s: EffectSpec = effect.parse().map_err(crate::Error::msg)?;
            Ok(scale_to_snr(&s, &l, *snr, cfg.fleet.noise_mm)?.0)
        })
        .collect()
}

/// One night's diagnosis.json of the night-fleet, the first effect scaled
/// by `factor`.
fn night_diagnosis(
    cfg: &NightsConfig,
    dcfg: &Checked<DiagnoseConfig>,
    specs: &[EffectSpec],
    seed: u64,
    factor: f64,
) -> Result<Diagnosis> {
    let mut batches = Vec::new();
    // Machine → its observable and the indices of its effects.
    let mut machines: BTreeMap<&str, (&str, Vec<usize>)> = BTreeMap::new();
    for (i, (m, obs, _, _)) in NIGHT_FLEET.iter().enumerate() {
        machines.entry(m).or_insert((obs, Vec::new())).1.push(i);
    }
    for (mi, (machine, (obs, fx))) in machines.iter().enumerate() {
        let fleet = ObsFleetConfig {
            seed: mix(seed, 8000 + mi as u64, 0, 0),
            ..cfg.fleet.clone()
        };
        let l = layout(&fleet)?;
        let mut real: Vec<f64> = l
            .sim
            .iter()
            .zip(noise(&fleet, l.len()))
            .map(|(s, n)| s + n)
            .collect();
        for i in fx {
            // Effect 0 (the form's wear) is the one that steps.
            let s = scale_spec(&specs[*i], if *i == 0 { factor } else { 1.0 });
            for (r, e) in real.iter_mut().zip(apply_effect(&s, &l)?) {
                *r += e;
            }
        }
        let b = to_batch(&l, &real, obs)?;
        batches.push(sparkout_pipeline::engine::with_machine_column(b, machine)?);
    }
    let batch = arrow::compute::concat_batches(&batches[0].schema(), &batches)?;
    let out = diagnose_checked(batch, dcfg, &[])?;
    Ok(out.diagnosis)
}

fn run_sequence(
    cfg: &NightsConfig,
    dcfg: &Checked<DiagnoseConfig>,
    specs: &[EffectSpec],
    sq: &Sequence,
) -> Result<SequenceResult> {
    let start = Instant::now();
    let mut rows: Vec<HistoryRow> = Vec::new();
    for n in 0..sq.nights {
        let d = night_diagnosis(
            cfg,
            dcfg,
            specs,
            mix(sq.seed, n as u64 + 1, 0, 0),
            sq.factor(n),
        )?;
        rows.extend(rows_of(&d, &date(n), "validate"));
    }
    let events: Vec<Event> = match (sq.kind, sq.change) {
        ("event", Some(c)) => vec![Event {
            night: date(c),
            machine: NIGHT_FLEET[0].0.into(),
            kind: "wheel_change".into(),
            note: "generated".into(),
            source: "--event".into(),
        }],
        _ => Vec::new(),
    };
    let t = trend(&rows, &events, Vec::new(), &cfg.trend);
    let index: BTreeMap<String, usize> = (0..sq.nights).map(|n| (date(n), n)).collect();
    let alerts: Vec<AlertBrief> = t
        .alerts
        .iter()
        .map(|a| AlertBrief {
            night: index[&a.night],
            rank: a.rank,
            kind: a.kind.clone(),
            observable: a.observable.clone(),
            effect: a.effect.clone(),
            param: a.param.clone(),
            fraction_of_gap: a.fraction_of_gap,
            z: a.z,
        })
        .collect();
    let hit = |a: &AlertBrief| -> bool {
        matches!(sq.kind, "step" | "drift")
            && sq.change.is_some_and(|c| a.night >= c)
            && a.kind == "moved"
            && a.observable == STEP_OBSERVABLE
            && a.effect == STEP_EFFECT
            && a.param.as_deref() == Some("k")
    };
    let first = alerts.iter().filter(|a| hit(a)).min_by_key(|a| a.night);
    Ok(SequenceResult {
        kind: sq.kind.into(),
        size: sq.size,
        seed: sq.seed,
        nights: sq.nights,
        change_night: sq.change,
        delay_nights: first.map(|a| a.night - sq.change.unwrap_or(0)),
        first_of_night: first.map(|a| a.rank == 1),
        false_alerts: alerts.iter().filter(|a| !hit(a)).count(),
        tested_nights: sq.nights.saturating_sub(1),
        alerts,
        seconds: start.elapsed().as_secs_f64(),
    })
}

fn step_summary(size: f64, rs: &[&SequenceResult]) -> StepSummary {
    let mut delays: Vec<usize> = rs.iter().filter_map(|r| r.delay_nights).collect();
    delays.sort_unstable();
    StepSummary {
        size,
        sequences: rs.len(),
        detected: delays.len(),
        same_night: delays.iter().filter(|d| **d == 0).count(),
        within_three: delays.iter().filter(|d| **d <= 2).count(),
        first_of_night: rs.iter().filter(|r| r.first_of_night == Some(true)).count(),
        delay_median: delays.get(delays.len() / 2).copied(),
        delay_max: delays.last().copied(),
    }
}

/// Runs every sequence (rayon over sequences; results in a fixed order).
pub fn run(cfg: &NightsConfig) -> Result<NightsReport> {
    // `[diagnose]` checked once for every night's diagnosis.
    let dcfg = cfg.diagnose.clone().checked()?;
    cfg.trend.check()?;
    let start = Instant::now();
    let specs = fleet_specs(cfg)?;
    let changed = cfg.before_nights + cfg.after_nights;
    let mut seqs = Vec::new();
    for i in 0..cfg.stationary_sequences {
        seqs.push(Sequence {
            kind: "stationary",
            size: 0.0,
            seed: mix(cfg.seed, 100, i as u64, 0),
            nights: cfg.stationary_nights,
            change: None,
        });
    }
    for (si, size) in cfg.step_sizes.iter().enumerate() {
        for i in 0..cfg.step_sequences {
            seqs.push(Sequence {
                kind: "step",
                size: *size,
                seed: mix(cfg.seed, 200 + si as u64, i as u64, 0),
                nights: changed,
                change: Some(cfg.before_nights),
            });
        }
    }
    for i in 0..cfg.drift_sequences {
        seqs.push(Sequence {
            kind: "drift",
            size: cfg.drift_per_night,
            seed: mix(cfg.seed, 300, i as u64, 0),
            nights: cfg.before_nights + 2 * cfg.after_nights,
            change: Some(cfg.before_nights),
        });
    }
    for i in 0..cfg.event_sequences {
        seqs.push(Sequence {
            kind: "event",
            size: 1.0,
            seed: mix(cfg.seed, 400, i as u64, 0),
            nights: changed,
            change: Some(cfg.before_nights),
        });
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .stack_size(256 << 20)
        .build()?;
    let results: Vec<SequenceResult> = pool.install(|| {
        seqs.par_iter()
            .map(|s| run_sequence(cfg, &dcfg, &specs, s))
            .collect::<Result<_>>()
    })?;
    let of = |kind: &str| -> Vec<&SequenceResult> {
        results.iter().filter(|r| r.kind == kind).collect()
    };
    let stationary = of("stationary");
    let tested: usize = stationary.iter().map(|r| r.tested_nights).sum();
    let false_alerts: usize = stationary.iter().map(|r| r.false_alerts).sum();
    let steps = cfg
        .step_sizes
        .iter()
        .map(|s| {
            let rs: Vec<&SequenceResult> =
                of("step").into_iter().filter(|r| r.size == *s).collect();
            step_summary(*s, &rs)
        })
        .collect();
    let drift = (cfg.drift_sequences > 0).then(|| step_summary(cfg.drift_per_night, &of("drift")));
    let events = of("event");
    let report = NightsReport {
        config: cfg.clone(),
        seconds: start.elapsed().as_secs_f64(),
        stationary_night_fleets: stationary.iter().map(|r| r.nights).sum(),
        stationary_tested: tested,
        stationary_false_alerts: false_alerts,
        false_alerts_per_100: 100.0 * false_alerts as f64 / tested.max(1) as f64,
        steps,
        drift,
        event_sequences: events.len(),
        event_alerts: events.iter().map(|r| r.alerts.len()).sum(),
        other_false_alerts: of("step")
            .iter()
            .chain(&of("drift"))
            .map(|r| r.false_alerts)
            .sum(),
        results: results.clone(),
    };
    Ok(report)
}

/// The report as text.
pub fn render_text(r: &NightsReport) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "validate --nights{}: seed {}, {:.1} s",
        if r.config.quick { " --quick" } else { "" },
        r.config.seed,
        r.seconds
    );
    let _ = writeln!(
        s,
        "stationary: {} false alert(s) over {} night-fleets ({} that could alert): {:.2} per 100",
        r.stationary_false_alerts,
        r.stationary_night_fleets,
        r.stationary_tested,
        r.false_alerts_per_100
    );
    let line = |s: &mut String, label: String, st: &StepSummary| {
        let _ = writeln!(
            s,
            "{label}: detected {}/{} (same night {}, within three nights {}), first alert of its night {}, delay median {} max {} nights",
            st.detected,
            st.sequences,
            st.same_night,
            st.within_three,
            st.first_of_night,
            st.delay_median.map_or("-".into(), |d| d.to_string()),
            st.delay_max.map_or("-".into(), |d| d.to_string()),
        );
    };
    for st in &r.steps {
        line(&mut s, format!("step {:.0} %", 100.0 * st.size), st);
    }
    if let Some(d) = &r.drift {
        line(&mut s, format!("drift {:.0} %/night", 100.0 * d.size), d);
    }
    let _ = writeln!(
        s,
        "event (100 % step at a recorded wheel change): {} alert(s) over {} sequence(s)",
        r.event_alerts, r.event_sequences
    );
    let _ = writeln!(
        s,
        "other alerts on step/drift sequences (other series or before the change): {}",
        r.other_false_alerts
    );
    s
}

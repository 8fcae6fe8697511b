//! `sparkout validate` (docs/validation.md; checked on data whose
//! effect is withheld): fleets whose `real` carries one effect that `sim`
//! lacks — every catalogue effect at several SNRs (effect RMS / noise σ) —
//! plus effect-free fleets and out-of-catalogue fleets, each diagnosed, then
//! scored: confusion matrix (true × top-1 named), localisation (share of the
//! true effect's energy inside the reported `where` cells), parameter
//! recovery, held-out shrink against the oracle 1 − σ/√(σ² + effect_rms²),
//! false alarms, and confident wrong names on out-of-catalogue effects
//! (a selection whose unexplained RMS is below 1.5 σ).

use std::collections::BTreeMap;
use std::fmt::Write;
use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sparkout_pipeline::config_check::Checked;
use sparkout_pipeline::diagnose::{
    diagnose_checked, CellBound, DiagnoseConfig, Diagnosis, WhereCell,
};
use sparkout_pipeline::{EffectSpec, Result};

use crate::observations::{
    apply_effect, layout, noise, resolved_spec, rms, scale_to_snr, to_batch, ObsFleetConfig,
    ObsLayout,
};

mod score;
use score::*;
mod summary;
pub use summary::*;
pub mod nights;

/// Catalogue effects validated, on the covariate the generator gives each.
pub const CATALOGUE_CASES: [&str; 15] = [
    "offset",
    "scale:x_mm",
    "drift:t_s",
    "lag:feed_mm_s",
    "inertia:a_mm_s2",
    "backlash:dir",
    "wear:removed_mm3",
    "wear:pass",
    "compliance:force_n",
    "bow:y_mm",
    "periodic:x_mm",
    "periodic:t_s",
    "edge:path_end_mm",
    "squareness:x_mm,y_mm",
    "thermal:temp_c",
];

/// Out-of-catalogue effects: a step at an unknown position, a local bump, a
/// product of two non-position covariates.
pub const OOC_CASES: [&str; 3] = ["step:x_mm", "bump:x_mm,y_mm", "product:feed_mm_s,force_n"];

/// Two effects at once (each at SNR 10/√2, both must be
/// named), one effect under 1 % ±30σ spikes (named, its interval holding
/// the truth, robust shrink near the spike-free oracle), and one effect on
/// one of three machines only (localised to that machine).
pub const TWO_EFFECT_CASES: [&str; 2] = ["drift:t_s+wear:removed_mm3", "scale:x_mm+thermal:temp_c"];
pub const SPIKE_CASES: [&str; 2] = ["wear:removed_mm3", "drift:t_s"];
pub const ONE_MACHINE_CASES: [&str; 1] = ["wear:removed_mm3"];
/// The machine that carries the effect in one-machine fleets (of m0, m1, m2).
const EFFECT_MACHINE: &str = "m1";

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ValidateConfig {
    pub quick: bool,
    pub seed: u64,
    /// SNRs of the catalogue fleets.
    pub snrs: Vec<f64>,
    /// Fleets per (effect, SNR).
    pub fleets_per_case: usize,
    /// Restrict to these catalogue cases (keys of [`CATALOGUE_CASES`]).
    pub effects: Option<Vec<String>>,
    pub free_fleets: usize,
    /// Fleets per out-of-catalogue effect (SNR 10); 0 skips them.
    pub ooc_fleets: usize,
    /// Fleets per two-effect, spike and one-machine case; 0 skips them.
    pub mixed_fleets: usize,
    pub fleet: ObsFleetConfig,
    pub diagnose: DiagnoseConfig,
    /// Research (`--cells B`): the diagnosis sees each covariate rounded to
    /// the centre of one of B equal cells across its fleet range (`pass`
    /// and `dir` are whole already); the effect is made from the exact
    /// values. None: the exact covariates.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cells: Option<usize>,
}

impl ValidateConfig {
    /// The full run (< 5 min release on 2 cores) or `--quick` (< 30 s).
    pub fn new(quick: bool, seed: u64) -> Self {
        ValidateConfig {
            quick,
            seed,
            snrs: vec![1.0, 3.0, 10.0],
            fleets_per_case: if quick { 1 } else { 10 },
            effects: None,
            free_fleets: if quick { 4 } else { 20 },
            ooc_fleets: if quick { 1 } else { 5 },
            mixed_fleets: if quick { 1 } else { 5 },
            fleet: ObsFleetConfig::default(),
            diagnose: DiagnoseConfig::default(),
            cells: None,
        }
    }
}

impl Default for ValidateConfig {
    fn default() -> Self {
        Self::new(false, 0)
    }
}

/// One diagnosed fleet.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FleetResult {
    /// `effect:covariate`, or "none" for effect-free fleets.
    pub truth: String,
    pub kind: String,
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub snr: f64,
    pub seed: u64,
    /// First selected effect, or "none".
    pub named: String,
    pub selected: Vec<String>,
    pub localisation: Option<f64>,
    pub param_rel_error: Option<f64>,
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub shrink: f64,
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub oracle_shrink: f64,
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub unexplained_over_sigma: f64,
    /// Parameters of the named true effect whose 95 % interval was checked,
    /// and how many held the true value.
    pub intervals_checked: usize,
    pub intervals_covered: usize,
    /// Two-effect fleets: both true effects among the selected.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub all_named: Option<bool>,
    /// Spike fleets: the diagnosis's robust held-out shrink of the
    /// observable (outliers trimmed), against `oracle_shrink`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub robust_shrink: Option<f64>,
    /// One-machine fleets: a `where` cell over `machine` names the machine
    /// that carries the effect.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub machine_localised: Option<bool>,
    /// One-machine fleets: the true effect among `machine_effects` of that
    /// machine.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub machine_named: Option<bool>,
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub seconds: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CaseSummary {
    pub truth: String,
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub snr: f64,
    pub fleets: usize,
    pub top1_correct: usize,
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub accuracy: f64,
    pub localisation_mean: Option<f64>,
    pub param_rel_error_median: Option<f64>,
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub shrink_mean: f64,
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub oracle_shrink: f64,
    /// Mean over fleets of shrink / oracle.
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub shrink_over_oracle: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ValidationReport {
    pub quick: bool,
    pub seed: u64,
    pub fleets: usize,
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub seconds: f64,
    pub cases: Vec<CaseSummary>,
    /// SNR label → true effect → named effect → count.
    pub confusion: BTreeMap<String, BTreeMap<String, BTreeMap<String, usize>>>,
    /// Top-1 accuracy per SNR label.
    pub accuracy_by_snr: BTreeMap<String, f64>,
    /// Over SNR ≥ 3.
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub accuracy_snr_ge3: f64,
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub shrink_over_oracle_snr_ge3: f64,
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub false_alarm_rate: f64,
    pub free_fleets: usize,
    #[serde(deserialize_with = "sparkout_pipeline::files::json::f64_or_nan")]
    pub confident_wrong_rate: f64,
    pub ooc_fleets: usize,
    /// Out-of-catalogue: mean share of the effect's energy inside `where`.
    pub ooc_localisation_mean: Option<f64>,
    /// Share of checked 95 % parameter intervals that hold the true value
    /// (target 90–99 %), over catalogue fleets whose effect was named.
    pub interval_coverage: Option<f64>,
    pub intervals_checked: usize,
    /// Two-effect fleets where both effects were named, and their mean
    /// shrink / oracle.
    pub two_effects_fleets: usize,
    pub two_effects_all_named_rate: Option<f64>,
    pub two_effects_shrink_over_oracle: Option<f64>,
    /// Spike fleets: top-1 correct, the 95 % interval holding the truth,
    /// and the robust shrink / the spike-free oracle.
    pub spike_fleets: usize,
    pub spike_named_rate: Option<f64>,
    pub spike_interval_coverage: Option<f64>,
    pub spike_robust_shrink_over_oracle: Option<f64>,
    /// One-machine fleets: localised to the machine; named on that machine
    /// (`machine_effects`).
    pub one_machine_fleets: usize,
    pub one_machine_localised_rate: Option<f64>,
    pub one_machine_named_rate: Option<f64>,
    pub results: Vec<FleetResult>,
}

struct Job {
    truth: String,
    kind: &'static str,
    snr: f64,
    seed: u64,
}

fn run_fleet(
    cfg: &ValidateConfig,
    dcfg: &Checked<DiagnoseConfig>,
    job: &Job,
) -> Result<FleetResult> {
    let start = Instant::now();
    let fleet = ObsFleetConfig {
        seed: job.seed,
        ..cfg.fleet.clone()
    };
    let sigma = fleet.noise_mm;
    let l = layout(&fleet)?;
    // Each run's machine (round robin over m0, m1, m2) in one-machine fleets.
    let machine_of_row: Option<Vec<String>> = (job.kind == "one_machine").then(|| {
        let mut runs: Vec<&String> = l.run.iter().collect();
        runs.sort();
        runs.dedup();
        l.run
            .iter()
            .map(|r| format!("m{}", runs.binary_search(&r).unwrap_or(0) % 3))
            .collect()
    });
    let parts: Vec<&str> = if job.truth == "none" {
        Vec::new()
    } else {
        job.truth.split('+').collect()
    };
    let part_snr = job.snr / (parts.len().max(1) as f64).sqrt();
    let mut spec = None;
    let mut effect = vec![0.0; l.len()];
    for part in &parts {
        let s: EffectSpec = part.parse().map_err(crate::Error::msg)?;
        let s = resolved_spec(&s, &l)?;
        let (s, v) = scale_to_snr(&s, &l, part_snr, sigma)?;
        debug_assert_eq!(apply_effect(&s, &l)?.len(), v.len());
        for (e, x) in effect.iter_mut().zip(&v) {
            *e += x;
        }
        spec.get_or_insert(s);
    }
    if let Some(m) = &machine_of_row {
        for (e, mi) in effect.iter_mut().zip(m) {
            if mi != EFFECT_MACHINE {
                *e = 0.0;
            }
        }
    }
    let mut real: Vec<f64> = l
        .sim
        .iter()
        .zip(&effect)
        .zip(noise(&fleet, l.len()))
        .map(|((s, e), n)| s + e + n)
        .collect();
    if job.kind == "spikes" {
        // 1 % of rows, ±30σ, alternating sign, at seed-dependent rows.
        let offset = (job.seed % 100) as usize;
        for (k, i) in (offset..real.len()).step_by(100).enumerate() {
            real[i] += if k % 2 == 0 { 30.0 } else { -30.0 } * sigma;
        }
    }
    let rounded = cfg.cells.map(|b| in_cells_of(&l, b));
    let mut batch = to_batch(rounded.as_ref().unwrap_or(&l), &real, &fleet.observable)?;
    if let Some(m) = &machine_of_row {
        batch = sparkout_pipeline::engine::with_machine_column(batch, "")?;
        let idx = batch.schema().index_of("machine")?;
        let mut cols = batch.columns().to_vec();
        cols[idx] = std::sync::Arc::new(arrow::array::StringArray::from(m.clone()));
        batch = arrow::record_batch::RecordBatch::try_new(batch.schema(), cols)?;
    }
    let dcfg = DiagnoseConfig::reseeded(dcfg, job.seed)?;
    let out = diagnose_checked(batch, &dcfg, &[])?;
    let d = &out.diagnosis;
    let named = d.selected.first().cloned().unwrap_or_else(|| "none".into());
    let e_energy: f64 = effect.iter().map(|e| e * e).sum();
    let localisation = (e_energy > 0.0).then(|| {
        let inside = in_cells(&d.where_, &l);
        effect
            .iter()
            .zip(&inside)
            .filter(|(_, i)| **i)
            .map(|(e, _)| e * e)
            .sum::<f64>()
            / e_energy
    });
    let eff_rms = rms(&effect);
    let oracle = 1.0 - sigma / (sigma * sigma + eff_rms * eff_rms).sqrt();
    let shrink = if d.gap.rms_mm > 0.0 {
        1.0 - d.unexplained.rms_mm / d.gap.rms_mm
    } else {
        0.0
    };
    let single = matches!(job.kind, "catalogue" | "spikes");
    let param_rel_error = match &spec {
        Some(s) if named == job.truth && single => param_error(s, d),
        _ => None,
    };
    let (intervals_checked, intervals_covered) = match &spec {
        Some(s) if named == job.truth && single => interval_hits(s, d),
        _ => (0, 0),
    };
    let all_named = (job.kind == "two_effects")
        .then(|| parts.iter().all(|p| d.selected.iter().any(|s| s == p)));
    let robust_shrink = (job.kind == "spikes")
        .then(|| d.per_observable.first().map(|o| o.shrink))
        .flatten();
    let machine_localised = (job.kind == "one_machine").then(|| {
        d.where_
            .iter()
            .any(|c| c.covariate == "machine" && c.lo.as_label() == Some(EFFECT_MACHINE))
    });
    let machine_named = (job.kind == "one_machine").then(|| {
        d.machine_effects
            .iter()
            .any(|e| e.machine == EFFECT_MACHINE && e.effect == job.truth)
    });
    Ok(FleetResult {
        truth: job.truth.clone(),
        kind: job.kind.into(),
        snr: job.snr,
        seed: job.seed,
        named,
        selected: d.selected.clone(),
        localisation,
        param_rel_error,
        shrink,
        oracle_shrink: oracle,
        unexplained_over_sigma: d.unexplained.rms_mm / sigma.max(1e-300),
        intervals_checked,
        intervals_covered,
        all_named,
        robust_shrink,
        machine_localised,
        machine_named,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// The layout with each covariate but the whole-numbered `pass` and `dir`
/// rounded to the centre of one of `b` equal cells across its range.
fn in_cells_of(l: &ObsLayout, b: usize) -> ObsLayout {
    let mut out = l.clone();
    for (name, v) in out.cols.iter_mut() {
        if name == "pass" || name == "dir" {
            continue;
        }
        let Some((lo, hi)) = sparkout_pipeline::effect::min_max(v) else {
            continue;
        };
        let w = (hi - lo) / b as f64;
        if w <= 0.0 {
            continue;
        }
        for x in v.iter_mut() {
            let k = (((*x - lo) / w).floor() as usize).min(b - 1);
            *x = lo + (k as f64 + 0.5) * w;
        }
    }
    out
}

fn mix(seed: u64, a: u64, b: u64, c: u64) -> u64 {
    // SplitMix64 over the case coordinates: independent, reproducible seeds.
    let mut z = seed
        ^ a.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ b.wrapping_mul(0xBF58_476D_1CE4_E5B9)
        ^ c.wrapping_mul(0x94D0_49BB_1331_11EB);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Runs the validation (rayon over fleets; results in a fixed order).
pub fn run(cfg: &ValidateConfig) -> Result<ValidationReport> {
    // `[diagnose]` checked once; each fleet takes it with its own seed.
    let dcfg = cfg.diagnose.clone().checked()?;
    let start = Instant::now();
    let mut jobs = Vec::new();
    for (ci, case) in CATALOGUE_CASES.iter().enumerate() {
        if let Some(only) = &cfg.effects {
            let name = case.split(':').next().unwrap_or(case);
            if !only.iter().any(|o| o == case || o == name) {
                continue;
            }
        }
        for (si, snr) in cfg.snrs.iter().enumerate() {
            for rep in 0..cfg.fleets_per_case {
                jobs.push(Job {
                    truth: case.to_string(),
                    kind: "catalogue",
                    snr: *snr,
                    seed: mix(cfg.seed, ci as u64 + 1, si as u64 + 1, rep as u64),
                });
            }
        }
    }
    for rep in 0..cfg.free_fleets {
        jobs.push(Job {
            truth: "none".into(),
            kind: "effect_free",
            snr: 0.0,
            seed: mix(cfg.seed, 1000, 0, rep as u64),
        });
    }
    for (oi, case) in OOC_CASES.iter().enumerate() {
        for rep in 0..cfg.ooc_fleets {
            jobs.push(Job {
                truth: case.to_string(),
                kind: "out_of_catalogue",
                snr: 10.0,
                seed: mix(cfg.seed, 2000 + oi as u64, 0, rep as u64),
            });
        }
    }
    let mixed: [(&str, &[&str], f64); 3] = [
        ("two_effects", &TWO_EFFECT_CASES, 10.0),
        ("spikes", &SPIKE_CASES, 10.0),
        ("one_machine", &ONE_MACHINE_CASES, 10.0),
    ];
    for (ki, (kind, cases, snr)) in mixed.iter().enumerate() {
        for (ci, case) in cases.iter().enumerate() {
            for rep in 0..cfg.mixed_fleets {
                jobs.push(Job {
                    truth: case.to_string(),
                    kind,
                    snr: *snr,
                    seed: mix(cfg.seed, 3000 + 10 * ki as u64 + ci as u64, 0, rep as u64),
                });
            }
        }
    }
    // A pool of its own with large stacks: fleets run in parallel and each
    // diagnosis runs its candidates in parallel too; a worker waiting on an
    // inner join steals other fleets, which nests their frames on its stack.
    let pool = rayon::ThreadPoolBuilder::new()
        .stack_size(256 << 20)
        .build()?;
    let results: Vec<FleetResult> = pool.install(|| {
        jobs.par_iter()
            .map(|j| run_fleet(cfg, &dcfg, j))
            .collect::<Result<_>>()
    })?;
    Ok(summarise(cfg, results, start.elapsed().as_secs_f64()))
}

#[cfg(test)]
mod cells_tests {
    use super::*;

    /// Every covariate but `pass` and `dir` lands on one of B cell centres
    /// across its range; the extremes fall in the first and last cells.
    #[test]
    fn covariates_round_to_cell_centres() {
        let l = layout(&ObsFleetConfig::default()).unwrap();
        let b = 4;
        let c = in_cells_of(&l, b);
        for (name, v) in &l.cols {
            let got = &c.cols[name];
            if name == "pass" || name == "dir" {
                assert_eq!(got, v, "{name}");
                continue;
            }
            let lo = v.iter().cloned().fold(f64::INFINITY, f64::min);
            let hi = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            if hi == lo {
                continue;
            }
            let w = (hi - lo) / b as f64;
            let centres: Vec<f64> = (0..b).map(|k| lo + (k as f64 + 0.5) * w).collect();
            for (x, y) in v.iter().zip(got) {
                assert!(centres.contains(y), "{name}: {x} → {y}");
                assert!(
                    (x - y).abs() <= 0.5 * w * (1.0 + 1e-12),
                    "{name}: {x} → {y}"
                );
            }
        }
    }

    /// Two cells lose what the exact covariates find: the research option
    /// changes what the diagnosis sees.
    #[test]
    fn two_cells_lose_a_periodic_the_exact_covariates_find() {
        let base = ValidateConfig {
            effects: Some(vec!["periodic:x_mm".into()]),
            snrs: vec![10.0],
            fleets_per_case: 1,
            free_fleets: 0,
            ooc_fleets: 0,
            mixed_fleets: 0,
            ..ValidateConfig::new(true, 0)
        };
        let exact = run(&base).unwrap();
        let coarse = run(&ValidateConfig {
            cells: Some(2),
            ..base
        })
        .unwrap();
        assert_eq!(exact.results[0].named, "periodic:x_mm");
        assert_ne!(coarse.results[0].named, "periodic:x_mm");
    }
}

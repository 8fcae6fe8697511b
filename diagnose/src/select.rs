//! "Which unmodelled effect causes it?" (docs/design.md §7 point 2):
//! leave-runs-out cross-validation of every candidate, the paired run-by-run
//! test, and forward selection.
//!
//! Cross-validation: runs are assigned to k folds by a seeded shuffle; each
//! fold fits on the other folds' runs and scores its own. The error of a
//! candidate is scored per *unit* — a held-out run, or, with fewer than 6
//! runs, contiguous blocks of a held-out run, so the paired test has enough
//! pairs; units never straddle runs, so nothing scored was fitted on.
//!
//! Test: one-sided paired t-test on d_u = ln(rms_before_u / rms_after_u)
//! over the units (H0: mean d ≤ 0). Runs differ a lot in scale (feeds,
//! loads), so a ratio per unit is compared, not pooled sums (docs/design.md §7).
//!
//! Forward selection is stagewise: after an effect is chosen, each fold's
//! target becomes its residual after that effect (fitted on the fold's
//! training runs), and the remaining candidates are re-scored against it.
//! It stops when the best candidate's p ≥ α, or the held-out RMS is at the
//! noise floor (≤ `noise_margin`·σ), or `max_effects` are chosen. Parsimony:
//! a candidate with fewer parameters that is itself significant and not
//! significantly worse than the best (same paired test) is preferred, so
//! `offset` wins when no shape does better (docs/design.md §7). "Better" also needs
//! a practical margin: a mean log RMS ratio of at least `min_gain` (1 %).
//!
//! A round's choice is then held to stability and materiality
//! (`stability.rs`): its gain holding on at least `min_frequency` of
//! half-subsamples of the runs, and removing at least `min_gap_share` of
//! the explainable gap. A choice that fails is "minor" (kept in `effects`
//! with its figures, not selected) and the round's next choice is tried.
//! The chosen effect's indistinguishable rivals (same round, 95 % paired
//! interval over held-out units containing zero) are recorded with it.

use std::collections::BTreeMap;
use std::ops::Range;
use std::sync::Arc;

use crate::err;
use rayon::prelude::*;
use statrs::distribution::{ContinuousCDF, StudentsT};

use super::covariates::{CovRows, Covariates};
use super::effect::{with_columns, CovStats, Effect, EffectData, FittedEffect, Frame};
use super::fit::{self, choose_theta, dot, scan_rows, FoldSpec};
use crate::Result;

mod cross_validate;
pub use cross_validate::*;
pub mod stability;

/// Level of the parsimony comparison (see `select`).
pub const PARSIMONY_ALPHA: f64 = 0.05;

/// The rows of one observable, sorted by run (then time), with its folds.
pub struct Problem<'a> {
    /// The covariates, in memory or read a chunk at a time.
    pub x: &'a Covariates,
    pub gap: &'a [f64],
    /// Scoring units, contiguous, each inside one run.
    pub units: Vec<Range<usize>>,
    /// The CV fold that holds each unit out.
    pub unit_fold: Vec<usize>,
    /// The run (a single run: the block) of each unit; stability
    /// resamples keep or drop a run's units together.
    pub unit_run: Vec<usize>,
    /// Number of CV folds k; fold index k is "all runs" (the final fit).
    pub k: usize,
    pub frames: BTreeMap<String, CovStats>,
}

impl Problem<'_> {
    /// Training masks: folds 0..k leave their units out, fold k trains on all.
    pub fn train_masks(&self) -> Vec<Vec<bool>> {
        let mut m: Vec<Vec<bool>> = (0..self.k)
            .map(|f| self.unit_fold.iter().map(|&uf| uf != f).collect())
            .collect();
        m.push(vec![true; self.units.len()]);
        m
    }
    pub fn frame(&self, e: &dyn Effect) -> Result<Frame> {
        e.covariates()
            .iter()
            .map(|c| {
                self.frames
                    .get(c)
                    .copied()
                    .ok_or_else(|| err!("covariate `{c}` not available"))
            })
            .collect()
    }
    fn min_train_rows(&self, masks: &[Vec<bool>]) -> usize {
        masks
            .iter()
            .map(|m| {
                self.units
                    .iter()
                    .zip(m)
                    .filter(|(_, t)| **t)
                    .map(|(u, _)| u.len())
                    .sum::<usize>()
            })
            .min()
            .unwrap_or(0)
    }
}

/// A candidate scored in one round: its index, fit, mean log RMS ratio
/// (held-out gain) and one-sided p-value.
type Scored = (usize, CandEval, f64, f64);

/// One round of forward selection's scoring: every live candidate
/// cross-validated against the current targets (in parallel), its record
/// written (a failed fit is skipped with the reason).
fn score_round(
    prob: &Problem,
    cands: &[&dyn Effect],
    tg: &Targets,
    live: &[usize],
    before: &[f64],
    step: usize,
    records: &mut [Option<Record>],
) -> Vec<Scored> {
    let live_cands: Vec<&dyn Effect> = live.iter().map(|&i| cands[i]).collect();
    let evals: Vec<(usize, Result<CandEval>, f64)> = live
        .iter()
        .zip(evaluate_all(&live_cands, prob, tg))
        .map(|(&i, (ev, secs))| (i, ev, secs))
        .collect();
    if tracing::enabled!(tracing::Level::DEBUG) {
        let mut slow: Vec<(f64, String)> = evals
            .iter()
            .map(|(i, _, s)| (*s, cands[*i].key()))
            .collect();
        slow.sort_by(|a, b| b.0.total_cmp(&a.0));
        let total: f64 = slow.iter().map(|(s, _)| s).sum();
        let top: Vec<String> = slow
            .iter()
            .take(3)
            .map(|(s, k)| format!("{k} {s:.2} s"))
            .collect();
        tracing::debug!(
            "round {step}: candidates' time {total:.2} s, slowest {}",
            top.join(", ")
        );
    }
    let evals = evals.into_iter().map(|(i, e, _)| (i, e));
    let sse_before: f64 = before.iter().sum();
    let mut scored = Vec::new();
    for (i, ev) in evals {
        match ev {
            Err(e) => {
                records[i] = Some(Record::skipped(
                    i,
                    step,
                    format!("fit failed: {e}"),
                    sse_before,
                ));
            }
            Ok(ev) => {
                let (mlr, p) = paired_log_test(before, &ev.unit_sse);
                let (params, off) = params_of(cands[i], prob, &ev, prob.k);
                records[i] = Some(Record {
                    idx: i,
                    step,
                    skipped: None,
                    sse_before,
                    sse_after: ev.unit_sse.iter().sum(),
                    mean_log_ratio: mlr,
                    p_value: p,
                    params,
                    offset_mm: off,
                    selected: false,
                    selection_frequency: f64::NAN,
                    gap_share: f64::NAN,
                    minor: false,
                    indistinguishable: Vec::new(),
                    also_passed: Vec::new(),
                });
                scored.push((i, ev, mlr, p));
            }
        }
    }
    scored
}

/// The round's choice among `scored`: the best by mean log ratio (ties by
/// fewer parameters, then name order) among the statistically *and*
/// practically significant — a consistent 0.01 % gain over many points
/// passes a t-test but explains nothing — then, for parsimony, a simpler
/// significant candidate that is not significantly worse. None: nothing is
/// significant.
/// Candidates marked in `rejected` (minor ones) are passed over.
fn pick(
    scored: &[Scored],
    cands: &[&dyn Effect],
    opt: &SelectOptions,
    sse_before: f64,
    rejected: &[bool],
) -> Option<usize> {
    let significant = |s: &Scored| {
        s.3 < opt.alpha && s.2 >= opt.min_gain && s.1.unit_sse.iter().sum::<f64>() < sse_before
    };
    let mut best: Option<usize> = None;
    for (j, s) in scored.iter().enumerate() {
        if rejected[j] || !significant(s) {
            continue;
        }
        best = match best {
            None => Some(j),
            Some(b) => {
                let (sb, np_b) = (scored[b].2, cands[scored[b].0].n_params());
                let np = cands[s.0].n_params();
                if s.2 > sb || (s.2 == sb && np < np_b) {
                    Some(j)
                } else {
                    Some(b)
                }
            }
        };
    }
    let b = best?;
    let np_best = cands[scored[b].0].n_params();
    let mut alt: Option<usize> = None;
    for (j, s) in scored.iter().enumerate() {
        if j == b || rejected[j] || !significant(s) || cands[s.0].n_params() >= np_best {
            continue;
        }
        let (gain, p_worse) = paired_log_test(&s.1.unit_sse, &scored[b].1.unit_sse);
        // "Not significantly worse" at α_p = max(α, 0.05): this test
        // asks which of two explanations holds, with only as many pairs
        // as held-out runs, so it is run at a less strict level than the
        // "is there an effect" test.
        let alpha_p = opt.alpha.max(PARSIMONY_ALPHA);
        if p_worse.is_nan() || p_worse >= alpha_p || gain < opt.min_gain {
            // The simplest such candidate; among equally simple ones the
            // best scored.
            let np = cands[s.0].n_params();
            alt = match alt {
                Some(a) => {
                    let np_a = cands[scored[a].0].n_params();
                    if np < np_a || (np == np_a && s.2 > scored[a].2) {
                        Some(j)
                    } else {
                        Some(a)
                    }
                }
                None => Some(j),
            };
        }
    }
    Some(alt.unwrap_or(b))
}

/// One-sided paired t-test that `after` is smaller than `before`, on the
/// log ratio of each unit's RMS. Returns (mean log ratio, p-value).
pub fn paired_log_test(before: &[f64], after: &[f64]) -> (f64, f64) {
    let d: Vec<f64> = before
        .iter()
        .zip(after)
        .filter(|(b, a)| b.is_finite() && a.is_finite())
        .map(|(b, a)| 0.5 * ((b + 1e-300) / (a + 1e-300)).ln())
        .collect();
    let m = d.len();
    if m == 0 {
        return (f64::NAN, f64::NAN);
    }
    let mean = d.iter().sum::<f64>() / m as f64;
    if m < 2 {
        return (mean, f64::NAN);
    }
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (m - 1) as f64;
    let se = (var / m as f64).sqrt();
    let p = if se <= 1e-300 * mean.abs().max(1.0) {
        if mean > 0.0 {
            0.0
        } else {
            1.0
        }
    } else {
        match StudentsT::new(0.0, 1.0, (m - 1) as f64) {
            Ok(t) => t.sf(mean / se),
            Err(_) => f64::NAN,
        }
    };
    (mean, p)
}

/// A candidate's record in `effects`: its score in the last round it was
/// evaluated in (the round it was selected in, or the final round).
pub struct Record {
    pub idx: usize,
    pub step: usize,
    pub skipped: Option<String>,
    pub sse_before: f64,
    pub sse_after: f64,
    pub mean_log_ratio: f64,
    pub p_value: f64,
    pub params: BTreeMap<String, f64>,
    pub offset_mm: f64,
    pub selected: bool,
    /// Share of half-subsamples of runs on whose held-out units its gain
    /// holds (`stability.rs`).
    pub selection_frequency: f64,
    /// Held-out SSE it removes over the observable's explainable SSE.
    pub gap_share: f64,
    /// Chosen by the round's test but below `min_frequency` or
    /// `min_gap_share`: listed, not selected.
    pub minor: bool,
    /// Selected: candidates (indices) of the same round whose held-out
    /// error cannot be told from its own.
    pub indistinguishable: Vec<usize>,
    /// Selected: every other candidate of the same round that passed the
    /// held-out test against the round's targets (`indistinguishable`
    /// among them), with its held-out Σ residual² in that round (its own
    /// record may belong to a later round). Such a rival on a covariate
    /// that moves with the selected one's within runs explains the same
    /// gap by another cause — the collinearity note names it
    /// (collinear.rs).
    pub also_passed: Vec<(usize, f64)>,
}

impl Record {
    /// A candidate that was not scored at this step, and why.
    fn skipped(idx: usize, step: usize, why: String, sse_before: f64) -> Record {
        Record {
            idx,
            step,
            skipped: Some(why),
            sse_before,
            sse_after: f64::NAN,
            mean_log_ratio: f64::NAN,
            p_value: f64::NAN,
            params: BTreeMap::new(),
            offset_mm: f64::NAN,
            selected: false,
            selection_frequency: f64::NAN,
            gap_share: f64::NAN,
            minor: false,
            indistinguishable: Vec::new(),
            also_passed: Vec::new(),
        }
    }
}

pub struct Selection {
    pub records: Vec<Record>,
    /// Candidate indices in the order they were selected.
    pub chosen: Vec<usize>,
    /// Held-out contribution of each chosen effect per row (offset included).
    pub contrib: Vec<Vec<f64>>,
    /// All-runs fits of the chosen effects, stagewise: (params, offset).
    pub final_params: Vec<(BTreeMap<String, f64>, f64)>,
    /// The cross-validated fits of the chosen effects (fold k = all runs):
    /// intervals read their covariance and fold spread.
    pub chosen_evals: Vec<CandEval>,
    /// Held-out Σ residual² per unit before each chosen effect (its
    /// `unit_sse` is after).
    pub chosen_before: Vec<Vec<f64>>,
    /// Held-out residual after the selection, per row.
    pub residual: Vec<f64>,
    /// Held-out Σ residual² per unit before any effect (the raw gap) and
    /// after the selection.
    pub unit_sse_gap: Vec<f64>,
    pub unit_sse_after: Vec<f64>,
    pub stop_reason: String,
}

impl Selection {
    /// The all-runs target the `j`-th chosen effect was fitted to: the gap
    /// less the all-runs fits of the effects chosen before it. Computed
    /// again when asked — unit by unit, the same subtractions in the same
    /// order as the selection made, so the same bits — rather than kept as
    /// a column per chosen effect through the selection.
    pub fn final_target(
        &self,
        prob: &Problem,
        cands: &[&dyn Effect],
        j: usize,
    ) -> Result<Vec<f64>> {
        let mut target = prob.gap.to_vec();
        for (&ci, ev) in self.chosen[..j].iter().zip(&self.chosen_evals) {
            take_out_fold(cands[ci], prob, ev, prob.k, &mut target, &mut Vec::new())?;
        }
        Ok(target)
    }

    /// Whether every effect chosen before the `j`-th predicts row by row
    /// (a linear form; a plugin effect predicts all rows at once), so that
    /// [`Selection::final_target_rows`] serves any rows.
    pub fn final_target_is_row_by_row(&self, j: usize) -> bool {
        self.chosen_evals[..j]
            .iter()
            .all(|ev| matches!(ev.fit, CandFit::Fast { .. }))
    }

    /// [`Selection::final_target`] of the observable's rows `rows` into
    /// `out` — the same bits — when [`Selection::final_target_is_row_by_row`];
    /// `None` otherwise (ask for the column).
    pub fn final_target_rows(
        &self,
        prob: &Problem,
        cands: &[&dyn Effect],
        j: usize,
        rows: Range<usize>,
        out: &mut Vec<f64>,
    ) -> Result<Option<()>> {
        if !self.final_target_is_row_by_row(j) {
            return Ok(None);
        }
        let earlier = self.chosen[..j].iter().zip(&self.chosen_evals);
        out.clear();
        out.extend_from_slice(&prob.gap[rows.clone()]);
        let mut pred = Vec::new();
        for (&ci, ev) in earlier {
            let covs = cands[ci].covariates();
            fold_prediction(
                cands[ci],
                prob,
                ev,
                prob.k,
                &prob.x.rows_of(&covs, rows.clone())?.data(),
                &mut pred,
            )?;
            out.iter_mut().zip(&pred).for_each(|(y, p)| *y -= p);
        }
        Ok(Some(()))
    }
}

pub struct SelectOptions {
    pub alpha: f64,
    pub noise_margin: f64,
    pub sigma_mm: f64,
    /// The unit of the gap (`mm`, `mm/s`), for the messages.
    pub gap_unit: String,
    pub max_effects: usize,
    /// Smallest mean log RMS ratio that counts as a gain (selection and
    /// parsimony).
    pub min_gain: f64,
    /// Stability: smallest selection frequency over half-subsamples of runs.
    pub min_frequency: f64,
    /// Materiality: smallest share of the explainable gap removed.
    pub min_gap_share: f64,
    /// Seed of the half-subsamples (when there are too many to list).
    pub seed: u64,
    /// False: score every candidate but select nothing ("no gap above noise").
    pub allow_selection: bool,
}

/// Scores every candidate and runs forward selection.
pub fn select(prob: &Problem, cands: &[&dyn Effect], opt: &SelectOptions) -> Result<Selection> {
    let n = prob.x.len();
    let k = prob.k;
    let masks = prob.train_masks();
    let min_train = prob.min_train_rows(&masks);
    let mut records: Vec<Option<Record>> = (0..cands.len()).map(|_| None).collect();
    for (i, c) in cands.iter().enumerate() {
        let need = c.n_params() + 1;
        if need > min_train {
            records[i] = Some(Record::skipped(
                i,
                1,
                format!(
                    "{need} parameters but only {min_train} observations in the smallest training fold"
                ),
                f64::NAN,
            ));
        }
    }
    // Every fold's first target is the gap; a chosen effect's fits are
    // taken out of the folds' targets as the passes read them.
    let mut tg = Targets::gap(prob);
    let unit_sse_gap: Vec<f64> = prob
        .units
        .iter()
        .map(|u| dot(&prob.gap[u.clone()], &prob.gap[u.clone()]))
        .collect();
    let mut before = unit_sse_gap.clone();
    let explainable = stability::explainable_sse(unit_sse_gap.iter().sum(), n, opt.sigma_mm);
    let halves = stability::half_samples(&prob.unit_run, opt.seed);
    let mut chosen: Vec<usize> = Vec::new();
    let mut final_params = Vec::new();
    let mut chosen_evals = Vec::new();
    let mut chosen_before = Vec::new();
    let stop_reason;
    let mut step = 0;
    loop {
        step += 1;
        // After the first round (which scores every candidate against the
        // raw gap), stop before re-scoring when nothing is left to explain;
        // the candidates keep their scores from the previous round.
        let rms_now = (before.iter().sum::<f64>() / n as f64).sqrt();
        if step > 1 && rms_now <= opt.noise_margin * opt.sigma_mm {
            stop_reason = format!(
                "held-out RMS {} at the noise floor (≤ {}·σ)",
                crate::units::format::show_in(rms_now, &opt.gap_unit),
                opt.noise_margin
            );
            break;
        }
        if chosen.len() >= opt.max_effects {
            stop_reason = format!("{} effects selected (maximum)", opt.max_effects);
            break;
        }
        let live: Vec<usize> = (0..cands.len())
            .filter(|i| {
                !chosen.contains(i) && records[*i].as_ref().is_none_or(|r| r.skipped.is_none())
            })
            .collect();
        if live.is_empty() {
            stop_reason = "no candidate left".to_string();
            break;
        }
        let sse_before: f64 = before.iter().sum();
        let t_round = std::time::Instant::now();
        let mut scored = score_round(prob, cands, &tg, &live, &before, step, &mut records);
        tracing::debug!(
            "round {step}: {} candidates scored in {:.2} s",
            live.len(),
            t_round.elapsed().as_secs_f64()
        );
        if !opt.allow_selection {
            stop_reason = "no gap above noise".to_string();
            break;
        }
        if rms_now <= opt.noise_margin * opt.sigma_mm {
            stop_reason = format!(
                "held-out RMS {} at the noise floor (≤ {}·σ)",
                crate::units::format::show_in(rms_now, &opt.gap_unit),
                opt.noise_margin
            );
            break;
        }
        for (i, ev, _, _) in &scored {
            if let Some(r) = records[*i].as_mut() {
                r.selection_frequency =
                    stability::selection_frequency(&before, &ev.unit_sse, &halves, opt);
                r.gap_share =
                    stability::gap_share(sse_before, ev.unit_sse.iter().sum(), explainable);
            }
        }
        // The round's choice, held to stability and materiality: a choice
        // that fails either is minor, and the next choice is tried.
        let mut rejected = vec![false; scored.len()];
        let chosen_now = loop {
            let Some(b) = pick(&scored, cands, opt, sse_before, &rejected) else {
                break None;
            };
            let Some(r) = records[scored[b].0].as_mut() else {
                break None;
            };
            // NaN frequency (a single unit: no subsample) does not block.
            let stable =
                r.selection_frequency.is_nan() || r.selection_frequency >= opt.min_frequency;
            if stable && r.gap_share >= opt.min_gap_share {
                break Some(b);
            }
            r.minor = true;
            rejected[b] = true;
        };
        let Some(b) = chosen_now else {
            stop_reason = if rejected.iter().any(|r| *r) {
                format!(
                    "the candidates that pass the held-out test are minor (selection frequency < {} or gap share < {})",
                    opt.min_frequency, opt.min_gap_share
                )
            } else {
                format!(
                    "no candidate lowers the held-out gap significantly (p < {})",
                    opt.alpha
                )
            };
            break;
        };
        let passed: Vec<&Scored> = scored
            .iter()
            .enumerate()
            .filter(|(j, s)| *j != b && stability::passes(&before, &s.1.unit_sse, opt))
            .map(|(_, s)| s)
            .collect();
        let rivals: Vec<usize> = passed
            .iter()
            .filter(|s| stability::indistinguishable(&scored[b].1.unit_sse, &s.1.unit_sse))
            .map(|s| s.0)
            .collect();
        let also_passed: Vec<(usize, f64)> = passed
            .iter()
            .map(|s| (s.0, s.1.unit_sse.iter().sum()))
            .collect();
        let (ci, ev, _, _) = scored.swap_remove(b);
        let t_out = std::time::Instant::now();
        let new_targets = tg.taking_out(prob, cands[ci], &ev)?;
        tracing::debug!(
            "round {step}: {} taken out in {:.2} s",
            cands[ci].key(),
            t_out.elapsed().as_secs_f64()
        );
        final_params.push(params_of(cands[ci], prob, &ev, k));
        if let Some(r) = records[ci].as_mut() {
            r.selected = true;
            r.indistinguishable = rivals;
            r.also_passed = also_passed;
        }
        chosen_before.push(std::mem::replace(&mut before, ev.unit_sse.clone()));
        chosen_evals.push(ev);
        chosen.push(ci);
        tg = new_targets;
    }
    // The chosen effects' held-out contributions, computed once the
    // selection is done (not held through its rounds: 8 B a row each).
    let contrib: Vec<Vec<f64>> = chosen
        .iter()
        .zip(&chosen_evals)
        .map(|(&ci, ev)| held_out_contribution(prob, cands[ci], ev))
        .collect::<Result<_>>()?;
    let residual: Vec<f64> = (0..n)
        .map(|i| prob.gap[i] - contrib.iter().map(|c| c[i]).sum::<f64>())
        .collect();
    Ok(Selection {
        records: records.into_iter().flatten().collect(),
        chosen,
        contrib,
        final_params,
        chosen_evals,
        chosen_before,
        residual,
        unit_sse_gap,
        unit_sse_after: before,
        stop_reason,
    })
}

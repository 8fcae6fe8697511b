//! What the diagnosis returns: diagnosis.json v1 (docs/formats.md
//! "diagnosis.json (v1)") plus the fields later versions added — every v1
//! field unchanged — and the per-row diagnosis.parquet.

use std::collections::{BTreeMap, BTreeSet};

use super::augment::{AugmentedModelFile, ModelEffect, ModelFactor, ModelFrame, ModelLinear};
use super::effect::Effect;
use super::gather::ObsRows;
use super::intervals::ChosenIntervals;
use super::machines::{self, MachineTest};
use super::observations::Table;
use super::select::{Problem, Record, Selection};
use super::{cells, report, Accum, DiagnoseConfig, Notes};
use crate::Result;

const PAIRED_TEST: &str = "one-sided paired t-test on ln(rms_before/rms_after) over held-out units (runs; blocks of runs when fewer than 6 runs)";

use crate::document::fin;
pub use crate::document::*;

/// Per selected effect (in selection order): does it hold for every machine?
/// Empty entries without a `machine` column or with one machine.
pub fn machine_tests(
    table: &Table,
    o: &ObsRows,
    prob: &Problem,
    cands: &[&dyn Effect],
    sel: &Selection,
) -> Result<Vec<Option<MachineTest>>> {
    if !table.has_machine || o.machines().len() < 2 {
        return Ok(sel.chosen.iter().map(|_| None).collect());
    }
    let machine = o.machine_of_rows();
    sel.chosen
        .iter()
        .enumerate()
        .map(|(j, &ci)| {
            // Whole columns of the effect's covariates: the pooled and
            // per-machine fits are refits on rows.
            machines::per_machine(
                cands[ci],
                &prob.x.columns(&cands[ci].covariates())?.data(),
                &sel.final_target(prob, cands, j)?,
                &machine,
                &o.run_ranges,
                &table.machine_names,
            )
        })
        .collect()
}

/// The `effects` entries of one observable: selected (in order), then by
/// score, skipped last.
#[allow(clippy::too_many_arguments)]
pub fn effect_entries(
    observable: &str,
    gap_unit: &str,
    n: usize,
    cands: &[&dyn Effect],
    sel: &Selection,
    tests: &[Option<MachineTest>],
    intervals: &ChosenIntervals,
    cfg: &DiagnoseConfig,
) -> Vec<EffectEntry> {
    let mut recs: Vec<&Record> = sel.records.iter().collect();
    let rank = |r: &Record| {
        if r.selected {
            (
                0usize,
                sel.chosen.iter().position(|&c| c == r.idx).unwrap_or(0) as f64,
            )
        } else if r.skipped.is_some() {
            (2, 0.0)
        } else {
            (1, -r.mean_log_ratio)
        }
    };
    recs.sort_by(|a, b| {
        let (ra, rb) = (rank(a), rank(b));
        ra.0.cmp(&rb.0)
            .then(ra.1.total_cmp(&rb.1))
            .then(a.idx.cmp(&b.idx))
    });
    recs.into_iter()
        .map(|r| {
            let e = cands[r.idx];
            let covs = e.covariates();
            let before = (r.sse_before / n as f64).sqrt();
            let after = (r.sse_after / n as f64).sqrt();
            let j = sel.chosen.iter().position(|&c| c == r.idx && r.selected);
            let test = j.and_then(|j| tests.get(j)).and_then(|t| t.as_ref());
            let iv = j.and_then(|j| intervals.get(j));
            let covariate = (!covs.is_empty()).then(|| covs.join(","));
            let params: BTreeMap<String, f64> = r
                .params
                .iter()
                .filter(|(_, v)| v.is_finite())
                .map(|(k, v)| (k.clone(), *v))
                .collect();
            EffectEntry {
                name: e.name().to_string(),
                param_units: param_units(&params, covariate.as_deref(), gap_unit),
                covariate,
                observable: observable.to_string(),
                params,
                offset_mm: fin(r.offset_mm),
                n_params: e.n_params(),
                cv_rms_before_mm: fin(before),
                cv_rms_after_mm: fin(after),
                shrink: fin(1.0 - after / before),
                p_value: fin(r.p_value),
                mean_log_ratio: fin(r.mean_log_ratio),
                selected: r.selected,
                selection_frequency: fin(r.selection_frequency),
                gap_share: fin(r.gap_share),
                minor: r.minor,
                indistinguishable_from: r
                    .indistinguishable
                    .iter()
                    .map(|&i| cands[i].key())
                    .collect(),
                step: r.step,
                skipped_reason: r.skipped.clone(),
                per_machine: test
                    .filter(|t| t.disagree(cfg.alpha, cfg.min_gain))
                    .map(|t| t.fits.clone()),
                machines_differ_p: test.and_then(|t| fin(t.p_value)),
                intervals: iv.map(|i| i.0.clone()),
                shrink_interval: iv.and_then(|i| i.1),
                gap_unit: gap_unit.to_string(),
            }
        })
        .collect()
}

/// Selected effects of one observable into the fleet accumulators: keys,
/// explained variance, per-row contributions, augmented model, residual.
/// Trimmed outliers (`slots.trimmed`) get the all-runs fits' predictions.
/// Returns the observable's selected keys.
#[allow(clippy::too_many_arguments)]
pub fn record_selected(
    o: &ObsRows,
    prob: &Problem,
    cands: &[&dyn Effect],
    sel: &mut Selection,
    sigma_mm: f64,
    slots: &crate::Slots,
    acc: &mut Accum,
) -> Result<Vec<String>> {
    let extra_rows = slots.trimmed;
    // A slot per row of the observable: the analysed rows and the trimmed.
    let n_slots = sel.residual.len() + slots.trimmed_slots.len();
    let mut extra_resid: Vec<f64> = slots.trimmed_gap.to_vec();
    let mut obs_selected = Vec::new();
    for (j, &ci) in sel.chosen.iter().enumerate() {
        let e = cands[ci];
        let key = e.key();
        if !acc.selected_keys.contains(&key) {
            acc.selected_keys.push(key.clone());
        }
        if let Some(r) = sel.records.iter().find(|r| r.idx == ci && r.selected) {
            let var = sigma_mm.powi(2).max(f64::MIN_POSITIVE);
            *acc.explained_var.entry(key.clone()).or_insert(0.0) +=
                ((r.sse_before - r.sse_after) / var).max(0.0);
        }
        obs_selected.push(key.clone());
        // The held-out contributions move to the accumulator (nothing
        // after reads the selection's), spread to their slots in place:
        // 8 B a row per chosen effect not held twice.
        let mut contrib = std::mem::take(&mut sel.contrib[j]);
        slots.spread(&mut contrib, n_slots);
        let col: &mut Vec<f64> = match acc.contrib_cols.entry(key.clone()) {
            std::collections::btree_map::Entry::Vacant(v) => v.insert(contrib),
            std::collections::btree_map::Entry::Occupied(o) => {
                let col = o.into_mut();
                *col = contrib;
                col
            }
        };
        if !extra_rows.is_empty() {
            let pred = trimmed_prediction(e, prob, &sel.chosen_evals[j], slots)?;
            for ((&slot, p), r) in slots
                .trimmed_slots
                .iter()
                .zip(pred)
                .zip(extra_resid.iter_mut())
            {
                col[slot] = p;
                *r -= p;
            }
        }
        let (params, off) = &sel.final_params[j];
        let covs = e.covariates();
        // The catalogue form it evaluates as outside the diagnosis (`run
        // --augment`): its own name, or that of the catalogue effect a
        // plugin composite renames; none for products of forms.
        let form = super::effect::Kind::from_name(e.name())
            .or_else(|| {
                e.replaces()
                    .and_then(|r| super::effect::Kind::from_name(r.split(':').next().unwrap_or("")))
            })
            .map(|k| k.name());
        // The all-runs fit exactly as the diagnosis predicts with it (θ,
        // feature-space intercept and coefficients of its linear form, and
        // the catalogue forms it is built from), so `run --augment` replays
        // any linear-form effect — products of forms included.
        let linear = match (&sel.chosen_evals[j].fit, e.linear_form()) {
            (super::select::CandFit::Fast { theta, beta }, Some(form))
                if !form.factors().is_empty() =>
            {
                Some(ModelLinear {
                    coef: beta[prob.k][1..].iter().map(|b| fin(*b)).collect(),
                    factors: form
                        .factors()
                        .iter()
                        .map(|(k, c)| ModelFactor {
                            covariates: c.clone(),
                            form: k.name().to_string(),
                        })
                        .collect(),
                    intercept: fin(beta[prob.k][0]),
                    theta: fin(theta[prob.k]),
                })
            }
            _ => None,
        };
        acc.augmented.push(ModelEffect {
            covariate: (!covs.is_empty()).then(|| covs.join(",")),
            form: form.map(str::to_string),
            frame: covs
                .iter()
                .map(|c| (c.clone(), prob.frames.get(c).copied().map(ModelFrame::from)))
                .collect(),
            key,
            linear,
            name: e.name().to_string(),
            observable: o.name.to_string(),
            offset_mm: fin(*off),
            params: params
                .iter()
                .filter(|(_, v)| v.is_finite())
                .map(|(k, v)| (k.clone(), *v))
                .collect(),
        });
    }
    // The held-out residual moves to the accumulator too, spread to its
    // slots in place; the trimmed rows' residuals after the all-runs fits.
    let mut residual = std::mem::take(&mut sel.residual);
    slots.spread(&mut residual, n_slots);
    for (&slot, r) in slots.trimmed_slots.iter().zip(extra_resid) {
        residual[slot] = r;
    }
    acc.residual_all = residual;
    Ok(obs_selected)
}

/// The all-runs fit of `e` (the one reported, fold k of `ev`) predicted on
/// the trimmed rows of `slots` (offset included).
fn trimmed_prediction(
    e: &dyn Effect,
    prob: &Problem,
    ev: &super::select::CandEval,
    slots: &super::Slots,
) -> Result<Vec<f64>> {
    let mut xd = super::effect::EffectData::new(slots.trimmed.len());
    for c in e.covariates() {
        let v = slots
            .trimmed_covs
            .iter()
            .find(|(n, _)| *n == c)
            .map(|(_, v)| v)
            .ok_or_else(|| crate::err!("covariate `{c}` not in the table"))?;
        xd.push(&c, v);
    }
    let mut pred = Vec::new();
    super::select::fold_prediction(e, prob, ev, prob.k, &xd, &mut pred)?;
    Ok(pred)
}

/// The fleet-level diagnosis from the per-observable results.
/// `localise` finds the per-machine effects once the document is known
/// and before the per-row table is built: what it holds (the rows'
/// covariates) is let go before that table takes its memory.
pub fn assemble(
    table: Table,
    cfg: &DiagnoseConfig,
    mut acc: Accum,
    mut notes: Notes,
    localise: impl FnOnce(&Table, &Diagnosis) -> Result<Vec<MachineEffect>>,
) -> Result<DiagnosisOutput> {
    let n_all = table.n;
    if acc.blocked {
        notes.add("single run: blocked folds within the run".into());
    }
    if acc.summaries.iter().all(|s| !s.gap_above_noise) {
        notes.add("no gap above noise".into());
    }
    let sum_g2: f64 = table.gap_sums.sum_sq;
    let sum_r2: f64 = match &acc.spill {
        Some(spill) => spill.sum_sq_residual(&table.obs)?,
        None => acc.residual_all.iter().map(|r| r * r).sum(),
    };
    let noise_floor = (acc
        .summaries
        .iter()
        .map(|s| s.n as f64 * s.noise_floor_mm.powi(2))
        .sum::<f64>()
        / n_all as f64)
        .sqrt();
    let sources: BTreeSet<&str> = acc
        .summaries
        .iter()
        .map(|s| s.noise_floor_source.as_str())
        .collect();
    let noise_src = if sources.len() == 1 {
        sources
            .into_iter()
            .next()
            .unwrap_or("point_to_point")
            .to_string()
    } else {
        "mixed".into()
    };
    let (where_, where_after) = cells::where_lists(&acc.cells, sum_g2, sum_r2, cfg.alpha);
    // Stable: ties keep the order of first selection.
    let explained = std::mem::take(&mut acc.explained_var);
    acc.selected_keys.sort_by(|a, b| {
        let w = |k: &String| explained.get(k).copied().unwrap_or(0.0);
        w(b).total_cmp(&w(a))
    });
    let mut diagnosis = Diagnosis {
        version: 1,
        observables: table.obs_names.clone(),
        machines: if table.has_machine {
            table.machine_names.clone()
        } else {
            Vec::new()
        },
        gap: GapSummary {
            rms_mm: (sum_g2 / n_all as f64).sqrt(),
            max_abs_mm: table.gap_sums.max_abs,
            noise_floor_mm: noise_floor,
            n: n_all,
        },
        where_,
        effects: acc.effects,
        selected: acc.selected_keys.clone(),
        unexplained: Unexplained {
            rms_mm: (sum_r2 / n_all as f64).sqrt(),
            share: if sum_g2 > 0.0 { sum_r2 / sum_g2 } else { 0.0 },
            where_: where_after,
        },
        noise_floor_source: noise_src,
        cv: CvInfo {
            folds: acc.folds_used,
            by: if acc.blocked {
                "blocked_within_run".into()
            } else {
                "run".into()
            },
            test: PAIRED_TEST.into(),
            seed: cfg.seed,
        },
        per_observable: acc.summaries,
        notes: notes.into_vec(),
        machine_effects: Vec::new(),
    };
    diagnosis.machine_effects = localise(&table, &diagnosis)?;
    let fitted_on_runs = table.run_names.clone();
    let results = match acc.spill.take() {
        Some(spill) => crate::per_row::Results::Spilled(spill),
        None => crate::per_row::Results::Memory {
            gap: std::mem::take(&mut acc.gap_all),
            residual: std::mem::take(&mut acc.residual_all),
            contrib: std::mem::take(&mut acc.contrib_cols),
        },
    };
    let per_row = crate::per_row::PerRow::new(table, &acc.selected_keys, results);
    let augmented_model = AugmentedModelFile {
        applies_as: "real ≈ sim + Σ over effects of (offset_mm + form(covariates; params)), per observable; forms as in the effect catalogue of docs/formats.md".into(),
        effects: acc.augmented,
        // `run --augment` reports the augmented gap on the runs not listed
        // here (held out by construction).
        fitted_on_runs,
        kind: super::augment::MODEL_KIND.into(),
        version: 1,
    };
    let report_html = report::section(&diagnosis);
    Ok(DiagnosisOutput {
        diagnosis,
        per_row,
        augmented_model,
        report_html,
    })
}

//! Sim-to-real gap diagnosis (DESIGN.md "Sim-to-real gap diagnosis";
//! CONTRACTS.md §2 and "diagnosis.json (v1)"; issue 4).
//!
//! [`diagnose`] answers, per observable: where the gap lies (cells of
//! covariate space tested against the noise floor, `cells`), which catalogue
//! or plugin effect explains it (leave-runs-out CV + forward selection,
//! `select`), and how far it shrinks on held-out runs. It is pure and
//! deterministic for a given seed: names are sorted, folds come from a
//! seeded shuffle, rayon only fills vectors whose order is fixed.

pub mod cells;
pub mod effect;
pub mod fit;
pub mod noise;
pub mod observations;
pub mod report;
pub mod select;

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::sync::Arc;

use anyhow::bail;
use arrow::array::{ArrayRef, Float64Array, RecordBatch};
use arrow::datatypes::{DataType, Field, Schema};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rayon::prelude::*;
use serde::Serialize;

pub use effect::{
    catalogue, catalogue_effect, composite, product, shape_value, CovStats, Effect, EffectData,
    FittedEffect, Kind, LinearForm,
};
pub use observations::read_observations;

use crate::Result;
use noise::NoiseFloor;

/// Settings of the diagnosis (`[diagnose]` config section / CLI flags).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DiagnoseConfig {
    /// k of the k-fold cross-validation by run.
    pub folds: usize,
    /// Restrict candidates to these effect names (catalogue or plugin).
    pub effects: Option<Vec<String>>,
    /// Seed of the fold assignment.
    pub seed: u64,
    /// Significance level of every test (cells, paired CV test).
    pub alpha: f64,
    /// Selection stops when the held-out RMS is ≤ noise_margin·σ, and a gap
    /// at or below it is "no gap above noise".
    pub noise_margin: f64,
    /// At most this many effects are selected per observable.
    pub max_effects: usize,
    /// Smallest held-out gain that counts (mean ln of RMS before/after over
    /// held-out units): selection needs it, and a more complex candidate
    /// must beat a simpler one by it (parsimony).
    pub min_gain: f64,
}

impl Default for DiagnoseConfig {
    fn default() -> Self {
        DiagnoseConfig {
            folds: 5,
            effects: None,
            seed: 0,
            alpha: 0.01,
            noise_margin: 1.1,
            max_effects: 4,
            min_gain: 0.01,
        }
    }
}

impl DiagnoseConfig {
    pub fn validate(&self) -> Result<()> {
        if self.folds < 2 {
            bail!("diagnose.folds must be at least 2 (got {})", self.folds);
        }
        if !(self.alpha > 0.0 && self.alpha < 1.0) {
            bail!("diagnose.alpha must be in (0, 1) (got {})", self.alpha);
        }
        if !(self.noise_margin >= 1.0 && self.noise_margin.is_finite()) {
            bail!(
                "diagnose.noise_margin must be ≥ 1 (got {})",
                self.noise_margin
            );
        }
        if !(self.min_gain >= 0.0 && self.min_gain.is_finite()) {
            bail!("diagnose.min_gain must be ≥ 0 (got {})", self.min_gain);
        }
        if self.max_effects == 0 {
            bail!("diagnose.max_effects must be at least 1");
        }
        if let Some(e) = &self.effects {
            if e.is_empty() {
                bail!("diagnose.effects is empty: name at least one effect or omit it");
            }
        }
        Ok(())
    }
}

/// diagnosis.json `gap`.
#[derive(Debug, Clone, Serialize)]
pub struct GapSummary {
    pub rms_mm: f64,
    pub max_abs_mm: f64,
    pub noise_floor_mm: f64,
    pub n: usize,
}

/// A cell of `where` / `unexplained.where`. `lo`/`hi` are numbers for a
/// 1-D cell and `[x, y]` arrays for an x/y tile (CONTRACTS.md).
#[derive(Debug, Clone, Serialize)]
pub struct WhereCell {
    pub covariate: String,
    pub lo: serde_json::Value,
    pub hi: serde_json::Value,
    pub observable: String,
    pub share: f64,
    pub rms_mm: f64,
    /// Bonferroni-adjusted over all cells of all observables.
    pub p_value: f64,
    pub n: usize,
    /// Only in `unexplained.where`: the cell's gap RMS before the selection
    /// and 1 − after/before.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rms_before_mm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shrink: Option<f64>,
}

/// An entry of `effects`.
#[derive(Debug, Clone, Serialize)]
pub struct EffectEntry {
    pub name: String,
    pub covariate: Option<String>,
    pub observable: String,
    pub params: BTreeMap<String, f64>,
    pub offset_mm: Option<f64>,
    pub n_params: usize,
    pub cv_rms_before_mm: Option<f64>,
    pub cv_rms_after_mm: Option<f64>,
    pub shrink: Option<f64>,
    pub p_value: Option<f64>,
    /// Mean over held-out units of ln(rms_before/rms_after): the ranking score.
    pub mean_log_ratio: Option<f64>,
    pub selected: bool,
    /// Selection round the score belongs to (1 = against the raw gap).
    pub step: usize,
    pub skipped_reason: Option<String>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Unexplained {
    pub rms_mm: f64,
    pub share: f64,
    #[serde(rename = "where")]
    pub where_: Vec<WhereCell>,
}

#[derive(Debug, Clone, Serialize)]
pub struct CvInfo {
    pub folds: usize,
    /// "run" or "blocked_within_run".
    pub by: String,
    pub test: String,
    pub seed: u64,
}

/// Per-observable summary (extra to v1).
#[derive(Debug, Clone, Serialize)]
pub struct ObservableSummary {
    pub observable: String,
    pub n: usize,
    pub runs: usize,
    pub rms_mm: f64,
    pub noise_floor_mm: f64,
    pub noise_floor_source: String,
    pub gap_above_noise: bool,
    pub p_value: f64,
    pub selected: Vec<String>,
    pub cv_rms_before_mm: f64,
    pub cv_rms_after_mm: f64,
    pub shrink: f64,
    pub stop_reason: String,
}

/// diagnosis.json v1 (every contract field) plus extras.
#[derive(Debug, Clone, Serialize)]
pub struct Diagnosis {
    pub version: u32,
    pub observables: Vec<String>,
    pub gap: GapSummary,
    #[serde(rename = "where")]
    pub where_: Vec<WhereCell>,
    pub effects: Vec<EffectEntry>,
    pub selected: Vec<String>,
    pub unexplained: Unexplained,
    /// "replicates", "point_to_point" or "mixed" (per observable below).
    pub noise_floor_source: String,
    pub cv: CvInfo,
    pub per_observable: Vec<ObservableSummary>,
    pub notes: Vec<String>,
}

pub struct DiagnosisOutput {
    pub diagnosis: Diagnosis,
    /// diagnosis.parquet: run, observable, gap, contrib_<name:cov>…,
    /// residual_after — one row per observation, in input order.
    pub per_row: RecordBatch,
    /// The selected effects fitted on all runs, for a simulator to add.
    pub augmented_model: serde_json::Value,
    /// Self-contained `<section>` for the fleet report.
    pub report_html: String,
}

const PAIRED_TEST: &str = "one-sided paired t-test on ln(rms_before/rms_after) over held-out units (runs; blocks of runs when fewer than 6 runs)";
/// Fewer scoring units than this: held-out runs are split into blocks.
const MIN_UNITS: usize = 6;

fn fin(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// Diagnoses paired observations (validated like [`read_observations`]).
pub fn diagnose(
    obs: &RecordBatch,
    cfg: &DiagnoseConfig,
    extra_effects: &[Box<dyn Effect>],
) -> Result<DiagnosisOutput> {
    cfg.validate()?;
    let batch = observations::validate_observations(obs, Path::new("<observations>"))?;
    let table = observations::Table::from_batch(&batch)?;
    let mut notes: BTreeSet<String> = BTreeSet::new();
    let mut ordered_notes: Vec<String> = Vec::new();
    let mut note = |s: String, notes: &mut BTreeSet<String>| {
        if notes.insert(s.clone()) {
            ordered_notes.push(s);
        }
    };
    for d in &table.dropped {
        note(
            format!("covariate {d} has no finite value: skipped"),
            &mut notes,
        );
    }
    if let Some(wanted) = &cfg.effects {
        for w in wanted {
            let known = Kind::from_name(w).is_some() || extra_effects.iter().any(|e| e.name() == w);
            if !known {
                bail!("unknown effect `{w}` in diagnose.effects (catalogue: offset, scale, drift, lag, inertia, backlash, wear, compliance, bow, periodic, edge, squareness, thermal, or a plugin composite)");
            }
        }
    }
    let n_all = table.n;
    let mut residual_all = vec![0.0; n_all];
    let mut contrib_cols: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut selected_keys: Vec<String> = Vec::new();
    // Held-out SSE each selected effect removed, in units of its
    // observable's noise variance, summed over observables: the fleet's
    // `selected` list is ordered by it (the effect that explains the most
    // signal first), not by the order observables happen to be named in.
    let mut explained_var: BTreeMap<String, f64> = BTreeMap::new();
    let mut effects: Vec<EffectEntry> = Vec::new();
    let mut summaries = Vec::new();
    let mut all_cells: Vec<(String, f64, f64, cells::Cell)> = Vec::new(); // (obs, σ, df, cell)
    let mut augmented = Vec::new();
    let mut blocked = false;
    let mut folds_used = 0;
    for (oi, oname) in table.obs_names.iter().enumerate() {
        // Rows of the observable sorted by run, then time (else input order).
        let t = table.cov("t_s");
        let mut rows: Vec<usize> = (0..n_all)
            .filter(|&i| table.obs[i] as usize == oi)
            .collect();
        rows.sort_by(|&a, &b| {
            table.run[a]
                .cmp(&table.run[b])
                .then_with(|| match t {
                    Some(t) => t[a].total_cmp(&t[b]),
                    None => std::cmp::Ordering::Equal,
                })
                .then(a.cmp(&b))
        });
        let n = rows.len();
        let gap: Vec<f64> = rows.iter().map(|&i| table.gap[i]).collect();
        let run: Vec<u32> = rows.iter().map(|&i| table.run[i]).collect();
        let mut run_ranges: Vec<std::ops::Range<usize>> = Vec::new();
        let mut s = 0;
        for i in 1..=n {
            if i == n || run[i] != run[s] {
                run_ranges.push(s..i);
                s = i;
            }
        }
        // Covariates: gathered, sorted once (frames and cell edges).
        let gathered: Vec<(String, Vec<f64>, Vec<f64>, CovStats)> = table
            .covs
            .par_iter()
            .map(|(name, v)| {
                let v: Vec<f64> = rows.iter().map(|&i| v[i]).collect();
                let mut sorted = v.clone();
                sorted.sort_unstable_by(f64::total_cmp);
                let st = CovStats::from_sorted(&sorted);
                (name.clone(), v, sorted, st)
            })
            .collect();
        let mut cols = Vec::new();
        for c in gathered {
            // A covariate belongs to the observables whose rows carry it
            // (CONTRACTS §2: a fleet table mixes observables, each with its
            // own covariates; the others are null there). Absent for every
            // row of this observable → not applicable; absent for some →
            // skipped and said.
            let finite = c.1.iter().filter(|v| v.is_finite()).count();
            if finite == 0 {
                continue;
            }
            if finite < c.1.len() {
                note(
                    format!(
                        "{oname}: covariate {} is missing (null/NaN) in {} of {} rows: skipped",
                        c.0,
                        c.1.len() - finite,
                        c.1.len()
                    ),
                    &mut notes,
                );
                continue;
            }
            if c.3.is_constant() {
                note(format!("constant covariate {} skipped", c.0), &mut notes);
            } else {
                cols.push(c);
            }
        }
        if table.covs.is_empty() {
            note("no covariates: offset only".into(), &mut notes);
        } else if cols.is_empty() {
            note(
                format!("{oname}: no varying covariates: offset only"),
                &mut notes,
            );
        }
        // Noise floor: replicates, else point-to-point.
        let nf: NoiseFloor = {
            let rep = table.trial.as_ref().and_then(|trial| {
                let tr: Vec<i64> = rows.iter().map(|&i| trial[i]).collect();
                let has_position = ["x_mm", "y_mm", "z_mm", "phi_rad"]
                    .iter()
                    .any(|p| cols.iter().any(|c| c.0 == *p));
                if table.point.is_none() && !has_position {
                    return None;
                }
                // Replicates repeat the same measurement: same run, point and
                // every setting (position, speed, direction, load, pass);
                // only the trial and what runs on with time (t_s, temperature,
                // cumulative usage) may differ. Keying on the point id alone
                // would pool a point probed at two speeds, or point 3 of two
                // faces, and count their real difference as noise.
                let settings: Vec<&Vec<f64>> = cols
                    .iter()
                    .filter(|c| !is_time_like(&c.0))
                    .map(|c| &c.1)
                    .collect();
                let key: Vec<Vec<i64>> = rows
                    .iter()
                    .enumerate()
                    .map(|(j, &i)| {
                        let mut k = vec![table.run[i] as i64];
                        if let Some(p) = &table.point {
                            k.push(p[i]);
                        }
                        k.extend(settings.iter().map(|c| c[j].to_bits() as i64));
                        k
                    })
                    .collect();
                noise::replicate_floor(&gap, &key, &tr)
            });
            let nf = rep.unwrap_or_else(|| noise::point_to_point_floor(&gap, &run_ranges));
            // A measurement cannot be compared finer than its own stated
            // uncertainty (e.g. positions logged in 1 mm steps): the floor
            // is never below the RMS of `real_u` where the table states it.
            let stated = table.real_u.as_ref().and_then(|u| {
                let v: Vec<f64> = rows
                    .iter()
                    .map(|&i| u[i])
                    .filter(|x| x.is_finite())
                    .collect();
                (!v.is_empty())
                    .then(|| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt())
            });
            match stated {
                Some(s) if s > nf.sigma_mm => {
                    note(
                        format!(
                            "{oname}: noise floor {s:.3e} from the stated uncertainty real_u (the data's own scatter gave {:.3e})",
                            nf.sigma_mm
                        ),
                        &mut notes,
                    );
                    NoiseFloor { sigma_mm: s, ..nf }
                }
                _ => nf,
            }
        };
        // Folds: by run when there are ≥ 2 runs, else blocks of the one run.
        let (fold_groups, k): (Vec<std::ops::Range<usize>>, usize) = if run_ranges.len() >= 2 {
            (run_ranges.clone(), cfg.folds.min(run_ranges.len()))
        } else {
            blocked = true;
            let k = cfg.folds.min(n.max(1));
            ((0..k).map(|b| b * n / k..(b + 1) * n / k).collect(), k)
        };
        folds_used = folds_used.max(k);
        let mut order: Vec<usize> = (0..fold_groups.len()).collect();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(
            cfg.seed ^ (oi as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
        );
        order.shuffle(&mut rng);
        let mut group_fold = vec![0usize; fold_groups.len()];
        for (pos, &g) in order.iter().enumerate() {
            group_fold[g] = pos % k;
        }
        let split = if fold_groups.len() >= MIN_UNITS {
            1
        } else {
            MIN_UNITS.div_ceil(fold_groups.len())
        };
        let mut units = Vec::new();
        let mut unit_fold = Vec::new();
        for (g, r) in fold_groups.iter().enumerate() {
            let parts = split.min(r.len()).max(1);
            for b in 0..parts {
                let u = r.start + b * r.len() / parts..r.start + (b + 1) * r.len() / parts;
                if !u.is_empty() {
                    units.push(u);
                    unit_fold.push(group_fold[g]);
                }
            }
        }
        let mut x = EffectData::new(n);
        for c in &cols {
            x.push(&c.0, &c.1);
        }
        let prob = select::Problem {
            x,
            gap: &gap,
            units,
            unit_fold,
            k,
            frames: cols.iter().map(|c| (c.0.clone(), c.3)).collect(),
        };
        // Candidates: catalogue on the varying covariates + plugin effects.
        let names: Vec<String> = cols.iter().map(|c| c.0.clone()).collect();
        let wanted = |e: &dyn Effect| {
            cfg.effects
                .as_ref()
                .is_none_or(|w| w.iter().any(|n| n == e.name()))
        };
        let builtin = catalogue(&names);
        let mut cands: Vec<&dyn Effect> = builtin
            .iter()
            .map(|b| b.as_ref())
            .filter(|e| wanted(*e))
            .collect();
        for e in extra_effects {
            if !wanted(e.as_ref()) {
                continue;
            }
            let missing: Vec<String> = e
                .covariates()
                .into_iter()
                .filter(|c| !names.contains(c))
                .collect();
            if missing.is_empty() {
                if let Some(generic) = e.replaces() {
                    cands.retain(|c| c.key() != generic);
                }
                cands.push(e.as_ref());
            } else {
                note(
                    format!(
                        "{} not applicable: covariate {} absent or constant",
                        e.key(),
                        missing.join(",")
                    ),
                    &mut notes,
                );
            }
        }
        // Is there a gap above noise at all? F-test of the whole observable
        // plus the practical margin (σ̂ is an estimate; see cells.rs).
        let ms = gap.iter().map(|g| g * g).sum::<f64>() / n as f64;
        let rms = ms.sqrt();
        let p_gap = cells::cell_p(ms, n, nf.sigma_mm, nf.df);
        let above = p_gap < cfg.alpha && rms > cfg.noise_margin * nf.sigma_mm;
        let opt = select::SelectOptions {
            alpha: cfg.alpha,
            noise_margin: cfg.noise_margin,
            sigma_mm: nf.sigma_mm,
            max_effects: cfg.max_effects,
            min_gain: cfg.min_gain,
            allow_selection: above,
        };
        let sel = select::select(&prob, &cands, &opt)?;
        // effects entries: selected (in order), then by score, skipped last.
        let mut recs: Vec<&select::Record> = sel.records.iter().collect();
        recs.sort_by(|a, b| {
            let rank = |r: &select::Record| {
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
            let (ra, rb) = (rank(a), rank(b));
            ra.0.cmp(&rb.0)
                .then(ra.1.total_cmp(&rb.1))
                .then(a.idx.cmp(&b.idx))
        });
        for r in recs {
            let e = cands[r.idx];
            let covs = e.covariates();
            let before = (r.sse_before / n as f64).sqrt();
            let after = (r.sse_after / n as f64).sqrt();
            effects.push(EffectEntry {
                name: e.name().to_string(),
                covariate: (!covs.is_empty()).then(|| covs.join(",")),
                observable: oname.clone(),
                params: r
                    .params
                    .iter()
                    .filter(|(_, v)| v.is_finite())
                    .map(|(k, v)| (k.clone(), *v))
                    .collect(),
                offset_mm: fin(r.offset_mm),
                n_params: e.n_params(),
                cv_rms_before_mm: fin(before),
                cv_rms_after_mm: fin(after),
                shrink: fin(1.0 - after / before),
                p_value: fin(r.p_value),
                mean_log_ratio: fin(r.mean_log_ratio),
                selected: r.selected,
                step: r.step,
                skipped_reason: r.skipped.clone(),
            });
        }
        // Selected effects: keys, per-row contributions, augmented model.
        let mut obs_selected = Vec::new();
        for (j, &ci) in sel.chosen.iter().enumerate() {
            let e = cands[ci];
            let key = e.key();
            if !selected_keys.contains(&key) {
                selected_keys.push(key.clone());
            }
            if let Some(r) = sel.records.iter().find(|r| r.idx == ci && r.selected) {
                let var = nf.sigma_mm.powi(2).max(f64::MIN_POSITIVE);
                *explained_var.entry(key.clone()).or_insert(0.0) +=
                    ((r.sse_before - r.sse_after) / var).max(0.0);
            }
            obs_selected.push(key.clone());
            let col = contrib_cols
                .entry(key.clone())
                .or_insert_with(|| vec![0.0; n_all]);
            for (pos, &i) in rows.iter().enumerate() {
                col[i] = sel.contrib[j][pos];
            }
            let (params, off) = &sel.final_params[j];
            let covs = e.covariates();
            augmented.push(serde_json::json!({
                "observable": oname,
                "name": e.name(),
                "covariate": if covs.is_empty() { serde_json::Value::Null } else { covs.join(",").into() },
                "key": key,
                "params": params.iter().filter(|(_, v)| v.is_finite()).map(|(k, v)| (k.clone(), serde_json::json!(v))).collect::<serde_json::Map<_, _>>(),
                "offset_mm": fin(*off),
                "frame": covs.iter().map(|c| (c.clone(), serde_json::json!(prob.frames.get(c)))).collect::<serde_json::Map<_, _>>(),
            }));
        }
        for (pos, &i) in rows.iter().enumerate() {
            residual_all[i] = sel.residual[pos];
        }
        let sse_b: f64 = sel.unit_sse_gap.iter().sum();
        let sse_a: f64 = sel.unit_sse_after.iter().sum();
        let (rb, ra) = ((sse_b / n as f64).sqrt(), (sse_a / n as f64).sqrt());
        if !above {
            note(format!("{oname}: no gap above noise"), &mut notes);
        }
        summaries.push(ObservableSummary {
            observable: oname.clone(),
            n,
            runs: run_ranges.len(),
            rms_mm: rms,
            noise_floor_mm: nf.sigma_mm,
            noise_floor_source: nf.source.as_str().into(),
            gap_above_noise: above,
            p_value: p_gap,
            selected: obs_selected,
            cv_rms_before_mm: rb,
            cv_rms_after_mm: ra,
            shrink: if rb > 0.0 { 1.0 - ra / rb } else { 0.0 },
            stop_reason: sel.stop_reason.clone(),
        });
        // Cells of this observable.
        let cov_refs: Vec<(&str, &[f64], &[f64])> = cols
            .iter()
            .map(|c| (c.0.as_str(), c.1.as_slice(), c.2.as_slice()))
            .collect();
        if !cov_refs.is_empty() {
            for c in cells::cells(&cov_refs, &gap, &sel.residual)? {
                all_cells.push((oname.clone(), nf.sigma_mm, nf.df, c));
            }
        }
    }
    if blocked {
        note(
            "single run: blocked folds within the run".into(),
            &mut notes,
        );
    }
    if summaries.iter().all(|s| !s.gap_above_noise) {
        note("no gap above noise".into(), &mut notes);
    }
    // Gap summary over all observables.
    let sum_g2: f64 = table.gap.iter().map(|g| g * g).sum();
    let sum_r2: f64 = residual_all.iter().map(|r| r * r).sum();
    let noise_floor = (summaries
        .iter()
        .map(|s| s.n as f64 * s.noise_floor_mm.powi(2))
        .sum::<f64>()
        / n_all as f64)
        .sqrt();
    let sources: BTreeSet<&str> = summaries
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
    let m_cells = all_cells.len().max(1) as f64;
    let mk = |o: &str, c: &cells::Cell, ss: f64, total: f64, p: f64| WhereCell {
        covariate: c.covariate.clone(),
        lo: if c.lo.len() == 1 {
            serde_json::json!(c.lo[0])
        } else {
            serde_json::json!(c.lo)
        },
        hi: if c.hi.len() == 1 {
            serde_json::json!(c.hi[0])
        } else {
            serde_json::json!(c.hi)
        },
        observable: o.to_string(),
        share: if total > 0.0 { ss / total } else { 0.0 },
        rms_mm: (ss / c.n.max(1) as f64).sqrt(),
        p_value: (p * m_cells).min(1.0),
        n: c.n,
        rms_before_mm: None,
        shrink: None,
    };
    let mut where_: Vec<WhereCell> = Vec::new();
    let mut where_after: Vec<WhereCell> = Vec::new();
    for (o, sigma, df, c) in &all_cells {
        let p = cells::cell_p(c.sum_g2 / c.n.max(1) as f64, c.n, *sigma, *df);
        if p * m_cells < cfg.alpha {
            where_.push(mk(o, c, c.sum_g2, sum_g2, p));
        }
        let pa = cells::cell_p(c.sum_r2 / c.n.max(1) as f64, c.n, *sigma, *df);
        if pa * m_cells < cfg.alpha {
            let mut w = mk(o, c, c.sum_r2, sum_r2, pa);
            let before = (c.sum_g2 / c.n.max(1) as f64).sqrt();
            w.rms_before_mm = Some(before);
            w.shrink = fin(1.0 - w.rms_mm / before);
            where_after.push(w);
        }
    }
    let order = |a: &WhereCell, b: &WhereCell| {
        b.rms_mm
            .total_cmp(&a.rms_mm)
            .then(a.observable.cmp(&b.observable))
            .then(a.covariate.cmp(&b.covariate))
            .then(a.lo.to_string().cmp(&b.lo.to_string()))
    };
    where_.sort_by(order);
    where_after.sort_by(order);
    // Stable: ties keep the order of first selection.
    selected_keys.sort_by(|a, b| {
        let w = |k: &String| explained_var.get(k).copied().unwrap_or(0.0);
        w(b).total_cmp(&w(a))
    });
    let diagnosis = Diagnosis {
        version: 1,
        observables: table.obs_names.clone(),
        gap: GapSummary {
            rms_mm: (sum_g2 / n_all as f64).sqrt(),
            max_abs_mm: table.gap.iter().fold(0.0, |m, g| m.max(g.abs())),
            noise_floor_mm: noise_floor,
            n: n_all,
        },
        where_,
        effects,
        selected: selected_keys.clone(),
        unexplained: Unexplained {
            rms_mm: (sum_r2 / n_all as f64).sqrt(),
            share: if sum_g2 > 0.0 { sum_r2 / sum_g2 } else { 0.0 },
            where_: where_after,
        },
        noise_floor_source: noise_src,
        cv: CvInfo {
            folds: folds_used,
            by: if blocked {
                "blocked_within_run".into()
            } else {
                "run".into()
            },
            test: PAIRED_TEST.into(),
            seed: cfg.seed,
        },
        per_observable: summaries,
        notes: ordered_notes,
    };
    let per_row = per_row_batch(&batch, &table, &contrib_cols, &selected_keys, &residual_all)?;
    let augmented_model = serde_json::json!({
        "version": 1,
        "kind": "sparkout.augmented_model",
        "applies_as": "real ≈ sim + Σ over effects of (offset_mm + form(covariates; params)), per observable; forms as in CONTRACTS.md catalogue",
        "effects": augmented,
    });
    let report_html = report::section(&diagnosis);
    Ok(DiagnosisOutput {
        diagnosis,
        per_row,
        augmented_model,
        report_html,
    })
}

fn per_row_batch(
    batch: &RecordBatch,
    table: &observations::Table,
    contrib: &BTreeMap<String, Vec<f64>>,
    keys: &[String],
    residual: &[f64],
) -> Result<RecordBatch> {
    let to_utf8 = |name: &str| -> Result<ArrayRef> {
        let a = batch.column_by_name(name).expect("validated");
        Ok(arrow::compute::cast(a, &DataType::Utf8)?)
    };
    let mut fields = vec![
        Field::new("run", DataType::Utf8, false),
        Field::new("observable", DataType::Utf8, false),
        Field::new("gap", DataType::Float64, false),
    ];
    let mut cols: Vec<ArrayRef> = vec![
        to_utf8("run")?,
        to_utf8("observable")?,
        Arc::new(Float64Array::from(table.gap.clone())),
    ];
    for k in keys {
        fields.push(Field::new(format!("contrib_{k}"), DataType::Float64, false));
        cols.push(Arc::new(Float64Array::from(contrib[k].clone())));
    }
    fields.push(Field::new("residual_after", DataType::Float64, false));
    cols.push(Arc::new(Float64Array::from(residual.to_vec())));
    Ok(RecordBatch::try_new(Arc::new(Schema::new(fields)), cols)?)
}

#[cfg(test)]
mod tests;

/// Covariates that change between replicates of one measurement by nature:
/// time, temperature and cumulative usage.
fn is_time_like(name: &str) -> bool {
    name == "t_s" || name == "temp_c" || name == "infeed_count" || name.ends_with("_mm3")
}

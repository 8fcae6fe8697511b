//! Machines kept apart: does one selected effect hold for
//! every machine of an observable, or does each machine need its own?
//!
//! Test (a Chow test): the restricted model is one shape for all machines
//! with a free offset per machine (a machine's offset is a gap of its own,
//! not a disagreement about the effect) — the pooled fit's shape, rescaled,
//! plus per-machine offsets, by least squares; the full model fits the
//! effect on each machine's rows alone. F = ((SSE_r − SSE_u)/Δdf) /
//! (SSE_u/df_u) with Δdf = (M − 1)·n_params (an offset-only effect:
//! M − 1, against one pooled offset). Residuals within a run are correlated, which makes F too
//! liberal on long runs, so the per-machine fits also need a practical
//! gain: ½·ln(SSE_r/SSE_u) ≥ `min_gain`, the selection's own margin.

use std::collections::BTreeMap;

use super::cells::f_sf;
use super::document::MachineFit;
use super::effect::{Effect, EffectData};
use super::fit::solve;
use crate::Result;

/// The outcome of the test for one selected effect.
pub struct MachineTest {
    /// p-value of "one effect for all machines".
    pub p_value: f64,
    /// ½·ln(SSE_r/SSE_u): how much the per-machine fits gain.
    pub gain: f64,
    pub fits: Vec<MachineFit>,
}

impl MachineTest {
    /// The machines disagree: statistically and practically.
    pub fn disagree(&self, alpha: f64, min_gain: f64) -> bool {
        self.p_value < alpha && self.gain >= min_gain
    }
}

/// Per-machine fits of `e` against `target` (rows of one observable), and
/// the test that the machines share one effect. `None` with fewer than
/// two machines or when a machine has too few rows to fit.
pub fn per_machine(
    e: &dyn Effect,
    x: &EffectData,
    target: &[f64],
    machine: &[u32],
    run_ranges: &[std::ops::Range<usize>],
    machine_names: &[String],
) -> Result<Option<MachineTest>> {
    let mut ids = machine.to_vec();
    ids.sort_unstable();
    ids.dedup();
    let m = ids.len();
    let p = e.n_params();
    if m < 2 {
        return Ok(None);
    }
    let covs = e.covariates();
    let n = target.len();
    // Pooled shape, then per-machine offsets + one scale of it.
    let pooled = e.fit(x, target)?;
    let shape = pooled.predict(x);
    let q = if p == 0 { 1 } else { m + 1 };
    let mut g = vec![0.0; q * q];
    let mut h = vec![0.0; q];
    let feat = |i: usize, j: usize| -> f64 {
        if p == 0 {
            1.0
        } else if j < m {
            f64::from(ids[j] == machine[i])
        } else {
            shape[i]
        }
    };
    for (i, &t) in target.iter().enumerate().take(n) {
        for a in 0..q {
            let fa = feat(i, a);
            if fa == 0.0 {
                continue;
            }
            h[a] += fa * t;
            for b in 0..q {
                g[a * q + b] += fa * feat(i, b);
            }
        }
    }
    let Some(beta) = solve(&g, &h) else {
        return Ok(None);
    };
    let sse_r: f64 = (0..n)
        .map(|i| {
            let fit: f64 = (0..q).map(|a| beta[a] * feat(i, a)).sum();
            (target[i] - fit).powi(2)
        })
        .sum();
    // Each machine alone.
    let mut sse_u = 0.0;
    let mut fits = Vec::with_capacity(m);
    for &id in &ids {
        let rows: Vec<usize> = (0..n).filter(|&i| machine[i] == id).collect();
        if rows.len() < p + 3 {
            return Ok(None);
        }
        let store: Vec<Vec<f64>> = covs
            .iter()
            .map(|c| {
                x.require(c)
                    .map(|col| rows.iter().map(|&i| col[i]).collect())
            })
            .collect::<Result<_>>()?;
        let mut xd = EffectData::new(rows.len());
        for (c, v) in covs.iter().zip(&store) {
            xd.push(c, v);
        }
        let y: Vec<f64> = rows.iter().map(|&i| target[i]).collect();
        let Ok(fe) = e.fit(&xd, &y) else {
            return Ok(None);
        };
        let off = fe.offset_mm();
        let pred = fe.predict(&xd);
        sse_u += y
            .iter()
            .zip(&pred)
            .map(|(y, s)| (y - off - s).powi(2))
            .sum::<f64>();
        let runs = run_ranges.iter().filter(|r| machine[r.start] == id).count();
        fits.push(MachineFit {
            machine: machine_names[id as usize].clone(),
            n: rows.len(),
            runs,
            params: fe
                .params()
                .into_iter()
                .filter(|(_, v)| v.is_finite())
                .collect::<BTreeMap<_, _>>(),
            offset_mm: off.is_finite().then_some(off),
        });
    }
    let d1 = ((m - 1) * p.max(1)) as f64;
    let d2 = n as f64 - (m * (p + 1)) as f64;
    if d2 < 1.0 || sse_u.is_nan() || sse_u <= 0.0 {
        return Ok(None);
    }
    let gain = 0.5 * (sse_r.max(sse_u) / sse_u).ln();
    let f = ((sse_r - sse_u).max(0.0) / d1) / (sse_u / d2);
    Ok(Some(MachineTest {
        p_value: f_sf(f, d1, d2),
        gain,
        fits,
    }))
}

/// Where a `where` cell over `machine` localised an observable's gap to one
/// machine, that machine's rows of that observable are diagnosed on their
/// own (the same candidates, folds over its runs): an effect only one
/// machine has is diluted by the others in the fleet-wide fit and may pass
/// no held-out test there. The sub-table has one machine, so this never
/// recurses.
pub fn localised_effects(
    table: &super::observations::Table,
    d: &super::document::Diagnosis,
    cfg: &super::DiagnoseConfig,
    scopes: &[super::EffectScope],
) -> crate::Result<Vec<super::document::MachineEffect>> {
    let mut pairs: Vec<(String, String)> = d
        .where_
        .iter()
        .filter(|c| c.covariate == "machine")
        .filter_map(|c| Some((c.observable.clone(), c.lo.as_label()?.to_string())))
        .collect();
    pairs.sort();
    pairs.dedup();
    let mut found = Vec::new();
    for (observable, machine) in pairs {
        let (Some(m), Some(o)) = (
            table.machine_names.iter().position(|n| *n == machine),
            table.obs_names.iter().position(|n| *n == observable),
        ) else {
            continue;
        };
        let of_obs = table.obs.rows_where(|id| id as usize == o);
        let rows: Vec<usize> = table
            .machine
            .at(&of_obs)
            .into_iter()
            .zip(&of_obs)
            .filter(|(id, _)| *id as usize == m)
            .map(|(_, &i)| i)
            .collect();
        let sub = table.rebuild(&rows)?;
        // A machine's own diagnosis needs held-out runs.
        let Ok(one) = super::run_diagnosis(sub, cfg, scopes) else {
            continue;
        };
        let runs = one.diagnosis.per_observable.first().map_or(0, |p| p.runs);
        for e in one.diagnosis.effects.iter().filter(|e| e.selected) {
            found.push(super::document::MachineEffect {
                machine: machine.clone(),
                observable: observable.clone(),
                effect: e.key(),
                params: e.params.clone(),
                param_units: e.param_units.clone(),
                intervals: e.intervals.clone(),
                shrink: e.shrink,
                shrink_interval: e.shrink_interval,
                runs,
            });
        }
    }
    Ok(found)
}

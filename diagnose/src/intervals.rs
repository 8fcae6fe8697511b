//! An interval on every number.
//!
//! Parameters: the selected effect's all-runs fit is a least-squares fit
//! in z = (offset, amplitudes…, θ). Its covariance is taken two ways from
//! the Jacobian J of the fitted values in z (the θ column by central
//! difference of the features):
//! - pooled noise: s²(J'J)⁻¹, s² = SSE/(n − q) — right when residuals are
//!   independent;
//! - by run: the cluster-robust sandwich (J'J)⁻¹ Σ_runs (J_r'e_r)(J_r'e_r)'
//!   (J'J)⁻¹ · C/(C − 1) — right when residuals within a run are
//!   correlated (a drifting sensor, a warm-up the model lacks), which is
//!   what real runs do.
//!
//! Each reported parameter (a function of z through the form's `params`,
//! differentiated numerically) takes the larger of the two standard errors
//! — never more precision than either the noise or the run-to-run spread
//! supports — and its 95 % interval uses Student's t with n − q degrees of
//! freedom for the pooled estimate or C − 1 for the run estimate,
//! whichever was larger. The check: the spread of the same parameter over
//! the k cross-validation fits (a delete-a-fold jackknife,
//! se² = (k−1)/k·Σ(p_f − p̄)²) is reported beside it as `se_folds`.
//! Effects without a linear form get the fold estimate alone.
//!
//! The held-out shrink 1 − √(SSE_after/SSE_before) gets a 95 % percentile
//! interval from a bootstrap over held-out units (runs, or blocks of runs),
//! seeded, so it is reproducible.

use std::collections::BTreeMap;
use std::ops::Range;

use nalgebra::{DMatrix, DVector};
use rand::{Rng, SeedableRng};
use serde::Serialize;

use super::effect::Effect;
use super::select::{params_of, CandEval, CandFit, Problem};

/// A parameter's uncertainty (diagnosis.json `effects[].intervals`).
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct ParamInterval {
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
    pub se: f64,
    /// 95 % interval.
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
    pub lo: f64,
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
    pub hi: f64,
    /// Where the standard error came from: "pooled", "runs" or "folds".
    pub from: String,
    /// The check: the jackknife spread over the CV folds' fits.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub se_folds: Option<f64>,
}

/// Bootstrap replicates of the shrink interval.
const BOOTSTRAP: usize = 400;

fn t975(df: f64) -> f64 {
    if df.is_nan() || df < 1.0 {
        return f64::NAN;
    }
    crate::student_t::t_quantile(0.975, df)
}

/// Reported parameters (with `offset_mm`) of a parameter vector z.
fn report(e: &dyn Effect, prob: &Problem, z: &[f64], has_theta: bool) -> BTreeMap<String, f64> {
    let form = e.linear_form().expect("linear form");
    let Ok(frame) = prob.frame(e) else {
        return BTreeMap::new();
    };
    let m = form.n_linear();
    let theta = if has_theta { z[m + 1] } else { f64::NAN };
    let (mut p, off) = form.params(&frame, theta, &z[1..=m], z[0]);
    p.insert("offset_mm".into(), off);
    p
}

/// What a chosen effect's all-runs fit was fitted to, over the rows of one
/// run at a time (`None`: not available).
pub type TargetOfRows<'a> = dyn Fn(Range<usize>, &mut Vec<f64>) -> Option<()> + 'a;

/// Intervals of every parameter of chosen effect `e`; `target` gives what
/// its all-runs fit was fitted to, run by run; `runs` are the run units of
/// the rows.
pub fn param_intervals(
    e: &dyn Effect,
    prob: &Problem,
    ev: &CandEval,
    target: &TargetOfRows,
    runs: &[Range<usize>],
) -> BTreeMap<String, ParamInterval> {
    let k = prob.k;
    let folds = fold_spread(e, prob, ev);
    let model = match &ev.fit {
        CandFit::Fast { theta, beta } => {
            model_se(e, prob, theta[k], &beta[k], target, runs).unwrap_or_default()
        }
        CandFit::Slow { .. } => BTreeMap::new(),
    };
    let (mut all, off) = params_of(e, prob, ev, k);
    all.insert("offset_mm".into(), off);
    let mut out = BTreeMap::new();
    for (name, value) in all {
        if !value.is_finite() {
            continue;
        }
        let sf = folds.get(&name).copied().filter(|v| v.is_finite());
        let (se, df, from) = match model.get(&name) {
            Some(&(se, df, from)) if se.is_finite() => (se, df, from),
            _ => match sf {
                Some(s) => (s, (k as f64 - 1.0).max(1.0), "folds"),
                None => continue,
            },
        };
        let h = t975(df) * se;
        out.insert(
            name,
            ParamInterval {
                se,
                lo: value - h,
                hi: value + h,
                from: from.to_string(),
                se_folds: sf,
            },
        );
    }
    out
}

/// Jackknife standard error over the k fold fits, per parameter.
fn fold_spread(e: &dyn Effect, prob: &Problem, ev: &CandEval) -> BTreeMap<String, f64> {
    let k = prob.k;
    if k < 2 {
        return BTreeMap::new();
    }
    let fits: Vec<BTreeMap<String, f64>> = (0..k)
        .map(|f| {
            let (mut p, off) = params_of(e, prob, ev, f);
            p.insert("offset_mm".into(), off);
            p
        })
        .collect();
    let mut out = BTreeMap::new();
    for name in fits[0].keys() {
        let v: Vec<f64> = fits.iter().filter_map(|p| p.get(name).copied()).collect();
        if v.len() != k || v.iter().any(|x| !x.is_finite()) {
            continue;
        }
        let mean = v.iter().sum::<f64>() / k as f64;
        let ss: f64 = v.iter().map(|x| (x - mean).powi(2)).sum();
        out.insert(name.clone(), ((k as f64 - 1.0) / k as f64 * ss).sqrt());
    }
    out
}

/// (se, df, source) per reported parameter from the fit's covariance.
fn model_se(
    e: &dyn Effect,
    prob: &Problem,
    theta: f64,
    beta: &[f64],
    target: &TargetOfRows,
    runs: &[Range<usize>],
) -> Option<BTreeMap<String, (f64, f64, &'static str)>> {
    let form = e.linear_form()?;
    let frame = prob.frame(e).ok()?;
    let m = form.n_linear();
    let n = prob.x.len();
    let has_theta = theta.is_finite();
    let q = m + 1 + usize::from(has_theta);
    if n <= q {
        return None;
    }
    // One pass over the runs, each on its own rows' features (run-sized
    // buffers, never the fleet's): J'J, the SSE and each run's score J_r'e_r
    // are sums of per-run sums, merged in run order (docs/design.md §8).
    debug_assert!(crate::folds::tile(runs, n), "the runs tile the rows");
    let covs = form.covariates();
    let h = 1e-4 * theta.abs().max(1e-12);
    let mut a = DMatrix::<f64>::zeros(q, q);
    let mut sse = 0.0;
    let mut scores: Vec<DVector<f64>> = Vec::with_capacity(runs.len());
    let (mut feats, mut fp, mut fm) = (
        vec![Vec::new(); m],
        vec![Vec::new(); m],
        vec![Vec::new(); m],
    );
    // Jacobian columns of a run: 1, features, ∂(Σ β_j F_j)/∂θ.
    let mut jac: Vec<Vec<f64>> = vec![Vec::new(); q];
    let mut resid: Vec<f64> = Vec::new();
    let mut target_r: Vec<f64> = Vec::new();
    for r in runs {
        let len = r.len();
        target(r.clone(), &mut target_r)?;
        let xs = prob.x.rows_of(&covs, r.clone()).ok()?;
        let xr = xs.data();
        form.features(&frame, &xr, theta, &mut feats).ok()?;
        jac[0].clear();
        jac[0].resize(len, 1.0);
        for (col, f) in jac[1..=m].iter_mut().zip(&feats) {
            col.clear();
            col.extend_from_slice(&f[..len]);
        }
        if has_theta {
            form.features(&frame, &xr, theta + h, &mut fp).ok()?;
            form.features(&frame, &xr, theta - h, &mut fm).ok()?;
            jac[q - 1].clear();
            jac[q - 1].extend((0..len).map(|i| {
                (0..m)
                    .map(|j| beta[j + 1] * (fp[j][i] - fm[j][i]) / (2.0 * h))
                    .sum::<f64>()
            }));
        }
        resid.clear();
        resid.extend((0..len).map(|i| {
            target_r[i] - beta[0] - (0..m).map(|j| beta[j + 1] * feats[j][i]).sum::<f64>()
        }));
        for i in 0..q {
            for j in 0..q {
                a[(i, j)] += super::fit::dot(&jac[i], &jac[j]);
            }
        }
        sse += super::fit::dot(&resid, &resid);
        scores.push(DVector::from_fn(q, |j, _| super::fit::dot(&jac[j], &resid)));
    }
    let a_inv = a
        .clone()
        .try_inverse()
        .or_else(|| a.pseudo_inverse(1e-12).ok())?;
    let df_pooled = (n - q) as f64;
    let v_pooled = &a_inv * (sse / df_pooled);
    let c = runs.len();
    let v_runs = (c >= 3).then(|| {
        let mut meat = DMatrix::<f64>::zeros(q, q);
        for s in &scores {
            meat += s * s.transpose();
        }
        &a_inv * meat * &a_inv * (c as f64 / (c as f64 - 1.0))
    });
    // Reported parameters as functions of z = (offset, β…, θ).
    let mut z: Vec<f64> = beta.to_vec();
    if has_theta {
        z.push(theta);
    }
    let base = report(e, prob, &z, has_theta);
    let mut grads: BTreeMap<String, Vec<f64>> =
        base.keys().map(|k| (k.clone(), vec![0.0; q])).collect();
    for i in 0..q {
        let h = if has_theta && i == q - 1 {
            1e-5 * z[i].abs().max(1e-12)
        } else {
            1e-6 * z[i].abs().max(1e-9)
        };
        let (mut zp, mut zm) = (z.clone(), z.clone());
        zp[i] += h;
        zm[i] -= h;
        let (pp, pm) = (
            report(e, prob, &zp, has_theta),
            report(e, prob, &zm, has_theta),
        );
        for (name, g) in grads.iter_mut() {
            if let (Some(a), Some(b)) = (pp.get(name), pm.get(name)) {
                g[i] = (a - b) / (2.0 * h);
            }
        }
    }
    let quad = |v: &DMatrix<f64>, g: &[f64]| {
        let gv = DVector::from_column_slice(g);
        (gv.transpose() * v * &gv)[(0, 0)].max(0.0).sqrt()
    };
    let mut out = BTreeMap::new();
    for (name, g) in grads {
        let sp = quad(&v_pooled, &g);
        let entry = match &v_runs {
            Some(vr) => {
                let sr = quad(vr, &g);
                if sr > sp {
                    (sr, (c - 1) as f64, "runs")
                } else {
                    (sp, df_pooled, "pooled")
                }
            }
            None => (sp, df_pooled, "pooled"),
        };
        out.insert(name, entry);
    }
    Some(out)
}

/// 95 % bootstrap interval of 1 − √(Σafter/Σbefore) over held-out units.
pub fn shrink_interval(before: &[f64], after: &[f64], seed: u64) -> Option<[f64; 2]> {
    let u: Vec<(f64, f64)> = before
        .iter()
        .zip(after)
        .filter(|(b, a)| b.is_finite() && a.is_finite())
        .map(|(b, a)| (*b, *a))
        .collect();
    if u.len() < 3 {
        return None;
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0xB007_5742_u64);
    let mut s: Vec<f64> = (0..BOOTSTRAP)
        .map(|_| {
            let (mut b, mut a) = (0.0, 0.0);
            for _ in 0..u.len() {
                let (ub, ua) = u[rng.random_range(0..u.len())];
                b += ub;
                a += ua;
            }
            if b > 0.0 {
                1.0 - (a / b).sqrt()
            } else {
                0.0
            }
        })
        .collect();
    s.sort_by(f64::total_cmp);
    let q = |p: f64| s[((p * (s.len() - 1) as f64).round() as usize).min(s.len() - 1)];
    Some([q(0.025), q(0.975)])
}

pub use crate::units::format::format_pm;

/// Intervals of the chosen effects of one observable, in selection order:
/// (parameter intervals, held-out shrink interval).
pub type ChosenIntervals = Vec<(BTreeMap<String, ParamInterval>, Option<[f64; 2]>)>;

pub fn chosen_intervals(
    cands: &[&dyn Effect],
    prob: &Problem,
    sel: &super::select::Selection,
    runs: &[Range<usize>],
    seed: u64,
) -> ChosenIntervals {
    sel.chosen
        .iter()
        .enumerate()
        .map(|(j, &ci)| {
            let ev = &sel.chosen_evals[j];
            // Run by run from the earlier effects' fits (no column of the
            // observable's length), or from the column when one of them
            // predicts only all rows at once.
            let column = (!sel.final_target_is_row_by_row(j))
                .then(|| sel.final_target(prob, cands, j).unwrap_or_default());
            let target = |r: Range<usize>, out: &mut Vec<f64>| -> Option<()> {
                match &column {
                    Some(c) => {
                        out.clear();
                        out.extend_from_slice(c.get(r)?);
                        Some(())
                    }
                    None => sel.final_target_rows(prob, cands, j, r, out).ok().flatten(),
                }
            };
            (
                param_intervals(cands[ci], prob, ev, &target, runs),
                shrink_interval(&sel.chosen_before[j], &ev.unit_sse, seed ^ j as u64),
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats() {
        assert_eq!(format_pm(1.5e-5, 0.08e-5), "1.50e-5 ± 0.08e-5");
        assert_eq!(format_pm(600.0, 25.0), "600 ± 25");
        assert_eq!(format_pm(0.0123, 0.0004), "0.0123 ± 0.0004");
        assert_eq!(format_pm(1.5e-5, 0.0003e-5), "1.5000e-5 ± 0.0003e-5");
        assert_eq!(format_pm(2.5, 0.0012), "2.500 ± 0.001");
    }

    #[test]
    fn shrink_interval_brackets_the_point_estimate() {
        let before = vec![4.0, 5.0, 6.0, 5.5, 4.5, 5.2];
        let after = vec![1.0, 1.2, 0.9, 1.1, 1.3, 1.0];
        let [lo, hi] = shrink_interval(&before, &after, 1).unwrap();
        let point = 1.0 - (6.5f64 / 30.2).sqrt();
        assert!(
            lo <= point && point <= hi && hi - lo < 0.2,
            "{lo} {point} {hi}"
        );
    }
}

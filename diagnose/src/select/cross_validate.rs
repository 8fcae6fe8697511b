//! Cross-validating one candidate: per-fold targets, the fast path for
//! linear forms (sufficient statistics, θ scanned per fold), the slow path
//! (refit per fold) for plugin effects, and each fold's prediction and
//! parameters.

use super::*;
use crate::effect::LinearForm;

/// Per-fold targets (fold k = all runs) and their Σy² per unit.
pub struct Targets {
    pub per_fold: Vec<Arc<Vec<f64>>>,
    distinct: Vec<Arc<Vec<f64>>>,
    of_fold: Vec<usize>,
    yy_u: Vec<Vec<f64>>,
}

impl Targets {
    /// The per-fold targets, the rest let go (so a target held by no one
    /// else can be changed in place).
    pub fn into_per_fold(self) -> Vec<Arc<Vec<f64>>> {
        self.per_fold
    }

    pub fn new(per_fold: Vec<Arc<Vec<f64>>>, units: &[Range<usize>]) -> Targets {
        let mut distinct: Vec<Arc<Vec<f64>>> = Vec::new();
        let mut of_fold = Vec::new();
        for t in &per_fold {
            match distinct.iter().position(|d| Arc::ptr_eq(d, t)) {
                Some(i) => of_fold.push(i),
                None => {
                    of_fold.push(distinct.len());
                    distinct.push(t.clone());
                }
            }
        }
        let yy_u = distinct
            .iter()
            .map(|t| {
                units
                    .iter()
                    .map(|u| dot(&t[u.clone()], &t[u.clone()]))
                    .collect()
            })
            .collect();
        Targets {
            per_fold,
            distinct,
            of_fold,
            yy_u,
        }
    }
}

/// A candidate's cross-validated fit.
pub enum CandFit {
    /// θ and [offset, coefs…] per fold (k + 1 entries).
    Fast {
        theta: Vec<f64>,
        beta: Vec<Vec<f64>>,
    },
    /// A plugin effect without a linear form: one fitted effect per fold.
    Slow { fitted: Vec<Box<dyn FittedEffect>> },
}

pub struct CandEval {
    pub fit: CandFit,
    /// Held-out SSE per unit.
    pub unit_sse: Vec<f64>,
}

/// How much finer than a form's θ-scan resolution the CV folds' training
/// rows are pooled: a feature changes by well under 1 % inside a bin.
const TRAIN_POOL_FINER: f64 = 8.0;

/// Cross-validates one candidate against the current targets.
pub fn evaluate(e: &dyn Effect, prob: &Problem, tg: &Targets) -> Result<CandEval> {
    let masks = prob.train_masks();
    let frame = prob.frame(e)?;
    let Some(form) = e.linear_form() else {
        return evaluate_slow(e, prob, tg, &masks);
    };
    let nf = masks.len();
    let tslices: Vec<&[f64]> = tg.distinct.iter().map(|t| t.as_slice()).collect();
    // Coefficients of folds 0..k fitted on pooled rows (one-covariate θ
    // forms; see below); `None` for a fold fitted on rows.
    let mut pooled_beta: Vec<Option<Vec<f64>>> = vec![None; nf];
    let thetas: Vec<f64> = match form.theta(&frame) {
        None => vec![f64::NAN; nf],
        Some(tr) => {
            // θ is scanned over groups of units that every fold trains on
            // alike (`fit::fold_groups`): the scan costs folds × bins, not
            // runs × bins.
            let groups = fit::fold_groups(&masks, prob.units.len());
            let group_rows: Vec<Vec<Range<usize>>> = groups
                .iter()
                .map(|g| g.iter().map(|&u| prob.units[u].clone()).collect())
                .collect();
            let group_train: Vec<Vec<bool>> = masks
                .iter()
                .map(|m| groups.iter().map(|g| m[g[0]]).collect())
                .collect();
            let group_yy: Vec<Vec<f64>> = tg
                .yy_u
                .iter()
                .map(|yy| {
                    groups
                        .iter()
                        .map(|g| g.iter().map(|&u| yy[u]).sum())
                        .collect()
                })
                .collect();
            // The CV folds' training cells first (`TRAIN_POOL_FINER`), the
            // θ scan's coarser cells from them: one pass over the rows.
            let mut fine_store = Vec::new();
            let fine_rows = scan_rows(
                form.as_ref(),
                &frame,
                &prob.x,
                &group_rows,
                &tslices,
                TRAIN_POOL_FINER,
                &mut fine_store,
            )?;
            let mut store = Vec::new();
            let coarse_rows;
            let rows = if fine_rows.w.is_some() {
                coarse_rows = fit::coarser(form.as_ref(), &frame, &fine_rows, &mut store)?;
                &coarse_rows
            } else {
                &fine_rows
            };
            let spec = FoldSpec {
                train: &group_train,
                target_of_fold: &tg.of_fold,
            };
            let thetas = choose_theta(form.as_ref(), &frame, &tr, rows, &group_yy, &spec)?;
            if fine_rows.w.is_some() {
                // Each CV fold fits at its own θ on its training groups'
                // fine cells, so a row is evaluated once for every fold's
                // held-out score instead of once per fold; fold k (all
                // runs: the reported fit) stays exact on rows.
                let k = prob.k;
                let betas =
                    fit::pooled_fold_betas(form.as_ref(), &frame, &fine_rows, &thetas[..k], &spec)?;
                for (slot, b) in pooled_beta.iter_mut().zip(betas) {
                    *slot = Some(b);
                }
            }
            thetas
        }
    };
    let p = form.n_linear() + 1;
    let mut beta = vec![Vec::new(); nf];
    let mut unit_sse = vec![f64::NAN; prob.units.len()];
    let mut done = vec![false; nf];
    let covs = form.covariates();
    // Fleet-sized feature columns, reused between candidates (`with_columns`).
    with_columns(form.n_linear(), |buf| -> Result<()> {
        for f0 in 0..nf {
            if done[f0] {
                continue;
            }
            let th = thetas[f0];
            if let Some(b) = pooled_beta[f0].take() {
                // Held-out units only, each on its own rows at the fold's θ.
                done[f0] = true;
                let t = tg.of_fold[f0];
                for (u, train) in masks[f0].iter().enumerate() {
                    if !*train {
                        let r = prob.units[u].clone();
                        form.features(&frame, &prob.x.rows_of(&covs, r.clone())?, th, buf)?;
                        let g = fit::design_gram(buf, None, 0..r.len());
                        let h = fit::design_xy(buf, &tslices[t][r.clone()], 0..r.len());
                        unit_sse[u] = fit::sse(&g, &h, tg.yy_u[t][u], &b);
                    }
                }
                beta[f0] = b;
                continue;
            }
            let same: Vec<usize> = (f0..nf)
                .filter(|&f| {
                    !done[f] && pooled_beta[f].is_none() && thetas[f].to_bits() == th.to_bits()
                })
                .collect();
            // Each unit's statistics from its own rows' features (a
            // unit-sized buffer, never a fleet-sized one): features are
            // row by row and a unit's sums run over its rows in order, so
            // the blocks are those of the observable's columns, bit for bit
            // — and what a node holding only that run computes
            // (docs/design.md §8).
            let mut ts: Vec<usize> = same.iter().map(|&f| tg.of_fold[f]).collect();
            ts.sort_unstable();
            ts.dedup();
            let mut g_u: Vec<Vec<f64>> = Vec::with_capacity(prob.units.len());
            let mut h_of: Vec<Vec<Vec<f64>>> = (0..ts.len())
                .map(|_| Vec::with_capacity(prob.units.len()))
                .collect();
            for u in &prob.units {
                form.features(&frame, &prob.x.rows_of(&covs, u.clone())?, th, buf)?;
                g_u.push(fit::design_gram(buf, None, 0..u.len()));
                for (h_u, &t) in h_of.iter_mut().zip(&ts) {
                    h_u.push(fit::design_xy(buf, &tslices[t][u.clone()], 0..u.len()));
                }
            }
            for &f in &same {
                done[f] = true;
                let t = tg.of_fold[f];
                let h_u = &h_of[ts.binary_search(&t).expect("target listed")];
                let (g, h) = fit::train_sums(&g_u, h_u, &masks[f], p);
                let b = fit::solve(&g, &h).ok_or_else(|| err!("singular normal equations"))?;
                for (u, tr) in masks[f].iter().enumerate() {
                    if !*tr {
                        unit_sse[u] = fit::sse(&g_u[u], &h_u[u], tg.yy_u[t][u], &b);
                    }
                }
                beta[f] = b;
            }
        }
        Ok(())
    })?;
    Ok(CandEval {
        fit: CandFit::Fast {
            theta: thetas,
            beta,
        },
        unit_sse,
    })
}

pub(super) fn gather<'a>(
    prob: &Problem,
    covs: &[String],
    rows: &[usize],
    store: &'a mut Vec<Vec<f64>>,
) -> Result<EffectData<'a>> {
    store.clear();
    for c in covs {
        let col = prob.x.require(c)?;
        store.push(rows.iter().map(|&i| col[i]).collect());
    }
    let mut d = EffectData::new(rows.len());
    for (c, v) in covs.iter().zip(store.iter()) {
        d.push(c, v);
    }
    Ok(d)
}

pub(super) fn evaluate_slow(
    e: &dyn Effect,
    prob: &Problem,
    tg: &Targets,
    masks: &[Vec<bool>],
) -> Result<CandEval> {
    let covs = e.covariates();
    let mut fitted = Vec::new();
    let mut unit_sse = vec![f64::NAN; prob.units.len()];
    for (f, m) in masks.iter().enumerate() {
        let rows: Vec<usize> = prob
            .units
            .iter()
            .zip(m)
            .filter(|(_, t)| **t)
            .flat_map(|(u, _)| u.clone())
            .collect();
        let y: Vec<f64> = rows.iter().map(|&i| tg.per_fold[f][i]).collect();
        let mut store = Vec::new();
        let xd = gather(prob, &covs, &rows, &mut store)?;
        let fe = e.fit(&xd, &y)?;
        let pred = fe.predict(&prob.x);
        let off = fe.offset_mm();
        for (u, t) in m.iter().enumerate() {
            if !*t {
                let r = prob.units[u].clone();
                unit_sse[u] = r.map(|i| (tg.per_fold[f][i] - off - pred[i]).powi(2)).sum();
            }
        }
        fitted.push(fe);
    }
    Ok(CandEval {
        fit: CandFit::Slow { fitted },
        unit_sse,
    })
}

/// Fold `f`'s fit ready to predict any rows: a linear form's θ and
/// coefficients with its frame, or a plugin's fitted effect.
enum FoldFit<'a> {
    Linear {
        form: Arc<dyn LinearForm>,
        frame: Frame,
        theta: f64,
        beta: &'a [f64],
    },
    Fitted(&'a dyn FittedEffect),
}

impl<'a> FoldFit<'a> {
    fn of(e: &dyn Effect, prob: &Problem, ev: &'a CandEval, f: usize) -> Result<FoldFit<'a>> {
        Ok(match &ev.fit {
            CandFit::Fast { theta, beta } => FoldFit::Linear {
                form: e.linear_form().expect("fast fit has a form"),
                frame: prob.frame(e)?,
                theta: theta[f],
                beta: &beta[f],
            },
            CandFit::Slow { fitted } => FoldFit::Fitted(fitted[f].as_ref()),
        })
    }

    /// The prediction (offset included) of the rows of `x` into `pred`. A
    /// linear form's is row by row: the same bits for a row whether `x` is
    /// one unit, the trimmed rows or the whole observable.
    fn predict(&self, x: &EffectData, pred: &mut Vec<f64>) -> Result<()> {
        pred.clear();
        match self {
            FoldFit::Linear {
                form,
                frame,
                theta,
                beta,
            } => with_columns(form.n_linear(), |buf| -> Result<()> {
                form.features(frame, x, *theta, buf)?;
                pred.resize(x.len(), beta[0]);
                for (col, bj) in buf.iter().zip(&beta[1..]) {
                    for (o, v) in pred.iter_mut().zip(col.iter()) {
                        *o += bj * v;
                    }
                }
                Ok(())
            }),
            FoldFit::Fitted(fe) => {
                let off = fe.offset_mm();
                pred.extend(fe.predict(x).into_iter().map(|p| p + off));
                Ok(())
            }
        }
    }
}

/// Fold `f`'s prediction (offset included) of the rows of `x` into `pred`
/// (f = k: the all-runs fit, the one reported and replayed).
pub fn fold_prediction(
    e: &dyn Effect,
    prob: &Problem,
    ev: &CandEval,
    f: usize,
    x: &EffectData,
    pred: &mut Vec<f64>,
) -> Result<()> {
    FoldFit::of(e, prob, ev, f)?.predict(x, pred)
}

/// Fold `f`'s fit (offset included) taken out of `target`: each unit's
/// rows predicted from their own features (a unit-sized buffer, bit for
/// bit a prediction over all rows) and subtracted; `held` receives the
/// prediction of the units fold `f` holds out, in row order (fold k holds
/// none out).
pub fn take_out_fold(
    e: &dyn Effect,
    prob: &Problem,
    ev: &CandEval,
    f: usize,
    target: &mut [f64],
    held: &mut Vec<f64>,
) -> Result<()> {
    debug_assert!(
        crate::folds::tile(&prob.units, target.len()),
        "the scoring units tile the rows"
    );
    let is_held = |u: usize| f < prob.k && prob.unit_fold[u] == f;
    let fit = FoldFit::of(e, prob, ev, f)?;
    let mut pred = Vec::new();
    // A plugin's fitted effect predicts the rows it is given with no
    // promise that a row's value is its own alone: all rows at once.
    let covs = match &fit {
        FoldFit::Linear { form, .. } => Some(form.covariates()),
        FoldFit::Fitted(_) => {
            fit.predict(&prob.x, &mut pred)?;
            None
        }
    };
    for (u, r) in prob.units.iter().enumerate() {
        let p = match &covs {
            None => &pred[r.clone()],
            Some(covs) => {
                fit.predict(&prob.x.rows_of(covs, r.clone())?, &mut pred)?;
                &pred[..]
            }
        };
        for (y, p) in target[r.clone()].iter_mut().zip(p) {
            *y -= p;
        }
        if is_held(u) {
            held.extend_from_slice(p);
        }
    }
    Ok(())
}

/// Contract parameters and offset of fold `f`'s fit (f = k: all runs).
pub fn params_of(
    e: &dyn Effect,
    prob: &Problem,
    ev: &CandEval,
    f: usize,
) -> (BTreeMap<String, f64>, f64) {
    match &ev.fit {
        CandFit::Fast { theta, beta } => {
            let form = e.linear_form().expect("fast");
            match prob.frame(e) {
                Ok(frame) => form.params(&frame, theta[f], &beta[f][1..], beta[f][0]),
                Err(_) => (BTreeMap::new(), f64::NAN),
            }
        }
        CandFit::Slow { fitted } => (fitted[f].params(), fitted[f].offset_mm()),
    }
}

//! Least squares from additive sufficient statistics, and the 1-D search of
//! a form's nonlinear parameter θ.
//!
//! Why sufficient statistics: for a model linear in its coefficients β, the
//! normal equations X'WX β = X'Wy are sums over rows. Computing X'X, X'y and
//! y'y once per *unit* (a run, or a block of a run) lets every fold of the
//! leave-runs-out cross-validation fit from the sum over its training units
//! and score each held-out unit exactly as y'y − 2β'X'y + β'X'Xβ — no row is
//! touched per fold ("Speed"). For the θ scan, rows are first pooled into
//! cells of the form's covariates (`LinearForm::pool_resolutions`: θ's
//! resolution, or a thousandth of a linear covariate's range), so each grid
//! value costs a pass over cells, not rows; the chosen θ is then refined by
//! golden section. The CV folds fit at their θ on finer cells and score
//! their held-out units exactly on rows (docs/models.md §8.1).

use std::borrow::Cow;
use std::ops::Range;

use crate::bail;
use nalgebra::{DMatrix, DVector};

use super::{Columns, EffectData, Frame, LinearForm, ThetaRange};
use crate::Result;

pub mod pool;
pub use pool::CellPool;

/// X'WX (p×p, p = 1 + n_linear; column 0 is the offset).
pub fn design_gram(feats: &[Vec<f64>], w: Option<&[f64]>, r: Range<usize>) -> Vec<f64> {
    let p = feats.len() + 1;
    let mut g = vec![0.0; p * p];
    let n = match w {
        Some(w) => w[r.clone()].iter().sum(),
        None => r.len() as f64,
    };
    g[0] = n;
    // Unweighted, the features' sums side by side (`sums_in_order`).
    let sums = match w {
        Some(_) => Vec::new(),
        None => {
            let cols: Vec<&[f64]> = feats.iter().map(|f| &f[r.clone()]).collect();
            sums_in_order(&cols)
        }
    };
    for j in 0..feats.len() {
        let fj = &feats[j][r.clone()];
        let s = match w {
            Some(w) => dot(fj, &w[r.clone()]),
            None => sums[j],
        };
        g[j + 1] = s;
        g[(j + 1) * p] = s;
        for k in j..feats.len() {
            let fk = &feats[k][r.clone()];
            let s = match w {
                Some(w) => dot3(fj, fk, &w[r.clone()]),
                None => dot(fj, fk),
            };
            g[(j + 1) * p + k + 1] = s;
            g[(k + 1) * p + j + 1] = s;
        }
    }
    g
}

/// X'y (length p) where `sy` holds y (rows) or Σy (pooled rows).
pub fn design_xy(feats: &[Vec<f64>], sy: &[f64], r: Range<usize>) -> Vec<f64> {
    let sum = sy[r.clone()].iter().sum();
    design_xy_summed(feats, sy, r, sum)
}

/// [`design_xy`] with Σ sy over `r` already taken (`sum_sy`, the bits of
/// `iter().sum()`, e.g. by [`sums_in_order`]): a unit's Σy is the same
/// for every candidate scored on it, so it is summed once, not per
/// candidate.
pub fn design_xy_summed(feats: &[Vec<f64>], sy: &[f64], r: Range<usize>, sum_sy: f64) -> Vec<f64> {
    let mut h = Vec::with_capacity(feats.len() + 1);
    h.push(sum_sy);
    for f in feats {
        h.push(dot(&f[r.clone()], &sy[r.clone()]));
    }
    h
}

/// Each column's sum, added in row order from the start value of
/// `iter().sum()` — its bits exactly — with the columns side by side in one
/// loop: a sum in order waits on its previous add (a few cycles a row), so
/// several independent ones interleaved cost about what one does.
pub fn sums_in_order(cols: &[&[f64]]) -> Vec<f64> {
    // Row i of every column in one step: the loop is over rows, not over
    // one column.
    #[allow(clippy::needless_range_loop)]
    fn side_by_side<const N: usize>(cols: &[&[f64]], out: &mut Vec<f64>) {
        let zero: f64 = std::iter::empty::<f64>().sum();
        let n = cols[0].len();
        assert!(cols.iter().all(|c| c.len() == n), "columns of one length");
        let c: [&[f64]; N] = std::array::from_fn(|j| &cols[j][..n]);
        let mut s = [zero; N];
        for i in 0..n {
            for j in 0..N {
                s[j] += c[j][i];
            }
        }
        out.extend_from_slice(&s);
    }
    let mut out = Vec::with_capacity(cols.len());
    for part in cols.chunks(4) {
        match part.len() {
            1 => side_by_side::<1>(part, &mut out),
            2 => side_by_side::<2>(part, &mut out),
            3 => side_by_side::<3>(part, &mut out),
            _ => side_by_side::<4>(part, &mut out),
        }
    }
    out
}

/// Four-way unrolled dot product (f64 sums do not auto-vectorise otherwise).
pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (mut s0, mut s1, mut s2, mut s3) = (0.0, 0.0, 0.0, 0.0);
    let mut i = 0;
    while i + 4 <= n {
        s0 += a[i] * b[i];
        s1 += a[i + 1] * b[i + 1];
        s2 += a[i + 2] * b[i + 2];
        s3 += a[i + 3] * b[i + 3];
        i += 4;
    }
    while i < n {
        s0 += a[i] * b[i];
        i += 1;
    }
    (s0 + s1) + (s2 + s3)
}

fn dot3(a: &[f64], b: &[f64], c: &[f64]) -> f64 {
    let n = a.len().min(b.len()).min(c.len());
    let (mut s0, mut s1) = (0.0, 0.0);
    let mut i = 0;
    while i + 2 <= n {
        s0 += a[i] * b[i] * c[i];
        s1 += a[i + 1] * b[i + 1] * c[i + 1];
        i += 2;
    }
    if i < n {
        s0 += a[i] * b[i] * c[i];
    }
    s0 + s1
}

pub fn add_into(acc: &mut [f64], v: &[f64]) {
    for (a, b) in acc.iter_mut().zip(v) {
        *a += b;
    }
}

/// Solves G β = h (symmetric positive semi-definite). Cholesky with a tiny
/// ridge for conditioning; a singular system (collinear features) falls back
/// to the SVD minimum-norm solution.
pub fn solve(g: &[f64], h: &[f64]) -> Option<Vec<f64>> {
    let p = h.len();
    if p == 0 {
        return Some(Vec::new());
    }
    let scale = (0..p).map(|i| g[i * p + i].abs()).fold(0.0, f64::max);
    if scale.is_nan() || scale <= 0.0 || !scale.is_finite() {
        return None;
    }
    let mut m = DMatrix::from_row_slice(p, p, g);
    for i in 0..p {
        m[(i, i)] += 1e-12 * scale;
    }
    let b = DVector::from_column_slice(h);
    if let Some(ch) = m.clone().cholesky() {
        let x = ch.solve(&b);
        if x.iter().all(|v| v.is_finite()) {
            return Some(x.iter().copied().collect());
        }
    }
    let svd = m.svd(true, true);
    svd.solve(&b, 1e-10 * scale)
        .ok()
        .map(|x| x.iter().copied().collect())
}

/// y'y − 2β'h + β'Gβ: the SSE of coefficients β on a unit's statistics.
pub fn sse(g: &[f64], h: &[f64], yy: f64, beta: &[f64]) -> f64 {
    let p = beta.len();
    let mut quad = 0.0;
    for i in 0..p {
        let mut s = 0.0;
        for j in 0..p {
            s += g[i * p + j] * beta[j];
        }
        quad += beta[i] * s;
    }
    (yy - 2.0 * dot(beta, h) + quad).max(0.0)
}

/// Rows (or pooled bins) over which θ is scanned: one covariate column
/// (pooled) or the original rows, weights, and per-target Σy per row.
pub struct ScanRows<'a> {
    pub x: EffectData<'a>,
    pub w: Option<Vec<f64>>,
    /// Σy per (pseudo-)row for each distinct target: the targets
    /// themselves when rows are not pooled (fleet-sized: not copied).
    pub sy: Vec<Cow<'a, [f64]>>,
    /// The rows of each scan unit (a group of units, [`fold_groups`]).
    pub units: Vec<Vec<Range<usize>>>,
}

/// The units grouped by the folds that train on them: units every fold
/// treats alike are summed together in the θ scan, so its cost depends on
/// the number of folds, not of runs (a fleet of 500 runs is 6 groups for
/// 5 folds; with the rows of a group pooled into one set of covariate bins,
/// the 10⁶-row scan went from 10⁶ rows per grid value to a few thousand
/// bins). Groups in order of their first unit; members in unit order.
pub fn fold_groups(train: &[Vec<bool>], n_units: usize) -> Vec<Vec<usize>> {
    let mut groups: Vec<Vec<usize>> = Vec::new();
    let mut pattern_of_group: Vec<Vec<bool>> = Vec::new();
    for u in 0..n_units {
        let pattern: Vec<bool> = train.iter().map(|m| m[u]).collect();
        match pattern_of_group.iter().position(|p| *p == pattern) {
            Some(g) => groups[g].push(u),
            None => {
                pattern_of_group.push(pattern);
                groups.push(vec![u]);
            }
        }
    }
    groups
}

/// Pooled covariates (a column each), counts, Σy per target, pooled unit
/// ranges.
pub type Pooled = (Vec<Vec<f64>>, Vec<f64>, Vec<Vec<f64>>, Vec<Range<usize>>);

/// Per-unit X'X, and X'y per target per unit.
type UnitStats = (Vec<Vec<f64>>, Vec<Vec<Vec<f64>>>);

/// Pools the rows of each unit — a unit being one or more row ranges —
/// into cells of width `res[j]` of each covariate `cols[j]` counted from
/// `mins[j]` (cell value = the mean of each covariate inside), the grid
/// spanning the columns' values. Rows may themselves be pooled cells:
/// `weights` are their counts and `targets` their Σy, so coarse cells come
/// from fine ones without the rows. Returns the pooled covariates, the
/// counts, Σy per target and the pooled unit ranges (one per unit); cells
/// in ascending order.
///
/// A unit's cells are merged from its ranges' own ([`CellPool`]): each
/// range (a run, or a block of one) is pooled on its own — sums in row
/// order — and a cell's sums are its ranges' partial sums added in range
/// order (docs/design.md §8).
pub fn pool_rows(
    cols: &[&[f64]],
    mins: &[f64],
    res: &[f64],
    weights: Option<&[f64]>,
    units: &[Vec<Range<usize>>],
    targets: &[&[f64]],
) -> Pooled {
    let axes = pool::spans(cols, mins)
        .into_iter()
        .zip(mins.iter().zip(res))
        .map(|(span, (&min, &r))| pool::Axis::new(min, span, r))
        .collect();
    let mut cells = CellPool::new(axes, targets.len(), units.len());
    cells.add_groups(units, cols, weights, targets);
    cells.finish()
}

/// Folds as seen by the fitter: which units train each fold, and which
/// target (index into the targets) each fold fits.
pub struct FoldSpec<'a> {
    pub train: &'a [Vec<bool>],
    pub target_of_fold: &'a [usize],
}

/// Per-unit G and per-target, per-unit h for one θ over scan rows.
fn unit_stats(
    form: &dyn LinearForm,
    frame: &Frame,
    rows: &ScanRows,
    theta: f64,
    buf: &mut [Vec<f64>],
) -> Result<UnitStats> {
    form.features(frame, &rows.x, theta, buf)?;
    Ok(unit_stats_of(buf, rows))
}

/// Per-unit G and per-target, per-unit h of features `buf` of scan rows.
fn unit_stats_of(buf: &[Vec<f64>], rows: &ScanRows) -> UnitStats {
    let per_range = |u: &Range<usize>| match (buf.len(), rows.w.as_deref()) {
        (1, Some(w)) => unit_moments::<1>(buf, w, &rows.sy, u.clone()),
        (2, Some(w)) => unit_moments::<2>(buf, w, &rows.sy, u.clone()),
        (_, w) => (
            design_gram(buf, w, u.clone()),
            rows.sy
                .iter()
                .map(|sy| design_xy(buf, sy, u.clone()))
                .collect(),
        ),
    };
    // A unit of several ranges (unpooled rows of a group) sums its ranges.
    let per_unit = |ranges: &[Range<usize>]| {
        let mut it = ranges.iter();
        let (mut g, mut h) = match it.next() {
            Some(r) => per_range(r),
            None => per_range(&(0..0)),
        };
        for r in it {
            let (g_r, h_r) = per_range(r);
            add_into(&mut g, &g_r);
            for (h_t, x) in h.iter_mut().zip(&h_r) {
                add_into(h_t, x);
            }
        }
        (g, h)
    };
    // g by unit, h by [target][unit]: each unit's vectors moved into place.
    let mut g = Vec::with_capacity(rows.units.len());
    let mut h = vec![Vec::with_capacity(rows.units.len()); rows.sy.len()];
    for u in &rows.units {
        let (g_u, h_u) = per_unit(u);
        g.push(g_u);
        for (h_t, x) in h.iter_mut().zip(h_u) {
            h_t.push(x);
        }
    }
    (g, h)
}

/// Lanes of the fused sums (independent accumulators the loop vectorises).
const LANES: usize = 4;

/// Rows of a column `a` and `F` feature columns (all `a.len()` long), each
/// handed to `row` with its lane: whole groups of [`LANES`] rows sliced once
/// (no bounds check per value) with a constant lane each (independent sums
/// the compiler keeps in registers), then the tail in lane 0.
#[inline(always)]
fn in_lanes<const F: usize>(a: &[f64], f: [&[f64]; F], mut row: impl FnMut(f64, [f64; F], usize)) {
    let n = a.len();
    let whole = n / LANES * LANES;
    for c in (0..whole).step_by(LANES) {
        let a4 = &a[c..c + LANES];
        let f4: [&[f64]; F] = std::array::from_fn(|j| &f[j][c..c + LANES]);
        for l in 0..LANES {
            row(a4[l], std::array::from_fn(|j| f4[j][l]), l);
        }
    }
    for i in whole..n {
        row(a[i], std::array::from_fn(|j| f[j][i]), 0);
    }
}

/// [`design_gram`] with weights and [`design_xy`] of every target over one
/// unit's pooled rows in one pass per matrix: the θ scan's inner loop (its
/// six to nine separate dot products were half the diagnosis' time), the
/// columns read once, the sums in [`LANES`] lanes. `F` features.
fn unit_moments<const F: usize>(
    feats: &[Vec<f64>],
    w: &[f64],
    sy: &[Cow<[f64]>],
    r: Range<usize>,
) -> (Vec<f64>, Vec<Vec<f64>>) {
    let w = &w[r.clone()];
    let n = w.len();
    let f: [&[f64]; F] = std::array::from_fn(|j| &feats[j][r.clone()][..n]);
    let lanes = |acc: &[f64; LANES]| (acc[0] + acc[1]) + (acc[2] + acc[3]);
    let p = F + 1;
    let mut g = vec![0.0; p * p];
    {
        let (mut sw, mut s1, mut s2) = ([0.0; LANES], [[0.0; LANES]; F], [[[0.0; LANES]; F]; F]);
        in_lanes(w, f, |wi, x, l| {
            sw[l] += wi;
            for j in 0..F {
                let wa = wi * x[j];
                s1[j][l] += wa;
                for k in j..F {
                    s2[j][k][l] += wa * x[k];
                }
            }
        });
        g[0] = lanes(&sw);
        for j in 0..F {
            let s = lanes(&s1[j]);
            g[j + 1] = s;
            g[(j + 1) * p] = s;
            for k in j..F {
                let s = lanes(&s2[j][k]);
                g[(j + 1) * p + k + 1] = s;
                g[(k + 1) * p + j + 1] = s;
            }
        }
    }
    let h = sy
        .iter()
        .map(|sy| {
            let sy = &sy[r.clone()][..n];
            let (mut s0, mut s1) = ([0.0; LANES], [[0.0; LANES]; F]);
            in_lanes(sy, f, |y, x, l| {
                s0[l] += y;
                for j in 0..F {
                    s1[j][l] += x[j] * y;
                }
            });
            std::iter::once(lanes(&s0))
                .chain(s1.iter().map(lanes))
                .collect()
        })
        .collect();
    (g, h)
}

/// X'X and X'y of a fold: the sums of its training units' (`train[u]`)
/// per-unit statistics, in unit order.
pub fn train_sums(
    g_u: &[Vec<f64>],
    h_u: &[Vec<f64>],
    train: &[bool],
    p: usize,
) -> (Vec<f64>, Vec<f64>) {
    let mut g = vec![0.0; p * p];
    let mut h = vec![0.0; p];
    for (u, t) in train.iter().enumerate() {
        if *t {
            add_into(&mut g, &g_u[u]);
            add_into(&mut h, &h_u[u]);
        }
    }
    (g, h)
}

/// Training SSE at the least-squares optimum: y'y − β'h.
fn train_sse(g_u: &[Vec<f64>], h_u: &[Vec<f64>], yy_u: &[f64], train: &[bool], p: usize) -> f64 {
    let (g, h) = train_sums(g_u, h_u, train, p);
    let yy: f64 = yy_u
        .iter()
        .zip(train)
        .filter(|(_, t)| **t)
        .map(|(y, _)| y)
        .sum();
    match solve(&g, &h) {
        Some(b) => sse(&g, &h, yy, &b),
        None => f64::INFINITY,
    }
}

/// Chooses θ per fold: coarse grid on the scan rows, then golden-section
/// refinement between the best grid value's neighbours (in log θ, or in
/// frequency 1/θ for periodic), all on the fold's training units.
/// `yy_u[t][u]` is Σy² of target t in unit u.
pub fn choose_theta(
    form: &dyn LinearForm,
    frame: &Frame,
    tr: &ThetaRange,
    rows: &ScanRows,
    yy_u: &[Vec<f64>],
    folds: &FoldSpec,
) -> Result<Vec<f64>> {
    super::with_columns(form.n_linear(), |buf| {
        choose_theta_in(form, frame, tr, rows, yy_u, folds, buf)
    })
}

/// [`choose_theta`] with the feature columns it fills.
fn choose_theta_in(
    form: &dyn LinearForm,
    frame: &Frame,
    tr: &ThetaRange,
    rows: &ScanRows,
    yy_u: &[Vec<f64>],
    folds: &FoldSpec,
    buf: &mut Columns,
) -> Result<Vec<f64>> {
    let p = form.n_linear() + 1;
    let nf = folds.train.len();
    let mut best = vec![(f64::INFINITY, 0usize); nf];
    form.features_grid(frame, &rows.x, &tr.grid, buf, &mut |gi, feats| {
        let (g_u, h_u) = unit_stats_of(feats, rows);
        for (f, b) in best.iter_mut().enumerate() {
            let t = folds.target_of_fold[f];
            let s = train_sse(&g_u, &h_u[t], &yy_u[t], &folds.train[f], p);
            if s < b.0 {
                *b = (s, gi);
            }
        }
        Ok(())
    })?;
    let to = |th: f64| {
        if tr.refine_in_frequency {
            1.0 / th
        } else {
            th.ln()
        }
    };
    let from = |z: f64| {
        if tr.refine_in_frequency {
            1.0 / z
        } else {
            z.exp()
        }
    };
    let mut out = Vec::with_capacity(nf);
    let mut refined: std::collections::HashMap<u64, UnitStats> = std::collections::HashMap::new();
    for (f, &(best_sse, gi)) in best.iter().enumerate() {
        let lo_t = tr.grid[gi.saturating_sub(1)];
        let hi_t = tr.grid[(gi + 1).min(tr.grid.len() - 1)];
        let (mut a, mut b) = (to(lo_t), to(hi_t));
        if a > b {
            std::mem::swap(&mut a, &mut b);
        }
        let t = folds.target_of_fold[f];
        // Folds that share a best grid value start from the same bracket and
        // mostly walk the same points: the unit statistics at a point are
        // the same for every fold, so each is computed once.
        let mut eval = |z: f64| -> Result<f64> {
            let (g_u, h_u) = match refined.entry(z.to_bits()) {
                std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
                std::collections::hash_map::Entry::Vacant(e) => {
                    e.insert(unit_stats(form, frame, rows, from(z), buf)?)
                }
            };
            Ok(train_sse(g_u, &h_u[t], &yy_u[t], &folds.train[f], p))
        };
        let (mut bz, mut bs) = (to(tr.grid[gi]), best_sse);
        if b > a {
            let r = 0.5 * (5f64.sqrt() - 1.0);
            let (mut x1, mut x2) = (b - r * (b - a), a + r * (b - a));
            let (mut f1, mut f2) = (eval(x1)?, eval(x2)?);
            for _ in 0..20 {
                if f1 < f2 {
                    b = x2;
                    x2 = x1;
                    f2 = f1;
                    x1 = b - r * (b - a);
                    f1 = eval(x1)?;
                } else {
                    a = x1;
                    x1 = x2;
                    f1 = f2;
                    x2 = a + r * (b - a);
                    f2 = eval(x2)?;
                }
            }
            for (z, s) in [(x1, f1), (x2, f2)] {
                if s < bs {
                    bz = z;
                    bs = s;
                }
            }
        }
        out.push(from(bz).clamp(tr.lo.min(tr.hi), tr.hi.max(tr.lo)));
    }
    Ok(out)
}

/// Coefficients [offset, coefs…] of each fold `f < thetas.len()` fitted at
/// its θ on the pooled scan rows of its training groups (`folds.train[f]`
/// over the groups of `rows`). The held-out score needs only the fold's
/// own rows at its θ, so each row is evaluated once for all folds instead
/// of once per fold (`LinearForm::pool_resolutions` bounds what pooling
/// changes; docs/models.md §8.1).
pub fn pooled_fold_betas(
    form: &dyn LinearForm,
    frame: &Frame,
    rows: &ScanRows,
    thetas: &[f64],
    folds: &FoldSpec,
) -> Result<Vec<Vec<f64>>> {
    let p = form.n_linear() + 1;
    super::with_columns(form.n_linear(), |buf| {
        let mut at: Vec<(u64, UnitStats)> = Vec::new();
        let mut out = Vec::with_capacity(thetas.len());
        for (f, &th) in thetas.iter().enumerate() {
            let i = match at.iter().position(|(b, _)| *b == th.to_bits()) {
                Some(i) => i,
                None => {
                    at.push((th.to_bits(), unit_stats(form, frame, rows, th, buf)?));
                    at.len() - 1
                }
            };
            let (g_u, h_u) = &at[i].1;
            let t = folds.target_of_fold[f];
            let (g, h) = train_sums(g_u, &h_u[t], &folds.train[f], p);
            match solve(&g, &h) {
                Some(b) => out.push(b),
                None => bail!("singular normal equations"),
            }
        }
        Ok(out)
    })
}

/// Builds the scan rows of a form over `x`: pooled into cells of the
/// covariates at the form's pooling resolutions divided by `finer`
/// ([`LinearForm::pool_resolutions`]), or the original rows when it has
/// none. `units`: the row ranges of each scan unit (a group of
/// [`fold_groups`]).
#[allow(clippy::too_many_arguments)]
pub fn scan_rows<'a>(
    form: &dyn LinearForm,
    frame: &Frame,
    x: &EffectData<'a>,
    units: &[Vec<Range<usize>>],
    targets: &[&'a [f64]],
    finer: f64,
    pooled_store: &'a mut Vec<Vec<f64>>,
) -> Result<ScanRows<'a>> {
    let covs = form.covariates();
    let res = form
        .pool_resolutions(frame)
        .filter(|r| r.len() == covs.len() && r.iter().all(|v| *v > 0.0 && v.is_finite()));
    let Some(res) = res else {
        return Ok(ScanRows {
            x: x.clone(),
            w: None,
            sy: targets.iter().map(|t| Cow::Borrowed(*t)).collect(),
            units: units.to_vec(),
        });
    };
    let cols: Vec<&[f64]> = covs.iter().map(|c| x.require(c)).collect::<Result<_>>()?;
    let mins: Vec<f64> = frame.iter().map(|s| s.min).collect();
    let res: Vec<f64> = res.iter().map(|r| r / finer).collect();
    let pooled = pool_rows(&cols, &mins, &res, None, units, targets);
    Ok(scan_rows_of_cells(&covs, pooled, pooled_store))
}

/// Scan rows over pooled cells (of covariates `covs`), their covariate
/// columns kept in `store`.
pub fn scan_rows_of_cells<'a>(
    covs: &[String],
    (xc, w, sy, pu): Pooled,
    store: &'a mut Vec<Vec<f64>>,
) -> ScanRows<'a> {
    *store = xc;
    let columns: &'a Vec<Vec<f64>> = store;
    let mut x = EffectData::new(w.len());
    for (c, v) in covs.iter().zip(columns) {
        x.push(c, v);
    }
    ScanRows {
        x,
        w: Some(w),
        sy: sy.into_iter().map(Cow::Owned).collect(),
        units: pu.into_iter().map(|r| vec![r]).collect(),
    }
}

/// Pooled scan rows pooled again into the form's own (coarser) cells:
/// the θ scan's rows from the CV folds' finer ones without another pass
/// over the rows. `rows` must be pooled ([`scan_rows`] with `finer` ≥ 1).
pub fn coarser<'a>(
    form: &dyn LinearForm,
    frame: &Frame,
    rows: &ScanRows,
    pooled_store: &'a mut Vec<Vec<f64>>,
) -> Result<ScanRows<'a>> {
    let covs = form.covariates();
    let (Some(res), Some(w)) = (form.pool_resolutions(frame), rows.w.as_deref()) else {
        bail!("coarser cells of rows that are not pooled");
    };
    let cols: Vec<&[f64]> = covs
        .iter()
        .map(|c| rows.x.require(c))
        .collect::<Result<_>>()?;
    let mins: Vec<f64> = frame.iter().map(|s| s.min).collect();
    let targets: Vec<&[f64]> = rows.sy.iter().map(|t| t.as_ref()).collect();
    let pooled = pool_rows(&cols, &mins, &res, Some(w), &rows.units, &targets);
    Ok(scan_rows_of_cells(&covs, pooled, pooled_store))
}

/// One least-squares fit of a form: θ (NaN when linear), coefficients of
/// the shape features, offset (feature-space; see `LinearForm::params`).
#[derive(Debug, Clone)]
pub struct FormFit {
    pub theta: f64,
    pub coef: Vec<f64>,
    pub offset: f64,
}

/// Fits a form with an offset on all rows of `x` (the `Effect::fit` path
/// and the augmented model): θ scan + refine, then exact least squares.
pub fn fit_form(
    form: &dyn LinearForm,
    frame: &Frame,
    x: &EffectData,
    y: &[f64],
) -> Result<FormFit> {
    let n = x.len();
    if y.len() != n {
        bail!("fit: {} gap values for {} rows", y.len(), n);
    }
    let p = form.n_linear() + 1;
    if n < p {
        bail!("fit: {n} observations for {p} parameters");
    }
    let units = vec![vec![0..n]];
    let theta = match form.theta(frame) {
        None => f64::NAN,
        Some(tr) => {
            let mut store = Vec::new();
            let rows = scan_rows(form, frame, x, &units, &[y], 1.0, &mut store)?;
            let yy = vec![vec![dot(y, y)]];
            let train = vec![vec![true]];
            let spec = FoldSpec {
                train: &train,
                target_of_fold: &[0],
            };
            choose_theta(form, frame, &tr, &rows, &yy, &spec)?[0]
        }
    };
    let (g, h) = super::with_columns(form.n_linear(), |buf| -> Result<_> {
        form.features(frame, x, theta, buf)?;
        Ok((design_gram(buf, None, 0..n), design_xy(buf, y, 0..n)))
    })?;
    let beta = solve(&g, &h).ok_or_else(|| crate::err!("fit: singular normal equations"))?;
    Ok(FormFit {
        theta,
        coef: beta[1..].to_vec(),
        offset: beta[0],
    })
}

#[cfg(test)]
mod tests {
    /// A seeded uniform on [0, 1) (xorshift64): the pooling tests' data.
    pub(super) fn uniform(mut state: u64) -> impl FnMut() -> f64 {
        move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    use super::*;

    #[test]
    fn solve_recovers_linear_coefficients() {
        // y = 2 + 3 f
        let f = vec![(0..50).map(|i| i as f64 / 10.0).collect::<Vec<_>>()];
        let y: Vec<f64> = f[0].iter().map(|v| 2.0 + 3.0 * v).collect();
        let g = design_gram(&f, None, 0..50);
        let h = design_xy(&f, &y, 0..50);
        let b = solve(&g, &h).unwrap();
        assert!((b[0] - 2.0).abs() < 1e-9 && (b[1] - 3.0).abs() < 1e-9);
        assert!(sse(&g, &h, dot(&y, &y), &b) < 1e-9);
    }

    #[test]
    fn fused_unit_moments_are_the_separate_sums() {
        let n = 203;
        let col =
            |k: f64| -> Vec<f64> { (0..n).map(|i| ((i as f64) * k).sin() + 0.1 * k).collect() };
        let feats = vec![col(0.37), col(1.3)];
        let w: Vec<f64> = (0..n).map(|i| 1.0 + (i % 5) as f64).collect();
        let sy = [col(0.11), col(2.9)];
        let sy_cow: Vec<Cow<[f64]>> = sy.iter().map(|v| Cow::Borrowed(&v[..])).collect();
        for r in [0..n, 17..18, 40..131, 5..5] {
            let one = super::unit_moments::<1>(&feats[..1], &w, &sy_cow, r.clone());
            let two = super::unit_moments::<2>(&feats, &w, &sy_cow, r.clone());
            for (fused, f) in [(one, &feats[..1]), (two, &feats[..])] {
                let g = design_gram(f, Some(&w), r.clone());
                let close = |a: &[f64], b: &[f64]| {
                    a.len() == b.len()
                        && a.iter()
                            .zip(b)
                            .all(|(x, y)| (x - y).abs() <= 1e-12 * (1.0 + y.abs()))
                };
                assert!(close(&fused.0, &g), "{:?} vs {g:?}", fused.0);
                for (t, s) in sy.iter().enumerate() {
                    assert!(close(&fused.1[t], &design_xy(f, s, r.clone())));
                }
            }
        }
    }

    #[test]
    fn pooling_keeps_sums() {
        let c: Vec<f64> = (0..100).map(|i| (i % 10) as f64).collect();
        let y: Vec<f64> = (0..100).map(|i| i as f64).collect();
        let unit = |r: Range<usize>| vec![r];
        let (xc, w, sy, u) = pool_rows(
            &[&c],
            &[0.0],
            &[0.5],
            None,
            &[unit(0..50), unit(50..100)],
            &[&y],
        );
        assert_eq!(u.len(), 2);
        assert_eq!(xc[0].len(), 20);
        assert_eq!(w.iter().sum::<f64>(), 100.0);
        assert!((sy[0].iter().sum::<f64>() - y.iter().sum::<f64>()).abs() < 1e-9);
        // A unit of two ranges pools them into one set of bins.
        let (xc, w, sy, u) = pool_rows(&[&c], &[0.0], &[0.5], None, &[vec![0..30, 70..100]], &[&y]);
        assert_eq!(u, vec![0..10]);
        assert_eq!(xc[0], (0..10).map(f64::from).collect::<Vec<_>>());
        assert_eq!(w, vec![6.0; 10]);
        let want: f64 = (0..30).chain(70..100).map(f64::from).sum();
        assert_eq!(sy[0].iter().sum::<f64>(), want);
    }

    /// One covariate: the sums of a target are the same bits whether it is
    /// pooled alone (sums held in a small array) or among eight (held in a
    /// vector), over a unit of one range and one of several.
    #[test]
    fn pooling_one_covariate_holds_sums_alike_for_any_target_count() {
        let n = 3_000;
        let c: Vec<f64> = (0..n).map(|i| ((i * 37) % 101) as f64 * 0.013).collect();
        let ys: Vec<Vec<f64>> = (0..8)
            .map(|t| (0..n).map(|i| ((i * (t + 3)) as f64 * 0.7).sin()).collect())
            .collect();
        let refs: Vec<&[f64]> = ys.iter().map(|y| y.as_slice()).collect();
        let units = vec![vec![0..1_000], vec![1_000..1_700, 2_200..n, 1_700..2_200]];
        let all = pool_rows(&[&c], &[0.0], &[0.05], None, &units, &refs);
        for (t, y) in refs.iter().enumerate() {
            let one = pool_rows(&[&c], &[0.0], &[0.05], None, &units, &[y]);
            assert_eq!(one.3, all.3);
            assert_eq!(one.1, all.1);
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&one.2[0]), bits(&all.2[t]), "target {t}");
            assert_eq!(bits(&one.0[0]), bits(&all.0[0]));
        }
    }

    /// Two covariates: one cell per (a, b) pair that occurs, cells in
    /// ascending (a, b) order, each holding its rows' count, mean
    /// covariates and Σy — what a product form's scan is computed on.
    #[test]
    fn pooling_on_two_covariates_keeps_each_cells_sums() {
        let a: Vec<f64> = (0..100).map(|i| (i % 10) as f64).collect();
        let b: Vec<f64> = (0..100)
            .map(|i| if i % 3 == 0 { -1.0 } else { 1.0 })
            .collect();
        let y: Vec<f64> = (0..100).map(|i| (i * i) as f64).collect();
        let one = |r: Range<usize>| vec![r];
        let (xc, w, sy, u) = pool_rows(
            &[&a, &b],
            &[0.0, -1.0],
            &[0.5, 0.5],
            None,
            &[one(0..100)],
            &[&y],
        );
        assert_eq!(u, vec![0..20]);
        let mut cells: Vec<(f64, f64)> = a.iter().copied().zip(b.iter().copied()).collect();
        cells.sort_by(|p, q| p.partial_cmp(q).unwrap());
        cells.dedup();
        assert_eq!(cells.len(), 20);
        for (c, (va, vb)) in cells.iter().enumerate() {
            let rows: Vec<usize> = (0..100).filter(|&i| a[i] == *va && b[i] == *vb).collect();
            assert_eq!((xc[0][c], xc[1][c]), (*va, *vb));
            assert_eq!(w[c], rows.len() as f64);
            assert_eq!(sy[0][c], rows.iter().map(|&i| y[i]).sum::<f64>());
        }
    }

    /// Pooling gives the bits of its definition: each range's rows sorted
    /// by (cell, row) and equal cells summed in that order (a range's
    /// partial cells), then a unit's partial cells of equal cell summed in
    /// range order. Weights, several targets, a unit of two ranges, ties on
    /// bin edges; one covariate (dense bins), cell and row packed in 64
    /// bits (3 coarse covariates), in 128 (6 fine ones) and not packed (7
    /// fine ones).
    #[test]
    fn pooling_by_packed_keys_equals_pooling_by_sorted_rows() {
        let n = 5_000;
        let mut next = uniform(0x2545_f491_4f6c_dd1d);
        let w: Vec<f64> = (0..n).map(|i| 1.0 + (i % 3) as f64).collect();
        let y1: Vec<f64> = (0..n).map(|i| (i as f64 * 0.1).sin()).collect();
        let y2: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).cos() * 1e3).collect();
        let units = vec![
            vec![0..1_200, 3_000..4_000],
            vec![1_200..3_000],
            vec![4_000..n],
        ];
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        // Fine: finer than MAX_POOL_BINS allows, so 65 537 bins (17 bits)
        // per covariate.
        for (nd, res) in [
            (1, 1.0 / 7.0),
            (1, 1e-9),
            (3, 1.0 / 7.0),
            (6, 1e-9),
            (7, 1e-9),
        ] {
            // Coarse: values on bin edges (ties); fine: many cells.
            let cols: Vec<Vec<f64>> = (0..nd)
                .map(|_| {
                    (0..n)
                        .map(|_| match res > 1e-3 {
                            true => (next() * 7.0).floor() / 7.0,
                            false => next(),
                        })
                        .collect()
                })
                .collect();
            let col_refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
            let (mins, ress) = (vec![0.0; nd], vec![res; nd]);
            let got = pool_rows(&col_refs, &mins, &ress, Some(&w), &units, &[&y1, &y2]);
            // The reference: sort (each covariate's bin…, row), sum runs of
            // equal cells in row order.
            let r: Vec<(f64, usize)> = cols
                .iter()
                .map(|c| {
                    let span = c.iter().fold(0.0f64, |m, v| m.max(*v));
                    let r = res.max(span / pool::MAX_POOL_BINS);
                    (r, (span / r) as usize + 1)
                })
                .collect();
            let bin = |j: usize, i: usize| ((cols[j][i] / r[j].0) as usize).min(r[j].1 - 1);
            let (mut xc, mut ws) = (vec![vec![]; nd], vec![]);
            let (mut sy, mut pu) = (vec![vec![]; 2], vec![]);
            for u in &units {
                // (cell, [count, Σw·c…, Σy…]) of each range, range by range.
                let mut partial: Vec<(Vec<usize>, Vec<f64>)> = Vec::new();
                for r in u {
                    let mut keyed: Vec<(Vec<usize>, usize)> = r
                        .clone()
                        .map(|i| ((0..nd).map(|j| bin(j, i)).collect(), i))
                        .collect();
                    keyed.sort_unstable();
                    for run in keyed.chunk_by(|p, q| p.0 == q.0) {
                        let mut sums = vec![0.0; 1 + nd + 2];
                        for &(_, i) in run {
                            sums[0] += w[i];
                            for j in 0..nd {
                                sums[1 + j] += w[i] * cols[j][i];
                            }
                            sums[1 + nd] += y1[i];
                            sums[2 + nd] += y2[i];
                        }
                        partial.push((run[0].0.clone(), sums));
                    }
                }
                // Stable: equal cells stay in range order.
                partial.sort_by(|p, q| p.0.cmp(&q.0));
                let start = ws.len();
                for run in partial.chunk_by(|p, q| p.0 == q.0) {
                    let mut sums = run[0].1.clone();
                    for (_, p) in &run[1..] {
                        sums.iter_mut().zip(p).for_each(|(s, v)| *s += v);
                    }
                    (0..nd).for_each(|j| xc[j].push(sums[1 + j] / sums[0]));
                    ws.push(sums[0]);
                    (0..2).for_each(|t| sy[t].push(sums[1 + nd + t]));
                }
                pu.push(start..ws.len());
            }
            assert_eq!(got.3, pu, "{nd} covariates");
            assert!(pu.iter().all(|r| r.len() >= 5), "{nd} covariates: {pu:?}");
            if res > 1e-3 {
                assert!(ws.len() < n / 4, "coarse cells hold several rows");
            }
            assert_eq!(bits(&got.1), bits(&ws));
            for (g, want) in got.0.iter().zip(&xc).chain(got.2.iter().zip(&sy)) {
                assert_eq!(bits(g), bits(want), "{nd} covariates");
            }
            assert_eq!((got.0.len(), got.2.len()), (nd, 2));
        }
    }

    /// Folds fitted on pooled cells land on the exact least squares of the
    /// rows within what pooling changes (a drift shape, θ fixed).
    #[test]
    fn pooled_fold_fits_are_the_row_fits() {
        let n = 20_000;
        let t: Vec<f64> = (0..n)
            .map(|i| (i as f64 * 0.618_034).fract() * 50.0)
            .collect();
        let y: Vec<f64> = t
            .iter()
            .enumerate()
            .map(|(i, v)| {
                // The halves differ, so a fold that trained on the wrong
                // units would be far off.
                let amp = if i < n / 2 { 2.0 } else { 3.0 };
                0.3 + amp * (1.0 - (-v / 7.0).exp()) + 0.01 * ((i * 7919) % 13) as f64
            })
            .collect();
        let form = super::super::Shape {
            kind: super::super::Kind::Drift,
            covs: vec!["t_s".into()],
        };
        let frame = vec![super::super::CovStats::from_values(&t)];
        let x = EffectData::new(n).with("t_s", &t);
        let one = |r: Range<usize>| vec![r];
        let units = [one(0..n / 2), one(n / 2..n)];
        let train = [vec![true, false], vec![true, true]];
        let spec = FoldSpec {
            train: &train,
            target_of_fold: &[0, 0],
        };
        let mut store = Vec::new();
        let rows = scan_rows(&form, &frame, &x, &units, &[&y], 8.0, &mut store).unwrap();
        assert!(rows.w.is_some() && rows.x.len() < n);
        let pooled = pooled_fold_betas(&form, &frame, &rows, &[7.0, 7.0], &spec).unwrap();
        let exact = |r: Range<usize>| {
            super::super::with_columns(1, |buf| {
                form.features(&frame, &x, 7.0, buf).unwrap();
                let (g, h) = (design_gram(buf, None, r.clone()), design_xy(buf, &y, r));
                solve(&g, &h).unwrap()
            })
        };
        for (b, want) in pooled.iter().zip([exact(0..n / 2), exact(0..n)]) {
            for (p, q) in b.iter().zip(&want) {
                assert!((p - q).abs() < 1e-4 * (1.0 + q.abs()), "{b:?} vs {want:?}");
            }
        }
    }

    /// Units are grouped by the folds that train on them (here: the units
    /// one fold holds out form a group), groups in order of first
    /// appearance; with one all-units fit, every unit is in one group.
    #[test]
    fn units_group_by_their_training_folds() {
        // Unit fold assignment 0 1 0 2 1 0, three folds + the all-runs fit.
        let unit_fold = [0usize, 1, 0, 2, 1, 0];
        let mut train: Vec<Vec<bool>> = (0..3)
            .map(|f| unit_fold.iter().map(|&uf| uf != f).collect())
            .collect();
        train.push(vec![true; 6]);
        assert_eq!(
            fold_groups(&train, 6),
            vec![vec![0, 2, 5], vec![1, 4], vec![3]]
        );
        assert_eq!(fold_groups(&[vec![true; 3]], 3), vec![vec![0, 1, 2]]);
    }

    /// The columns' sums side by side are each column's `iter().sum()`,
    /// bit for bit, for any number of columns: values of mixed sign and
    /// magnitude (where the order of additions shows), a column of −0.0
    /// (whose sum's sign shows the start value), empty columns.
    #[test]
    fn sums_side_by_side_are_the_sums_in_order() {
        let mut next = uniform(0x0123_4567_89ab_cdef);
        for rows in [0usize, 1, 7, 1000] {
            let cols: Vec<Vec<f64>> = (0..9)
                .map(|j| {
                    (0..rows)
                        .map(|_| match j {
                            0 => -0.0,
                            _ => (next() - 0.5) * 10f64.powi((next() * 24.0) as i32 - 12),
                        })
                        .collect()
                })
                .collect();
            for k in 1..=cols.len() {
                let part: Vec<&[f64]> = cols[..k].iter().map(|c| c.as_slice()).collect();
                let got = sums_in_order(&part);
                let want: Vec<u64> = part
                    .iter()
                    .map(|c| c.iter().sum::<f64>().to_bits())
                    .collect();
                assert_eq!(
                    got.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                    want,
                    "{rows} rows, {k} columns"
                );
            }
        }
    }
}

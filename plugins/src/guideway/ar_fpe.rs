//! The time-series model of δz (docs/models.md §3.2): difference d times, fit
//! AR(p) for p = 1..p_max by least squares, choose p by the Final
//! Prediction Error FPE(p) = σ̂²_p·(N + p + 1)/(N − p − 1) (the default,
//! as published), or by one of the consistent criteria:
//! BIC(p) = N·ln σ̂²_p + p·ln N (Schwarz) and HQ(p) = N·ln σ̂²_p +
//! 2p·ln ln N (Hannan–Quinn). FPE is asymptotically AIC and keeps a
//! positive probability of overfitting however long the series; BIC and
//! HQ pick the true order with probability → 1 (BIC at the price of
//! missing small last coefficients on short series). All three are
//! computed every time and reported; `[guideway.predictor] criterion`
//! chooses which one sets the order.
//!
//! Every order is fitted on the same N = len − p_max samples (the first
//! p_max differenced values only serve as lags), so the FPEs compare like
//! with like (statsmodels' `AutoReg(..., hold_back=p_max, trend="n")` does
//! the same). The lag cross-products G[i][j] = Σ_t y(t−i)·y(t−j) are
//! computed once in O(N·p_max) — the first row directly, the rest by the
//! shift identity G[i][j] = G[i−1][j−1] + (entering) − (leaving) — and each
//! order is then a p×p Cholesky solve (nalgebra): O(N·p_max + p_max⁴).

use crate::bail;
use nalgebra::{DMatrix, DVector};
use sparkout_pipeline::Result;

/// Coefficients c_i of (1 − B)^d = Σ c_i Bⁱ.
pub fn difference_poly(d: usize) -> Vec<f64> {
    let mut c = vec![1.0];
    for _ in 0..d {
        let mut n = vec![0.0; c.len() + 1];
        for (i, v) in c.iter().enumerate() {
            n[i] += v;
            n[i + 1] -= v;
        }
        c = n;
    }
    c
}

/// y(t) = (1 − B)^d x(t) for t = d..len (length len − d).
pub fn difference(x: &[f64], d: usize) -> Vec<f64> {
    let c = difference_poly(d);
    if x.len() <= d {
        return Vec::new();
    }
    (d..x.len())
        .map(|t| c.iter().enumerate().map(|(i, ci)| ci * x[t - i]).sum())
        .collect()
}

/// x(t) from its difference y(t) and the d previous values of x:
/// x(t) = y(t) − Σ_{i≥1} c_i x(t − i) (docs/models.md §3.3: δ̂z(n) = ŷ(n) +
/// 2δz(n−1) − δz(n−2) for d = 2). `prev[0]` is x(t−1).
pub fn undifference(y: f64, prev: &[f64], c: &[f64]) -> f64 {
    y - c[1..].iter().zip(prev).map(|(ci, x)| ci * x).sum::<f64>()
}

/// Order-selection criterion.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Criterion {
    Fpe,
    Bic,
    Hq,
}

impl Criterion {
    pub const ALL: [Criterion; 3] = [Criterion::Fpe, Criterion::Bic, Criterion::Hq];
    pub const NAMES: &'static [&'static str] = &["fpe", "bic", "hq"];
    pub fn as_str(self) -> &'static str {
        match self {
            Criterion::Fpe => "fpe",
            Criterion::Bic => "bic",
            Criterion::Hq => "hq",
        }
    }
}

/// The order search.
#[derive(Debug, Clone)]
pub struct FpeSearch {
    /// Samples every order is fitted on.
    pub n_eff: usize,
    /// Per order p = 1..=p_max: FPE, BIC, HQ, σ̂², coefficients a_1..a_p.
    pub fpe: Vec<f64>,
    pub bic: Vec<f64>,
    pub hq: Vec<f64>,
    pub sigma2: Vec<f64>,
    pub coefficients: Vec<Vec<f64>>,
    /// The criterion that chose `order`.
    pub criterion: Criterion,
    /// The order with the smallest value of `criterion`.
    pub order: usize,
}

/// 1 + the index of the smallest value.
fn argmin1(v: &[f64]) -> usize {
    1 + v
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .map(|(i, _)| i)
        .unwrap_or(0)
}

impl FpeSearch {
    pub fn values(&self, c: Criterion) -> &[f64] {
        match c {
            Criterion::Fpe => &self.fpe,
            Criterion::Bic => &self.bic,
            Criterion::Hq => &self.hq,
        }
    }
    /// The order each criterion would choose.
    pub fn order_by(&self, c: Criterion) -> usize {
        argmin1(self.values(c))
    }
    /// The same fits with the order chosen by `c`.
    pub fn with_criterion(mut self, c: Criterion) -> FpeSearch {
        self.criterion = c;
        self.order = self.order_by(c);
        self
    }
    pub fn chosen(&self) -> &[f64] {
        &self.coefficients[self.order - 1]
    }
    pub fn sigma2_chosen(&self) -> f64 {
        self.sigma2[self.order - 1]
    }
}

/// Minimum series length (after differencing) for an order search to p_max.
pub fn min_len(p_max: usize) -> usize {
    2 * p_max + 2
}

/// Lag cross-product matrix over t = p_max..len.
fn cross_products(y: &[f64], p_max: usize) -> DMatrix<f64> {
    let n = y.len();
    let q = p_max + 1;
    let mut g = DMatrix::<f64>::zeros(q, q);
    for j in 0..q {
        let mut s = 0.0;
        for t in p_max..n {
            s += y[t] * y[t - j];
        }
        g[(0, j)] = s;
        g[(j, 0)] = s;
    }
    for i in 1..q {
        for j in i..q {
            let enter = y[p_max - i] * y[p_max - j];
            let leave = y[n - i] * y[n - j];
            let v = g[(i - 1, j - 1)] + enter - leave;
            g[(i, j)] = v;
            g[(j, i)] = v;
        }
    }
    g
}

/// Fit AR(1..=p_max) to `y` (already differenced) and choose by FPE
/// (see [`FpeSearch::with_criterion`] for the others).
pub fn fpe_search(y: &[f64], p_max: usize) -> Result<FpeSearch> {
    if p_max == 0 {
        bail!("p_max must be at least 1");
    }
    if y.len() < min_len(p_max) {
        bail!(
            "series of {} values is too short for AR orders up to p_max = {p_max} (need at least {})",
            y.len(),
            min_len(p_max)
        );
    }
    // Scale to unit RMS so the normal equations are well conditioned
    // whatever the unit (coefficients are scale-free; σ² scales back).
    let rms = (y.iter().map(|v| v * v).sum::<f64>() / y.len() as f64).sqrt();
    let scale = if rms > 0.0 { 1.0 / rms } else { 1.0 };
    let ys: Vec<f64> = y.iter().map(|v| v * scale).collect();
    let g = cross_products(&ys, p_max);
    let n_eff = y.len() - p_max;
    let nf = n_eff as f64;
    let (mut fpe, mut sigma2, mut coefficients) = (Vec::new(), Vec::new(), Vec::new());
    let (mut bic, mut hq) = (Vec::new(), Vec::new());
    for p in 1..=p_max {
        let a = g.view((1, 1), (p, p)).into_owned();
        let b = DVector::from_iterator(p, (1..=p).map(|i| g[(i, 0)]));
        let coef = match a.clone().cholesky() {
            Some(ch) => ch.solve(&b),
            // Collinear lags (e.g. an exactly periodic series): least norm.
            None => a
                .svd(true, true)
                .solve(&b, 1e-12)
                .map_err(|e| crate::err!("AR({p}) fit: {e}"))?,
        };
        let rss = (g[(0, 0)] - coef.dot(&b)).max(0.0);
        let s2 = rss / nf / (scale * scale);
        sigma2.push(s2);
        fpe.push(s2 * (nf + p as f64 + 1.0) / (nf - p as f64 - 1.0));
        // σ̂² in the series' unit (mm²); a perfect fit stays finite.
        let ln_s2 = s2.max(f64::MIN_POSITIVE).ln();
        bic.push(nf * ln_s2 + p as f64 * nf.ln());
        hq.push(nf * ln_s2 + 2.0 * p as f64 * nf.ln().max(1.0).ln());
        coefficients.push(coef.iter().copied().collect());
    }
    let order = argmin1(&fpe);
    Ok(FpeSearch {
        n_eff,
        fpe,
        bic,
        hq,
        sigma2,
        coefficients,
        criterion: Criterion::Fpe,
        order,
    })
}

/// Batch least-squares AR(p) coefficients over t = start..len (what RLS
/// converges to when started at `start`).
pub fn batch_ls(y: &[f64], p: usize, start: usize) -> Vec<f64> {
    let mut a = DMatrix::<f64>::zeros(p, p);
    let mut b = DVector::<f64>::zeros(p);
    for t in start.max(p)..y.len() {
        for i in 0..p {
            b[i] += y[t] * y[t - 1 - i];
            for j in 0..p {
                a[(i, j)] += y[t - 1 - i] * y[t - 1 - j];
            }
        }
    }
    a.cholesky()
        .map(|c| c.solve(&b).iter().copied().collect())
        .unwrap_or_else(|| vec![0.0; p])
}

/// ψ-weights of the integrated model Φ(B)(1 − B)^d x = ε (x(t+h) forecast
/// error variance = σ²·Σ_{i<h} ψ_i²).
pub fn psi_weights(coef: &[f64], d: usize, h: usize) -> Vec<f64> {
    // π(B) = 1 − Σ π_i Bⁱ = (1 − Σ a_i Bⁱ)(1 − B)^d.
    let c = difference_poly(d);
    let mut phi = vec![1.0];
    phi.extend(coef.iter().map(|a| -a));
    let mut full = vec![0.0; phi.len() + c.len() - 1];
    for (i, p) in phi.iter().enumerate() {
        for (j, q) in c.iter().enumerate() {
            full[i + j] += p * q;
        }
    }
    let pi: Vec<f64> = full[1..].iter().map(|v| -v).collect();
    let mut psi = vec![1.0];
    for j in 1..h {
        let s: f64 = (1..=j.min(pi.len())).map(|i| pi[i - 1] * psi[j - i]).sum();
        psi.push(s);
    }
    psi
}

/// h-step forecasts of x (undifferenced) from its history with AR
/// coefficients on the d-th difference, and their 1σ (mm).
pub fn forecast(x: &[f64], coef: &[f64], d: usize, sigma2: f64, h: usize) -> Vec<(f64, f64)> {
    let c = difference_poly(d);
    let mut xs: Vec<f64> = x.to_vec();
    let mut ys = difference(x, d);
    let psi = psi_weights(coef, d, h);
    let mut var = 0.0;
    let mut out = Vec::with_capacity(h);
    for w in psi.iter().take(h) {
        let yhat: f64 = coef
            .iter()
            .enumerate()
            .map(|(i, a)| a * ys.get(ys.len().wrapping_sub(1 + i)).copied().unwrap_or(0.0))
            .sum();
        let prev: Vec<f64> = (1..=d).map(|i| xs[xs.len() - i]).collect();
        let xhat = undifference(yhat, &prev, &c);
        var += sigma2 * w * w;
        out.push((xhat, var.sqrt()));
        ys.push(yhat);
        xs.push(xhat);
    }
    out
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// (1 − B)^d x = AR(coef) driven by N(0, σ²), length n (after a burn-in).
    pub fn simulate(coef: &[f64], d: usize, n: usize, sigma: f64, seed: u64) -> Vec<f64> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let nd = Normal::new(0.0, sigma).unwrap();
        let burn = 200;
        let mut y: Vec<f64> = Vec::with_capacity(n + burn);
        for t in 0..n + burn {
            let mut v = nd.sample(&mut rng);
            for (i, a) in coef.iter().enumerate() {
                if t > i {
                    v += a * y[t - 1 - i];
                }
            }
            y.push(v);
        }
        let mut x = y[burn..].to_vec();
        for _ in 0..d {
            let mut acc = 0.0;
            for v in x.iter_mut() {
                acc += *v;
                *v = acc;
            }
        }
        x
    }

    #[test]
    fn differencing_round_trips() {
        let x = [1.0, 4.0, 9.0, 16.0, 25.0];
        assert_eq!(difference(&x, 2), vec![2.0, 2.0, 2.0]);
        let c = difference_poly(2);
        assert_eq!(c, vec![1.0, -2.0, 1.0]);
        assert_eq!(undifference(2.0, &[16.0, 9.0], &c), 25.0);
    }

    #[test]
    fn fpe_recovers_an_ar2() {
        let x = simulate(&[0.6, -0.3], 0, 4000, 1.0, 5);
        let s = fpe_search(&x, 8).unwrap();
        assert_eq!(s.order, 2, "{:?}", s.fpe);
        let a = s.chosen();
        assert!(
            (a[0] - 0.6).abs() < 0.05 && (a[1] + 0.3).abs() < 0.05,
            "{a:?}"
        );
        assert!((s.sigma2_chosen() - 1.0).abs() < 0.08);
        // The shifted cross-products equal the direct sums.
        let g = cross_products(&x, 8);
        let direct: f64 = (8..x.len()).map(|t| x[t - 3] * x[t - 5]).sum();
        assert!((g[(3, 5)] - direct).abs() < 1e-8 * direct.abs().max(1.0));
        assert!(fpe_search(&x[..10], 8).is_err());
    }

    #[test]
    fn forecasts_of_a_line_stay_on_it_with_growing_sigma() {
        let x: Vec<f64> = (0..50).map(|i| 2.0 + 0.5 * i as f64).collect();
        let f = forecast(&x, &[0.3], 2, 1.0, 4);
        for (h, (v, s)) in f.iter().enumerate() {
            assert!((v - (2.0 + 0.5 * (50 + h) as f64)).abs() < 1e-9);
            assert!(*s > 0.0);
        }
        assert!(f[3].1 > f[0].1);
        assert_eq!(psi_weights(&[], 1, 3), vec![1.0, 1.0, 1.0]);
    }
}

//! Recursive least squares for the AR parameters (docs/models.md §3.3):
//!
//! ```text
//! Â(n) = Â(n−1) + P(n)X(n)[y(n) − X(n)ᵀÂ(n−1)]
//! P(n) = [P(n−1) − P(n−1)X XᵀP(n−1) / (λ + XᵀP(n−1)X)] / λ
//! Â(0) = 0, P(0) = 100·I
//! ```
//!
//! (λ = 1 is the source's form; λ < 1 forgets old samples.) P(0) = 100·I
//! is a prior of scale 10 on the coefficients *relative to the data's
//! unit*: the source worked in µm, so the caller feeds δz in µm — in mm the
//! same P(0) would be a strong ridge (10⁶ times stronger) and RLS would
//! hardly move. Plain loops over a p×p array: p ≤ 50 and this runs per
//! sample over 10⁶ samples (benches/guideway_predictor.rs).

/// The online estimator.
#[derive(Debug, Clone)]
pub struct Rls {
    pub p: usize,
    pub a: Vec<f64>,
    /// P, row-major p×p.
    pm: Vec<f64>,
    lambda: f64,
    px: Vec<f64>,
}

impl Rls {
    /// Â(0) = 0, P(0) = p0·I.
    pub fn new(p: usize, p0: f64, lambda: f64) -> Rls {
        let mut pm = vec![0.0; p * p];
        for i in 0..p {
            pm[i * p + i] = p0;
        }
        Rls {
            p,
            a: vec![0.0; p],
            pm,
            lambda,
            px: vec![0.0; p],
        }
    }

    /// The one-step prediction Â(n−1)ᵀX(n).
    pub fn predict(&self, x: &[f64]) -> f64 {
        self.a.iter().zip(x).map(|(a, v)| a * v).sum()
    }

    /// Update with regressor X(n) (x[i] = y(n−1−i)) and target y(n);
    /// returns the a-priori error y − X ᵀÂ(n−1).
    pub fn update(&mut self, x: &[f64], y: f64) -> f64 {
        let p = self.p;
        let e = y - self.predict(x);
        let mut denom = self.lambda;
        for i in 0..p {
            let row = &self.pm[i * p..(i + 1) * p];
            let v: f64 = row.iter().zip(x).map(|(a, b)| a * b).sum();
            self.px[i] = v;
            denom += x[i] * v;
        }
        // Gain K = P(n)X = P(n−1)X / (λ + XᵀP(n−1)X).
        let inv = 1.0 / denom;
        for i in 0..p {
            self.a[i] += self.px[i] * inv * e;
        }
        let il = 1.0 / self.lambda;
        for i in 0..p {
            let pi = self.px[i] * inv;
            let row = &mut self.pm[i * p..(i + 1) * p];
            for (j, r) in row.iter_mut().enumerate() {
                *r = (*r - pi * self.px[j]) * il;
            }
        }
        e
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::guideway::ar_fpe::{batch_ls, tests::simulate};

    #[test]
    fn rls_converges_to_batch_least_squares() {
        let y = simulate(&[0.5, -0.2, 0.1, 0.15], 0, 5000, 1.0, 9);
        let mut r = Rls::new(4, 100.0, 1.0);
        for t in 4..y.len() {
            let x: Vec<f64> = (0..4).map(|i| y[t - 1 - i]).collect();
            r.update(&x, y[t]);
        }
        let b = batch_ls(&y, 4, 4);
        for (a, c) in r.a.iter().zip(&b) {
            assert!((a - c).abs() < 1e-5, "{:?} vs {b:?}", r.a);
        }
    }
}

//! Scalar Kalman filter fusing the AR one-step prediction with the
//! measurement (docs/models.md §3.3): process variance q = the prediction-error
//! variance, measurement variance r = table repeatability²:
//!
//! ```text
//! P⁻ = P + q;  K = P⁻/(P⁻ + r);  P = (1 − K)P⁻;  δ̂ ← δ̂⁻ + K(Z − δ̂⁻)
//! ```
//!
//! with the prior δ̂⁻ the predictor's δ̂z(n).

#[derive(Debug, Clone, Copy)]
pub struct Kalman {
    pub q: f64,
    pub r: f64,
    pub p: f64,
}

/// One step's outcome.
#[derive(Debug, Clone, Copy)]
pub struct KalmanStep {
    pub estimate: f64,
    pub gain: f64,
    /// Z − prior.
    pub innovation: f64,
    pub p: f64,
}

impl Kalman {
    /// Starts with P = r (the first estimate is as uncertain as a reading).
    pub fn new(q: f64, r: f64) -> Kalman {
        Kalman { q, r, p: r }
    }
    pub fn step(&mut self, prior: f64, z: f64) -> KalmanStep {
        let pm = self.p + self.q;
        let k = pm / (pm + self.r);
        self.p = (1.0 - k) * pm;
        let innovation = z - prior;
        KalmanStep {
            estimate: prior + k * innovation,
            gain: k,
            innovation,
            p: self.p,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gain_converges_to_the_riccati_fixed_point() {
        let (q, r) = (1.0, 4.0);
        let mut k = Kalman::new(q, r);
        let mut s = k.step(0.0, 1.0);
        for _ in 0..100 {
            s = k.step(0.0, 1.0);
        }
        // P∞ solves P = (P+q)r/(P+q+r): P² + qP − qr = 0.
        let p_inf = (-q + (q * q + 4.0 * q * r).sqrt()) / 2.0;
        assert!((s.p - p_inf).abs() < 1e-9);
        assert!((s.gain - (p_inf + q) / (p_inf + q + r)).abs() < 1e-9);
        assert!((s.estimate - s.gain).abs() < 1e-12);
    }
}

//! The forward model: the commanded path through a first-order position
//! loop with velocity feed-forward (docs/servo.md "Model"):
//!
//! ```text
//! ė = −Kv·e − (1 − ff)·v_cmd,   e = actual − commanded position
//! ```
//!
//! In steady motion e = −(1 − ff)·v/Kv: the axis trails the command by the
//! lag (1 − ff)/Kv seconds. Integrated exactly for a commanded velocity that
//! is linear between samples, so the log rate (10 Hz of a controller trace
//! or 1 kHz of a drive) does not matter.

/// One axis' position loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisServo {
    /// Position-loop gain Kv, 1/s.
    pub kv_1_s: f64,
    /// Velocity feed-forward fraction in [0, 1].
    pub ff: f64,
}

impl AxisServo {
    /// Steady-state lag (s): e = −lag·v.
    pub fn lag_s(&self) -> f64 {
        (1.0 - self.ff) / self.kv_1_s
    }
}

/// Simulated following error e (mm) and its rate ė (mm/s) at the sample
/// times `t_s` for commanded velocities `v_mm_s` (linear between samples).
/// Starts in steady state, e(0) = −lag·v(0) (at rest: 0).
pub fn simulate(s: AxisServo, t_s: &[f64], v_mm_s: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let n = t_s.len();
    assert_eq!(n, v_mm_s.len(), "simulate: t and v lengths differ");
    let (k, c) = (s.kv_1_s, 1.0 - s.ff);
    let mut e = Vec::with_capacity(n);
    if n == 0 {
        return (e, Vec::new());
    }
    e.push(-c * v_mm_s[0] / k);
    for i in 1..n {
        let dt = t_s[i] - t_s[i - 1];
        let e0 = e[i - 1];
        if dt <= 0.0 {
            e.push(e0);
            continue;
        }
        // v(τ) = v0 + s·τ; particular solution α + β·τ with β = −c·s/K and
        // α = (c·s/K − c·v0)/K; e(τ) = α + β·τ + (e0 − α)·exp(−K·τ).
        let v0 = v_mm_s[i - 1];
        let slope = (v_mm_s[i] - v0) / dt;
        let beta = -c * slope / k;
        let alpha = (c * slope / k - c * v0) / k;
        e.push(alpha + beta * dt + (e0 - alpha) * (-k * dt).exp());
    }
    let edot = e.iter().zip(v_mm_s).map(|(e, v)| -k * e - c * v).collect();
    (e, edot)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_speed_settles_to_the_lag() {
        let s = AxisServo {
            kv_1_s: 30.0,
            ff: 0.25,
        };
        let t: Vec<f64> = (0..200).map(|i| i as f64 * 0.01).collect();
        let v: Vec<f64> = t
            .iter()
            .map(|&t| if t < 0.5 { 0.0 } else { 20.0 })
            .collect();
        let (e, edot) = simulate(s, &t, &v);
        assert_eq!(e[0], 0.0);
        let want = -s.lag_s() * 20.0;
        assert!((e[199] - want).abs() < 1e-9, "{} vs {want}", e[199]);
        assert!(edot[199].abs() < 1e-7);
    }

    #[test]
    fn ramp_matches_the_closed_form_at_any_step() {
        // v = a·t from rest: e(t) = −c·a·(t/K − (1 − e^{−Kt})/K²).
        let s = AxisServo {
            kv_1_s: 25.0,
            ff: 0.0,
        };
        let a = 100.0;
        for dt in [0.001, 0.1] {
            let t: Vec<f64> = (0..=10).map(|i| i as f64 * dt).collect();
            let v: Vec<f64> = t.iter().map(|t| a * t).collect();
            let (e, _) = simulate(s, &t, &v);
            for (ti, ei) in t.iter().zip(&e) {
                let k = s.kv_1_s;
                let want = -a * (ti / k - (1.0 - (-k * ti).exp()) / (k * k));
                assert!((ei - want).abs() < 1e-12, "dt {dt}: {ei} vs {want}");
            }
        }
    }
}

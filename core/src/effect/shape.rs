//! The catalogue's shapes (docs/formats.md §7 "Candidate effects") as
//! linear forms: features per θ, the θ grid, parameters in contract units.

use super::*;

/// A catalogue shape on concrete covariates.
#[derive(Debug, Clone)]
pub struct Shape {
    pub kind: Kind,
    pub covs: Vec<String>,
}

/// Cells over a covariate's range within which a form without θ pools rows.
const LINEAR_POOL_BINS: f64 = 1024.0;

/// Grid values between exact sin_cos evaluations of the periodic scan.
const ROTATION_ANCHOR: usize = 256;

pub(super) fn log_grid(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if hi.is_nan() || lo.is_nan() || hi <= lo || n < 2 {
        return vec![lo];
    }
    let (a, b) = (lo.ln(), hi.ln());
    (0..n)
        .map(|i| (a + (b - a) * i as f64 / (n - 1) as f64).exp())
        .collect()
}

impl LinearForm for Shape {
    fn covariates(&self) -> Vec<String> {
        self.covs.clone()
    }
    fn factors(&self) -> Vec<(Kind, Vec<String>)> {
        vec![(self.kind, self.covs.clone())]
    }
    fn n_linear(&self) -> usize {
        self.kind.n_linear()
    }
    fn theta(&self, frame: &Frame) -> Option<ThetaRange> {
        match self.kind {
            Kind::Drift => {
                let s = frame[0];
                // t_s counts from the run's start; the span is the latest time.
                let span = s.max.max(s.range()).max(1e-9);
                let (lo, hi) = (span * DRIFT_TAU_MIN_FRAC, span);
                Some(ThetaRange {
                    name: "tau_s".into(),
                    lo,
                    hi,
                    grid: log_grid(lo, hi, 40),
                    // Pooled at the bin mean, the error is second order:
                    // (τ/20)²/24τ² ≈ 1e-4 relative.
                    resolution: lo / 20.0,
                    refine_in_frequency: false,
                })
            }
            Kind::Edge => {
                let s = frame[0];
                let range = s.max.max(s.range()).max(1e-9);
                // Down to a third of the sample step: a pressure rise that
                // only the outermost sample sees is still an edge effect.
                let lo = (s.step / 3.0).max(range / 500.0).min(range);
                let hi = range;
                Some(ThetaRange {
                    name: "lambda_mm".into(),
                    lo,
                    hi,
                    grid: log_grid(lo, hi, 32),
                    resolution: lo / 20.0,
                    refine_in_frequency: false,
                })
            }
            Kind::Periodic => {
                let s = frame[0];
                let (lo, hi) = periodic_lambda_bounds(&s);
                let range = s.range().max(1e-300);
                // Uniform in frequency, a quarter cycle over the range apart.
                let (f_lo, f_hi) = (1.0 / hi, 1.0 / lo);
                let df = 0.25 / range;
                let n = (((f_hi - f_lo) / df).ceil() as usize).max(1);
                let mut grid: Vec<f64> = (0..=n)
                    .map(|i| 1.0 / (f_lo + (f_hi - f_lo) * i as f64 / n as f64))
                    .collect();
                grid.reverse();
                Some(ThetaRange {
                    name: "lambda".into(),
                    lo,
                    hi,
                    grid,
                    // phase error 2π·res/λ ≤ 0.1 rad
                    resolution: lo / 64.0,
                    refine_in_frequency: true,
                })
            }
            _ => None,
        }
    }

    /// θ forms: θ's resolution; the others (linear in their covariates,
    /// or the bow's parabola) a thousandth of each covariate's range —
    /// pooled at the cell mean, a linear feature's sum is exact.
    fn pool_resolutions(&self, frame: &Frame) -> Option<Vec<f64>> {
        if let Some(t) = self.theta(frame) {
            return Some(vec![t.resolution]);
        }
        Some(
            frame
                .iter()
                .map(|s| match s.range() {
                    r if r > 0.0 && r.is_finite() => r / LINEAR_POOL_BINS,
                    // A constant covariate: one cell, whatever its width.
                    _ => 1.0,
                })
                .collect(),
        )
    }
    fn features(&self, frame: &Frame, x: &EffectData, theta: f64, out: &mut Columns) -> Result<()> {
        let n = x.len();
        for o in out.iter_mut() {
            o.resize(n, 0.0);
        }
        let k = self.kind;
        if k == Kind::Offset {
            return Ok(());
        }
        let c = x.require(&self.covs[0])?;
        let s = frame[0];
        match k {
            Kind::Offset => {}
            Kind::Scale
            | Kind::Lag
            | Kind::Inertia
            | Kind::Wear
            | Kind::Compliance
            | Kind::Thermal => {
                let (m, h) = s.mid_half();
                let inv = 1.0 / h;
                for (o, v) in out[0].iter_mut().zip(c) {
                    *o = (v - m) * inv;
                }
            }
            Kind::Backlash => {
                for (o, v) in out[0].iter_mut().zip(c) {
                    *o = 0.5 * v;
                }
            }
            Kind::Bow => {
                let (c0, c1) = (s.min, s.max);
                let d2 = (c1 - c0).powi(2).max(1e-300);
                for (o, v) in out[0].iter_mut().zip(c) {
                    *o = 4.0 * (v - c0) * (c1 - v) / d2;
                }
            }
            Kind::Drift => {
                let inv = 1.0 / theta;
                for (o, v) in out[0].iter_mut().zip(c) {
                    *o = 1.0 - (-v * inv).exp();
                }
            }
            Kind::Edge => {
                let inv = 1.0 / theta;
                for (o, v) in out[0].iter_mut().zip(c) {
                    *o = (-v * inv).exp();
                }
            }
            Kind::Periodic => {
                let w = 2.0 * PI / theta;
                let (a, b) = out.split_at_mut(1);
                for ((sn, cs), v) in a[0].iter_mut().zip(b[0].iter_mut()).zip(c) {
                    let (si, co) = (w * v).sin_cos();
                    *sn = si;
                    *cs = co;
                }
            }
            Kind::Squareness => {
                // k·c1·c2 exactly (no centring: centring would add linear
                // terms that are not part of the contract's form).
                let c2 = x.require(&self.covs[1])?;
                let s2 = frame[1];
                let inv = 1.0 / (s.max_abs.max(1e-300) * s2.max_abs.max(1e-300));
                for ((o, a), b) in out[0].iter_mut().zip(c).zip(c2) {
                    *o = a * b * inv;
                }
            }
        }
        Ok(())
    }

    /// Periodic: the grid is uniform in frequency, so sin/cos of w·c at the
    /// next grid value are a rotation of the current ones by Δw·c (angle
    /// addition: 4 products per row instead of a sin_cos, which was 40 % of
    /// the diagnosis' time). Re-anchored on an exact sin_cos every
    /// [`ROTATION_ANCHOR`] values, so rounding cannot accumulate.
    fn features_grid(
        &self,
        frame: &Frame,
        x: &EffectData,
        grid: &[f64],
        out: &mut Columns,
        each: &mut dyn FnMut(usize, &Columns) -> Result<()>,
    ) -> Result<()> {
        let w: Vec<f64> = grid.iter().map(|t| 2.0 * PI / t).collect();
        let dw = match w.as_slice() {
            [a, b, ..] => b - a,
            _ => 0.0,
        };
        let uniform = dw != 0.0
            && w.windows(2)
                .all(|p| ((p[1] - p[0]) - dw).abs() <= 1e-9 * dw.abs());
        if self.kind != Kind::Periodic || !uniform {
            return features_each(self, frame, x, grid, out, each);
        }
        let c = x.require(&self.covs[0])?;
        let step: Vec<(f64, f64)> = c.iter().map(|v| (dw * v).sin_cos()).collect();
        for (gi, &theta) in grid.iter().enumerate() {
            if gi % ROTATION_ANCHOR == 0 {
                self.features(frame, x, theta, out)?;
            } else {
                let (a, b) = out.split_at_mut(1);
                for ((sn, cs), (sd, cd)) in a[0].iter_mut().zip(b[0].iter_mut()).zip(&step) {
                    let (s0, c0) = (*sn, *cs);
                    *sn = s0 * cd + c0 * sd;
                    *cs = c0 * cd - s0 * sd;
                }
            }
            each(gi, out)?;
        }
        Ok(())
    }

    fn params(&self, frame: &Frame, theta: f64, coef: &[f64], offset: f64) -> ParamsAndOffset {
        let mut p = BTreeMap::new();
        let mut off = offset;
        match self.kind {
            Kind::Offset => {
                p.insert("offset_mm".into(), offset);
            }
            Kind::Scale | Kind::Lag | Kind::Inertia | Kind::Wear | Kind::Compliance => {
                let (m, h) = frame[0].mid_half();
                let k = coef[0] / h;
                off -= k * m;
                p.insert("k".into(), k);
            }
            Kind::Thermal => {
                let (m, h) = frame[0].mid_half();
                let k = coef[0] / h;
                off -= k * m;
                off += k * THERMAL_T0_C;
                p.insert("k".into(), k);
                p.insert("t0_c".into(), THERMAL_T0_C);
            }
            Kind::Backlash => {
                p.insert("b_mm".into(), coef[0]);
            }
            Kind::Bow => {
                p.insert("amplitude_mm".into(), coef[0]);
                p.insert("c0".into(), frame[0].min);
                p.insert("c1".into(), frame[0].max);
            }
            Kind::Drift => {
                p.insert("amplitude_mm".into(), coef[0]);
                p.insert("tau_s".into(), theta);
            }
            Kind::Edge => {
                p.insert("k_mm".into(), coef[0]);
                p.insert("lambda_mm".into(), theta);
            }
            Kind::Periodic => {
                // a·sin + b·cos = A·sin(· + φ) with A cos φ = a, A sin φ = b.
                let (a, b) = (coef[0], coef[1]);
                p.insert("amplitude_mm".into(), a.hypot(b));
                p.insert("phase_rad".into(), b.atan2(a));
                p.insert("lambda".into(), theta);
            }
            Kind::Squareness => {
                let inv = frame[0].max_abs.max(1e-300) * frame[1].max_abs.max(1e-300);
                p.insert("k".into(), coef[0] / inv);
            }
        }
        (p, off)
    }
}

/// Evaluates a catalogue shape from contract parameters (the generator and
/// the augmented model use this; `frame` supplies bow's c0/c1 when the
/// parameters do not). Returns the value of `form(c; params)` per row.
pub fn shape_value(
    kind: Kind,
    params: &BTreeMap<String, f64>,
    c: &[f64],
    c2: Option<&[f64]>,
) -> Vec<f64> {
    let g = |k: &str, d: f64| params.get(k).copied().unwrap_or(d);
    let mut out = vec![0.0; c.len()];
    for (i, o) in out.iter_mut().enumerate() {
        let v = c.get(i).copied().unwrap_or(0.0);
        *o = match kind {
            Kind::Offset => g("offset_mm", 0.0),
            Kind::Scale | Kind::Lag | Kind::Inertia | Kind::Wear | Kind::Compliance => {
                g("k", 0.0) * v
            }
            Kind::Thermal => g("k", 0.0) * (v - g("t0_c", THERMAL_T0_C)),
            Kind::Backlash => g("b_mm", 0.0) * v / 2.0,
            Kind::Bow => {
                let (c0, c1) = (g("c0", 0.0), g("c1", 1.0));
                4.0 * g("amplitude_mm", 0.0) * (v - c0) * (c1 - v) / (c1 - c0).powi(2).max(1e-300)
            }
            Kind::Drift => g("amplitude_mm", 0.0) * (1.0 - (-v / g("tau_s", 1.0)).exp()),
            Kind::Edge => g("k_mm", 0.0) * (-v / g("lambda_mm", 1.0)).exp(),
            Kind::Periodic => {
                g("amplitude_mm", 0.0)
                    * (2.0 * PI * v / g("lambda", 1.0) + g("phase_rad", 0.0)).sin()
            }
            Kind::Squareness => g("k", 0.0) * v * c2.map(|c2| c2[i]).unwrap_or(0.0),
        };
    }
    out
}

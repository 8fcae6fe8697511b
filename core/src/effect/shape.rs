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
                sin_cos_of(|i| w * c[i], &mut a[0][..c.len()], &mut b[0][..c.len()]);
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
        let (mut step_sin, mut step_cos) = (vec![0.0; c.len()], vec![0.0; c.len()]);
        sin_cos_of(|i| dw * c[i], &mut step_sin, &mut step_cos);
        for (gi, &theta) in grid.iter().enumerate() {
            if gi % ROTATION_ANCHOR == 0 {
                self.features(frame, x, theta, out)?;
            } else {
                let (a, b) = out.split_at_mut(1);
                for ((sn, cs), (sd, cd)) in a[0]
                    .iter_mut()
                    .zip(b[0].iter_mut())
                    .zip(step_sin.iter().zip(&step_cos))
                {
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

/// Arguments up to this size are reduced by [`sin_cos_reduced`]'s two-part
/// π/2 (n·π/2's first part exact for |n| < 2²⁰); larger ones go to the
/// standard library's sin_cos.
const REDUCED_ARG_MAX: f64 = 4.0e5;

/// `sin[i], cos[i] = sin_cos(arg(i))` for every i of the outputs: the
/// periodic form's features, a sine and cosine per row (held-out scores and
/// the all-runs fit are on rows), which with the standard library's scalar
/// sin_cos were the diagnosis' largest single cost. Which of the two a row
/// gets depends on its own argument only, so a row's features are the same
/// bits whether it is computed with its run alone or with the whole fleet
/// (the statistics merged per run rest on that; docs/design.md §8). While
/// every argument is within [`REDUCED_ARG_MAX`] — in practice always — the
/// loop has no branch or call, so it runs in vector registers.
fn sin_cos_of(arg: impl Fn(usize) -> f64, sin: &mut [f64], cos: &mut [f64]) {
    let n = sin.len().min(cos.len());
    let small = |x: f64| x.abs() <= REDUCED_ARG_MAX;
    if (0..n).all(|i| small(arg(i))) {
        for i in 0..n {
            (sin[i], cos[i]) = sin_cos_reduced(arg(i));
        }
    } else {
        for i in 0..n {
            let x = arg(i);
            (sin[i], cos[i]) = if small(x) {
                sin_cos_reduced(x)
            } else {
                x.sin_cos()
            };
        }
    }
}

/// sin and cos of |x| ≤ [`REDUCED_ARG_MAX`] without a branch: x = n·π/2 + r
/// with n the nearest integer (Cody–Waite, π/2 in two parts; absolute error
/// of r ≈ n·2·10⁻²¹), sin and cos of |r| ≤ π/4 by the minimax polynomials
/// of FreeBSD's msun (k_sin.c, k_cos.c, < 1 ulp), then the quadrant n mod 4
/// swaps and signs them. Within a few 10⁻¹⁶ of the correctly rounded values
/// (unit test), and the same bits on every machine: plain IEEE arithmetic,
/// no library call.
// The constants are msun's, digits as published (each parses to the
// double msun uses).
#[allow(clippy::excessive_precision)]
#[inline(always)]
fn sin_cos_reduced(x: f64) -> (f64, f64) {
    const INV_PIO2: f64 = std::f64::consts::FRAC_2_PI;
    const PIO2_1: f64 = 1.570_796_326_734_125_614_17;
    const PIO2_1T: f64 = 6.077_100_506_506_192_249_32e-11;
    // Adding 1.5·2⁵² rounds to an integer, which the low mantissa bits hold.
    const TOINT: f64 = 1.5 / f64::EPSILON;
    const S: [f64; 6] = [
        -1.666_666_666_666_663_243_48e-1,
        8.333_333_333_322_489_461_24e-3,
        -1.984_126_982_985_794_931_34e-4,
        2.755_731_370_707_006_767_89e-6,
        -2.505_076_025_340_686_341_95e-8,
        1.589_690_995_211_550_102_21e-10,
    ];
    const C: [f64; 6] = [
        4.166_666_666_666_660_190_37e-2,
        -1.388_888_888_887_410_957_49e-3,
        2.480_158_728_947_672_941_78e-5,
        -2.755_731_435_139_066_330_35e-7,
        2.087_572_321_298_174_827_90e-9,
        -1.135_964_755_778_819_482_65e-11,
    ];
    let t = x * INV_PIO2 + TOINT;
    let q = t.to_bits() & 3;
    let nq = t - TOINT;
    let r = (x - nq * PIO2_1) - nq * PIO2_1T;
    let z = r * r;
    let w = z * z;
    let rs = S[1] + z * (S[2] + z * S[3]) + z * w * (S[4] + z * S[5]);
    let s = r + z * r * (S[0] + z * rs);
    let hz = 0.5 * z;
    let one_hz = 1.0 - hz;
    let rc = z * (C[0] + z * (C[1] + z * C[2])) + w * w * (C[3] + z * (C[4] + z * C[5]));
    let c = one_hz + (((1.0 - one_hz) - hz) + z * rc);
    // Quadrant 1 and 3 swap sine and cosine; 2 and 3 negate the sine, 1
    // and 2 the cosine.
    let (s, c) = if q & 1 == 1 { (c, s) } else { (s, c) };
    let sign_s = (q & 2) << 62;
    let sign_c = ((q + 1) & 2) << 62;
    (
        f64::from_bits(s.to_bits() ^ sign_s),
        f64::from_bits(c.to_bits() ^ sign_c),
    )
}

#[cfg(test)]
mod sin_cos_tests {
    use super::*;

    /// Within 4·10⁻¹⁶ of the standard library over the periodic form's
    /// arguments (up to ±64 cycles of a range far from 0, and beyond), the
    /// quadrant edges included; the library's own beyond the reduced range.
    #[test]
    fn reduced_sin_cos_is_the_library_s_within_a_few_ulp() {
        let mut worst = 0.0f64;
        let mut args: Vec<f64> = (-200_000..=200_000)
            .map(|i| i as f64 * 1.000_37e-2)
            .collect();
        args.extend((0..2_000).map(|k| k as f64 * std::f64::consts::FRAC_PI_2));
        args.extend((0..2_000).map(|k| -(k as f64) * std::f64::consts::FRAC_PI_4));
        args.extend([0.0, -0.0, 1e-300, 3.9e5, -3.9e5, REDUCED_ARG_MAX]);
        for &x in &args {
            let (s, c) = sin_cos_reduced(x);
            let (s0, c0) = x.sin_cos();
            worst = worst.max((s - s0).abs()).max((c - c0).abs());
        }
        assert!(worst <= 4e-16, "worst error {worst:e}");
        let (mut s, mut c) = (vec![0.0; 3], vec![0.0; 3]);
        let big = [1.0, 5e5, 2.0];
        sin_cos_of(|i| big[i], &mut s, &mut c);
        assert_eq!(
            (s[1], c[1]),
            5e5f64.sin_cos(),
            "large arguments are the library's"
        );
    }
}

#[cfg(test)]
mod row_wise_tests {
    use crate::effect::{catalogue, CovStats, EffectData};

    /// A row's features depend on that row alone: computed over any range
    /// of the rows they are the same bits as the range of the features
    /// computed over all of them. Per-run statistics merged across runs
    /// (and the per-unit blocks of the cross-validation) rest on it. The
    /// positions reach past the reduced sine's range on some rows only.
    #[test]
    fn features_of_a_range_are_the_range_of_the_features() {
        let n = 5_000;
        let wave = |i: usize, a: f64| ((i as f64 * a).sin() * 43_758.545_3).fract();
        let t_s: Vec<f64> = (0..n).map(|i| i as f64 * 0.01 + wave(i, 1.3)).collect();
        let x_mm: Vec<f64> = (0..n)
            .map(|i| {
                let v = 400.0 * wave(i, 2.7);
                if i % 97 == 0 {
                    v * 1.0e5
                } else {
                    v
                }
            })
            .collect();
        let y_mm: Vec<f64> = (0..n).map(|i| -50.0 + 100.0 * wave(i, 0.77)).collect();
        let dir: Vec<f64> = (0..n)
            .map(|i| if wave(i, 5.1) > 0.0 { 1.0 } else { -1.0 })
            .collect();
        let end_mm: Vec<f64> = (0..n).map(|i| 30.0 * wave(i, 3.3).abs()).collect();
        let cols: Vec<(&str, &Vec<f64>)> = vec![
            ("t_s", &t_s),
            ("x_mm", &x_mm),
            ("y_mm", &y_mm),
            ("dir", &dir),
            ("path_end_mm", &end_mm),
        ];
        let names: Vec<String> = cols.iter().map(|(c, _)| c.to_string()).collect();
        let mut x = EffectData::new(n);
        for (c, v) in &cols {
            x.push(c, v);
        }
        let ranges = [0..1, 1..8, 8..1_500, 1_500..n];
        let mut forms = 0;
        for e in catalogue(&names) {
            let Some(form) = e.linear_form() else {
                continue;
            };
            let frame: Vec<CovStats> = form
                .covariates()
                .iter()
                .map(|c| CovStats::from_values(x.col(c).unwrap()))
                .collect();
            let thetas = match form.theta(&frame) {
                None => vec![f64::NAN],
                Some(tr) => vec![tr.grid[0], tr.grid[tr.grid.len() / 2], tr.lo * 1.37],
            };
            let covs = form.covariates();
            for th in thetas {
                let mut all = vec![Vec::new(); form.n_linear()];
                form.features(&frame, &x, th, &mut all).unwrap();
                for r in ranges.clone() {
                    let mut part = vec![Vec::new(); form.n_linear()];
                    let xr = x.rows_of(&covs, r.clone()).unwrap();
                    form.features(&frame, &xr, th, &mut part).unwrap();
                    for (a, p) in all.iter().zip(&part) {
                        let a: Vec<u64> = a[r.clone()].iter().map(|v| v.to_bits()).collect();
                        let p: Vec<u64> = p.iter().map(|v| v.to_bits()).collect();
                        assert_eq!(a, p, "{} at θ {th}, rows {r:?}", e.key());
                    }
                }
            }
            forms += 1;
        }
        assert!(forms >= 8, "only {forms} forms tried");
    }
}

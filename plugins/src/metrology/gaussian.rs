//! The Gaussian profile filter (ISO 16610-21) on any x spacing.
//!
//! Weighting function s(x) = (1/(αλc))·exp(−π(x/(αλc))²),
//! α = √(ln 2/π): a sine of wavelength λc keeps 50 % of its amplitude in
//! the mean line.
//!
//! Discretisation (chosen for non-uniform x, used on every profile): the
//! convolution integral is a sum over the measured points, each weighted by
//! the length of x it stands for, Δⱼ = (xⱼ₊₁ − xⱼ₋₁)/2 (half a step at the
//! two ends), and normalised by the weights present:
//!
//!   w(xᵢ) = Σⱼ s(xⱼ − xᵢ)·Δⱼ·zⱼ / Σⱼ s(xⱼ − xᵢ)·Δⱼ,  over |xⱼ − xᵢ| ≤ λc.
//!
//! No resampling, so no interpolated heights. On a uniform step Δⱼ is
//! constant inside the profile and this is the usual discrete Gaussian
//! kernel normalised to sum 1. The kernel is truncated at ±λc, where s has
//! fallen to exp(−π²/ln 2) ≈ 6.5·10⁻⁷ of its peak. The normalisation keeps
//! the mean line unbiased where the kernel runs off the profile's ends, but
//! the filter is still short of data there: callers evaluate roughness only
//! from λc/2 inside each end.

/// α = √(ln 2 / π).
pub fn alpha() -> f64 {
    (std::f64::consts::LN_2 / std::f64::consts::PI).sqrt()
}

/// The Δx weight of every point (trapezoid rule).
pub fn dx_weights(x: &[f64]) -> Vec<f64> {
    let n = x.len();
    (0..n)
        .map(|i| {
            let lo = if i == 0 { x[0] } else { x[i - 1] };
            let hi = if i + 1 == n { x[n - 1] } else { x[i + 1] };
            0.5 * (hi - lo)
        })
        .collect()
}

/// The mean line of z(x) (x strictly increasing) for cut-off `lambda_c`
/// (same unit as x).
pub fn mean_line(x: &[f64], z: &[f64], lambda_c: f64) -> Vec<f64> {
    let d = dx_weights(x);
    let al = alpha() * lambda_c;
    let n = x.len();
    let mut out = Vec::with_capacity(n);
    let mut lo = 0;
    let mut hi = 0;
    for i in 0..n {
        while x[i] - x[lo] > lambda_c {
            lo += 1;
        }
        while hi + 1 < n && x[hi + 1] - x[i] <= lambda_c {
            hi += 1;
        }
        let (mut num, mut den) = (0.0, 0.0);
        for j in lo..=hi {
            let t = (x[j] - x[i]) / al;
            let w = (-std::f64::consts::PI * t * t).exp() / al * d[j];
            num += w * z[j];
            den += w;
        }
        out.push(num / den);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn amplitude_kept(lambda: f64, lambda_c: f64, step: f64) -> f64 {
        // A long profile; the gain is read in the middle, far from the ends.
        let n = (40.0 * lambda_c.max(lambda) / step) as usize;
        let x: Vec<f64> = (0..n).map(|i| i as f64 * step).collect();
        let k = 2.0 * std::f64::consts::PI / lambda;
        let z: Vec<f64> = x.iter().map(|&u| (k * u).cos()).collect();
        let m = mean_line(&x, &z, lambda_c);
        let mid = n / 2;
        // Amplitude of the mean line over one period around the middle.
        let per = (lambda / step) as usize;
        (mid..mid + per).map(|i| m[i].abs()).fold(0.0, f64::max)
    }

    #[test]
    fn the_cut_off_wavelength_keeps_half_its_amplitude() {
        let g = amplitude_kept(0.8, 0.8, 0.0005);
        assert!((g - 0.5).abs() < 1e-3, "{g}");
        // Transfer exp(−π(αλc/λ)²): long waves pass, short ones are removed.
        let long = amplitude_kept(8.0, 0.8, 0.004);
        let want = (-std::f64::consts::PI * (alpha() * 0.8 / 8.0f64).powi(2)).exp();
        assert!((long - want).abs() < 1e-3, "{long} vs {want}");
        assert!(amplitude_kept(0.08, 0.8, 0.0005) < 1e-3);
    }

    #[test]
    fn non_uniform_spacing_gives_the_same_mean_line_as_uniform_on_a_smooth_profile() {
        // The same smooth profile sampled on a jittered grid: the mean line
        // agrees with the uniform one to the discretisation error.
        let f = |u: f64| (u * 1.3).sin() + 0.3 * (u * 0.4).cos();
        let xu: Vec<f64> = (0..4000).map(|i| i as f64 * 0.0025).collect();
        // Odd points moved by up to ±0.4 of a step; even points stay, so
        // the two mean lines are compared at the same x.
        let xn: Vec<f64> = xu
            .iter()
            .enumerate()
            .map(|(i, &u)| {
                if i % 2 == 1 && i < 3999 {
                    u + 0.001 * (((i * 7919) % 13) as f64 / 12.0 - 0.5)
                } else {
                    u
                }
            })
            .collect();
        let mu = mean_line(&xu, &xu.iter().map(|&u| f(u)).collect::<Vec<_>>(), 2.5);
        let mn = mean_line(&xn, &xn.iter().map(|&u| f(u)).collect::<Vec<_>>(), 2.5);
        for i in (1500..2500).step_by(50) {
            assert_eq!(xu[i], xn[i]);
            assert!((mu[i] - mn[i]).abs() < 1e-6, "{i}: {} {}", mu[i], mn[i]);
        }
    }
}

//! Quantiles of Student's t at any degrees of freedom.
//!
//! statrs inverts the t CDF through its inverse incomplete beta, which
//! drifts for large degrees of freedom (0.975 quantile at df = 10⁶:
//! 1.959848, true 1.959966; at 10⁷: 1.83) and does not return at all near
//! df = 1.7·10⁷ — the residual degrees of freedom of an observable with
//! 1.7·10⁷ rows, i.e. a fleet of ≈ 10⁸ observation rows, which hung the
//! diagnosis. Above [`EXPANSION_DF`] the quantile is the normal one
//! corrected in powers of 1/df (the Cornish–Fisher expansion, Abramowitz &
//! Stegun 26.7.5), whose first omitted term is below 10⁻¹⁷ there; at
//! df = 10⁴ the two agree to 10⁻⁹.

use statrs::distribution::{ContinuousCDF, Normal, StudentsT};

/// Degrees of freedom above which the expansion replaces statrs.
pub const EXPANSION_DF: f64 = 1.0e4;

/// The `p` quantile of Student's t with `df` degrees of freedom (NaN for
/// df ≤ 0 or p outside [0, 1]).
pub fn t_quantile(p: f64, df: f64) -> f64 {
    if df.is_nan() || df <= 0.0 || !(0.0..=1.0).contains(&p) {
        return f64::NAN;
    }
    if df <= EXPANSION_DF {
        return StudentsT::new(0.0, 1.0, df)
            .map(|t| t.inverse_cdf(p))
            .unwrap_or(f64::NAN);
    }
    let z = Normal::standard().inverse_cdf(p);
    if !z.is_finite() {
        return z;
    }
    let z2 = z * z;
    let g1 = (z2 + 1.0) * z / 4.0;
    let g2 = ((5.0 * z2 + 16.0) * z2 + 3.0) * z / 96.0;
    let g3 = (((3.0 * z2 + 19.0) * z2 + 17.0) * z2 - 15.0) * z / 384.0;
    let g4 = ((((79.0 * z2 + 776.0) * z2 + 1482.0) * z2 - 1920.0) * z2 - 945.0) * z / 92160.0;
    let v = 1.0 / df;
    z + v * (g1 + v * (g2 + v * (g3 + v * g4)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn large_degrees_of_freedom_give_the_normal_limit_and_return() {
        // Where statrs is exact the expansion agrees with it.
        for df in [1.0e3, 5.0e3, EXPANSION_DF] {
            let exact = StudentsT::new(0.0, 1.0, df).unwrap().inverse_cdf(0.975);
            let v = 1.0 / df;
            let z = Normal::standard().inverse_cdf(0.975);
            let z2 = z * z;
            let series = z + v
                * ((z2 + 1.0) * z / 4.0
                    + v * (((5.0 * z2 + 16.0) * z2 + 3.0) * z / 96.0
                        + v * ((((3.0 * z2 + 19.0) * z2 + 17.0) * z2 - 15.0) * z / 384.0)));
            assert!(
                (exact - series).abs() < 1e-8,
                "df {df}: {exact} vs {series}"
            );
        }
        // Past it: monotone towards 1.959964 from above, and finite for the
        // residual degrees of freedom of a 10⁸-row fleet's observables
        // (statrs does not return for 1.7·10⁷).
        let mut last = t_quantile(0.975, EXPANSION_DF);
        for df in [2.0e4, 1.0e5, 1.0e6, 1.0e7, 16_999_996.0, 1.0e8, 1.0e12] {
            let t = t_quantile(0.975, df);
            assert!(t < last && t > 1.959_963_98, "df {df}: {t}");
            last = t;
        }
        let limit = t_quantile(0.975, 1.0e12);
        assert!((limit - 1.959_963_984_540_054).abs() < 1e-9, "{limit}");
        assert!((t_quantile(0.025, 1.0e7) + t_quantile(0.975, 1.0e7)).abs() < 1e-15);
        assert!(t_quantile(0.975, 0.0).is_nan() && t_quantile(1.5, 10.0).is_nan());
    }
}

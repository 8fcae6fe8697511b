//! Design profiles R(φ) of the shapes the source grinds (docs/models.md §4):
//! ellipses (placed on a cylinder: one elliptical section per axial
//! position) and a tangent cam — base circle, nose circle and the two
//! straight flanks tangent to both (so it has straight parts with κ = 0 and
//! no corners). Used by the generator, the tests and the bench.

use std::f64::consts::TAU;

/// Polar radius of an ellipse centred on the work axis, semi-axes `a`
/// (along φ = 0) and `b`.
pub fn ellipse_r(phi: f64, a: f64, b: f64) -> f64 {
    a * b / ((b * phi.cos()).powi(2) + (a * phi.sin()).powi(2)).sqrt()
}

/// A tangent cam: base circle of radius `base` about the work axis, nose
/// circle of radius `nose` whose centre is `lift_centre` from the axis at
/// φ = 0, joined by straight flanks tangent to both.
#[derive(Debug, Clone, Copy)]
pub struct TangentCam {
    pub base: f64,
    pub nose: f64,
    pub lift_centre: f64,
}

impl TangentCam {
    /// Validity: nose smaller than the base and sticking out of it.
    pub fn check(&self) -> Result<(), String> {
        if !(self.nose > 0.0
            && self.nose < self.base
            && self.lift_centre + self.nose > self.base
            && self.lift_centre > self.base - self.nose)
        {
            return Err(format!("invalid tangent cam {self:?}: need 0 < nose < base and the nose circle outside the base"));
        }
        Ok(())
    }

    /// Normal angle of the flanks (θ_t: cos θ_t = (base − nose)/centre).
    fn theta_t(&self) -> f64 {
        ((self.base - self.nose) / self.lift_centre).acos()
    }

    /// The radius vector at φ: the far boundary of the convex hull of the
    /// two discs along the ray — the largest exit distance over the base
    /// disc, the nose disc and the quadrilateral of the four tangent points
    /// (the hull is their union and it is convex).
    pub fn r(&self, phi: f64) -> f64 {
        let (s, c) = phi.sin_cos();
        let mut best = self.base;
        // Nose disc: |t·u − (d, 0)|² = r_n² → t² − 2 d c t + d² − r_n² = 0.
        let d = self.lift_centre;
        let disc = (d * c).powi(2) - (d * d - self.nose * self.nose);
        if disc >= 0.0 {
            best = best.max(d * c + disc.sqrt());
        }
        // Quadrilateral T1 T2 T2' T1'.
        let th = self.theta_t();
        let (st, ct) = th.sin_cos();
        let q = [
            [self.base * ct, self.base * st],
            [d + self.nose * ct, self.nose * st],
            [d + self.nose * ct, -self.nose * st],
            [self.base * ct, -self.base * st],
        ];
        for k in 0..4 {
            let (p, r) = (q[k], q[(k + 1) % 4]);
            // Ray t·(c, s) meets segment p + u·(r − p), u ∈ [0, 1].
            let e = [r[0] - p[0], r[1] - p[1]];
            let den = c * e[1] - s * e[0];
            if den.abs() < 1e-15 {
                continue;
            }
            let t = (p[0] * e[1] - p[1] * e[0]) / den;
            let u = (p[0] * s - p[1] * c) / den;
            if t > 0.0 && (-1e-12..=1.0 + 1e-12).contains(&u) {
                best = best.max(t);
            }
        }
        best
    }
}

/// `n` points over a whole turn (φ = 2π·k/n) of a shape.
pub fn sample(n: usize, f: impl Fn(f64) -> f64) -> (Vec<f64>, Vec<f64>) {
    let phi: Vec<f64> = (0..n).map(|k| TAU * k as f64 / n as f64).collect();
    let r = phi.iter().map(|&p| f(p)).collect();
    (phi, r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::form::curvature::{CurvatureConfig, Profile};

    fn cam() -> TangentCam {
        TangentCam {
            base: 40.0,
            nose: 15.0,
            lift_centre: 35.0,
        }
    }

    #[test]
    fn cam_pieces() {
        let c = cam();
        c.check().unwrap();
        assert!((c.r(0.0) - 50.0).abs() < 1e-12); // nose tip
        assert!((c.r(std::f64::consts::PI) - 40.0).abs() < 1e-12); // base
                                                                   // On a flank the point lies on the tangent line p·n(θt) = base.
        let th = ((40.0f64 - 15.0) / 35.0).acos();
        let phi = 0.5 * th + 0.3; // between the nose and the base contact
        let r = c.r(phi);
        let proj = r * (phi.cos() * th.cos() + phi.sin() * th.sin());
        assert!(proj <= 40.0 + 1e-9);
    }

    /// The cam's flanks are straight: κ ≈ 0 there, and finite, positive
    /// (convex) and bounded by the nose curvature everywhere — no blow-up
    /// where ρ = ∞.
    #[test]
    fn cam_curvature_is_zero_on_the_flanks_and_bounded() {
        let c = cam();
        let (phi, r) = sample(2000, |p| c.r(p));
        let p = Profile::new(&phi, &r, &CurvatureConfig::default()).unwrap();
        let th = ((c.base - c.nose) / c.lift_centre).acos();
        // Polar angles of the flank's ends (nose and base tangent points).
        let t2 = (c.nose * th.sin()).atan2(c.lift_centre + c.nose * th.cos());
        let t1 = th;
        let mut flat = 0;
        for (i, &f) in phi.iter().enumerate() {
            let k = p.kappa_per_mm[i];
            assert!(
                k.is_finite() && k > -1e-3 && k < 1.2 / c.nose,
                "κ({f}) = {k}"
            );
            let a = if f > std::f64::consts::PI {
                std::f64::consts::TAU - f
            } else {
                f
            };
            if a > t2 + 0.05 && a < t1 - 0.05 {
                assert!(k.abs() < 1e-5, "flank κ({f}) = {k}");
                flat += 1;
            }
        }
        assert!(flat > 50, "{flat}");
    }
}

//! The design profile R(φ) as a plane curve: derivatives by local
//! polynomial regression (a regularised differentiation, robust to the
//! rounding noise of exported profiles), the profile normal, the pressure
//! angle γ0 and the curvature κ = 1/ρ (docs/models.md §4).
//!
//! The curvature is carried as κ, not ρ: a straight part of the profile has
//! κ = 0 and ρ = ∞, and every formula downstream is written in κ so that a
//! flat stays finite instead of blowing up.

use nalgebra::{Matrix4, Vector4};

/// How the derivatives are estimated.
#[derive(Debug, Clone, Copy)]
pub struct CurvatureConfig {
    /// Points in each local fit (odd, ≥ 5): a cubic in (φ − φᵢ) fitted by
    /// tricube-weighted least squares over this many neighbours. More
    /// points smooth more (less noise, more bias at sharp corners).
    pub window_points: usize,
}

impl Default for CurvatureConfig {
    fn default() -> Self {
        CurvatureConfig { window_points: 9 }
    }
}

/// Why a profile cannot be differentiated.
#[derive(Debug, Clone, PartialEq)]
pub enum ProfileProblem {
    /// Row (index into the given points) where φ does not increase.
    NotIncreasing {
        row: usize,
        prev: f64,
        this: f64,
    },
    TooFewPoints {
        n: usize,
        need: usize,
    },
    NonPositiveRadius {
        row: usize,
        r: f64,
    },
}

impl std::fmt::Display for ProfileProblem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ProfileProblem::NotIncreasing { prev, this, .. } => write!(
                f,
                "phi_rad must be strictly increasing along the design profile ({this} after {prev}); sort the design rows by phi_rad and drop duplicates"
            ),
            ProfileProblem::TooFewPoints { n, need } => write!(
                f,
                "the design profile has {n} points; the curvature needs at least {need} (window_points) — export a denser profile or lower [form.<stage>].window_points"
            ),
            ProfileProblem::NonPositiveRadius { r, .. } => {
                write!(f, "radius vector r_mm must be > 0, found {r}")
            }
        }
    }
}

impl ProfileProblem {
    /// The offending row, when there is one.
    pub fn row(&self) -> Option<usize> {
        match self {
            ProfileProblem::NotIncreasing { row, .. }
            | ProfileProblem::NonPositiveRadius { row, .. } => Some(*row),
            ProfileProblem::TooFewPoints { .. } => None,
        }
    }
    pub fn column(&self) -> &'static str {
        match self {
            ProfileProblem::NonPositiveRadius { .. } => "r_mm",
            _ => "phi_rad",
        }
    }
}

/// A design profile with its differential geometry, one entry per point.
#[derive(Debug, Clone)]
pub struct Profile {
    pub phi_rad: Vec<f64>,
    pub r_mm: Vec<f64>,
    /// dR/dφ (mm/rad) and d²R/dφ² (mm/rad²) from the local fits.
    pub dr: Vec<f64>,
    pub ddr: Vec<f64>,
    /// Signed curvature (1/mm): > 0 convex, 0 straight, < 0 concave.
    pub kappa_per_mm: Vec<f64>,
    /// Outward unit normal (x, y).
    pub normal: Vec<[f64; 2]>,
    /// Pressure angle γ0 = atan(R′/R): between the radius vector and the
    /// profile normal (docs/models.md §4).
    pub gamma0_rad: Vec<f64>,
    /// Whether the profile is a whole turn (derivative windows wrap).
    pub closed: bool,
}

/// Check a design profile's ordering and size (what the curvature needs).
pub fn check_profile(phi: &[f64], r: &[f64], cfg: &CurvatureConfig) -> Result<(), ProfileProblem> {
    let need = cfg.window_points.max(5);
    for (i, &ri) in r.iter().enumerate() {
        if !(ri > 0.0) {
            return Err(ProfileProblem::NonPositiveRadius { row: i, r: ri });
        }
    }
    for i in 1..phi.len() {
        if !(phi[i] > phi[i - 1]) {
            return Err(ProfileProblem::NotIncreasing {
                row: i,
                prev: phi[i - 1],
                this: phi[i],
            });
        }
    }
    if phi.len() < need {
        return Err(ProfileProblem::TooFewPoints { n: phi.len(), need });
    }
    Ok(())
}

impl Profile {
    /// Differentiate a design profile (φ strictly increasing, ≥ window points).
    pub fn new(phi: &[f64], r: &[f64], cfg: &CurvatureConfig) -> Result<Profile, ProfileProblem> {
        check_profile(phi, r, cfg)?;
        let n = phi.len();
        let span = phi[n - 1] - phi[0];
        let step = span / (n - 1) as f64;
        // A whole turn: the last point is one step short of the first + 2π.
        let closed = (span + step - std::f64::consts::TAU).abs() < 1.5 * step;
        let w = cfg.window_points.max(5) | 1; // odd
        let h = w / 2;
        let mut dr = vec![0.0; n];
        let mut ddr = vec![0.0; n];
        for i in 0..n {
            // Neighbours: (Δφ, R) over the window; wrapped on a whole turn,
            // shifted inward at the ends of an open profile.
            let mut pts = Vec::with_capacity(w);
            if closed {
                for k in 0..w {
                    let j = i as isize + k as isize - h as isize;
                    let (jj, shift) = if j < 0 {
                        ((j + n as isize) as usize, -std::f64::consts::TAU)
                    } else if j >= n as isize {
                        ((j - n as isize) as usize, std::f64::consts::TAU)
                    } else {
                        (j as usize, 0.0)
                    };
                    pts.push((phi[jj] + shift - phi[i], r[jj]));
                }
            } else {
                let lo = i.saturating_sub(h).min(n - w);
                for j in lo..lo + w {
                    pts.push((phi[j] - phi[i], r[j]));
                }
            }
            let c = local_cubic(&pts);
            dr[i] = c[1];
            ddr[i] = 2.0 * c[2];
        }
        let mut kappa = vec![0.0; n];
        let mut normal = vec![[0.0; 2]; n];
        let mut gamma0 = vec![0.0; n];
        for i in 0..n {
            let (rr, d1, d2) = (r[i], dr[i], ddr[i]);
            // Polar curvature: κ = (R² + 2R′² − R·R″)/(R² + R′²)^{3/2}.
            // Bounded everywhere R > 0; zero on a straight part.
            let q = rr * rr + d1 * d1;
            kappa[i] = (rr * rr + 2.0 * d1 * d1 - rr * d2) / q.powf(1.5);
            let (s, c) = phi[i].sin_cos();
            // Tangent dP/dφ; outward normal = tangent turned clockwise (the
            // profile runs counter-clockwise with φ).
            let tx = d1 * c - rr * s;
            let ty = d1 * s + rr * c;
            let tn = tx.hypot(ty);
            normal[i] = [ty / tn, -tx / tn];
            gamma0[i] = (d1 / rr).atan();
        }
        Ok(Profile {
            phi_rad: phi.to_vec(),
            r_mm: r.to_vec(),
            dr,
            ddr,
            kappa_per_mm: kappa,
            normal,
            gamma0_rad: gamma0,
            closed,
        })
    }

    pub fn len(&self) -> usize {
        self.phi_rad.len()
    }
    pub fn is_empty(&self) -> bool {
        self.phi_rad.is_empty()
    }

    /// Profile point (x, y) in mm.
    pub fn point(&self, i: usize) -> [f64; 2] {
        let (s, c) = self.phi_rad[i].sin_cos();
        [self.r_mm[i] * c, self.r_mm[i] * s]
    }

    /// Arc length from the first point to each point (mm), along the chords.
    pub fn arc_length_mm(&self) -> Vec<f64> {
        let mut s = vec![0.0; self.len()];
        for i in 1..self.len() {
            let (a, b) = (self.point(i - 1), self.point(i));
            s[i] = s[i - 1] + (b[0] - a[0]).hypot(b[1] - a[1]);
        }
        s
    }

    /// R at any φ: cubic Hermite between the bracketing design points with
    /// the fitted slopes (exact at the design points). φ outside the design
    /// range is wrapped by 2π on a closed profile, else `None`.
    pub fn r_at(&self, phi: f64) -> Option<f64> {
        self.interp(phi, &self.r_mm, Some(&self.dr))
    }

    /// Linear interpolation of any per-point quantity at φ (same wrapping).
    pub fn value_at(&self, phi: f64, v: &[f64]) -> Option<f64> {
        self.interp(phi, v, None)
    }

    /// Where φ falls on the design grid: the segment's end points (k, k1)
    /// and the position t ∈ [0, 1] between them (φ wrapped on a closed
    /// turn; past the end of an open profile, the last point with t = 0).
    /// None outside an open profile.
    pub fn segment_at(&self, phi: f64) -> Option<(usize, usize, f64)> {
        let n = self.len();
        let (p0, p1) = (self.phi_rad[0], self.phi_rad[n - 1]);
        let mut x = phi;
        if self.closed {
            x = p0 + (x - p0).rem_euclid(std::f64::consts::TAU);
        }
        let tol = 1e-9;
        if x < p0 - tol || (!self.closed && x > p1 + tol) {
            return None;
        }
        // Index of the segment [k, k+1] (k+1 wraps to 0 on a closed turn).
        let k = match self.phi_rad.partition_point(|&p| p <= x) {
            0 => 0,
            k => k - 1,
        };
        let (k1, x1) = if k + 1 < n {
            (k + 1, self.phi_rad[k + 1])
        } else if self.closed {
            (0, p0 + std::f64::consts::TAU)
        } else {
            return Some((n - 1, n - 1, 0.0));
        };
        let x0 = self.phi_rad[k];
        Some((k, k1, ((x - x0) / (x1 - x0)).clamp(0.0, 1.0)))
    }

    fn interp(&self, phi: f64, v: &[f64], slope: Option<&[f64]>) -> Option<f64> {
        let (k, k1, t) = self.segment_at(phi)?;
        if k == k1 {
            return Some(v[k]);
        }
        Some(match slope {
            None => v[k] + t * (v[k1] - v[k]),
            Some(m) => {
                let hh = if k1 > k {
                    self.phi_rad[k1] - self.phi_rad[k]
                } else {
                    self.phi_rad[0] + std::f64::consts::TAU - self.phi_rad[k]
                };
                let (t2, t3) = (t * t, t * t * t);
                (2.0 * t3 - 3.0 * t2 + 1.0) * v[k]
                    + (t3 - 2.0 * t2 + t) * hh * m[k]
                    + (-2.0 * t3 + 3.0 * t2) * v[k1]
                    + (t3 - t2) * hh * m[k1]
            }
        })
    }
}

/// Tricube-weighted least-squares cubic through (Δφ, R) points; returns
/// the coefficients c0..c3 of R ≈ c0 + c1·Δφ + c2·Δφ² + c3·Δφ³. The
/// abscissae are scaled to [−1, 1] before solving so the normal equations
/// stay well conditioned whatever the angular step.
fn local_cubic(pts: &[(f64, f64)]) -> [f64; 4] {
    let scale = pts
        .iter()
        .map(|p| p.0.abs())
        .fold(0.0_f64, f64::max)
        .max(f64::MIN_POSITIVE);
    let mut ata = Matrix4::<f64>::zeros();
    let mut atb = Vector4::<f64>::zeros();
    for &(dx, y) in pts {
        let u = dx / scale;
        // Tricube weights on a slightly widened support so the window's
        // outermost points keep some weight.
        let a = (u.abs() / 1.2).min(1.0);
        let wgt = (1.0 - a * a * a).powi(3);
        let row = Vector4::new(1.0, u, u * u, u * u * u);
        ata += wgt * row * row.transpose();
        atb += wgt * y * row;
    }
    let c = ata.cholesky().map(|ch| ch.solve(&atb)).unwrap_or_else(|| {
        ata.pseudo_inverse(1e-14)
            .map(|p| p * atb)
            .unwrap_or_default()
    });
    [
        c[0],
        c[1] / scale,
        c[2] / (scale * scale),
        c[3] / (scale * scale * scale),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::TAU;

    fn turn(n: usize) -> Vec<f64> {
        (0..n).map(|i| TAU * i as f64 / n as f64).collect()
    }

    #[test]
    fn circle_has_constant_curvature() {
        let phi = turn(360);
        let r = vec![40.0; 360];
        let p = Profile::new(&phi, &r, &CurvatureConfig::default()).unwrap();
        assert!(p.closed);
        for k in &p.kappa_per_mm {
            assert!((k - 1.0 / 40.0).abs() < 1e-9, "{k}");
        }
        assert!(p.gamma0_rad.iter().all(|g| g.abs() < 1e-9));
    }

    #[test]
    fn ellipse_curvature_matches_closed_form() {
        let (a, b) = (60.0, 40.0);
        let phi = turn(720);
        let r: Vec<f64> = phi
            .iter()
            .map(|f| a * b / ((b * f.cos()).powi(2) + (a * f.sin()).powi(2)).sqrt())
            .collect();
        let p = Profile::new(&phi, &r, &CurvatureConfig::default()).unwrap();
        // At the ends of the major axis κ = a/b², of the minor axis b/a².
        let k0 = p.kappa_per_mm[0];
        let k90 = p.kappa_per_mm[180];
        assert!((k0 / (a / (b * b)) - 1.0).abs() < 2e-3, "{k0}");
        assert!((k90 / (b / (a * a)) - 1.0).abs() < 2e-3, "{k90}");
    }

    /// Rounding noise of an exported profile (±0.1 µm) on a circle: the
    /// local fits keep κ close to 1/R (a 3-point second difference would
    /// be off by orders of magnitude).
    #[test]
    fn noisy_profile_curvature_is_regularised() {
        let phi = turn(1440);
        let r: Vec<f64> = (0..1440)
            .map(|i| 50.0 + 1e-4 * ((i * 7919 % 13) as f64 / 6.0 - 1.0))
            .collect();
        let q = Profile::new(&phi, &r, &CurvatureConfig { window_points: 25 }).unwrap();
        let worst = q
            .kappa_per_mm
            .iter()
            .fold(0.0_f64, |m, k| m.max((k * 50.0 - 1.0).abs()));
        assert!(worst < 0.5, "relative κ error {worst}");
    }

    #[test]
    fn bad_profiles_are_rejected() {
        let cfg = CurvatureConfig::default();
        let e = Profile::new(
            &[0.0, 0.1, 0.1, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8],
            &[10.0; 9],
            &cfg,
        )
        .unwrap_err();
        assert_eq!(e.row(), Some(2));
        assert_eq!(e.column(), "phi_rad");
        let e = Profile::new(&[0.0, 0.1, 0.2], &[10.0; 3], &cfg).unwrap_err();
        assert!(matches!(e, ProfileProblem::TooFewPoints { n: 3, need: 9 }));
    }

    #[test]
    fn hermite_interpolation_is_exact_at_nodes_and_wraps() {
        let phi = turn(90);
        let r: Vec<f64> = phi.iter().map(|f| 40.0 + 2.0 * f.cos()).collect();
        let p = Profile::new(&phi, &r, &CurvatureConfig::default()).unwrap();
        assert!((p.r_at(phi[10]).unwrap() - r[10]).abs() < 1e-12);
        let mid = 0.5 * (phi[10] + phi[11]);
        assert!((p.r_at(mid).unwrap() - (40.0 + 2.0 * mid.cos())).abs() < 1e-6);
        let last = phi[89] + 0.5 * (TAU - phi[89]);
        assert!((p.r_at(last).unwrap() - (40.0 + 2.0 * last.cos())).abs() < 1e-6);
        assert!((p.r_at(mid + TAU).unwrap() - p.r_at(mid).unwrap()).abs() < 1e-12);
    }
}

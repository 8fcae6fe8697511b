//! Plane fits of touch points and the datum (docs/models.md §1.3).
//!
//! - The thesis's fit: OLS of the coordinate normal to the face on the other
//!   two (`z = b0 + b1·x + b2·y` on `xy`, `x = b0 + b1·y + b2·z` on `yz`,
//!   `y = b0 + b1·x + b2·z` on `zx`).
//! - The orthogonal (total least squares) fit: the plane through the
//!   centroid whose normal is the eigenvector of the smallest eigenvalue of
//!   the scatter matrix (as ISO 10360-6 reference software does).
//! - Optional robust rejection: touches farther than `k` robust scales
//!   (1.4826·MAD) from the TLS plane are dropped and the fit repeated.
//! - Each plane carries the covariance of its `(n, d)` (n·p = d, |n| = 1),
//!   which the datum (the intersection of three planes) propagates.

use nalgebra::{Matrix3, Matrix4, SymmetricEigen, Vector3};

/// A face of the block; the label is the plane its points span.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Face {
    /// Normal Z.
    Xy,
    /// Normal X.
    Yz,
    /// Normal Y.
    Zx,
}

impl Face {
    pub const ALL: [Face; 3] = [Face::Xy, Face::Yz, Face::Zx];
    pub fn parse(s: &str) -> Option<Face> {
        match s {
            "xy" => Some(Face::Xy),
            "yz" => Some(Face::Yz),
            "zx" => Some(Face::Zx),
            _ => None,
        }
    }
    pub fn label(self) -> &'static str {
        match self {
            Face::Xy => "xy",
            Face::Yz => "yz",
            Face::Zx => "zx",
        }
    }
    /// Index (0 = x, 1 = y, 2 = z) of the coordinate normal to the face.
    pub fn normal_axis(self) -> usize {
        match self {
            Face::Xy => 2,
            Face::Yz => 0,
            Face::Zx => 1,
        }
    }
    /// The two in-plane coordinates in the order of the thesis's regression
    /// (b1 multiplies the first, b2 the second).
    pub fn in_plane_axes(self) -> (usize, usize) {
        match self {
            Face::Xy => (0, 1),
            Face::Yz => (1, 2),
            Face::Zx => (0, 2),
        }
    }
    pub fn index(self) -> usize {
        match self {
            Face::Xy => 0,
            Face::Yz => 1,
            Face::Zx => 2,
        }
    }
}

/// Why a fit failed (the stage turns it into an input error).
#[derive(Debug, Clone, PartialEq)]
pub struct FitError(pub String);

impl std::fmt::Display for FitError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
impl std::error::Error for FitError {}

/// A plane `n·p = d`, |n| = 1, `n` oriented so its normal-axis component is
/// positive, with the 4×4 covariance of `(nx, ny, nz, d)` (rank 3: the
/// normal only moves tangentially). NaN covariance when the fit has no
/// residual degrees of freedom.
#[derive(Debug, Clone, PartialEq)]
pub struct Plane {
    pub n: Vector3<f64>,
    pub d: f64,
    pub cov: Matrix4<f64>,
}

impl Plane {
    /// Signed orthogonal distance of a point.
    pub fn distance(&self, p: &Vector3<f64>) -> f64 {
        self.n.dot(p) - self.d
    }
    /// The normal coordinate of the plane at the in-plane position of `p`
    /// (the other two coordinates of `p` are kept).
    pub fn normal_coordinate_at(&self, face: Face, p: &Vector3<f64>) -> f64 {
        let a = face.normal_axis();
        let (u, w) = face.in_plane_axes();
        (self.d - self.n[u] * p[u] - self.n[w] * p[w]) / self.n[a]
    }
    /// From `a·x + b·y + c·z + e = 0` (the `--planes` form), oriented with
    /// its largest normal component positive.
    pub fn from_coefficients(a: f64, b: f64, c: f64, e: f64) -> Result<Plane, FitError> {
        let m = Vector3::new(a, b, c);
        let k = m.norm();
        if !(k.is_finite() && k > 0.0 && e.is_finite()) {
            return Err(FitError(format!(
                "plane {a},{b},{c},{e}: the normal (a, b, c) must be finite and non-zero"
            )));
        }
        let axis = m.iamax();
        let s = if m[axis] < 0.0 { -1.0 } else { 1.0 };
        Ok(Plane {
            n: m * (s / k),
            d: -e * s / k,
            cov: Matrix4::zeros(),
        })
    }
}

/// The thesis's OLS fit of one face.
#[derive(Debug, Clone, PartialEq)]
pub struct OlsFit {
    /// [b0, b1, b2].
    pub b: [f64; 3],
    /// Covariance of b (s²·(XᵀX)⁻¹).
    pub cov_b: Matrix3<f64>,
    /// Residuals of the normal coordinate (measured − fitted), mm.
    pub residuals: Vec<f64>,
    pub plane: Plane,
}

/// The orthogonal fit of one face.
#[derive(Debug, Clone, PartialEq)]
pub struct TlsFit {
    pub plane: Plane,
    pub centroid: Vector3<f64>,
    /// Orthogonal residuals (signed distances), mm.
    pub residuals: Vec<f64>,
    /// Eigenvalues of the scatter matrix, ascending (mm²).
    pub eigenvalues: [f64; 3],
    /// Residual σ (mm), NaN with exactly 3 points.
    pub sigma: f64,
}

pub fn rms(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

pub fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0f64, |m, x| m.max(x.abs()))
}

fn centroid(pts: &[Vector3<f64>]) -> Vector3<f64> {
    pts.iter().fold(Vector3::zeros(), |a, p| a + p) / pts.len() as f64
}

/// Centroid, ascending eigenvalues and their eigenvectors.
type ScatterEigen = (Vector3<f64>, [f64; 3], [Vector3<f64>; 3]);

/// Eigen-decomposition of the scatter matrix, ascending, and the collinearity
/// check: the plane is defined only if the points spread in two directions
/// clearly more than they scatter off the plane.
fn scatter_eigen(
    face: Face,
    pts: &[Vector3<f64>],
    collinear_ratio: f64,
) -> Result<ScatterEigen, FitError> {
    if pts.len() < 3 {
        return Err(FitError(format!(
            "face {} has {} touch point(s); a plane needs at least 3",
            face.label(),
            pts.len()
        )));
    }
    let c = centroid(pts);
    let mut s = Matrix3::zeros();
    for p in pts {
        let q = p - c;
        s += q * q.transpose();
    }
    let eig = SymmetricEigen::new(s);
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let lam = [
        eig.eigenvalues[idx[0]].max(0.0),
        eig.eigenvalues[idx[1]].max(0.0),
        eig.eigenvalues[idx[2]].max(0.0),
    ];
    let vecs = [
        eig.eigenvectors.column(idx[0]).into_owned(),
        eig.eigenvectors.column(idx[1]).into_owned(),
        eig.eigenvectors.column(idx[2]).into_owned(),
    ];
    let n = pts.len() as f64;
    let spread = |l: f64| (l / n).sqrt();
    if lam[1].sqrt() <= collinear_ratio * lam[2].sqrt() || lam[1] <= 4.0 * lam[0] {
        return Err(FitError(format!(
            "the {} touch points of face {} are (nearly) collinear: RMS spread {:.6} mm along the line, {:.6} mm across it in the plane and {:.6} mm off it — they do not define a plane",
            pts.len(),
            face.label(),
            spread(lam[2]),
            spread(lam[1]),
            spread(lam[0])
        )));
    }
    Ok((c, lam, vecs))
}

/// TLS: normal = eigenvector of the smallest eigenvalue of the scatter
/// matrix; covariance by first-order perturbation (the normal tilts towards
/// each in-plane eigenvector e_k with variance σ²/λ_k; d = n·c).
pub fn fit_tls(face: Face, pts: &[Vector3<f64>], collinear_ratio: f64) -> Result<TlsFit, FitError> {
    let (c, lam, vecs) = scatter_eigen(face, pts, collinear_ratio)?;
    let mut n = vecs[0];
    if n[face.normal_axis()] < 0.0 {
        n = -n;
    }
    let d = n.dot(&c);
    let residuals: Vec<f64> = pts.iter().map(|p| n.dot(p) - d).collect();
    let dof = pts.len() as f64 - 3.0;
    let sigma2 = if dof > 0.0 {
        residuals.iter().map(|r| r * r).sum::<f64>() / dof
    } else {
        f64::NAN
    };
    let cov_n = (vecs[1] * vecs[1].transpose()) * (sigma2 / lam[1])
        + (vecs[2] * vecs[2].transpose()) * (sigma2 / lam[2]);
    let cov_nd = cov_n * c;
    let var_d = c.dot(&(cov_n * c)) + sigma2 / pts.len() as f64;
    let mut cov = Matrix4::zeros();
    cov.fixed_view_mut::<3, 3>(0, 0).copy_from(&cov_n);
    for i in 0..3 {
        cov[(i, 3)] = cov_nd[i];
        cov[(3, i)] = cov_nd[i];
    }
    cov[(3, 3)] = var_d;
    Ok(TlsFit {
        plane: Plane { n, d, cov },
        centroid: c,
        residuals,
        eigenvalues: lam,
        sigma: sigma2.sqrt(),
    })
}

/// The thesis's OLS fit (normal coordinate on the other two), with the
/// covariance of b and of the equivalent (n, d).
pub fn fit_ols(face: Face, pts: &[Vector3<f64>], collinear_ratio: f64) -> Result<OlsFit, FitError> {
    // Same geometric sanity check as TLS (fewer than 3 / collinear).
    scatter_eigen(face, pts, collinear_ratio)?;
    let a = face.normal_axis();
    let (u, w) = face.in_plane_axes();
    // Centre the regressors for conditioning, then shift b0 back.
    let c = centroid(pts);
    let mut xtx = Matrix3::zeros();
    let mut xty = Vector3::zeros();
    for p in pts {
        let x = Vector3::new(1.0, p[u] - c[u], p[w] - c[w]);
        xtx += x * x.transpose();
        xty += x * p[a];
    }
    // The in-plane design must span two directions (a face label that
    // does not match the points' orientation fails here).
    let inplane = xtx.fixed_view::<2, 2>(1, 1).into_owned();
    let e = SymmetricEigen::new(inplane);
    let (lo, hi) = (e.eigenvalues.min(), e.eigenvalues.max());
    if !(lo > collinear_ratio * collinear_ratio * hi && lo > 0.0) {
        return Err(FitError(format!(
            "face {}: the points do not spread over the {}{} plane (is the face label right?)",
            face.label(),
            ["x", "y", "z"][u],
            ["x", "y", "z"][w]
        )));
    }
    let inv = xtx
        .try_inverse()
        .ok_or_else(|| FitError(format!("face {}: singular OLS design", face.label())))?;
    let bc = inv * xty;
    // b0 at the origin: normal = bc0 + b1 (u − cu) + b2 (w − cw).
    let b0 = bc[0] - bc[1] * c[u] - bc[2] * c[w];
    let b = [b0, bc[1], bc[2]];
    let residuals: Vec<f64> = pts
        .iter()
        .map(|p| p[a] - (b0 + b[1] * p[u] + b[2] * p[w]))
        .collect();
    let dof = pts.len() as f64 - 3.0;
    let s2 = if dof > 0.0 {
        residuals.iter().map(|r| r * r).sum::<f64>() / dof
    } else {
        f64::NAN
    };
    // Covariance of the centred coefficients, then of b (b0 = bc0 − b1 cu − b2 cw).
    let cov_c = inv * s2;
    let t = Matrix3::new(1.0, -c[u], -c[w], 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
    let cov_b = t * cov_c * t.transpose();
    // (n, d) from b: m = e_a − b1 e_u − b2 e_w, n = m/|m|, d = b0/|m|.
    let mut m = Vector3::zeros();
    m[a] = 1.0;
    m[u] = -b[1];
    m[w] = -b[2];
    let k = m.norm();
    let n = m / k;
    let d = b0 / k;
    // Jacobian of (n, d) w.r.t. (b0, b1, b2).
    let dn_dm = (Matrix3::identity() - n * n.transpose()) / k;
    let mut jac = nalgebra::Matrix4x3::zeros();
    let mut eu = Vector3::zeros();
    eu[u] = -1.0;
    let mut ew = Vector3::zeros();
    ew[w] = -1.0;
    let dn_db1 = dn_dm * eu;
    let dn_db2 = dn_dm * ew;
    for i in 0..3 {
        jac[(i, 1)] = dn_db1[i];
        jac[(i, 2)] = dn_db2[i];
    }
    // d = b0/k: ∂d/∂b0 = 1/k, ∂d/∂m = −b0 m/k³ = −d n/k.
    jac[(3, 0)] = 1.0 / k;
    jac[(3, 1)] = (-d * n / k).dot(&eu);
    jac[(3, 2)] = (-d * n / k).dot(&ew);
    let cov = jac * cov_b * jac.transpose();
    Ok(OlsFit {
        b,
        cov_b,
        residuals,
        plane: Plane { n, d, cov },
    })
}

/// Robust selection: indices of the points kept after iteratively rejecting
/// those farther than `k`·scale from the TLS plane, scale = 1.4826·MAD of
/// the residuals (floored at `min_scale_mm`, so exact data reject nothing).
pub fn robust_keep(
    face: Face,
    pts: &[Vector3<f64>],
    k: f64,
    min_scale_mm: f64,
    collinear_ratio: f64,
) -> Result<(Vec<usize>, f64), FitError> {
    let mut keep: Vec<usize> = (0..pts.len()).collect();
    let mut scale = f64::NAN;
    for _ in 0..10 {
        let sub: Vec<Vector3<f64>> = keep.iter().map(|&i| pts[i]).collect();
        let fit = fit_tls(face, &sub, collinear_ratio)?;
        let r_all: Vec<f64> = pts.iter().map(|p| fit.plane.distance(p)).collect();
        let r_kept: Vec<f64> = keep.iter().map(|&i| r_all[i]).collect();
        let med = median(&r_kept);
        let mad = median(&r_kept.iter().map(|r| (r - med).abs()).collect::<Vec<_>>());
        scale = (1.4826 * mad).max(min_scale_mm);
        let next: Vec<usize> = (0..pts.len())
            .filter(|&i| (r_all[i] - med).abs() <= k * scale)
            .collect();
        if next.len() < 3 {
            return Err(FitError(format!(
                "face {}: robust rejection would leave {} of {} points (scale {:.6} mm, k = {k}); the touches do not agree on a plane",
                face.label(),
                next.len(),
                pts.len(),
                scale
            )));
        }
        if next == keep {
            break;
        }
        keep = next;
    }
    Ok((keep, scale))
}

pub fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let m = s.len() / 2;
    if s.len() % 2 == 1 {
        s[m]
    } else {
        0.5 * (s[m - 1] + s[m])
    }
}

/// The datum: the intersection of three planes, its covariance, the
/// condition number of the normals' matrix and the inter-face squareness.
#[derive(Debug, Clone, PartialEq)]
pub struct Datum {
    pub p: Vector3<f64>,
    pub cov: Matrix3<f64>,
    /// σ_max/σ_min of the matrix of unit normals (1 for a perfect cube).
    pub condition: f64,
}

/// Solve `N p = D` for three planes (docs/models.md §1.3). Covariance by
/// linearising the solve: for plane k, δp = N⁻¹ e_k (δd_k − δn_k·p), so
/// J_k = N⁻¹ e_k [−pᵀ, 1] and Cov(p) = Σ_k J_k Cov_k J_kᵀ (planes are fitted
/// from different touches, hence independent). An ill-conditioned system
/// (nearly parallel faces) is an error, not a wild number.
pub fn intersect(planes: [&Plane; 3], max_condition: f64) -> Result<Datum, FitError> {
    let nm = Matrix3::from_rows(&[
        planes[0].n.transpose(),
        planes[1].n.transpose(),
        planes[2].n.transpose(),
    ]);
    let sv = nm.singular_values();
    let (smax, smin) = (sv.max(), sv.min());
    let condition = if smin > 0.0 {
        smax / smin
    } else {
        f64::INFINITY
    };
    if !(condition <= max_condition) {
        let ang = |a: &Plane, b: &Plane| a.n.dot(&b.n).abs().min(1.0).acos().to_degrees();
        return Err(FitError(format!(
            "the three faces are nearly parallel (angles between normals {:.3}°, {:.3}°, {:.3}°): condition number {:.3e} > max_condition {:.3e}, the datum would be ill-conditioned",
            ang(planes[0], planes[1]),
            ang(planes[1], planes[2]),
            ang(planes[2], planes[0]),
            condition,
            max_condition
        )));
    }
    let inv = nm
        .try_inverse()
        .ok_or_else(|| FitError("the three face normals are linearly dependent".into()))?;
    let dvec = Vector3::new(planes[0].d, planes[1].d, planes[2].d);
    let p = inv * dvec;
    let mut cov = Matrix3::zeros();
    for (k, pl) in planes.iter().enumerate() {
        let col = inv.column(k).into_owned();
        let g = nalgebra::Vector4::new(-p[0], -p[1], -p[2], 1.0);
        let var = g.dot(&(pl.cov * g));
        cov += col * col.transpose() * var;
    }
    Ok(Datum { p, cov, condition })
}

/// Deviation from 90° of the angle between two planes' normals (rad),
/// normals oriented along their own axes (positive: the faces open wider
/// than square).
pub fn squareness(a: &Plane, b: &Plane) -> f64 {
    (-a.n.dot(&b.n)).clamp(-1.0, 1.0).asin()
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// docs/models.md §1.3, the thesis's worked numbers: face with normal Z,
    /// outer square, points 1, 6, 7, 12.
    pub fn thesis_points() -> Vec<Vector3<f64>> {
        vec![
            Vector3::new(60.29546, 13.23640, -12.38640),
            Vector3::new(60.29092, 63.22650, -12.26790),
            Vector3::new(20.28898, 63.22607, -12.32380),
            Vector3::new(20.28729, 13.22610, -12.39170),
        ]
    }

    #[test]
    fn thesis_plane_example() {
        let f = fit_ols(Face::Xy, &thesis_points(), 1e-3).unwrap();
        assert!((f.b[0] - -12.4445).abs() < 5e-5, "b0 {}", f.b[0]);
        assert!((f.b[1] - 0.000765).abs() < 5e-7, "b1 {}", f.b[1]);
        assert!((f.b[2] - 0.001864).abs() < 5e-7, "b2 {}", f.b[2]);
        for r in &f.residuals {
            assert!((r.abs() - 0.01266).abs() < 5e-5, "residual {r}");
        }
        // Alternating signs around the square.
        assert!(f.residuals[0] * f.residuals[1] < 0.0 && f.residuals[1] * f.residuals[2] < 0.0);
        // TLS on the same points: nearly the same plane (the tilt is tiny).
        let t = fit_tls(Face::Xy, &thesis_points(), 1e-3).unwrap();
        assert!((t.plane.n - f.plane.n).norm() < 1e-5);
    }

    /// A small deterministic normal generator for tests.
    pub struct Rng(u64);
    impl Rng {
        pub fn new(seed: u64) -> Rng {
            Rng(seed ^ 0x9E37_79B9_7F4A_7C15)
        }
        pub fn uniform(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((self.0 >> 11) as f64 + 0.5) / ((1u64 << 53) as f64)
        }
        pub fn normal(&mut self) -> f64 {
            let (u1, u2) = (self.uniform(), self.uniform());
            (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
        }
    }

    /// Points on the plane n·p = d over a square grid in its in-plane axes,
    /// with normal noise of σ along n.
    pub fn plane_points(
        face: Face,
        n: Vector3<f64>,
        d: f64,
        sigma: f64,
        rng: &mut Rng,
    ) -> Vec<Vector3<f64>> {
        let a = face.normal_axis();
        let (u, w) = face.in_plane_axes();
        let mut out = Vec::new();
        for (su, sw) in [(10.0, 10.0), (40.0, 10.0), (40.0, 40.0), (10.0, 40.0)] {
            for scale in [1.0, 0.7, 0.4] {
                let mut p = Vector3::zeros();
                p[u] = 25.0 + (su - 25.0) * scale;
                p[w] = 25.0 + (sw - 25.0) * scale;
                p[a] = (d - n[u] * p[u] - n[w] * p[w]) / n[a];
                out.push(p + n * (sigma * rng.normal()));
            }
        }
        out
    }

    #[test]
    fn tls_recovers_a_tilted_plane() {
        let n = Vector3::new(0.03, -0.02, 1.0).normalize();
        let mut rng = Rng::new(1);
        let pts = plane_points(Face::Xy, n, 5.0, 0.0, &mut rng);
        let f = fit_tls(Face::Xy, &pts, 1e-3).unwrap();
        assert!((f.plane.n - n).norm() < 1e-12);
        assert!((f.plane.d - 5.0).abs() < 1e-10);
        assert!(rms(&f.residuals) < 1e-10);
        // A tilt about an in-plane axis far from horizontal: OLS and TLS
        // agree on noise-free data too.
        let o = fit_ols(Face::Xy, &pts, 1e-3).unwrap();
        assert!((o.plane.n - n).norm() < 1e-12);
    }

    #[test]
    fn too_few_and_collinear_points_are_errors() {
        let pts = vec![Vector3::new(0.0, 0.0, 1.0), Vector3::new(1.0, 0.0, 1.0)];
        let e = fit_tls(Face::Xy, &pts, 1e-3).unwrap_err();
        assert!(e.0.contains("at least 3"), "{e}");
        let line: Vec<Vector3<f64>> = (0..6)
            .map(|i| Vector3::new(i as f64, 2.0 * i as f64, 1.0))
            .collect();
        let e = fit_tls(Face::Xy, &line, 1e-3).unwrap_err();
        assert!(e.0.contains("collinear"), "{e}");
        let e = fit_ols(Face::Xy, &line, 1e-3).unwrap_err();
        assert!(e.0.contains("collinear"), "{e}");
    }

    #[test]
    fn robust_rejects_one_bad_touch() {
        let n = Vector3::new(0.0, 0.0, 1.0);
        let mut rng = Rng::new(2);
        let mut pts = plane_points(Face::Xy, n, 0.0, 0.005, &mut rng);
        pts[5].z += 0.5;
        let (keep, scale) = robust_keep(Face::Xy, &pts, 4.0, 1e-4, 1e-3).unwrap();
        assert!(!keep.contains(&5));
        assert_eq!(keep.len(), pts.len() - 1);
        assert!(scale > 0.001 && scale < 0.02, "{scale}");
    }

    fn cube_planes(sigma: f64, rng: &mut Rng) -> [TlsFit; 3] {
        // Block corner at (1, 2, 3), slightly rotated.
        let r = nalgebra::Rotation3::from_euler_angles(0.002, -0.001, 0.003);
        let origin = Vector3::new(1.0, 2.0, 3.0);
        let mut fits = Vec::new();
        for face in Face::ALL {
            let mut axis = Vector3::zeros();
            axis[face.normal_axis()] = 1.0;
            let n = r * axis;
            let d = n.dot(&origin);
            let pts = plane_points(face, n, d, sigma, rng);
            fits.push(fit_tls(face, &pts, 1e-3).unwrap());
        }
        [fits[0].clone(), fits[1].clone(), fits[2].clone()]
    }

    #[test]
    fn datum_is_the_intersection_and_squareness_is_zero_for_a_rigid_block() {
        let mut rng = Rng::new(3);
        let f = cube_planes(0.0, &mut rng);
        let d = intersect([&f[0].plane, &f[1].plane, &f[2].plane], 10.0).unwrap();
        assert!((d.p - Vector3::new(1.0, 2.0, 3.0)).norm() < 1e-9, "{}", d.p);
        assert!((d.condition - 1.0).abs() < 1e-6);
        assert!(squareness(&f[0].plane, &f[1].plane).abs() < 1e-12);
        // A face tilted by 1 mrad off square shows as 1 mrad.
        let tilted = Plane {
            n: Vector3::new(0.001f64.sin(), 0.0, 0.001f64.cos()),
            d: 0.0,
            cov: Matrix4::zeros(),
        };
        let yz = Plane {
            n: Vector3::new(1.0, 0.0, 0.0),
            d: 0.0,
            cov: Matrix4::zeros(),
        };
        assert!((squareness(&tilted, &yz).abs() - 0.001).abs() < 1e-9);
    }

    #[test]
    fn nearly_parallel_faces_are_an_error() {
        let a = Plane::from_coefficients(0.0, 0.0, 1.0, 0.0).unwrap();
        let b = Plane::from_coefficients(0.01, 0.0, 1.0, -1.0).unwrap();
        let c = Plane::from_coefficients(0.0, 1.0, 0.0, 0.0).unwrap();
        let e = intersect([&a, &b, &c], 10.0).unwrap_err();
        assert!(e.0.contains("nearly parallel"), "{e}");
    }

    #[test]
    fn datum_covariance_matches_monte_carlo() {
        let sigma = 0.01;
        let mut rng = Rng::new(4);
        // The propagated covariance depends on the data through σ̂ (9
        // residual dof per face here, so one realisation may be off by 2×):
        // compare its mean over the trials (E σ̂² = σ²) with the scatter.
        let trials = 2000;
        let mut ps = Vec::with_capacity(trials);
        let mut prop = Matrix3::zeros();
        for _ in 0..trials {
            let f = cube_planes(sigma, &mut rng);
            let d = intersect([&f[0].plane, &f[1].plane, &f[2].plane], 10.0).unwrap();
            ps.push(d.p);
            prop += d.cov / trials as f64;
        }
        let mean = ps.iter().fold(Vector3::zeros(), |a, p| a + p) / trials as f64;
        let mut emp = Matrix3::zeros();
        for p in &ps {
            let q = p - mean;
            emp += q * q.transpose();
        }
        emp /= (trials - 1) as f64;
        for i in 0..3 {
            let ratio = emp[(i, i)] / prop[(i, i)];
            assert!(
                (0.75..1.33).contains(&ratio),
                "axis {i}: MC {} vs propagated {}",
                emp[(i, i)],
                prop[(i, i)]
            );
        }
        // The datum is unbiased.
        assert!(
            (mean - Vector3::new(1.0, 2.0, 3.0)).norm()
                < 5.0 * prop.trace().sqrt() / (trials as f64).sqrt()
        );
        // OLS covariance propagates as well (same check, coarser).
        let mut rng = Rng::new(5);
        let mut pts = Vec::new();
        let n = Vector3::new(0.0, 0.0, 1.0);
        for _ in 0..trials {
            let p = plane_points(Face::Xy, n, 0.0, sigma, &mut rng);
            pts.push(fit_ols(Face::Xy, &p, 1e-3).unwrap());
        }
        let var_d: f64 = pts.iter().map(|f| f.plane.d * f.plane.d).sum::<f64>() / trials as f64;
        let mean_prop: f64 = pts.iter().map(|f| f.plane.cov[(3, 3)]).sum::<f64>() / trials as f64;
        let ratio = var_d / mean_prop;
        assert!((0.7..1.4).contains(&ratio), "OLS var(d) ratio {ratio}");
    }
}

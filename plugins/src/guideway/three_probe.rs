//! Three-probe error separation (MODELS.md §3.1): workpiece shape h, table
//! straightness motion error δz and pitch β from probes A, B, C spaced
//! L = k·ΔL apart along the travel:
//!
//! ```text
//! Z_A(n) = h(j)      + δz(n)
//! Z_B(n) = h(j + k)  + δz(n) +  L·β(n)
//! Z_C(n) = h(j + 2k) + δz(n) + 2L·β(n)
//! ```
//!
//! with j the grid index of the workpiece point under A at sample n (for a
//! single forward traverse j = n and k = 1, the source's form).
//!
//! Two solutions:
//! - [`separate_recursion`]: the published recursion
//!   h(j+2k) = Z_A − 2Z_B + Z_C + 2h(j+k) − h(j), started from the first
//!   readings (δz = β = 0 where the stencil has no known point yet), run in
//!   recorded order; δz = Z_A − h(j), β = [Z_B − Z_A − h(j+k) + h(j)]/L.
//!   Sensor noise is integrated twice from the start of the travel.
//! - [`separate_lsq`]: one least-squares solve over the whole travel, every
//!   pass at once. δz(n), β(n) are local to a sample, so they are eliminated
//!   exactly: per sample the residual direction is the second difference,
//!   and the normal equations in h are Σ s sᵀ h = Σ s·D(n) with the stencil
//!   s = (+1 at j, −2 at j+k, +1 at j+2k) and D = Z_A − 2Z_B + Z_C — banded
//!   (half-bandwidth 2k), assembled sparse, solved with nalgebra's
//!   Cholesky. Given h, δz and β are the local LS line through the three
//!   residual readings (intercept (5a + 2b − c)/6, slope (c − a)/2L), which
//!   is orthogonal to D, so its noise is independent of ĥ.
//!
//! The free constants: the second difference cannot see a + b·j (per
//! interleaved sub-grid when k > 1: 2k constants). [`Reference::Line`] (the
//! default, ISO straightness convention) reports h about its least-squares
//! line, i.e. h ⊥ the null space — the minimum-norm solution;
//! [`Reference::Ends`] sets h = 0 at both ends of the travel. δz and β take
//! the complementary trend, so the readings are reproduced exactly either
//! way.
//!
//! Uncertainty (LS): reading noise σ i.i.d. on the three probes gives
//! Var D = 6σ², Cov ĥ = 6σ²·(Σ s sᵀ)⁺ (referenced), Var δẑ = 5σ²/6 +
//! wᵀ Cov ĥ w, Var β̂ = σ²/2L² + vᵀ Cov ĥ v. σ is estimated from the
//! residuals of D when the travel is redundant (several passes), else the
//! configured probe noise is used (one pass with k = 1 is exactly
//! determined: no residual degrees of freedom).
//!
//! Not curable by either method (MODELS.md weakness, see README): a probe
//! zero offset o_A − 2o_B + o_C adds a constant to D, which is exactly a
//! parabola in h — indistinguishable from a curved workpiece in one setup.

use anyhow::{anyhow, bail};
use nalgebra::{DMatrix, DVector};
use sparkout_pipeline::{InputError, Result};

use super::input::Readings;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    Lsq,
    Recursion,
}

impl Method {
    pub fn parse(s: &str) -> Option<Method> {
        match s {
            "lsq" => Some(Method::Lsq),
            "recursion" => Some(Method::Recursion),
            _ => None,
        }
    }
    pub fn as_str(self) -> &'static str {
        match self {
            Method::Lsq => "lsq",
            Method::Recursion => "recursion",
        }
    }
}

/// How the constants the second difference cannot see are fixed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reference {
    /// h about its least-squares line (per sub-grid when k > 1).
    Line,
    /// h = 0 at the first and last workpiece point (per sub-grid).
    Ends,
}

impl Reference {
    pub fn parse(s: &str) -> Option<Reference> {
        match s {
            "line" => Some(Reference::Line),
            "ends" => Some(Reference::Ends),
            _ => None,
        }
    }
    pub fn as_str(self) -> &'static str {
        match self {
            Reference::Line => "line",
            Reference::Ends => "ends",
        }
    }
}

/// Result of a separation.
#[derive(Debug, Clone)]
pub struct Separation {
    pub method: Method,
    /// Reference of h (`None`: the recursion's own start values).
    pub reference: Option<Reference>,
    /// Workpiece shape per grid point j (mm).
    pub h_mm: Vec<f64>,
    pub h_sigma_mm: Option<Vec<f64>>,
    /// Per sample.
    pub dz_mm: Vec<f64>,
    pub beta_rad: Vec<f64>,
    pub dz_sigma_mm: Option<Vec<f64>>,
    pub beta_sigma_rad: Option<Vec<f64>>,
    /// Reading noise behind the bands, and where it came from.
    pub sigma_mm: Option<f64>,
    pub sigma_source: Option<&'static str>,
    /// Residual degrees of freedom of the LS solve.
    pub dof: usize,
}

impl Separation {
    /// h under probe A at each sample.
    pub fn h_at_samples(&self, r: &Readings) -> Vec<f64> {
        r.j.iter().map(|&j| self.h_mm[j]).collect()
    }
    pub fn h_sigma_at_samples(&self, r: &Readings) -> Option<Vec<f64>> {
        self.h_sigma_mm
            .as_ref()
            .map(|s| r.j.iter().map(|&j| s[j]).collect())
    }
}

/// RMS of h about its least-squares line (straightness, reference-free).
pub fn straightness_rms(h: &[f64]) -> f64 {
    let n = h.len() as f64;
    if h.len() < 3 {
        return 0.0;
    }
    let xm = (n - 1.0) / 2.0;
    let ym = h.iter().sum::<f64>() / n;
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (i, y) in h.iter().enumerate() {
        let dx = i as f64 - xm;
        sxy += dx * (y - ym);
        sxx += dx * dx;
    }
    let b = sxy / sxx;
    (h.iter()
        .enumerate()
        .map(|(i, y)| (y - ym - b * (i as f64 - xm)).powi(2))
        .sum::<f64>()
        / n)
        .sqrt()
}

fn stencil(r: &Readings, i: usize) -> [usize; 3] {
    let j = r.j[i];
    [j, j + r.k, j + 2 * r.k]
}

fn second_difference(r: &Readings, i: usize) -> f64 {
    r.z_mm[0][i] - 2.0 * r.z_mm[1][i] + r.z_mm[2][i]
}

/// δz and β of one sample from h (local LS line through the three
/// residual readings; with exact data the same as MODELS.md's formulas).
fn local(r: &Readings, i: usize, h: &[f64]) -> (f64, f64) {
    let [a, b, c] = stencil(r, i);
    let ra = r.z_mm[0][i] - h[a];
    let rb = r.z_mm[1][i] - h[b];
    let rc = r.z_mm[2][i] - h[c];
    (
        (5.0 * ra + 2.0 * rb - rc) / 6.0,
        (rc - ra) / (2.0 * r.spacing_mm),
    )
}

/// Orthonormal basis (m × 2k) of the null space of the second-difference
/// operator: per sub-grid r (j ≡ r mod k), a constant and a slope.
fn null_basis(m: usize, k: usize) -> DMatrix<f64> {
    let mut b = DMatrix::zeros(m, 2 * k);
    for j in 0..m {
        let r = j % k;
        b[(j, 2 * r)] = 1.0;
        b[(j, 2 * r + 1)] = j as f64 - (m as f64 - 1.0) / 2.0;
    }
    b.qr().q()
}

/// The published recursion (see the module doc).
pub fn separate_recursion(r: &Readings) -> Result<Separation> {
    let m = r.positions();
    let mut h: Vec<Option<f64>> = vec![None; m];
    let mut dz = Vec::with_capacity(r.len());
    let mut beta = Vec::with_capacity(r.len());
    for i in 0..r.len() {
        let s = stencil(r, i);
        let z = [r.z_mm[0][i], r.z_mm[1][i], r.z_mm[2][i]];
        let d = second_difference(r, i);
        let unknown: Vec<usize> = (0..3).filter(|&q| h[s[q]].is_none()).collect();
        match unknown.len() {
            0 => {}
            1 => {
                let v = |q: usize| h[s[q]].expect("known");
                let solved = match unknown[0] {
                    2 => d - v(0) + 2.0 * v(1),
                    0 => d + 2.0 * v(1) - v(2),
                    _ => (v(0) + v(2) - d) / 2.0,
                };
                h[s[unknown[0]]] = Some(solved);
            }
            _ => {
                // "h(0), h(1) set from the first readings": the table error
                // is taken as zero where nothing is known yet (β = 0, δz
                // from a known point if there is one).
                let dz0 = (0..3)
                    .find_map(|q| h[s[q]].map(|hv| z[q] - hv))
                    .unwrap_or(0.0);
                for q in unknown {
                    h[s[q]] = Some(z[q] - dz0);
                }
            }
        }
        let (ha, hb) = (h[s[0]].expect("set"), h[s[1]].expect("set"));
        dz.push(z[0] - ha);
        beta.push((z[1] - z[0] - hb + ha) / r.spacing_mm);
    }
    // Points never under a probe cannot happen (every stencil is filled).
    let h_mm: Vec<f64> = h.into_iter().map(|v| v.unwrap_or(f64::NAN)).collect();
    Ok(Separation {
        method: Method::Recursion,
        reference: None,
        h_mm,
        h_sigma_mm: None,
        dz_mm: dz,
        beta_rad: beta,
        dz_sigma_mm: None,
        beta_sigma_rad: None,
        sigma_mm: None,
        sigma_source: None,
        dof: 0,
    })
}

/// Largest workpiece grid the LS solve takes: its covariance needs the
/// dense m×m inverse (3000² doubles = 72 MB per matrix).
pub const MAX_LSQ_POINTS: usize = 3000;

/// One least-squares solve over the whole travel (see the module doc).
/// `sigma_cfg_mm`: reading noise to use when the residuals have too few
/// degrees of freedom to estimate it.
pub fn separate_lsq(r: &Readings, reference: Reference, sigma_cfg_mm: f64) -> Result<Separation> {
    let m = r.positions();
    let k = r.k;
    if m < 2 * k + 1 {
        bail!("travel too short for the probe spacing");
    }
    if m > MAX_LSQ_POINTS {
        return Err(InputError::new(
            &r.path,
            format!(
                "{m} workpiece points: the least-squares separation with full covariance handles up to {MAX_LSQ_POINTS} (dense m×m normal equations); use [guideway.separate] method = \"recursion\" or a coarser sample step"
            ),
        )
        .column("x_mm")
        .into());
    }
    // Banded normal matrix Σ s sᵀ and right-hand side Σ s·D.
    let mut nm = DMatrix::<f64>::zeros(m, m);
    let mut rhs = DVector::<f64>::zeros(m);
    const W: [f64; 3] = [1.0, -2.0, 1.0];
    for i in 0..r.len() {
        let s = stencil(r, i);
        let d = second_difference(r, i);
        for a in 0..3 {
            rhs[s[a]] += W[a] * d;
            for b in 0..3 {
                nm[(s[a], s[b])] += W[a] * W[b];
            }
        }
    }
    // Fix the null space (a + b·j per sub-grid) by adding c·QQᵀ: on the
    // null space the matrix is c·I, on its complement Σ s sᵀ, so the
    // solution is the minimum-norm one (h ⊥ null space = the `line`
    // reference) and A⁻¹ − QQᵀ/c is the pseudo-inverse.
    let q = null_basis(m, k);
    let qqt = &q * q.transpose();
    let c = (nm.trace() / m as f64).max(1e-300);
    let a = &nm + &qqt * c;
    let chol = a.cholesky().ok_or_else(|| {
        anyhow::Error::from(
            InputError::new(
                &r.path,
                "the travel leaves workpiece points that no probe stencil connects (x_mm has holes): the separation is not determined",
            )
            .column("x_mm"),
        )
    })?;
    let h = chol.solve(&rhs);
    let pinv = chol.inverse() - &qqt / c;
    // Residual σ of D = 6σ² per sample.
    let rank = m - 2 * k;
    let dof = r.len().saturating_sub(rank);
    let rss: f64 = (0..r.len())
        .map(|i| {
            let s = stencil(r, i);
            let fit = h[s[0]] - 2.0 * h[s[1]] + h[s[2]];
            (second_difference(r, i) - fit).powi(2)
        })
        .sum();
    let (sigma, source) = if dof >= 10 {
        ((rss / dof as f64 / 6.0).sqrt(), "residuals")
    } else {
        (sigma_cfg_mm, "config")
    };
    let mut cov = pinv * (6.0 * sigma * sigma);
    let mut h: Vec<f64> = h.iter().copied().collect();
    if reference == Reference::Ends {
        // h' = T h, T = I − Q (R Q)⁻¹ R, R: h = 0 at each sub-grid's ends.
        let mut rm = DMatrix::<f64>::zeros(2 * k, m);
        for sub in 0..k {
            let first = sub;
            let last = sub + ((m - 1 - sub) / k) * k;
            if last == first {
                bail!("reference `ends` needs at least two points per sub-grid");
            }
            rm[(2 * sub, first)] = 1.0;
            rm[(2 * sub + 1, last)] = 1.0;
        }
        let rq = &rm * &q;
        let rq_inv = rq
            .try_inverse()
            .ok_or_else(|| anyhow!("reference `ends`: singular constraint"))?;
        let t = DMatrix::<f64>::identity(m, m) - &q * rq_inv * &rm;
        let hv = &t * DVector::from_column_slice(&h);
        h = hv.iter().copied().collect();
        cov = &t * cov * t.transpose();
    }
    let mut dz = Vec::with_capacity(r.len());
    let mut beta = Vec::with_capacity(r.len());
    let mut dz_s = Vec::with_capacity(r.len());
    let mut beta_s = Vec::with_capacity(r.len());
    let l = r.spacing_mm;
    let wd = [-5.0 / 6.0, -2.0 / 6.0, 1.0 / 6.0];
    let wb = [1.0 / (2.0 * l), 0.0, -1.0 / (2.0 * l)];
    let quad = |w: &[f64; 3], s: &[usize; 3]| -> f64 {
        let mut v = 0.0;
        for a in 0..3 {
            for b in 0..3 {
                v += w[a] * w[b] * cov[(s[a], s[b])];
            }
        }
        v
    };
    for i in 0..r.len() {
        let (d, b) = local(r, i, &h);
        dz.push(d);
        beta.push(b);
        let s = stencil(r, i);
        let s2 = sigma * sigma;
        dz_s.push((5.0 * s2 / 6.0 + quad(&wd, &s)).max(0.0).sqrt());
        beta_s.push((s2 / (2.0 * l * l) + quad(&wb, &s)).max(0.0).sqrt());
    }
    let h_sigma = (0..m).map(|j| cov[(j, j)].max(0.0).sqrt()).collect();
    Ok(Separation {
        method: Method::Lsq,
        reference: Some(reference),
        h_mm: h,
        h_sigma_mm: Some(h_sigma),
        dz_mm: dz,
        beta_rad: beta,
        dz_sigma_mm: Some(dz_s),
        beta_sigma_rad: Some(beta_s),
        sigma_mm: Some(sigma),
        sigma_source: Some(source),
        dof,
    })
}

/// The chosen method.
pub fn separate(
    r: &Readings,
    method: Method,
    reference: Reference,
    sigma_cfg_mm: f64,
) -> Result<Separation> {
    match method {
        Method::Lsq => separate_lsq(r, reference, sigma_cfg_mm),
        Method::Recursion => separate_recursion(r),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::guideway::input::{prepare, tests::geom, InputOptions, RawReadings};
    use std::path::Path;

    /// Exact readings of a known h, δz, β over `passes` back-and-forth passes.
    fn synth(m: usize, k: usize, passes: usize) -> (Readings, Vec<f64>, Vec<f64>) {
        let step = 30.0;
        let l = k as f64 * step;
        let hj = |j: usize| 2e-3 * ((j as f64) * 0.21).sin() + 1e-6 * (j * j) as f64;
        let mut raw = RawReadings::default();
        let (mut dzs, mut n) = (Vec::new(), 0i64);
        for p in 0..passes {
            let js: Vec<usize> = if p % 2 == 0 {
                (0..m).collect()
            } else {
                (0..m).rev().collect()
            };
            for j in js {
                let dz = 1e-3 * (n as f64 * 0.05).cos() + 3e-4 * p as f64;
                let beta = 1e-6 * (n as f64 * 0.03).sin();
                raw.n.push(n);
                raw.x_mm.push(j as f64 * step);
                raw.z_mm[0].push(hj(j) + dz);
                raw.z_mm[1].push(hj(j + k) + dz + l * beta);
                raw.z_mm[2].push(hj(j + 2 * k) + dz + 2.0 * l * beta);
                dzs.push(dz);
                n += 1;
            }
        }
        let r = prepare(
            Path::new("g.parquet"),
            raw,
            &geom(l, step),
            &InputOptions::default(),
        )
        .unwrap();
        let h = (0..r.positions()).map(hj).collect();
        (r, h, dzs)
    }

    /// ĥ − h must be a line a + b·j and δẑ − δz = −(a + b·j) at A's point.
    fn assert_exact_up_to_line(r: &Readings, s: &Separation, h: &[f64], dz: &[f64]) {
        let e: Vec<f64> = s.h_mm.iter().zip(h).map(|(a, b)| a - b).collect();
        let n = e.len() as f64;
        let xm = (n - 1.0) / 2.0;
        let ym = e.iter().sum::<f64>() / n;
        let b = e
            .iter()
            .enumerate()
            .map(|(i, y)| (i as f64 - xm) * (y - ym))
            .sum::<f64>()
            / e.iter()
                .enumerate()
                .map(|(i, _)| (i as f64 - xm).powi(2))
                .sum::<f64>();
        let line = |j: usize| ym + b * (j as f64 - xm);
        for (j, v) in e.iter().enumerate() {
            assert!((v - line(j)).abs() < 1e-10, "h at {j}: {v} vs line");
        }
        for (i, d) in dz.iter().enumerate() {
            let want = d - line(r.j[i]);
            assert!((s.dz_mm[i] - want).abs() < 1e-10, "dz at {i}");
        }
    }

    #[test]
    fn both_methods_are_exact_on_noise_free_data() {
        let (r, h, dz) = synth(40, 1, 3);
        for s in [
            separate_recursion(&r).unwrap(),
            separate_lsq(&r, Reference::Line, 1e-4).unwrap(),
            separate_lsq(&r, Reference::Ends, 1e-4).unwrap(),
        ] {
            assert_exact_up_to_line(&r, &s, &h, &dz);
        }
        let ends = separate_lsq(&r, Reference::Ends, 1e-4).unwrap();
        assert!(ends.h_mm[0].abs() < 1e-12 && ends.h_mm[41].abs() < 1e-12);
        let line = separate_lsq(&r, Reference::Line, 1e-4).unwrap();
        assert!(line.h_mm.iter().sum::<f64>().abs() < 1e-10);
        assert_eq!(line.sigma_source, Some("residuals"));
        assert!(line.sigma_mm.unwrap() < 1e-12);
    }

    #[test]
    fn single_pass_lsq_uses_the_configured_sigma() {
        let (r, _, _) = synth(30, 1, 1);
        let s = separate_lsq(&r, Reference::Line, 1e-4).unwrap();
        assert_eq!(s.sigma_source, Some("config"));
        let hs = s.h_sigma_mm.unwrap();
        // Integrated twice: the band is widest at the ends, never zero.
        assert!(hs.iter().all(|v| *v > 0.0));
        assert!(hs[0] > hs[15]);
    }
}

//! Three-probe error separation (docs/models.md §3.1): workpiece shape h, table
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
//!   exactly: per sample the residual direction is the second difference
//!   D = Z_A − 2Z_B + Z_C with the stencil s = (+1 at j, −2 at j+k, +1 at
//!   j+2k). Samples sharing a stencil are the same row, so the problem is
//!   the averaged D̄(j) weighted by its count; with every j present it is
//!   square up to the null space and its solution reproduces D̄ exactly —
//!   computed by the recursion on D̄ as compensated cumulative sums, then
//!   referenced (no normal equations: their condition number grows as m⁴). O(samples + m) with the covariance band, any length. Given
//!   h, δz and β are the local LS line through the three residual readings
//!   (intercept (5a + 2b − c)/6, slope (c − a)/2L), which is orthogonal to
//!   D, so its noise is independent of ĥ.
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
//! Var D = 6σ², Cov ĥ = 6σ²·(Σ s sᵀ)⁺ (referenced; only its band within
//! 2k is needed and computed, see [`solve_chain`]), Var δẑ = 5σ²/6 +
//! wᵀ Cov ĥ w, Var β̂ = σ²/2L² + vᵀ Cov ĥ v. σ is estimated from the
//! residuals of D when the travel is redundant (several passes), else the
//! configured probe noise is used (one pass with k = 1 is exactly
//! determined: no residual degrees of freedom).
//!
//! Not curable by either method (docs/models.md §3.1, weak points): a probe
//! zero offset o_A − 2o_B + o_C adds a constant to D, which is exactly a
//! parabola in h — indistinguishable from a curved workpiece in one setup.

use crate::bail;
use sparkout_pipeline::{InputError, Result};

use super::input::Readings;

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    Lsq,
    Recursion,
}

impl Method {
    pub fn as_str(self) -> &'static str {
        match self {
            Method::Lsq => "lsq",
            Method::Recursion => "recursion",
        }
    }
}

/// How the constants the second difference cannot see are fixed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Reference {
    /// h about its least-squares line (per sub-grid when k > 1).
    Line,
    /// h = 0 at the first and last workpiece point (per sub-grid).
    Ends,
}

impl Reference {
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
/// residual readings; with exact data the same as the recursion of docs/models.md §3.1).
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

/// Running sum with Neumaier's compensation: the particular solution is a
/// double cumulative sum over up to 10⁵ points, where plain summation
/// loses digits in proportion to the length (exact to 1e-9 mm
/// at 30 000 points).
#[derive(Debug, Default, Clone, Copy)]
struct Sum {
    s: f64,
    c: f64,
}

impl Sum {
    fn add(&mut self, x: f64) {
        let t = self.s + x;
        self.c += if self.s.abs() >= x.abs() {
            (self.s - t) + x
        } else {
            (x - t) + self.s
        };
        self.s = t;
    }
    fn get(&self) -> f64 {
        self.s + self.c
    }
}

/// `G·d` of the module doc: h(t), t = 0..len, of one sub-grid with
/// h(0) = h(1) = 0 and h(t+2) − 2h(t+1) + h(t) = d(t) — the published
/// recursion (docs/models.md §3.1) written as two compensated cumulative sums
/// (slope, then height), so rounding does not grow with the travel.
fn double_sum(d: &[f64], len: usize) -> Vec<f64> {
    let mut h = vec![0.0; len];
    let (mut slope, mut height) = (Sum::default(), Sum::default());
    for (t, v) in d.iter().enumerate().take(len.saturating_sub(2)) {
        slope.add(*v);
        height.add(slope.get());
        h[t + 2] = height.get();
    }
    h
}

/// `Gᵀ·v`: (Gᵀv)(u) = Σ_{t ≥ u+2} (t − 1 − u)·v(t), two reverse cumulative
/// sums (only feeds the uncertainty, so no compensation).
fn double_sum_adjoint(v: &[f64]) -> Vec<f64> {
    let len = v.len();
    let mut out = vec![0.0; len.saturating_sub(2)];
    let (mut r1, mut r2) = (0.0, 0.0);
    for t in (2..len).rev() {
        r1 += v[t];
        r2 += r1;
        out[t - 2] = r2;
    }
    out
}

/// One sub-grid (grid points j ≡ r mod k) solved: h about its reference,
/// and the band of its covariance per unit variance of D, cov(t, t + δ)
/// for δ = 0, 1, 2 (zero past the end).
struct ChainFit {
    h: Vec<f64>,
    cov: [Vec<f64>; 3],
}

/// Solve one sub-grid of `len` points from its averaged second
/// differences `dbar` (len − 2 of them) with weights w = 1/count (Var D̄ =
/// w·Var D). ĥ = T·G·D̄, T = I − B·Uᵀ removes the trend B = [1, t − c]
/// the second difference cannot see: for `Line` U = B(BᵀB)⁻¹ (orthogonal
/// projection: ĥ ⊥ null space, the minimum-norm LS solution), for `Ends`
/// Uᵀh = (mean of the end values, end-to-end slope). Cov ĥ ∝ T·M·Tᵀ with
/// M = G·W·Gᵀ, whose band has the closed form M(t, t+δ) = b(t) + δ·a(t),
/// a(t) = Σ_{u≤t−2} w(u)(t−1−u), b(t) = Σ_{u≤t−2} w(u)(t−1−u)² (both by
/// running sums), and M·U costs two passes of G: O(len) in all.
fn solve_chain(dbar: &[f64], w: &[f64], len: usize, reference: Reference) -> ChainFit {
    let c = (len as f64 - 1.0) / 2.0;
    let bt = |t: usize| t as f64 - c;
    let u: [Vec<f64>; 2] = match reference {
        Reference::Line => {
            let sxx: f64 = (0..len)
                .map(|t| bt(t) * bt(t))
                .sum::<f64>()
                .max(f64::MIN_POSITIVE);
            [
                vec![1.0 / len as f64; len],
                (0..len).map(|t| bt(t) / sxx).collect(),
            ]
        }
        Reference::Ends => {
            let mut u0 = vec![0.0; len];
            let mut u1 = vec![0.0; len];
            u0[0] += 0.5;
            u0[len - 1] += 0.5;
            let span = (len as f64 - 1.0).max(1.0);
            u1[0] -= 1.0 / span;
            u1[len - 1] += 1.0 / span;
            [u0, u1]
        }
    };
    let dot = |a: &[f64], b: &[f64]| -> f64 { a.iter().zip(b).map(|(x, y)| x * y).sum() };
    let hp = double_sum(dbar, len);
    let (a0, a1) = (dot(&u[0], &hp), dot(&u[1], &hp));
    let h = (0..len).map(|t| hp[t] - a0 - a1 * bt(t)).collect();

    // M·U and Uᵀ·M·U.
    let mu: Vec<Vec<f64>> = u
        .iter()
        .map(|uc| {
            let g = double_sum_adjoint(uc);
            let wg: Vec<f64> = g.iter().zip(w).map(|(g, w)| g * w).collect();
            double_sum(&wg, len)
        })
        .collect();
    let kk = [
        [dot(&u[0], &mu[0]), dot(&u[0], &mu[1])],
        [dot(&u[1], &mu[0]), dot(&u[1], &mu[1])],
    ];
    let bvec = |t: usize| [1.0, bt(t)];
    let mut cov = [vec![0.0; len], vec![0.0; len], vec![0.0; len]];
    let (mut s, mut a, mut b) = (0.0, 0.0, 0.0);
    for t in 0..len {
        for (delta, band) in cov.iter_mut().enumerate() {
            let t2 = t + delta;
            if t2 >= len {
                continue;
            }
            let (bi, bj) = (bvec(t), bvec(t2));
            let mut v = b + delta as f64 * a;
            for q in 0..2 {
                v -= bi[q] * mu[q][t2] + mu[q][t] * bj[q];
                for p in 0..2 {
                    v += bi[q] * kk[q][p] * bj[p];
                }
            }
            band[t] = v;
        }
        // a(t+1) = a(t) + S(t), b(t+1) = b(t) + 2a(t) + S(t), S(t) = Σ_{u≤t−1} w.
        if t >= 1 {
            s += w.get(t - 1).copied().unwrap_or(0.0);
        }
        b += 2.0 * a + s;
        a += s;
    }
    ChainFit { h, cov }
}

/// One least-squares solve over the whole travel (see the module doc).
/// `sigma_cfg_mm`: reading noise to use when the residuals have too few
/// degrees of freedom to estimate it.
///
/// Samples with the same stencil are identical rows of the LS problem, so
/// it reduces to the averaged second differences D̄(j) with weights
/// count(j); with every j = 0..m−2k present the system in h is square up
/// to the 2k-dimensional null space, and its LS solution reproduces D̄
/// exactly: the recursion on D̄ (no normal equations, whose condition
/// number grows as m⁴ — the dense solve gave 3.7e-6 mm errors at 2 900 points),
/// then the reference. O(samples + m), any length.
pub fn separate_lsq(r: &Readings, reference: Reference, sigma_cfg_mm: f64) -> Result<Separation> {
    let m = r.positions();
    let k = r.k;
    if m < 2 * k + 1 {
        bail!("travel too short for the probe spacing");
    }
    let eqs = m - 2 * k;
    let mut dsum = vec![0.0; eqs];
    let mut count = vec![0usize; eqs];
    for i in 0..r.len() {
        dsum[r.j[i]] += second_difference(r, i);
        count[r.j[i]] += 1;
    }
    if let Some(j) = count.iter().position(|c| *c == 0) {
        return Err(InputError::new(
            &r.path,
            format!(
                "no sample has probe A at x_mm = {} (grid point {j}): the travel leaves workpiece points that no probe stencil connects (x_mm has holes), the separation is not determined",
                r.x0_mm + j as f64 * r.step_mm
            ),
        )
        .column("x_mm")
        .into());
    }
    let mut h = vec![0.0; m];
    let mut cov = [vec![0.0; m], vec![0.0; m], vec![0.0; m]];
    for sub in 0..k {
        let grid: Vec<usize> = (sub..m).step_by(k).collect();
        let len = grid.len();
        let eq: Vec<usize> = grid.iter().copied().take(len.saturating_sub(2)).collect();
        let dbar: Vec<f64> = eq.iter().map(|&j| dsum[j] / count[j] as f64).collect();
        let w: Vec<f64> = eq.iter().map(|&j| 1.0 / count[j] as f64).collect();
        let fit = solve_chain(&dbar, &w, len, reference);
        for (t, &j) in grid.iter().enumerate() {
            h[j] = fit.h[t];
            for (band, fb) in cov.iter_mut().zip(&fit.cov) {
                band[j] = fb[t];
            }
        }
    }
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
    let var_d = 6.0 * sigma * sigma;
    for band in cov.iter_mut() {
        band.iter_mut().for_each(|v| *v *= var_d);
    }
    let mut dz = Vec::with_capacity(r.len());
    let mut beta = Vec::with_capacity(r.len());
    let mut dz_s = Vec::with_capacity(r.len());
    let mut beta_s = Vec::with_capacity(r.len());
    let l = r.spacing_mm;
    let wd = [-5.0 / 6.0, -2.0 / 6.0, 1.0 / 6.0];
    let wb = [1.0 / (2.0 * l), 0.0, -1.0 / (2.0 * l)];
    // wᵀ Cov ĥ w over a stencil (j, j+k, j+2k) from the band.
    let quad = |w: &[f64; 3], s: &[usize; 3]| -> f64 {
        let diag: f64 = (0..3).map(|a| w[a] * w[a] * cov[0][s[a]]).sum();
        diag + 2.0
            * (w[0] * w[1] * cov[1][s[0]] + w[1] * w[2] * cov[1][s[1]] + w[0] * w[2] * cov[2][s[0]])
    };
    let s2 = sigma * sigma;
    for i in 0..r.len() {
        let (d, b) = local(r, i, &h);
        dz.push(d);
        beta.push(b);
        let s = stencil(r, i);
        dz_s.push((5.0 * s2 / 6.0 + quad(&wd, &s)).max(0.0).sqrt());
        beta_s.push((s2 / (2.0 * l * l) + quad(&wb, &s)).max(0.0).sqrt());
    }
    let h_sigma = cov[0].iter().map(|v| v.max(0.0).sqrt()).collect();
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
mod tests;

//! Identification of the 21 error functions and the tracker frame from
//! tracker points (docs/models.md §5): nonlinear least squares by
//! Levenberg–Marquardt (the `levenberg-marquardt` crate) on measured minus
//! modelled tracker points, the parameters' covariance from JᵀJ and the
//! residual variance, and the checks that refuse an unidentifiable
//! configuration instead of returning a meaningless fit.

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt, TerminationReason};
use nalgebra::storage::Owned;
use nalgebra::{DMatrix, DVector, Dyn, Matrix3, Rotation3, SVD};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::chain::{function_axis, is_rotation, Layout, Model, Point, V3};

/// One tracker measurement of one commanded point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Obs {
    pub pt: Point,
    /// Measured point, tracker frame (mm).
    pub m: V3,
}

/// Solver settings.
#[derive(Debug, Clone, Copy)]
pub struct IdentOptions {
    /// Smallest accepted σ_min/σ_max of the column-scaled Jacobian.
    pub rcond: f64,
    pub max_evaluations: usize,
}

impl Default for IdentOptions {
    fn default() -> Self {
        IdentOptions {
            rcond: 1e-8,
            max_evaluations: 200,
        }
    }
}

/// Why the data cannot identify the model: a message naming what is
/// missing (points, spread, tool offsets) or which parameters cannot be
/// separated.
#[derive(Debug, Clone, PartialEq)]
pub struct Unidentifiable(pub String);

impl std::fmt::Display for Unidentifiable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.0)
    }
}

impl std::error::Error for Unidentifiable {}

/// An identified model.
#[derive(Debug, Clone)]
pub struct Identified {
    pub model: Model,
    /// Covariance of the parameters (layout order), s²·(JᵀJ)⁻¹.
    pub cov: DMatrix<f64>,
    /// Residual standard deviation per coordinate, s = √(RSS/dof) (mm).
    pub sigma_mm: f64,
    pub dof: usize,
    pub evaluations: usize,
    pub termination: String,
    /// σ_min/σ_max of the column-scaled Jacobian at the solution.
    pub rcond: f64,
}

impl Identified {
    pub fn std(&self, i: usize) -> f64 {
        self.cov[(i, i)].max(0.0).sqrt()
    }
}

/// A seeded, deterministic split of `n` rows into (identification,
/// held-out), each sorted; `round(fraction·n)` rows are held out.
pub fn split(n: usize, fraction: f64, seed: u64) -> (Vec<usize>, Vec<usize>) {
    let h = ((fraction * n as f64).round() as usize).min(n);
    let mut idx: Vec<usize> = (0..n).collect();
    idx.shuffle(&mut ChaCha8Rng::seed_from_u64(seed));
    let mut hold: Vec<usize> = idx[..h].to_vec();
    let mut ident: Vec<usize> = idx[h..].to_vec();
    hold.sort_unstable();
    ident.sort_unstable();
    (ident, hold)
}

/// The Jacobian of the stacked tracker residuals (3 rows per point).
pub fn jacobian(model: &Model, obs: &[Obs]) -> DMatrix<f64> {
    let n = model.layout.n_params();
    let mut j = DMatrix::zeros(3 * obs.len(), n);
    let mut rows = vec![vec![0.0; n]; 3];
    for (i, o) in obs.iter().enumerate() {
        {
            let (a, rest) = rows.split_at_mut(1);
            let (b, c) = rest.split_at_mut(1);
            model.tracker_point_jac(&o.pt, [&mut a[0], &mut b[0], &mut c[0]]);
        }
        for (r, row) in rows.iter().enumerate() {
            for (k, v) in row.iter().enumerate() {
                j[(3 * i + r, k)] = *v;
            }
        }
    }
    j
}

pub fn residuals(model: &Model, obs: &[Obs]) -> DVector<f64> {
    let mut r = DVector::zeros(3 * obs.len());
    for (i, o) in obs.iter().enumerate() {
        let d = model.tracker_point(&o.pt) - o.m;
        for k in 0..3 {
            r[3 * i + k] = d[k];
        }
    }
    r
}

struct Problem<'a> {
    model: Model,
    obs: &'a [Obs],
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for Problem<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;
    fn set_params(&mut self, x: &DVector<f64>) {
        self.model.params.copy_from(x);
    }
    fn params(&self) -> DVector<f64> {
        self.model.params.clone()
    }
    fn residuals(&self) -> Option<DVector<f64>> {
        Some(residuals(&self.model, self.obs))
    }
    fn jacobian(&self) -> Option<DMatrix<f64>> {
        Some(jacobian(&self.model, self.obs))
    }
}

/// Rigid alignment (Kabsch) of the nominal points onto the measured ones:
/// the tracker frame's starting value, the machine errors being small.
pub fn kabsch(obs: &[Obs]) -> (V3, V3) {
    let n = obs.len() as f64;
    let pc = obs.iter().map(|o| o.pt.nominal()).sum::<V3>() / n;
    let mc = obs.iter().map(|o| o.m).sum::<V3>() / n;
    let mut h = Matrix3::zeros();
    for o in obs {
        h += (o.pt.nominal() - pc) * (o.m - mc).transpose();
    }
    let svd = h.svd(true, true);
    let (u, vt) = (svd.u.expect("u"), svd.v_t.expect("v_t"));
    let v = vt.transpose();
    let d = (v * u.transpose()).determinant().signum();
    let r = v * Matrix3::from_diagonal(&V3::new(1.0, 1.0, d)) * u.transpose();
    let rot = Rotation3::from_matrix_unchecked(r);
    let w = rot.scaled_axis();
    (w, mc - r * pc)
}

/// Data checks that need no Jacobian: enough equations, points spread in
/// 3-D, enough distinct positions per axis for the polynomial degree.
pub fn precheck(layout: &Layout, obs: &[Obs]) -> Result<(), Unidentifiable> {
    let n = obs.len();
    let p = layout.n_params();
    if 3 * n <= p {
        return Err(Unidentifiable(format!(
            "too few points: {n} identification points give {} equations for {p} parameters (21 error functions of degree {}, tracker frame); need at least {} points — measure more points, lower the degree or the holdout fraction",
            3 * n,
            layout.degree,
            p / 3 + 1
        )));
    }
    let c = obs
        .iter()
        .map(|o| V3::new(o.pt.q[0], o.pt.q[1], o.pt.q[2]))
        .sum::<V3>()
        / n as f64;
    let mut s = Matrix3::zeros();
    for o in obs {
        let d = V3::new(o.pt.q[0], o.pt.q[1], o.pt.q[2]) - c;
        s += d * d.transpose();
    }
    let e = s.symmetric_eigen();
    let (imin, imax) = (e.eigenvalues.imin(), e.eigenvalues.imax());
    if e.eigenvalues[imin] <= 1e-12 * e.eigenvalues[imax].max(1e-300) {
        let nrm = e.eigenvectors.column(imin);
        return Err(Unidentifiable(format!(
            "the identification points all lie on one plane (normal ≈ ({:.3}, {:.3}, {:.3})): error functions of position cannot be separated from each other; spread the points through the workspace volume",
            nrm[0], nrm[1], nrm[2]
        )));
    }
    for axis in 0..3 {
        let needed = (0..layout.coef.len())
            .filter(|&i| function_axis(layout.coef[i].0) == axis)
            .map(|i| layout.coef[i].1 + 1)
            .max()
            .unwrap_or(0);
        let mut v: Vec<f64> = obs.iter().map(|o| o.pt.q[axis]).collect();
        v.sort_by(f64::total_cmp);
        v.dedup_by(|a, b| (*a - *b).abs() < 1e-6);
        if v.len() < needed {
            return Err(Unidentifiable(format!(
                "{}_mm takes only {} distinct values among the identification points; polynomials of degree {} in it need at least {needed} — add points at other {} positions or lower the degree",
                super::chain::AXES[axis],
                v.len(),
                needed - 1,
                super::chain::AXES[axis]
            )));
        }
    }
    Ok(())
}

/// Column-scaled SVD of J: (column norms, singular values, V).
fn scaled_svd(j: &DMatrix<f64>) -> (DVector<f64>, DVector<f64>, DMatrix<f64>) {
    let norms = DVector::from_iterator(
        j.ncols(),
        j.column_iter().map(|c| {
            let n = c.norm();
            if n > 0.0 {
                n
            } else {
                1.0
            }
        }),
    );
    let mut js = j.clone();
    for (k, mut c) in js.column_iter_mut().enumerate() {
        c /= norms[k];
    }
    let svd = SVD::new(js, false, true);
    let v = svd.v_t.expect("v_t").transpose();
    (norms, svd.singular_values, v)
}

fn rcond_of(sv: &DVector<f64>) -> f64 {
    let max = sv.max();
    if max > 0.0 {
        sv.min() / max
    } else {
        0.0
    }
}

/// Names the parameters in the Jacobian's (near) null space.
fn rank_message(layout: &Layout, j: &DMatrix<f64>, rcond: f64) -> Option<String> {
    let (norms, sv, v) = scaled_svd(j);
    let zero_col: Vec<usize> = j
        .column_iter()
        .enumerate()
        .filter(|(_, c)| c.norm() == 0.0)
        .map(|(k, _)| k)
        .collect();
    let _ = norms;
    let max = sv.max();
    let mut groups: Vec<String> = Vec::new();
    let mut add = |g: String| {
        if !groups.contains(&g) {
            groups.push(g);
        }
    };
    for k in &zero_col {
        add(layout.param_group(*k));
    }
    let mut weak: Vec<(f64, usize)> = sv
        .iter()
        .enumerate()
        .filter(|(_, s)| **s < rcond * max)
        .map(|(i, s)| (*s, i))
        .collect();
    if weak.is_empty() && zero_col.is_empty() {
        return None;
    }
    weak.sort_by(|a, b| a.0.total_cmp(&b.0));
    for (_, i) in &weak {
        let col = v.column(*i);
        let mut ranked: Vec<(f64, usize)> = col
            .iter()
            .enumerate()
            .filter(|(_, x)| x.abs() > 0.2)
            .map(|(k, x)| (x.abs(), k))
            .collect();
        ranked.sort_by(|a, b| b.0.total_cmp(&a.0));
        for (_, k) in ranked {
            add(layout.param_group(k));
        }
    }
    let spindle = groups
        .iter()
        .any(|g| matches!(g.as_str(), "ex_z" | "ey_z" | "ez_z" | "ez_y"));
    let hint = if spindle {
        "rotations of the spindle carriage (ε of Z, and ε_z of Y) are seen only through the tool offset: measure with at least three tool offsets not on one line (tracker.parquet column `tool`, machine [tool] offsets_mm), or hold those functions at zero with [mill.kinematics] fixed = [...]"
    } else {
        "spread the points through the workspace, lower the degree, or hold the functions at zero with [mill.kinematics] fixed = [...]"
    };
    Some(format!(
        "the tracker points cannot identify the model (rank-deficient Jacobian: {} of {} directions below rcond {rcond:e}, σ_min/σ_max = {:.1e}); these cannot be separated: {}; {hint}",
        weak.len().max(zero_col.len()),
        sv.len(),
        rcond_of(&sv),
        groups.join(", "),
    ))
}

/// Identify the model from tracker points.
pub fn identify(
    layout: Layout,
    obs: &[Obs],
    opt: &IdentOptions,
) -> Result<Identified, Unidentifiable> {
    precheck(&layout, obs)?;
    let mut model = Model::zeros(layout);
    let (w, t) = kabsch(obs);
    model.set_frame(&w, &t);
    let j0 = jacobian(&model, obs);
    if let Some(msg) = rank_message(&model.layout, &j0, opt.rcond) {
        return Err(Unidentifiable(msg));
    }
    let lm = LevenbergMarquardt::new()
        .with_ftol(1e-12)
        .with_xtol(1e-12)
        .with_gtol(1e-12)
        .with_patience(
            opt.max_evaluations
                .div_ceil(model.layout.n_params() + 1)
                .max(2),
        );
    let (problem, report) = lm.minimize(Problem { model, obs });
    let ok = report.termination.was_successful()
        || matches!(
            report.termination,
            TerminationReason::NoImprovementPossible(_)
        );
    if !ok {
        return Err(Unidentifiable(format!(
            "Levenberg–Marquardt did not converge ({:?} after {} evaluations); check the data or raise [mill.kinematics] max_evaluations",
            report.termination, report.number_of_evaluations
        )));
    }
    let model = problem.model;
    let j = jacobian(&model, obs);
    let r = residuals(&model, obs);
    let p = model.layout.n_params();
    let dof = 3 * obs.len() - p;
    let s2 = r.norm_squared() / dof as f64;
    let (norms, sv, v) = scaled_svd(&j);
    let rcond = rcond_of(&sv);
    if rcond < opt.rcond {
        if let Some(msg) = rank_message(&model.layout, &j, opt.rcond) {
            return Err(Unidentifiable(msg));
        }
    }
    // (JᵀJ)⁻¹ = D⁻¹ V Σ⁻² Vᵀ D⁻¹ with J·D⁻¹ = U Σ Vᵀ.
    let mut vs = v.clone();
    for (k, mut c) in vs.column_iter_mut().enumerate() {
        c /= sv[k];
    }
    let mut cov = &vs * vs.transpose() * s2;
    for a in 0..p {
        for b in 0..p {
            cov[(a, b)] /= norms[a] * norms[b];
        }
    }
    Ok(Identified {
        model,
        cov,
        sigma_mm: s2.sqrt(),
        dof,
        evaluations: report.number_of_evaluations,
        termination: format!("{:?}", report.termination),
        rcond,
    })
}

/// Standard deviation of an error function's value at `q` from the
/// covariance (σ² = bᵀ C b over its coefficients' basis values).
pub fn function_sigma(id: &Identified, f: usize, q: f64) -> f64 {
    let layout = &id.model.layout;
    let mut leg = Vec::new();
    super::chain::legendre(layout.xi(function_axis(f), q), layout.degree, &mut leg);
    let idx: Vec<(usize, f64)> = layout
        .coef
        .iter()
        .enumerate()
        .filter(|(_, (g, _))| *g == f)
        .map(|(i, (_, m))| (i, leg[*m]))
        .collect();
    let mut v = 0.0;
    for &(a, ba) in &idx {
        for &(b, bb) in &idx {
            v += ba * bb * id.cov[(a, b)];
        }
    }
    v.max(0.0).sqrt()
}

/// Whether a function is a rotation (for units in tables).
pub fn unit_of(f: usize) -> &'static str {
    if is_rotation(f) {
        "rad"
    } else {
        "mm"
    }
}

#[cfg(test)]
mod tests {
    use super::super::chain::function_index;
    use super::*;
    use rand::Rng;
    use rand_distr::StandardNormal;

    const TRAVELS: [(f64, f64); 3] = [(0.0, 600.0), (0.0, 400.0), (0.0, 300.0)];

    fn tools() -> Vec<V3> {
        vec![
            V3::new(0.0, 0.0, -120.0),
            V3::new(100.0, 0.0, -120.0),
            V3::new(0.0, 100.0, -120.0),
        ]
    }

    /// A machine with errors of realistic size in the identification gauge.
    fn truth(layout: Layout, rng: &mut ChaCha8Rng) -> Model {
        let mut m = Model::zeros(layout);
        for i in 0..m.layout.coef.len() {
            let f = m.layout.coef[i].0;
            let scale = if is_rotation(f) { 2e-5 } else { 0.008 };
            m.params[i] = scale * rng.sample::<f64, _>(StandardNormal);
        }
        let si = m.layout.sq_index();
        for k in 0..3 {
            m.params[si + k] = 3e-5 * rng.sample::<f64, _>(StandardNormal);
        }
        m.set_frame(&V3::new(0.4, -0.7, 2.1), &V3::new(1800.0, -650.0, 320.0));
        m
    }

    fn measure(
        m: &Model,
        n: usize,
        tools: &[V3],
        sigma: f64,
        rng: &mut ChaCha8Rng,
        plane_z: Option<f64>,
    ) -> Vec<Obs> {
        (0..n)
            .map(|i| {
                let q = [
                    rng.random::<f64>() * 600.0,
                    rng.random::<f64>() * 400.0,
                    plane_z.unwrap_or_else(|| rng.random::<f64>() * 300.0),
                ];
                let pt = Point {
                    q,
                    tool: tools[i % tools.len()],
                };
                let noise = V3::new(
                    rng.sample(StandardNormal),
                    rng.sample(StandardNormal),
                    rng.sample(StandardNormal),
                ) * sigma;
                Obs {
                    pt,
                    m: m.tracker_point(&pt) + noise,
                }
            })
            .collect()
    }

    #[test]
    fn recovers_the_errors_within_their_uncertainty() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let layout = Layout::new(3, TRAVELS, &[]);
        let t = truth(layout.clone(), &mut rng);
        let obs = measure(&t, 600, &tools(), 0.002, &mut rng, None);
        let id = identify(layout, &obs, &IdentOptions::default()).unwrap();
        assert!(
            (id.sigma_mm / 0.002 - 1.0).abs() < 0.15,
            "s = {}",
            id.sigma_mm
        );
        let mut worst: f64 = 0.0;
        for i in 0..t.params.len() {
            let mut d = id.model.params[i] - t.params[i];
            // The rotation vector is defined modulo 2π along its axis; the
            // true one is small enough that the identified one matches.
            if !d.is_finite() {
                d = f64::INFINITY;
            }
            let z = d.abs() / id.std(i);
            worst = worst.max(z);
            assert!(
                z <= 4.0,
                "{}: est {} true {} σ {}",
                id.model.layout.param_name(i),
                id.model.params[i],
                t.params[i],
                id.std(i)
            );
        }
        assert!(worst > 0.5, "suspiciously exact: worst z {worst}");
    }

    #[test]
    fn one_tool_offset_cannot_see_spindle_rotations() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let layout = Layout::new(3, TRAVELS, &[]);
        let t = truth(layout.clone(), &mut rng);
        let obs = measure(&t, 400, &tools()[..1], 0.002, &mut rng, None);
        let e = identify(layout, &obs, &IdentOptions::default()).unwrap_err();
        assert!(e.0.contains("ez_z") && e.0.contains("tool offset"), "{e}");
        // Holding those functions at zero makes it identifiable again.
        let fixed: Vec<usize> = ["ex_z", "ey_z", "ez_z", "ez_y"]
            .iter()
            .map(|n| function_index(n).unwrap())
            .collect();
        let layout = Layout::new(3, TRAVELS, &fixed);
        let mut t2 = Model::zeros(layout.clone());
        // Same machine without the fixed functions.
        for (i, c) in layout.coef.iter().enumerate() {
            let j = t.layout.coef.iter().position(|d| d == c).unwrap();
            t2.params[i] = t.params[j];
        }
        let (si, sj) = (layout.sq_index(), t.layout.sq_index());
        for k in 0..9 {
            t2.params[si + k] = t.params[sj + k];
        }
        let obs = measure(&t2, 400, &tools()[..1], 0.002, &mut rng, None);
        assert!(identify(layout, &obs, &IdentOptions::default()).is_ok());
    }

    #[test]
    fn too_few_points_and_planar_points_are_errors() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let layout = Layout::new(3, TRAVELS, &[]);
        let t = truth(layout.clone(), &mut rng);
        let obs = measure(&t, 15, &tools(), 0.002, &mut rng, None);
        let e = identify(layout.clone(), &obs, &IdentOptions::default()).unwrap_err();
        assert!(e.0.starts_with("too few points"), "{e}");
        let obs = measure(&t, 300, &tools(), 0.002, &mut rng, Some(150.0));
        let e = identify(layout, &obs, &IdentOptions::default()).unwrap_err();
        assert!(e.0.contains("one plane"), "{e}");
    }

    #[test]
    fn split_is_seeded_and_disjoint() {
        let (a, b) = split(100, 0.2, 3);
        assert_eq!((a.len(), b.len()), (80, 20));
        assert_eq!(split(100, 0.2, 3), (a.clone(), b.clone()));
        assert_ne!(split(100, 0.2, 4).1, b);
        assert!(b.iter().all(|i| !a.contains(i)));
    }
}

//! The XFYZ kinematic chain with 21 error functions and the tracker frame
//! (docs/models.md §5).
//!
//! Frames and conventions:
//! - `x_mm, y_mm, z_mm` are the commanded axis positions. X moves the table
//!   (which carries the workpiece and, in the volumetric verification, the
//!   laser tracker); Y and Z move the tool. The nominal tool point relative
//!   to the table is `(x, y, z) + t`, `t` the tool (reflector) offset in the
//!   spindle frame.
//! - Each axis k has six error functions of its own position q_k: three
//!   translations δ_x,k, δ_y,k, δ_z,k (mm) and three small rotations ε_x,k,
//!   ε_y,k, ε_z,k (rad), with R_k = I + [ε_k]× exactly as docs/models.md §5
//!   writes it. Squareness: the Y axis moves along (s_xy, 1, 0) and the Z
//!   axis along (s_xz, s_yz, 1) in the frame defined by X (ISO 230-1 style:
//!   X is the reference direction).
//! - Chain (homogeneous transforms, nominal motion ∘ error transform):
//!   tool in the foundation frame  f = y·u_Y + δ_Y + R_Y (z·u_Z + δ_Z + R_Z t);
//!   table in the foundation frame maps q ↦ −x·e_x + δ_X + R_X q, so the tool
//!   point relative to the table is p = R_X⁻¹ (f + x·e_x − δ_X).
//! - The tracker measures m = Q(ω)·p + T: Q the Rodrigues rotation of the
//!   rotation vector ω (unit axis × angle θ), T a translation — both
//!   identified with the machine errors.
//!
//! Error functions are Legendre series in the axis position mapped onto
//! [−1, 1] over the axis travel (better conditioned than monomials).
//!
//! Gauge (what the data cannot tell apart, fixed explicitly — not left to
//! the solver): see [`min_order`].

use nalgebra::{DVector, Matrix3, Rotation3, Vector3};

pub type V3 = Vector3<f64>;

/// Axis letters in chain order.
pub const AXES: [&str; 3] = ["x", "y", "z"];
/// The six error functions of an axis: translations then rotations.
pub const KINDS: [&str; 6] = ["dx", "dy", "dz", "ex", "ey", "ez"];
/// 18 axis error functions + 3 squareness terms.
pub const N_FUNCTIONS: usize = 18;
pub const SQUARENESS: [&str; 3] = ["sq_xy", "sq_xz", "sq_yz"];
pub const FRAME: [&str; 6] = [
    "tracker_wx_rad",
    "tracker_wy_rad",
    "tracker_wz_rad",
    "tracker_tx_mm",
    "tracker_ty_mm",
    "tracker_tz_mm",
];

/// Error function index: axis·6 + kind.
pub fn function_name(f: usize) -> String {
    format!("{}_{}", KINDS[f % 6], AXES[f / 6])
}

pub fn function_index(name: &str) -> Option<usize> {
    (0..N_FUNCTIONS).find(|&f| function_name(f) == name)
}

/// Axis (0, 1, 2) whose position an error function depends on.
pub fn function_axis(f: usize) -> usize {
    f / 6
}

pub fn is_rotation(f: usize) -> bool {
    f % 6 >= 3
}

/// Lowest Legendre order identified for function `f`; lower orders are
/// fixed at zero because they are gauge freedoms (indistinguishable from the
/// tracker frame or from the squareness terms whatever the data):
/// - P0 (the mean over the travel) of the nine translations: a constant
///   offset of the tool point, absorbed by the tracker translation T.
/// - P0 of the three rotations of X: a constant rotation of the table, which
///   carries the tracker, i.e. a rotation of the tracker frame Q.
/// - P0 of the three rotations of Y: tilts of the Y carriage rotate the Z
///   axis (→ squareness s_xz, s_yz) and the tool offset (→ the constant
///   rotation of Z, which stays identified).
/// - P1 (the least-squares slope) of the six straightness functions: a tilt
///   of an axis direction, i.e. squareness or tracker rotation (ISO 230-1
///   defines straightness about its reference straight line for this
///   reason).
///
/// So positioning (δ_x,X, δ_y,Y, δ_z,Z) and the rotations of X and Y start
/// at P1, straightness at P2, and the rotations of Z (the spindle carriage,
/// seen through the tool offsets) at P0.
pub fn min_order(f: usize) -> usize {
    let axis = function_axis(f);
    let kind = f % 6;
    if kind < 3 {
        if kind == axis {
            1
        } else {
            2
        }
    } else if axis == 2 {
        0
    } else {
        1
    }
}

/// Legendre polynomials P_0..P_degree at ξ.
pub fn legendre(xi: f64, degree: usize, out: &mut Vec<f64>) {
    out.clear();
    out.push(1.0);
    if degree >= 1 {
        out.push(xi);
    }
    for m in 1..degree {
        let mf = m as f64;
        let next = ((2.0 * mf + 1.0) * xi * out[m] - mf * out[m - 1]) / (mf + 1.0);
        out.push(next);
    }
}

/// Which parameters are free, and where they sit in the parameter vector:
/// `[coefficients…, s_xy, s_xz, s_yz, ω_x, ω_y, ω_z, T_x, T_y, T_z]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    pub degree: usize,
    /// Axis travels (min, max), mm.
    pub travels: [(f64, f64); 3],
    /// Free coefficients: (function, Legendre order).
    pub coef: Vec<(usize, usize)>,
}

impl Layout {
    /// Every function to `degree`, minus the gauge-fixed orders and the
    /// functions in `fixed` (held at zero).
    pub fn new(degree: usize, travels: [(f64, f64); 3], fixed: &[usize]) -> Layout {
        let mut coef = Vec::new();
        for f in 0..N_FUNCTIONS {
            if fixed.contains(&f) {
                continue;
            }
            for m in min_order(f)..=degree {
                coef.push((f, m));
            }
        }
        Layout {
            degree,
            travels,
            coef,
        }
    }
    pub fn n_params(&self) -> usize {
        self.coef.len() + 9
    }
    pub fn sq_index(&self) -> usize {
        self.coef.len()
    }
    pub fn frame_index(&self) -> usize {
        self.coef.len() + 3
    }
    /// Name of parameter `i`: `dx_x.P2`, `sq_xy`, `tracker_wx_rad`.
    pub fn param_name(&self, i: usize) -> String {
        if i < self.coef.len() {
            let (f, m) = self.coef[i];
            format!("{}.P{m}", function_name(f))
        } else if i < self.frame_index() {
            SQUARENESS[i - self.sq_index()].to_string()
        } else {
            FRAME[i - self.frame_index()].to_string()
        }
    }
    /// The group a parameter belongs to (its error function, `squareness` or
    /// `tracker`), for messages.
    pub fn param_group(&self, i: usize) -> String {
        if i < self.coef.len() {
            function_name(self.coef[i].0)
        } else if i < self.frame_index() {
            SQUARENESS[i - self.sq_index()].to_string()
        } else {
            "tracker frame".to_string()
        }
    }
    /// Axis position mapped to [−1, 1] over the travel.
    pub fn xi(&self, axis: usize, q: f64) -> f64 {
        let (lo, hi) = self.travels[axis];
        2.0 * (q - lo) / (hi - lo) - 1.0
    }
}

/// Values of the 18 error functions at one set of axis positions.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ErrorValues {
    /// [axis][x, y, z] translation, mm.
    pub delta: [[f64; 3]; 3],
    /// [axis][x, y, z] rotation, rad.
    pub eps: [[f64; 3]; 3],
}

impl ErrorValues {
    pub fn get(&self, f: usize) -> f64 {
        let (a, k) = (f / 6, f % 6);
        if k < 3 {
            self.delta[a][k]
        } else {
            self.eps[a][k - 3]
        }
    }
    pub fn set(&mut self, f: usize, v: f64) {
        let (a, k) = (f / 6, f % 6);
        if k < 3 {
            self.delta[a][k] = v;
        } else {
            self.eps[a][k - 3] = v;
        }
    }
}

/// One commanded point: axis positions and the tool offset it was measured
/// with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point {
    pub q: [f64; 3],
    pub tool: V3,
}

impl Point {
    /// The nominal tool point relative to the table.
    pub fn nominal(&self) -> V3 {
        V3::new(self.q[0], self.q[1], self.q[2]) + self.tool
    }
}

fn skew(v: &V3) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// docs/models.md §5: R_k = [[1, −ε_z, ε_y], [ε_z, 1, −ε_x], [−ε_y, ε_x, 1]].
fn small_rotation(e: &[f64; 3]) -> Matrix3<f64> {
    Matrix3::identity() + skew(&V3::new(e[0], e[1], e[2]))
}

/// The chain at one point: the tool point relative to the table and,
/// optionally, its sensitivity to each of the 18 error values and the 3
/// squareness terms (∂p/∂e, analytic).
pub fn chain_point(
    errs: &ErrorValues,
    sq: [f64; 3],
    pt: &Point,
    sens: Option<&mut [V3; 21]>,
) -> V3 {
    let [x, y, z] = pt.q;
    let dx = V3::from(errs.delta[0]);
    let dy = V3::from(errs.delta[1]);
    let dz = V3::from(errs.delta[2]);
    let rx = small_rotation(&errs.eps[0]);
    let ry = small_rotation(&errs.eps[1]);
    let rz = small_rotation(&errs.eps[2]);
    let u_y = V3::new(sq[0], 1.0, 0.0);
    let u_z = V3::new(sq[1], sq[2], 1.0);
    let w = z * u_z + dz + rz * pt.tool;
    let v = y * u_y + dy + ry * w + x * V3::x() - dx;
    // R_X = I + [ε]× is invertible for any small ε (det = 1 + |ε|²).
    let a = rx.try_inverse().unwrap_or_else(Matrix3::identity);
    let p = a * v;
    if let Some(s) = sens {
        let ary = a * ry;
        let units = [V3::x(), V3::y(), V3::z()];
        for k in 0..3 {
            // Translations.
            s[k] = -(a * units[k]);
            s[6 + k] = a * units[k];
            s[12 + k] = ary * units[k];
            // Rotations: dR/dε_k = [e_k]×.
            let ek = skew(&units[k]);
            s[3 + k] = -(a * (ek * p));
            s[9 + k] = a * (ek * w);
            s[15 + k] = ary * (ek * pt.tool);
        }
        s[18] = a * V3::new(y, 0.0, 0.0);
        s[19] = ary * V3::new(z, 0.0, 0.0);
        s[20] = ary * V3::new(0.0, z, 0.0);
    }
    p
}

/// Rodrigues rotation of a rotation vector (axis × angle).
pub fn rotation(w: &V3) -> Matrix3<f64> {
    Rotation3::new(*w).into_inner()
}

/// Right Jacobian of SO(3): R(ω + δ) ≈ R(ω)·Exp(J_r(ω)·δ), so
/// ∂(R(ω)p)/∂ω = −R(ω)[p]× J_r(ω).
pub fn right_jacobian(w: &V3) -> Matrix3<f64> {
    let th = w.norm();
    let k = skew(w);
    let (a, b) = if th < 1e-6 {
        (0.5 - th * th / 24.0, 1.0 / 6.0 - th * th / 120.0)
    } else {
        (
            (1.0 - th.cos()) / (th * th),
            (th - th.sin()) / (th * th * th),
        )
    };
    Matrix3::identity() - a * k + b * k * k
}

/// A machine model: layout + parameter values.
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    pub layout: Layout,
    pub params: DVector<f64>,
}

impl Model {
    pub fn zeros(layout: Layout) -> Model {
        let n = layout.n_params();
        Model {
            layout,
            params: DVector::zeros(n),
        }
    }
    pub fn squareness(&self) -> [f64; 3] {
        let i = self.layout.sq_index();
        [self.params[i], self.params[i + 1], self.params[i + 2]]
    }
    pub fn omega(&self) -> V3 {
        let i = self.layout.frame_index();
        V3::new(self.params[i], self.params[i + 1], self.params[i + 2])
    }
    pub fn translation(&self) -> V3 {
        let i = self.layout.frame_index() + 3;
        V3::new(self.params[i], self.params[i + 1], self.params[i + 2])
    }
    pub fn set_frame(&mut self, w: &V3, t: &V3) {
        let i = self.layout.frame_index();
        for k in 0..3 {
            self.params[i + k] = w[k];
            self.params[i + 3 + k] = t[k];
        }
    }
    /// Value of error function `f` at axis position `q`.
    pub fn function_value(&self, f: usize, q: f64) -> f64 {
        let mut leg = Vec::with_capacity(self.layout.degree + 1);
        legendre(
            self.layout.xi(function_axis(f), q),
            self.layout.degree,
            &mut leg,
        );
        self.layout
            .coef
            .iter()
            .zip(self.params.iter())
            .filter(|((g, _), _)| *g == f)
            .map(|((_, m), c)| c * leg[*m])
            .sum()
    }
    /// All 18 error values at a point (Legendre values per axis in `leg`).
    fn errors_with(&self, leg: &[Vec<f64>; 3]) -> ErrorValues {
        let mut e = ErrorValues::default();
        for (&(f, m), c) in self.layout.coef.iter().zip(self.params.iter()) {
            let v = e.get(f) + c * leg[function_axis(f)][m];
            e.set(f, v);
        }
        e
    }
    pub fn errors(&self, q: [f64; 3]) -> ErrorValues {
        let leg = self.legendre_at(q);
        self.errors_with(&leg)
    }
    fn legendre_at(&self, q: [f64; 3]) -> [Vec<f64>; 3] {
        let mut leg: [Vec<f64>; 3] = Default::default();
        for (a, l) in leg.iter_mut().enumerate() {
            legendre(self.layout.xi(a, q[a]), self.layout.degree, l);
        }
        leg
    }
    /// The tool point relative to the table (machine frame).
    pub fn machine_point(&self, pt: &Point) -> V3 {
        chain_point(&self.errors(pt.q), self.squareness(), pt, None)
    }
    /// Volumetric error: actual minus nominal tool point, machine frame.
    pub fn deviation(&self, pt: &Point) -> V3 {
        self.machine_point(pt) - pt.nominal()
    }
    /// The point as the tracker sees it.
    pub fn tracker_point(&self, pt: &Point) -> V3 {
        rotation(&self.omega()) * self.machine_point(pt) + self.translation()
    }
    /// A tracker measurement brought back into the machine frame.
    pub fn to_machine(&self, m: &V3) -> V3 {
        rotation(&self.omega()).transpose() * (m - self.translation())
    }
    /// The tracker point and its 3 Jacobian rows (∂m/∂params, written
    /// into `rows[0..3][0..n_params]`).
    pub fn tracker_point_jac(&self, pt: &Point, rows: [&mut [f64]; 3]) -> V3 {
        let leg = self.legendre_at(pt.q);
        let errs = self.errors_with(&leg);
        let mut sens = [V3::zeros(); 21];
        let p = chain_point(&errs, self.squareness(), pt, Some(&mut sens));
        let w = self.omega();
        let q = rotation(&w);
        let qs: Vec<V3> = sens.iter().map(|s| q * s).collect();
        let [r0, r1, r2] = rows;
        for (j, &(f, m)) in self.layout.coef.iter().enumerate() {
            let d = qs[f] * leg[function_axis(f)][m];
            r0[j] = d.x;
            r1[j] = d.y;
            r2[j] = d.z;
        }
        let si = self.layout.sq_index();
        for k in 0..3 {
            let d = qs[18 + k];
            r0[si + k] = d.x;
            r1[si + k] = d.y;
            r2[si + k] = d.z;
        }
        let fi = self.layout.frame_index();
        let dw = -(q * skew(&p) * right_jacobian(&w));
        for k in 0..3 {
            r0[fi + k] = dw[(0, k)];
            r1[fi + k] = dw[(1, k)];
            r2[fi + k] = dw[(2, k)];
            r0[fi + 3 + k] = if k == 0 { 1.0 } else { 0.0 };
            r1[fi + 3 + k] = if k == 1 { 1.0 } else { 0.0 };
            r2[fi + 3 + k] = if k == 2 { 1.0 } else { 0.0 };
        }
        q * p + self.translation()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> Model {
        let layout = Layout::new(3, [(0.0, 600.0), (0.0, 400.0), (0.0, 300.0)], &[]);
        let mut m = Model::zeros(layout);
        for i in 0..m.params.len() {
            m.params[i] = 1e-4 * ((i * 7919 % 13) as f64 - 6.0);
        }
        m.set_frame(&V3::new(0.3, -1.2, 2.0), &V3::new(1500.0, -700.0, 250.0));
        m
    }

    #[test]
    fn legendre_matches_closed_forms() {
        let mut l = Vec::new();
        legendre(0.3, 4, &mut l);
        let x: f64 = 0.3;
        assert!((l[2] - 0.5 * (3.0 * x * x - 1.0)).abs() < 1e-15);
        assert!((l[3] - 0.5 * (5.0 * x.powi(3) - 3.0 * x)).abs() < 1e-15);
        assert!((l[4] - (35.0 * x.powi(4) - 30.0 * x * x + 3.0) / 8.0).abs() < 1e-15);
    }

    #[test]
    fn layout_counts_gauge_fixed_orders() {
        let l = Layout::new(3, [(0.0, 1.0); 3], &[]);
        // positioning 3×3, straightness 6×2, rotations of X, Y 6×3, of Z 3×4.
        assert_eq!(l.coef.len(), 9 + 12 + 18 + 12);
        assert_eq!(l.n_params(), 51 + 9);
        let fixed = Layout::new(3, [(0.0, 1.0); 3], &[function_index("ez_z").unwrap()]);
        assert_eq!(fixed.coef.len(), 51 - 4);
        assert_eq!(l.param_name(0), "dx_x.P1");
    }

    #[test]
    fn nominal_machine_is_the_nominal_point() {
        let layout = Layout::new(2, [(0.0, 600.0), (0.0, 400.0), (0.0, 300.0)], &[]);
        let m = Model::zeros(layout);
        let pt = Point {
            q: [100.0, 50.0, 20.0],
            tool: V3::new(5.0, 0.0, -100.0),
        };
        assert!((m.machine_point(&pt) - pt.nominal()).norm() < 1e-12);
    }

    #[test]
    fn analytic_jacobian_matches_central_differences() {
        let m = model();
        let pt = Point {
            q: [420.0, 130.0, 260.0],
            tool: V3::new(80.0, -20.0, -120.0),
        };
        let n = m.layout.n_params();
        let mut rows = vec![vec![0.0; n]; 3];
        {
            let (a, rest) = rows.split_at_mut(1);
            let (b, c) = rest.split_at_mut(1);
            m.tracker_point_jac(&pt, [&mut a[0], &mut b[0], &mut c[0]]);
        }
        for j in 0..n {
            let h = if j >= m.layout.frame_index() + 3 {
                1e-3
            } else {
                1e-6
            };
            let mut mp = m.clone();
            mp.params[j] += h;
            let mut mm = m.clone();
            mm.params[j] -= h;
            let d = (mp.tracker_point(&pt) - mm.tracker_point(&pt)) / (2.0 * h);
            for (r, row) in rows.iter().enumerate() {
                let scale = d[r].abs().max(row[j].abs()).max(1e-3);
                assert!(
                    (d[r] - row[j]).abs() / scale < 1e-5,
                    "param {} row {r}: numeric {} analytic {}",
                    m.layout.param_name(j),
                    d[r],
                    row[j]
                );
            }
        }
    }

    #[test]
    fn squareness_tilts_the_y_axis() {
        let layout = Layout::new(2, [(0.0, 600.0), (0.0, 400.0), (0.0, 300.0)], &[]);
        let mut m = Model::zeros(layout);
        let i = m.layout.sq_index();
        m.params[i] = 1e-4;
        let pt = Point {
            q: [0.0, 400.0, 0.0],
            tool: V3::zeros(),
        };
        let d = m.deviation(&pt);
        assert!((d.x - 0.04).abs() < 1e-12 && d.y.abs() < 1e-12);
    }
}

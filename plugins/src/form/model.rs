//! The form grinder's model (docs/models.md §4): the wheel-centre equidistant
//! programmed for a nominal wheel radius R_kn, and the profile error δ(φ)
//! left when the wheel actually has radius R_k after dressing. Also the
//! run-side plumbing every stage shares: the machine's usable wheel-radius
//! range, the design and measured rows of profile.parquet, and which radii
//! a run was ground with.

use std::path::Path;

use crate::form::tables::PROFILE;
use arrow::array::{Array, Float64Array};
use sparkout_pipeline::contracts::{MachineConfig, Table};
use sparkout_pipeline::{InputError, Result, Run};

use super::curvature::{CurvatureConfig, Profile};

/// The wheel-centre path programmed for one nominal radius, per profile
/// point. Machine axes (docs/models.md §4, a 4-axis X, Z, A, C form grinder):
/// C turns the work so the wheel centre lies on the X axis, X is the wheel
/// centre's distance from the work axis (R_e), Z the section's position
/// along the work axis, A the angle γ between the centre's radius vector
/// and the contact normal (the head swivel that keeps the wheel normal to
/// the profile).
#[derive(Debug, Clone)]
pub struct CentrePath {
    pub nominal_mm: f64,
    /// R_e(φ) = |P + R_kn·n| (the law-of-cosines form of docs/models.md §4).
    pub x_mm: Vec<f64>,
    /// Polar angle of the wheel centre, unwrapped (continuous).
    pub c_rad: Vec<f64>,
    /// γ(φ): angle between the centre's radius vector and the normal. It
    /// equals atan((dR_e/dφ_e)/R_e) exactly (the offset curve shares the
    /// profile's normals), without a second numerical derivative.
    pub gamma_rad: Vec<f64>,
    /// Which δ formula the errors of this path use.
    pub model: DeltaModel,
}

/// Which δ(φ) formula to use (`delta_model`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DeltaModel {
    /// docs/models.md §4 as published ([`delta_mm`]).
    #[default]
    Published,
    /// The wheel against the profile's osculating circle, without the
    /// published small-angle shortcuts ([`delta_osculating_mm`]); closer
    /// to the exact envelope of the wheel (see the tests).
    Osculating,
}

impl DeltaModel {
    pub const NAMES: &'static [&'static str] = &["published", "osculating"];
    pub fn delta(self, kappa: f64, gamma: f64, r_kn: f64, r_k: f64) -> Option<f64> {
        match self {
            DeltaModel::Published => delta_mm(kappa, gamma, r_kn, r_k),
            DeltaModel::Osculating => delta_osculating_mm(kappa, gamma, r_kn, r_k),
        }
    }
}

impl CentrePath {
    pub fn with_model(mut self, model: DeltaModel) -> CentrePath {
        self.model = model;
        self
    }
    /// δ at point `i` of `p` for actual radius `r_k`.
    pub fn delta(&self, p: &Profile, i: usize, r_k: f64) -> Option<f64> {
        self.model
            .delta(p.kappa_per_mm[i], self.gamma_rad[i], self.nominal_mm, r_k)
    }
}

/// The equidistant for nominal radius `r_kn`.
pub fn centre_path(p: &Profile, r_kn: f64) -> CentrePath {
    let n = p.len();
    let mut x = Vec::with_capacity(n);
    let mut c = Vec::with_capacity(n);
    let mut g = Vec::with_capacity(n);
    let mut prev_c: Option<f64> = None;
    for i in 0..n {
        let pt = p.point(i);
        let nn = p.normal[i];
        let cx = pt[0] + r_kn * nn[0];
        let cy = pt[1] + r_kn * nn[1];
        let re = cx.hypot(cy);
        let mut ang = cy.atan2(cx);
        if let Some(pc) = prev_c {
            // Unwrap: C is a rotary axis, it does not jump by 2π.
            ang += std::f64::consts::TAU * ((pc - ang) / std::f64::consts::TAU).round();
        }
        prev_c = Some(ang);
        let (ux, uy) = (cx / re, cy / re);
        // Signed angle from the radius vector to the normal.
        g.push((ux * nn[1] - uy * nn[0]).atan2(ux * nn[0] + uy * nn[1]));
        x.push(re);
        c.push(ang);
    }
    CentrePath {
        nominal_mm: r_kn,
        x_mm: x,
        c_rad: c,
        gamma_rad: g,
        model: DeltaModel::Published,
    }
}

/// δ at one point (docs/models.md §4), positive = material left along the
/// normal:
///
///   δ = (R_kn − R_k)·[1 − cos γ] − [ρ − R_k]·[1 − cos ε],
///   sin ε = (R_kn − R_k)·sin γ / (ρ + R_k),
///
/// written in κ = 1/ρ so a straight part (κ = 0, ρ = ∞) gives the finite
/// limit δ = (R_kn − R_k)·[1 − cos γ]:
///   sin ε = Δ·sin γ·κ / (1 + R_k·κ),
///   [ρ − R_k]·[1 − cos ε] = (1 − R_k·κ)·(Δ·sin γ)²·κ / ((1 + R_k·κ)²·(1 + cos ε)).
/// `None` where the wheel cannot follow the profile (a concave part whose
/// radius of curvature is smaller than the wheel: 1 + R_k·κ ≤ 0).
pub fn delta_mm(kappa: f64, gamma: f64, r_kn: f64, r_k: f64) -> Option<f64> {
    let d = r_kn - r_k;
    let den = 1.0 + r_k * kappa;
    if !(den > 0.0) {
        return None;
    }
    let sg = gamma.sin();
    let sin_e = d * sg * kappa / den;
    if !(sin_e.abs() <= 1.0) {
        return None;
    }
    let cos_e = (1.0 - sin_e * sin_e).sqrt();
    let second = (1.0 - r_k * kappa) * (d * sg).powi(2) * kappa / (den * den * (1.0 + cos_e));
    Some(d * (1.0 - gamma.cos()) - second)
}

/// δ from the osculating circle (centre O = P − ρ·n, radius ρ): the
/// programmed wheel centre is at ρ + R_kn from O, the controller moves it
/// radially in by Δ = R_kn − R_k (at angle γ to the normal), so the actual
/// centre is L = sqrt((ρ+R_kn)² − 2Δ(ρ+R_kn)·cos γ + Δ²) from O and the
/// wheel stands L − ρ − R_k off the profile. Written in κ to stay finite on
/// a straight part (κ = 0 gives Δ·(1 − cos γ)):
///   δ = [2Δ(1 − cos γ) + κΔ(R_kn + R_k − 2R_kn·cos γ + Δ)] / (κL + 1 + κR_k),
///   κL = sqrt((1 + κR_kn)² − 2Δκ(1 + κR_kn)·cos γ + (Δκ)²).
pub fn delta_osculating_mm(kappa: f64, gamma: f64, r_kn: f64, r_k: f64) -> Option<f64> {
    let d = r_kn - r_k;
    if !(1.0 + r_k * kappa > 0.0) {
        return None;
    }
    let c = gamma.cos();
    let a = 1.0 + kappa * r_kn;
    let kl2 = a * a - 2.0 * d * kappa * a * c + (d * kappa).powi(2);
    if !(kl2 >= 0.0) {
        return None;
    }
    let num = 2.0 * d * (1.0 - c) + kappa * d * (r_kn + r_k - 2.0 * r_kn * c + d);
    let den = kl2.sqrt() + 1.0 + kappa * r_k;
    (den > 0.0).then(|| num / den)
}

/// δ along the whole profile for a centre path and an actual radius; on
/// failure the first point (index) where the wheel cannot follow.
pub fn profile_error(p: &Profile, path: &CentrePath, r_k: f64) -> Result<Vec<f64>, usize> {
    (0..p.len())
        .map(|i| path.delta(p, i, r_k).ok_or(i))
        .collect()
}

/// δ at φ for a wheel the controller knows as radius `r_k` that has worn
/// by `wear_mm` since (unknown to the controller): the model at the two
/// design points around φ, interpolated as [`Profile::value_at`]
/// interpolates a per-point δ, so a per-row wear agrees with δ computed on
/// the grid. The controller places the centre for `r_k` (docs/models.md §4:
/// radially in by R_kn − R_k); the worn wheel's surface then stands
/// `wear_mm` further off the profile along the normal — exactly so in the
/// osculating-circle geometry (δ = L − ρ − R with L fixed by the
/// controller's R_k), and to first order in the published form. None
/// outside the profile or where the wheel cannot follow it.
pub fn delta_at(p: &Profile, path: &CentrePath, phi: f64, r_k: f64, wear_mm: f64) -> Option<f64> {
    let (k, k1, t) = p.segment_at(phi)?;
    let (a, b) = (path.delta(p, k, r_k)?, path.delta(p, k1, r_k)?);
    Some(wear_mm + if k == k1 { a } else { a + t * (b - a) })
}

/// The volume the wheel has removed since its last dressing as a function
/// of arc length s along the profile: (`[process] removed_before_mm3`,
/// stock_mm × wheel width) so that removed = v0 + area·s; None unless
/// run.toml gives removed_before_mm3 and stock_mm and a width is known
/// (`[process] width_mm`, else the machine's `wheel.width_mm`).
pub fn wheel_usage(run: &Run) -> Option<(f64, f64)> {
    let width = process_f64(run, "width_mm").or_else(|| {
        run.machine
            .section::<super::config::MachineWheel>()
            .and_then(|w| w.width_mm)
    });
    match (
        process_f64(run, "removed_before_mm3"),
        process_f64(run, "stock_mm"),
        width,
    ) {
        (Some(v0), Some(stock), Some(w)) => Some((v0, stock * w)),
        _ => None,
    }
}

/// The machine's usable wheel-radius range (`[wheel]` of the machine
/// config): a new wheel has `radius_max_mm`, dressing may take it down by
/// `usable_range_mm` (docs/models.md §4: 175 mm, 50 mm in the source).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelRange {
    pub r_max_mm: f64,
    pub range_mm: f64,
}

impl WheelRange {
    pub fn r_min_mm(&self) -> f64 {
        self.r_max_mm - self.range_mm
    }
    pub fn from_machine(m: &MachineConfig) -> Result<WheelRange> {
        let wheel = m
            .section::<super::config::MachineWheel>()
            .cloned()
            .unwrap_or_default();
        let get = |k: &str, v: Option<f64>| {
            v.ok_or_else(|| {
                InputError::new(
                    &m.source,
                    format!(
                        "machine `{}` needs {k} (a number, mm) for the form plugin",
                        m.id
                    ),
                )
                .column(k.to_string())
            })
        };
        let w = WheelRange {
            r_max_mm: get("wheel.radius_max_mm", wheel.radius_max_mm)?,
            range_mm: get("wheel.usable_range_mm", wheel.usable_range_mm)?,
        };
        w.check()
            .map_err(|m2| InputError::new(&m.source, m2).column("wheel"))?;
        Ok(w)
    }
    pub fn check(&self) -> std::result::Result<(), String> {
        if !(self.r_max_mm > 0.0 && self.r_max_mm.is_finite()) {
            return Err(format!(
                "the largest wheel radius must be > 0 mm, found {}",
                self.r_max_mm
            ));
        }
        if !(self.range_mm > 0.0 && self.range_mm < self.r_max_mm) {
            return Err(format!(
                "the usable radius range must be > 0 and below the largest radius ({} mm), found {}",
                self.r_max_mm, self.range_mm
            ));
        }
        Ok(())
    }
    /// Whether a radius lies in the usable range (with 1 µm slack).
    pub fn contains(&self, r: f64) -> bool {
        r >= self.r_min_mm() - 1e-3 && r <= self.r_max_mm + 1e-3
    }
}

/// The rows of profile.parquet split by state, with their file row indices.
pub struct ProfileRows {
    pub design_rows: Vec<usize>,
    pub measured_rows: Vec<usize>,
    pub phi: Vec<f64>,
    pub r: Vec<f64>,
    /// wheel_radius_mm per file row (None when absent or null).
    pub wheel: Vec<Option<f64>>,
    /// An extra `t_s` column per file row, if the file has one.
    pub t_s: Option<Vec<Option<f64>>>,
}

fn opt_f64_col(t: &Table, name: &str) -> Option<Vec<Option<f64>>> {
    let c = t.batch().column_by_name(name)?;
    let a = c.as_any().downcast_ref::<Float64Array>()?;
    Some(
        (0..a.len())
            .map(|i| (!a.is_null(i)).then(|| a.value(i)))
            .collect(),
    )
}

impl ProfileRows {
    pub fn from_table(t: &Table) -> Result<ProfileRows, InputError> {
        let state = t.str("state")?;
        let mut design_rows = Vec::new();
        let mut measured_rows = Vec::new();
        for (i, s) in state.iter().enumerate() {
            match *s {
                "design" => design_rows.push(i),
                "measured" => measured_rows.push(i),
                other => {
                    return Err(InputError::new(
                        t.path(),
                        format!(
                            "unknown state `{other}` (docs/formats.md: `design` or `measured`)"
                        ),
                    )
                    .column("state")
                    .row(i))
                }
            }
        }
        if design_rows.is_empty() {
            return Err(InputError::new(
                t.path(),
                "no `design` rows: the form plugin needs the design profile R(φ)",
            )
            .column("state"));
        }
        let wheel = opt_f64_col(t, "wheel_radius_mm").unwrap_or_else(|| vec![None; t.len()]);
        for (i, w) in wheel.iter().enumerate() {
            if let Some(w) = w {
                if !(w.is_finite() && *w > 0.0) {
                    return Err(InputError::new(
                        t.path(),
                        format!("wheel radius must be a finite number > 0, found {w}"),
                    )
                    .column("wheel_radius_mm")
                    .row(i));
                }
            }
        }
        Ok(ProfileRows {
            design_rows,
            measured_rows,
            phi: t.f64("phi_rad")?.to_vec(),
            r: t.f64("r_mm")?.to_vec(),
            wheel,
            t_s: opt_f64_col(t, "t_s"),
        })
    }

    /// The design profile, differentiated; errors name the file row.
    pub fn design(&self, path: &Path, cfg: &CurvatureConfig) -> Result<Profile, InputError> {
        let phi: Vec<f64> = self.design_rows.iter().map(|&i| self.phi[i]).collect();
        let r: Vec<f64> = self.design_rows.iter().map(|&i| self.r[i]).collect();
        Profile::new(&phi, &r, cfg).map_err(|e| {
            let mut err = InputError::new(path, format!("design profile: {e}")).column(e.column());
            if let Some(k) = e.row() {
                err = err.row(self.design_rows[k]);
            }
            err
        })
    }
}

/// The run's profile table, split.
pub fn profile_rows(run: &Run) -> Result<(std::sync::Arc<Table>, ProfileRows)> {
    let t = run.require(&PROFILE)?;
    let rows = ProfileRows::from_table(&t)?;
    Ok((t, rows))
}

/// What every δ(φ) stage starts from: the machine's usable wheel range,
/// the run's profile table and rows, the design profile (with the stage
/// section's curvature window) and the programmed nominal radius r_kn (the
/// section's `nominal_mm`, else [`nominal_radius`]'s fallbacks).
pub fn profile_setup(
    ctx: &sparkout_pipeline::StageContext,
    window_points: usize,
    nominal_mm: Option<f64>,
) -> Result<(WheelRange, std::sync::Arc<Table>, ProfileRows, Profile, f64)> {
    let range = WheelRange::from_machine(&ctx.run.machine)?;
    let (table, rows) = profile_rows(ctx.run)?;
    let design = rows.design(table.path(), &super::config::curvature(window_points))?;
    let r_kn = nominal_radius(ctx.run, nominal_mm, &range)?;
    Ok((range, table, rows, design, r_kn))
}

/// A number from run.toml `[process]` (integers accepted).
pub fn process_f64(run: &Run, key: &str) -> Option<f64> {
    match run.spec.process.get(key)? {
        toml::Value::Float(f) => Some(*f),
        toml::Value::Integer(i) => Some(*i as f64),
        _ => None,
    }
}

/// Path speed along the profile: run.toml `[process] feed_mm_s`, else the
/// machine's `[process] feed_mm_s`, else 10 mm/s; must be > 0.
pub fn feed_mm_s(run: &Run) -> Result<f64> {
    let feed = process_f64(run, "feed_mm_s")
        .or_else(|| {
            run.machine
                .section::<super::config::MachineProcess>()
                .and_then(|p| p.feed_mm_s)
        })
        .unwrap_or(10.0);
    if !(feed > 0.0 && feed.is_finite()) {
        return Err(InputError::new(
            run.spec.run_toml_path(),
            format!("feed_mm_s must be a finite number > 0, found {feed}"),
        )
        .column("process.feed_mm_s")
        .into());
    }
    Ok(feed)
}

/// The nominal radius the run's program was made for: stage config
/// `nominal_mm`, else run.toml `[process] nominal_wheel_radius_mm`, else the
/// machine's largest radius (a program for the new wheel).
pub fn nominal_radius(run: &Run, nominal_mm: Option<f64>, range: &WheelRange) -> Result<f64> {
    let outside = |r: f64| {
        format!(
            "nominal wheel radius {r} mm is outside the machine's usable range [{}, {}] mm",
            range.r_min_mm(),
            range.r_max_mm
        )
    };
    if let Some(r) = nominal_mm {
        if !range.contains(r) {
            crate::bail!("stage config nominal_mm: {}", outside(r));
        }
        return Ok(r);
    }
    let r = match run.spec.process.get("nominal_wheel_radius_mm") {
        None => return Ok(range.r_max_mm),
        Some(_) => process_f64(run, "nominal_wheel_radius_mm"),
    };
    match r {
        Some(r) if range.contains(r) => Ok(r),
        Some(r) => Err(InputError::new(run.spec.run_toml_path(), outside(r))
            .column("process.nominal_wheel_radius_mm")
            .into()),
        None => Err(InputError::new(
            run.spec.run_toml_path(),
            "[process] nominal_wheel_radius_mm must be a number (mm)",
        )
        .column("process.nominal_wheel_radius_mm")
        .into()),
    }
}

/// Check a measured wheel radius against the usable range, naming the row.
pub fn check_wheel_radius(
    path: &Path,
    row: usize,
    r: f64,
    range: &WheelRange,
) -> Result<(), InputError> {
    if range.contains(r) {
        Ok(())
    } else {
        Err(InputError::new(
            path,
            format!(
                "wheel radius {r} mm is outside the machine's usable range [{}, {}] mm (wheel.radius_max_mm − wheel.usable_range_mm … wheel.radius_max_mm); a wheel dressed below it must be replaced",
                range.r_min_mm(),
                range.r_max_mm
            ),
        )
        .column("wheel_radius_mm")
        .row(row))
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::f64::consts::TAU;

    /// An ellipse profile with semi-axes a, b (mm), n points (the form
    /// plugin's tests share it).
    pub(crate) fn ellipse(n: usize, a: f64, b: f64) -> Profile {
        let phi: Vec<f64> = (0..n).map(|i| TAU * i as f64 / n as f64).collect();
        let r: Vec<f64> = phi
            .iter()
            .map(|f| a * b / ((b * f.cos()).powi(2) + (a * f.sin()).powi(2)).sqrt())
            .collect();
        Profile::new(&phi, &r, &CurvatureConfig::default()).unwrap()
    }

    #[test]
    fn no_error_at_the_nominal_radius_and_on_a_circle() {
        let p = ellipse(720, 60.0, 40.0);
        let path = centre_path(&p, 150.0);
        assert!(profile_error(&p, &path, 150.0)
            .unwrap()
            .iter()
            .all(|d| d.abs() < 1e-12));
        let phi: Vec<f64> = (0..360).map(|i| TAU * i as f64 / 360.0).collect();
        let c = Profile::new(&phi, &vec![40.0; 360], &CurvatureConfig::default()).unwrap();
        let cp = centre_path(&c, 150.0);
        assert!(profile_error(&c, &cp, 140.0)
            .unwrap()
            .iter()
            .all(|d| d.abs() < 1e-9));
    }

    /// The centre path's radius is the law-of-cosines R_e and γ matches
    /// atan((dR_e/dφ_e)/R_e) taken numerically along the path.
    #[test]
    fn centre_path_matches_law_of_cosines_and_gamma_definition() {
        let p = ellipse(2000, 60.0, 40.0);
        let rkn = 150.0;
        let path = centre_path(&p, rkn);
        for i in (5..1995).step_by(97) {
            let re =
                (p.r_mm[i].powi(2) + rkn * rkn + 2.0 * p.r_mm[i] * rkn * p.gamma0_rad[i].cos())
                    .sqrt();
            assert!((re - path.x_mm[i]).abs() < 1e-9);
            let dre =
                (path.x_mm[i + 1] - path.x_mm[i - 1]) / (path.c_rad[i + 1] - path.c_rad[i - 1]);
            let g = (dre / path.x_mm[i]).atan();
            assert!(
                (g + path.gamma_rad[i]).abs() < 1e-4 || (g - path.gamma_rad[i]).abs() < 1e-4,
                "{g} vs {}",
                path.gamma_rad[i]
            );
        }
    }

    /// First order: δ ≈ (R_kn − R_k)(1 − cos γ), close to linear in the
    /// radius deviation (docs/models.md §4), and finite on a straight part.
    #[test]
    fn delta_is_close_to_linear_in_the_radius_deviation() {
        let p = ellipse(720, 60.0, 40.0);
        let path = centre_path(&p, 170.0);
        let d1 = profile_error(&p, &path, 165.0).unwrap();
        let d2 = profile_error(&p, &path, 160.0).unwrap();
        let m1 = d1.iter().cloned().fold(0.0, f64::max);
        let m2 = d2.iter().cloned().fold(0.0, f64::max);
        assert!(m1 > 0.0 && (m2 / m1 - 2.0).abs() < 0.05, "{m1} {m2}");
        for (d, g) in d1.iter().zip(&path.gamma_rad) {
            let first = 5.0 * (1.0 - g.cos());
            assert!((d - first).abs() < 0.05 * first.abs() + 1e-9);
        }
        assert_eq!(
            delta_mm(0.0, 0.3, 170.0, 160.0),
            Some(10.0 * (1.0 - 0.3f64.cos()))
        );
        assert_eq!(delta_mm(-1.0 / 100.0, 0.3, 170.0, 160.0), None);
    }

    /// Against the exact envelope of the real wheel: circles of radius R_k
    /// at the controller's centres (programmed centre moved radially in by
    /// R_kn − R_k); the ground surface along each design normal is the
    /// nearest entry into any circle. The published δ stays within a few
    /// per cent of it; the osculating-circle δ within one per cent.
    #[test]
    fn delta_matches_the_exact_wheel_envelope() {
        let p = ellipse(4000, 60.0, 40.0);
        let (rkn, rk) = (150.0, 140.0);
        let path = centre_path(&p, rkn);
        let centres: Vec<[f64; 2]> = (0..p.len())
            .map(|j| {
                let pt = p.point(j);
                let c = [pt[0] + rkn * p.normal[j][0], pt[1] + rkn * p.normal[j][1]];
                let re = c[0].hypot(c[1]);
                [c[0] - (rkn - rk) * c[0] / re, c[1] - (rkn - rk) * c[1] / re]
            })
            .collect();
        let (mut worst_pub, mut worst_osc, mut biggest) = (0.0_f64, 0.0_f64, 0.0_f64);
        for i in (0..p.len()).step_by(100) {
            let (pt, n) = (p.point(i), p.normal[i]);
            let mut surface = f64::INFINITY;
            for c in &centres {
                let (dx, dy) = (pt[0] - c[0], pt[1] - c[1]);
                let b = n[0] * dx + n[1] * dy;
                let disc = b * b - (dx * dx + dy * dy - rk * rk);
                // Only wheels ahead along the normal (the line also meets
                // wheels on the far side of the work, behind the profile).
                if disc >= 0.0 && b < 0.0 {
                    surface = surface.min(-b - disc.sqrt());
                }
            }
            let (k, g) = (p.kappa_per_mm[i], path.gamma_rad[i]);
            let published = delta_mm(k, g, rkn, rk).unwrap();
            let osculating = delta_osculating_mm(k, g, rkn, rk).unwrap();
            worst_pub = worst_pub.max((published - surface).abs());
            worst_osc = worst_osc.max((osculating - surface).abs());
            biggest = biggest.max(surface.abs());
        }
        assert!(biggest > 0.04, "{biggest}");
        assert!(
            worst_pub < 0.05 * biggest,
            "published off by {worst_pub} of {biggest}"
        );
        assert!(
            worst_osc < 0.015 * biggest,
            "osculating off by {worst_osc} of {biggest}"
        );
        assert!(worst_osc < worst_pub);
        // Both reduce to Δ(1 − cos γ) on a straight part.
        assert_eq!(
            delta_osculating_mm(0.0, 0.3, 170.0, 160.0),
            delta_mm(0.0, 0.3, 170.0, 160.0)
        );
    }
}

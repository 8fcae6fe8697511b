//! `datum`: per face the thesis's OLS fit and an orthogonal (TLS) fit with
//! optional robust rejection and covariances, per square of 4 points and
//! over all points; the datum (the intersection of the three planes) with
//! its covariance propagated from the planes', the inter-face squareness,
//! and the thesis's error vector E = A·α and transition angles
//! (MODELS.md §1.3).
//!
//! Length (over 700 lines with its tests; ~830 of code): the per-face fits,
//! the datum with its covariance, the run-less `stage datum --planes` form
//! and the summary share `FaceFit`; planes.rs holds the plane algebra.

use anyhow::{anyhow, bail};
use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use serde_json::{json, Value};
use sparkout_pipeline::contracts::schema::{AE, PROBE};
use sparkout_pipeline::contracts::BatchBuilder;
use sparkout_pipeline::json_f64;
use sparkout_pipeline::{
    InputError, Result, Stage, StageArgs, StageContext, StageOutput, StageSpec,
};
use statrs::distribution::{ChiSquared, ContinuousCDF};

use super::config::{check_config, Check};
use super::planes::{
    fit_ols, fit_tls, intersect, max_abs, rms, robust_keep, squareness, Datum, Face, FitError,
    OlsFit, Plane, TlsFit,
};
use super::repeatability::{latency, pooled_std_by_face};
use super::touches::{self, Touch};

/// Datum settings (`[robot.datum]`).
#[derive(Debug, Clone, Copy)]
pub struct DatumConfig {
    /// Which fit defines the datum: TLS (default) or the thesis's OLS.
    pub use_tls: bool,
    pub robust: bool,
    pub reject_k: f64,
    /// Floor of the robust scale (mm), so exact data reject nothing.
    pub min_scale_mm: f64,
    pub max_condition: f64,
    pub collinear_ratio: f64,
    pub confidence: f64,
    /// Remove each method's trigger latency (estimated from ≥ 2 approach
    /// speeds, MODELS.md §1.1) from its touches before fitting: p − v·L·dir.
    pub correct_latency: bool,
}

impl Default for DatumConfig {
    fn default() -> Self {
        DatumConfig {
            use_tls: true,
            robust: true,
            reject_k: 4.0,
            min_scale_mm: 0.0005,
            max_condition: 10.0,
            collinear_ratio: 1e-3,
            confidence: 0.95,
            correct_latency: true,
        }
    }
}

const KEYS: &[(&str, Check)] = &[
    ("fit", Check::OneOf(&["tls", "ols"])),
    ("robust", Check::Bool),
    ("reject_k", Check::Positive),
    ("min_scale_mm", Check::Positive),
    ("max_condition", Check::AtLeastOne),
    ("collinear_ratio", Check::Probability),
    ("confidence", Check::Probability),
    ("correct_latency", Check::Bool),
    (
        "method",
        Check::OneOf(&["auto", "all", "ae", "electrical", "mechanical"]),
    ),
];

/// Precision order of the probing methods (MODELS.md §1.1: AE 25–85 µm,
/// electrical 163 µm, mechanical 700 µm range): `method = "auto"` fits the
/// datum with the most precise method a run has.
const METHOD_PRECISION_ORDER: [&str; 3] = ["ae", "electrical", "mechanical"];

/// The touches the datum is fitted from (`[robot.datum] method`): `all`
/// pools every method, `auto` takes the most precise method present, a
/// method name takes that method. Pooling methods whose scatter differs by
/// 10× lets the worst one set the planes.
pub fn select_method(
    all: &[Touch],
    method: &str,
    file: &std::path::Path,
) -> Result<(Vec<Touch>, String)> {
    let present: std::collections::BTreeSet<&str> = all.iter().map(|t| t.method.as_str()).collect();
    let chosen = match method {
        "all" => return Ok((all.to_vec(), "all".into())),
        "auto" => match METHOD_PRECISION_ORDER.iter().find(|m| present.contains(*m)) {
            Some(m) => *m,
            None => return Ok((all.to_vec(), "all".into())),
        },
        m => m,
    };
    let picked: Vec<Touch> = all.iter().filter(|t| t.method == chosen).cloned().collect();
    if picked.is_empty() {
        return Err(InputError::new(
            file,
            format!(
                "no touches of method `{chosen}` (methods present: {}); set [robot.datum] method = \"auto\" or one of those",
                present.iter().copied().collect::<Vec<_>>().join(", ")
            ),
        )
        .column("method")
        .into());
    }
    Ok((picked, chosen.to_string()))
}

impl DatumConfig {
    pub fn from_ctx(ctx: &StageContext) -> DatumConfig {
        let d = DatumConfig::default();
        DatumConfig {
            use_tls: ctx.cfg_str("fit", "tls") == "tls",
            robust: ctx.cfg_bool("robust", d.robust),
            reject_k: ctx.cfg_f64("reject_k", d.reject_k),
            min_scale_mm: ctx.cfg_f64("min_scale_mm", d.min_scale_mm),
            max_condition: ctx.cfg_f64("max_condition", d.max_condition),
            collinear_ratio: ctx.cfg_f64("collinear_ratio", d.collinear_ratio),
            confidence: ctx.cfg_f64("confidence", d.confidence),
            correct_latency: ctx.cfg_bool("correct_latency", d.correct_latency),
        }
    }
}

/// Both fits of one face over one scope of points.
#[derive(Debug, Clone)]
pub struct FaceFit {
    pub face: Face,
    pub tls: TlsFit,
    pub ols: OlsFit,
    /// Indices (into the face's touches) kept, and the rejected ones.
    pub kept: Vec<usize>,
    pub rejected: Vec<usize>,
    pub robust_scale_mm: Option<f64>,
}

impl FaceFit {
    pub fn plane(&self, use_tls: bool) -> &Plane {
        if use_tls {
            &self.tls.plane
        } else {
            &self.ols.plane
        }
    }
}

/// Fit one face's points (TLS first: its checks name the geometric problem).
pub fn fit_face(
    face: Face,
    pts: &[Vector3<f64>],
    cfg: &DatumConfig,
    robust: bool,
) -> Result<FaceFit, FitError> {
    let (kept, scale) = if robust {
        let (k, s) = robust_keep(
            face,
            pts,
            cfg.reject_k,
            cfg.min_scale_mm,
            cfg.collinear_ratio,
        )?;
        (k, Some(s))
    } else {
        ((0..pts.len()).collect(), None)
    };
    let sub: Vec<Vector3<f64>> = kept.iter().map(|&i| pts[i]).collect();
    let tls = fit_tls(face, &sub, cfg.collinear_ratio)?;
    let ols = fit_ols(face, &sub, cfg.collinear_ratio)?;
    let rejected = (0..pts.len()).filter(|i| !kept.contains(i)).collect();
    Ok(FaceFit {
        face,
        tls,
        ols,
        kept,
        rejected,
        robust_scale_mm: scale,
    })
}

/// The datum of three faces' fits and what comes with it.
#[derive(Debug, Clone)]
pub struct DatumResult {
    pub datum: Datum,
    /// Squareness (rad): xy–yz, yz–zx, zx–xy.
    pub squareness: [f64; 3],
    /// Semi-axes (mm) of the confidence ellipsoid, descending, and their
    /// directions.
    pub ellipsoid_mm: [f64; 3],
    pub ellipsoid_axes: [Vector3<f64>; 3],
}

pub fn datum_of(planes: [&Plane; 3], cfg: &DatumConfig) -> Result<DatumResult, FitError> {
    let datum = intersect(planes, cfg.max_condition)?;
    let sq = [
        squareness(planes[0], planes[1]),
        squareness(planes[1], planes[2]),
        squareness(planes[2], planes[0]),
    ];
    let (ell, axes) = ellipsoid(&datum.cov, cfg.confidence);
    Ok(DatumResult {
        datum,
        squareness: sq,
        ellipsoid_mm: ell,
        ellipsoid_axes: axes,
    })
}

/// Confidence ellipsoid of a 3-D normal: semi-axes sqrt(χ²₃(p)·λ_k).
pub fn ellipsoid(cov: &Matrix3<f64>, p: f64) -> ([f64; 3], [Vector3<f64>; 3]) {
    if !cov.iter().all(|x| x.is_finite()) {
        return ([f64::NAN; 3], [Vector3::zeros(); 3]);
    }
    let chi2 = ChiSquared::new(3.0).expect("3 dof").inverse_cdf(p);
    let e = SymmetricEigen::new(*cov);
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&a, &b| e.eigenvalues[b].total_cmp(&e.eigenvalues[a]));
    let ax = |k: usize| (chi2 * e.eigenvalues[idx[k]].max(0.0)).sqrt();
    let v = |k: usize| e.eigenvectors.column(idx[k]).into_owned();
    ([ax(0), ax(1), ax(2)], [v(0), v(1), v(2)])
}

/// The thesis's matrix A (MODELS.md §1.3): rows are the planes' OLS
/// coefficients ordered so the normal coordinate's coefficient −1 is on the
/// diagonal (yz → x, zx → y, xy → z).
pub fn thesis_a(b: [[f64; 3]; 3]) -> Matrix3<f64> {
    let [bxy, byz, bzx] = b;
    Matrix3::new(
        -1.0, byz[1], byz[2], // x = b0 + b1·y + b2·z
        bzx[1], -1.0, bzx[2], // y = b0 + b1·x + b2·z
        bxy[1], bxy[2], -1.0, // z = b0 + b1·x + b2·y
    )
}

/// Thesis OLS coefficients equivalent to a plane (normal coordinate as a
/// function of the other two).
pub fn ols_form(face: Face, p: &Plane) -> [f64; 3] {
    let a = face.normal_axis();
    let (u, w) = face.in_plane_axes();
    [p.d / p.n[a], -p.n[u] / p.n[a], -p.n[w] / p.n[a]]
}

fn m3(m: &Matrix3<f64>) -> Value {
    if !m.iter().all(|x| x.is_finite()) {
        return Value::Null;
    }
    json!([
        [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
        [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
        [m[(2, 0)], m[(2, 1)], m[(2, 2)]]
    ])
}

fn v3(v: &Vector3<f64>) -> Value {
    if v.iter().all(|x| x.is_finite()) {
        json!([v[0], v[1], v[2]])
    } else {
        Value::Null
    }
}

fn sq_json(sq: &[f64; 3]) -> Value {
    json!({"xy_yz": json_f64(sq[0]), "yz_zx": json_f64(sq[1]), "zx_xy": json_f64(sq[2])})
}

/// Square of a point id in the thesis's pattern (0–3 outer, 4–7 middle,
/// 8–11 inner), if any.
pub fn square_of(point: i32) -> Option<usize> {
    (0..12).contains(&point).then_some((point / 4) as usize)
}

pub const SQUARES: [&str; 3] = ["outer", "middle", "inner"];

/// The whole datum analysis of a run's touches.
pub struct DatumAnalysis {
    pub fits: [FaceFit; 3],
    /// Touch indices of each face (into the run's touches).
    pub face_touches: [Vec<usize>; 3],
    pub main: DatumResult,
    pub ols: Option<DatumResult>,
    pub squares: Vec<(usize, [FaceFit; 3], Option<DatumResult>)>,
    pub alpha_mm: [Option<f64>; 3],
    /// Latency removed per method (s), when `correct_latency`.
    pub latency_s: std::collections::BTreeMap<String, f64>,
}

/// The touches with each method's estimated trigger latency removed
/// (MODELS.md §1.1: a touch registered L after contact at speed v overshoots
/// by v·L along the approach direction). Methods touched at one speed only
/// are left as they are.
pub fn latency_corrected(all: &[Touch]) -> (Vec<Touch>, std::collections::BTreeMap<String, f64>) {
    let mut by: std::collections::BTreeMap<String, Vec<&Touch>> = Default::default();
    for t in all {
        by.entry(t.method.clone()).or_default().push(t);
    }
    let lat: std::collections::BTreeMap<String, f64> = by
        .iter()
        .filter_map(|(m, ts)| latency(ts).map(|l| (m.clone(), l.latency_s)))
        .filter(|(_, l)| l.is_finite())
        .collect();
    let out = all
        .iter()
        .map(|t| {
            let mut c = t.clone();
            if let Some(l) = lat.get(&t.method) {
                c.p -= t.dir * (t.approach_mm_s * l);
            }
            c
        })
        .collect();
    (out, lat)
}

/// Where the touches came from (for error messages).
fn source_file(ctx: &StageContext, t: &[Touch]) -> std::path::PathBuf {
    if t.first().is_some_and(|t| t.source == "ae") {
        ctx.run.table_path(&AE)
    } else {
        ctx.run.table_path(&PROBE)
    }
}

pub fn analyse(raw: &[Touch], cfg: &DatumConfig, file: &std::path::Path) -> Result<DatumAnalysis> {
    let (corrected, latency_s) = if cfg.correct_latency {
        latency_corrected(raw)
    } else {
        (raw.to_vec(), Default::default())
    };
    let all = &corrected[..];
    let bad = |msg: String| -> anyhow::Error { InputError::new(file, msg).column("face").into() };
    let mut face_touches: [Vec<usize>; 3] = Default::default();
    for (i, t) in all.iter().enumerate() {
        face_touches[t.face.index()].push(i);
    }
    let mut fits = Vec::new();
    for face in Face::ALL {
        let idx = &face_touches[face.index()];
        let pts: Vec<Vector3<f64>> = idx.iter().map(|&i| all[i].p).collect();
        fits.push(fit_face(face, &pts, cfg, cfg.robust).map_err(|e| bad(e.0))?);
    }
    let fits: [FaceFit; 3] = fits.try_into().map_err(|_| anyhow!("three faces"))?;
    let planes = |tls: bool| [fits[0].plane(tls), fits[1].plane(tls), fits[2].plane(tls)];
    let main = datum_of(planes(cfg.use_tls), cfg).map_err(|e| bad(e.0))?;
    let ols = datum_of(planes(!cfg.use_tls), cfg).ok();
    // Per square of the thesis's pattern, when every face has ≥ 3 points in it.
    let mut squares = Vec::new();
    for sq in 0..3 {
        let mut sfits = Vec::new();
        for face in Face::ALL {
            let pts: Vec<Vector3<f64>> = face_touches[face.index()]
                .iter()
                .filter(|&&i| square_of(all[i].point) == Some(sq))
                .map(|&i| all[i].p)
                .collect();
            if pts.len() < 3 {
                break;
            }
            match fit_face(face, &pts, cfg, false) {
                Ok(f) => sfits.push(f),
                Err(_) => break,
            }
        }
        if sfits.len() == 3 {
            let sfits: [FaceFit; 3] = sfits.try_into().map_err(|_| anyhow!("three faces"))?;
            let d = datum_of(
                [
                    sfits[0].plane(cfg.use_tls),
                    sfits[1].plane(cfg.use_tls),
                    sfits[2].plane(cfg.use_tls),
                ],
                cfg,
            )
            .ok();
            squares.push((sq, sfits, d));
        }
    }
    Ok(DatumAnalysis {
        fits,
        face_touches,
        main,
        ols,
        squares,
        alpha_mm: pooled_std_by_face(all),
        latency_s,
    })
}

/// Transition angles (MODELS.md §1.3: ±(atan(ΔY/Lx) + atan(ΔZ/Lx))), read as:
/// for each face, the two other faces' repeatability σ over the spacing L of
/// the detection points on this face (the side of its outer square of
/// nominal points).
fn transition_angles(all: &[Touch], a: &DatumAnalysis) -> Value {
    let mut m = serde_json::Map::new();
    for face in Face::ALL {
        let (u, w) = face.in_plane_axes();
        let idx = &a.face_touches[face.index()];
        let extent = |k: usize| {
            let (lo, hi) = idx
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &i| {
                    (lo.min(all[i].nom[k]), hi.max(all[i].nom[k]))
                });
            hi - lo
        };
        let l = 0.5 * (extent(u) + extent(w));
        let others: Vec<Option<f64>> = Face::ALL
            .iter()
            .filter(|f| **f != face)
            .map(|f| a.alpha_mm[f.index()])
            .collect();
        let v = match (others[0], others[1]) {
            (Some(p), Some(q)) if l > 0.0 => json_f64((p / l).atan() + (q / l).atan()),
            _ => Value::Null,
        };
        m.insert(face.label().into(), v);
    }
    Value::Object(m)
}

fn plane_json(f: &FaceFit, use_tls: bool, all: &[Touch], idx: &[usize]) -> Value {
    let r = if use_tls {
        &f.tls.residuals
    } else {
        &f.ols.residuals
    };
    let rejected: Vec<Value> = f
        .rejected
        .iter()
        .map(|&k| {
            let t = &all[idx[k]];
            json!({"point": t.point, "trial": t.trial, "method": t.method, "approach_mm_s": t.approach_mm_s,
                   "distance_mm": f.tls.plane.distance(&t.p)})
        })
        .collect();
    json!({
        "ols": f.ols.b,
        "tls_normal": [f.tls.plane.n[0], f.tls.plane.n[1], f.tls.plane.n[2]],
        "tls_d": f.tls.plane.d,
        "residual_rms_mm": json_f64(rms(r)),
        "residual_max_mm": json_f64(max_abs(r)),
        "ols_residual_rms_mm": json_f64(rms(&f.ols.residuals)),
        "tls_residual_rms_mm": json_f64(rms(&f.tls.residuals)),
        "n": f.kept.len() + f.rejected.len(),
        "n_rejected": f.rejected.len(),
        "robust_scale_mm": f.robust_scale_mm.map_or(Value::Null, json_f64),
        "rejected": rejected,
    })
}

fn datum_json(d: &DatumResult) -> Value {
    let c = &d.datum.cov;
    json!({
        "datum_mm": v3(&d.datum.p),
        "datum_cov_mm2": m3(c),
        "datum_sigma_mm": [json_f64(c[(0, 0)].sqrt()), json_f64(c[(1, 1)].sqrt()), json_f64(c[(2, 2)].sqrt())],
        "condition": d.datum.condition,
        "squareness_rad": sq_json(&d.squareness),
    })
}

pub fn summary(all: &[Touch], a: &DatumAnalysis, cfg: &DatumConfig) -> Value {
    let mut planes = serde_json::Map::new();
    for f in &a.fits {
        planes.insert(
            f.face.label().into(),
            plane_json(f, cfg.use_tls, all, &a.face_touches[f.face.index()]),
        );
    }
    let b = [a.fits[0].ols.b, a.fits[1].ols.b, a.fits[2].ols.b];
    let alpha_x = a.alpha_mm[Face::Yz.index()];
    let alpha_y = a.alpha_mm[Face::Zx.index()];
    let alpha_z = a.alpha_mm[Face::Xy.index()];
    let error_vector = match (alpha_x, alpha_y, alpha_z) {
        (Some(x), Some(y), Some(z)) => v3(&(thesis_a(b) * Vector3::new(x, y, z))),
        _ => Value::Null,
    };
    let m = &a.main;
    let squares: Vec<Value> = a
        .squares
        .iter()
        .map(|(sq, fits, d)| {
            let res: serde_json::Map<String, Value> = fits
                .iter()
                .map(|f| {
                    (
                        f.face.label().to_string(),
                        json!({"ols": f.ols.b, "residual_rms_mm": json_f64(rms(if cfg.use_tls { &f.tls.residuals } else { &f.ols.residuals })), "n": f.kept.len()}),
                    )
                })
                .collect();
            json!({
                "square": SQUARES[*sq],
                "planes": res,
                "datum_mm": d.as_ref().map(|d| v3(&d.datum.p)).unwrap_or(Value::Null),
                "datum_sigma_mm": d.as_ref().map(|d| json!([json_f64(d.datum.cov[(0,0)].sqrt()), json_f64(d.datum.cov[(1,1)].sqrt()), json_f64(d.datum.cov[(2,2)].sqrt())])).unwrap_or(Value::Null),
            })
        })
        .collect();
    json!({
        "fit": if cfg.use_tls { "tls" } else { "ols" },
        "planes": planes,
        "datum_mm": v3(&m.datum.p),
        "datum_cov_mm2": m3(&m.datum.cov),
        "datum_sigma_mm": [json_f64(m.datum.cov[(0, 0)].sqrt()), json_f64(m.datum.cov[(1, 1)].sqrt()), json_f64(m.datum.cov[(2, 2)].sqrt())],
        "datum_ellipsoid_mm": {
            "confidence": cfg.confidence,
            "semi_axes_mm": [json_f64(m.ellipsoid_mm[0]), json_f64(m.ellipsoid_mm[1]), json_f64(m.ellipsoid_mm[2])],
            "axes": [v3(&m.ellipsoid_axes[0]), v3(&m.ellipsoid_axes[1]), v3(&m.ellipsoid_axes[2])],
        },
        "condition": m.datum.condition,
        "squareness_rad": sq_json(&m.squareness),
        "error_vector_mm": error_vector,
        "alpha_mm": {"x": alpha_x, "y": alpha_y, "z": alpha_z},
        "transition_angles_rad": transition_angles(all, a),
        "datum_other_fit": a.ols.as_ref().map(datum_json).unwrap_or(Value::Null),
        "by_square": squares,
        "latency_corrected_s": a.latency_s,
    })
}

const COV_NAMES: [(usize, usize, &str); 10] = [
    (0, 0, "cov_nx_nx"),
    (0, 1, "cov_nx_ny"),
    (0, 2, "cov_nx_nz"),
    (0, 3, "cov_nx_d"),
    (1, 1, "cov_ny_ny"),
    (1, 2, "cov_ny_nz"),
    (1, 3, "cov_ny_d"),
    (2, 2, "cov_nz_nz"),
    (2, 3, "cov_nz_d"),
    (3, 3, "cov_d_d"),
];

/// The `planes` artifact: one row per face × fit × scope.
fn planes_batch(a: &DatumAnalysis, use_tls: bool) -> arrow::record_batch::RecordBatch {
    struct Row<'a> {
        face: Face,
        fit: &'static str,
        scope: &'static str,
        f: &'a FaceFit,
    }
    let mut rows = Vec::new();
    for f in &a.fits {
        for fit in ["tls", "ols"] {
            rows.push(Row {
                face: f.face,
                fit,
                scope: "all",
                f,
            });
        }
    }
    for (sq, fits, _) in &a.squares {
        for f in fits {
            for fit in ["tls", "ols"] {
                rows.push(Row {
                    face: f.face,
                    fit,
                    scope: SQUARES[*sq],
                    f,
                });
            }
        }
    }
    fn plane<'a>(r: &Row<'a>) -> &'a Plane {
        if r.fit == "tls" {
            &r.f.tls.plane
        } else {
            &r.f.ols.plane
        }
    }
    fn resid<'a>(r: &Row<'a>) -> &'a [f64] {
        if r.fit == "tls" {
            &r.f.tls.residuals
        } else {
            &r.f.ols.residuals
        }
    }
    let mut b = BatchBuilder::new()
        .str(
            "face",
            &rows.iter().map(|r| r.face.label()).collect::<Vec<_>>(),
        )
        .str("fit", &rows.iter().map(|r| r.fit).collect::<Vec<_>>())
        .str("scope", &rows.iter().map(|r| r.scope).collect::<Vec<_>>())
        .i32(
            "primary",
            rows.iter()
                .map(|r| ((r.fit == "tls") == use_tls) as i32)
                .collect(),
        )
        .i32("n", rows.iter().map(|r| r.f.kept.len() as i32).collect())
        .i32(
            "n_rejected",
            rows.iter().map(|r| r.f.rejected.len() as i32).collect(),
        )
        .f64(
            "b0",
            rows.iter().map(|r| ols_form(r.face, plane(r))[0]).collect(),
        )
        .f64(
            "b1",
            rows.iter().map(|r| ols_form(r.face, plane(r))[1]).collect(),
        )
        .f64(
            "b2",
            rows.iter().map(|r| ols_form(r.face, plane(r))[2]).collect(),
        )
        .f64("nx", rows.iter().map(|r| plane(r).n[0]).collect())
        .f64("ny", rows.iter().map(|r| plane(r).n[1]).collect())
        .f64("nz", rows.iter().map(|r| plane(r).n[2]).collect())
        .f64("d_mm", rows.iter().map(|r| plane(r).d).collect())
        .f64(
            "residual_rms_mm",
            rows.iter().map(|r| rms(resid(r))).collect(),
        )
        .f64(
            "residual_max_mm",
            rows.iter().map(|r| max_abs(resid(r))).collect(),
        );
    for (i, j, name) in COV_NAMES {
        b = b.f64(name, rows.iter().map(|r| plane(r).cov[(i, j)]).collect());
    }
    b.build()
}

/// The `datum` artifact: one row per scope × fit.
fn datum_batch(a: &DatumAnalysis, use_tls: bool) -> arrow::record_batch::RecordBatch {
    let primary = if use_tls { "tls" } else { "ols" };
    let other = if use_tls { "ols" } else { "tls" };
    let mut rows: Vec<(&str, &str, &DatumResult)> = vec![("all", primary, &a.main)];
    if let Some(o) = &a.ols {
        rows.push(("all", other, o));
    }
    for (sq, _, d) in &a.squares {
        if let Some(d) = d {
            rows.push((SQUARES[*sq], primary, d));
        }
    }
    let c = |i: usize, j: usize| {
        rows.iter()
            .map(|r| r.2.datum.cov[(i, j)])
            .collect::<Vec<_>>()
    };
    BatchBuilder::new()
        .str("scope", &rows.iter().map(|r| r.0).collect::<Vec<_>>())
        .str("fit", &rows.iter().map(|r| r.1).collect::<Vec<_>>())
        .f64("x_mm", rows.iter().map(|r| r.2.datum.p[0]).collect())
        .f64("y_mm", rows.iter().map(|r| r.2.datum.p[1]).collect())
        .f64("z_mm", rows.iter().map(|r| r.2.datum.p[2]).collect())
        .f64("cov_xx_mm2", c(0, 0))
        .f64("cov_xy_mm2", c(0, 1))
        .f64("cov_xz_mm2", c(0, 2))
        .f64("cov_yy_mm2", c(1, 1))
        .f64("cov_yz_mm2", c(1, 2))
        .f64("cov_zz_mm2", c(2, 2))
        .f64(
            "ellipsoid_a_mm",
            rows.iter().map(|r| r.2.ellipsoid_mm[0]).collect(),
        )
        .f64(
            "ellipsoid_b_mm",
            rows.iter().map(|r| r.2.ellipsoid_mm[1]).collect(),
        )
        .f64(
            "ellipsoid_c_mm",
            rows.iter().map(|r| r.2.ellipsoid_mm[2]).collect(),
        )
        .f64(
            "condition",
            rows.iter().map(|r| r.2.datum.condition).collect(),
        )
        .f64(
            "squareness_xy_yz_rad",
            rows.iter().map(|r| r.2.squareness[0]).collect(),
        )
        .f64(
            "squareness_yz_zx_rad",
            rows.iter().map(|r| r.2.squareness[1]).collect(),
        )
        .f64(
            "squareness_zx_xy_rad",
            rows.iter().map(|r| r.2.squareness[2]).collect(),
        )
        .build()
}

pub struct DatumStage;

const SPEC: StageSpec = StageSpec {
    name: "datum",
    version: 2,
    reads: &[],
    reads_artifacts: &["touches"],
    writes: &["planes", "datum"],
    about: "face planes (thesis OLS + orthogonal TLS, robust), datum = intersection with covariance, squareness, E = A·α (MODELS.md §1.3)",
};

impl Stage for DatumStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn validate_config(&self, config: &toml::Table) -> Result<()> {
        check_config(config, KEYS)
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let cfg = DatumConfig::from_ctx(ctx);
        let every = touches::require(ctx)?;
        let file = source_file(ctx, &every);
        let (all, method) = select_method(&every, ctx.cfg_str("method", "auto"), &file)?;
        let a = analyse(&all, &cfg, &file)?;
        let mut s = summary(&all, &a, &cfg);
        s["touch_method"] = json!(method);
        Ok(StageOutput::new(s)
            .with("planes", planes_batch(&a, cfg.use_tls))
            .with("datum", datum_batch(&a, cfg.use_tls)))
    }
    fn run_standalone(&self, args: &StageArgs) -> Option<Result<Value>> {
        Some(standalone(args))
    }
}

/// `sparkout stage datum --planes "a,b,c,d;a,b,c,d;a,b,c,d"` (each
/// a·x + b·y + c·z + d = 0), optionally `--alpha "αx,αy,αz"` (mm) for the
/// thesis's error vector and `--max-condition`.
fn standalone(args: &StageArgs) -> Result<Value> {
    for k in args.keys() {
        if !["planes", "alpha", "max-condition"].contains(&k.as_str()) {
            bail!("stage datum: unknown option --{k} (known: --planes, --alpha, --max-condition)");
        }
    }
    let spec = args.get("planes").ok_or_else(|| {
        anyhow!("stage datum: give --run DIR, or --planes \"a,b,c,d;a,b,c,d;a,b,c,d\"")
    })?;
    let parse = |s: &str, n: usize, what: &str| -> Result<Vec<f64>> {
        let v: Vec<f64> = s
            .split(',')
            .map(|x| x.trim().parse::<f64>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| {
                anyhow!("stage datum: {what} `{s}` must be {n} comma-separated numbers")
            })?;
        if v.len() != n || !v.iter().all(|x| x.is_finite()) {
            bail!("stage datum: {what} `{s}` must be {n} comma-separated finite numbers");
        }
        Ok(v)
    };
    let parts: Vec<&str> = spec.split(';').filter(|s| !s.trim().is_empty()).collect();
    if parts.len() != 3 {
        bail!(
            "stage datum: --planes needs exactly three planes separated by `;`, got {}",
            parts.len()
        );
    }
    let mut planes = Vec::new();
    for (i, p) in parts.iter().enumerate() {
        let v = parse(p, 4, &format!("plane {}", i + 1))?;
        planes.push(
            Plane::from_coefficients(v[0], v[1], v[2], v[3])
                .map_err(|e| anyhow!("stage datum: {e}"))?,
        );
    }
    // Label planes by their dominant normal axis when that is unambiguous.
    let face_of = |p: &Plane| match p.n.iamax() {
        0 => Face::Yz,
        1 => Face::Zx,
        _ => Face::Xy,
    };
    let faces: Vec<Face> = planes.iter().map(face_of).collect();
    let distinct = faces[0] != faces[1] && faces[1] != faces[2] && faces[0] != faces[2];
    let mut order = [0usize, 1, 2];
    if distinct {
        order.sort_by_key(|&i| faces[i].index());
    }
    let cfg = DatumConfig {
        max_condition: match args.get("max-condition") {
            Some(s) => s
                .parse::<f64>()
                .ok()
                .filter(|x| *x >= 1.0)
                .ok_or_else(|| anyhow!("stage datum: --max-condition must be a number ≥ 1"))?,
            None => DatumConfig::default().max_condition,
        },
        ..DatumConfig::default()
    };
    let d = datum_of(
        [&planes[order[0]], &planes[order[1]], &planes[order[2]]],
        &cfg,
    )
    .map_err(|e| anyhow!("stage datum: {e}"))?;
    let mut pj = serde_json::Map::new();
    for (k, &i) in order.iter().enumerate() {
        let p = &planes[i];
        let label = if distinct {
            faces[i].label().to_string()
        } else {
            format!("p{}", k + 1)
        };
        let mut o = json!({"normal": [p.n[0], p.n[1], p.n[2]], "d": p.d, "tls_normal": [p.n[0], p.n[1], p.n[2]], "tls_d": p.d});
        if distinct {
            o["ols"] = json!(ols_form(faces[i], p));
        }
        pj.insert(label, o);
    }
    let error_vector = match (distinct, args.get("alpha")) {
        (true, Some(s)) => {
            let a = parse(s, 3, "--alpha")?;
            let b = [
                ols_form(Face::Xy, &planes[order[0]]),
                ols_form(Face::Yz, &planes[order[1]]),
                ols_form(Face::Zx, &planes[order[2]]),
            ];
            v3(&(thesis_a(b) * Vector3::new(a[0], a[1], a[2])))
        }
        _ => Value::Null,
    };
    let sq = if distinct {
        sq_json(&d.squareness)
    } else {
        json!({"p1_p2": json_f64(d.squareness[0]), "p2_p3": json_f64(d.squareness[1]), "p3_p1": json_f64(d.squareness[2])})
    };
    Ok(json!({
        "planes": pj,
        "datum_mm": v3(&d.datum.p),
        "datum_cov_mm2": Value::Null,
        "condition": d.datum.condition,
        "squareness_rad": sq,
        "error_vector_mm": error_vector,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::repeatability::tests::synth_touches;

    #[test]
    fn standalone_planes_give_their_intersection() {
        // x = 1, y = 2, z = 3 given in scrambled order and scale.
        let args: StageArgs = [(
            "planes".to_string(),
            "0,0,2,-6; 1,0,0,-1; 0,-1,0,2".to_string(),
        )]
        .into_iter()
        .collect();
        let v = DatumStage.run_standalone(&args).unwrap().unwrap();
        let p: Vec<f64> = v["datum_mm"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        assert!(
            (p[0] - 1.0).abs() < 1e-12 && (p[1] - 2.0).abs() < 1e-12 && (p[2] - 3.0).abs() < 1e-12
        );
        assert_eq!(v["planes"]["xy"]["ols"][0].as_f64(), Some(3.0));
        assert!(v["squareness_rad"]["xy_yz"].as_f64().unwrap().abs() < 1e-15);
        let bad: StageArgs = [(
            "planes".to_string(),
            "0,0,1,0;0,0.01,1,-1;1,0,0,0".to_string(),
        )]
        .into_iter()
        .collect();
        let e = DatumStage.run_standalone(&bad).unwrap().unwrap_err();
        assert!(e.to_string().contains("nearly parallel"), "{e}");
    }

    #[test]
    fn datum_of_synthetic_block_within_its_uncertainty() {
        let origin = Vector3::new(100.0, 200.0, -12.0);
        let ts = synth_touches(origin, &[5.0], 5, 0.0, 0.01, 21);
        let cfg = DatumConfig::default();
        let a = analyse(&ts, &cfg, std::path::Path::new("probe.parquet")).unwrap();
        let err = a.main.datum.p - origin;
        let cov = a.main.datum.cov;
        // Mahalanobis distance within the 99.9 % region of χ²₃.
        let m = err.dot(&(cov.try_inverse().unwrap() * err));
        assert!(m < 16.3, "datum error {err} vs cov {cov}");
        assert_eq!(a.squares.len(), 3);
        let s = summary(&ts, &a, &cfg);
        assert!(s["error_vector_mm"].is_array());
        // E ≈ −α for near-axis-aligned planes.
        let e0 = s["error_vector_mm"][0].as_f64().unwrap();
        assert!((e0 + a.alpha_mm[1].unwrap()).abs() < 1e-3);
        assert!(s["datum_ellipsoid_mm"]["semi_axes_mm"][0].as_f64().unwrap() > 0.0);
    }

    #[test]
    fn trigger_latency_is_removed_before_the_datum() {
        // 20 ms at 5 and 10 mm/s: 0.1–0.2 mm of overshoot into each face.
        let origin = Vector3::new(10.0, 20.0, 30.0);
        let ts = synth_touches(origin, &[5.0, 10.0], 5, 0.02, 0.005, 33);
        let f = std::path::Path::new("probe.parquet");
        let a = analyse(&ts, &DatumConfig::default(), f).unwrap();
        assert!((a.latency_s["ae"] - 0.02).abs() < 1e-3, "{:?}", a.latency_s);
        let err = a.main.datum.p - origin;
        let m = err.dot(&(a.main.datum.cov.try_inverse().unwrap() * err));
        assert!(m < 16.3, "corrected datum error {err}");
        let raw = DatumConfig {
            correct_latency: false,
            ..DatumConfig::default()
        };
        let b = analyse(&ts, &raw, f).unwrap();
        // Uncorrected, the datum sits inside the block by ≈ v̄·L = 0.15 mm
        // on every axis (approaches along −axis).
        let e = b.main.datum.p - origin;
        assert!(e.iter().all(|x| (x + 0.15).abs() < 0.02), "{e}");
    }

    #[test]
    fn bad_faces_are_input_errors() {
        let origin = Vector3::zeros();
        let ts = synth_touches(origin, &[5.0], 1, 0.0, 0.001, 1);
        let cfg = DatumConfig::default();
        let f = std::path::Path::new("probe.parquet");
        // Fewer than 3 points on a face.
        let few: Vec<Touch> = ts
            .iter()
            .filter(|t| t.face != Face::Zx || t.point < 2)
            .cloned()
            .collect();
        let e = analyse(&few, &cfg, f).err().unwrap();
        let ie = e.downcast_ref::<InputError>().unwrap();
        assert!(
            ie.message.contains("at least 3") && ie.message.contains("zx"),
            "{ie}"
        );
        // Collinear: the yz face's points all on one line.
        let mut col = ts.clone();
        for t in col.iter_mut().filter(|t| t.face == Face::Yz) {
            t.p.z = t.p.y;
        }
        let e = analyse(&col, &cfg, f).err().unwrap();
        assert!(e.to_string().contains("collinear"), "{e}");
        // Nearly parallel: the zx face's points actually lie on a plane
        // tilted 88° towards xy.
        let mut par = ts.clone();
        let n = Vector3::new(
            0.0,
            (2.0f64).to_radians().sin(),
            (2.0f64).to_radians().cos(),
        );
        for t in par.iter_mut().filter(|t| t.face == Face::Zx) {
            // (x, z) in-plane positions kept; put the point on n·p = 0.
            let (x, z) = (t.p.x, t.p.z + 30.0);
            t.p = Vector3::new(x, -(n.z * z) / n.y, z);
        }
        let e = analyse(&par, &cfg, f).err().unwrap();
        assert!(e.to_string().contains("nearly parallel"), "{e}");
    }
}

//! `datum`: per face the thesis's OLS fit and an orthogonal (TLS) fit with
//! optional robust rejection and covariances, per square of 4 points and
//! over all points; the datum (the intersection of the three planes) with
//! its covariance propagated from the planes', the inter-face squareness,
//! and the thesis's error vector E = A·α and transition angles
//! (docs/models.md §1.3).
//!
//! planes.rs holds the plane algebra; datum/output.rs what the stage
//! writes (summary JSON and the `planes`/`datum` artifacts).

use crate::robot::tables::PROBE;
use crate::{bail, err};
use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use serde_json::Value;
use sparkout_pipeline::config_check::{Check, Section, SectionCheck};
use sparkout_pipeline::contracts::schema::AE;
use sparkout_pipeline::contracts::BatchBuilder;
use sparkout_pipeline::{
    InputError, Result, Stage, StageArgs, StageContext, StageOutput, StageSpec,
};
use statrs::distribution::{ChiSquared, ContinuousCDF};

use super::planes::{
    fit_ols, fit_tls, intersect, max_abs, rms, robust_keep, squareness, Datum, Face, FitError,
    OlsFit, Plane, TlsFit,
};
use super::repeatability::{latency, pooled_std_by_face};
use super::summary::{
    fin, DatumStandalone, GivenPlane, GivenSquareness, PlaneSquareness, Squareness,
};
use super::touches::{self, Touch};

mod output;
pub use output::*;

/// Which plane fit defines the datum.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PlaneFit {
    /// Orthogonal (total least squares): errors in every coordinate.
    Tls,
    /// The thesis's ordinary least squares along the face normal's axis.
    Ols,
}

/// Datum settings (`[robot.datum]`).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DatumConfig {
    /// Which fit defines the datum: TLS (default) or the thesis's OLS.
    pub fit: PlaneFit,
    pub robust: bool,
    pub reject_k: f64,
    /// Floor of the robust scale (mm), so exact data reject nothing.
    pub min_scale_mm: f64,
    pub max_condition: f64,
    pub collinear_ratio: f64,
    pub confidence: f64,
    /// Remove each method's trigger latency (estimated from ≥ 2 approach
    /// speeds, docs/models.md §1.1) from its touches before fitting: p − v·L·dir.
    pub correct_latency: bool,
    /// Touches the datum is fitted from ([`select_method`]).
    pub method: String,
}

impl Default for DatumConfig {
    fn default() -> Self {
        DatumConfig {
            fit: PlaneFit::Tls,
            robust: true,
            reject_k: 4.0,
            min_scale_mm: 0.0005,
            max_condition: 10.0,
            collinear_ratio: 1e-3,
            confidence: 0.95,
            correct_latency: true,
            method: "auto".to_string(),
        }
    }
}

impl Section for DatumConfig {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("fit", Check::OneOf(&["tls", "ols"])),
        ("reject_k", Check::Positive),
        ("min_scale_mm", Check::Positive),
        ("max_condition", Check::AtLeastOne),
        ("collinear_ratio", Check::Probability),
        ("confidence", Check::Probability),
        (
            "method",
            Check::OneOf(&["auto", "all", "ae", "electrical", "mechanical"]),
        ),
    ];
}

impl PlaneFit {
    pub fn as_str(self) -> &'static str {
        match self {
            PlaneFit::Tls => "tls",
            PlaneFit::Ols => "ols",
        }
    }
}

impl DatumConfig {
    pub fn use_tls(&self) -> bool {
        self.fit == PlaneFit::Tls
    }
}

/// Precision order of the probing methods (docs/models.md §1.1: AE 25–85 µm,
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

/// The thesis's matrix A (docs/models.md §1.3): rows are the planes' OLS
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
/// (docs/models.md §1.1: a touch registered L after contact at speed v overshoots
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
    let bad = |msg: String| -> crate::Error { InputError::new(file, msg).column("face").into() };
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
    let fits: [FaceFit; 3] = fits.try_into().map_err(|_| err!("three faces"))?;
    let planes = |tls: bool| [fits[0].plane(tls), fits[1].plane(tls), fits[2].plane(tls)];
    let main = datum_of(planes(cfg.use_tls()), cfg).map_err(|e| bad(e.0))?;
    let ols = datum_of(planes(!cfg.use_tls()), cfg).ok();
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
            let sfits: [FaceFit; 3] = sfits.try_into().map_err(|_| err!("three faces"))?;
            let d = datum_of(
                [
                    sfits[0].plane(cfg.use_tls()),
                    sfits[1].plane(cfg.use_tls()),
                    sfits[2].plane(cfg.use_tls()),
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

pub struct DatumStage;

const SPEC: StageSpec = StageSpec {
    name: "datum",
    version: 2,
    reads: &[],
    reads_artifacts: &["touches"],
    writes: &["planes", "datum"],
    reads_augmented_model: false,
    about: "face planes (thesis OLS + orthogonal TLS, robust), datum = intersection with covariance, squareness, E = A·α (docs/models.md §1.3)",
    config: SectionCheck::of::<DatumConfig>(),
};

impl Stage for DatumStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let cfg: &DatumConfig = ctx.section()?;
        let every = touches::require(ctx)?;
        let file = source_file(ctx, &every);
        let (all, method) = select_method(&every, &cfg.method, &file)?;
        let a = analyse(&all, cfg, &file)?;
        let s = summary(&all, &a, cfg, &method);
        Ok(StageOutput::typed(&s)?
            .with("planes", planes_batch(&a, cfg.use_tls()))
            .with("datum", datum_batch(&a, cfg.use_tls())))
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
        err!("stage datum: give --run DIR, or --planes \"a,b,c,d;a,b,c,d;a,b,c,d\"")
    })?;
    let parse = |s: &str, n: usize, what: &str| -> Result<Vec<f64>> {
        let v: Vec<f64> = s
            .split(',')
            .map(|x| x.trim().parse::<f64>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| err!("stage datum: {what} `{s}` must be {n} comma-separated numbers"))?;
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
                .map_err(|e| err!("stage datum: {e}"))?,
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
                .ok_or_else(|| err!("stage datum: --max-condition must be a number ≥ 1"))?,
            None => DatumConfig::default().max_condition,
        },
        ..DatumConfig::default()
    };
    let d = datum_of(
        [&planes[order[0]], &planes[order[1]], &planes[order[2]]],
        &cfg,
    )
    .map_err(|e| err!("stage datum: {e}"))?;
    let mut pj = std::collections::BTreeMap::new();
    for (k, &i) in order.iter().enumerate() {
        let p = &planes[i];
        let label = if distinct {
            faces[i].label().to_string()
        } else {
            format!("p{}", k + 1)
        };
        let n = [p.n[0], p.n[1], p.n[2]];
        let o = GivenPlane {
            normal: n,
            d: p.d,
            tls_normal: n,
            tls_d: p.d,
            ols: distinct.then(|| ols_form(faces[i], p)),
        };
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
        _ => None,
    };
    let sq = if distinct {
        GivenSquareness::Faces(Squareness::new(&d.squareness))
    } else {
        GivenSquareness::Planes(PlaneSquareness {
            p1_p2: fin(d.squareness[0]),
            p2_p3: fin(d.squareness[1]),
            p3_p1: fin(d.squareness[2]),
        })
    };
    Ok(serde_json::to_value(DatumStandalone {
        planes: pj,
        datum_mm: v3(&d.datum.p),
        datum_cov_mm2: None,
        condition: d.datum.condition,
        squareness_rad: sq,
        error_vector_mm: error_vector,
    })?)
}

#[cfg(test)]
mod tests;

//! What `datum` writes: summary.json's datum section (planes, datum,
//! squareness, transition angles) and the `planes` and `datum` artifacts.

use std::collections::BTreeMap;

use super::*;
use crate::robot::summary::{
    fin, fin_opt, AxisTriple, DatumSummary, Ellipsoid, OtherFit, PlaneSummary, RejectedTouch,
    SquareDatum, SquarePlane, Squareness,
};

pub(super) fn m3(m: &Matrix3<f64>) -> Option<[[f64; 3]; 3]> {
    if !m.iter().all(|x| x.is_finite()) {
        return None;
    }
    Some([
        [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
        [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
        [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
    ])
}

pub(super) fn v3(v: &Vector3<f64>) -> Option<[f64; 3]> {
    v.iter().all(|x| x.is_finite()).then(|| [v[0], v[1], v[2]])
}

/// The square roots of a covariance's diagonal (`None` where undefined).
fn sigma3(c: &Matrix3<f64>) -> [Option<f64>; 3] {
    [0, 1, 2].map(|i| fin(c[(i, i)].sqrt()))
}

/// Transition angles (docs/models.md §1.3: ±(atan(ΔY/Lx) + atan(ΔZ/Lx))), read as:
/// for each face, the two other faces' repeatability σ over the spacing L of
/// the detection points on this face (the side of its outer square of
/// nominal points).
pub(super) fn transition_angles(all: &[Touch], a: &DatumAnalysis) -> BTreeMap<String, Option<f64>> {
    let mut m = BTreeMap::new();
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
            (Some(p), Some(q)) if l > 0.0 => fin((p / l).atan() + (q / l).atan()),
            _ => None,
        };
        m.insert(face.label().into(), v);
    }
    m
}

pub(super) fn plane_summary(
    f: &FaceFit,
    use_tls: bool,
    all: &[Touch],
    idx: &[usize],
) -> PlaneSummary {
    let r = if use_tls {
        &f.tls.residuals
    } else {
        &f.ols.residuals
    };
    let rejected: Vec<RejectedTouch> = f
        .rejected
        .iter()
        .map(|&k| {
            let t = &all[idx[k]];
            RejectedTouch {
                point: t.point,
                trial: t.trial,
                method: t.method.clone(),
                approach_mm_s: t.approach_mm_s,
                distance_mm: f.tls.plane.distance(&t.p),
            }
        })
        .collect();
    PlaneSummary {
        ols: f.ols.b.map(fin),
        tls_normal: [0, 1, 2].map(|i| fin(f.tls.plane.n[i])),
        tls_d: f.tls.plane.d,
        residual_rms_mm: fin(rms(r)),
        residual_max_mm: fin(max_abs(r)),
        ols_residual_rms_mm: fin(rms(&f.ols.residuals)),
        tls_residual_rms_mm: fin(rms(&f.tls.residuals)),
        n: f.kept.len() + f.rejected.len(),
        n_rejected: f.rejected.len(),
        robust_scale_mm: fin_opt(f.robust_scale_mm),
        rejected,
    }
}

pub(super) fn other_fit(d: &DatumResult) -> OtherFit {
    let c = &d.datum.cov;
    OtherFit {
        datum_mm: v3(&d.datum.p),
        datum_cov_mm2: m3(c),
        datum_sigma_mm: sigma3(c),
        condition: d.datum.condition,
        squareness_rad: Squareness::new(&d.squareness),
    }
}

/// `datum.json` of a run; `touch_method` is the method the touches were
/// selected by.
pub fn summary(
    all: &[Touch],
    a: &DatumAnalysis,
    cfg: &DatumConfig,
    touch_method: &str,
) -> DatumSummary {
    let mut planes = BTreeMap::new();
    for f in &a.fits {
        planes.insert(
            f.face.label().into(),
            plane_summary(f, cfg.use_tls(), all, &a.face_touches[f.face.index()]),
        );
    }
    let b = [a.fits[0].ols.b, a.fits[1].ols.b, a.fits[2].ols.b];
    let alpha_x = a.alpha_mm[Face::Yz.index()];
    let alpha_y = a.alpha_mm[Face::Zx.index()];
    let alpha_z = a.alpha_mm[Face::Xy.index()];
    let error_vector = match (alpha_x, alpha_y, alpha_z) {
        (Some(x), Some(y), Some(z)) => v3(&(thesis_a(b) * Vector3::new(x, y, z))),
        _ => None,
    };
    let m = &a.main;
    let by_square: Vec<SquareDatum> = a
        .squares
        .iter()
        .map(|(sq, fits, d)| {
            let planes: BTreeMap<String, SquarePlane> = fits
                .iter()
                .map(|f| {
                    let r = if cfg.use_tls() {
                        &f.tls.residuals
                    } else {
                        &f.ols.residuals
                    };
                    (
                        f.face.label().to_string(),
                        SquarePlane {
                            ols: f.ols.b.map(fin),
                            residual_rms_mm: fin(rms(r)),
                            n: f.kept.len(),
                        },
                    )
                })
                .collect();
            SquareDatum {
                square: SQUARES[*sq].into(),
                planes,
                datum_mm: d.as_ref().and_then(|d| v3(&d.datum.p)),
                datum_sigma_mm: d.as_ref().map(|d| sigma3(&d.datum.cov)),
            }
        })
        .collect();
    DatumSummary {
        fit: if cfg.use_tls() { "tls" } else { "ols" }.into(),
        planes,
        datum_mm: v3(&m.datum.p),
        datum_cov_mm2: m3(&m.datum.cov),
        datum_sigma_mm: sigma3(&m.datum.cov),
        datum_ellipsoid_mm: Ellipsoid {
            confidence: cfg.confidence,
            semi_axes_mm: m.ellipsoid_mm.map(fin),
            axes: [0, 1, 2].map(|i| v3(&m.ellipsoid_axes[i])),
        },
        condition: m.datum.condition,
        squareness_rad: Squareness::new(&m.squareness),
        error_vector_mm: error_vector,
        alpha_mm: AxisTriple {
            x: fin_opt(alpha_x),
            y: fin_opt(alpha_y),
            z: fin_opt(alpha_z),
        },
        transition_angles_rad: transition_angles(all, a),
        datum_other_fit: a.ols.as_ref().map(other_fit),
        by_square,
        latency_corrected_s: a
            .latency_s
            .iter()
            .map(|(k, v)| (k.clone(), fin(*v)))
            .collect(),
        touch_method: touch_method.into(),
    }
}

pub(super) const COV_NAMES: [(usize, usize, &str); 10] = [
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
pub(super) fn planes_batch(a: &DatumAnalysis, use_tls: bool) -> arrow::record_batch::RecordBatch {
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
    // A face of exactly 3 points fits its plane with no residual degree of
    // freedom: the covariance is undefined, written as null (never NaN).
    for (i, j, name) in COV_NAMES {
        b = b.opt_f64(
            name,
            rows.iter()
                .map(|r| Some(plane(r).cov[(i, j)]).filter(|v| v.is_finite()))
                .collect(),
        );
    }
    b.build()
}

/// The `datum` artifact: one row per scope × fit.
pub(super) fn datum_batch(a: &DatumAnalysis, use_tls: bool) -> arrow::record_batch::RecordBatch {
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
    // Undefined (no residual degree of freedom, e.g. 3 points per face):
    // null, never NaN.
    let c = |i: usize, j: usize| {
        rows.iter()
            .map(|r| Some(r.2.datum.cov[(i, j)]).filter(|v| v.is_finite()))
            .collect::<Vec<_>>()
    };
    let ell = |k: usize| {
        rows.iter()
            .map(|r| Some(r.2.ellipsoid_mm[k]).filter(|v| v.is_finite()))
            .collect::<Vec<_>>()
    };
    BatchBuilder::new()
        .str("scope", &rows.iter().map(|r| r.0).collect::<Vec<_>>())
        .str("fit", &rows.iter().map(|r| r.1).collect::<Vec<_>>())
        .f64("x_mm", rows.iter().map(|r| r.2.datum.p[0]).collect())
        .f64("y_mm", rows.iter().map(|r| r.2.datum.p[1]).collect())
        .f64("z_mm", rows.iter().map(|r| r.2.datum.p[2]).collect())
        .opt_f64("cov_xx_mm2", c(0, 0))
        .opt_f64("cov_xy_mm2", c(0, 1))
        .opt_f64("cov_xz_mm2", c(0, 2))
        .opt_f64("cov_yy_mm2", c(1, 1))
        .opt_f64("cov_yz_mm2", c(1, 2))
        .opt_f64("cov_zz_mm2", c(2, 2))
        .opt_f64("ellipsoid_a_mm", ell(0))
        .opt_f64("ellipsoid_b_mm", ell(1))
        .opt_f64("ellipsoid_c_mm", ell(2))
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

//! What `datum` writes: summary.json's datum section (planes, datum,
//! squareness, transition angles) and the `planes` and `datum` artifacts.

use super::*;

pub(super) fn m3(m: &Matrix3<f64>) -> Value {
    if !m.iter().all(|x| x.is_finite()) {
        return Value::Null;
    }
    json!([
        [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
        [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
        [m[(2, 0)], m[(2, 1)], m[(2, 2)]]
    ])
}

pub(super) fn v3(v: &Vector3<f64>) -> Value {
    if v.iter().all(|x| x.is_finite()) {
        json!([v[0], v[1], v[2]])
    } else {
        Value::Null
    }
}

pub(super) fn sq_json(sq: &[f64; 3]) -> Value {
    json!({"xy_yz": json_f64(sq[0]), "yz_zx": json_f64(sq[1]), "zx_xy": json_f64(sq[2])})
}

/// Transition angles (docs/models.md §1.3: ±(atan(ΔY/Lx) + atan(ΔZ/Lx))), read as:
/// for each face, the two other faces' repeatability σ over the spacing L of
/// the detection points on this face (the side of its outer square of
/// nominal points).
pub(super) fn transition_angles(all: &[Touch], a: &DatumAnalysis) -> Value {
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

pub(super) fn plane_json(f: &FaceFit, use_tls: bool, all: &[Touch], idx: &[usize]) -> Value {
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

pub(super) fn datum_json(d: &DatumResult) -> Value {
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
            plane_json(f, cfg.use_tls(), all, &a.face_touches[f.face.index()]),
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
                        json!({"ols": f.ols.b, "residual_rms_mm": json_f64(rms(if cfg.use_tls() { &f.tls.residuals } else { &f.ols.residuals })), "n": f.kept.len()}),
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
        "fit": if cfg.use_tls() { "tls" } else { "ols" },
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

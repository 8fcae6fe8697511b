//! Report sections of a mill run: the identification (numbers, squareness,
//! tracker frame), the identified error functions, the volumetric error map
//! before and after compensation, and the residuals (docs/models.md §5).

use sparkout_pipeline::contracts::{batch_f64, batch_i32};
use sparkout_pipeline::report::svg::{heat, shared_vmax, xy_chart, Heat, Mark, Series};
use sparkout_pipeline::report::{fmt_fixed, fmt_um, table, warning, Verdict};
use sparkout_pipeline::{ArtifactStore, ReportSection, Run};

use super::chain::{AXES, KINDS};
use super::summary::KinematicsSummary;
use crate::typed_summary::finite;

/// A length in mm as µm; `None` (not computed) and NaN print as such.
fn um(v: Option<f64>) -> String {
    fmt_um(v.and_then(finite), 2)
}

fn urad(v: f64) -> String {
    fmt_fixed(finite(v).map(|x| x * 1e6), 2)
}

fn identification(s: &KinematicsSummary) -> ReportSection {
    let mut html = table(
        &["quantity", "value"],
        &[
            vec!["parameters".into(), s.params.to_string()],
            vec![
                "points (identification / held out)".into(),
                format!("{} / {}", s.points_identification, s.points_holdout),
            ],
            vec!["fit RMS (µm, 3-D)".into(), um(s.fit_rms_mm)],
            vec!["held-out RMS (µm, 3-D)".into(), um(s.holdout_rms_mm)],
            vec![
                "residual σ per coordinate (µm)".into(),
                um(Some(s.sigma_mm)),
            ],
            vec![
                "volumetric error before (µm RMS)".into(),
                um(s.before_rms_mm),
            ],
            vec![
                "volumetric error after table compensation (µm RMS)".into(),
                um(s.after_rms_mm),
            ],
            vec![
                "degree / tools".into(),
                format!("{} / {}", s.degree, s.tools),
            ],
            vec![
                "rcond (scaled Jacobian)".into(),
                // Two significant digits, never scientific notation.
                sparkout_pipeline::units::format::plain_number(s.rcond, 2),
            ],
            vec![
                "solver".into(),
                format!("{} evaluations, {}", s.evaluations, s.termination),
            ],
        ],
    );
    for w in &s.warnings {
        html.push_str(&warning(w));
    }
    // Compensation exists to shrink the volumetric error.
    if let (Some(b), Some(a)) = (
        s.before_rms_mm.and_then(finite),
        s.after_rms_mm.and_then(finite),
    ) {
        if a > b {
            html.push_str(&warning(&format!(
                "the compensation table makes the volumetric error worse: {:.1} → {:.1} µm RMS. Do not load it; check the tracker data and the identification.",
                b * 1e3,
                a * 1e3
            )));
        }
    }
    let rows: Vec<Vec<String>> = super::chain::SQUARENESS
        .iter()
        .map(|k| {
            let sq = s.squareness.get(*k);
            vec![
                k.to_string(),
                sq.map_or_else(|| urad(f64::NAN), |q| urad(q.value_rad)),
                sq.map_or_else(|| urad(f64::NAN), |q| urad(q.sigma_rad)),
            ]
        })
        .collect();
    html.push_str(&table(&["squareness", "value (µrad)", "σ (µrad)"], &rows));
    let gauge: Vec<String> = s
        .gauge
        .iter()
        .map(|g| format!("<li>{}</li>", sparkout_pipeline::report::esc(g)))
        .collect();
    html.push_str(&format!(
        "<p class=\"note\">Fixed gauge freedoms (not identifiable from any tracker data, held at zero):</p><ul class=\"note\">{}</ul>",
        gauge.join("")
    ));
    ReportSection {
        title: "Volumetric identification (21 errors + tracker frame)".into(),
        html,
    }
}

/// Per error function: largest |value| over the travel and its largest σ.
fn function_table(s: &KinematicsSummary) -> String {
    let rows: Vec<Vec<String>> = s
        .functions
        .iter()
        .map(|(name, v)| {
            let rot = v.unit == "rad";
            let fmt = |x: f64| if rot { urad(x) } else { um(Some(x)) };
            vec![
                name.clone(),
                if rot { "µrad" } else { "µm" }.to_string(),
                if v.fixed {
                    "held at 0".into()
                } else {
                    fmt(v.max_abs)
                },
                fmt(v.max_sigma),
            ]
        })
        .collect();
    table(
        &["function", "unit", "max |value| over travel", "max σ"],
        &rows,
    )
}

fn functions(a: &ArtifactStore) -> Option<ReportSection> {
    let t = a.get("compensation_table").ok()??;
    let axis = sparkout_pipeline::contracts::batch_str(&t, "axis").ok()?;
    let pos = batch_f64(&t, "pos_mm").ok()?;
    let cols = ["dx_mm", "dy_mm", "dz_mm", "ex_rad", "ey_rad", "ez_rad"];
    let vals: Vec<&[f64]> = cols.iter().filter_map(|c| batch_f64(&t, c).ok()).collect();
    if vals.len() != 6 {
        return None;
    }
    let mut html = crate::typed_summary::read::<KinematicsSummary>(a, "kinematics")
        .map(|s| function_table(&s))
        .unwrap_or_default();
    for ax in AXES {
        for (range, unit, scale) in [(0..3, "µm", 1e3), (3..6, "µrad", 1e6)] {
            let series: Vec<Vec<(f64, f64)>> = range
                .clone()
                .map(|k| {
                    (0..pos.len())
                        .filter(|&i| axis[i] == ax)
                        .map(|i| (pos[i], vals[k][i] * scale))
                        .collect()
                })
                .collect();
            let names: Vec<String> = range
                .clone()
                .map(|k| format!("{}_{ax}", KINDS[k]))
                .collect();
            let s: Vec<Series> = series
                .iter()
                .zip(&names)
                .map(|(p, n)| Series {
                    name: n,
                    points: p,
                    mark: Mark::Line,
                })
                .collect();
            html.push_str(&xy_chart(
                &format!(
                    "{} error functions of {}",
                    if unit == "µm" {
                        "Translational"
                    } else {
                        "Rotational"
                    },
                    ax.to_uppercase()
                ),
                &format!("{ax} (mm)"),
                &format!("error ({unit})"),
                &s,
            ));
        }
    }
    Some(ReportSection {
        title: "Error functions (compensation table)".into(),
        html,
    })
}

fn map(a: &ArtifactStore) -> Option<ReportSection> {
    let m = a.get("volumetric_map").ok()??;
    let (x, y, z) = (
        batch_f64(&m, "x_mm").ok()?,
        batch_f64(&m, "y_mm").ok()?,
        batch_f64(&m, "z_mm").ok()?,
    );
    let before = batch_f64(&m, "before_mm").ok()?;
    // After compensation is what the tracker measured less the table's
    // correction at each tracker point (|d − c|), spread over the map's
    // grid. The map's own `after_mm` is the model less the table built
    // from that model — zero by construction, so it cannot show what the
    // table leaves behind.
    let measured = measured_after(a);
    let after: Vec<f64> = match &measured {
        Some(pts) => (0..x.len()).map(|i| idw(pts, [x[i], y[i], z[i]])).collect(),
        None => vec![f64::NAN; x.len()],
    };
    let mut zs: Vec<f64> = z.to_vec();
    zs.sort_by(f64::total_cmp);
    zs.dedup();
    let mut html = String::new();
    // Bottom, middle and top Z levels.
    let levels = [zs[0], zs[zs.len() / 2], zs[zs.len() - 1]];
    for zl in levels {
        let pick = |v: &[f64]| -> Vec<(f64, f64, f64)> {
            (0..x.len())
                .filter(|&i| z[i] == zl)
                .map(|i| (x[i], y[i], v[i] * 1e3))
                .collect()
        };
        // Before and after on one colour scale (per level).
        let (b, af) = (pick(before), pick(&after));
        let vmax = shared_vmax([b.as_slice(), af.as_slice()]);
        for (title, c) in [
            (
                format!("|volumetric error| before compensation, z = {zl:.0} mm"),
                &b,
            ),
            (
                format!("|volumetric error| after table compensation (measured), z = {zl:.0} mm"),
                &af,
            ),
        ] {
            let mut h = Heat::new(&title, c, "µm");
            h.vmax = Some(vmax);
            html.push_str(&heat(&h));
        }
    }
    html.insert_str(
        0,
        "<p>Before: the identified model's volumetric error. After: the measured residual |d − c| at the tracker points (measured deviation less the table's correction), interpolated onto the grid by inverse distance from the 8 nearest points — the table's effect as measured, not as the model would have it.</p>",
    );
    Some(ReportSection {
        title: "Volumetric error map before and after compensation".into(),
        html,
    })
}

/// Tracker points (x, y, z, |d − c| mm) after table compensation.
fn measured_after(a: &ArtifactStore) -> Option<Vec<([f64; 3], f64)>> {
    let r = a.get("tracker_residuals").ok()??;
    let (x, y, z, v) = (
        batch_f64(&r, "x_mm").ok()?,
        batch_f64(&r, "y_mm").ok()?,
        batch_f64(&r, "z_mm").ok()?,
        batch_f64(&r, "after_mm").ok()?,
    );
    let pts: Vec<([f64; 3], f64)> = (0..x.len())
        .filter(|&i| v[i].is_finite())
        .map(|i| ([x[i], y[i], z[i]], v[i]))
        .collect();
    (!pts.is_empty()).then_some(pts)
}

/// Inverse-distance-squared mean of the 8 points nearest `q` (a point
/// on a tracker position takes its value).
fn idw(pts: &[([f64; 3], f64)], q: [f64; 3]) -> f64 {
    let mut d: Vec<(f64, f64)> = pts
        .iter()
        .map(|(p, v)| {
            let d2 = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2);
            (d2, *v)
        })
        .collect();
    d.sort_by(|a, b| a.0.total_cmp(&b.0));
    d.truncate(8);
    if let Some(&(_, v)) = d.first().filter(|p| p.0 < 1e-12) {
        return v;
    }
    let (num, den) = d
        .iter()
        .fold((0.0, 0.0), |(n, w), (d2, v)| (n + v / d2, w + 1.0 / d2));
    num / den
}

/// The verdict: RMS volumetric error before → after table compensation,
/// both measured at the tracker points, against the tolerance.
pub fn verdicts(run: &Run, a: &ArtifactStore) -> Vec<Verdict> {
    let Some(s) = crate::typed_summary::read::<KinematicsSummary>(a, "kinematics") else {
        return Vec::new();
    };
    let um = |v: Option<f64>| v.map(|v| v * 1e3).unwrap_or(f64::NAN);
    vec![Verdict::new(
        "volumetric error (RMS, measured)",
        "µm",
        "after table compensation",
        um(s.after_rms_mm),
    )
    .before("before compensation", um(s.before_rms_mm))
    .limit("volumetric_um", run.tolerance("volumetric_um"))]
}

fn residuals(a: &ArtifactStore) -> Option<ReportSection> {
    let r = a.get("tracker_residuals").ok()??;
    let hold = batch_i32(&r, "holdout").ok()?;
    let res = batch_f64(&r, "residual_mm").ok()?;
    let before: Vec<f64> = (0..r.num_rows())
        .map(|i| {
            let d = |c: &str| batch_f64(&r, c).map(|v| v[i]).unwrap_or(f64::NAN);
            (d("measured_dx_mm").powi(2)
                + d("measured_dy_mm").powi(2)
                + d("measured_dz_mm").powi(2))
            .sqrt()
        })
        .collect();
    let pts = |h: i32, v: &[f64]| -> Vec<(f64, f64)> {
        (0..v.len())
            .filter(|&i| hold[i] == h)
            .map(|i| (i as f64, v[i] * 1e3))
            .collect()
    };
    let (fi, ho, bf) = (pts(0, res), pts(1, res), pts(0, &before));
    let mut html = xy_chart(
        "3-D residual per point (measurement order)",
        "point (row)",
        "µm",
        &[
            Series {
                name: "identification",
                points: &fi,
                mark: Mark::Points,
            },
            Series {
                name: "held out",
                points: &ho,
                mark: Mark::Points,
            },
        ],
    );
    html.push_str(&xy_chart(
        "Measured volumetric error (before compensation), identification points",
        "point (row)",
        "µm",
        &[Series {
            name: "|d|",
            points: &bf,
            mark: Mark::Points,
        }],
    ));
    Some(ReportSection {
        title: "Residuals".into(),
        html,
    })
}

pub fn sections(_run: &Run, artifacts: &ArtifactStore) -> Vec<ReportSection> {
    let mut out = Vec::new();
    if let Some(s) = crate::typed_summary::read::<KinematicsSummary>(artifacts, "kinematics") {
        out.push(identification(&s));
    }
    out.extend(functions(artifacts));
    out.extend(map(artifacts));
    out.extend(residuals(artifacts));
    out
}

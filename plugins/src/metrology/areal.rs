//! Areal height parameters (ISO 25178-2, field parameters) of a map or a
//! point set, after form removal by a least-squares plane and by a
//! second-order polynomial surface ("curvature" detrend).
//!
//! With r the residuals from the fitted form (mean zero: the fit has a
//! constant term) over the N valid points:
//! Sq = √(Σr²/N), Sa = Σ|r|/N, Sp = max r, Sv = −min r, Sz = Sp + Sv,
//! Ssk = Σr³/N / Sq³, Sku = Σr⁴/N / Sq⁴.
//!
//! Means are plain means over the points, not area-weighted: on a regular
//! grid every point stands for the same area, so that is the standard's
//! definition; on scattered points a dense cluster counts for more, and the
//! output says so rather than guessing a tessellation.

use crate::{bail, err};
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use sparkout_pipeline::Result;

use super::spikes::SpikeReport;
use super::{console_length, spikes, Figure, OrWhy};

/// Which form is removed before the heights are evaluated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Form {
    /// z = c₀ + c₁x + c₂y.
    Plane,
    /// z = c₀ + c₁x + c₂y + c₃x² + c₄xy + c₅y².
    SecondOrder,
}

/// Residuals of z from the least-squares form over the points.
///
/// Solved by Householder QR on centred, scaled coordinates (never the
/// normal equations: squaring the condition number would cost the digits
/// that make a nm texture on a mm form).
pub fn residuals(x: &[f64], y: &[f64], z: &[f64], form: Form) -> Result<Vec<f64>> {
    let n = z.len();
    let cols = match form {
        Form::Plane => 3,
        Form::SecondOrder => 6,
    };
    if n < cols {
        bail!(
            "{n} points; removing a {} needs at least {cols}",
            form_name(form)
        );
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / n as f64;
    let (mx, my, mz) = (mean(x), mean(y), mean(z));
    let half_range = |v: &[f64], m: f64| {
        let s = v.iter().fold(0.0_f64, |a, &t| a.max((t - m).abs()));
        if s > 0.0 {
            s
        } else {
            1.0
        }
    };
    let (sx, sy) = (half_range(x, mx), half_range(y, my));
    let a = DMatrix::from_fn(n, cols, |i, j| {
        let (u, v) = ((x[i] - mx) / sx, (y[i] - my) / sy);
        match j {
            0 => 1.0,
            1 => u,
            2 => v,
            3 => u * u,
            4 => u * v,
            _ => v * v,
        }
    });
    let b = DVector::from_iterator(n, z.iter().map(|&t| t - mz));
    let qr = a.clone().qr();
    let r = qr.r();
    let qtb = qr.q().transpose() * &b;
    // A rank-deficient design (all points on a line, or a single row of a
    // grid for the second order) has a zero on R's diagonal.
    let scale = r.diagonal().iter().fold(0.0_f64, |m, d| m.max(d.abs()));
    if r.diagonal().iter().any(|d| d.abs() <= 1e-12 * scale) {
        bail!(
            "the points do not determine a {} (they lie on a line, or on too few rows/columns)",
            form_name(form)
        );
    }
    let c = r
        .solve_upper_triangular(&qtb)
        .ok_or_else(|| err!("{}: singular fit", form_name(form)))?;
    let fit = a * c;
    Ok((0..n).map(|i| (z[i] - mz) - fit[i]).collect())
}

fn form_name(form: Form) -> &'static str {
    match form {
        Form::Plane => "least-squares plane",
        Form::SecondOrder => "second-order polynomial surface",
    }
}

/// Height parameters of residuals (mm; Ssk, Sku dimensionless).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Heights {
    pub sq: f64,
    pub sa: f64,
    pub sz: f64,
    pub sp: f64,
    pub sv: f64,
    /// NaN when Sq is zero to rounding (the shape of nothing is undefined).
    pub ssk: f64,
    pub sku: f64,
}

/// Plain-mean height parameters of residuals (see the module notes).
pub fn heights(r: &[f64], scale: f64) -> Heights {
    let n = r.len() as f64;
    let m = |p: i32| r.iter().map(|v| v.powi(p)).sum::<f64>() / n;
    let sq = m(2).sqrt();
    let sa = r.iter().map(|v| v.abs()).sum::<f64>() / n;
    let sp = r.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let sv = -r.iter().copied().fold(f64::INFINITY, f64::min);
    // Residuals of an exact plane are rounding noise: their skewness is
    // noise too, so it is not reported.
    let flat = sq <= 64.0 * f64::EPSILON * scale.max(f64::MIN_POSITIVE);
    let (ssk, sku) = if flat {
        (f64::NAN, f64::NAN)
    } else {
        (m(3) / sq.powi(3), m(4) / sq.powi(4))
    };
    Heights {
        sq,
        sa,
        sz: sp + sv,
        sp,
        sv,
        ssk,
        sku,
    }
}

/// [`Heights`] as figures with their units, as the JSON holds them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HeightFigures {
    #[serde(rename = "Sq")]
    pub sq: Figure,
    #[serde(rename = "Sa")]
    pub sa: Figure,
    #[serde(rename = "Sz")]
    pub sz: Figure,
    #[serde(rename = "Sp")]
    pub sp: Figure,
    #[serde(rename = "Sv")]
    pub sv: Figure,
    #[serde(rename = "Ssk")]
    pub ssk: Figure,
    #[serde(rename = "Sku")]
    pub sku: Figure,
}

impl Heights {
    pub fn figures(&self) -> HeightFigures {
        HeightFigures {
            sq: Figure::mm(self.sq),
            sa: Figure::mm(self.sa),
            sz: Figure::mm(self.sz),
            sp: Figure::mm(self.sp),
            sv: Figure::mm(self.sv),
            ssk: Figure::ratio(self.ssk),
            sku: Figure::ratio(self.sku),
        }
    }
}

/// The evaluation area of an `areal` object.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvaluationArea {
    pub x_min: Figure,
    pub x_max: Figure,
    pub x_extent: Figure,
    pub y_min: Figure,
    pub y_max: Figure,
    pub y_extent: Figure,
    pub n_valid: usize,
    /// `null` when the reader left unmeasured cells out before counting.
    pub n_not_measured: Option<usize>,
    /// Why `n_not_measured` is unknown.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub not_measured: Option<String>,
}

/// The `areal` object of `flatness --surface`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ArealReport {
    pub standard: String,
    pub evaluation_area: EvaluationArea,
    pub filter: String,
    pub weighting: String,
    pub least_squares_plane: HeightFigures,
    pub second_order: OrWhy<HeightFigures>,
    pub spikes: SpikeReport,
}

/// The largest |z| (the scale rounding noise is relative to).
fn scale_of(z: &[f64]) -> f64 {
    z.iter().fold(0.0_f64, |a, v| a.max(v.abs()))
}

/// [`surface_report`] of points a reader has already cleared of unmeasured
/// cells (the Parquet surface reader leaves null/NaN grid cells out): the
/// count of those is not known here, and the output says so.
pub fn report_read_points(x: &[f64], y: &[f64], z: &[f64]) -> Result<serde_json::Value> {
    Ok(serde_json::to_value(read_points_report(x, y, z)?)?)
}

/// [`report_read_points`] as its type.
pub fn read_points_report(x: &[f64], y: &[f64], z: &[f64]) -> Result<ArealReport> {
    let mut v = surface_report(x, y, z)?;
    v.evaluation_area.n_not_measured = None;
    v.evaluation_area.not_measured = Some(
        "null or NaN cells of a gridded map are left out by the surface reader before these figures; their count is not known here".into(),
    );
    Ok(v)
}

/// The `areal` object of `flatness --surface`: evaluation area, heights
/// after both forms, the spike report. Points with a non-finite z are not
/// measured: counted and left out; a non-finite x or y is an error.
pub fn surface_report(x: &[f64], y: &[f64], z: &[f64]) -> Result<ArealReport> {
    if let Some(i) = (0..x.len()).find(|&i| !(x[i].is_finite() && y[i].is_finite())) {
        bail!("point {i}: x or y is not a finite number");
    }
    let keep: Vec<usize> = (0..z.len()).filter(|&i| z[i].is_finite()).collect();
    let pick = |v: &[f64]| keep.iter().map(|&i| v[i]).collect::<Vec<f64>>();
    let (x, y, z, missing) = (pick(x), pick(y), pick(z), z.len() - keep.len());
    let scale = scale_of(&z);
    let plane = residuals(&x, &y, &z, Form::Plane)?;
    let second = match residuals(&x, &y, &z, Form::SecondOrder) {
        Ok(r) => OrWhy::Computed(heights(&r, scale).figures()),
        Err(e) => OrWhy::NotComputed {
            not_computed: e.to_string(),
        },
    };
    let range = |v: &[f64]| {
        v.iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &t| {
                (lo.min(t), hi.max(t))
            })
    };
    let ((x0, x1), (y0, y1)) = (range(&x), range(&y));
    Ok(ArealReport {
        standard: "ISO 25178-2 height parameters; flatness ISO 12781".into(),
        evaluation_area: EvaluationArea {
            x_min: Figure::mm(x0),
            x_max: Figure::mm(x1),
            x_extent: Figure::mm(x1 - x0),
            y_min: Figure::mm(y0),
            y_max: Figure::mm(y1),
            y_extent: Figure::mm(y1 - y0),
            n_valid: z.len(),
            n_not_measured: Some(missing),
            not_measured: None,
        },
        filter: "none: no S- or L-filter; only the form is removed (least-squares plane, or second-order polynomial surface)".into(),
        weighting: "plain means over the valid points, not area-weighted (exact on a regular grid; on scattered points dense regions count more)".into(),
        least_squares_plane: heights(&plane, scale).figures(),
        second_order: second,
        spikes: spikes::report(&x, &y, &z, &plane)?,
    })
}

/// Console lines of an `areal` object (lengths through
/// [`console_length`]).
pub fn console(a: &ArealReport) -> String {
    let mut s = String::new();
    let area = &a.evaluation_area;
    s += &format!(
        "evaluation area {} × {}, {} valid points{}; filter: none (form removal only); plain means\n",
        console_length(area.x_extent.value),
        console_length(area.y_extent.value),
        area.n_valid,
        match area.n_not_measured {
            Some(k) => format!(" ({k} not measured, left out)"),
            None => " (unmeasured cells left out by the reader)".into(),
        },
    );
    for (h, title) in [
        (
            &OrWhy::Computed(a.least_squares_plane.clone()),
            "after LS plane  ",
        ),
        (&a.second_order, "after 2nd order "),
    ] {
        let h = match h {
            OrWhy::Computed(h) => h,
            OrWhy::NotComputed { not_computed } => {
                s += &format!("{title} not computed: {not_computed}\n");
                continue;
            }
        };
        let l = |f: &Figure| console_length(f.value);
        let r = |f: &Figure| {
            if f.value.is_finite() {
                format!("{:.3}", f.value)
            } else {
                "n/a".into()
            }
        };
        s += &format!(
            "{title} Sq {}  Sa {}  Sz {}  Sp {}  Sv {}  Ssk {}  Sku {}\n",
            l(&h.sq),
            l(&h.sa),
            l(&h.sz),
            l(&h.sp),
            l(&h.sv),
            r(&h.ssk),
            r(&h.sku)
        );
    }
    s += &spikes::console(&a.spikes);
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tilted_cosine_after_plane_removal_has_the_cosine_s_figures() {
        // z = tilt + A cos(2πu) on a grid symmetric about u = 0 over whole
        // periods: Σu·cos = 0, so the plane takes only the tilt, and the
        // discrete means are exact: Sq = A/√2, Sz = 2A, Ssk = 0, Sku = 3/2.
        let (mut x, mut y, mut z) = (vec![], vec![], vec![]);
        let a = 1e-3;
        let n = 400;
        for i in 0..n {
            for j in 0..5 {
                let u = -2.0 + 4.0 * (i as f64 + 0.5) / n as f64;
                x.push(u);
                y.push(j as f64);
                z.push(
                    0.2 + 0.01 * u - 0.003 * j as f64 + a * (2.0 * std::f64::consts::PI * u).cos(),
                );
            }
        }
        let r = residuals(&x, &y, &z, Form::Plane).unwrap();
        let h = heights(&r, scale_of(&z));
        assert!((h.sq - a / 2f64.sqrt()).abs() < 1e-12 * a, "{h:?}");
        assert!((h.sku - 1.5).abs() < 1e-9, "{h:?}");
        assert!(h.ssk.abs() < 1e-9, "{h:?}");
        // Midpoints miss the crests by half a step: 1 − cos(π/100) of A.
        assert!((h.sz - 2.0 * a).abs() < 1e-3 * a, "{h:?}");
        assert!((h.sz - (h.sp + h.sv)).abs() < 1e-18);
    }

    #[test]
    fn second_order_removes_a_paraboloid_exactly() {
        let (mut x, mut y, mut z) = (vec![], vec![], vec![]);
        for i in 0..20 {
            for j in 0..15 {
                let (u, v) = (i as f64 * 2.5, j as f64 * 3.0);
                x.push(u);
                y.push(v);
                z.push(1.0 + 1e-3 * u - 2e-3 * v + 4e-5 * u * u - 1e-5 * u * v + 3e-5 * v * v);
            }
        }
        let r = residuals(&x, &y, &z, Form::SecondOrder).unwrap();
        let h = heights(&r, scale_of(&z));
        assert!(h.sq < 1e-14, "{}", h.sq);
        assert!(
            h.ssk.is_nan(),
            "the shape of rounding noise is not reported"
        );
        // The plane leaves the curvature.
        let p = heights(&residuals(&x, &y, &z, Form::Plane).unwrap(), 1.0);
        assert!(p.sq > 1e-3);
    }

    #[test]
    fn points_on_a_line_are_refused_and_nan_heights_are_left_out() {
        let x = [0.0, 1.0, 2.0, 3.0];
        let y = [0.0, 1.0, 2.0, 3.0];
        assert!(residuals(&x, &y, &[0.0, 1.0, 0.0, 1.0], Form::Plane)
            .unwrap_err()
            .to_string()
            .contains("line"));
        let (mut x, mut y, mut z) = (vec![], vec![], vec![]);
        for i in 0..6 {
            for j in 0..6 {
                x.push(i as f64);
                y.push(j as f64);
                z.push(if (i + j) % 7 == 3 {
                    f64::NAN
                } else {
                    ((i * 7 + j * 3) % 5) as f64 * 1e-4
                });
            }
        }
        let a = surface_report(&x, &y, &z).unwrap();
        let missing = z.iter().filter(|v| v.is_nan()).count();
        assert_eq!(a.evaluation_area.n_not_measured, Some(missing));
        assert_eq!(a.evaluation_area.n_valid, 36 - missing);
        assert!(a.least_squares_plane.sq.value.is_finite());
        assert!(console(&a).contains("not measured"));
    }
}

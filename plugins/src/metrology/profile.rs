//! Profile parameters (ISO 21920-2) of a line profile z(x), on any x
//! spacing.
//!
//! Primary profile P: the heights minus their least-squares line (no λs
//! filter). Roughness profile R: P minus its Gaussian mean line
//! ([`super::gaussian`], cut-off λc), evaluated on n sampling lengths of λc
//! (default 5) centred in the profile, so at least λc/2 at each end, where
//! the filter runs short of data, is left out.
//!
//! Integrals are of the piecewise-linear profile through the points, over
//! the x span L of the points evaluated (exact for that profile; on a
//! uniform step it is the trapezoid rule). With c = z − m on each segment
//! [x₀, x₁], Δx = x₁ − x₀:
//!
//! - m  = Σ Δx (z₀ + z₁)/2 / L
//! - Pq, Rq = √(Σ Δx (c₀² + c₀c₁ + c₁²)/3 / L) (= √(I₂ − m²))
//! - Pa, Ra = Σ ∫|c| / L, a segment whose ends differ in sign split at its
//!   zero: Δx (c₀² + c₁²) / (2(|c₀| + |c₁|))
//! - Psk, Rsk = Σ Δx (c₀³ + c₀²c₁ + c₀c₁² + c₁³)/4 / L / q³
//! - Pku, Rku = Σ Δx (c₀⁴ + c₀³c₁ + c₀²c₁² + c₀c₁³ + c₁⁴)/5 / L / q⁴
//! - Pt, Rt = max − min of the points over the evaluation length
//! - Rz = mean over the sampling lengths of (max − min) of R's points in
//!   each (half-open [a, a + λc), the last one closed)

use crate::bail;
use serde::{Deserialize, Serialize};
use sparkout_pipeline::Result;

use super::readers::ProfileInput;
use super::{console_length, gaussian, nan, nan_vec, straightness, Figure, OrWhy};

/// Default number of sampling lengths in the evaluation length.
pub const DEFAULT_SAMPLING_LENGTHS: usize = 5;

/// Moments of the piecewise-linear profile through (x, z).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Moments {
    /// The x span integrated over.
    pub length: f64,
    pub mean: f64,
    pub q: f64,
    pub a: f64,
    /// NaN when q is 0.
    pub sk: f64,
    pub ku: f64,
    /// max − min of the points.
    pub t: f64,
}

pub fn moments(x: &[f64], z: &[f64]) -> Moments {
    let n = x.len();
    let length = x[n - 1] - x[0];
    let mut m = 0.0;
    for i in 0..n - 1 {
        m += (x[i + 1] - x[i]) * (z[i] + z[i + 1]) / 2.0;
    }
    m /= length;
    let (mut i2, mut i3, mut i4, mut ia) = (0.0, 0.0, 0.0, 0.0);
    for i in 0..n - 1 {
        let d = x[i + 1] - x[i];
        let (a, b) = (z[i] - m, z[i + 1] - m);
        i2 += d * (a * a + a * b + b * b) / 3.0;
        i3 += d * (a * a * a + a * a * b + a * b * b + b * b * b) / 4.0;
        i4 += d * (a.powi(4) + a.powi(3) * b + a * a * b * b + a * b.powi(3) + b.powi(4)) / 5.0;
        ia += if a * b >= 0.0 {
            d * (a.abs() + b.abs()) / 2.0
        } else {
            d * (a * a + b * b) / (2.0 * (a.abs() + b.abs()))
        };
    }
    let q = (i2 / length).sqrt();
    let (sk, ku) = if q > 0.0 {
        (i3 / length / q.powi(3), i4 / length / q.powi(4))
    } else {
        (f64::NAN, f64::NAN)
    };
    let (lo, hi) = z
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    Moments {
        length,
        mean: m,
        q,
        a: ia / length,
        sk,
        ku,
        t: hi - lo,
    }
}

/// What to compute beyond the primary profile.
#[derive(Debug, Clone, Copy)]
pub struct Settings {
    /// Gaussian cut-off, mm; `None`: no roughness figures.
    pub lambda_c: Option<f64>,
    pub sampling_lengths: usize,
}

/// The `profile` stage's JSON: straightness, P and R figures of a line
/// profile, and the input as read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProfileReport {
    pub form_removal: String,
    pub straightness: Straightness,
    pub x_spacing: XSpacing,
    pub integration: String,
    pub primary: Primary,
    /// The Gaussian filter (`null` without a cut-off).
    pub filter: Option<GaussianFilter>,
    pub roughness: OrWhy<Roughness>,
    /// The file as read (the stage adds it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub input: Option<ProfileInput>,
}

/// [`ProfileReport`]'s straightness.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Straightness {
    pub standard: String,
    pub least_squares: Figure,
    pub min_zone: Figure,
    #[serde(deserialize_with = "nan")]
    pub least_squares_slope: f64,
}

/// [`ProfileReport`]'s x spacing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct XSpacing {
    pub uniform: bool,
    pub min_step: Figure,
    pub max_step: Figure,
}

/// The primary profile's figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Primary {
    pub filter: String,
    pub evaluation_length: Figure,
    pub n_points: usize,
    #[serde(rename = "Pt")]
    pub pt: Figure,
    #[serde(rename = "Pq")]
    pub pq: Figure,
    #[serde(rename = "Pa")]
    pub pa: Figure,
    #[serde(rename = "Psk")]
    pub psk: Figure,
    #[serde(rename = "Pku")]
    pub pku: Figure,
}

/// The Gaussian profile filter in force.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GaussianFilter {
    #[serde(rename = "type")]
    pub kind: String,
    pub lambda_c: Figure,
    #[serde(deserialize_with = "nan")]
    pub alpha: f64,
    pub weighting: String,
    pub truncation: String,
    pub discretisation: String,
    pub lambda_s: String,
}

/// The roughness profile's figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Roughness {
    pub end_effect: String,
    pub sampling_length: Figure,
    pub sampling_lengths: usize,
    pub sampling_lengths_note: String,
    pub evaluation_start: Figure,
    pub evaluation_end: Figure,
    pub evaluation_length: Figure,
    pub n_points: usize,
    #[serde(rename = "Rq")]
    pub rq: Figure,
    #[serde(rename = "Ra")]
    pub ra: Figure,
    #[serde(rename = "Rz")]
    pub rz: Figure,
    #[serde(rename = "Rz_per_sampling_length", deserialize_with = "nan_vec")]
    pub rz_per_sampling_length: Vec<f64>,
    #[serde(rename = "Rt")]
    pub rt: Figure,
    #[serde(rename = "Rsk")]
    pub rsk: Figure,
    #[serde(rename = "Rku")]
    pub rku: Figure,
}

/// Straightness, P and R figures of a profile (x strictly increasing, mm)
/// as the `profile` stage's JSON.
pub fn analyse(x: &[f64], z: &[f64], s: Settings) -> Result<ProfileReport> {
    if x.len() < 3 {
        bail!("{} points; a profile needs at least 3", x.len());
    }
    let ls = straightness::least_squares(x, z)?;
    let mz = straightness::min_zone(x, z)?;
    let p: Vec<f64> = (0..x.len())
        .map(|i| z[i] - (ls.slope * x[i] + ls.intercept))
        .collect();
    let pm = moments(x, &p);
    let steps: Vec<f64> = x.windows(2).map(|w| w[1] - w[0]).collect();
    let (smin, smax) = steps
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    let mean_step = pm.length / steps.len() as f64;
    let uniform = smax - smin <= 1e-6 * mean_step;
    let filter = s.lambda_c.map(|lc| GaussianFilter {
        kind: "Gaussian profile filter (ISO 16610-21)".into(),
        lambda_c: Figure::mm(lc),
        alpha: gaussian::alpha(),
        weighting: "s(x) = (1/(α·λc))·exp(−π·(x/(α·λc))²), α = √(ln 2/π)".into(),
        truncation: "±λc".into(),
        discretisation: "Δx-weighted sum over the measured points, normalised by the weights present: w(xᵢ) = Σ s(xⱼ−xᵢ)Δⱼzⱼ / Σ s(xⱼ−xᵢ)Δⱼ, Δⱼ = (xⱼ₊₁ − xⱼ₋₁)/2; no resampling".into(),
        lambda_s: "none".into(),
    });
    let roughness = match s.lambda_c {
        None => OrWhy::NotComputed {
            not_computed: "no cut-off: give --lambda-c MM (standard cut-offs 0.08, 0.25, 0.8, 2.5, 8 mm) for the R figures".into(),
        },
        Some(lc) => roughness(x, &p, lc, s.sampling_lengths)?,
    };
    Ok(ProfileReport {
        form_removal: "least-squares line over the points".into(),
        straightness: Straightness {
            standard: "ISO 12780 (distances along z)".into(),
            least_squares: Figure::mm(ls.width),
            min_zone: Figure::mm(mz.width),
            least_squares_slope: ls.slope,
        },
        x_spacing: XSpacing {
            uniform,
            min_step: Figure::mm(smin),
            max_step: Figure::mm(smax),
        },
        integration: "piecewise-linear profile through the points, over the x span of the points evaluated (trapezoid rule on a uniform step)".into(),
        primary: Primary {
            filter: "none (no λs filter)".into(),
            evaluation_length: Figure::mm(pm.length),
            n_points: x.len(),
            pt: Figure::mm(pm.t),
            pq: Figure::mm(pm.q),
            pa: Figure::mm(pm.a),
            psk: Figure::ratio(pm.sk),
            pku: Figure::ratio(pm.ku),
        },
        filter,
        roughness,
        input: None,
    })
}

fn roughness(x: &[f64], p: &[f64], lc: f64, want: usize) -> Result<OrWhy<Roughness>> {
    if !(lc.is_finite() && lc > 0.0) {
        bail!("--lambda-c must be a length > 0 (mm)");
    }
    if want == 0 {
        bail!("--sampling-lengths must be at least 1");
    }
    let n = x.len();
    let total = x[n - 1] - x[0];
    // Whole sampling lengths that fit once λc/2 is left at each end.
    let fit = ((total - lc) / lc + 1e-9).floor().max(0.0) as usize;
    let k = want.min(fit);
    if k == 0 {
        return Ok(OrWhy::NotComputed {
            not_computed: format!(
                "the profile is {} mm long; a sampling length of λc = {lc} mm plus λc/2 at each end needs {} mm",
                total,
                2.0 * lc
            ),
        });
    }
    let w = gaussian::mean_line(x, p, lc);
    let r: Vec<f64> = (0..n).map(|i| p[i] - w[i]).collect();
    let ln = k as f64 * lc;
    let start = x[0] + (total - ln) / 2.0;
    let end = start + ln;
    let eps = 1e-9 * lc;
    let idx: Vec<usize> = (0..n)
        .filter(|&i| x[i] >= start - eps && x[i] <= end + eps)
        .collect();
    if idx.len() < 3 {
        bail!("fewer than 3 points in the evaluation length [{start}, {end}] mm");
    }
    let (ex, er): (Vec<f64>, Vec<f64>) = idx.iter().map(|&i| (x[i], r[i])).unzip();
    let rm = moments(&ex, &er);
    let mut peaks = Vec::with_capacity(k);
    for s in 0..k {
        let (a, b) = (start + s as f64 * lc, start + (s + 1) as f64 * lc);
        let last = s + 1 == k;
        let (lo, hi) = ex
            .iter()
            .zip(&er)
            .filter(|(&u, _)| u >= a - eps && (u < b - eps || (last && u <= b + eps)))
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), (_, &v)| {
                (l.min(v), h.max(v))
            });
        if !lo.is_finite() {
            bail!("sampling length {} ([{a}, {b}] mm) holds no point; the profile's step is longer than λc", s + 1);
        }
        peaks.push(hi - lo);
    }
    let rz = peaks.iter().sum::<f64>() / k as f64;
    let note = if k < want {
        format!(
            "{k} of the {want} sampling lengths asked fit in the profile ({} mm long, λc/2 left at each end)",
            total
        )
    } else {
        format!("{k} sampling lengths")
    };
    Ok(OrWhy::Computed(Roughness {
        end_effect: "the Gaussian mean line lacks data near the ends: the evaluation length is centred in the profile and leaves at least λc/2 at each end out".into(),
        sampling_length: Figure::mm(lc),
        sampling_lengths: k,
        sampling_lengths_note: note,
        evaluation_start: Figure::mm(start),
        evaluation_end: Figure::mm(end),
        evaluation_length: Figure::mm(ln),
        n_points: ex.len(),
        rq: Figure::mm(rm.q),
        ra: Figure::mm(rm.a),
        rz: Figure::mm(rz),
        rz_per_sampling_length: peaks,
        rt: Figure::mm(rm.t),
        rsk: Figure::ratio(rm.sk),
        rku: Figure::ratio(rm.ku),
    }))
}

/// Console lines of the `profile` stage's JSON (lengths through
/// [`console_length`]).
pub fn console(v: &ProfileReport) -> String {
    let l = |f: &Figure| console_length(f.value);
    let r = |f: &Figure| {
        if f.value.is_finite() {
            format!("{:.3}", f.value)
        } else {
            "n/a".into()
        }
    };
    let mut s = String::new();
    if let Some(inp) = &v.input {
        s += &format!(
            "{}: {} points (x {} [{}], z {} [{}]){}\n",
            inp.file,
            inp.n_points,
            inp.x.column,
            inp.x.unit,
            inp.z.column,
            inp.z.unit,
            match inp.n_not_measured {
                k if k > 0 => format!(", {k} not measured (left out)"),
                _ => String::new(),
            }
        );
        for n in &inp.notes {
            s += &format!("  note: {n}\n");
        }
    }
    let st = &v.straightness;
    s += &format!(
        "straightness: LS {}  min-zone {}\n",
        l(&st.least_squares),
        l(&st.min_zone)
    );
    let p = &v.primary;
    s += &format!(
        "primary (no filter, LS line removed, length {}): Pt {}  Pq {}  Pa {}  Psk {}  Pku {}\n",
        l(&p.evaluation_length),
        l(&p.pt),
        l(&p.pq),
        l(&p.pa),
        r(&p.psk),
        r(&p.pku)
    );
    match &v.roughness {
        OrWhy::NotComputed { not_computed } => {
            s += &format!("roughness: not computed: {not_computed}\n");
        }
        OrWhy::Computed(g) => {
            s += &format!(
                "roughness (Gaussian λc {}, {} × {} evaluated from {} to {}, λc/2 at least left at each end): Rq {}  Ra {}  Rz {}  Rt {}  Rsk {}  Rku {}\n",
                console_length(v.filter.as_ref().map_or(f64::NAN, |f| f.lambda_c.value)),
                g.sampling_lengths,
                l(&g.sampling_length),
                l(&g.evaluation_start),
                l(&g.evaluation_end),
                l(&g.rq),
                l(&g.ra),
                l(&g.rz),
                l(&g.rt),
                r(&g.rsk),
                r(&g.rku)
            );
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn piecewise_linear_moments_are_exact_for_a_triangle_wave() {
        // A triangle wave of amplitude A sampled at its corners only is
        // exactly piecewise linear: Rq = A/√3, Ra = A/2, Rku = 9/5.
        let a = 2e-3;
        let x: Vec<f64> = (0..=40).map(|i| i as f64 * 0.5).collect();
        let z: Vec<f64> = (0..=40).map(|i| if i % 2 == 0 { -a } else { a }).collect();
        let m = moments(&x, &z);
        assert!(m.mean.abs() < 1e-18);
        assert!((m.q - a / 3f64.sqrt()).abs() < 1e-15, "{}", m.q);
        assert!((m.a - a / 2.0).abs() < 1e-15, "{}", m.a);
        assert!((m.ku - 1.8).abs() < 1e-12, "{}", m.ku);
        assert!(m.sk.abs() < 1e-12);
        // Non-uniform: the same wave with its rising flanks sampled twice
        // more is the same piecewise-linear profile.
        let mut xn = vec![];
        let mut zn = vec![];
        for i in 0..40 {
            xn.push(x[i]);
            zn.push(z[i]);
            if z[i] < 0.0 {
                for f in [0.3, 0.7] {
                    xn.push(x[i] + f * 0.5);
                    zn.push(z[i] + f * (z[i + 1] - z[i]));
                }
            }
        }
        xn.push(x[40]);
        zn.push(z[40]);
        let mn = moments(&xn, &zn);
        assert!((mn.q - m.q).abs() < 1e-15 && (mn.a - m.a).abs() < 1e-15);
    }

    #[test]
    fn roughness_of_a_short_wave_on_a_long_one() {
        // A 0.1 µm sine of 0.1 mm period on a 0.2 µm wave of 12 mm: with
        // λc = 0.8 the mean line keeps the long wave (gain 0.997) and the
        // R profile is the short sine, Rq = A/√2.
        let step = 0.0005;
        let n = (6.0 / step) as usize + 1;
        let x: Vec<f64> = (0..n).map(|i| i as f64 * step).collect();
        let tau = 2.0 * std::f64::consts::PI;
        let a = 1e-4;
        let z: Vec<f64> = x
            .iter()
            .map(|&u| 2e-4 * (tau * u / 12.0).sin() + a * (tau * u / 0.1).sin())
            .collect();
        let v = analyse(
            &x,
            &z,
            Settings {
                lambda_c: Some(0.8),
                sampling_lengths: 5,
            },
        )
        .unwrap();
        let OrWhy::Computed(g) = &v.roughness else {
            panic!("λc 0.8 fits 5 sampling lengths: {:?}", v.roughness);
        };
        let rq = g.rq.value;
        assert!((rq - a / 2f64.sqrt()).abs() < 0.02 * a, "{rq}");
        assert!((g.rz.value - 2.0 * a).abs() < 0.05 * a);
        assert_eq!(g.sampling_lengths, 5);
        assert!((g.evaluation_start.value - 1.0).abs() < 1e-12);
        assert!(console(&v).contains("Rq"));
        // Without λc: no R figures, and the output says how to get them.
        let v = analyse(
            &x,
            &z,
            Settings {
                lambda_c: None,
                sampling_lengths: 5,
            },
        )
        .unwrap();
        assert!(
            matches!(&v.roughness, OrWhy::NotComputed { not_computed } if not_computed.contains("--lambda-c"))
        );
        // Too short for one sampling length and its two half ends.
        let v = analyse(
            &x[..1000],
            &z[..1000],
            Settings {
                lambda_c: Some(0.8),
                sampling_lengths: 5,
            },
        )
        .unwrap();
        assert!(matches!(v.roughness, OrWhy::NotComputed { .. }));
    }
}

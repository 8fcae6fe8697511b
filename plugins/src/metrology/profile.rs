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

use anyhow::bail;
use serde_json::{json, Value};
use sparkout_pipeline::Result;

use super::{console_length, gaussian, mm, ratio, straightness, value_of};

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

/// Straightness, P and R figures of a profile (x strictly increasing, mm)
/// as the `profile` stage's JSON.
pub fn analyse(x: &[f64], z: &[f64], s: Settings) -> Result<Value> {
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
    let mut out = json!({
        "form_removal": "least-squares line over the points",
        "straightness": {
            "standard": "ISO 12780 (distances along z)",
            "least_squares": mm(ls.width),
            "min_zone": mm(mz.width),
            "least_squares_slope": ls.slope,
        },
        "x_spacing": {
            "uniform": uniform,
            "min_step": mm(smin),
            "max_step": mm(smax),
        },
        "integration": "piecewise-linear profile through the points, over the x span of the points evaluated (trapezoid rule on a uniform step)",
        "primary": {
            "filter": "none (no λs filter)",
            "evaluation_length": mm(pm.length),
            "n_points": x.len(),
            "Pt": mm(pm.t),
            "Pq": mm(pm.q),
            "Pa": mm(pm.a),
            "Psk": ratio(pm.sk),
            "Pku": ratio(pm.ku),
        },
    });
    out["filter"] = match s.lambda_c {
        None => Value::Null,
        Some(lc) => json!({
            "type": "Gaussian profile filter (ISO 16610-21)",
            "lambda_c": mm(lc),
            "alpha": gaussian::alpha(),
            "weighting": "s(x) = (1/(α·λc))·exp(−π·(x/(α·λc))²), α = √(ln 2/π)",
            "truncation": "±λc",
            "discretisation": "Δx-weighted sum over the measured points, normalised by the weights present: w(xᵢ) = Σ s(xⱼ−xᵢ)Δⱼzⱼ / Σ s(xⱼ−xᵢ)Δⱼ, Δⱼ = (xⱼ₊₁ − xⱼ₋₁)/2; no resampling",
            "lambda_s": "none",
        }),
    };
    out["roughness"] = match s.lambda_c {
        None => {
            json!({"not_computed": "no cut-off: give --lambda-c MM (standard cut-offs 0.08, 0.25, 0.8, 2.5, 8 mm) for the R figures"})
        }
        Some(lc) => roughness(x, &p, lc, s.sampling_lengths)?,
    };
    Ok(out)
}

fn roughness(x: &[f64], p: &[f64], lc: f64, want: usize) -> Result<Value> {
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
        return Ok(json!({"not_computed": format!(
            "the profile is {} mm long; a sampling length of λc = {lc} mm plus λc/2 at each end needs {} mm",
            total, 2.0 * lc
        )}));
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
    Ok(json!({
        "end_effect": "the Gaussian mean line lacks data near the ends: the evaluation length is centred in the profile and leaves at least λc/2 at each end out",
        "sampling_length": mm(lc),
        "sampling_lengths": k,
        "sampling_lengths_note": note,
        "evaluation_start": mm(start),
        "evaluation_end": mm(end),
        "evaluation_length": mm(ln),
        "n_points": ex.len(),
        "Rq": mm(rm.q),
        "Ra": mm(rm.a),
        "Rz": mm(rz),
        "Rz_per_sampling_length": peaks,
        "Rt": mm(rm.t),
        "Rsk": ratio(rm.sk),
        "Rku": ratio(rm.ku),
    }))
}

/// Console lines of the `profile` stage's JSON (lengths through
/// [`console_length`]).
pub fn console(v: &Value) -> String {
    let l = |f: &Value| console_length(value_of(f));
    let r = |f: &Value| {
        let x = value_of(f);
        if x.is_finite() {
            format!("{x:.3}")
        } else {
            "n/a".into()
        }
    };
    let mut s = String::new();
    let inp = &v["input"];
    if inp.is_object() {
        s += &format!(
            "{}: {} points (x {} [{}], z {} [{}]){}\n",
            inp["file"].as_str().unwrap_or(""),
            inp["n_points"],
            inp["x"]["column"].as_str().unwrap_or(""),
            inp["x"]["unit"].as_str().unwrap_or(""),
            inp["z"]["column"].as_str().unwrap_or(""),
            inp["z"]["unit"].as_str().unwrap_or(""),
            match inp["n_not_measured"].as_u64() {
                Some(k) if k > 0 => format!(", {k} not measured (left out)"),
                _ => String::new(),
            }
        );
        for n in inp["notes"].as_array().into_iter().flatten() {
            s += &format!("  note: {}\n", n.as_str().unwrap_or(""));
        }
    }
    let st = &v["straightness"];
    s += &format!(
        "straightness: LS {}  min-zone {}\n",
        l(&st["least_squares"]),
        l(&st["min_zone"])
    );
    let p = &v["primary"];
    s += &format!(
        "primary (no filter, LS line removed, length {}): Pt {}  Pq {}  Pa {}  Psk {}  Pku {}\n",
        l(&p["evaluation_length"]),
        l(&p["Pt"]),
        l(&p["Pq"]),
        l(&p["Pa"]),
        r(&p["Psk"]),
        r(&p["Pku"])
    );
    let g = &v["roughness"];
    if let Some(why) = g["not_computed"].as_str() {
        s += &format!("roughness: not computed: {why}\n");
    } else {
        s += &format!(
            "roughness (Gaussian λc {}, {} × {} evaluated from {} to {}, λc/2 at least left at each end): Rq {}  Ra {}  Rz {}  Rt {}  Rsk {}  Rku {}\n",
            l(&v["filter"]["lambda_c"]),
            g["sampling_lengths"],
            l(&g["sampling_length"]),
            l(&g["evaluation_start"]),
            l(&g["evaluation_end"]),
            l(&g["Rq"]),
            l(&g["Ra"]),
            l(&g["Rz"]),
            l(&g["Rt"]),
            r(&g["Rsk"]),
            r(&g["Rku"])
        );
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
        let g = &v["roughness"];
        let rq = value_of(&g["Rq"]);
        assert!((rq - a / 2f64.sqrt()).abs() < 0.02 * a, "{rq}");
        assert!((value_of(&g["Rz"]) - 2.0 * a).abs() < 0.05 * a);
        assert_eq!(g["sampling_lengths"], 5);
        assert!((value_of(&g["evaluation_start"]) - 1.0).abs() < 1e-12);
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
        assert!(v["roughness"]["not_computed"]
            .as_str()
            .unwrap()
            .contains("--lambda-c"));
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
        assert!(v["roughness"]["not_computed"].is_string());
    }
}

//! Spikes: points whose residual from the least-squares plane is far from
//! the rest, by a robust rule, reported with the flatness and Sz they
//! cause. A few spikes (dust, a stylus skip, a dropout read as a height)
//! decide peak-to-valley figures alone, so they are shown, never dropped
//! silently: every figure is given with and without them.
//!
//! Rule: with r the LS-plane residuals, med = median(r) and
//! MAD = median(|r − med|), a point is a spike when
//! |r − med| > K · 1.4826 · MAD. 1.4826·MAD estimates σ for Gaussian
//! residuals without being moved by the spikes themselves; K = 6 flags
//! about 2 in 10⁹ Gaussian points, so on a clean map of 10⁶ points the
//! rule stays silent. When more than half the residuals are equal the MAD
//! is 0 and the rule does not apply (said in the output).

use serde::{Deserialize, Serialize};
use sparkout_pipeline::Result;

use super::areal::{heights, residuals, Form};
use super::plane::flatness;
use super::{console_length, json_number, nan, Figure};

/// Spike threshold in robust standard deviations.
pub const K: f64 = 6.0;
/// Positions listed in the output (the count is always complete).
pub const SHOWN: usize = 20;
/// MAD to σ for Gaussian data: 1/Φ⁻¹(3/4).
pub const MAD_TO_SIGMA: f64 = 1.4826;

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// The spikes of residuals `r`: indices (largest deviation first), median,
/// MAD and the threshold on |r − median| (`None` when MAD = 0).
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    pub median: f64,
    pub mad: f64,
    pub threshold: Option<f64>,
    pub indices: Vec<usize>,
}

pub fn detect(r: &[f64]) -> Detection {
    let med = median(&mut r.to_vec());
    let mad = median(&mut r.iter().map(|v| (v - med).abs()).collect::<Vec<_>>());
    if mad <= 0.0 {
        return Detection {
            median: med,
            mad,
            threshold: None,
            indices: vec![],
        };
    }
    let t = K * MAD_TO_SIGMA * mad;
    let mut idx: Vec<usize> = (0..r.len()).filter(|&i| (r[i] - med).abs() > t).collect();
    idx.sort_by(|&i, &j| {
        (r[j] - med)
            .abs()
            .total_cmp(&(r[i] - med).abs())
            .then(i.cmp(&j))
    });
    Detection {
        median: med,
        mad,
        threshold: Some(t),
        indices: idx,
    }
}

/// LS flatness, minimum-zone flatness, Sz and Sq of a point set (plane
/// removed).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SpikeFigures {
    pub n: usize,
    pub least_squares_flatness: Figure,
    pub min_zone_flatness: Figure,
    #[serde(rename = "Sz")]
    pub sz: Figure,
    #[serde(rename = "Sq")]
    pub sq: Figure,
}

/// One spike: where it is and its residual from the LS plane.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SpikePosition {
    #[serde(deserialize_with = "nan")]
    pub x_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub y_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub residual_mm: f64,
}

/// The `spikes` object: the rule, what it found, and the figures with and
/// without the spikes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SpikeReport {
    pub rule: String,
    #[serde(deserialize_with = "nan")]
    pub k: f64,
    pub median: Figure,
    pub mad: Figure,
    /// `null` value with a note when the rule does not apply.
    pub threshold: Figure,
    pub count: usize,
    /// The first [`SHOWN`] spikes.
    pub positions: Vec<SpikePosition>,
    pub positions_shown: usize,
    pub with_spikes: SpikeFigures,
    pub without_spikes: SpikeFigures,
}

fn figures(x: &[f64], y: &[f64], z: &[f64]) -> Result<SpikeFigures> {
    let f = flatness(x, y, z)?;
    let r = residuals(x, y, z, Form::Plane)?;
    let h = heights(&r, 1.0);
    Ok(SpikeFigures {
        n: z.len(),
        least_squares_flatness: Figure::mm(f.least_squares.width_mm),
        min_zone_flatness: Figure::mm(f.min_zone.width_mm),
        sz: Figure::mm(h.sz),
        sq: Figure::mm(h.sq),
    })
}

/// The `spikes` object of the points; `plane` is their LS-plane residuals.
pub fn report(x: &[f64], y: &[f64], z: &[f64], plane: &[f64]) -> Result<SpikeReport> {
    let d = detect(plane);
    let with = figures(x, y, z)?;
    let without = if d.indices.is_empty() {
        with.clone()
    } else {
        let mut out = vec![true; z.len()];
        d.indices.iter().for_each(|&i| out[i] = false);
        let pick = |v: &[f64]| {
            (0..v.len())
                .filter(|&i| out[i])
                .map(|i| v[i])
                .collect::<Vec<f64>>()
        };
        let (cx, cy, cz) = (pick(x), pick(y), pick(z));
        figures(&cx, &cy, &cz)?
    };
    let positions: Vec<SpikePosition> = d
        .indices
        .iter()
        .take(SHOWN)
        .map(|&i| SpikePosition {
            x_mm: x[i],
            y_mm: y[i],
            residual_mm: plane[i],
        })
        .collect();
    Ok(SpikeReport {
        rule: format!(
            "|r − median(r)| > k·1.4826·MAD of the least-squares-plane residuals r, k = {K}"
        ),
        k: K,
        median: Figure::mm(d.median),
        mad: Figure::mm(d.mad),
        threshold: d.threshold.map_or(
            Figure {
                note: Some(
                    "MAD = 0: more than half the residuals are equal, the rule does not apply"
                        .into(),
                ),
                ..Figure::mm(f64::NAN)
            },
            Figure::mm,
        ),
        count: d.indices.len(),
        positions_shown: positions.len(),
        positions,
        with_spikes: with,
        without_spikes: without,
    })
}

/// Console lines of a `spikes` object.
pub fn console(s: &SpikeReport) -> String {
    let count = s.count;
    let line = |v: &SpikeFigures| {
        format!(
            "LS flatness {}  min-zone {}  Sz {}",
            console_length(v.least_squares_flatness.value),
            console_length(v.min_zone_flatness.value),
            console_length(v.sz.value)
        )
    };
    let mut out = format!(
        "spikes (|r − median| > {}·1.4826·MAD = {}): {count}\n",
        json_number(s.k),
        console_length(s.threshold.value)
    );
    if count > 0 {
        let shown: Vec<String> = s
            .positions
            .iter()
            .map(|p| {
                let l = console_length;
                format!("({}, {}) {}", l(p.x_mm), l(p.y_mm), l(p.residual_mm))
            })
            .collect();
        out += &format!(
            "  at (x, y) and residual: {}{}\n",
            shown.join("; "),
            if count > shown.len() {
                format!("; … {} more in the JSON count", count - shown.len())
            } else {
                String::new()
            }
        );
        out += &format!("  with spikes:    {}\n", line(&s.with_spikes));
        out += &format!("  without spikes: {}\n", line(&s.without_spikes));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn injected_spikes_are_found_and_change_the_peak_to_valley() {
        // A smooth wavy map plus three spikes of 50 µm.
        let (mut x, mut y, mut z) = (vec![], vec![], vec![]);
        for i in 0..30 {
            for j in 0..20 {
                let (u, v) = (i as f64 * 2.0, j as f64 * 2.0);
                x.push(u);
                y.push(v);
                z.push(1e-4 * (u / 7.0).sin() * (v / 5.0).cos() + 2e-5 * u);
            }
        }
        for &k in &[37usize, 250, 511] {
            z[k] += 0.05;
        }
        let r = residuals(&x, &y, &z, Form::Plane).unwrap();
        let d = detect(&r);
        let mut found = d.indices.clone();
        found.sort();
        assert_eq!(found, [37, 250, 511]);
        let rep = report(&x, &y, &z, &r).unwrap();
        assert_eq!(rep.count, 3);
        let with = rep.with_spikes.min_zone_flatness.value;
        let without = rep.without_spikes.min_zone_flatness.value;
        assert!(with > 0.05 && without < 5e-4, "{with} {without}");
        assert_eq!(rep.without_spikes.n, 600 - 3);
        assert!(console(&rep).contains("without spikes"));
    }

    #[test]
    fn a_clean_map_has_no_spikes_and_equal_residuals_disable_the_rule() {
        let r: Vec<f64> = (0..1000).map(|i| ((i * 37) % 101) as f64 * 1e-6).collect();
        assert!(detect(&r).indices.is_empty());
        let d = detect(&[0.0, 0.0, 0.0, 1.0]);
        assert_eq!(d.threshold, None);
        assert!(d.indices.is_empty());
    }
}

//! Scoring one diagnosed fleet against its truth: localisation (the true
//! effect's energy inside the reported cells), parameter error, and whether
//! each 95 % interval holds the true parameter.

use super::*;

pub(super) fn snr_label(s: f64) -> String {
    format!("snr{s}")
}

/// Rows inside a reported cell (1-D: lo ≤ c ≤ hi; tile: both axes).
pub(super) fn in_cells(cells: &[WhereCell], l: &ObsLayout) -> Vec<bool> {
    let mut inside = vec![false; l.len()];
    for c in cells {
        let names: Vec<&str> = c.covariate.split(',').collect();
        let bounds: Vec<(f64, f64)> = match (&c.lo, &c.hi) {
            (CellBound::Point(lo), CellBound::Point(hi)) => {
                lo.iter().copied().zip(hi.iter().copied()).collect()
            }
            (CellBound::Number(lo), CellBound::Number(hi)) => vec![(*lo, *hi)],
            // A labelled cell (a machine) bounds no number.
            _ => vec![(f64::NAN, f64::NAN)],
        };
        let cols: Vec<&[f64]> = match names.iter().map(|n| l.col(n)).collect::<Result<Vec<_>>>() {
            Ok(c) => c,
            Err(_) => continue,
        };
        for (i, flag) in inside.iter_mut().enumerate() {
            if !*flag
                && cols
                    .iter()
                    .zip(&bounds)
                    .all(|(col, (lo, hi))| col[i] >= *lo && col[i] <= *hi)
            {
                *flag = true;
            }
        }
    }
    inside
}

/// Largest relative error over the shape and amplitude parameters of the
/// truth (phase as |Δφ|/π; c0, c1, t0_c are fixed by the frame, skipped).
pub(super) fn param_error(truth: &EffectSpec, d: &Diagnosis) -> Option<f64> {
    let e = d.effects.iter().find(|e| e.selected)?;
    let mut worst: f64 = 0.0;
    for (k, t) in &truth.params {
        if matches!(k.as_str(), "c0" | "c1" | "t0_c") {
            continue;
        }
        let got = if k == "offset_mm" && truth.name == "offset" {
            *e.params.get("offset_mm")?
        } else {
            *e.params.get(k)?
        };
        let err = if k == "phase_rad" {
            let d = (got - t).rem_euclid(2.0 * std::f64::consts::PI);
            d.min(2.0 * std::f64::consts::PI - d) / std::f64::consts::PI
        } else {
            (got - t).abs() / t.abs().max(1e-300)
        };
        worst = worst.max(err);
    }
    Some(worst)
}

/// (checked, covered): the truth's parameters against the named effect's
/// 95 % intervals (phase compared modulo 2π; c0, c1, t0_c are frame
/// constants, skipped).
pub(super) fn interval_hits(truth: &EffectSpec, d: &Diagnosis) -> (usize, usize) {
    let Some(e) = d.effects.iter().find(|e| e.selected) else {
        return (0, 0);
    };
    let Some(iv) = &e.intervals else {
        return (0, 0);
    };
    let (mut checked, mut covered) = (0, 0);
    for (k, t) in &truth.params {
        if matches!(k.as_str(), "c0" | "c1" | "t0_c") {
            continue;
        }
        let (Some(i), Some(v)) = (
            iv.get(k),
            if k == "offset_mm" {
                e.offset_mm
            } else {
                e.params.get(k).copied()
            },
        ) else {
            continue;
        };
        let diff = if k == "phase_rad" {
            let tau = 2.0 * std::f64::consts::PI;
            let d = (t - v).rem_euclid(tau);
            d.min(tau - d)
        } else {
            (t - v).abs()
        };
        checked += 1;
        // Symmetric intervals: value ± half-width.
        covered += usize::from(diff <= 0.5 * (i.hi - i.lo));
    }
    (checked, covered)
}

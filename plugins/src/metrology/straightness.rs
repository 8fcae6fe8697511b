//! Straightness of a line profile (ISO 12780): least-squares and minimum
//! zone, as distances along z between two parallel lines enclosing the
//! points (the same convention as `flatness`: heights are small deviations,
//! so along z and normal to the lines differ by 1/√(1 + a²) ≈ 1 − a²/2).
//!
//! Minimum zone: minimise c_hi − c_lo subject to
//! c_lo ≤ zᵢ − a·xᵢ ≤ c_hi, the linear programme `flatness` solves for
//! planes, with the same solver (microlp). Only the vertices of the upper
//! and lower convex hulls can touch the zone, so the LP is set over them;
//! long hulls (a smooth arc puts every point on one) are solved by the
//! same constraint generation as flatness: the LP over a subset, its line
//! checked against every vertex, the worst violators added, until none
//! is left.

use crate::{bail, err};
use microlp::{ComparisonOp, OptimizationDirection, Problem};
use sparkout_pipeline::Result;

/// z = slope·x + intercept and the spread of the residuals from it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Line {
    pub slope: f64,
    pub intercept: f64,
    /// max − min of the residuals, same unit as z.
    pub width: f64,
}

fn spread(x: &[f64], z: &[f64], a: f64, idx: impl Iterator<Item = usize>) -> (f64, f64) {
    idx.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), i| {
        let r = z[i] - a * x[i];
        (lo.min(r), hi.max(r))
    })
}

/// The least-squares line over the points (each point one equation), on
/// centred coordinates.
pub fn least_squares(x: &[f64], z: &[f64]) -> Result<Line> {
    let n = x.len();
    if n < 2 {
        bail!("{n} points; a line needs at least 2");
    }
    let (mx, mz) = (
        x.iter().sum::<f64>() / n as f64,
        z.iter().sum::<f64>() / n as f64,
    );
    let (mut sxx, mut sxz) = (0.0, 0.0);
    for i in 0..n {
        sxx += (x[i] - mx) * (x[i] - mx);
        sxz += (x[i] - mx) * (z[i] - mz);
    }
    if sxx <= 0.0 {
        bail!("all points have the same x; no line through them");
    }
    let a = sxz / sxx;
    let (lo, hi) = spread(x, z, a, 0..n);
    Ok(Line {
        slope: a,
        intercept: mz - a * mx,
        width: hi - lo,
    })
}

/// Indices of the vertices of the upper and lower convex hulls of (x, z),
/// x non-decreasing (Andrew's monotone chain).
fn hull_vertices(x: &[f64], z: &[f64]) -> Vec<usize> {
    let cross = |o: usize, a: usize, b: usize| {
        (x[a] - x[o]) * (z[b] - z[o]) - (z[a] - z[o]) * (x[b] - x[o])
    };
    let mut order: Vec<usize> = (0..x.len()).collect();
    order.sort_by(|&i, &j| x[i].total_cmp(&x[j]).then(z[i].total_cmp(&z[j])));
    let mut lower: Vec<usize> = Vec::new();
    for &p in &order {
        while lower.len() >= 2 && cross(lower[lower.len() - 2], lower[lower.len() - 1], p) <= 0.0 {
            lower.pop();
        }
        lower.push(p);
    }
    let mut upper: Vec<usize> = Vec::new();
    for &p in order.iter().rev() {
        while upper.len() >= 2 && cross(upper[upper.len() - 2], upper[upper.len() - 1], p) <= 0.0 {
            upper.pop();
        }
        upper.push(p);
    }
    lower.extend(upper);
    lower.sort_unstable();
    lower.dedup();
    lower
}

/// The zone LP over the points `idx`: the slope.
fn zone_slope(x: &[f64], z: &[f64], idx: &[usize]) -> Result<f64> {
    let n = idx.len() as f64;
    let mx = idx.iter().map(|&i| x[i]).sum::<f64>() / n;
    let mz = idx.iter().map(|&i| z[i]).sum::<f64>() / n;
    // Scaled x keeps the LP well conditioned (x in mm over metres, z in µm).
    let sx = idx
        .iter()
        .map(|&i| (x[i] - mx).abs())
        .fold(0.0, f64::max)
        .max(1e-300);
    let mut p = Problem::new(OptimizationDirection::Minimize);
    let free = (f64::NEG_INFINITY, f64::INFINITY);
    let a = p.add_var(0.0, free);
    let lo = p.add_var(-1.0, free);
    let hi = p.add_var(1.0, free);
    for &i in idx {
        let (u, w) = ((x[i] - mx) / sx, z[i] - mz);
        p.add_constraint([(a, u), (hi, 1.0)], ComparisonOp::Ge, w);
        p.add_constraint([(a, u), (lo, 1.0)], ComparisonOp::Le, w);
    }
    let sol = p
        .solve()
        .map_err(|e| err!("minimum-zone straightness LP failed: {e}"))?;
    Ok(sol[a] / sx)
}

/// Exact minimum-zone straightness.
pub fn min_zone(x: &[f64], z: &[f64]) -> Result<Line> {
    const DIRECT: usize = 600;
    const ADD: usize = 100;
    let ls = least_squares(x, z)?;
    let hull = hull_vertices(x, z);
    let mut subset: Vec<usize> = if hull.len() <= DIRECT {
        hull.clone()
    } else {
        // Seed with the extremes of the least-squares residuals.
        let r = |i: usize| z[i] - ls.slope * x[i];
        let mut o = hull.clone();
        o.sort_by(|&i, &j| r(i).total_cmp(&r(j)).then(i.cmp(&j)));
        let mut s: Vec<usize> = o[..ADD].to_vec();
        s.extend_from_slice(&o[o.len() - ADD..]);
        s.sort_unstable();
        s.dedup();
        s
    };
    loop {
        let a = zone_slope(x, z, &subset)?;
        let (lo_s, hi_s) = spread(x, z, a, subset.iter().copied());
        let (lo, hi) = spread(x, z, a, hull.iter().copied());
        let tol = 1e-12 * (1.0 + (hi_s - lo_s).abs());
        if (hi - lo) <= (hi_s - lo_s) + tol || subset.len() == hull.len() {
            // The zone cannot be wider than the least-squares spread; a
            // solver's last-digit noise is not allowed to say otherwise.
            let w = (hi - lo).min(ls.width);
            return Ok(Line {
                slope: a,
                intercept: 0.5 * (lo + hi),
                width: w,
            });
        }
        let r = |i: usize| z[i] - a * x[i];
        let mut above: Vec<usize> = hull
            .iter()
            .copied()
            .filter(|&i| r(i) > hi_s + tol)
            .collect();
        let mut below: Vec<usize> = hull
            .iter()
            .copied()
            .filter(|&i| r(i) < lo_s - tol)
            .collect();
        above.sort_by(|&i, &j| r(j).total_cmp(&r(i)));
        below.sort_by(|&i, &j| r(i).total_cmp(&r(j)));
        subset.extend(above.into_iter().take(ADD));
        subset.extend(below.into_iter().take(ADD));
        subset.sort_unstable();
        subset.dedup();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Independent answer: the width is a convex function of the slope,
    /// piecewise linear, with its minimum at the slope of some pair of
    /// points; try every pair.
    fn brute(x: &[f64], z: &[f64]) -> f64 {
        let n = x.len();
        let mut best = f64::INFINITY;
        for i in 0..n {
            for j in i + 1..n {
                if x[i] != x[j] {
                    let a = (z[j] - z[i]) / (x[j] - x[i]);
                    let (lo, hi) = spread(x, z, a, 0..n);
                    best = best.min(hi - lo);
                }
            }
        }
        best
    }

    #[test]
    fn min_zone_matches_the_pairwise_search_and_never_exceeds_least_squares() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for case in 0..20 {
            let n = 10 + case * 3;
            let mut x: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..50.0)).collect();
            x.sort_by(f64::total_cmp);
            let z: Vec<f64> = x
                .iter()
                .map(|&u| 1e-4 * u + 2e-3 * (u / 9.0).sin() + rng.random_range(-5e-4..5e-4))
                .collect();
            let mz = min_zone(&x, &z).unwrap();
            let b = brute(&x, &z);
            assert!(
                (mz.width - b).abs() < 1e-12,
                "case {case}: {} vs {b}",
                mz.width
            );
            assert!(mz.width <= least_squares(&x, &z).unwrap().width);
        }
    }

    #[test]
    fn a_long_arc_uses_constraint_generation_and_stays_exact() {
        // Every point of a circular arc is a hull vertex.
        let n = 3001;
        let x: Vec<f64> = (0..n).map(|i| i as f64 * 0.01).collect();
        let z: Vec<f64> = x.iter().map(|&u| 1e-3 * (u - 15.0).powi(2)).collect();
        let mz = min_zone(&x, &z).unwrap();
        // A convex profile's zone lies between its chord and the parallel
        // tangent: for c·u² over [−h, h] both are level, width c·h².
        let want = 1e-3 * 15.0 * 15.0;
        assert!((mz.width - want).abs() < 1e-9, "{} vs {want}", mz.width);
    }

    #[test]
    fn a_line_is_refused_without_two_distinct_x() {
        assert!(least_squares(&[1.0, 1.0], &[0.0, 1.0]).is_err());
        assert!(least_squares(&[1.0], &[0.0]).is_err());
    }
}

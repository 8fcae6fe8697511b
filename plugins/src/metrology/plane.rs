//! Flatness of a point set (docs/models.md §2.4): the least-squares
//! reference plane (peak-to-valley of the residuals) and the exact minimum
//! zone.
//!
//! Minimum zone: the smallest distance between two parallel planes
//! enclosing all points, solved exactly as a linear programme (microlp) in
//! the plane's slopes and the two offsets: minimise c_hi − c_lo subject to
//! c_lo ≤ z_i − a·x_i − b·y_i ≤ c_hi. Distances are taken along z, as for
//! the least-squares value: heights are deviations from the nominal plane
//! (µm over metres), so the zone measured normal to the planes differs by a
//! factor 1/sqrt(1 + a² + b²), below 1e-9 relative for slopes < 4e-5.

use crate::err;
use microlp::{ComparisonOp, OptimizationDirection, Problem};
use nalgebra::{Matrix3, Vector3};
use sparkout_pipeline::Result;

/// z = a·x + b·y + c.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneFit {
    pub plane: [f64; 3],
    /// max − min of the residuals from that plane, mm.
    pub width_mm: f64,
}

fn width(x: &[f64], y: &[f64], z: &[f64], a: f64, b: f64) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for i in 0..z.len() {
        let r = z[i] - a * x[i] - b * y[i];
        lo = lo.min(r);
        hi = hi.max(r);
    }
    (lo, hi)
}

/// Least-squares plane (centred normal equations) and the peak-to-valley of
/// its residuals.
pub fn least_squares(x: &[f64], y: &[f64], z: &[f64]) -> Result<PlaneFit> {
    let n = z.len() as f64;
    let (mx, my, mz) = (
        x.iter().sum::<f64>() / n,
        y.iter().sum::<f64>() / n,
        z.iter().sum::<f64>() / n,
    );
    let mut m = Matrix3::zeros();
    let mut r = Vector3::zeros();
    for i in 0..z.len() {
        let v = Vector3::new(x[i] - mx, y[i] - my, 1.0);
        m += v * v.transpose();
        r += v * (z[i] - mz);
    }
    let s = m
        .lu()
        .solve(&r)
        .ok_or_else(|| err!("least-squares plane: the points are collinear"))?;
    let (a, b) = (s[0], s[1]);
    let c = mz + s[2] - a * mx - b * my;
    let (lo, hi) = width(x, y, z, a, b);
    Ok(PlaneFit {
        plane: [a, b, c],
        width_mm: hi - lo,
    })
}

/// Exact minimum-zone flatness by linear programming. The plane returned is
/// the zone's mid-plane; its width is re-evaluated from the points.
///
/// Large maps (an interferometer gives 10⁵–10⁶ points) are solved by
/// constraint generation: the LP over a subset gives a zone no wider than
/// the true one; its plane applied to every point gives one no narrower.
/// When the two agree the subset's answer is exact; otherwise the points
/// furthest outside are added and the LP solved again. Only points on the
/// hull of the surface matter, so a few rounds of a few hundred points do.
pub fn min_zone(x: &[f64], y: &[f64], z: &[f64]) -> Result<PlaneFit> {
    const DIRECT: usize = 600;
    const ADD: usize = 100;
    if z.len() <= DIRECT {
        let all: Vec<usize> = (0..z.len()).collect();
        return min_zone_of(x, y, z, &all);
    }
    // Start from the extremes of the least-squares residuals.
    let ls = least_squares(x, y, z)?;
    let (a, b) = (ls.plane[0], ls.plane[1]);
    let mut order: Vec<usize> = (0..z.len()).collect();
    order.sort_by(|&i, &j| {
        let (ri, rj) = (z[i] - a * x[i] - b * y[i], z[j] - a * x[j] - b * y[j]);
        ri.total_cmp(&rj).then(i.cmp(&j))
    });
    let mut subset: Vec<usize> = order[..ADD].to_vec();
    subset.extend_from_slice(&order[order.len() - ADD..]);
    loop {
        let fit = min_zone_of(x, y, z, &subset)?;
        let (a, b) = (fit.plane[0], fit.plane[1]);
        let (lo_s, hi_s) = width_of(x, y, z, a, b, &subset);
        let (lo, hi) = width(x, y, z, a, b);
        let tol = 1e-12 * (1.0 + (hi_s - lo_s).abs());
        if hi - lo <= (hi_s - lo_s) + tol || subset.len() == z.len() {
            return Ok(PlaneFit {
                plane: [a, b, 0.5 * (lo + hi)],
                width_mm: hi - lo,
            });
        }
        let r = |i: usize| z[i] - a * x[i] - b * y[i];
        let mut above: Vec<usize> = (0..z.len()).filter(|&i| r(i) > hi_s + tol).collect();
        let mut below: Vec<usize> = (0..z.len()).filter(|&i| r(i) < lo_s - tol).collect();
        above.sort_by(|&i, &j| r(j).total_cmp(&r(i)).then(i.cmp(&j)));
        below.sort_by(|&i, &j| r(i).total_cmp(&r(j)).then(i.cmp(&j)));
        subset.extend(above.into_iter().take(ADD));
        subset.extend(below.into_iter().take(ADD));
        subset.sort_unstable();
        subset.dedup();
    }
}

fn width_of(x: &[f64], y: &[f64], z: &[f64], a: f64, b: f64, idx: &[usize]) -> (f64, f64) {
    idx.iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &i| {
            let r = z[i] - a * x[i] - b * y[i];
            (lo.min(r), hi.max(r))
        })
}

/// The minimum-zone LP over the points `idx`.
fn min_zone_of(x: &[f64], y: &[f64], z: &[f64], idx: &[usize]) -> Result<PlaneFit> {
    // Centre and scale the coordinates so the LP is well conditioned.
    let n = idx.len() as f64;
    let mean = |v: &[f64]| idx.iter().map(|&i| v[i]).sum::<f64>() / n;
    let (mx, my, mz) = (mean(x), mean(y), mean(z));
    let spread = |v: &[f64], m: f64| {
        idx.iter()
            .map(|&i| (v[i] - m).abs())
            .fold(0.0, f64::max)
            .max(1e-12)
    };
    let (sx, sy) = (spread(x, mx), spread(y, my));
    let mut p = Problem::new(OptimizationDirection::Minimize);
    let free = (f64::NEG_INFINITY, f64::INFINITY);
    let a = p.add_var(0.0, free);
    let b = p.add_var(0.0, free);
    let lo = p.add_var(-1.0, free);
    let hi = p.add_var(1.0, free);
    for &i in idx {
        let (u, v, w) = ((x[i] - mx) / sx, (y[i] - my) / sy, z[i] - mz);
        p.add_constraint([(a, u), (b, v), (hi, 1.0)], ComparisonOp::Ge, w);
        p.add_constraint([(a, u), (b, v), (lo, 1.0)], ComparisonOp::Le, w);
    }
    let sol = p.solve().map_err(|e| err!("minimum-zone LP failed: {e}"))?;
    let (aa, bb) = (sol[a] / sx, sol[b] / sy);
    let (rlo, rhi) = width_of(x, y, z, aa, bb, idx);
    Ok(PlaneFit {
        plane: [aa, bb, 0.5 * (rlo + rhi)],
        width_mm: rhi - rlo,
    })
}

/// Both flatness values of one state.
#[derive(Debug, Clone, Copy)]
pub struct Flatness {
    pub least_squares: PlaneFit,
    pub min_zone: PlaneFit,
}

pub fn flatness(x: &[f64], y: &[f64], z: &[f64]) -> Result<Flatness> {
    Ok(Flatness {
        least_squares: least_squares(x, y, z)?,
        min_zone: min_zone(x, y, z)?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn min_zone_never_exceeds_least_squares_on_random_surfaces() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for case in 0..25 {
            let n = 30 + case * 7;
            let x: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..2000.0)).collect();
            let y: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..1600.0)).collect();
            let (a, b) = (rng.random_range(-1e-4..1e-4), rng.random_range(-1e-4..1e-4));
            let z: Vec<f64> = (0..n)
                .map(|i| a * x[i] + b * y[i] + rng.random_range(-0.02..0.02) + 1e-8 * x[i] * y[i])
                .collect();
            let f = flatness(&x, &y, &z).unwrap();
            assert!(
                f.min_zone.width_mm <= f.least_squares.width_mm + 1e-12,
                "case {case}: {} > {}",
                f.min_zone.width_mm,
                f.least_squares.width_mm
            );
            assert!(f.min_zone.width_mm > 0.0);
        }
    }

    #[test]
    fn min_zone_is_exact_on_two_parallel_planes() {
        // Points on z = a x + b y + c and on the same plane + h: the zone is h.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let (a, b, c, h) = (3e-5, -2e-5, 0.1, 0.0173);
        let mut x = Vec::new();
        let mut y = Vec::new();
        let mut z = Vec::new();
        for k in 0..200 {
            let (u, v) = (rng.random_range(0.0..2000.0), rng.random_range(0.0..1600.0));
            x.push(u);
            y.push(v);
            z.push(a * u + b * v + c + if k % 2 == 0 { h } else { 0.0 });
        }
        let f = min_zone(&x, &y, &z).unwrap();
        assert!((f.width_mm - h).abs() < 1e-9 * h.max(1.0), "{}", f.width_mm);
        assert!((f.plane[0] - a).abs() < 1e-12 && (f.plane[1] - b).abs() < 1e-12);
        // Least squares on the same points is no better.
        let ls = least_squares(&x, &y, &z).unwrap();
        assert!(ls.width_mm >= f.width_mm - 1e-12);
    }

    #[test]
    fn constraint_generation_matches_the_full_lp() {
        // A map above the direct-LP size: the subset loop must give the
        // zone of the LP over every point.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(21);
        let n = 1500;
        let x: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..500.0)).collect();
        let y: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..300.0)).collect();
        let z: Vec<f64> = (0..n)
            .map(|i| {
                2e-5 * x[i]
                    + 1e-3 * (x[i] / 60.0).sin() * (y[i] / 45.0).cos()
                    + rng.random_range(-2e-4..2e-4)
            })
            .collect();
        let fast = min_zone(&x, &y, &z).unwrap();
        let all: Vec<usize> = (0..n).collect();
        let full = min_zone_of(&x, &y, &z, &all).unwrap();
        assert!(
            (fast.width_mm - full.width_mm).abs() < 1e-12,
            "{} vs {}",
            fast.width_mm,
            full.width_mm
        );
        // And the width reported is the width over every point.
        let (lo, hi) = width(&x, &y, &z, fast.plane[0], fast.plane[1]);
        assert!((hi - lo - fast.width_mm).abs() < 1e-15);
    }

    #[test]
    fn least_squares_recovers_a_plane() {
        let x = [0.0, 1.0, 0.0, 1.0, 0.5];
        let y = [0.0, 0.0, 1.0, 1.0, 0.5];
        let z: Vec<f64> = x
            .iter()
            .zip(&y)
            .map(|(u, v)| 0.2 * u - 0.3 * v + 1.0)
            .collect();
        let f = least_squares(&x, &y, &z).unwrap();
        assert!((f.plane[0] - 0.2).abs() < 1e-12 && (f.plane[2] - 1.0).abs() < 1e-12);
        assert!(f.width_mm < 1e-12);
    }
}

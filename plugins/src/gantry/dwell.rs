//! Dwell-time optimisation for selective polishing
//! (docs/models.md §2.6; removal = dwell map ⊛ tool influence function).
//!
//! The tool centre may stop on a lattice: the measurement grid extended by
//! `overhang_nodes` on every side (the disc may run partly off the measured
//! area — the measured grid sits inside the stone by an edge margin,
//! docs/models.md §2.4 — which is what lets it lower the grid's edges as much as
//! its interior). A dwell map d (s per lattice node) removes K·d on the grid,
//! K the "same" FFT convolution with the sampled influence function. K is
//! symmetric (radial kernel), so Kᵀ is the same convolution of the grid
//! values embedded in the lattice.
//!
//! Two targets:
//! - [`Target::Flatten`]: heights z; minimise ½‖P(z − K·d)‖² + λ·Σd, P the
//!   projection off the best plane (a + b·x + c·y is free: the surface only
//!   has to be flat, not level), so the residual is judged two-sided about
//!   the best plane over the whole surface — removal that digs below it is
//!   penalised as much as what stays above;
//! - [`Target::Removal`]: a removal map T; minimise ½‖T − K·d‖² + λ·Σd.
//!
//! λ·Σd is the polishing time (lattice dwell), weighted by `time_weight`
//! relative to the first gradient, ‖K·P·z‖∞; it picks the quickest of the
//! nearly equally flat plans (without it the minimiser is free to add a
//! uniform layer that costs time and changes nothing).
//!
//! Constraints: 0 ≤ d ≤ max_dwell_s, and a node is either skipped (tool
//! lifted) or dwelt on for at least min_dwell_s — the dwell of a node run at
//! the machine's highest feed (lattice pitch / max feed); the longest is the
//! pitch at the lowest feed. Solved by FISTA (accelerated projected
//! gradient, step 1/L with L = (Σ kernel)² ≥ ‖K‖², adaptive restart) on the
//! box [0, max]; then nodes below min/2 are dropped, the rest clamped to
//! [min, max] and the same solver polishes the dwell on that support. Each
//! iteration is two FFT convolutions (plans and kernel spectrum kept):
//! O(N log N) per iteration, no influence matrix is formed.

use super::grid::Grid;
use super::tool_influence::{Convolver, PolishTool};

/// Machine limits and solver settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DwellLimits {
    /// Shortest non-zero dwell per lattice node (pitch / max feed), s.
    pub min_dwell_s: f64,
    /// Longest dwell per lattice node (pitch / min feed), s.
    pub max_dwell_s: f64,
    /// Lattice nodes the tool centre may go past the grid on every side.
    pub overhang_nodes: usize,
    /// Weight of the polishing time against the squared residual.
    pub time_weight: f64,
    pub iterations: usize,
}

/// What the dwell has to achieve.
#[derive(Debug, Clone, Copy)]
pub enum Target<'a> {
    /// Heights on the grid: make them flat about any plane.
    Flatten(&'a [f64]),
    /// A removal depth per grid node.
    Removal(&'a [f64]),
}

/// The dwell lattice and its convolution with the influence function.
pub struct DwellOperator {
    nx: usize,
    ny: usize,
    pad: usize,
    /// Lattice size (grid + 2·pad per axis).
    pub lx: usize,
    pub ly: usize,
    x0: f64,
    y0: f64,
    dx: f64,
    dy: f64,
    conv: Convolver,
    /// (Σ kernel)²: bounds ‖K‖² for a non-negative kernel.
    lipschitz: f64,
    /// Orthonormal basis of {1, x, y} on the grid nodes.
    plane: [Vec<f64>; 3],
}

impl DwellOperator {
    pub fn new(grid: &Grid, tool: &PolishTool, overhang_nodes: usize) -> DwellOperator {
        let (nx, ny, pad) = (grid.nx(), grid.ny(), overhang_nodes);
        let (lx, ly) = (nx + 2 * pad, ny + 2 * pad);
        let (ker, kx, ky) = tool.kernel(grid.dx, grid.dy);
        let sum: f64 = ker.iter().sum();
        // Gram–Schmidt of 1, x, y (centred, scaled) over the grid.
        let n = grid.len();
        let (xm, ym) = (
            (grid.x0 + grid.x_max()) / 2.0,
            (grid.y0 + grid.y_max()) / 2.0,
        );
        let mut plane: [Vec<f64>; 3] = [
            vec![1.0; n],
            (0..n).map(|k| grid.xy(k).0 - xm).collect(),
            (0..n).map(|k| grid.xy(k).1 - ym).collect(),
        ];
        for a in 0..3 {
            for b in 0..a {
                let p: f64 = plane[a].iter().zip(&plane[b]).map(|(u, v)| u * v).sum();
                let (head, tail) = plane.split_at_mut(a);
                tail[0]
                    .iter_mut()
                    .zip(&head[b])
                    .for_each(|(u, v)| *u -= p * v);
            }
            let norm = plane[a].iter().map(|v| v * v).sum::<f64>().sqrt();
            if norm > 0.0 {
                plane[a].iter_mut().for_each(|v| *v /= norm);
            }
        }
        DwellOperator {
            nx,
            ny,
            pad,
            lx,
            ly,
            x0: grid.x0,
            y0: grid.y0,
            dx: grid.dx,
            dy: grid.dy,
            conv: Convolver::new(lx, ly, &ker, kx, ky),
            lipschitz: (sum * sum).max(f64::MIN_POSITIVE),
            plane,
        }
    }

    pub fn lattice_len(&self) -> usize {
        self.lx * self.ly
    }

    /// Tool-centre position of lattice node k (row-major, y rows).
    pub fn lattice_xy(&self, k: usize) -> (f64, f64) {
        let (i, j) = (k % self.lx, k / self.lx);
        (
            self.x0 + (i as f64 - self.pad as f64) * self.dx,
            self.y0 + (j as f64 - self.pad as f64) * self.dy,
        )
    }

    pub fn pitch_mm(&self) -> (f64, f64) {
        (self.dx, self.dy)
    }

    /// Removal depth (mm) on the grid of a lattice dwell map (s).
    pub fn removal(&self, dwell: &[f64]) -> Vec<f64> {
        let full = self.conv.apply(dwell);
        let mut out = Vec::with_capacity(self.nx * self.ny);
        for j in 0..self.ny {
            let row = (j + self.pad) * self.lx + self.pad;
            out.extend_from_slice(&full[row..row + self.nx]);
        }
        out
    }

    /// Kᵀ: grid values → lattice (the kernel is symmetric).
    fn adjoint(&self, r: &[f64]) -> Vec<f64> {
        let mut img = vec![0.0; self.lattice_len()];
        for j in 0..self.ny {
            let row = (j + self.pad) * self.lx + self.pad;
            img[row..row + self.nx].copy_from_slice(&r[j * self.nx..(j + 1) * self.nx]);
        }
        self.conv.apply(&img)
    }

    /// v minus its least-squares plane.
    pub fn remove_plane(&self, v: &mut [f64]) {
        for q in &self.plane {
            let p: f64 = v.iter().zip(q).map(|(a, b)| a * b).sum();
            v.iter_mut().zip(q).for_each(|(a, b)| *a -= p * b);
        }
    }

    /// Residual of a dwell map for a target (plane removed for Flatten).
    pub fn residual(&self, target: Target, dwell: &[f64]) -> Vec<f64> {
        let k = self.removal(dwell);
        match target {
            Target::Flatten(z) => {
                let mut r: Vec<f64> = z.iter().zip(&k).map(|(a, b)| a - b).collect();
                self.remove_plane(&mut r);
                r
            }
            Target::Removal(t) => t.iter().zip(&k).map(|(a, b)| a - b).collect(),
        }
    }

    /// Gradient of ½‖residual‖² at d: −Kᵀ·residual.
    fn gradient(&self, target: Target, dwell: &[f64]) -> Vec<f64> {
        let r = self.residual(target, dwell);
        self.adjoint(&r).into_iter().map(|v| -v).collect()
    }

    /// FISTA with per-node bounds [lo, hi] from `start`.
    fn fista(
        &self,
        target: Target,
        lambda: f64,
        bounds: &[(f64, f64)],
        start: Vec<f64>,
        iterations: usize,
    ) -> Vec<f64> {
        let step = 1.0 / self.lipschitz;
        let mut d = start;
        let mut y = d.clone();
        let mut t = 1.0f64;
        for _ in 0..iterations {
            let g = self.gradient(target, &y);
            let next: Vec<f64> = y
                .iter()
                .zip(&g)
                .zip(bounds)
                .map(|((v, g), (lo, hi))| (v - step * (g + lambda)).clamp(*lo, *hi))
                .collect();
            // Restart the momentum when it points uphill (O'Donoghue &
            // Candès): keeps the iteration monotone on this ill-posed
            // deconvolution.
            let uphill: f64 = y
                .iter()
                .zip(&next)
                .zip(&d)
                .map(|((y, n), d)| (y - n) * (n - d))
                .sum();
            let t_next = if uphill > 0.0 {
                1.0
            } else {
                (1.0 + (1.0 + 4.0 * t * t).sqrt()) / 2.0
            };
            let beta = if uphill > 0.0 {
                0.0
            } else {
                (t - 1.0) / t_next
            };
            y = next
                .iter()
                .zip(&d)
                .map(|(n, o)| n + beta * (n - o))
                .zip(bounds)
                .map(|(v, (lo, hi))| v.clamp(*lo, *hi))
                .collect();
            d = next;
            t = t_next;
        }
        d
    }

    /// The dwell map (s per lattice node) for a target within the limits.
    pub fn solve(&self, target: Target, lim: &DwellLimits) -> Vec<f64> {
        let n = self.lattice_len();
        let g0 = self.gradient(target, &vec![0.0; n]);
        let scale = g0.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let lambda = lim.time_weight * scale;
        let hi = lim.max_dwell_s.max(0.0);
        let d = self.fista(
            target,
            lambda,
            &vec![(0.0, hi); n],
            vec![0.0; n],
            lim.iterations,
        );
        let lo = lim.min_dwell_s.min(hi);
        if lo <= 0.0 {
            return d;
        }
        // Skip or dwell at least `lo`: keep the support, polish on it.
        let bounds: Vec<(f64, f64)> = d
            .iter()
            .map(|v| if *v >= lo / 2.0 { (lo, hi) } else { (0.0, 0.0) })
            .collect();
        let start: Vec<f64> = d
            .iter()
            .zip(&bounds)
            .map(|(v, (l, h))| v.clamp(*l, *h))
            .collect();
        self.fista(target, lambda, &bounds, start, lim.iterations.div_ceil(2))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gantry::tool_influence::direct_convolve_same;

    fn tool() -> PolishTool {
        crate::gantry::tool_influence::tests::aplm_tool(100.0, 50.0)
    }

    #[test]
    fn removal_is_the_convolution_and_the_adjoint_its_transpose() {
        let grid = Grid::new(0.0, 30.0, 9, 0.0, 30.0, 7);
        let t = tool();
        let op = DwellOperator::new(&grid, &t, 2);
        let d: Vec<f64> = (0..op.lattice_len())
            .map(|k| ((k * 37) % 11) as f64 / 10.0)
            .collect();
        let (ker, kx, ky) = t.kernel(30.0, 30.0);
        let full = direct_convolve_same(&d, (op.lx, op.ly), &ker, (kx, ky));
        let rem = op.removal(&d);
        for j in 0..7 {
            for i in 0..9 {
                let want = full[(j + 2) * op.lx + i + 2];
                assert!((rem[j * 9 + i] - want).abs() < 1e-12);
            }
        }
        // <K d, r> = <d, Kᵀ r>.
        let r: Vec<f64> = (0..63).map(|k| ((k * 13) % 7) as f64 - 3.0).collect();
        let lhs: f64 = rem.iter().zip(&r).map(|(a, b)| a * b).sum();
        let rhs: f64 = d.iter().zip(op.adjoint(&r)).map(|(a, b)| a * b).sum();
        assert!((lhs - rhs).abs() < 1e-9 * lhs.abs().max(1.0));
    }

    #[test]
    fn a_bowl_is_flattened_within_the_limits() {
        let grid = Grid::new(0.0, 30.0, 31, 0.0, 30.0, 21);
        let t = tool();
        let op = DwellOperator::new(&grid, &t, 2);
        let z: Vec<f64> = (0..grid.len())
            .map(|k| {
                let (x, y) = grid.xy(k);
                0.04 * ((x - 450.0).powi(2) / 450.0f64.powi(2)
                    + (y - 300.0).powi(2) / 300.0f64.powi(2))
                    + 0.005 * (x / 170.0).sin()
            })
            .collect();
        let lim = DwellLimits {
            min_dwell_s: 0.06,
            max_dwell_s: 30.0,
            overhang_nodes: 2,
            time_weight: 1e-4,
            iterations: 600,
        };
        let d = op.solve(Target::Flatten(&z), &lim);
        assert!(d
            .iter()
            .all(|v| *v == 0.0 || (*v >= 0.06 - 1e-12 && *v <= 30.0)));
        let before = {
            let mut r = z.clone();
            op.remove_plane(&mut r);
            r.iter().cloned().fold(f64::MIN, f64::max) - r.iter().cloned().fold(f64::MAX, f64::min)
        };
        let r = op.residual(Target::Flatten(&z), &d);
        let after =
            r.iter().cloned().fold(f64::MIN, f64::max) - r.iter().cloned().fold(f64::MAX, f64::min);
        assert!(after < 0.25 * before, "{after} vs {before}");
    }
}

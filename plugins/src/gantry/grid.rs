//! The measurement grid (docs/models.md §2.4): a topography state's points must
//! form a regular rectangular grid, each node exactly once. Bad grids are
//! errors that name the file, the column and the offending row.

use std::collections::BTreeMap;

use sparkout_pipeline::contracts::Table;
use sparkout_pipeline::InputError;

use super::config::STATES;

/// A regular grid: x_i = x0 + i·dx, y_j = y0 + j·dy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    pub x0: f64,
    pub dx: f64,
    pub y0: f64,
    pub dy: f64,
    nx: usize,
    ny: usize,
}

impl Grid {
    pub fn new(x0: f64, dx: f64, nx: usize, y0: f64, dy: f64, ny: usize) -> Grid {
        Grid {
            x0,
            dx,
            y0,
            dy,
            nx,
            ny,
        }
    }
    pub fn nx(&self) -> usize {
        self.nx
    }
    pub fn ny(&self) -> usize {
        self.ny
    }
    pub fn len(&self) -> usize {
        self.nx * self.ny
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    pub fn x(&self, i: usize) -> f64 {
        self.x0 + i as f64 * self.dx
    }
    pub fn y(&self, j: usize) -> f64 {
        self.y0 + j as f64 * self.dy
    }
    pub fn x_max(&self) -> f64 {
        self.x(self.nx - 1)
    }
    pub fn y_max(&self) -> f64 {
        self.y(self.ny - 1)
    }
    /// (x, y) of node k (row-major, y rows).
    pub fn xy(&self, k: usize) -> (f64, f64) {
        (self.x(k % self.nx), self.y(k / self.nx))
    }
    pub fn area_mm2(&self) -> f64 {
        (self.x_max() - self.x0) * (self.y_max() - self.y0)
    }
    /// Bilinear interpolation of node values at (x, y), clamped to the grid.
    pub fn bilinear(&self, v: &[f64], x: f64, y: f64) -> f64 {
        let fx = ((x - self.x0) / self.dx).clamp(0.0, (self.nx - 1) as f64);
        let fy = ((y - self.y0) / self.dy).clamp(0.0, (self.ny - 1) as f64);
        let (i0, j0) = (fx.floor() as usize, fy.floor() as usize);
        let (i1, j1) = ((i0 + 1).min(self.nx - 1), (j0 + 1).min(self.ny - 1));
        let (u, w) = (fx - i0 as f64, fy - j0 as f64);
        let n = self.nx;
        v[j0 * n + i0] * (1.0 - u) * (1.0 - w)
            + v[j0 * n + i1] * u * (1.0 - w)
            + v[j1 * n + i0] * (1.0 - u) * w
            + v[j1 * n + i1] * u * w
    }
}

/// One topography state on its grid.
#[derive(Debug, Clone)]
pub struct Surface {
    pub state: String,
    pub grid: Grid,
    /// Heights, row-major (y rows), mm.
    pub z: Vec<f64>,
    /// Measurement times, when the table has t_s.
    pub t: Option<Vec<f64>>,
}

/// The states present, in the file's canonical order (pattern → before →
/// after_grind → after_polish → final), unknown state names after them in
/// order of first appearance.
pub fn states(table: &Table) -> Result<Vec<String>, InputError> {
    let col = table.str("state")?;
    let mut seen: Vec<String> = Vec::new();
    for s in col {
        if !seen.iter().any(|x| x == s) {
            seen.push(s.to_string());
        }
    }
    let mut out: Vec<String> = STATES
        .iter()
        .filter(|s| seen.iter().any(|x| x == *s))
        .map(|s| s.to_string())
        .collect();
    out.extend(seen.into_iter().filter(|s| !STATES.contains(&s.as_str())));
    Ok(out)
}

/// Distinct sorted values, merging those closer than `tol`.
fn distinct(v: &[f64], tol: f64) -> Vec<f64> {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let mut out: Vec<f64> = Vec::new();
    for x in s {
        if out.last().is_none_or(|l| x - l > tol) {
            out.push(x);
        }
    }
    out
}

/// One state's surface, checked to be a regular grid with every node once.
pub fn surface(table: &Table, state: &str) -> Result<Surface, InputError> {
    let path = table.path();
    let st = table.str("state")?;
    let (xs, ys) = (table.f64("x_mm")?, table.f64("y_mm")?);
    let ts = table.opt_f64("t_s");
    let rows: Vec<usize> = (0..table.len()).filter(|&r| st[r] == state).collect();
    if rows.is_empty() {
        let have = states(table)?;
        return Err(InputError::new(
            path,
            format!(
                "no rows with state `{state}` (states present: {})",
                have.join(", ")
            ),
        )
        .column("state"));
    }
    let x: Vec<f64> = rows.iter().map(|&r| xs[r]).collect();
    let y: Vec<f64> = rows.iter().map(|&r| ys[r]).collect();
    let span = |v: &[f64]| {
        v.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
            - v.iter().cloned().fold(f64::INFINITY, f64::min)
    };
    let tol = 1e-6 * span(&x).max(span(&y)).max(1.0);
    let ux = distinct(&x, tol);
    let uy = distinct(&y, tol);
    if ux.len() < 2 || uy.len() < 2 {
        return Err(InputError::new(
            path,
            format!(
                "state `{state}`: {} distinct x and {} distinct y values; a measurement grid needs at least 2 of each",
                ux.len(),
                uy.len()
            ),
        )
        .column(if ux.len() < 2 { "x_mm" } else { "y_mm" }));
    }
    let step = |u: &[f64], col: &str| -> Result<f64, InputError> {
        let d = (u[u.len() - 1] - u[0]) / (u.len() - 1) as f64;
        for (k, w) in u.windows(2).enumerate() {
            if ((w[1] - w[0]) - d).abs() > 1e-6 * d.max(1.0) {
                // Name a row holding the offending coordinate.
                let v = w[1];
                let c = if col == "x_mm" { &x } else { &y };
                let r = c.iter().position(|a| (a - v).abs() <= tol).map(|p| rows[p]);
                let mut e = InputError::new(
                    path,
                    format!(
                        "state `{state}`: irregular grid — {col} spacing {:.6} between {} and {} differs from the mean step {:.6} (value {} of {}); the grid must be regular (docs/models.md §2.4)",
                        w[1] - w[0],
                        w[0],
                        w[1],
                        d,
                        k + 1,
                        u.len()
                    ),
                )
                .column(col);
                if let Some(r) = r {
                    e = e.row(r);
                }
                return Err(e);
            }
        }
        Ok(d)
    };
    let dx = step(&ux, "x_mm")?;
    let dy = step(&uy, "y_mm")?;
    let grid = Grid::new(ux[0], dx, ux.len(), uy[0], dy, uy.len());
    let mut z = vec![f64::NAN; grid.len()];
    let mut t = ts.map(|_| vec![f64::NAN; grid.len()]);
    let mut first: BTreeMap<usize, usize> = BTreeMap::new();
    let zs = table.f64("z_mm")?;
    for (p, &r) in rows.iter().enumerate() {
        let i = ((x[p] - grid.x0) / dx).round() as usize;
        let j = ((y[p] - grid.y0) / dy).round() as usize;
        let k = j * grid.nx() + i;
        if let Some(&r0) = first.get(&k) {
            return Err(InputError::new(
                path,
                format!(
                    "state `{state}`: duplicated grid point (x = {}, y = {}) in rows {r0} and {r}; each grid point must be measured once per state",
                    x[p], y[p]
                ),
            )
            .column("x_mm")
            .row(r));
        }
        first.insert(k, r);
        z[k] = zs[r];
        if let (Some(t), Some(ts)) = (t.as_mut(), ts) {
            t[k] = ts[r];
        }
    }
    if let Some(k) = z.iter().position(|v| v.is_nan()) {
        let (gx, gy) = grid.xy(k);
        return Err(InputError::new(
            path,
            format!(
                "state `{state}`: grid point (x = {gx}, y = {gy}) is missing ({} of {} points present); the grid must be complete",
                rows.len(),
                grid.len()
            ),
        )
        .column("x_mm"));
    }
    Ok(Surface {
        state: state.to_string(),
        grid,
        z,
        t,
    })
}

/// The pattern state, which the compensation matrices are referred to
/// (docs/models.md §2.1): a topography without one is a bad input.
/// What every surface stage starts from: the run's gantry, its
/// topography table and the `pattern` state's surface (which fixes the
/// grid every other state must share).
pub fn run_surface(
    ctx: &sparkout_pipeline::StageContext,
) -> sparkout_pipeline::Result<(super::machine::Gantry, std::sync::Arc<Table>, Surface)> {
    let g = super::machine::Gantry::from_run(&ctx.run.machine, &ctx.run.spec)?;
    let t = ctx.run.require(&crate::gantry::tables::TOPOGRAPHY)?;
    let pattern = pattern(&t)?;
    Ok((g, t, pattern))
}

pub fn pattern(table: &Table) -> Result<Surface, InputError> {
    let have = states(table)?;
    if !have.iter().any(|s| s == "pattern") {
        return Err(InputError::new(
            table.path(),
            format!(
                "no `pattern` state (states present: {}); the gantry's compensation matrices are Γ = τ − τ_pattern, so the reference (pattern) surface must be measured (docs/models.md §2.1)",
                have.join(", ")
            ),
        )
        .column("state"));
    }
    surface(table, "pattern")
}

/// A state's surface on the same grid as `reference` (else an error naming
/// the state).
pub fn same_grid(table: &Table, state: &str, reference: &Grid) -> Result<Surface, InputError> {
    let s = surface(table, state)?;
    let g = &s.grid;
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-6 * (a.abs() + b.abs()).max(1.0);
    if g.nx() != reference.nx()
        || g.ny() != reference.ny()
        || !close(g.x0, reference.x0)
        || !close(g.y0, reference.y0)
        || !close(g.dx, reference.dx)
        || !close(g.dy, reference.dy)
    {
        return Err(InputError::new(
            table.path(),
            format!(
                "state `{state}` is on a {}×{} grid from ({}, {}) step ({}, {}), not the pattern's {}×{} grid from ({}, {}) step ({}, {}); measure every state on the same grid",
                g.nx(), g.ny(), g.x0, g.y0, g.dx, g.dy,
                reference.nx(), reference.ny(), reference.x0, reference.y0, reference.dx, reference.dy
            ),
        )
        .column("state"));
    }
    Ok(s)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::gantry::tables::TOPOGRAPHY;
    use sparkout_pipeline::contracts::BatchBuilder;

    pub fn table(rows: &[(&str, f64, f64, f64)]) -> Table {
        let b = BatchBuilder::new()
            .str("state", &rows.iter().map(|r| r.0).collect::<Vec<_>>())
            .f64("x_mm", rows.iter().map(|r| r.1).collect())
            .f64("y_mm", rows.iter().map(|r| r.2).collect())
            .f64("z_mm", rows.iter().map(|r| r.3).collect())
            .build();
        Table::from_batch(std::path::Path::new("topography.parquet"), &TOPOGRAPHY, b).unwrap()
    }

    fn grid_rows(
        state: &'static str,
        xs: &[f64],
        ys: &[f64],
    ) -> Vec<(&'static str, f64, f64, f64)> {
        let mut v = Vec::new();
        for &y in ys {
            for &x in xs {
                v.push((state, x, y, 0.001 * x - 0.002 * y));
            }
        }
        v
    }

    #[test]
    fn reads_a_regular_grid_in_any_row_order() {
        let mut rows = grid_rows("pattern", &[0.0, 10.0, 20.0], &[5.0, 15.0]);
        rows.reverse();
        rows.extend(grid_rows("after_grind", &[0.0, 10.0, 20.0], &[5.0, 15.0]));
        let t = table(&rows);
        let s = pattern(&t).unwrap();
        assert_eq!((s.grid.nx(), s.grid.ny()), (3, 2));
        assert!((s.z[3 + 2] - (0.02 - 0.03)).abs() < 1e-15);
        assert_eq!(states(&t).unwrap(), vec!["pattern", "after_grind"]);
        assert!(same_grid(&t, "after_grind", &s.grid).is_ok());
    }

    #[test]
    fn bad_grids_are_named() {
        // No pattern state.
        let t = table(&grid_rows("before", &[0.0, 1.0], &[0.0, 1.0]));
        let e = pattern(&t).unwrap_err();
        assert_eq!(e.column.as_deref(), Some("state"));
        assert!(e.message.contains("no `pattern` state"), "{e}");
        // Duplicated point: rows 0 and 4.
        let mut rows = grid_rows("pattern", &[0.0, 1.0], &[0.0, 1.0]);
        rows.push(("pattern", 0.0, 0.0, 0.0));
        let e = pattern(&table(&rows)).unwrap_err();
        assert!(
            e.message
                .contains("duplicated grid point (x = 0, y = 0) in rows 0 and 4"),
            "{e}"
        );
        assert_eq!(e.row, Some(4));
        // Irregular spacing in x.
        let rows = grid_rows("pattern", &[0.0, 10.0, 25.0], &[0.0, 1.0]);
        let e = pattern(&table(&rows)).unwrap_err();
        assert!(e.message.contains("irregular grid"), "{e}");
        assert_eq!(e.column.as_deref(), Some("x_mm"));
        assert!(e.row.is_some());
        // Missing node.
        let mut rows = grid_rows("pattern", &[0.0, 1.0, 2.0], &[0.0, 1.0]);
        rows.remove(4);
        let e = pattern(&table(&rows)).unwrap_err();
        assert!(
            e.message.contains("grid point (x = 1, y = 1) is missing"),
            "{e}"
        );
    }
}

//! The replay source: a run's commanded path (motion.parquet, cmd_* per
//! docs/formats.md §4) plus an optional compensation Parquet (`t_s` and any of
//! `dx_mm`, `dy_mm`, `dz_mm`: the gantry's Γ sampled along the path, the
//! guide-way compensation curve, or anyone's offsets), both resampled to the
//! replay cycle.

use std::path::Path;

use arrow::array::{Array, Float64Array};
use arrow::compute::cast;
use arrow::datatypes::DataType;

use crate::contracts::schema::MOTION;
use crate::contracts::{read_parquet, RunSpec, Table};
use crate::error::{Error, InputError, Result};

/// Compensation columns, one per axis (x, y, z).
pub const COMP_COLUMNS: [&str; 3] = ["dx_mm", "dy_mm", "dz_mm"];

/// The path to stream, one entry per cycle.
#[derive(Debug, Clone, Default)]
pub struct Plan {
    /// Source time of cycle 0 (s); cycle k is at t0_s + k·cycle.
    pub t0_s: f64,
    pub cmd_mm: Vec<[f64; 3]>,
    pub comp_mm: Vec<[f64; 3]>,
    /// Passed through to the recorded run when the source has them.
    pub feed_mm_s: Option<Vec<f64>>,
    pub segment: Option<Vec<i32>>,
}

/// Linear interpolation of (t, v) at increasing query times `q`, holding
/// the end values outside [t0, tn]; `t` non-decreasing (a repeated time
/// takes its last value).
pub fn resample_linear(t: &[f64], v: &[f64], q: &[f64]) -> Vec<f64> {
    let mut out = Vec::with_capacity(q.len());
    let mut i = 0usize;
    for &x in q {
        while i + 1 < t.len() && t[i + 1] <= x {
            i += 1;
        }
        let y = if x < t[0] {
            v[0]
        } else if i + 1 < t.len() && t[i + 1] > t[i] {
            let w = (x - t[i]) / (t[i + 1] - t[i]);
            v[i] + w * (v[i + 1] - v[i])
        } else {
            v[i]
        };
        out.push(y);
    }
    out
}

/// Sample-and-hold (the value of the last row with t ≤ q).
fn resample_hold<T: Copy>(t: &[f64], v: &[T], q: &[f64]) -> Vec<T> {
    let mut i = 0usize;
    q.iter()
        .map(|&x| {
            while i + 1 < t.len() && t[i + 1] <= x {
                i += 1;
            }
            v[i]
        })
        .collect()
}

/// The cycle grid over [t_first, t_last] of a motion table.
fn grid(t_first: f64, t_last: f64, cycle_s: f64) -> Vec<f64> {
    let n = ((t_last - t_first) / cycle_s + 1e-9).floor() as usize + 1;
    (0..n).map(|k| t_first + k as f64 * cycle_s).collect()
}

/// A compensation's offsets per axis (x, y, z), `None` where the file has
/// no such column.
pub type AxisOffsets = [Option<Vec<f64>>; 3];

/// Read and check a compensation Parquet; (t_s, per-axis offsets).
pub fn read_compensation(path: &Path) -> Result<(Vec<f64>, AxisOffsets)> {
    // A bad file read by sparkout-core stays this crate's bad input.
    let batch = read_parquet(path).map_err(|e| match e.input() {
        Some(ie) => Error::Input(ie.clone()),
        None => Error::Core(e),
    })?;
    let names: Vec<String> = batch
        .schema()
        .fields()
        .iter()
        .map(|f| f.name().clone())
        .collect();
    // Axis-like: d + a 1–2 character axis name + _mm (da_mm, dw_mm, dx2_mm …).
    for n in &names {
        let axis_like = n
            .strip_prefix('d')
            .and_then(|r| r.strip_suffix("_mm"))
            .is_some_and(|a| {
                (1..=2).contains(&a.len()) && a.chars().all(|c| c.is_ascii_alphanumeric())
            });
        if axis_like && !COMP_COLUMNS.contains(&n.as_str()) {
            return Err(InputError::new(
                path,
                format!(
                    "unknown axis `{n}`: replay drives x, y and z; name the offsets dx_mm, dy_mm, dz_mm"
                ),
            )
            .column(n.as_str())
            .into());
        }
    }
    let col = |name: &str| -> Result<Option<Vec<f64>>, InputError> {
        let Some(c) = batch.column_by_name(name) else {
            return Ok(None);
        };
        if !matches!(c.data_type(), DataType::Float64 | DataType::Float32) {
            return Err(InputError::new(
                path,
                format!("wrong type {} (float64 expected)", c.data_type()),
            )
            .column(name));
        }
        let c = cast(c, &DataType::Float64)
            .map_err(|e| InputError::new(path, format!("cannot convert: {e}")).column(name))?;
        let a = c
            .as_any()
            .downcast_ref::<Float64Array>()
            .expect("cast to f64");
        if let Some(row) = (0..a.len()).find(|&i| a.is_null(i) || !a.value(i).is_finite()) {
            let what = if a.is_null(row) {
                "null".to_string()
            } else {
                a.value(row).to_string()
            };
            return Err(
                InputError::new(path, format!("{what} (offsets must be finite numbers)"))
                    .column(name)
                    .row(row),
            );
        }
        Ok(Some(a.values().to_vec()))
    };
    let t = col("t_s")?.ok_or_else(|| {
        InputError::new(
            path,
            format!(
                "a compensation needs a t_s column (s, strictly increasing) and offsets dx_mm/dy_mm/dz_mm; columns present: {}",
                names.join(", ")
            ),
        )
        .column("t_s")
    })?;
    if t.is_empty() {
        return Err(InputError::new(path, "compensation table is empty").into());
    }
    if let Some(i) = t.windows(2).position(|w| w[1] <= w[0]) {
        return Err(InputError::new(
            path,
            format!(
                "t_s must be strictly increasing ({} after {})",
                t[i + 1],
                t[i]
            ),
        )
        .column("t_s")
        .row(i + 1)
        .into());
    }
    let axes = [
        col(COMP_COLUMNS[0])?,
        col(COMP_COLUMNS[1])?,
        col(COMP_COLUMNS[2])?,
    ];
    if axes.iter().all(|a| a.is_none()) {
        return Err(InputError::new(
            path,
            format!(
                "no offset column: a compensation needs at least one of dx_mm, dy_mm, dz_mm (columns present: {})",
                names.join(", ")
            ),
        )
        .into());
    }
    Ok((t, axes))
}

/// Load a run's commanded path and an optional compensation, resampled to
/// `cycle_s`.
pub fn load_plan(
    run_dir: &Path,
    compensation: Option<&Path>,
    cycle_s: f64,
) -> Result<(RunSpec, Plan)> {
    let spec = RunSpec::load(run_dir)?;
    let motion_path = run_dir.join("motion.parquet");
    if !motion_path.is_file() {
        return Err(InputError::new(
            &motion_path,
            "the run has no motion.parquet: replay streams a run's commanded path (t_s, cmd_x_mm, cmd_y_mm, cmd_z_mm)",
        )
        .into());
    }
    let motion = Table::read(&motion_path, &MOTION)?;
    let t = motion.f64("t_s")?;
    let q = grid(t[0], t[t.len() - 1], cycle_s);
    let cmd: Vec<Vec<f64>> = ["cmd_x_mm", "cmd_y_mm", "cmd_z_mm"]
        .iter()
        .map(|c| Ok(resample_linear(t, motion.f64(c)?, &q)))
        .collect::<Result<_, InputError>>()?;
    let mut comp = vec![[0.0; 3]; q.len()];
    if let Some(path) = compensation {
        let (ct, axes) = read_compensation(path)?;
        for (a, v) in axes.iter().enumerate() {
            if let Some(v) = v {
                for (k, c) in resample_linear(&ct, v, &q).into_iter().enumerate() {
                    comp[k][a] = c;
                }
            }
        }
    }
    let feed_mm_s = motion
        .opt_f64("feed_mm_s")
        .filter(|f| f.iter().all(|v| v.is_finite()))
        .map(|f| resample_linear(t, f, &q));
    let segment = motion.opt_i32("segment").map(|s| resample_hold(t, s, &q));
    let plan = Plan {
        t0_s: t[0],
        cmd_mm: (0..q.len())
            .map(|k| [cmd[0][k], cmd[1][k], cmd[2][k]])
            .collect(),
        comp_mm: comp,
        feed_mm_s,
        segment,
    };
    Ok((spec, plan))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linear_resampling_holds_ends_and_handles_repeats() {
        let t = [0.0, 1.0, 1.0, 3.0];
        let v = [0.0, 10.0, 20.0, 40.0];
        let q = [-1.0, 0.0, 0.5, 1.0, 2.0, 3.0, 4.0];
        assert_eq!(
            resample_linear(&t, &v, &q),
            vec![0.0, 0.0, 5.0, 20.0, 30.0, 40.0, 40.0]
        );
        assert_eq!(
            resample_hold(&t, &[1, 2, 3, 4], &q),
            vec![1, 1, 1, 3, 3, 4, 4]
        );
    }

    #[test]
    fn grid_covers_the_run_at_the_cycle() {
        let g = grid(0.5, 0.512, 0.004);
        assert_eq!(g.len(), 4);
        assert!((g[3] - 0.512).abs() < 1e-12);
    }
}

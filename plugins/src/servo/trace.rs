//! The servo trace of a run: per axis, commanded and actual position, and
//! commanded/actual velocity and commanded acceleration — logged where the
//! controller logs them (motion.parquet v1.1 columns, docs/formats.md §4 and
//! docs/servo.md), else by central differences of the logged positions.

use arrow::array::Array;
use sparkout_pipeline::contracts::schema::MOTION;
use sparkout_pipeline::contracts::Table;
use sparkout_pipeline::{InputError, Run};

use super::config::AXES;

/// Where a velocity came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    Logged,
    Differences,
}

impl Source {
    pub fn as_str(self) -> &'static str {
        match self {
            Source::Logged => "logged",
            Source::Differences => "differences",
        }
    }
}

/// One axis of a trace.
#[derive(Debug, Clone)]
pub struct AxisTrace {
    /// `x`, `y` or `z`.
    pub axis: &'static str,
    pub index: usize,
    pub cmd_mm: Vec<f64>,
    pub act_mm: Vec<f64>,
    pub cmd_v_mm_s: Vec<f64>,
    /// Logged actual velocity (the velocity error is then act − cmd
    /// velocity; without it, the rate of the following error).
    pub act_v_mm_s: Option<Vec<f64>>,
    pub cmd_a_mm_s2: Vec<f64>,
    pub cmd_v_source: Source,
    pub cmd_a_source: Source,
}

/// A run's trace: time, per-axis traces (axes with an `act_<a>_mm` column)
/// and the optional path feed and program segment (line).
#[derive(Debug, Clone)]
pub struct Trace {
    pub t_s: Vec<f64>,
    pub axes: Vec<AxisTrace>,
    /// Axes without actual positions (cannot be compared).
    pub skipped: Vec<&'static str>,
    /// All three commanded positions (covariates x_mm, y_mm, z_mm).
    pub cmd_xyz_mm: [Vec<f64>; 3],
    pub feed_mm_s: Option<Vec<f64>>,
    pub segment: Option<Vec<i32>>,
}

/// Central differences dy/dt over non-uniform, possibly repeated times
/// (one-sided at the ends; a zero time step keeps the previous rate).
pub fn derivative(t: &[f64], y: &[f64]) -> Vec<f64> {
    let n = t.len();
    let mut d = vec![0.0; n];
    if n < 2 {
        return d;
    }
    for i in 0..n {
        let (a, b) = (i.saturating_sub(1), (i + 1).min(n - 1));
        let dt = t[b] - t[a];
        d[i] = if dt > 0.0 {
            (y[b] - y[a]) / dt
        } else if i > 0 {
            d[i - 1]
        } else {
            0.0
        };
    }
    d
}

/// A logged optional column, all finite, or `None`. A column present with a
/// null/NaN is a bad input naming the row (a gap in the log would silently
/// switch the source of a velocity).
fn logged(table: &Table, col: &str) -> Result<Option<Vec<f64>>, InputError> {
    let Some(v) = table.opt_f64(col) else {
        return Ok(None);
    };
    let arr = table.batch().column_by_name(col).expect("has");
    if let Some(i) = (0..arr.len()).find(|&i| arr.is_null(i) || !v[i].is_finite()) {
        return Err(InputError::new(
            table.path(),
            "null or non-finite value in a logged servo column (log it on every row or leave the column out)",
        )
        .column(col)
        .row(i));
    }
    Ok(Some(v.to_vec()))
}

impl Trace {
    pub fn read(run: &Run) -> Result<Trace, InputError> {
        let m = run.require(&MOTION)?;
        Self::from_table(&m)
    }

    pub fn from_table(m: &Table) -> Result<Trace, InputError> {
        let t = m.f64("t_s")?.to_vec();
        let cmd_xyz_mm = [
            m.f64("cmd_x_mm")?.to_vec(),
            m.f64("cmd_y_mm")?.to_vec(),
            m.f64("cmd_z_mm")?.to_vec(),
        ];
        let mut axes = Vec::new();
        let mut skipped = Vec::new();
        for (i, a) in AXES.iter().enumerate() {
            let Some(act) = logged(m, &format!("act_{a}_mm"))? else {
                skipped.push(*a);
                continue;
            };
            let cmd = cmd_xyz_mm[i].clone();
            let (cmd_v, cmd_v_source) = match logged(m, &format!("cmd_v_{a}_mm_s"))? {
                Some(v) => (v, Source::Logged),
                None => (derivative(&t, &cmd), Source::Differences),
            };
            let (cmd_a, cmd_a_source) = match logged(m, &format!("cmd_a_{a}_mm_s2"))? {
                Some(v) => (v, Source::Logged),
                None => (derivative(&t, &cmd_v), Source::Differences),
            };
            axes.push(AxisTrace {
                axis: a,
                index: i,
                cmd_mm: cmd,
                act_mm: act,
                cmd_v_mm_s: cmd_v,
                act_v_mm_s: logged(m, &format!("act_v_{a}_mm_s"))?,
                cmd_a_mm_s2: cmd_a,
                cmd_v_source,
                cmd_a_source,
            });
        }
        if axes.is_empty() {
            return Err(InputError::new(
                m.path(),
                "the servo plugin compares commanded with actual positions: motion.parquet needs at least one of act_x_mm, act_y_mm, act_z_mm",
            )
            .column("act_x_mm"));
        }
        let segment = if m.has("segment") {
            let arr = m.batch().column_by_name("segment").expect("has");
            if let Some(i) = (0..arr.len()).find(|&i| arr.is_null(i)) {
                return Err(InputError::new(m.path(), "null segment")
                    .column("segment")
                    .row(i));
            }
            Some(m.i32("segment")?.to_vec())
        } else {
            None
        };
        Ok(Trace {
            t_s: t,
            axes,
            skipped,
            cmd_xyz_mm,
            feed_mm_s: logged(m, "feed_mm_s")?,
            segment,
        })
    }
}

/// Direction of travel (+1/−1) per sample from the commanded velocity; at
/// rest (|v| ≤ standstill) the last direction is held (the first motion's
/// before any), so a reversal is a change of sign between two motions.
/// Also the commanded distance travelled since the last reversal (mm, by
/// integrating |v|, which quantised positions cannot give); the first
/// motion of the run counts as a reversal (breakaway from rest).
pub fn direction(t: &[f64], v: &[f64], standstill_mm_s: f64) -> (Vec<f64>, Vec<f64>) {
    let n = v.len();
    let first = v
        .iter()
        .find(|x| x.abs() > standstill_mm_s)
        .map_or(1.0, |x| x.signum());
    let mut dir = Vec::with_capacity(n);
    let mut dist = Vec::with_capacity(n);
    let (mut cur, mut d) = (first, 0.0);
    for i in 0..n {
        if i > 0 {
            let dt = (t[i] - t[i - 1]).max(0.0);
            d += 0.5 * (v[i].abs() + v[i - 1].abs()) * dt;
        }
        if v[i].abs() > standstill_mm_s && v[i].signum() != cur {
            cur = v[i].signum();
            // The reversal happened between the samples: the distance since
            // the zero crossing, not since the previous sample.
            d = if i > 0 && v[i - 1] * v[i] < 0.0 {
                let dt = (t[i] - t[i - 1]).max(0.0);
                0.5 * v[i].abs() * dt * v[i].abs() / (v[i].abs() + v[i - 1].abs())
            } else {
                0.0
            };
        }
        dir.push(cur);
        dist.push(d);
    }
    (dir, dist)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derivative_of_a_parabola_and_repeated_times() {
        let t = [0.0, 1.0, 2.0, 2.0, 3.0];
        let y: Vec<f64> = t.iter().map(|t| t * t).collect();
        let d = derivative(&t, &y);
        assert_eq!(d[1], 2.0);
        assert_eq!(d[0], 1.0);
        assert!(d.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn direction_holds_through_rest_and_resets_distance_at_reversal() {
        let t: Vec<f64> = (0..8).map(|i| i as f64).collect();
        let v = [0.0, 2.0, 2.0, 0.0, 2.0, -2.0, -2.0, 0.0];
        let (dir, d) = direction(&t, &v, 1e-3);
        assert_eq!(dir, vec![1.0, 1.0, 1.0, 1.0, 1.0, -1.0, -1.0, -1.0]);
        assert_eq!(d[1], 1.0);
        assert_eq!(d[4], 5.0, "rest does not reset");
        assert_eq!(d[5], 0.5, "reversal half way between samples");
        assert_eq!(d[6], 2.5);
    }
}

//! `flatness`: least-squares reference plane (peak-to-valley of the
//! residuals) and exact minimum-zone flatness (MODELS.md §2.4) of any
//! topography state (`state` key, default the last state in the order
//! pattern → before → after_grind → after_polish → final).
//!
//! Minimum zone: the smallest distance between two parallel planes
//! enclosing all points, solved exactly as a linear programme (microlp) in
//! the plane's slopes and the two offsets: minimise c_hi − c_lo subject to
//! c_lo ≤ z_i − a·x_i − b·y_i ≤ c_hi. Distances are taken along z, as for
//! the least-squares value: heights are deviations from the nominal plane
//! (µm over metres), so the zone measured normal to the planes differs by a
//! factor 1/sqrt(1 + a² + b²), below 1e-9 relative for slopes < 4e-5.

use anyhow::{anyhow, Context};
use microlp::{ComparisonOp, OptimizationDirection, Problem};
use nalgebra::{Matrix3, Vector3};
use serde_json::{json, Value};
use sparkout_pipeline::contracts::schema::TOPOGRAPHY;
use sparkout_pipeline::contracts::{BatchBuilder, Table};
use sparkout_pipeline::{Result, Stage, StageArgs, StageContext, StageOutput, StageSpec};

use super::config::{check_config, Check, STATES};
use super::grid;

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
        .ok_or_else(|| anyhow!("least-squares plane: the points are collinear"))?;
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
pub fn min_zone(x: &[f64], y: &[f64], z: &[f64]) -> Result<PlaneFit> {
    // Centre and scale the coordinates so the LP is well conditioned.
    let n = z.len() as f64;
    let (mx, my, mz) = (
        x.iter().sum::<f64>() / n,
        y.iter().sum::<f64>() / n,
        z.iter().sum::<f64>() / n,
    );
    let sx = x
        .iter()
        .map(|v| (v - mx).abs())
        .fold(0.0, f64::max)
        .max(1e-12);
    let sy = y
        .iter()
        .map(|v| (v - my).abs())
        .fold(0.0, f64::max)
        .max(1e-12);
    let mut p = Problem::new(OptimizationDirection::Minimize);
    let free = (f64::NEG_INFINITY, f64::INFINITY);
    let a = p.add_var(0.0, free);
    let b = p.add_var(0.0, free);
    let lo = p.add_var(-1.0, free);
    let hi = p.add_var(1.0, free);
    for i in 0..z.len() {
        let (u, v, w) = ((x[i] - mx) / sx, (y[i] - my) / sy, z[i] - mz);
        p.add_constraint([(a, u), (b, v), (hi, 1.0)], ComparisonOp::Ge, w);
        p.add_constraint([(a, u), (b, v), (lo, 1.0)], ComparisonOp::Le, w);
    }
    let sol = p
        .solve()
        .map_err(|e| anyhow!("minimum-zone LP failed: {e}"))?;
    let (aa, bb) = (sol[a] / sx, sol[b] / sy);
    let (rlo, rhi) = width(x, y, z, aa, bb);
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

fn state_points(t: &Table, state: &str) -> Result<(Vec<f64>, Vec<f64>, Vec<f64>)> {
    let st = t.str("state")?;
    let (xs, ys, zs) = (t.f64("x_mm")?, t.f64("y_mm")?, t.f64("z_mm")?);
    let rows: Vec<usize> = (0..t.len()).filter(|&r| st[r] == state).collect();
    if rows.len() < 3 {
        let have = grid::states(t)?;
        return Err(sparkout_pipeline::InputError::new(
            t.path(),
            format!(
                "state `{state}` has {} points; flatness needs at least 3 (states present: {})",
                rows.len(),
                have.join(", ")
            ),
        )
        .column("state")
        .into());
    }
    Ok((
        rows.iter().map(|&r| xs[r]).collect(),
        rows.iter().map(|&r| ys[r]).collect(),
        rows.iter().map(|&r| zs[r]).collect(),
    ))
}

/// Flatness of every state (artifact rows) and the JSON of the chosen one.
pub fn analyse(t: &Table, state: Option<&str>) -> Result<(Vec<(String, Flatness)>, Value)> {
    let states = grid::states(t)?;
    let chosen = match state {
        Some(s) => s.to_string(),
        None => states
            .last()
            .cloned()
            .ok_or_else(|| anyhow!("topography has no rows"))?,
    };
    if !states.contains(&chosen) {
        return Err(sparkout_pipeline::InputError::new(
            t.path(),
            format!(
                "no rows with state `{chosen}` (states present: {})",
                states.join(", ")
            ),
        )
        .column("state")
        .into());
    }
    let mut all = Vec::new();
    for s in &states {
        let (x, y, z) = state_points(t, s)?;
        all.push((
            s.clone(),
            flatness(&x, &y, &z).with_context(|| format!("state `{s}`"))?,
        ));
    }
    let f = all
        .iter()
        .find(|(s, _)| *s == chosen)
        .expect("chosen state")
        .1;
    let per_state: Vec<Value> = all
        .iter()
        .map(|(s, f)| json!({"state": s, "least_squares_mm": f.least_squares.width_mm, "min_zone_mm": f.min_zone.width_mm}))
        .collect();
    let summary = json!({
        "state": chosen,
        "least_squares_mm": f.least_squares.width_mm,
        "min_zone_mm": f.min_zone.width_mm,
        "plane": f.min_zone.plane,
        "least_squares_plane": f.least_squares.plane,
        "states": per_state,
    });
    Ok((all, summary))
}

pub struct FlatnessStage;

const KEYS: &[(&str, Check)] = &[("state", Check::OneOf(&STATES))];

const SPEC: StageSpec = StageSpec {
    name: "flatness",
    version: 1,
    reads: &[&TOPOGRAPHY],
    reads_artifacts: &[],
    writes: &["flatness"],
    about: "least-squares and exact minimum-zone flatness of a topography state (MODELS.md §2.4)",
};

impl Stage for FlatnessStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn validate_config(&self, config: &toml::Table) -> Result<()> {
        check_config(config, KEYS)
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let t = ctx.run.require(&TOPOGRAPHY)?;
        let state = ctx.config.get("state").and_then(|v| v.as_str());
        let (all, summary) = analyse(&t, state)?;
        Ok(StageOutput::new(summary).with("flatness", batch(&all)))
    }
    /// `sparkout stage flatness --topography FILE [--state NAME] --json`.
    fn run_standalone(&self, args: &StageArgs) -> Option<Result<Value>> {
        let file = args.get("topography")?;
        Some((|| {
            for k in args.keys() {
                if k != "topography" && k != "state" {
                    anyhow::bail!("unknown flag --{k} for `flatness` (known: --topography FILE, --state NAME)");
                }
            }
            let t = Table::read(std::path::Path::new(file), &TOPOGRAPHY)?;
            Ok(analyse(&t, args.get("state").map(|s| s.as_str()))?.1)
        })())
    }
}

fn batch(all: &[(String, Flatness)]) -> arrow::record_batch::RecordBatch {
    BatchBuilder::new()
        .str(
            "state",
            &all.iter().map(|a| a.0.as_str()).collect::<Vec<_>>(),
        )
        .f64(
            "least_squares_mm",
            all.iter().map(|a| a.1.least_squares.width_mm).collect(),
        )
        .f64(
            "min_zone_mm",
            all.iter().map(|a| a.1.min_zone.width_mm).collect(),
        )
        .f64(
            "plane_a",
            all.iter().map(|a| a.1.min_zone.plane[0]).collect(),
        )
        .f64(
            "plane_b",
            all.iter().map(|a| a.1.min_zone.plane[1]).collect(),
        )
        .f64(
            "plane_c_mm",
            all.iter().map(|a| a.1.min_zone.plane[2]).collect(),
        )
        .build()
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

//! `observe`: paired observations `surface_z` (docs/formats.md §7), one row per
//! grid node: real = the measured polished state (default `after_polish`),
//! sim = the `removal` stage's predicted final topography (the measured
//! ground surface minus the Preston removal of the path that was run).
//!
//! Covariates from the polishing path sample nearest to the node (the moment
//! the tool centre passed over it): x_mm, y_mm, t_s, feed_mm_s, dir (pass
//! direction), path_end_mm (distance along the pass to its nearer end),
//! a_mm_s2 (|tangential acceleration|), tool_removed_mm3 (volume the tool
//! had removed before then: contact time × the disc's volume rate). y_mm is
//! the spindle's position along the bridge in this machine's frame, which
//! the gantry's `thermal_bow` composite reads (composites apply only to
//! their plugin's observables).

use crate::err;
use crate::gantry::tables::TOPOGRAPHY;
use serde::{Deserialize, Serialize};
use sparkout_pipeline::config_check::SectionCheck;
use sparkout_pipeline::contracts::schema::MOTION;
use sparkout_pipeline::contracts::{batch_f64, BatchBuilder};
use sparkout_pipeline::{Result, Stage, StageContext, StageOutput, StageSpec};

use super::config::ObserveConfig;
use super::grid::{self, Grid};
use super::removal::{polishing_path, RemovalSummary};
use super::tool_influence::PathSample;

pub const OBSERVABLE: &str = "surface_z";

pub struct ObserveStage;

/// Index of the on-pass sample nearest to each node (all samples when the
/// path has no passes).
pub fn nearest_samples(grid: &Grid, path: &[PathSample]) -> Vec<usize> {
    let on: Vec<usize> = (0..path.len()).filter(|&k| path[k].segment >= 0).collect();
    let cand: Vec<usize> = if on.is_empty() {
        (0..path.len()).collect()
    } else {
        on
    };
    (0..grid.len())
        .map(|k| {
            let (x, y) = grid.xy(k);
            let mut best = (f64::INFINITY, 0);
            for &s in &cand {
                let d = (path[s].x_mm - x).powi(2) + (path[s].y_mm - y).powi(2);
                if d < best.0 {
                    best = (d, s);
                }
            }
            best.1
        })
        .collect()
}

const SPEC: StageSpec = StageSpec {
    name: "observe",
    // 2: no bridge_y_mm column (thermal_bow reads y_mm).
    // 3: `sim_augmented` from the removal's thermal-bow re-simulation.
    version: 3,
    reads: &[&TOPOGRAPHY, &MOTION],
    reads_artifacts: &["removal"],
    writes: &["observations"],
    reads_augmented_model: false,
    about: "paired observations surface_z (measured polished vs predicted) for the gap diagnosis (docs/formats.md)",
    config: SectionCheck::of::<ObserveConfig>(),
};

/// `observe.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ObserveSummary {
    pub rows: usize,
    pub observable: String,
    /// The topography state observed.
    pub state: String,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub rms_gap_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub max_abs_gap_mm: f64,
}

impl Stage for ObserveStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let (g, t, pattern) = grid::run_surface(ctx)?;
        let cfg: &ObserveConfig = ctx.section()?;
        let state = cfg.state.as_str();
        let real = grid::same_grid(&t, state, &pattern.grid)?;
        let rem = ctx.artifacts.require("removal")?;
        let sim = batch_f64(&rem, "final_mm")?;
        if sim.len() != real.z.len() {
            return Err(err!(
                "removal artifact has {} nodes, the `{state}` state {}",
                sim.len(),
                real.z.len()
            ));
        }
        let grid = real.grid;
        let (path, _) = polishing_path(ctx.run, &g, &grid, cfg.path == "motion")?;
        if path.is_empty() {
            return Err(err!("the polishing path has no samples"));
        }
        let near = nearest_samples(&grid, &path);
        // Cumulative contact time before each sample.
        let mut cum = vec![0.0; path.len()];
        for k in 1..path.len() {
            cum[k] = cum[k - 1] + path[k - 1].dt_s;
        }
        let vol = g.polish.volume_rate_mm3_s();
        let n = grid.len();
        let (xs, ys): (Vec<f64>, Vec<f64>) = (0..n).map(|k| grid.xy(k)).unzip();
        let pick = |f: &dyn Fn(&PathSample) -> f64| {
            near.iter().map(|&s| f(&path[s])).collect::<Vec<f64>>()
        };
        let path_end = pick(&|p| {
            if p.path_end_mm.is_finite() {
                p.path_end_mm
            } else {
                0.0
            }
        });
        let gap: Vec<f64> = (0..n).map(|k| real.z[k] - sim[k]).collect();
        let rms = (gap.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
        let mut batch = BatchBuilder::new()
            .str("run", &vec![ctx.run.spec.id.as_str(); n])
            .str("observable", &vec![OBSERVABLE; n])
            .f64("sim", sim.to_vec())
            .f64("real", real.z.clone())
            .f64("x_mm", xs)
            .f64("y_mm", ys)
            .f64("t_s", pick(&|p| p.t_s))
            .f64("feed_mm_s", pick(&|p| p.feed_mm_s))
            .f64("dir", pick(&|p| p.dir))
            .f64("path_end_mm", path_end)
            .f64("a_mm_s2", pick(&|p| p.a_mm_s2))
            .f64(
                "tool_removed_mm3",
                near.iter().map(|&s| cum[s] * vol).collect(),
            );
        // `run --augment`: the removal stage re-simulated the thermal bow in
        // the physics (gantry/augment.rs); its final surface is this sim.
        let in_physics = ctx
            .artifacts
            .summary_as::<RemovalSummary>("removal")
            .transpose()?
            .and_then(|s| s.augmented)
            .map(|a| a.in_physics);
        if let (Some(keys), Ok(aug)) = (&in_physics, batch_f64(&rem, "final_augmented_mm")) {
            batch = batch
                .f64("sim_augmented", aug.to_vec())
                .str("sim_augmented_effects", &vec![keys.as_str(); n]);
        }
        let batch = batch.build();
        let summary = ObserveSummary {
            rows: n,
            observable: OBSERVABLE.to_string(),
            state: state.to_string(),
            rms_gap_mm: rms,
            max_abs_gap_mm: gap.iter().map(|v| v.abs()).fold(0.0, f64::max),
        };
        Ok(StageOutput::typed(&summary)?.with("observations", batch))
    }
}

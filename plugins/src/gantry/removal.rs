//! `removal`: Preston removal of the polishing path actually run (motion.parquet,
//! or a planned raster when the run has none) from the ground surface: the
//! dwell-time map of the path convolved by FFT with the disc tool's
//! influence function, and the predicted final topography (docs/models.md §2.5).

use crate::gantry::tables::TOPOGRAPHY;
use crate::Context;
use serde::{Deserialize, Serialize};
use sparkout_pipeline::config_check::SectionCheck;
use sparkout_pipeline::contracts::schema::MOTION;
use sparkout_pipeline::contracts::BatchBuilder;
use sparkout_pipeline::{InputError, Result, Run, Stage, StageContext, StageOutput, StageSpec};

use super::augment::ThermalBow;
use super::config::RemovalConfig;
use super::grid::{self, Grid, Surface};
use super::machine::{Gantry, PassAxis};
use super::tool_influence::{
    complete_path, dwell_map, raster_path, removal_of_dwell, PathSample, PolishTool,
};

/// Controller rate of planned paths, Hz.
pub const PLAN_RATE_HZ: f64 = 50.0;

/// A tool larger than the surface cannot polish it selectively or by raster.
pub fn check_tool_fits(g: &Gantry, grid: &Grid, topo: &std::path::Path) -> Result<(), InputError> {
    let d = 2.0 * g.polish.radius_mm;
    let (lx, ly) = (grid.x_max() - grid.x0, grid.y_max() - grid.y0);
    if d > lx.min(ly) {
        return Err(InputError::new(
            topo,
            format!(
                "polishing tool diameter {d:.1} mm is larger than the surface ({lx:.1} × {ly:.1} mm); use a smaller tool ([polishing].tool_radius_mm / tool_area_mm2 in {}, or [process].tool_radius_mm)",
                g.source
            ),
        )
        .column("x_mm"));
    }
    Ok(())
}

/// The polishing path: the run's motion log when it has one, else a raster
/// over the grid planned from the tool's feed, step-over and acceleration.
pub fn polishing_path(
    run: &Run,
    g: &Gantry,
    grid: &Grid,
    prefer_motion: bool,
) -> Result<(Vec<PathSample>, &'static str)> {
    let axis_x = g.pass_axis == PassAxis::X;
    if prefer_motion {
        if let Some(m) = run.table(&MOTION)? {
            let (t, x, y) = (m.f64("t_s")?, m.f64("cmd_x_mm")?, m.f64("cmd_y_mm")?);
            let seg: Vec<i32> = match m.opt_i32("segment") {
                Some(s) => s.to_vec(),
                None => passes_from_positions(x, y, axis_x),
            };
            return Ok((complete_path(t, x, y, &seg, axis_x), "motion"));
        }
    }
    Ok((plan_raster(grid, &g.polish, axis_x), "raster"))
}

pub fn plan_raster(grid: &Grid, tool: &PolishTool, axis_x: bool) -> Vec<PathSample> {
    raster_path(
        grid,
        tool.feed_mm_s,
        tool.step_over_mm,
        tool.accel_mm_s2,
        PLAN_RATE_HZ,
        axis_x,
    )
}

/// Passes when a log has no segment column: runs of constant cross
/// coordinate (y for passes along x).
fn passes_from_positions(x: &[f64], y: &[f64], axis_x: bool) -> Vec<i32> {
    let c = if axis_x { y } else { x };
    let mut out = vec![-1; c.len()];
    let mut id = 0;
    let mut k = 0;
    while k < c.len() {
        let mut e = k;
        while e + 1 < c.len() && (c[e + 1] - c[k]).abs() < 1e-6 {
            e += 1;
        }
        if e > k {
            for o in out.iter_mut().take(e + 1).skip(k) {
                *o = id;
            }
            id += 1;
        }
        k = e + 1;
    }
    out
}

/// The removal prediction of one run.
pub struct Removal {
    pub start: Surface,
    pub dwell_s: Vec<f64>,
    pub removal_mm: Vec<f64>,
    pub final_mm: Vec<f64>,
    pub path: Vec<PathSample>,
    pub path_source: &'static str,
}

pub fn predict(run: &Run, g: &Gantry, start: Surface, prefer_motion: bool) -> Result<Removal> {
    let (path, src) = polishing_path(run, g, &start.grid, prefer_motion)?;
    let dwell = dwell_map(&start.grid, &path, |_| 1.0);
    let removal = removal_of_dwell(&start.grid, &g.polish, &dwell);
    let final_mm = start.z.iter().zip(&removal).map(|(z, r)| z - r).collect();
    Ok(Removal {
        start,
        dwell_s: dwell,
        removal_mm: removal,
        final_mm,
        path,
        path_source: src,
    })
}

/// `run --augment` (gantry/augment.rs): the removal re-simulated with the
/// thermal bow's pressure loss along the path, plus the effect's constant
/// part, as the final surface per node; and what was applied.
fn with_thermal_bow(
    r: &Removal,
    g: &Gantry,
    bow: &ThermalBow,
    node_y_mm: &[f64],
) -> Result<(Vec<f64>, RemovalAugmented)> {
    let mean_removal = r.removal_mm.iter().sum::<f64>() / r.removal_mm.len().max(1) as f64;
    let (py, pt): (Vec<f64>, Vec<f64>) = r.path.iter().map(|p| (p.y_mm, p.t_s)).unzip();
    let evaluated =
        |v: Option<Vec<f64>>| v.context("the augmented model's thermal bow cannot be evaluated");
    let growth = evaluated(bow.growth(&py, &pt))?;
    let offset = evaluated(bow.offset(node_y_mm))?;
    let scale = if mean_removal > 0.0 {
        1.0 / mean_removal
    } else {
        0.0
    };
    let grid = &r.start.grid;
    let dwell = dwell_map(grid, &r.path, |k| (1.0 - growth[k] * scale).max(0.0));
    let removal = removal_of_dwell(grid, &g.polish, &dwell);
    let fin = (0..grid.len())
        .map(|k| r.start.z[k] - removal[k] + offset[k])
        .collect();
    let lift_max =
        growth.iter().fold(0.0f64, |m, v| m.max(v.abs())) * scale * g.polish.spring_compression_mm;
    Ok((
        fin,
        RemovalAugmented {
            in_physics: bow.keys(),
            mean_removal_mm: mean_removal,
            bridge_lift_max_mm: lift_max,
        },
    ))
}

/// `removal.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RemovalSummary {
    /// The topography state the removal starts from.
    pub from_state: String,
    /// Where the polishing path came from (`motion`, `raster`).
    pub path: String,
    pub path_samples: usize,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub duration_s: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub tool_radius_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub pressure_pa: f64,
    /// Preston coefficient.
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub k_p_per_pa: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub removal_mean_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub removal_max_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub removal_min_mm: f64,
    /// Only under `run --augment` with a thermal bow.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub augmented: Option<RemovalAugmented>,
}

/// `removal.json` `augmented`: the thermal bow the removal re-simulated.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RemovalAugmented {
    pub in_physics: String,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub mean_removal_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub bridge_lift_max_mm: f64,
}

pub struct RemovalStage;

const SPEC: StageSpec = StageSpec {
    name: "removal",
    // 2: `final_augmented_mm` under `run --augment`; summary `augmented`.
    version: 2,
    reads: &[&TOPOGRAPHY, &MOTION],
    reads_artifacts: &[],
    writes: &["removal"],
    reads_augmented_model: true,
    about: "Preston removal of the polishing path (dwell ⊛ tool influence, FFT) and the predicted final topography (docs/models.md §2.5)",
    config: SectionCheck::of::<RemovalConfig>(),
};

impl Stage for RemovalStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let (g, t, pattern) = grid::run_surface(ctx)?;
        let cfg: &RemovalConfig = ctx.section()?;
        let from = cfg.from_state.as_str();
        let start = grid::same_grid(&t, from, &pattern.grid)?;
        check_tool_fits(&g, &start.grid, t.path())?;
        let r = predict(ctx.run, &g, start, cfg.path == "motion").context("removal")?;
        let grid = r.start.grid;
        let n = grid.len();
        let (xs, ys): (Vec<f64>, Vec<f64>) = (0..n).map(|k| grid.xy(k)).unzip();
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let duration = r.path.last().map(|p| p.t_s).unwrap_or(0.0)
            - r.path.first().map(|p| p.t_s).unwrap_or(0.0);
        let mut summary = RemovalSummary {
            from_state: from.to_string(),
            path: r.path_source.to_string(),
            path_samples: r.path.len(),
            duration_s: duration,
            tool_radius_mm: g.polish.radius_mm,
            pressure_pa: g.polish.pressure_pa,
            k_p_per_pa: g.polish.k_p_per_pa,
            removal_mean_mm: mean(&r.removal_mm),
            removal_max_mm: r.removal_mm.iter().cloned().fold(0.0, f64::max),
            removal_min_mm: r.removal_mm.iter().cloned().fold(f64::INFINITY, f64::min),
            augmented: None,
        };
        let mut batch = BatchBuilder::new()
            .f64("x_mm", xs)
            .f64("y_mm", ys.clone())
            .f64("start_mm", r.start.z.clone())
            .f64("dwell_s", r.dwell_s.clone())
            .f64("removal_mm", r.removal_mm.clone())
            .f64("final_mm", r.final_mm.clone());
        if let Some(bow) = ThermalBow::of(ctx) {
            let (fin, info) = with_thermal_bow(&r, &g, &bow, &ys)?;
            batch = batch.f64("final_augmented_mm", fin);
            summary.augmented = Some(info);
        }
        Ok(StageOutput::typed(&summary)?.with("removal", batch.build()))
    }
}

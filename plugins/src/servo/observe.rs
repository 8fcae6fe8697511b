//! `observe`: paired observations (docs/formats.md §7) for the gap diagnosis.
//!
//! Per sample and axis with actual positions: `following_error_<axis>`
//! (mm) and `velocity_error_<axis>` (mm/s — the one observable whose state
//! is not a length, docs/servo.md), sim from the servo model, real as
//! measured. `real_u` is the standard uncertainty of `real` from the
//! logging resolution (never a covariate; the diagnosis keeps its noise
//! floor at or above it).
//!
//! Covariates: `t_s`; the axis' commanded velocity `cmd_v_mm_s` (signed:
//! lag), acceleration `cmd_a_mm_s2` (inertia), jerk `cmd_j_mm_s3` (central
//! differences of the acceleration: on a velocity error an error ∝
//! acceleration shows ∝ jerk), direction `dir` (±1, held
//! at rest: backlash), commanded distance since the axis last reversed
//! `reversal_mm` (reversal spike); all three commanded positions `x_mm`,
//! `y_mm`, `z_mm` (scale, bow, periodic, squareness); and, when logged,
//! the path feed `feed_mm_s` and the program `segment` (line).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use sparkout_pipeline::config_check::SectionCheck;
use sparkout_pipeline::contracts::schema::MOTION;
use sparkout_pipeline::contracts::{batch_f64, BatchBuilder};
use sparkout_pipeline::{Result, Stage, StageContext, StageOutput, StageSpec};

use super::config::ObserveConfig;
use super::trace::{derivative, direction, Trace};

pub struct ObserveStage;

/// Observable names of an axis.
pub fn observables(axis: &str) -> [String; 2] {
    [
        format!("following_error_{axis}"),
        format!("velocity_error_{axis}"),
    ]
}

const SPEC: StageSpec = StageSpec {
    name: "observe",
    version: 2,
    reads: &[&MOTION],
    reads_artifacts: &["following_error"],
    writes: &["observations"],
    reads_augmented_model: false,
    about: "paired observations following_error_<axis> (mm) and velocity_error_<axis> (mm/s) for the gap diagnosis",
    config: SectionCheck::of::<ObserveConfig>(),
};

/// `observe.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ObserveSummary {
    pub rows: usize,
    /// Per axis with actual positions, by axis name.
    pub axes: BTreeMap<String, AxisReversals>,
    /// Which optional covariates the run logged.
    pub covariates: Covariates,
}

/// One axis of `observe.json`: how often its commanded direction reversed.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AxisReversals {
    pub reversals: usize,
}

/// `observe.json` `covariates`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Covariates {
    pub feed_mm_s: bool,
    pub segment: bool,
}

impl Stage for ObserveStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let cfg: &ObserveConfig = ctx.section()?;
        let trace = Trace::read(ctx.run)?;
        let fe = ctx.artifacts.require("following_error")?;
        let n = trace.t_s.len();
        let (mut obs, mut sim, mut real, mut u) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        // observations v1.1 `unit`: velocity errors are mm/s, and the
        // diagnosis prints each observable in its own unit.
        let mut units: Vec<&str> = Vec::new();
        let (mut v, mut a, mut dir, mut rev) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut j = Vec::new();
        let mut rows: Vec<usize> = Vec::new();
        let mut per = BTreeMap::new();
        for ax in &trace.axes {
            let (d, r) = direction(&trace.t_s, &ax.cmd_v_mm_s, cfg.standstill_mm_s);
            let reversals = d.windows(2).filter(|w| w[0] != w[1]).count();
            let jerk = derivative(&trace.t_s, &ax.cmd_a_mm_s2);
            let [fe_name, ve_name] = observables(ax.axis);
            for (name, kind) in [(fe_name, "e"), (ve_name, "ve")] {
                let unit = if kind == "e" { "mm" } else { "mm_s" };
                sim.extend_from_slice(batch_f64(&fe, &format!("sim_{kind}_{}_{unit}", ax.axis))?);
                real.extend_from_slice(batch_f64(&fe, &format!("real_{kind}_{}_{unit}", ax.axis))?);
                u.extend_from_slice(batch_f64(&fe, &format!("u_{kind}_{}_{unit}", ax.axis))?);
                obs.extend(std::iter::repeat_n(name, n));
                units.extend(std::iter::repeat_n(
                    if kind == "e" { "mm" } else { "mm/s" },
                    n,
                ));
                v.extend_from_slice(&ax.cmd_v_mm_s);
                a.extend_from_slice(&ax.cmd_a_mm_s2);
                j.extend_from_slice(&jerk);
                dir.extend_from_slice(&d);
                rev.extend_from_slice(&r);
                rows.extend(0..n);
            }
            per.insert(ax.axis.to_string(), AxisReversals { reversals });
        }
        let pick = |col: &[f64]| -> Vec<f64> { rows.iter().map(|&i| col[i]).collect() };
        let mut b = BatchBuilder::new()
            .str("run", &vec![ctx.run.spec.id.as_str(); rows.len()])
            .str("observable", &obs)
            .str("unit", &units)
            .f64("sim", sim)
            .f64("real", real)
            .f64("real_u", u)
            .f64("t_s", pick(&trace.t_s))
            .f64("cmd_v_mm_s", v)
            .f64("cmd_a_mm_s2", a)
            .f64("cmd_j_mm_s3", j)
            .f64("dir", dir)
            .f64("reversal_mm", rev)
            .f64("x_mm", pick(&trace.cmd_xyz_mm[0]))
            .f64("y_mm", pick(&trace.cmd_xyz_mm[1]))
            .f64("z_mm", pick(&trace.cmd_xyz_mm[2]));
        if let Some(f) = &trace.feed_mm_s {
            b = b.f64("feed_mm_s", pick(f));
        }
        if let Some(s) = &trace.segment {
            b = b.i32("segment", rows.iter().map(|&i| s[i]).collect());
        }
        let summary = ObserveSummary {
            rows: rows.len(),
            axes: per,
            covariates: Covariates {
                feed_mm_s: trace.feed_mm_s.is_some(),
                segment: trace.segment.is_some(),
            },
        };
        Ok(StageOutput::typed(&summary)?.with("observations", b.build()))
    }
}

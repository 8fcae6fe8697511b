//! `observe`: paired observations (docs/formats.md §7) for the gap diagnosis.
//!
//! One row per tracker point and machine axis: `tracker_dx`, `tracker_dy`,
//! `tracker_dz`. real = the measured deviation of the tool point from its
//! nominal position along that machine axis (the tracker measurement rotated
//! back by the identified tracker frame); sim = the deviation the identified
//! 21-error model predicts there (docs/models.md §5). What the polynomial model
//! cannot hold — thermal growth during the measurement, error shapes beyond
//! its degree — is the gap.
//!
//! Covariates: x_mm, y_mm, z_mm (commanded axis positions), t_s (when
//! tracker.parquet has it) and temp_c (the thermal.parquet reading
//! interpolated at t_s: one named sensor, or the mean of all). A covariate
//! the run cannot provide is left out of its table (docs/formats.md §7: an
//! absent covariate makes the effects that need it inapplicable); in a
//! fleet table those rows are null. `point` identifies the measurement
//! (reserved, never a covariate), with `trial` for re-measured
//! points: the diagnosis takes its noise floor from such replicates.

use std::collections::BTreeMap;

use crate::mill::tables::TRACKER;
use sparkout_pipeline::config_check::SectionCheck;
use sparkout_pipeline::contracts::schema::THERMAL;
use sparkout_pipeline::contracts::{BatchBuilder, Table};
use sparkout_pipeline::{InputError, Result, Stage, StageContext, StageOutput, StageSpec};

use super::augment::SpindleGrowth;
use super::config::{MillMachine, ObserveConfig};
use super::kinematics::{model_from_params, tracker_points};
use super::summary::{AugmentedGrowth, ObservableGap, ObserveCovariates, ObserveSummary};

pub const OBSERVABLES: [&str; 3] = ["tracker_dx", "tracker_dy", "tracker_dz"];

/// Temperature at given times from thermal.parquet: per sensor linear
/// interpolation (clamped at the ends), one sensor or the mean of all.
pub fn temperature_at(
    thermal: &Table,
    sensor: Option<&str>,
    t: &[f64],
) -> Result<Vec<f64>, InputError> {
    let ts = thermal.f64("t_s")?;
    let names = thermal.str("sensor")?;
    let temp = thermal.f64("temp_c")?;
    let mut by: BTreeMap<&str, Vec<(f64, f64)>> = BTreeMap::new();
    for i in 0..ts.len() {
        by.entry(names[i]).or_default().push((ts[i], temp[i]));
    }
    let chosen: Vec<&Vec<(f64, f64)>> = match sensor {
        Some(s) => vec![by.get(s).ok_or_else(|| {
            InputError::new(
                thermal.path(),
                format!(
                    "no sensor `{s}` ([mill.observe] temp_sensor); sensors present: {}",
                    by.keys().copied().collect::<Vec<_>>().join(", ")
                ),
            )
            .column("sensor")
        })?],
        None => by.values().collect(),
    };
    let interp = |s: &[(f64, f64)], x: f64| -> f64 {
        let j = s.partition_point(|p| p.0 <= x);
        if j == 0 {
            s[0].1
        } else if j == s.len() {
            s[s.len() - 1].1
        } else {
            let (a, b) = (s[j - 1], s[j]);
            if b.0 > a.0 {
                a.1 + (b.1 - a.1) * (x - a.0) / (b.0 - a.0)
            } else {
                b.1
            }
        }
    };
    Ok(t.iter()
        .map(|&x| chosen.iter().map(|s| interp(s, x)).sum::<f64>() / chosen.len() as f64)
        .collect())
}

pub struct ObserveStage;

const SPEC: StageSpec = StageSpec {
    name: "observe",
    // 2: `sim_augmented` on tracker_dz under `run --augment`.
    version: 2,
    reads: &[&TRACKER, &THERMAL],
    reads_artifacts: &["kinematic_params"],
    writes: &["observations"],
    reads_augmented_model: true,
    about: "paired observations tracker_dx/dy/dz (measured vs identified model) for the gap diagnosis (docs/formats.md)",
    config: SectionCheck::of::<ObserveConfig>(),
};

impl Stage for ObserveStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let cfg: &ObserveConfig = ctx.section()?;
        // The tool offsets come from the machine; identification settings do
        // not matter here (the model is read back from its artifact).
        let machine = MillMachine::from_config(&ctx.run.machine)?;
        let data = tracker_points(ctx.run, &machine)?;
        let params = ctx.artifacts.require("kinematic_params")?;
        let model = model_from_params(&params, machine.travels)?;
        let n = data.obs.len();
        let temp = match (&data.t_s, ctx.run.table(&THERMAL)?) {
            (Some(t), Some(th)) => Some(temperature_at(&th, cfg.temp_sensor.as_deref(), t)?),
            _ => None,
        };
        let mut real = Vec::with_capacity(3 * n);
        let mut sim = Vec::with_capacity(3 * n);
        let mut obs_name = Vec::with_capacity(3 * n);
        let mut rows = Vec::with_capacity(3 * n);
        for (k, name) in OBSERVABLES.iter().enumerate() {
            for (i, o) in data.obs.iter().enumerate() {
                let measured = model.to_machine(&o.m) - o.pt.nominal();
                real.push(measured[k]);
                sim.push(model.deviation(&o.pt)[k]);
                obs_name.push(*name);
                rows.push(i);
            }
        }
        let mut b = BatchBuilder::new()
            .str("run", &vec![ctx.run.spec.id.as_str(); rows.len()])
            .str("observable", &obs_name)
            .f64("sim", sim.clone())
            .f64("real", real.clone())
            .i32("point", rows.iter().map(|&i| data.point[i]).collect())
            .i32("trial", rows.iter().map(|&i| data.trial[i]).collect());
        for (a, name) in ["x_mm", "y_mm", "z_mm"].iter().enumerate() {
            b = b.f64(name, rows.iter().map(|&i| data.obs[i].pt.q[a]).collect());
        }
        if let Some(t) = &data.t_s {
            b = b.f64("t_s", rows.iter().map(|&i| t[i]).collect());
        }
        if let Some(temp) = &temp {
            b = b.f64("temp_c", rows.iter().map(|&i| temp[i]).collect());
        }
        // `run --augment`: the spindle's growth along z (mill/augment.rs).
        let mut augmented = None;
        if let (Some(sg), Some(t)) = (SpindleGrowth::of(ctx), &data.t_s) {
            if let Some((g, offset)) = sg.growth_and_offset(t, temp.as_deref()) {
                let keys = sg.keys();
                let dz = 2 * n;
                b = b
                    .opt_f64(
                        "sim_augmented",
                        (0..rows.len())
                            .map(|r| (r >= dz).then(|| sim[r] + g[rows[r]] + offset))
                            .collect(),
                    )
                    .opt_str(
                        "sim_augmented_effects",
                        (0..rows.len())
                            .map(|r| (r >= dz).then_some(keys.as_str()))
                            .collect(),
                    );
                augmented = Some(AugmentedGrowth {
                    in_physics: keys,
                    growth_max_mm: g.iter().fold(0.0f64, |m, v| m.max(v.abs())),
                });
            }
        }
        let mut per = BTreeMap::new();
        for (k, name) in OBSERVABLES.iter().enumerate() {
            let g = &(k * n..(k + 1) * n);
            let ms = real[g.clone()]
                .iter()
                .zip(&sim[g.clone()])
                .map(|(r, s)| (r - s) * (r - s))
                .sum::<f64>()
                / n as f64;
            per.insert(
                name.to_string(),
                ObservableGap {
                    n,
                    rms_gap_mm: ms.sqrt(),
                },
            );
        }
        let summary = ObserveSummary {
            rows: rows.len(),
            observables: per,
            covariates: ObserveCovariates {
                t_s: data.t_s.is_some(),
                temp_c: temp.is_some(),
            },
            augmented,
        };
        Ok(StageOutput::typed(&summary)?.with("observations", b.build()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    #[test]
    fn temperature_interpolates_per_sensor_and_averages() {
        let batch = BatchBuilder::new()
            .f64("t_s", vec![0.0, 0.0, 10.0, 10.0])
            .str("sensor", &["a", "b", "a", "b"])
            .f64("temp_c", vec![20.0, 30.0, 22.0, 30.0])
            .build();
        let t = Table::from_batch(Path::new("thermal.parquet"), &THERMAL, batch).unwrap();
        let v = temperature_at(&t, None, &[5.0, 20.0]).unwrap();
        assert!((v[0] - 25.5).abs() < 1e-12 && (v[1] - 26.0).abs() < 1e-12);
        let a = temperature_at(&t, Some("a"), &[-1.0, 5.0]).unwrap();
        assert_eq!(a, vec![20.0, 21.0]);
        let e = temperature_at(&t, Some("spindle"), &[1.0]).unwrap_err();
        assert_eq!(e.column.as_deref(), Some("sensor"));
    }
}

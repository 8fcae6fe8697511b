//! `follow`: the commanded path of every axis through the machine's servo
//! model (model.rs) beside what the axis did: simulated and measured
//! following error e = actual − commanded (mm) and velocity error (mm/s).
//!
//! The velocity error is act − cmd velocity where the controller logs both;
//! else the rate of the following error by central differences, applied to
//! the measured and the simulated error alike (so the difference operator
//! cancels in the gap). Each value carries the standard uncertainty its
//! logging resolution implies (config.rs `Resolution`): quantised positions
//! cannot show a following error finer than their step.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use sparkout_pipeline::config_check::{NoKeys, SectionCheck};
use sparkout_pipeline::contracts::schema::MOTION;
use sparkout_pipeline::contracts::BatchBuilder;
use sparkout_pipeline::{Result, Stage, StageContext, StageOutput, StageSpec};

use super::config::{ServoMachine, AXES};
use super::model::simulate;
use super::trace::{derivative, AxisTrace, Source, Trace};

/// One axis compared with its model.
#[derive(Debug, Clone)]
pub struct AxisCompare {
    pub axis: &'static str,
    pub real_e_mm: Vec<f64>,
    pub sim_e_mm: Vec<f64>,
    pub u_e_mm: Vec<f64>,
    pub real_ve_mm_s: Vec<f64>,
    pub sim_ve_mm_s: Vec<f64>,
    pub u_ve_mm_s: Vec<f64>,
    pub ve_source: Source,
}

/// Simulated vs measured following and velocity errors of one axis.
pub fn compare(t: &[f64], a: &AxisTrace, m: &ServoMachine) -> AxisCompare {
    let (sim_e, sim_edot) = simulate(m.axes[a.index], t, &a.cmd_v_mm_s);
    let real_e: Vec<f64> = a.act_mm.iter().zip(&a.cmd_mm).map(|(x, c)| x - c).collect();
    let u_e: Vec<f64> = a
        .act_mm
        .iter()
        .zip(&a.cmd_mm)
        .map(|(x, c)| m.position.u_diff(*x, *c))
        .collect();
    let n = t.len();
    let (real_ve, sim_ve, u_ve, src): (Vec<f64>, Vec<f64>, Vec<f64>, Source) = match &a.act_v_mm_s {
        Some(av) => (
            av.iter().zip(&a.cmd_v_mm_s).map(|(x, c)| x - c).collect(),
            sim_edot,
            av.iter()
                .zip(&a.cmd_v_mm_s)
                .map(|(x, c)| m.velocity.u_diff(*x, *c))
                .collect(),
            Source::Logged,
        ),
        None => {
            let u: Vec<f64> = (0..n)
                .map(|i| {
                    let (lo, hi) = (i.saturating_sub(1), (i + 1).min(n.saturating_sub(1)));
                    let dt = t[hi] - t[lo];
                    if dt > 0.0 {
                        (u_e[lo].powi(2) + u_e[hi].powi(2)).sqrt() / dt
                    } else {
                        0.0
                    }
                })
                .collect();
            (
                derivative(t, &real_e),
                derivative(t, &sim_e),
                u,
                Source::Differences,
            )
        }
    };
    AxisCompare {
        axis: a.axis,
        real_e_mm: real_e,
        sim_e_mm: sim_e,
        u_e_mm: u_e,
        real_ve_mm_s: real_ve,
        sim_ve_mm_s: sim_ve,
        u_ve_mm_s: u_ve,
        ve_source: src,
    }
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    if n == 0 {
        0.0
    } else {
        (s / n as f64).sqrt()
    }
}

/// Least-squares lag (s) of e = c − lag·v over the moving samples: the
/// axis' effective lag, to compare with the model's (1 − ff)/Kv.
pub fn effective_lag_s(e: &[f64], v: &[f64], standstill_mm_s: f64) -> Option<f64> {
    let rows: Vec<(f64, f64)> = e
        .iter()
        .zip(v)
        .filter(|(_, v)| v.abs() > standstill_mm_s)
        .map(|(e, v)| (*e, *v))
        .collect();
    if rows.len() < 3 {
        return None;
    }
    let n = rows.len() as f64;
    let (me, mv) = (
        rows.iter().map(|r| r.0).sum::<f64>() / n,
        rows.iter().map(|r| r.1).sum::<f64>() / n,
    );
    let sxx: f64 = rows.iter().map(|r| (r.1 - mv).powi(2)).sum();
    let sxy: f64 = rows.iter().map(|r| (r.1 - mv) * (r.0 - me)).sum();
    (sxx > 0.0).then(|| -sxy / sxx)
}

pub struct FollowStage;

const SPEC: StageSpec = StageSpec {
    name: "follow",
    version: 1,
    reads: &[&MOTION],
    reads_artifacts: &[],
    writes: &["following_error"],
    reads_augmented_model: false,
    about: "commanded path through the servo model: simulated vs measured following and velocity error per axis",
    config: SectionCheck::of::<NoKeys>(),
};

/// `follow.json`, which the report reads back.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FollowSummary {
    pub samples: usize,
    /// Per axis with actual positions, by axis name.
    pub axes: BTreeMap<String, AxisFollow>,
    /// Axes without actual positions (not compared).
    pub skipped_axes: Vec<String>,
    pub all_axes: Vec<String>,
}

/// One axis of `follow.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AxisFollow {
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub model_kv_1_s: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub model_ff: f64,
    /// The model's lag (1 − ff)/Kv, s.
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub model_lag_s: f64,
    /// The measured lag (`null` when the axis never moved).
    pub effective_lag_s: Option<f64>,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub rms_real_following_error_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub rms_sim_following_error_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub rms_following_gap_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub rms_velocity_gap_mm_s: f64,
    /// Where the commanded velocity came from (`logged`, `derived`).
    pub cmd_velocity: String,
    pub cmd_acceleration: String,
    pub velocity_error: String,
}

impl Stage for FollowStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let machine = ServoMachine::from_config(&ctx.run.machine)?;
        let trace = Trace::read(ctx.run)?;
        let mut b = BatchBuilder::new().f64("t_s", trace.t_s.clone());
        let mut per = BTreeMap::new();
        for a in &trace.axes {
            let c = compare(&trace.t_s, a, &machine);
            let s = machine.axes[a.index];
            per.insert(
                a.axis.to_string(),
                AxisFollow {
                    model_kv_1_s: s.kv_1_s,
                    model_ff: s.ff,
                    model_lag_s: s.lag_s(),
                    effective_lag_s: effective_lag_s(&c.real_e_mm, &a.cmd_v_mm_s, 1e-3),
                    rms_real_following_error_mm: rms(c.real_e_mm.iter().copied()),
                    rms_sim_following_error_mm: rms(c.sim_e_mm.iter().copied()),
                    rms_following_gap_mm: rms(c
                        .real_e_mm
                        .iter()
                        .zip(&c.sim_e_mm)
                        .map(|(r, s)| r - s)),
                    rms_velocity_gap_mm_s: rms(c
                        .real_ve_mm_s
                        .iter()
                        .zip(&c.sim_ve_mm_s)
                        .map(|(r, s)| r - s)),
                    cmd_velocity: a.cmd_v_source.as_str().to_string(),
                    cmd_acceleration: a.cmd_a_source.as_str().to_string(),
                    velocity_error: c.ve_source.as_str().to_string(),
                },
            );
            let ax = a.axis;
            b = b
                .f64(&format!("cmd_v_{ax}_mm_s"), a.cmd_v_mm_s.clone())
                .f64(&format!("real_e_{ax}_mm"), c.real_e_mm)
                .f64(&format!("sim_e_{ax}_mm"), c.sim_e_mm)
                .f64(&format!("u_e_{ax}_mm"), c.u_e_mm)
                .f64(&format!("real_ve_{ax}_mm_s"), c.real_ve_mm_s)
                .f64(&format!("sim_ve_{ax}_mm_s"), c.sim_ve_mm_s)
                .f64(&format!("u_ve_{ax}_mm_s"), c.u_ve_mm_s);
        }
        let summary = FollowSummary {
            samples: trace.t_s.len(),
            axes: per,
            skipped_axes: trace.skipped.iter().map(|a| a.to_string()).collect(),
            all_axes: AXES.iter().map(|a| a.to_string()).collect(),
        };
        Ok(StageOutput::typed(&summary)?.with("following_error", b.build()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::servo::model::AxisServo;

    #[test]
    fn summaries_round_trip() {
        let axis = AxisFollow {
            model_kv_1_s: 30.0,
            model_ff: 0.0,
            model_lag_s: 1.0 / 30.0,
            effective_lag_s: None,
            rms_real_following_error_mm: 0.5,
            rms_sim_following_error_mm: f64::NAN,
            rms_following_gap_mm: 0.1,
            rms_velocity_gap_mm_s: 0.2,
            cmd_velocity: "logged".into(),
            cmd_acceleration: "derived".into(),
            velocity_error: "logged".into(),
        };
        let mut x = axis.clone();
        x.effective_lag_s = Some(0.028);
        let s = FollowSummary {
            samples: 10,
            axes: [("x".to_string(), x), ("y".to_string(), axis)].into(),
            skipped_axes: vec!["z".into()],
            all_axes: vec!["x".into(), "y".into(), "z".into()],
        };
        let v = crate::typed_summary::round_trip(&s);
        assert!(v["axes"]["y"]["rms_sim_following_error_mm"].is_null());
        crate::typed_summary::round_trip(&crate::servo::observe::ObserveSummary {
            rows: 4,
            axes: [(
                "x".to_string(),
                crate::servo::observe::AxisReversals { reversals: 2 },
            )]
            .into(),
            covariates: crate::servo::observe::Covariates {
                feed_mm_s: true,
                segment: false,
            },
        });
    }

    #[test]
    fn effective_lag_of_a_pure_lag() {
        let v: Vec<f64> = (0..50).map(|i| (i as f64 * 0.3).sin() * 20.0).collect();
        let e: Vec<f64> = v.iter().map(|v| 0.01 - 0.008 * v).collect();
        let l = effective_lag_s(&e, &v, 1e-3).unwrap();
        assert!((l - 0.008).abs() < 1e-12);
        assert_eq!(
            AxisServo {
                kv_1_s: 40.0,
                ff: 0.2
            }
            .lag_s(),
            0.02
        );
    }
}

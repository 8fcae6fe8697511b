//! `observe`: paired observations (docs/formats.md §7) for the gap diagnosis.
//!
//! `motion_error`, one row per sample: real = the measured table motion
//! error δz (separation); sim = what the plugin's motion-error model
//! predicts for that sample *from the other passes of the run*: the
//! repeatable straightness at that grid point, i.e. the mean of δz at the
//! same point over every other pass (`[guideway.observe] sim =
//! "straightness"`, default), optionally plus the thermal and reversal
//! terms the compensation stage fitted (`sim = "model"`). Covariates: x_mm,
//! t_s, dir, temp_c (when recorded), infeed_count.
//!
//! Why not the one-step AR prediction: with d = 2 it extrapolates the last
//! two measurements, so its gap is the innovation — white by construction —
//! and any slow unmodelled effect (thermal growth with the infeeds, a
//! reversal error) is followed within a sample or two and never shows as a
//! shape. Its size is reported by the predictor (prediction_error_var_mm2);
//! the diagnosis compares against the model that compensation relies on.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use sparkout_pipeline::config_check::SectionCheck;
use sparkout_pipeline::contracts::BatchBuilder;
use sparkout_pipeline::{Result, Stage, StageContext, StageOutput, StageSpec};

use super::augment::ThermalGrowth;
use super::compensation::{CompensationSummary, ThermalReversal};
use super::config::ObserveConfig;
use super::separate::SepData;

pub const OBSERVABLE: &str = "motion_error";

/// sim per sample (None when no other pass saw that point).
pub fn leave_pass_out_sim(s: &SepData, model: Option<&ThermalReversal>) -> Vec<Option<f64>> {
    let n = s.len();
    let temp = |i: usize| s.temp_c.as_ref().map(|t| t[i]);
    let known = |i: usize| match model {
        Some(m) => m.g(s.infeed_count[i], temp(i)) + m.reversal(s.dir[i]),
        None => 0.0,
    };
    let base: Vec<f64> = (0..n).map(|i| s.dz_mm[i] - known(i)).collect();
    let mut by_point: BTreeMap<usize, (f64, usize)> = BTreeMap::new();
    let mut by_pass: BTreeMap<(usize, i32), (f64, usize)> = BTreeMap::new();
    for (i, v) in base.iter().enumerate() {
        let a = by_point.entry(s.j[i]).or_default();
        a.0 += v;
        a.1 += 1;
        let b = by_pass.entry((s.j[i], s.pass[i])).or_default();
        b.0 += v;
        b.1 += 1;
    }
    (0..n)
        .map(|i| {
            let (sa, ca) = by_point[&s.j[i]];
            let (sb, cb) = by_pass[&(s.j[i], s.pass[i])];
            (ca > cb).then(|| (sa - sb) / (ca - cb) as f64 + known(i))
        })
        .collect()
}

pub struct ObserveStage;

const SPEC: StageSpec = StageSpec {
    name: "observe",
    // 2: `sim_augmented` (+ effects) under `run --augment`; summary `augmented`.
    version: 2,
    reads: &[],
    reads_artifacts: &["separation", "compensation"],
    writes: &["observations"],
    reads_augmented_model: true,
    about: "paired observations motion_error (measured δz vs the straightness model from the other passes) for the gap diagnosis (docs/formats.md)",
    config: SectionCheck::of::<ObserveConfig>(),
};

/// `observe.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ObserveSummary {
    pub rows: usize,
    /// Where `sim` came from (`straightness`, `model`).
    pub sim: String,
    pub motion_error: ObservableGap,
    /// Samples whose grid point no other pass saw.
    pub skipped_no_other_pass: usize,
    /// `null` without a thermal growth from `run --augment`.
    pub augmented: Option<ObserveAugmented>,
}

/// `observe.json` `motion_error`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ObservableGap {
    pub n: usize,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub rms_gap_mm: f64,
}

/// `observe.json` `augmented`: the fleet's thermal growth in the model's g.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ObserveAugmented {
    pub in_physics: String,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub k_mm_per_infeed: f64,
}

impl Stage for ObserveStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let s = SepData::from_batch(ctx.artifacts.require("separation")?.as_ref())?;
        let mode = ctx.section::<ObserveConfig>()?.sim.clone();
        let model = if mode == "model" {
            ctx.artifacts
                .summary_as::<CompensationSummary>("compensation")
                .transpose()?
                .map(|c| ThermalReversal::from_summary(&c.fit))
        } else {
            None
        };
        let sim = leave_pass_out_sim(&s, model.as_ref());
        let rows: Vec<usize> = (0..s.len()).filter(|&i| sim[i].is_some()).collect();
        let pick = |v: &[f64]| rows.iter().map(|&i| v[i]).collect::<Vec<f64>>();
        let mut b = BatchBuilder::new()
            .str("run", &vec![ctx.run.spec.id.as_str(); rows.len()])
            .str("observable", &vec![OBSERVABLE; rows.len()])
            .f64("sim", rows.iter().map(|&i| sim[i].expect("kept")).collect())
            .f64("real", pick(&s.dz_mm))
            .f64("x_mm", pick(&s.x_mm))
            .f64("t_s", pick(&s.t_s))
            .f64("dir", pick(&s.dir));
        if let Some(t) = &s.temp_c {
            b = b.f64("temp_c", pick(t));
        }
        b = b.i32(
            "infeed_count",
            rows.iter().map(|&i| s.infeed_count[i]).collect(),
        );
        // `run --augment`: the fleet's thermal growth per infeed in the
        // model's g (guideway/augment.rs), the rest of the model as above.
        let augmented = match ThermalGrowth::of(ctx) {
            Some(tg) => {
                let mut m = model.clone().unwrap_or_default();
                m.k_mm_per_infeed = Some(tg.k_mm_per_infeed);
                let aug = leave_pass_out_sim(&s, Some(&m));
                b = b
                    .opt_f64("sim_augmented", rows.iter().map(|&i| aug[i]).collect())
                    .opt_str(
                        "sim_augmented_effects",
                        rows.iter()
                            .map(|&i| aug[i].map(|_| tg.keys.as_str()))
                            .collect(),
                    );
                Some(ObserveAugmented {
                    in_physics: tg.keys,
                    k_mm_per_infeed: tg.k_mm_per_infeed,
                })
            }
            None => None,
        };
        let gap: Vec<f64> = rows
            .iter()
            .map(|&i| s.dz_mm[i] - sim[i].expect("kept"))
            .collect();
        let rms = (gap.iter().map(|g| g * g).sum::<f64>() / gap.len().max(1) as f64).sqrt();
        let summary = ObserveSummary {
            rows: rows.len(),
            sim: mode,
            motion_error: ObservableGap {
                n: rows.len(),
                rms_gap_mm: rms,
            },
            skipped_no_other_pass: s.len() - rows.len(),
            augmented,
        };
        Ok(StageOutput::typed(&summary)?.with("observations", b.build()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sim_comes_from_the_other_passes() {
        // Two points, three passes; δz = s(j) + 0.1·pass.
        let s = SepData {
            n: (0..6).collect(),
            x_mm: vec![0.0, 30.0, 30.0, 0.0, 0.0, 30.0],
            h_mm: vec![0.0; 6],
            dz_mm: vec![1.0, 2.0, 2.1, 1.1, 1.2, 2.2],
            t_s: (0..6).map(|i| i as f64).collect(),
            dir: vec![1.0, 1.0, -1.0, -1.0, 1.0, 1.0],
            pass: vec![0, 0, 1, 1, 2, 2],
            infeed_count: vec![1, 1, 2, 2, 3, 3],
            j: vec![0, 1, 1, 0, 0, 1],
            temp_c: None,
        };
        let sim = leave_pass_out_sim(&s, None);
        assert!((sim[0].unwrap() - 1.15).abs() < 1e-12);
        assert!((sim[5].unwrap() - 2.05).abs() < 1e-12);
        // With the thermal term known, the sim follows the count.
        let m = ThermalReversal {
            k_mm_per_infeed: Some(0.1),
            ..Default::default()
        };
        let sim = leave_pass_out_sim(&s, Some(&m));
        for (i, v) in sim.iter().enumerate() {
            assert!((v.unwrap() - s.dz_mm[i]).abs() < 1e-12);
        }
    }
}

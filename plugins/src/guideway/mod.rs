//! Guide-way grinder (docs/models.md §3; Xu, Tao & Gao 2012): three displacement
//! probes on the headstock, error separation, a time-series predictor of
//! the table's motion error, and the headstock compensation curve.
//!
//! Stages (edges from the artifacts they read and write):
//!
//! | stage | reads | writes |
//! |---|---|---|
//! | `separate` | guideway | `separation` |
//! | `predictor` | `separation` | `predictor`, `ar_fpe`, `forecast` |
//! | `compensation` | `separation`, `predictor` | `compensation` |
//! | `observe` | `separation`, `compensation` | `observations` |

// `!(x > 0.0)` is deliberate where used: it rejects NaN as well.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::sync::Arc;

use sparkout_pipeline::config_check::Check;
use sparkout_pipeline::diagnose::{catalogue_effect, composite, Effect, Kind};
use sparkout_pipeline::{ArtifactStore, MachinePlugin, ProcessKeys, ReportSection, Run, Stage};

pub mod ar_fpe;
pub mod augment;
pub mod compensation;
pub mod config;
pub mod input;
pub mod kalman;
pub mod observe;
pub mod predictor;
pub mod report;
pub mod rls;
pub mod separate;
pub mod tables;
pub mod three_probe;

/// The source's machine, built into the binary.
pub const GUIDEWAY_GRINDER_TOML: &str = include_str!("../../machines/guideway-grinder.toml");

/// The `guideway` plugin.
pub struct GuidewayPlugin;

impl MachinePlugin for GuidewayPlugin {
    fn name(&self) -> &'static str {
        "guideway"
    }
    fn tables(&self) -> &'static [sparkout_pipeline::contracts::TableSchema] {
        tables::TABLES
    }
    fn required_tables(&self) -> Vec<Vec<&'static str>> {
        vec![vec!["guideway"]]
    }
    fn stages(&self) -> Vec<Arc<dyn Stage>> {
        vec![
            Arc::new(separate::SeparateStage),
            Arc::new(predictor::PredictorStage),
            Arc::new(compensation::CompensationStage),
            Arc::new(observe::ObserveStage),
        ]
    }
    /// What the stages read from run.toml `[process]` (and what the
    /// generator writes there, for provenance).
    fn process_keys(&self) -> ProcessKeys {
        &[
            ("probe_spacing_mm", Check::Positive),
            ("sample_step_mm", Check::Positive),
            ("infeed_mm", Check::Positive),
            ("passes", Check::WholeIn(1, 100_000)),
        ]
    }
    fn builtin_machines(&self) -> Vec<(&'static str, &'static str)> {
        vec![("guideway-grinder", GUIDEWAY_GRINDER_TOML)]
    }
    fn machine_sections(
        &self,
    ) -> &'static [(&'static str, sparkout_pipeline::config_check::SectionCheck)] {
        config::MACHINE_SECTIONS
    }
    /// `thermal_infeed` = wear on `infeed_count`: the source (docs/models.md
    /// §3.4) says the workpiece's thermal deformation grows mainly with the
    /// number of infeeds, so a gap linear in the infeed count is named for
    /// that cause. (A table reversal error is the catalogue's
    /// `backlash:dir`, whose documented cause it already is.)
    fn effects(&self) -> Vec<Box<dyn Effect>> {
        vec![composite(
            "thermal_infeed",
            catalogue_effect(Kind::Wear, &["infeed_count"]),
        )]
    }
    fn observables(&self) -> Vec<&'static str> {
        vec![observe::OBSERVABLE]
    }
    fn report_sections(&self, run: &Run, artifacts: &ArtifactStore) -> Vec<ReportSection> {
        report::sections(run, artifacts)
    }
    fn verdicts(
        &self,
        run: &Run,
        artifacts: &ArtifactStore,
    ) -> Vec<sparkout_pipeline::report::Verdict> {
        report::verdicts(run, artifacts)
    }
}

#[cfg(test)]
mod tests {
    use super::ar_fpe::Criterion;
    use super::compensation::{CompensationAugmented, CompensationSummary, ThermalReversalFit};
    use super::observe::{ObservableGap, ObserveAugmented, ObserveSummary};
    use super::predictor::{KalmanSummary, Orders, PredictorSummary};
    use super::separate::{OtherMethod, SeparateSummary};
    use crate::typed_summary::round_trip;

    /// Every summary the guide-way's stages write reads back as itself,
    /// NaN (written as `null`) included.
    #[test]
    fn summaries_round_trip() {
        let sep = SeparateSummary {
            method: "lsq".into(),
            n: 936,
            h_rms_mm: 0.001,
            dz_rms_mm: f64::NAN,
            beta_rms_rad: 7.9e-6,
            reference: "line".into(),
            positions: 80,
            passes: 12,
            k: 1,
            sample_step_mm: 30.0,
            probe_spacing_mm: 30.0,
            resampled: false,
            t_recorded: true,
            sigma_mm: Some(1e-4),
            sigma_source: Some("residuals".into()),
            dof: 858,
            h_sigma_max_mm: None,
            dz_sigma_max_mm: Some(0.0048),
            other: Some(OtherMethod {
                method: "recursion".into(),
                h_rms_mm: 0.0038,
                dz_rms_mm: 0.053,
                h_difference_rms_mm: f64::NAN,
            }),
        };
        let v = round_trip(&sep);
        assert!(v["dz_rms_mm"].is_null() && v["h_sigma_max_mm"].is_null());
        round_trip(&SeparateSummary {
            other: None,
            sigma_mm: None,
            sigma_source: None,
            ..sep
        });
        round_trip(&PredictorSummary {
            d: 2,
            p_max: 3,
            fpe: vec![1e-8, f64::NAN, 2e-8],
            bic: vec![-1.0, -2.0, -1.5],
            hq: vec![-1.0, -2.0, -1.5],
            criterion: Criterion::Bic,
            order: 2,
            orders: Orders {
                fpe: 3,
                bic: 2,
                hq: 2,
            },
            coefficients: vec![0.5, -0.3],
            sigma2_mm2: 5.5e-8,
            rls_coefficients: vec![0.49, -0.31],
            prediction_error_var_mm2: 6.2e-8,
            n: 936,
            n_eff: 930,
            kalman: KalmanSummary {
                q_mm2: 1e-9,
                r_mm2: 1e-8,
                gain_final: None,
                residual_var_mm2: f64::NAN,
            },
            forecast_dz_mm: vec![0.001, 0.002],
            forecast_sigma_mm: vec![1e-4, f64::NAN],
        });
        let fit = ThermalReversalFit {
            thermal_k_mm_per_infeed: Some(3.8e-4),
            thermal_k_sigma_mm_per_infeed: Some(1.6e-6),
            thermal_k_mm_per_c: None,
            thermal_k_sigma_mm_per_c: None,
            t0_c: 19.7,
            reversal_c_mm: Some(1.3e-6),
            reversal_c_sigma_mm: Some(1e-5),
            residual_rms_mm: f64::NAN,
            notes: vec!["one infeed count only".into()],
        };
        let comp = CompensationSummary {
            rows: 924,
            d: 2,
            order: 10,
            infeed_mm: 0.005,
            backlash_mm: 0.001,
            fit,
            thermal_k_per_mm_infeed: Some(0.077),
            dz_rms_mm: 0.007,
            prediction_residual_rms_mm: 2.4e-4,
            replay_columns: vec!["t_s".into(), "dz_mm".into()],
            augmented: None,
        };
        assert!(round_trip(&comp)["augmented"].is_null());
        round_trip(&CompensationSummary {
            augmented: Some(CompensationAugmented {
                in_physics: "thermal_infeed:infeed_count".into(),
                k_mm_per_infeed: 4e-4,
                k_mm_per_infeed_run_fit: None,
            }),
            ..comp
        });
        let obs = ObserveSummary {
            rows: 936,
            sim: "straightness".into(),
            motion_error: ObservableGap {
                n: 936,
                rms_gap_mm: 0.0015,
            },
            skipped_no_other_pass: 0,
            augmented: None,
        };
        round_trip(&obs);
        round_trip(&ObserveSummary {
            augmented: Some(ObserveAugmented {
                in_physics: "thermal_infeed:infeed_count".into(),
                k_mm_per_infeed: 4e-4,
            }),
            ..obs
        });
    }
}

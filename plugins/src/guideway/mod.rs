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
pub mod three_probe;

/// The source's machine, built into the binary.
pub const GUIDEWAY_GRINDER_TOML: &str = include_str!("../../machines/guideway-grinder.toml");

/// The `guideway` plugin.
pub struct GuidewayPlugin;

impl MachinePlugin for GuidewayPlugin {
    fn name(&self) -> &'static str {
        "guideway"
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

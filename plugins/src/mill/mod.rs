//! Three-axis XFYZ mill, volumetric verification with a laser tracker
//! (docs/models.md §5): 21 error functions (18 per-axis translations and
//! rotations as Legendre series of configurable degree, 3 squareness terms)
//! and the tracker frame identified by Levenberg–Marquardt.
//!
//! Stages (edges from the artifacts they read and write):
//!
//! | stage | reads | writes |
//! |---|---|---|
//! | `kinematics` | tracker | `kinematic_params`, `kinematic_covariance`, `compensation_table`, `volumetric_map`, `tracker_residuals`, `compensation_path` |
//! | `observe` | tracker, thermal, `kinematic_params` | `observations` |
//!
//! tracker.parquet follows docs/formats.md §4; an optional integer column
//! `tool` (an extra column, which the contract passes through) says which of
//! the machine's `[tool] offsets_mm` each point was measured with — several
//! offsets are what makes the spindle carriage's rotations identifiable.

use std::sync::Arc;

use sparkout_pipeline::config_check::Check;
use sparkout_pipeline::diagnose::{catalogue_effect, composite, Effect, Kind};
use sparkout_pipeline::{ArtifactStore, MachinePlugin, ProcessKeys, ReportSection, Run, Stage};

pub mod augment;
pub mod chain;
pub mod config;
pub mod identify;
pub mod kinematics;
pub mod observe;
pub mod report;
pub mod summary;
pub mod tables;

/// The XFYZ mill of the volumetric verification, built into the binary.
pub const XFYZ_MILL_TOML: &str = include_str!("../../machines/xfyz-mill.toml");

/// The `mill` plugin.
pub struct MillPlugin;

impl MachinePlugin for MillPlugin {
    fn name(&self) -> &'static str {
        "mill"
    }
    fn tables(&self) -> &'static [sparkout_pipeline::contracts::TableSchema] {
        tables::TABLES
    }
    fn required_tables(&self) -> Vec<Vec<&'static str>> {
        vec![vec!["tracker"]]
    }
    fn stages(&self) -> Vec<Arc<dyn Stage>> {
        vec![
            Arc::new(kinematics::KinematicsStage),
            Arc::new(observe::ObserveStage),
        ]
    }
    /// What the stages read from run.toml `[process]` (and what the
    /// generator writes there, for provenance).
    fn process_keys(&self) -> ProcessKeys {
        &[
            ("points", Check::WholeIn(1, 10_000_000)),
            ("point_period_s", Check::Positive),
            ("axes", Check::Text),
        ]
    }
    fn builtin_machines(&self) -> Vec<(&'static str, &'static str)> {
        vec![("xfyz-mill", XFYZ_MILL_TOML)]
    }
    fn machine_sections(
        &self,
    ) -> &'static [(&'static str, sparkout_pipeline::config_check::SectionCheck)] {
        config::MACHINE_SECTIONS
    }
    /// `thermal_growth` = drift in time (warm-up): the spindle
    /// and column grow towards a steady state as A·(1 − e^(−t/τ)) while the
    /// tracker points are taken; the identified geometric model is static,
    /// so the growth is left in the tracker gap. It applies only to the
    /// mill's tracker observables (composites are scoped
    /// to their plugin's observables), so other machines keep `drift:t_s`.
    fn effects(&self) -> Vec<Box<dyn Effect>> {
        vec![composite(
            "thermal_growth",
            catalogue_effect(Kind::Drift, &["t_s"]),
        )]
    }
    fn observables(&self) -> Vec<&'static str> {
        observe::OBSERVABLES.to_vec()
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

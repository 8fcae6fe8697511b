//! Form grinder (docs/models.md §4): a 4-axis (X, Z, A, C) form grinder grinds a
//! profile R(φ) programmed for a nominal wheel radius; dressing shrinks the
//! wheel and leaves a profile error δ(φ).
//!
//! Stages (edges from the artifacts they read and write):
//!
//! | stage | reads | writes |
//! |---|---|---|
//! | `profile_error` | profile | `profile_error` |
//! | `segment` | profile | `segments`, `segment_error`, `segment_sweep`, `toolpath` |
//! | `form_cldata` | `toolpath` | `cldata` (run-less: profile file → `.cls` programs) |
//! | `observe` | profile | `observations` (`profile_error`) |

// `!(x > 0.0)` is deliberate throughout: it rejects NaN as well.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::sync::Arc;

use sparkout_pipeline::config_check::Check;
use sparkout_pipeline::diagnose::{catalogue_effect, composite, Effect, Kind};
use sparkout_pipeline::{ArtifactStore, MachinePlugin, ProcessKeys, ReportSection, Run, Stage};

pub mod augment;
pub mod cldata;
pub mod config;
pub mod curvature;
pub mod model;
pub mod observe;
pub mod profile_error;
pub mod report;
pub mod segment;
pub mod shapes;
pub mod summary;
pub mod tables;

/// The form grinder of the source (wheel 175 mm, usable range 50 mm), built
/// into the binary.
pub const FORM_GRINDER_TOML: &str = include_str!("../../machines/form-grinder.toml");

/// The `form` plugin.
pub struct FormPlugin;

impl MachinePlugin for FormPlugin {
    fn name(&self) -> &'static str {
        "form"
    }
    fn tables(&self) -> &'static [sparkout_pipeline::contracts::TableSchema] {
        tables::TABLES
    }
    fn required_tables(&self) -> Vec<Vec<&'static str>> {
        vec![vec!["profile"]]
    }
    fn stages(&self) -> Vec<Arc<dyn Stage>> {
        vec![
            Arc::new(profile_error::ProfileErrorStage),
            Arc::new(segment::SegmentStage),
            Arc::new(cldata::CldataStage),
            Arc::new(observe::ObserveStage),
        ]
    }
    /// What the stages read from run.toml `[process]` (and what the
    /// generator writes there, for provenance).
    fn process_keys(&self) -> ProcessKeys {
        &[
            ("shape", Check::Text),
            ("z_mm", Check::Number),
            ("dressing", Check::WholeIn(0, 1_000_000)),
            ("part_in_dressing", Check::WholeIn(0, 1_000_000)),
            ("wheel_radius_mm", Check::Positive),
            ("nominal_wheel_radius_mm", Check::Positive),
            ("removed_before_mm3", Check::NonNegative),
            ("stock_mm", Check::Positive),
            ("feed_mm_s", Check::Positive),
            ("width_mm", Check::Positive),
        ]
    }
    fn builtin_machines(&self) -> Vec<(&'static str, &'static str)> {
        vec![("form-grinder", FORM_GRINDER_TOML)]
    }
    fn machine_sections(
        &self,
    ) -> &'static [(&'static str, sparkout_pipeline::config_check::SectionCheck)] {
        config::MACHINE_SECTIONS
    }
    /// `wheel_wear` = wear on the volume removed since the last dressing:
    /// the wheel loses radius in proportion to the volume it grinds
    /// (grinding ratio), the controller only knows the dressed radius, so
    /// the profile is left proud by k·removed_mm3 along the normal
    /// (docs/design.md §7, point 2).
    fn effects(&self) -> Vec<Box<dyn Effect>> {
        vec![composite(
            "wheel_wear",
            catalogue_effect(Kind::Wear, &["removed_mm3"]),
        )]
    }
    fn observables(&self) -> Vec<&'static str> {
        vec!["profile_error"]
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

//! Robot grinder (docs/models.md §1): KUKA KR16, the wheel is the probe, acoustic
//! emission detects contact.
//!
//! Stages (edges from the artifacts they read and write):
//!
//! | stage | reads | writes |
//! |---|---|---|
//! | `ingest` | probe, ae, motion, plan | `touches`, `contacts`, `touch_compare` |
//! | `repeatability` | `touches` | `repeatability` |
//! | `datum` | `touches` | `planes`, `datum` |
//! | `cycle` | passes | `cycle` |
//! | `observe` | `touches`, `planes`, `cycle` | `observations` |
//!
//! The data the stages read follow docs/formats.md §4 and docs/robot_data_spec.md.

// `!(x > 0.0)` is deliberate throughout: it rejects NaN as well.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::sync::Arc;

use sparkout_pipeline::config_check::Check;
use sparkout_pipeline::diagnose::{catalogue_effect, composite, product, Effect, Kind};
use sparkout_pipeline::{ArtifactStore, MachinePlugin, ProcessKeys, ReportSection, Run, Stage};

pub mod ae;
pub mod cycle;
pub mod datum;
pub mod ingest;
pub mod machine;
pub mod observe;
pub mod planes;
pub mod repeatability;
pub mod report;
pub mod summary;
pub mod tables;
pub mod touches;

/// The KR16 lab cell, built into the binary (docs/formats.md §3: machine ids
/// resolve to built-in configs last).
pub const KR16_LAB_TOML: &str = include_str!("../../machines/kr16-lab.toml");

/// The `robot` plugin.
pub struct RobotPlugin;

impl MachinePlugin for RobotPlugin {
    fn name(&self) -> &'static str {
        "robot"
    }
    fn tables(&self) -> &'static [sparkout_pipeline::contracts::TableSchema] {
        tables::TABLES
    }
    fn required_tables(&self) -> Vec<Vec<&'static str>> {
        vec![vec!["probe"], vec!["ae", "motion", "plan"]]
    }
    fn stages(&self) -> Vec<Arc<dyn Stage>> {
        vec![
            Arc::new(ingest::IngestStage),
            Arc::new(repeatability::RepeatabilityStage),
            Arc::new(datum::DatumStage),
            Arc::new(cycle::CycleStage),
            Arc::new(observe::ObserveStage),
        ]
    }
    /// What the stages read from run.toml `[process]` (and what the
    /// generator writes there, for provenance).
    fn process_keys(&self) -> ProcessKeys {
        &[
            ("weld_mm", Check::Positive),
            ("contact_area_mm2", Check::Positive),
            ("doc_rough_mm", Check::Positive),
            ("doc_finish_mm", Check::Positive),
            ("rough_passes", Check::WholeIn(0, cycle::MAX_PASSES)),
            ("finish_passes", Check::WholeIn(0, cycle::MAX_PASSES)),
            ("spark_passes", Check::WholeIn(0, cycle::MAX_PASSES)),
            ("feed_mm_s", Check::Positive),
            ("pass_length_mm", Check::Positive),
            ("standoff_mm", Check::Positive),
            ("motion_rate_hz", Check::Positive),
            ("block_size_mm", Check::PositiveArray(3)),
        ]
    }
    fn builtin_machines(&self) -> Vec<(&'static str, &'static str)> {
        vec![("kr16-lab", KR16_LAB_TOML)]
    }
    fn machine_sections(
        &self,
    ) -> &'static [(&'static str, sparkout_pipeline::config_check::SectionCheck)] {
        machine::MACHINE_SECTIONS
    }
    /// `trigger_latency` = lag on the signed normal approach speed (docs/design.md
    /// §7, point 2): a touch registered L seconds
    /// after contact overshoots by v·L along the approach direction, so the
    /// `touch_normal` gap is L·approach_normal_mm_s (k = L, in s).
    ///
    /// `thermal_drift` = drift(t_s)·normal_axis_z: the column's thermal
    /// growth lifts the TCP, which the motor encoders cannot see; only
    /// touches whose normal coordinate is z (face `xy`) move, by the drift
    /// A·(1 − e^(−t/τ)).
    ///
    /// `depth_compliance` = k·compliance_response_mm2: a compliance that
    /// grows with the depth of cut (docs/models.md §1.4 takes α constant)
    /// loses a cut ∝ δ′² on every pass — the first one too, from which the
    /// model's α is calibrated, so the gap it leaves is that loss plus the
    /// model's cuts at the over-estimated α (0 on pass 1, persisting
    /// through spark-out): the covariate observe.rs computes from the
    /// recurrence (`cycle::depth_compliance_response_mm2`). The loss's own
    /// form, k·δ′², misses all of that but its size.
    fn effects(&self) -> Vec<Box<dyn Effect>> {
        let mut out = vec![composite(
            "trigger_latency",
            catalogue_effect(Kind::Lag, &["approach_normal_mm_s"]),
        )];
        // Both factors are linear forms by construction: an error here is a
        // programming error, caught by the unit test below.
        out.extend(
            product(
                "thermal_drift",
                catalogue_effect(Kind::Drift, &["t_s"]),
                catalogue_effect(Kind::Scale, &["normal_axis_z"]),
            )
            .ok(),
        );
        out.push(composite(
            "depth_compliance",
            catalogue_effect(Kind::Scale, &["compliance_response_mm2"]),
        ));
        out
    }
    fn observables(&self) -> Vec<&'static str> {
        vec!["touch_normal*", "cut_depth"]
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
    use super::*;

    #[test]
    fn every_composite_effect_builds() {
        let names: Vec<String> = RobotPlugin
            .effects()
            .iter()
            .map(|e| e.name().to_string())
            .collect();
        assert_eq!(
            names,
            ["trigger_latency", "thermal_drift", "depth_compliance"]
        );
    }
}

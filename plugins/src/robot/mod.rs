//! Robot grinder (MODELS.md §1): KUKA KR16, the wheel is the probe, acoustic
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
//! The data the stages read follow CONTRACTS.md §1 and docs/robot_data_spec.md.

// `!(x > 0.0)` is deliberate throughout: it rejects NaN as well.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::sync::Arc;

use sparkout_pipeline::diagnose::{catalogue_effect, composite, Effect, Kind};
use sparkout_pipeline::{ArtifactStore, MachinePlugin, ReportSection, Run, Stage};

pub mod ae;
pub mod config;
pub mod cycle;
pub mod datum;
pub mod ingest;
pub mod observe;
pub mod planes;
pub mod repeatability;
pub mod report;
pub mod touches;

/// The KR16 lab cell, built into the binary (CONTRACTS.md §1: machine ids
/// resolve to built-in configs last).
pub const KR16_LAB_TOML: &str = include_str!("../../../configs/machines/kr16-lab.toml");

/// The `robot` plugin.
pub struct RobotPlugin;

impl MachinePlugin for RobotPlugin {
    fn name(&self) -> &'static str {
        "robot"
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
    fn builtin_machines(&self) -> Vec<(&'static str, &'static str)> {
        vec![("kr16-lab", KR16_LAB_TOML)]
    }
    /// `trigger_latency` = lag on the signed normal approach speed (DESIGN.md
    /// "Sim-to-real gap diagnosis", point 2): a touch registered L seconds
    /// after contact overshoots by v·L along the approach direction, so the
    /// `touch_normal` gap is L·approach_normal_mm_s (k = L, in s).
    fn effects(&self) -> Vec<Box<dyn Effect>> {
        vec![composite(
            "trigger_latency",
            catalogue_effect(Kind::Lag, &["approach_normal_mm_s"]),
        )]
    }
    fn report_sections(&self, run: &Run, artifacts: &ArtifactStore) -> Vec<ReportSection> {
        report::sections(run, artifacts)
    }
}

//! Servo axes (docs/servo.md): any controller trace of commanded vs actual
//! axis motion → following-error and velocity-error observables per axis →
//! the gap diagnosis. The forward model is the commanded path through a
//! configurable first-order position loop (gain Kv, velocity feed-forward
//! ff per axis, model.rs), so the diagnosis says what that model misses:
//! lag, acceleration-dependent lag, backlash, reversal spikes.
//!
//! Stages (edges from the artifacts they read and write):
//!
//! | stage | reads | writes |
//! |---|---|---|
//! | `follow` | motion | `following_error` |
//! | `observe` | motion, `following_error` | `observations` |
//!
//! motion.parquet follows docs/formats.md §4 with the v1.1 optional per-axis
//! velocity and acceleration columns (`cmd_v_x_mm_s`, `act_v_x_mm_s`,
//! `cmd_a_x_mm_s2`, ...); an axis needs `act_<axis>_mm` to be compared.

use std::sync::Arc;

use sparkout_pipeline::diagnose::{catalogue_effect, composite, only_on, product, Effect, Kind};
use sparkout_pipeline::report::Verdict;
use sparkout_pipeline::{ArtifactStore, MachinePlugin, ReportSection, Run, Stage};

pub mod config;
pub mod follow;
pub mod model;
pub mod observe;
pub mod report;
pub mod trace;

/// A three-axis machine with a 30 1/s position loop and a 0.5 µm encoder
/// (the generator's machine), built into the binary.
pub const SERVO_MILL_TOML: &str = include_str!("../../machines/servo-mill.toml");
/// The University of Michigan CNC mill of the tool-wear set.
pub const UMICH_CNC_TOML: &str = include_str!("../../machines/umich-cnc.toml");

pub fn builtin_machines() -> Vec<(&'static str, &'static str)> {
    vec![
        ("servo-mill", SERVO_MILL_TOML),
        ("umich-cnc", UMICH_CNC_TOML),
    ]
}

/// The `servo` plugin.
pub struct ServoPlugin;

impl MachinePlugin for ServoPlugin {
    fn name(&self) -> &'static str {
        "servo"
    }
    fn required_tables(&self) -> Vec<Vec<&'static str>> {
        vec![vec!["motion"]]
    }
    /// Velocities and accelerations come from central differences (a
    /// sample on either side), so a trace needs three rows.
    fn min_rows(&self) -> &'static [(&'static str, usize)] {
        &[("motion", 3)]
    }
    fn stages(&self) -> Vec<Arc<dyn Stage>> {
        vec![
            Arc::new(follow::FollowStage),
            Arc::new(observe::ObserveStage),
        ]
    }
    fn builtin_machines(&self) -> Vec<(&'static str, &'static str)> {
        builtin_machines()
    }
    fn machine_sections(
        &self,
    ) -> &'static [(&'static str, sparkout_pipeline::config_check::SectionCheck)] {
        config::MACHINE_SECTIONS
    }
    fn report_sections(&self, run: &Run, artifacts: &ArtifactStore) -> Vec<ReportSection> {
        report::sections(run, artifacts)
    }
    fn verdicts(&self, run: &Run, artifacts: &ArtifactStore) -> Vec<Verdict> {
        report::verdicts(run, artifacts)
    }
    /// Physically named versions of catalogue shapes on the servo's own
    /// covariates (names no other plugin emits, so they rename nothing of
    /// another fleet's diagnosis), one name per physical cause whichever
    /// observable shows it. A velocity error is the rate of the following
    /// error, so each cause's form there is the rate of its form on
    /// positions, with the same k (docs/models.md §7):
    /// - `servo_lag`: the axis lags more (k < 0) or less (k > 0, s) than
    ///   the model's (1 − ff)/Kv — k·cmd_v_mm_s on a following error,
    ///   k·cmd_a_mm_s2 on a velocity error.
    /// - `accel_lag`: an error ∝ acceleration, the loop is not first order
    ///   (velocity loop, drive inertia; k in s²) — k·cmd_a_mm_s2 on a
    ///   following error, k·cmd_j_mm_s3 (jerk) on a velocity error.
    /// - `reversal_spike` = edge(reversal_mm)·backlash(dir): friction at a
    ///   reversal, decaying with the distance travelled since, its sign
    ///   following the new direction (a ballbar's reversal spike); by
    ///   shape on both.
    ///
    /// `backlash:dir` keeps its catalogue name (lost motion b·dir/2).
    fn effects(&self) -> Vec<Box<dyn Effect>> {
        let (position, velocity) = (&["following_error_"], &["velocity_error_"]);
        let mut v = vec![
            only_on(
                position,
                composite("servo_lag", catalogue_effect(Kind::Lag, &["cmd_v_mm_s"])),
            ),
            only_on(
                position,
                composite(
                    "accel_lag",
                    catalogue_effect(Kind::Inertia, &["cmd_a_mm_s2"]),
                ),
            ),
            // k·c on any covariate is the inertia form; the catalogue has no
            // kind for a jerk, so only this composite reads it.
            only_on(
                velocity,
                composite(
                    "servo_lag",
                    catalogue_effect(Kind::Inertia, &["cmd_a_mm_s2"]),
                ),
            ),
            only_on(
                velocity,
                composite(
                    "accel_lag",
                    catalogue_effect(Kind::Inertia, &["cmd_j_mm_s3"]),
                ),
            ),
        ];
        // Both factors are linear forms: an error is a programming error,
        // caught by the unit test below.
        if let Ok(e) = product(
            "reversal_spike",
            catalogue_effect(Kind::Edge, &["reversal_mm"]),
            catalogue_effect(Kind::Backlash, &["dir"]),
        ) {
            v.push(e);
        }
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn composites_are_built() {
        let fx = ServoPlugin.effects();
        let names: Vec<String> = fx.iter().map(|e| e.key()).collect();
        assert_eq!(
            names,
            [
                "servo_lag:cmd_v_mm_s",
                "accel_lag:cmd_a_mm_s2",
                "servo_lag:cmd_a_mm_s2",
                "accel_lag:cmd_j_mm_s3",
                "reversal_spike:reversal_mm,dir"
            ]
        );
        // One form of each cause per family: on a velocity error the lag
        // is k·a, the acceleration lag k·j.
        let on = |obs: &str| -> Vec<String> {
            fx.iter()
                .filter(|e| e.applies_to(obs))
                .map(|e| e.key())
                .collect()
        };
        assert_eq!(
            on("following_error_x"),
            [
                "servo_lag:cmd_v_mm_s",
                "accel_lag:cmd_a_mm_s2",
                "reversal_spike:reversal_mm,dir"
            ]
        );
        assert_eq!(
            on("velocity_error_z"),
            [
                "servo_lag:cmd_a_mm_s2",
                "accel_lag:cmd_j_mm_s3",
                "reversal_spike:reversal_mm,dir"
            ]
        );
    }
}

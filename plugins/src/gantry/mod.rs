//! Lightweight stone gantry (docs/models.md §2): two stringers and a movable
//! bridge grinding and polishing slate.
//!
//! Stages (edges from the artifacts they read and write):
//!
//! | stage | reads | writes |
//! |---|---|---|
//! | `matrices` | topography (pattern), motion, machine | `static_matrix`, `dynamic_matrix`, `compensation_table`, `compensation_path` (with motion) |
//! | `flatness` | topography | `flatness` |
//! | `removal` | topography, motion | `removal` (predicted final topography) |
//! | `polish_plan` | topography | `polish_plan` |
//! | `observe` | topography, motion, `removal` | `observations` |

// `!(x > 0.0)` is deliberate: it rejects NaN as well.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::sync::Arc;

use sparkout_pipeline::config_check::Check;
use sparkout_pipeline::contracts::MachineConfig;
use sparkout_pipeline::diagnose::{catalogue_effect, composite, product, Effect, Kind};
use sparkout_pipeline::{ArtifactStore, MachinePlugin, ProcessKeys, ReportSection, Run, Stage};

pub mod augment;
pub mod beam;
pub mod config;
pub mod dwell;
pub mod flatness;
pub mod grid;
pub mod machine;
pub mod matrices;
pub mod moving_load;
pub mod observe;
pub mod polish_plan;
pub mod removal;
pub mod report;
pub mod straightness;
pub mod surface;
pub mod tool_influence;

/// The APLM gantry, built into the binary (docs/formats.md §4).
pub const APLM_GANTRY_TOML: &str = include_str!("../../machines/aplm-gantry.toml");

/// The built-in machine as a resolved config (run-less stage forms).
pub fn builtin_machine() -> anyhow::Result<MachineConfig> {
    Ok(MachineConfig {
        id: "aplm-gantry".into(),
        source: "built-in machine `aplm-gantry`".into(),
        table: APLM_GANTRY_TOML.parse()?,
        text: APLM_GANTRY_TOML.to_string(),
        ..Default::default()
    })
}

/// The `gantry` plugin.
pub struct GantryPlugin;

impl MachinePlugin for GantryPlugin {
    fn name(&self) -> &'static str {
        "gantry"
    }
    fn required_tables(&self) -> Vec<Vec<&'static str>> {
        vec![vec!["topography"]]
    }
    fn stages(&self) -> Vec<Arc<dyn Stage>> {
        vec![
            Arc::new(matrices::MatricesStage),
            Arc::new(flatness::FlatnessStage),
            Arc::new(removal::RemovalStage),
            Arc::new(polish_plan::PolishPlanStage),
            Arc::new(observe::ObserveStage),
        ]
    }
    /// Line-profile metrology (`sparkout stage profile --profile FILE`):
    /// a gantry's straightness traces are its users, no run table is.
    fn standalone_stages(&self) -> Vec<Arc<dyn Stage>> {
        vec![Arc::new(crate::metrology::ProfileStage)]
    }
    /// What the stages read from run.toml `[process]` (and what the
    /// generator writes there, for provenance).
    fn process_keys(&self) -> ProcessKeys {
        &[
            // grinding (the machine's [grinding] otherwise)
            ("grind_feed_mm_s", Check::Positive),
            ("depth_of_cut_mm", Check::Positive),
            // polishing: any key of the machine's [polishing] table
            ("k_p_per_pa", Check::Positive),
            ("pressure_pa", Check::Positive),
            ("tool_radius_mm", Check::Positive),
            ("tool_area_mm2", Check::Positive),
            ("spring_compression_mm", Check::Positive),
            ("spring_rate_n_mm", Check::Positive),
            ("rev_per_s", Check::Positive),
            ("linear_speed_mm_s", Check::Positive),
            ("feed_mm_s", Check::Positive),
            ("accel_mm_s2", Check::Positive),
            ("step_over_mm", Check::Positive),
        ]
    }
    fn builtin_machines(&self) -> Vec<(&'static str, &'static str)> {
        vec![("aplm-gantry", APLM_GANTRY_TOML)]
    }
    /// Physically named effects of the polished surface (docs/design.md §7 point 2):
    /// - `thermal_bow` = bow(y_mm)·drift(t_s): the bridge bows as it
    ///   warms; the spring-loaded disc turns the height change into a
    ///   pressure, hence removal, change (docs/models.md §2.5);
    /// - `raster_end_pressure` = edge(path_end_mm): acceleration and
    ///   deceleration at raster ends raise the pressure (docs/models.md §2.6);
    /// - `tool_wear` = wear(tool_removed_mm3): the pad's Preston coefficient
    ///   falls with the volume it has removed.
    fn effects(&self) -> Vec<Box<dyn Effect>> {
        let mut v = vec![
            composite(
                "raster_end_pressure",
                catalogue_effect(Kind::Edge, &["path_end_mm"]),
            ),
            composite(
                "tool_wear",
                catalogue_effect(Kind::Wear, &["tool_removed_mm3"]),
            ),
        ];
        if let Ok(e) = product(
            "thermal_bow",
            catalogue_effect(Kind::Bow, &["y_mm"]),
            catalogue_effect(Kind::Drift, &["t_s"]),
        ) {
            v.insert(0, e);
        }
        v
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

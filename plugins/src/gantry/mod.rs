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
pub mod tables;
pub mod tool_influence;

/// The APLM gantry, built into the binary (docs/formats.md §4).
pub const APLM_GANTRY_TOML: &str = include_str!("../../machines/aplm-gantry.toml");

/// The built-in machine as a resolved config (run-less stage forms).
pub fn builtin_machine() -> crate::Result<MachineConfig> {
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
    fn tables(&self) -> &'static [sparkout_pipeline::contracts::TableSchema] {
        tables::TABLES
    }
    fn machine_sections(
        &self,
    ) -> &'static [(&'static str, sparkout_pipeline::config_check::SectionCheck)] {
        machine::MACHINE_SECTIONS
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

#[cfg(test)]
mod tests {
    use super::flatness::{FlatnessSummary, StateFlatness, SurfaceFlatness};
    use super::matrices::{CriticalSpeeds, GridSummary, MatricesAugmented, MatricesSummary};
    use super::observe::ObserveSummary;
    use super::polish_plan::{
        FlatnessPair, PlanFlatness, PlanLimits, PolishPlanSummary, SweepPoint,
    };
    use super::removal::{RemovalAugmented, RemovalSummary};
    use crate::typed_summary::round_trip;

    /// Every summary the gantry's stages write reads back as itself, NaN
    /// (written as `null`) included; `augmented` keeps absent ≠ `null`.
    #[test]
    fn summaries_round_trip() {
        let m = MatricesSummary {
            grid: GridSummary {
                nx: 41,
                ny: 31,
                dx_mm: 30.0,
                dy_mm: 30.0,
            },
            cut_force_n: 208.6,
            moment_n_mm: 3.1e4,
            path_velocity_mm_s: 150.0,
            critical_speed_mm_s: CriticalSpeeds {
                stringer1: 3.7e5,
                stringer2: 3.7e5,
                bridge: f64::NAN,
            },
            series_terms_max: 12,
            gamma_static_max_mm: 0.155,
            gamma_dynamic_max_mm: 0.155,
            dynamic_minus_static_max_mm: 4.2e-5,
            static_share_max_mm: [("bridge".to_string(), f64::NAN)].into(),
            dynamic_share_max_mm: [("stringer1".to_string(), 0.1)].into(),
            compensation_path_rows: 0,
            augmented: None,
        };
        let v = round_trip(&m);
        assert!(
            v.get("augmented").is_none(),
            "the run-less JSON has no `augmented`"
        );
        let mut run = m.clone();
        run.augmented = Some(None);
        assert!(round_trip(&run)["augmented"].is_null());
        run.augmented = Some(Some(MatricesAugmented {
            in_physics: "thermal_bow:y_mm".into(),
            bridge_lift_max_mm: 0.002,
        }));
        round_trip(&run);

        let f = FlatnessSummary {
            state: "after_grind".into(),
            least_squares_mm: 0.064,
            min_zone_mm: 0.062,
            plane: [1.5e-5, f64::NAN, -0.14],
            least_squares_plane: [1.3e-5, -5.2e-6, -0.145],
            states: vec![StateFlatness {
                state: "pattern".into(),
                least_squares_mm: 0.0065,
                min_zone_mm: f64::NAN,
            }],
        };
        round_trip(&f);
        round_trip(&SurfaceFlatness {
            least_squares_mm: 0.01,
            min_zone_mm: 0.009,
            n: 100,
            areal: serde_json::json!({"sq_mm": 0.001}),
        });

        let pair = |a: f64, b: f64| FlatnessPair {
            least_squares_mm: a,
            min_zone_mm: b,
        };
        round_trip(&PolishPlanSummary {
            state: "after_grind".into(),
            method: "dwell_optimisation".into(),
            placements: 40,
            selective_s: 120.0,
            raster_s: 0.0,
            raster_sweeps: 1.5,
            ratio: f64::NAN,
            breakeven_area_fraction: None,
            tolerance_mm: 0.005,
            zone_points: 444,
            zone_area_fraction: 0.35,
            dwell_s: 100.0,
            travel_s: 20.0,
            flatness: PlanFlatness {
                before: pair(0.06, 0.059),
                selective: pair(0.02, 0.019),
                raster: pair(0.05, f64::NAN),
            },
            min_zone_ratio: 0.32,
            verdict: "flatter".into(),
            warning: None,
            points_above_tolerance_after: 3,
            max_above_plane_mm: 0.03,
            max_above_plane_after_mm: f64::NEG_INFINITY,
            limits: PlanLimits {
                min_dwell_s: 0.1,
                max_dwell_s: 30.0,
                overhang_mm: 20.0,
                time_weight: 0.01,
                iterations: 400,
            },
            sweep: vec![
                SweepPoint {
                    area_fraction: 0.1,
                    ratio: 0.2,
                },
                SweepPoint {
                    area_fraction: 0.2,
                    ratio: f64::NAN,
                },
            ],
        });

        let r = RemovalSummary {
            from_state: "after_grind".into(),
            path: "motion".into(),
            path_samples: 10835,
            duration_s: 216.2,
            tool_radius_mm: 100.0,
            pressure_pa: 389.93,
            k_p_per_pa: 1.7e-8,
            removal_mean_mm: 0.056,
            removal_max_mm: 0.066,
            removal_min_mm: f64::INFINITY,
            augmented: None,
        };
        assert!(round_trip(&r).get("augmented").is_none());
        round_trip(&RemovalSummary {
            augmented: Some(RemovalAugmented {
                in_physics: "thermal_bow:y_mm".into(),
                mean_removal_mm: 0.056,
                bridge_lift_max_mm: 0.001,
            }),
            ..r
        });
        round_trip(&ObserveSummary {
            rows: 1271,
            observable: "surface_z".into(),
            state: "after_polish".into(),
            rms_gap_mm: 0.0022,
            max_abs_gap_mm: f64::NAN,
        });
    }
}

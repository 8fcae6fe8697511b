//! The mill's stage summaries (`kinematics.json`, `observe.json`): one
//! serde type each, which the stage writes and the report reads back.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// `kinematics.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct KinematicsSummary {
    /// A fit far above the tracker's noise, and what to check.
    pub warnings: Vec<String>,
    /// Identified parameters.
    pub params: usize,
    /// 3-D RMS of the fit, of the held-out points, and of the volumetric
    /// error before and after table compensation (mm; `null`: no points).
    pub fit_rms_mm: Option<f64>,
    pub holdout_rms_mm: Option<f64>,
    pub before_rms_mm: Option<f64>,
    pub after_rms_mm: Option<f64>,
    /// Residual σ per coordinate, mm.
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub sigma_mm: f64,
    pub points: usize,
    pub points_identification: usize,
    pub points_holdout: usize,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub holdout_fraction: f64,
    pub seed: u64,
    pub degree: usize,
    pub tools: usize,
    /// Error functions held at zero by the machine config.
    pub fixed: Vec<String>,
    /// The gauge freedoms fixed at zero, in words.
    pub gauge: Vec<String>,
    pub dof: usize,
    /// Reciprocal condition number of the scaled Jacobian.
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub rcond: f64,
    pub evaluations: usize,
    pub termination: String,
    /// By name: `sq_xy`, `sq_xz`, `sq_yz`.
    pub squareness: BTreeMap<String, Squareness>,
    pub tracker: TrackerFrame,
    /// By function name (`dx_x` … `ez_z`).
    pub functions: BTreeMap<String, ErrorFunction>,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub table_step_mm: f64,
    pub map_grid: usize,
    /// Whether `compensation_path` was written.
    pub compensation_path: bool,
    /// Only under `run --augment` with a spindle growth.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub augmented: Option<AugmentedGrowth>,
}

/// `kinematics.json` `squareness.<name>`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Squareness {
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub value_rad: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub sigma_rad: f64,
}

/// `kinematics.json` `tracker`: the tracker's frame in the machine's.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TrackerFrame {
    #[serde(deserialize_with = "crate::typed_summary::arr_or_nan")]
    pub rotation_vector_rad: [f64; 3],
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub angle_rad: f64,
    #[serde(deserialize_with = "crate::typed_summary::arr_or_nan")]
    pub translation_mm: [f64; 3],
}

/// `kinematics.json` `functions.<name>`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ErrorFunction {
    /// `mm` or `rad`.
    pub unit: String,
    /// Held at zero (no coefficient identified).
    pub fixed: bool,
    /// Largest |value| and largest σ over the travel.
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub max_abs: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub max_sigma: f64,
    /// By coefficient (`P0`, `P1`, …).
    pub coefficients: BTreeMap<String, Coefficient>,
}

/// A coefficient of an error function and its σ.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Coefficient {
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub value: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub sigma: f64,
}

/// `augmented` of `kinematics.json` and `observe.json`: the augmented
/// model's spindle growth the stage put into the physics (mill/augment.rs).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AugmentedGrowth {
    /// The effects' keys, joined.
    pub in_physics: String,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub growth_max_mm: f64,
}

/// `observe.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ObserveSummary {
    pub rows: usize,
    /// By observable (`tracker_dx`, …).
    pub observables: BTreeMap<String, ObservableGap>,
    /// Which optional covariates the run has.
    pub covariates: ObserveCovariates,
    /// `null` without a spindle growth from `run --augment`.
    pub augmented: Option<AugmentedGrowth>,
}

/// `observe.json` `observables.<name>`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ObservableGap {
    pub n: usize,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub rms_gap_mm: f64,
}

/// `observe.json` `covariates`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ObserveCovariates {
    pub t_s: bool,
    pub temp_c: bool,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::typed_summary::round_trip;

    #[test]
    fn summaries_round_trip() {
        let growth = AugmentedGrowth {
            in_physics: "thermal_growth:t_s".into(),
            growth_max_mm: 0.004,
        };
        let k = KinematicsSummary {
            warnings: vec!["check the tool offsets".into()],
            params: 40,
            fit_rms_mm: Some(0.002),
            holdout_rms_mm: None,
            before_rms_mm: Some(0.05),
            after_rms_mm: Some(f64::NAN),
            sigma_mm: 0.001,
            points: 100,
            points_identification: 80,
            points_holdout: 20,
            holdout_fraction: 0.2,
            seed: 7,
            degree: 3,
            tools: 2,
            fixed: vec!["ez_z".into()],
            gauge: vec!["P0 → tracker translation".into()],
            dof: 200,
            rcond: f64::NAN,
            evaluations: 12,
            termination: "Converged".into(),
            squareness: [(
                "sq_xy".to_string(),
                Squareness {
                    value_rad: 1e-5,
                    sigma_rad: 1e-7,
                },
            )]
            .into(),
            tracker: TrackerFrame {
                rotation_vector_rad: [1e-4, f64::NAN, 0.0],
                angle_rad: 1e-4,
                translation_mm: [1.0, 2.0, 3.0],
            },
            functions: [(
                "dx_x".to_string(),
                ErrorFunction {
                    unit: "mm".into(),
                    fixed: false,
                    max_abs: 0.01,
                    max_sigma: 0.001,
                    coefficients: [(
                        "P2".to_string(),
                        Coefficient {
                            value: 1e-6,
                            sigma: 1e-8,
                        },
                    )]
                    .into(),
                },
            )]
            .into(),
            table_step_mm: 25.0,
            map_grid: 7,
            compensation_path: true,
            augmented: None,
        };
        let v = round_trip(&k);
        assert!(
            v.get("augmented").is_none(),
            "absent, not null, without --augment"
        );
        let mut augmented = k.clone();
        augmented.augmented = Some(growth.clone());
        round_trip(&augmented);
        let o = ObserveSummary {
            rows: 9,
            observables: [(
                "tracker_dz".to_string(),
                ObservableGap {
                    n: 3,
                    rms_gap_mm: 0.001,
                },
            )]
            .into(),
            covariates: ObserveCovariates {
                t_s: true,
                temp_c: false,
            },
            augmented: None,
        };
        assert!(round_trip(&o)["augmented"].is_null());
        round_trip(&ObserveSummary {
            augmented: Some(growth),
            ..o
        });
    }
}

//! The robot stages' summaries (`<stage>.json`) as serde types: the stage
//! that writes a summary builds one of these, and the report reads it back
//! through the same type, so a renamed field fails to compile instead of
//! printing "—".
//!
//! Numbers: serde_json writes a non-finite `f64` as `null`. A field the
//! stage may leave undefined is an `Option<f64>` (`null` ↔ `None`, written
//! through [`fin`]); a plain `f64` field reads `null` back as NaN
//! ([`nan`]). Field order is the order the keys were written in.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

pub(crate) use crate::typed_summary::{
    arr_or_nan as nan3, f64_or_nan as nan, finite as fin, json_number,
};

/// [`fin`] of an optional number.
pub fn fin_opt(x: Option<f64>) -> Option<f64> {
    x.and_then(fin)
}

// ---------------------------------------------------------------- ingest

/// `ingest.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IngestSummary {
    /// `probe` or `ae`.
    pub touch_source: String,
    pub n_touches: usize,
    /// Touches per face label.
    pub per_face: BTreeMap<String, usize>,
    /// The AE path's findings (`null` without ae + motion + plan).
    pub ae: Option<AeSummary>,
    /// Recorded vs AE-derived touches (`null` unless both exist).
    pub compare: Option<CompareSummary>,
}

/// The AE detector's parameters in force, in samples and seconds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AeParamsSummary {
    pub signal: String,
    pub signal_from: String,
    #[serde(deserialize_with = "nan")]
    pub sample_rate_hz: f64,
    pub window_samples: usize,
    #[serde(deserialize_with = "nan")]
    pub window_s: f64,
    pub min_dwell_samples: usize,
    #[serde(deserialize_with = "nan")]
    pub min_dwell_s: f64,
    pub merge_gap_samples: usize,
    #[serde(deserialize_with = "nan")]
    pub merge_gap_s: f64,
    pub noise_window_samples: usize,
    #[serde(deserialize_with = "nan")]
    pub noise_window_s: f64,
    #[serde(deserialize_with = "nan")]
    pub k_sigma: f64,
    #[serde(deserialize_with = "nan")]
    pub hysteresis: f64,
}

/// `ingest.json`'s `ae`: what the AE contact detection found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AeSummary {
    pub samples: u64,
    pub recording_blocks: usize,
    pub window_samples: usize,
    pub params: AeParamsSummary,
    pub events: usize,
    pub short_crossings: u64,
    pub stray_crossings: u64,
    pub warnings: Vec<String>,
    pub touches: usize,
    pub extra_events: usize,
    pub unassigned_events: usize,
    /// The first 100 plan rows without a contact.
    pub missed_seq: Vec<i32>,
    pub n_missed: usize,
    #[serde(deserialize_with = "nan")]
    pub noise_floor_v: f64,
    #[serde(deserialize_with = "nan")]
    pub noise_sigma_v: f64,
    #[serde(deserialize_with = "nan")]
    pub threshold_v: f64,
    #[serde(deserialize_with = "nan")]
    pub k_sigma: f64,
    #[serde(deserialize_with = "nan")]
    pub clock_offset_s: f64,
    /// `act` (measured) or `cmd` (commanded) positions.
    pub positions: String,
}

/// `ingest.json`'s `compare`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CompareSummary {
    pub n: usize,
    #[serde(deserialize_with = "nan")]
    pub rms_dist_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub max_dist_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub mean_dnormal_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub mean_dt_s: f64,
    pub by_speed: Vec<CompareGroup>,
}

/// One (method, approach speed) group of [`CompareSummary`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CompareGroup {
    pub method: String,
    #[serde(deserialize_with = "nan")]
    pub approach_mm_s: f64,
    pub n: usize,
    #[serde(deserialize_with = "nan")]
    pub mean_dnormal_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub mean_dt_s: f64,
}

/// `sparkout stage ingest --ae FILE`: the contacts of any signal column.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IngestStandalone {
    pub contacts: Vec<ContactSummary>,
    /// The first recording block's threshold (`null` without one).
    pub threshold: Option<f64>,
    pub params: AeParamsSummary,
    pub warnings: Vec<String>,
}

/// One contact of [`IngestStandalone`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ContactSummary {
    #[serde(deserialize_with = "nan")]
    pub start_s: f64,
    #[serde(deserialize_with = "nan")]
    pub end_s: f64,
    #[serde(deserialize_with = "nan")]
    pub peak: f64,
}

// --------------------------------------------------------- repeatability

/// `repeatability.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RepeatabilitySummary {
    /// One per (method, approach speed), in that order.
    pub groups: Vec<RepeatabilityGroup>,
    /// The headline trigger latency (`null` when not estimable).
    pub latency_s: Option<f64>,
    pub latency_by_method: BTreeMap<String, MethodLatency>,
}

/// One (method, approach speed) group of [`RepeatabilitySummary`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RepeatabilityGroup {
    pub method: String,
    #[serde(deserialize_with = "nan")]
    pub approach_mm_s: f64,
    /// By face label; a face the group did not touch is absent.
    pub faces: BTreeMap<String, FaceRepeatability>,
    pub mean_range_mm: Option<f64>,
    pub mean_std_mm: Option<f64>,
}

/// One face of a [`RepeatabilityGroup`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FaceRepeatability {
    pub range_mm: Option<f64>,
    pub std_mm: Option<f64>,
    pub n: usize,
    pub n_points: usize,
    #[serde(deserialize_with = "nan")]
    pub bias_mm: f64,
    pub scatter_mm: Option<f64>,
    pub bias_latency_corrected_mm: Option<f64>,
}

/// The trigger latency of one touch method.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MethodLatency {
    #[serde(deserialize_with = "nan")]
    pub latency_s: f64,
    pub stderr_s: Option<f64>,
    pub n: usize,
    pub speeds_mm_s: Vec<f64>,
}

// ----------------------------------------------------------------- datum

/// `datum.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DatumSummary {
    /// `tls` or `ols`: the fit the datum is taken from.
    pub fit: String,
    /// By face label.
    pub planes: BTreeMap<String, PlaneSummary>,
    /// `null` when not finite.
    pub datum_mm: Option<[f64; 3]>,
    pub datum_cov_mm2: Option<[[f64; 3]; 3]>,
    pub datum_sigma_mm: [Option<f64>; 3],
    pub datum_ellipsoid_mm: Ellipsoid,
    #[serde(deserialize_with = "nan")]
    pub condition: f64,
    pub squareness_rad: Squareness,
    /// The thesis's E = A·α (`null` without α on every face).
    pub error_vector_mm: Option<[f64; 3]>,
    pub alpha_mm: AxisTriple,
    /// By face label.
    pub transition_angles_rad: BTreeMap<String, Option<f64>>,
    /// The datum of the other fit (`null` when it has none).
    pub datum_other_fit: Option<OtherFit>,
    pub by_square: Vec<SquareDatum>,
    /// Latency corrected for, by touch method.
    pub latency_corrected_s: BTreeMap<String, Option<f64>>,
    /// The touch method the datum was taken from.
    pub touch_method: String,
}

/// One face plane of [`DatumSummary`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlaneSummary {
    /// The thesis's OLS form b0, b1, b2.
    pub ols: [Option<f64>; 3],
    pub tls_normal: [Option<f64>; 3],
    #[serde(deserialize_with = "nan")]
    pub tls_d: f64,
    pub residual_rms_mm: Option<f64>,
    pub residual_max_mm: Option<f64>,
    pub ols_residual_rms_mm: Option<f64>,
    pub tls_residual_rms_mm: Option<f64>,
    pub n: usize,
    pub n_rejected: usize,
    pub robust_scale_mm: Option<f64>,
    pub rejected: Vec<RejectedTouch>,
}

/// A touch the robust fit rejected.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RejectedTouch {
    pub point: i32,
    pub trial: i32,
    pub method: String,
    #[serde(deserialize_with = "nan")]
    pub approach_mm_s: f64,
    #[serde(deserialize_with = "nan")]
    pub distance_mm: f64,
}

/// The datum's confidence ellipsoid.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Ellipsoid {
    #[serde(deserialize_with = "nan")]
    pub confidence: f64,
    pub semi_axes_mm: [Option<f64>; 3],
    pub axes: [Option<[f64; 3]>; 3],
}

/// Deviation from 90° of each pair of faces (rad).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Squareness {
    pub xy_yz: Option<f64>,
    pub yz_zx: Option<f64>,
    pub zx_xy: Option<f64>,
}

impl Squareness {
    pub fn new(sq: &[f64; 3]) -> Self {
        Squareness {
            xy_yz: fin(sq[0]),
            yz_zx: fin(sq[1]),
            zx_xy: fin(sq[2]),
        }
    }
    /// `(key, value)` in the order the report lists them.
    pub fn pairs(&self) -> [(&'static str, Option<f64>); 3] {
        [
            ("xy_yz", self.xy_yz),
            ("yz_zx", self.yz_zx),
            ("zx_xy", self.zx_xy),
        ]
    }
}

/// A value per axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AxisTriple {
    pub x: Option<f64>,
    pub y: Option<f64>,
    pub z: Option<f64>,
}

/// `datum.json`'s `datum_other_fit`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OtherFit {
    pub datum_mm: Option<[f64; 3]>,
    pub datum_cov_mm2: Option<[[f64; 3]; 3]>,
    pub datum_sigma_mm: [Option<f64>; 3],
    #[serde(deserialize_with = "nan")]
    pub condition: f64,
    pub squareness_rad: Squareness,
}

/// The datum of one square of the thesis's pattern.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SquareDatum {
    pub square: String,
    /// By face label.
    pub planes: BTreeMap<String, SquarePlane>,
    pub datum_mm: Option<[f64; 3]>,
    pub datum_sigma_mm: Option<[Option<f64>; 3]>,
}

/// One face plane of a [`SquareDatum`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SquarePlane {
    pub ols: [Option<f64>; 3],
    pub residual_rms_mm: Option<f64>,
    pub n: usize,
}

/// `sparkout stage datum --planes ...`: the datum of three given planes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DatumStandalone {
    /// By face label when the planes face three distinct axes, else
    /// `p1`, `p2`, `p3`.
    pub planes: BTreeMap<String, GivenPlane>,
    pub datum_mm: Option<[f64; 3]>,
    /// Always `null`: given planes carry no covariance.
    pub datum_cov_mm2: Option<[[f64; 3]; 3]>,
    #[serde(deserialize_with = "nan")]
    pub condition: f64,
    pub squareness_rad: GivenSquareness,
    pub error_vector_mm: Option<[f64; 3]>,
}

/// One plane of [`DatumStandalone`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GivenPlane {
    #[serde(deserialize_with = "nan3")]
    pub normal: [f64; 3],
    #[serde(deserialize_with = "nan")]
    pub d: f64,
    #[serde(deserialize_with = "nan3")]
    pub tls_normal: [f64; 3],
    #[serde(deserialize_with = "nan")]
    pub tls_d: f64,
    /// The thesis's OLS form, when the plane is labelled by its face.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ols: Option<[f64; 3]>,
}

/// Squareness of given planes: by face pair when the planes are labelled
/// by face, else by plane pair.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum GivenSquareness {
    Faces(Squareness),
    Planes(PlaneSquareness),
}

/// Squareness of planes `p1`, `p2`, `p3`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlaneSquareness {
    pub p1_p2: Option<f64>,
    pub p2_p3: Option<f64>,
    pub p3_p1: Option<f64>,
}

// ----------------------------------------------------------------- cycle

/// `cycle.json` and `sparkout stage cycle`: the full summary, or the empty
/// one of a run without passes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum CycleSummary {
    Passes(CyclePasses),
    NoPasses(NoPasses),
}

/// The cycle model against the passes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CyclePasses {
    #[serde(deserialize_with = "nan")]
    pub alpha_first_pass: f64,
    pub alpha_fit: Option<f64>,
    #[serde(deserialize_with = "nan")]
    pub ratio_first_pass: f64,
    pub passes: Vec<CyclePass>,
    pub remaining_after_mm: Remaining,
    pub remaining_after_measured_mm: Remaining,
    /// Spark-out time constant by feed (mm/s).
    pub tau_s: BTreeMap<String, Option<f64>>,
    pub weld_mm: Option<f64>,
    pub rms_gap_first_pass_mm: Option<f64>,
    pub rms_gap_fit_mm: Option<f64>,
}

/// A probing-only run: no passes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoPasses {
    pub alpha_first_pass: Option<f64>,
    pub alpha_fit: Option<f64>,
    pub passes: Vec<CyclePass>,
    pub remaining_after_mm: Remaining,
    pub tau_s: BTreeMap<String, Option<f64>>,
    pub note: String,
}

/// One pass of [`CyclePasses`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CyclePass {
    pub pass: i32,
    pub stage: String,
    #[serde(deserialize_with = "nan")]
    pub nominal_doc_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub predicted_cut_mm: f64,
    pub measured_cut_mm: Option<f64>,
    pub predicted_cut_fit_mm: Option<f64>,
}

/// The stock left after the last pass of each stage.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Remaining {
    pub rough: Option<f64>,
    pub finish: Option<f64>,
    pub spark: Option<f64>,
}

impl Remaining {
    /// `(stage, value)` in pass order.
    pub fn stages(&self) -> [(&'static str, Option<f64>); 3] {
        [
            ("rough", self.rough),
            ("finish", self.finish),
            ("spark", self.spark),
        ]
    }
}

// --------------------------------------------------------------- observe

/// `observe.json`: the row count, the plane fit, and per observable its
/// count and RMS gap (keys of the observables beside the two fixed ones).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObserveSummary {
    pub rows: usize,
    pub plane_fit: String,
    #[serde(flatten)]
    pub observables: BTreeMap<String, ObservableGap>,
}

/// One observable of [`ObserveSummary`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObservableGap {
    pub n: usize,
    pub rms_gap_mm: Option<f64>,
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) use crate::typed_summary::reads_back as round_trip;

    fn params() -> AeParamsSummary {
        AeParamsSummary {
            signal: "raw".into(),
            signal_from: "config".into(),
            sample_rate_hz: 200_000.0,
            window_samples: 40,
            window_s: 2e-4,
            min_dwell_samples: 20,
            min_dwell_s: 1e-4,
            merge_gap_samples: 200,
            merge_gap_s: 1e-3,
            noise_window_samples: 2000,
            noise_window_s: 0.01,
            k_sigma: 8.0,
            hysteresis: 0.5,
        }
    }

    #[test]
    fn every_robot_summary_reads_back_what_it_wrote() {
        let compare = CompareSummary {
            n: 3,
            rms_dist_mm: 0.01,
            max_dist_mm: f64::NAN,
            mean_dnormal_mm: -0.002,
            mean_dt_s: 0.004,
            by_speed: vec![CompareGroup {
                method: "ae".into(),
                approach_mm_s: 5.0,
                n: 3,
                mean_dnormal_mm: 0.1,
                mean_dt_s: 0.2,
            }],
        };
        let ingest = IngestSummary {
            touch_source: "probe".into(),
            n_touches: 3,
            per_face: [("xy".to_string(), 3)].into_iter().collect(),
            ae: Some(AeSummary {
                samples: 10,
                recording_blocks: 1,
                window_samples: 40,
                params: params(),
                events: 4,
                short_crossings: 1,
                stray_crossings: 0,
                warnings: vec!["w".into()],
                touches: 3,
                extra_events: 1,
                unassigned_events: 0,
                missed_seq: vec![7],
                n_missed: 1,
                noise_floor_v: 0.001,
                noise_sigma_v: 0.0002,
                threshold_v: 0.003,
                k_sigma: 8.0,
                clock_offset_s: 0.1,
                positions: "act".into(),
            }),
            compare: Some(compare),
        };
        let back = round_trip(&ingest);
        assert!(back.compare.unwrap().max_dist_mm.is_nan());
        round_trip(&IngestSummary {
            ae: None,
            compare: None,
            ..ingest
        });
        round_trip(&IngestStandalone {
            contacts: vec![ContactSummary {
                start_s: 1.0,
                end_s: 1.5,
                peak: 0.2,
            }],
            threshold: None,
            params: params(),
            warnings: vec![],
        });
        let face = FaceRepeatability {
            range_mm: Some(0.01),
            std_mm: None,
            n: 10,
            n_points: 4,
            bias_mm: -0.02,
            scatter_mm: None,
            bias_latency_corrected_mm: Some(0.0),
        };
        round_trip(&RepeatabilitySummary {
            groups: vec![RepeatabilityGroup {
                method: "probe".into(),
                approach_mm_s: 5.0,
                faces: [("xy".to_string(), face)].into_iter().collect(),
                mean_range_mm: Some(0.01),
                mean_std_mm: None,
            }],
            latency_s: None,
            latency_by_method: [(
                "ae".to_string(),
                MethodLatency {
                    latency_s: 0.004,
                    stderr_s: None,
                    n: 20,
                    speeds_mm_s: vec![5.0, 10.0],
                },
            )]
            .into_iter()
            .collect(),
        });
        let sq = Squareness::new(&[1e-4, f64::NAN, -2e-4]);
        let plane = PlaneSummary {
            ols: [Some(1.0), None, Some(0.001)],
            tls_normal: [Some(0.0), Some(0.0), Some(1.0)],
            tls_d: 3.0,
            residual_rms_mm: Some(0.001),
            residual_max_mm: None,
            ols_residual_rms_mm: Some(0.001),
            tls_residual_rms_mm: Some(0.001),
            n: 12,
            n_rejected: 1,
            robust_scale_mm: None,
            rejected: vec![RejectedTouch {
                point: 3,
                trial: 1,
                method: "probe".into(),
                approach_mm_s: 5.0,
                distance_mm: 0.5,
            }],
        };
        let datum = DatumSummary {
            fit: "tls".into(),
            planes: [("xy".to_string(), plane)].into_iter().collect(),
            datum_mm: Some([1.0, 2.0, 3.0]),
            datum_cov_mm2: None,
            datum_sigma_mm: [Some(0.001), None, Some(0.002)],
            datum_ellipsoid_mm: Ellipsoid {
                confidence: 0.95,
                semi_axes_mm: [Some(0.003), Some(0.002), None],
                axes: [Some([1.0, 0.0, 0.0]), None, Some([0.0, 0.0, 1.0])],
            },
            condition: f64::NAN,
            squareness_rad: sq.clone(),
            error_vector_mm: None,
            alpha_mm: AxisTriple {
                x: Some(0.001),
                y: None,
                z: Some(0.002),
            },
            transition_angles_rad: [("xy".to_string(), None), ("yz".to_string(), Some(1e-4))]
                .into_iter()
                .collect(),
            datum_other_fit: Some(OtherFit {
                datum_mm: None,
                datum_cov_mm2: Some([[1e-6, 0.0, 0.0], [0.0, 1e-6, 0.0], [0.0, 0.0, 1e-6]]),
                datum_sigma_mm: [None, None, None],
                condition: 1.5,
                squareness_rad: sq.clone(),
            }),
            by_square: vec![SquareDatum {
                square: "outer".into(),
                planes: [(
                    "yz".to_string(),
                    SquarePlane {
                        ols: [Some(1.0), Some(0.0), None],
                        residual_rms_mm: None,
                        n: 4,
                    },
                )]
                .into_iter()
                .collect(),
                datum_mm: None,
                datum_sigma_mm: Some([Some(0.1), None, Some(0.3)]),
            }],
            latency_corrected_s: [("ae".to_string(), Some(0.004))].into_iter().collect(),
            touch_method: "probe".into(),
        };
        assert!(round_trip(&datum).condition.is_nan());
        let given = GivenPlane {
            normal: [0.0, 0.0, 1.0],
            d: 3.0,
            tls_normal: [0.0, 0.0, 1.0],
            tls_d: 3.0,
            ols: None,
        };
        for squareness_rad in [
            GivenSquareness::Faces(sq),
            GivenSquareness::Planes(PlaneSquareness {
                p1_p2: Some(0.1),
                p2_p3: None,
                p3_p1: Some(0.2),
            }),
        ] {
            let s = DatumStandalone {
                planes: [
                    ("p1".to_string(), given.clone()),
                    (
                        "xy".to_string(),
                        GivenPlane {
                            ols: Some([3.0, 0.0, 0.0]),
                            ..given.clone()
                        },
                    ),
                ]
                .into_iter()
                .collect(),
                datum_mm: Some([1.0, 2.0, 3.0]),
                datum_cov_mm2: None,
                condition: 1.0,
                squareness_rad,
                error_vector_mm: Some([0.1, 0.2, 0.3]),
            };
            assert_eq!(round_trip(&s), s);
        }
        let pass = CyclePass {
            pass: 1,
            stage: "rough".into(),
            nominal_doc_mm: 0.3,
            predicted_cut_mm: 0.2,
            measured_cut_mm: None,
            predicted_cut_fit_mm: Some(0.21),
        };
        for c in [
            CycleSummary::Passes(CyclePasses {
                alpha_first_pass: 0.5,
                alpha_fit: None,
                ratio_first_pass: 0.5 / 1.5,
                passes: vec![pass],
                remaining_after_mm: Remaining {
                    rough: Some(0.1),
                    finish: None,
                    spark: Some(0.01),
                },
                remaining_after_measured_mm: Remaining::default(),
                tau_s: [("20".to_string(), None)].into_iter().collect(),
                weld_mm: Some(2.27),
                rms_gap_first_pass_mm: None,
                rms_gap_fit_mm: Some(0.01),
            }),
            CycleSummary::NoPasses(NoPasses {
                alpha_first_pass: None,
                alpha_fit: None,
                passes: vec![],
                remaining_after_mm: Remaining::default(),
                tau_s: BTreeMap::new(),
                note: "no passes".into(),
            }),
        ] {
            assert_eq!(round_trip(&c), c);
        }
        let obs = ObserveSummary {
            rows: 10,
            plane_fit: "tls".into(),
            observables: [
                (
                    "cut_depth".to_string(),
                    ObservableGap {
                        n: 0,
                        rms_gap_mm: None,
                    },
                ),
                (
                    "touch_ae".to_string(),
                    ObservableGap {
                        n: 10,
                        rms_gap_mm: Some(0.002),
                    },
                ),
            ]
            .into_iter()
            .collect(),
        };
        assert_eq!(round_trip(&obs), obs);
    }
}

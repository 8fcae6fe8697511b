//! The form stages' summaries (`<stage>.json`) as serde types: the stage
//! that writes a summary builds one of these, and the report reads it back
//! through the same type, so a renamed field fails to compile instead of
//! printing NaN.
//!
//! Numbers: serde_json writes a non-finite `f64` as `null`; a plain `f64`
//! field reads `null` back as NaN ([`nan`]), an `Option<f64>` as `None`.
//! Field order is the order the keys were written in.

use serde::{Deserialize, Serialize};

pub(crate) use crate::typed_summary::{
    f64_or_nan as nan, finite as fin, vec_f64_or_nan as nan_vec,
};

// --------------------------------------------------------------- segment

/// `segment.json`: the wheel-radius segmentation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SegmentSummary {
    #[serde(deserialize_with = "nan")]
    pub r_max_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub range_mm: f64,
    pub profile_points: usize,
    pub segments: Vec<SegmentRow>,
    /// The largest profile error over the segments.
    #[serde(deserialize_with = "nan")]
    pub max_error_mm: f64,
    /// The largest profile error for each number of segments.
    pub sweep: Vec<SweepPoint>,
}

/// One segment of [`SegmentSummary`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SegmentRow {
    pub segment: usize,
    #[serde(deserialize_with = "nan")]
    pub nominal_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub r_min_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub r_max_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub max_error_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub phi_at_max_rad: f64,
    #[serde(deserialize_with = "nan")]
    pub radius_at_max_mm: f64,
}

/// One number of segments of [`SegmentSummary`]'s sweep.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepPoint {
    pub segments: usize,
    #[serde(deserialize_with = "nan")]
    pub max_error_mm: f64,
}

// ---------------------------------------------------------------- cldata

/// `form_cldata.json`: the programs written, one per segment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CldataSummary {
    pub programs: Vec<ProgramLines>,
}

/// One program of [`CldataSummary`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProgramLines {
    pub segment: i32,
    pub lines: usize,
}

/// `sparkout stage form_cldata --profile FILE`: the segmentation, and the
/// program files written with `--cldata-dir`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CldataStandalone {
    #[serde(flatten)]
    pub segment: SegmentSummary,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cldata_files: Option<Vec<String>>,
}

// --------------------------------------------------------- profile_error

/// `profile_error.json`: δ(φ) of the design profile for the actual radii.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProfileErrorSummary {
    #[serde(deserialize_with = "nan")]
    pub nominal_mm: f64,
    pub delta_model: String,
    pub points: usize,
    pub closed: bool,
    pub straight_points: usize,
    #[serde(deserialize_with = "nan")]
    pub curvature_max_per_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub curvature_min_per_mm: f64,
    pub radii: Vec<RadiusError>,
    #[serde(deserialize_with = "nan")]
    pub max_error_mm: f64,
    /// The fitted wheel wear of `run --augment` (`null` without one).
    pub augmented: Option<WearApplied>,
}

/// The profile error for one actual wheel radius.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RadiusError {
    #[serde(deserialize_with = "nan")]
    pub wheel_radius_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub max_error_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub signed_max_error_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub phi_at_max_rad: f64,
    #[serde(deserialize_with = "nan")]
    pub rms_error_mm: f64,
}

/// Whether the fitted wheel wear entered the compensation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum WearApplied {
    /// In the physics: the wear's effects and its largest radius loss.
    Applied {
        in_physics: String,
        wear_max_mm: Option<f64>,
    },
    /// Not applied: the run does not say how much the wheel has removed.
    NotApplied {
        in_physics: Option<String>,
        not_applied: String,
        why: String,
    },
}

// --------------------------------------------------------------- observe

/// `observe.json` of a form run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObserveSummary {
    pub observable: String,
    pub rows: usize,
    #[serde(deserialize_with = "nan")]
    pub nominal_mm: f64,
    #[serde(deserialize_with = "nan_vec")]
    pub wheel_radii_mm: Vec<f64>,
    #[serde(deserialize_with = "nan")]
    pub gap_rms_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub gap_mean_mm: f64,
    pub covariates: Vec<String>,
    /// `config` or `run`.
    pub nominal_source: String,
    /// The rows the worn wheel was applied to (`null` without a wear).
    pub augmented: Option<ObserveAugmented>,
}

/// [`ObserveSummary`]'s `augmented`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObserveAugmented {
    pub in_physics: String,
    pub rows: usize,
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::typed_summary::reads_back as round_trip;

    #[test]
    fn every_form_summary_reads_back_what_it_wrote() {
        let seg = SegmentSummary {
            r_max_mm: 175.0,
            range_mm: 50.0,
            profile_points: 720,
            segments: vec![SegmentRow {
                segment: 0,
                nominal_mm: 160.0,
                r_min_mm: 150.0,
                r_max_mm: 175.0,
                max_error_mm: f64::NAN,
                phi_at_max_rad: 1.0,
                radius_at_max_mm: 150.0,
            }],
            max_error_mm: 0.01,
            sweep: vec![SweepPoint {
                segments: 1,
                max_error_mm: 0.01,
            }],
        };
        let back = round_trip(&seg);
        assert!(back.segments[0].max_error_mm.is_nan());
        for files in [None, Some(vec!["segment_00.cls".to_string()])] {
            let c = CldataStandalone {
                segment: SegmentSummary {
                    segments: vec![],
                    ..seg.clone()
                },
                cldata_files: files,
            };
            assert_eq!(round_trip(&c), c);
        }
        let c = CldataSummary {
            programs: vec![ProgramLines {
                segment: 0,
                lines: 12,
            }],
        };
        assert_eq!(round_trip(&c), c);
        let radius = RadiusError {
            wheel_radius_mm: 160.0,
            max_error_mm: 0.01,
            signed_max_error_mm: -0.01,
            phi_at_max_rad: 0.5,
            rms_error_mm: 0.004,
        };
        for augmented in [
            None,
            Some(WearApplied::Applied {
                in_physics: "wear(removed_mm3)".into(),
                wear_max_mm: None,
            }),
            Some(WearApplied::NotApplied {
                in_physics: None,
                not_applied: "wear(removed_mm3)".into(),
                why: "unknown usage".into(),
            }),
        ] {
            let p = ProfileErrorSummary {
                nominal_mm: 170.0,
                delta_model: "exact".into(),
                points: 720,
                closed: true,
                straight_points: 0,
                curvature_max_per_mm: 0.1,
                curvature_min_per_mm: -0.1,
                radii: vec![radius.clone()],
                max_error_mm: 0.01,
                augmented,
            };
            assert_eq!(round_trip(&p), p);
        }
        for augmented in [
            None,
            Some(ObserveAugmented {
                in_physics: "wear(removed_mm3)".into(),
                rows: 10,
            }),
        ] {
            let o = ObserveSummary {
                observable: "profile_error".into(),
                rows: 10,
                nominal_mm: 170.0,
                wheel_radii_mm: vec![160.0, 158.0],
                gap_rms_mm: 0.002,
                gap_mean_mm: 0.0,
                covariates: vec!["phi_rad".into()],
                nominal_source: "run".into(),
                augmented,
            };
            assert_eq!(round_trip(&o), o);
        }
    }
}

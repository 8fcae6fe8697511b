//! The form plugin's config sections (`[form.profile_error]`,
//! `[form.segment]`, `[form.observe]`), one serde struct each: defaults
//! here only, each key's range as data ([`Section::CHECKS`]), read by the
//! pipeline's shared reader (`config_check::read_section`).

use serde::{Deserialize, Serialize};
pub use sparkout_pipeline::config_check::{Check, Section};
use sparkout_pipeline::Result;

use super::curvature::CurvatureConfig;
use super::model::{DeltaModel, WheelRange};

/// `window_points` of every stage that differentiates the profile: an odd
/// number of points ≥ 5 per local cubic fit.
const WINDOW_CHECK: (&str, Check) = ("window_points", Check::OddAtLeast(5));
const DELTA_MODEL_CHECK: (&str, Check) = ("delta_model", Check::OneOf(DeltaModel::NAMES));

fn default_window_points() -> usize {
    CurvatureConfig::default().window_points
}

/// The most segments `segment` splits the wheel's range into.
pub const MAX_SEGMENTS: usize = 1000;

/// `[form.profile_error]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ProfileErrorConfig {
    pub window_points: usize,
    pub delta_model: DeltaModel,
    /// None: run.toml `[process] nominal_wheel_radius_mm`, else the
    /// machine's largest radius.
    pub nominal_mm: Option<f64>,
    /// None: the measured rows' radii, else run.toml `[process]`.
    pub wheel_radius_mm: Option<f64>,
}

impl Default for ProfileErrorConfig {
    fn default() -> Self {
        ProfileErrorConfig {
            window_points: default_window_points(),
            delta_model: DeltaModel::default(),
            nominal_mm: None,
            wheel_radius_mm: None,
        }
    }
}

impl Section for ProfileErrorConfig {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("nominal_mm", Check::Positive),
        ("wheel_radius_mm", Check::Positive),
        DELTA_MODEL_CHECK,
        WINDOW_CHECK,
    ];
}

/// `[form.observe]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ObserveConfig {
    pub window_points: usize,
    /// The model whose δ is `sim`.
    pub delta_model: DeltaModel,
    /// As in [`ProfileErrorConfig::nominal_mm`].
    pub nominal_mm: Option<f64>,
}

impl Default for ObserveConfig {
    fn default() -> Self {
        ObserveConfig {
            window_points: default_window_points(),
            delta_model: DeltaModel::default(),
            nominal_mm: None,
        }
    }
}

impl Section for ObserveConfig {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("nominal_mm", Check::Positive),
        DELTA_MODEL_CHECK,
        WINDOW_CHECK,
    ];
}

/// `[form.segment]`, and the run-less `form_cldata` flags.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SegmentSection {
    pub window_points: usize,
    pub delta_model: DeltaModel,
    /// None: the machine's `[wheel] radius_max_mm`.
    pub r_max_mm: Option<f64>,
    /// None: the machine's `[wheel] usable_range_mm`.
    pub range_mm: Option<f64>,
    /// None: the machine's `[wheel] segments`, else 5.
    pub segments: Option<usize>,
    /// Wheel radii sampled per segment when searching its largest error.
    pub radius_samples: usize,
    /// The sweep reports the largest error for N = 1 … sweep_max.
    pub sweep_max: usize,
    /// None: run.toml `[process] z_mm`, else 0.
    pub z_mm: Option<f64>,
}

impl Default for SegmentSection {
    fn default() -> Self {
        SegmentSection {
            window_points: default_window_points(),
            delta_model: DeltaModel::default(),
            r_max_mm: None,
            range_mm: None,
            segments: None,
            radius_samples: 11,
            sweep_max: 10,
            z_mm: None,
        }
    }
}

impl Section for SegmentSection {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("r_max_mm", Check::Positive),
        ("range_mm", Check::Positive),
        ("segments", Check::WholeIn(1, MAX_SEGMENTS as i64)),
        // Both ends of each segment.
        ("radius_samples", Check::WholeIn(2, 1001)),
        ("sweep_max", Check::WholeIn(1, 100)),
        ("z_mm", Check::NonNegative),
        DELTA_MODEL_CHECK,
        WINDOW_CHECK,
    ];
    fn validate(&self) -> Result<()> {
        if let (Some(r_max_mm), Some(range_mm)) = (self.r_max_mm, self.range_mm) {
            WheelRange { r_max_mm, range_mm }
                .check()
                .map_err(|m| crate::err!(m))?;
        }
        Ok(())
    }
}

/// The curvature settings of a section's `window_points`.
pub fn curvature(window_points: usize) -> CurvatureConfig {
    CurvatureConfig { window_points }
}

/// `[wheel]` of a form machine config (configs/machines/form-grinder.toml),
/// read once when the machine is loaded. None: the machine does not say
/// (the stage that needs the value names the key).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MachineWheel {
    /// A new wheel's radius (mm).
    pub radius_max_mm: Option<f64>,
    /// How far dressing may take the radius down (mm).
    pub usable_range_mm: Option<f64>,
    pub width_mm: Option<f64>,
    /// Segments of the radius range (a `[form.segment]` key wins).
    pub segments: Option<usize>,
}

impl Section for MachineWheel {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("radius_max_mm", Check::Positive),
        ("usable_range_mm", Check::Positive),
        ("width_mm", Check::Positive),
        ("segments", Check::WholeIn(1, MAX_SEGMENTS as i64)),
    ];
}

/// `[process]` of a form machine config: the machine's defaults for what
/// a run's `[process]` may give.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MachineProcess {
    /// Path speed along the profile (mm/s).
    pub feed_mm_s: Option<f64>,
}

impl Section for MachineProcess {
    const CHECKS: &'static [(&'static str, Check)] = &[("feed_mm_s", Check::Positive)];
}

/// The form machine config's sections the stages read.
pub const MACHINE_SECTIONS: &[(&str, sparkout_pipeline::config_check::SectionCheck)] = &[
    (
        "wheel",
        sparkout_pipeline::config_check::SectionCheck::of::<MachineWheel>(),
    ),
    (
        "process",
        sparkout_pipeline::config_check::SectionCheck::of::<MachineProcess>(),
    ),
];

//! The sections of a robot machine config (configs/machines/kr16-lab.toml)
//! that the stages read, one serde struct each: read and checked once when
//! a run's machine is loaded, an error naming the file and `section.key`.

use serde::{Deserialize, Serialize};
use sparkout_pipeline::config_check::{Check, Section, SectionCheck};

/// `[probing]`: the probing cell.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MachineProbing {
    /// Default approach direction per face when no plan says (a zero
    /// vector: the face's −normal axis).
    pub approach_dir_xy: Option<[f64; 3]>,
    pub approach_dir_yz: Option<[f64; 3]>,
    pub approach_dir_zx: Option<[f64; 3]>,
    /// Approach start outside the nominal surface (mm).
    pub standoff_mm: Option<f64>,
    /// Approach speeds of the repeatability study (mm/s).
    pub speeds_mm_s: Option<Vec<f64>>,
}

impl Section for MachineProbing {
    const CHECKS: &'static [(&'static str, Check)] = &[("standoff_mm", Check::Positive)];
}

/// `[process]`: the machine's defaults for what a run's `[process]` may
/// give.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MachineProcess {
    /// Wheel–work contact area (mm²): removed volume = cut depth × area.
    pub contact_area_mm2: Option<f64>,
}

impl Section for MachineProcess {
    const CHECKS: &'static [(&'static str, Check)] = &[("contact_area_mm2", Check::Positive)];
}

/// The robot machine config's sections the stages read.
pub const MACHINE_SECTIONS: &[(&str, SectionCheck)] = &[
    ("probing", SectionCheck::of::<MachineProbing>()),
    ("process", SectionCheck::of::<MachineProcess>()),
];

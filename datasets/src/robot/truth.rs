//! The truth file: what was injected, for the validation harness. (Part of the robot generator; see mod.rs.)

use super::*;

// Truth

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(super) struct FaceTruth {
    /// Outward unit normal of the true face.
    pub(super) normal: [f64; 3],
    /// n·p = d on the face.
    pub(super) d: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(super) struct ContactTruth {
    pub(super) seq: i32,
    /// Controller time of the true contact, s.
    pub(super) t_s: f64,
    /// AE recorder time of the burst onset (= t_s − clock offset), s.
    pub(super) ae_t_s: f64,
    /// Controller time the touch was registered (t_s + latency), s.
    pub(super) registered_t_s: f64,
    /// Where the motion log puts the TCP at t_s (what an ideal AE ingest
    /// recovers): the true contact point in the controller's frame.
    pub(super) x_mm: f64,
    pub(super) y_mm: f64,
    pub(super) z_mm: f64,
    /// The physical contact point on the true surface (equals x/y/z without
    /// thermal drift, backlash or direct touch effects).
    pub(super) surface_x_mm: f64,
    pub(super) surface_y_mm: f64,
    pub(super) surface_z_mm: f64,
    /// Sign, along the face's +normal axis, of the last move before the
    /// approach (the plugin's `dir` covariate; a move outward of the block
    /// is a reversal before the inward approach).
    pub(super) dir: i32,
    /// Burst peak amplitude, V (a conditioned RMS log's cut level is
    /// this / √2).
    pub(super) ae_amplitude_v: f64,
    /// Conditioned RMS logs only: recorder time the wheel leaves the
    /// surface (the cut's end; the exit decays after it), s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(super) ae_leave_t_s: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(super) struct PassTruth {
    pub(super) pass: i32,
    /// True cut of the pass, mm.
    pub(super) cut_mm: f64,
    /// The compliance model's cut with the true α (no effects), mm.
    pub(super) model_cut_mm: f64,
    /// Cumulative true removal before the pass, mm³.
    pub(super) removed_mm3: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(super) struct RunTruth {
    pub(super) run: String,
    pub(super) run_index: usize,
    pub(super) seed: u64,
    pub(super) block_origin_mm: [f64; 3],
    pub(super) block_rotation_rad: [f64; 3],
    pub(super) block_offset_mm: [f64; 3],
    pub(super) faces: BTreeMap<String, FaceTruth>,
    pub(super) trigger_latency_s: BTreeMap<String, f64>,
    /// σ of the registered AE touches' normal coordinate per approach speed.
    pub(super) touch_sigma_mm: BTreeMap<String, f64>,
    /// σ of the comparison methods' registered touches, per method.
    pub(super) other_method_sigma_mm: BTreeMap<String, f64>,
    pub(super) ae_clock_offset_s: f64,
    pub(super) ae_sample_rate_hz: f64,
    /// `rms` for a conditioned RMS log; absent for raw (the files of raw
    /// fleets stay as they were).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(super) ae_signal: Option<String>,
    pub(super) ae_carrier_hz: f64,
    pub(super) ae_noise_v: f64,
    pub(super) has_probe: bool,
    pub(super) contacts: Vec<ContactTruth>,
    pub(super) alpha: f64,
    pub(super) passes: Vec<PassTruth>,
    pub(super) effects: Vec<EffectSpec>,
}

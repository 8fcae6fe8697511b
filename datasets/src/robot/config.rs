//! The fleet configuration and its checks. (Part of the robot generator; see mod.rs.)

use super::*;

// Configuration

/// Which runs get a `probe.parquet` (the controller's own registered
/// touches). Runs without it exercise the AE ingest path (ae + motion + plan).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ProbeMode {
    /// Every run has probe.parquet.
    All,
    /// Even runs have it, odd runs are AE-only.
    Alternate,
    /// No run has it (AE only).
    None,
}

impl ProbeMode {
    pub fn has_probe(self, run_index: usize) -> bool {
        match self {
            ProbeMode::All => true,
            ProbeMode::Alternate => run_index.is_multiple_of(2),
            ProbeMode::None => false,
        }
    }
}

impl FromStr for ProbeMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "all" => Ok(ProbeMode::All),
            "alternate" => Ok(ProbeMode::Alternate),
            "none" => Ok(ProbeMode::None),
            other => Err(format!(
                "unknown probe mode `{other}` (known: all, alternate, none)"
            )),
        }
    }
}

/// A comparison probing method (docs/models.md §1.1): its touches are registered
/// by the controller (probe.parquet) from the method's own signal, probed in
/// a second program after the AE program. They are not in plan.parquet (the
/// AE program) and the AE recorder is not armed for them.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ProbeMethod {
    /// `mechanical` or `electrical` (docs/formats.md probe.method).
    pub name: String,
    pub speed_mm_s: f64,
}

impl ProbeMethod {
    pub fn new(name: &str, speed_mm_s: f64) -> Self {
        ProbeMethod {
            name: name.to_string(),
            speed_mm_s,
        }
    }
    /// The method's name as a static label (validated: one of the two).
    pub(super) fn label(&self) -> &'static str {
        if self.name == "mechanical" {
            "mechanical"
        } else {
            "electrical"
        }
    }
    /// The thesis's two comparison methods at their published speeds.
    pub fn thesis() -> Vec<ProbeMethod> {
        vec![
            ProbeMethod::new("electrical", ELECTRICAL_RANGE_MM.1),
            ProbeMethod::new("mechanical", MECHANICAL_RANGE_MM.1),
        ]
    }
}

/// What the AE recorder writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum AeSignal {
    /// The sensor voltage at 20 kHz – 10 MHz: noise plus a decaying carrier
    /// burst at each contact, recorded in a triggered window per touch.
    Raw,
    /// A conditioned RMS at 100 Hz – 50 kHz (an RMS converter in front of a
    /// slow logger), recorded continuously: air → entry → cut → exit at
    /// each contact ([`AE_RMS_DEFAULT_RATE_HZ`] by default).
    Rms,
}

impl AeSignal {
    pub fn label(self) -> &'static str {
        match self {
            AeSignal::Raw => "raw",
            AeSignal::Rms => "rms",
        }
    }
}

impl FromStr for AeSignal {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "raw" => Ok(AeSignal::Raw),
            "rms" => Ok(AeSignal::Rms),
            other => Err(format!("unknown AE signal `{other}` (known: raw, rms)")),
        }
    }
}

/// Settings of a generated robot fleet.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RobotFleetConfig {
    pub runs: usize,
    pub seed: u64,
    /// Machine id written to run.toml and used as the fleet subdirectory.
    pub machine: String,
    /// AE sample rate, Hz (raw: 1 MHz default, as in the thesis's
    /// 100 kHz–2 MHz band; rms: 250 Hz is what `--ae-signal rms` picks).
    pub ae_sample_rate_hz: f64,
    /// Raw sensor voltage or conditioned RMS.
    pub ae_signal: AeSignal,
    /// Repeats of every nominal point at every speed.
    pub trials: usize,
    /// Approach speeds, mm/s (the thesis used 100, 10 and 5 mm/s).
    pub speeds_mm_s: Vec<f64>,
    pub with_probe: ProbeMode,
    /// Comparison methods probed after the AE program (every nominal point,
    /// `trials` times each), registered in probe.parquet only. Runs without
    /// probe.parquet (AE-only runs) skip them.
    pub other_methods: Vec<ProbeMethod>,
    /// Controller log rate, Hz.
    pub motion_rate_hz: f64,
    /// Approach start distance outside the nominal surface, mm.
    pub standoff_mm: f64,
    /// AE noise floor σ, V.
    pub ae_noise_v: f64,
    /// Burst amplitude in units of the noise σ (drawn ±25 % per touch).
    pub ae_burst_sigmas: f64,
    /// Burst carrier, Hz (clamped to 0.3 × sample rate).
    pub ae_carrier_hz: f64,
    /// Recorder window before / after each contact, s (triggered recording
    /// with pre-trigger keeps the files small).
    pub ae_pre_s: f64,
    pub ae_post_s: f64,
    /// Block pose: offset per axis drawn uniformly in ±this, mm.
    pub pose_offset_mm: f64,
    /// Block pose: rotation about each axis drawn uniformly in ±this, rad.
    pub pose_rotation_rad: f64,
    /// The run's true compliance α is drawn uniformly in [alpha_min, alpha_max].
    pub alpha_min: f64,
    pub alpha_max: f64,
    /// Weld stock above the finished surface, mm (thesis: 2.27).
    pub weld_mm: f64,
    pub rough_passes: usize,
    pub finish_passes: usize,
    pub spark_passes: usize,
    /// Nominal depth of cut δ′, mm (thesis: 0.3 rough, 0.1 finish).
    pub doc_rough_mm: f64,
    pub doc_finish_mm: f64,
    /// Grinding feed, mm/s (thesis: 20 mm/s the most stable).
    pub grind_feed_mm_s: f64,
    /// Wheel–work contact area that turns a cut depth into a removed volume, mm².
    pub contact_area_mm2: f64,
    /// Height measurement noise σ per reading, mm.
    pub height_noise_mm: f64,
}

impl Default for RobotFleetConfig {
    fn default() -> Self {
        RobotFleetConfig {
            runs: 8,
            seed: 0,
            machine: "kr16-lab".into(),
            ae_sample_rate_hz: 1e6,
            ae_signal: AeSignal::Raw,
            trials: 3,
            speeds_mm_s: vec![5.0, 10.0],
            with_probe: ProbeMode::Alternate,
            other_methods: ProbeMethod::thesis(),
            motion_rate_hz: 1000.0,
            standoff_mm: 1.5,
            ae_noise_v: 0.005,
            ae_burst_sigmas: 30.0,
            ae_carrier_hz: 250e3,
            ae_pre_s: 0.010,
            ae_post_s: 0.015,
            pose_offset_mm: 0.3,
            pose_rotation_rad: 2e-4,
            alpha_min: 0.45,
            alpha_max: 0.55,
            weld_mm: 2.27,
            rough_passes: 7,
            finish_passes: 2,
            spark_passes: 2,
            doc_rough_mm: 0.3,
            doc_finish_mm: 0.1,
            grind_feed_mm_s: 20.0,
            contact_area_mm2: 100.0,
            height_noise_mm: 0.002,
        }
    }
}

impl RobotFleetConfig {
    /// A small fleet that generates in a few seconds (`sparkout demo`).
    pub fn demo() -> Self {
        RobotFleetConfig {
            runs: 4,
            ae_sample_rate_hz: 200e3,
            trials: 2,
            ..Self::default()
        }
    }

    pub fn validate(&self) -> Result<()> {
        let pos = |name: &str, v: f64| -> Result<()> {
            if !(v.is_finite() && v > 0.0) {
                bail!("robot generator: {name} must be a positive number, got {v}");
            }
            Ok(())
        };
        if self.runs == 0 {
            bail!("robot generator: runs must be at least 1");
        }
        if self.machine.is_empty()
            || !self
                .machine
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_' || c == '.')
            || self.machine.starts_with('.')
        {
            bail!(
                "robot generator: machine id `{}` must be non-empty ASCII letters, digits, `-`, `_`, `.` (it names a directory)",
                self.machine
            );
        }
        match self.ae_signal {
            AeSignal::Raw => {
                if !(self.ae_sample_rate_hz.is_finite() && self.ae_sample_rate_hz >= 20e3) {
                    bail!(
                        "robot generator: ae_sample_rate_hz must be at least 20 kHz for a raw AE signal (the burst needs a carrier), got {}",
                        self.ae_sample_rate_hz
                    );
                }
            }
            AeSignal::Rms => {
                // A touch's contact lasts ~55 ms: at 100 Hz that is five
                // samples; the recording is continuous, so the rate is
                // capped where a run's log would outgrow the raw one.
                if !(self.ae_sample_rate_hz.is_finite()
                    && (100.0..=50e3).contains(&self.ae_sample_rate_hz))
                {
                    bail!(
                        "robot generator: ae_sample_rate_hz must be 100 Hz – 50 kHz for a conditioned RMS signal (recorded continuously), got {}",
                        self.ae_sample_rate_hz
                    );
                }
            }
        }
        if self.trials == 0 {
            bail!("robot generator: trials must be at least 1");
        }
        if self.speeds_mm_s.is_empty() {
            bail!("robot generator: speeds_mm_s needs at least one approach speed");
        }
        for &v in &self.speeds_mm_s {
            pos("every approach speed (mm/s)", v)?;
            if v > 200.0 {
                bail!("robot generator: approach speed {v} mm/s is beyond a probing approach (≤ 200 mm/s)");
            }
        }
        for m in &self.other_methods {
            if !matches!(m.name.as_str(), "mechanical" | "electrical") {
                bail!(
                    "robot generator: other method `{}` is not a comparison method (known: mechanical, electrical; `ae` is the main program)",
                    m.name
                );
            }
            pos("every other method's approach speed (mm/s)", m.speed_mm_s)?;
            if m.speed_mm_s > 200.0 {
                bail!(
                    "robot generator: {} approach speed {} mm/s is beyond a probing approach (≤ 200 mm/s)",
                    m.name,
                    m.speed_mm_s
                );
            }
        }
        pos("motion_rate_hz", self.motion_rate_hz)?;
        if self.motion_rate_hz < 100.0 {
            bail!("robot generator: motion_rate_hz must be at least 100 Hz");
        }
        pos("standoff_mm", self.standoff_mm)?;
        pos("ae_noise_v", self.ae_noise_v)?;
        pos("ae_burst_sigmas", self.ae_burst_sigmas)?;
        pos("ae_carrier_hz", self.ae_carrier_hz)?;
        pos("ae_pre_s", self.ae_pre_s)?;
        pos("ae_post_s", self.ae_post_s)?;
        pos("grind_feed_mm_s", self.grind_feed_mm_s)?;
        pos("contact_area_mm2", self.contact_area_mm2)?;
        pos("weld_mm", self.weld_mm)?;
        for (name, v) in [
            ("pose_offset_mm", self.pose_offset_mm),
            ("pose_rotation_rad", self.pose_rotation_rad),
            ("height_noise_mm", self.height_noise_mm),
            ("doc_rough_mm", self.doc_rough_mm),
            ("doc_finish_mm", self.doc_finish_mm),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                bail!("robot generator: {name} must be ≥ 0, got {v}");
            }
        }
        if !(self.alpha_min.is_finite()
            && self.alpha_max.is_finite()
            && self.alpha_min > 0.0
            && self.alpha_min <= self.alpha_max)
        {
            bail!(
                "robot generator: need 0 < alpha_min ≤ alpha_max, got [{}, {}]",
                self.alpha_min,
                self.alpha_max
            );
        }
        if self.rough_passes + self.finish_passes + self.spark_passes == 0 {
            bail!("robot generator: the grinding cycle needs at least one pass");
        }
        // The true surface must stay outside the closest point of the leg
        // (standoff − overtravel): offset on 3 axes plus rotation over the
        // largest lever arm of a probe point (~75 mm), with 0.1 mm margin.
        let budget =
            self.pose_offset_mm * 3f64.sqrt() + self.pose_rotation_rad * 3f64.sqrt() * 80.0;
        if budget + 0.1 > self.standoff_mm - OVERTRAVEL_MM {
            bail!(
                "robot generator: standoff_mm {} is too small for the pose spread (offset ±{} mm, rotation ±{} rad can put the surface {:.3} mm outward; need standoff ≥ {:.3} mm)",
                self.standoff_mm,
                self.pose_offset_mm,
                self.pose_rotation_rad,
                budget,
                budget + 0.1 + OVERTRAVEL_MM
            );
        }
        if self.ae_pre_s + self.ae_post_s > 0.2 {
            bail!("robot generator: AE window (ae_pre_s + ae_post_s) must be ≤ 0.2 s");
        }
        Ok(())
    }
}

//! Synthetic robotic-grinding fleet (MODELS.md §1; the data layout is
//! docs/robot_data_spec.md, the tables CONTRACTS.md §1).
//!
//! Each run is a KUKA-KR16-like cell probing a block with the grinding wheel
//! (acoustic-emission touch detection, MODELS.md §1.1–1.2) in the thesis's
//! pattern (3 faces × 3 concentric squares × 4 points, §1.3), followed by a
//! weld-repair grinding cycle (rough, finish, spark-out, §1.4).
//!
//! Frames. `cmd_*` is the commanded TCP; `act_*` is the TCP the controller
//! measures (joint encoders through the kinematic model), i.e. `cmd` plus
//! servo noise. The *physical* wheel can sit elsewhere: thermal drift and
//! backlash are invisible to motor-side encoders, so they appear as
//! `act − physical`. Contact happens when the physical wheel reaches the true
//! surface; interpolating the motion log at that time therefore gives where
//! the controller believes the contact is — the true surface point when no
//! effect is injected, the true point shifted by the effect otherwise, which
//! is exactly how the effect reaches the `touch_normal` observable.
//!
//! Timing per approach (spec): motion `segment` = plan `seq` from the start
//! of the approach until the robot has stopped; contact `t_c` = the physical
//! wheel reaches the true surface (controller clock); registration
//! `t_r = t_c + latency` (latency 0 unless `trigger_latency` is injected:
//! the effect-free baseline has no catalogue effect at all); the robot keeps
//! moving at approach speed until `t_r`, then decelerates, dwells and
//! retracts. The AE burst starts at `t_c` on the recorder clock
//! (`ae t_s = controller t_s − clock_offset_s`).
//!
//! Observables (docs/robot_data_spec.md; conventions as the robot plugin
//! reads them): a touch's "normal coordinate" is its coordinate on the face's
//! normal axis (z, x, y for `xy`, `yz`, `zx`); `approach_normal_mm_s` = v ×
//! the approach direction's +axis component; `dir` = sign along +axis of the
//! last commanded move before the approach segment (the generator alternates
//! inward legs and outward "reversal" legs at random). Registered touches
//! (probe.parquet) scatter with the AE method's thesis repeatability
//! (σ = range/d2(12), 7.7 µm at 5 mm/s, 26 µm at 10 mm/s); the contact
//! itself scatters by 2 µm (what AE-derived touches see).
//!
//! Determinism: every run draws from its own `ChaCha8Rng` streams keyed by
//! (seed, run index), so the files are byte-identical for a seed whatever
//! the number of rayon threads.

use std::collections::BTreeMap;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::Arc;

use anyhow::{bail, Context, Result};
use arrow::array::{Float32Array, Float64Array};
use arrow::datatypes::{DataType, Field, Schema, SchemaRef};
use arrow::record_batch::RecordBatch;
use nalgebra::{Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rayon::prelude::*;
use serde::Serialize;
use sparkout_pipeline::contracts::{
    write_atomic, write_json_atomic, write_parquet_atomic, write_parquet_batches_atomic,
    BatchBuilder,
};
use sparkout_pipeline::diagnose::{shape_value, Kind};
use sparkout_pipeline::EffectSpec;

type V3 = Vector3<f64>;

// ---------------------------------------------------------------------------
// Fixed cell geometry and process constants (documented, not configurable:
// they define the thesis-like cell; the knobs users need are in the config).

/// Nominal datum (the block corner where the three probed faces meet), in a
/// KR16 base frame, mm. Arbitrary but inside a KR16's 1.6 m reach.
const DATUM_NOM_MM: [f64; 3] = [450.0, -40.0, 180.0];
/// Block extent from the datum: +x, +y, and downward −z (mm). The top face
/// (`xy`) is z = datum z; the side faces `yz` (x = datum x) and `zx`
/// (y = datum y) face −x and −y.
const BLOCK_X_MM: f64 = 80.0;
const BLOCK_Y_MM: f64 = 80.0;
const BLOCK_H_MM: f64 = 60.0;
/// Half sides of the thesis's three concentric squares (outer, middle,
/// inner), 4 points each (MODELS.md §1.3), mm.
const SQUARE_HALF_MM: [f64; 3] = [24.0, 16.0, 8.0];
/// Transit speed between probe points, mm/s.
const TRANSIT_MM_S: f64 = 100.0;
/// Speed of the short normal leg before an approach and of the retract, mm/s.
const LEG_MM_S: f64 = 20.0;
/// Length of the normal leg when it arrives from outside (inward move), mm.
const LEG_OUT_MM: f64 = 2.0;
/// When the leg arrives from inside (outward move, a reversal before the
/// inward approach), it starts this much closer to the surface than the
/// approach start, mm.
const OVERTRAVEL_MM: f64 = 0.5;
/// Clearance above the top face for transit between faces, mm.
const SAFE_CLEARANCE_MM: f64 = 15.0;
/// Deceleration after the touch is registered, mm/s².
const STOP_DECEL_MM_S2: f64 = 1000.0;
/// Settle at the approach start before the slow probing move, s. Logged
/// with the approach's segment, so the move before the segment's first
/// sample is the leg (what a reader takes as the `dir` of the approach).
const SETTLE_S: f64 = 0.02;
/// Dwell after the stop before retracting, s.
const DWELL_S: f64 = 0.05;
/// Scatter of the contact itself along the normal (grain protrusion, surface
/// roughness), mm: the only scatter an ideal AE-derived touch has.
const CONTACT_SCATTER_MM: f64 = 0.002;
/// Encoder/servo noise of the measured TCP (`act_*`), mm per axis.
const ACT_NOISE_MM: f64 = 0.0003;
/// Thesis repeatability of the AE method (range of N repeated touches),
/// MODELS.md §1.1: 25 µm at 5 mm/s, 85 µm at 10 mm/s.
const AE_RANGE_5_MM: f64 = 0.025;
const AE_RANGE_10_MM: f64 = 0.085;
/// Thesis repeatability of the comparison methods (MODELS.md §1.1): 700 µm
/// for the mechanical dial gauge at 100 mm/s, 163 µm for the electrical
/// contact circuit at 10 mm/s (ranges; σ = range/d2(12)). Scaled linearly
/// with speed around those points: a method probed at another speed
/// overshoots proportionally more or less before it registers.
const MECHANICAL_RANGE_MM: (f64, f64) = (0.700, 100.0);
const ELECTRICAL_RANGE_MM: (f64, f64) = (0.163, 10.0);
/// d2 (expected range / σ of a normal sample) for N = 12, the middle of the
/// thesis's 10–15 repeats: converts a range into a standard deviation.
const D2_N12: f64 = 3.258;
/// AE burst: rise and decay time constants, s (a few ms of rubbing).
const AE_TAU_RISE_S: f64 = 20e-6;
const AE_TAU_DECAY_S: f64 = 2.5e-3;
/// Carrier kept below 0.3 × sample rate (no aliasing at low demo rates).
const AE_CARRIER_MAX_FRAC: f64 = 0.3;
/// AE recorder clock offset range (controller t = AE t + offset), s.
const CLOCK_OFFSET_RANGE_S: (f64, f64) = (0.02, 0.2);
/// Grinding: pass length over the block and pause between passes (the
/// heights are measured in the pause), mm and s.
const PASS_LENGTH_MM: f64 = 80.0;
const PASS_PAUSE_S: f64 = 20.0;
/// AE rows per streamed batch (one Parquet row group each at most): keeps
/// generation memory bounded whatever the fleet size.
const AE_BATCH_ROWS: usize = 1 << 17;
/// Pause between the end of probing and the first grinding pass, s.
const GRIND_START_DELAY_S: f64 = 30.0;

// Effect defaults, sized for SNR ≳ 3 against the default noise (see
// `known_effects` for the arithmetic).
const DEF_LATENCY_S: f64 = 0.024;
const DEF_WEAR_K_MM_PER_MM3: f64 = 1e-4;
const DEF_DRIFT_AMPLITUDE_MM: f64 = 0.4;
const DEF_DRIFT_TAU_S: f64 = 300.0;
const DEF_COMPLIANCE_K_PER_MM: f64 = 0.2;
const DEF_BACKLASH_B_MM: f64 = 0.12;

// ---------------------------------------------------------------------------
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

/// A comparison probing method (MODELS.md §1.1): its touches are registered
/// by the controller (probe.parquet) from the method's own signal, probed in
/// a second program after the AE program. They are not in plan.parquet (the
/// AE program) and the AE recorder is not armed for them.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ProbeMethod {
    /// `mechanical` or `electrical` (CONTRACTS.md probe.method).
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
    fn label(&self) -> &'static str {
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

/// Settings of a generated robot fleet.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RobotFleetConfig {
    pub runs: usize,
    pub seed: u64,
    /// Machine id written to run.toml and used as the fleet subdirectory.
    pub machine: String,
    /// Raw AE sample rate, Hz (1 MHz default, as in the thesis's 100 kHz–2 MHz band).
    pub ae_sample_rate_hz: f64,
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
        if !(self.ae_sample_rate_hz.is_finite() && self.ae_sample_rate_hz >= 20e3) {
            bail!(
                "robot generator: ae_sample_rate_hz must be at least 20 kHz (the burst needs a carrier), got {}",
                self.ae_sample_rate_hz
            );
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

// ---------------------------------------------------------------------------
// Effects

/// Catalogue kinds that may be applied directly to `touch_normal`.
const TOUCH_COVARIATES: &[&str] = &[
    "x_mm",
    "y_mm",
    "z_mm",
    "approach_mm_s",
    "approach_normal_mm_s",
    "t_s",
    "dir",
];
/// ... and to `cut_depth`.
const CUT_COVARIATES: &[&str] = &["pass", "nominal_doc_mm", "removed_mm3", "feed_mm_s"];

/// The injectable effects, with parameters and defaults, for `--help`.
pub fn known_effects() -> Vec<(&'static str, &'static str)> {
    vec![
        (
            "trigger_latency",
            "controller registers each touch latency_s after the true contact (default latency_s=0.024, two 12 ms KRC interpolation cycles): probe touches overshoot by v·L along the approach; touch_normal gap = L·approach_normal_mm_s (v times the approach direction's component along the face's +normal axis; AE-derived touches are unaffected: the burst starts at the true contact)",
        ),
        (
            "wheel_wear",
            "dulling wheel: each pass's real cut shrinks by k_mm_per_mm3·removed_mm3 (default k_mm_per_mm3=1e-4, ≈ −22 µm by the last pass); cut_depth gap = −k·removed_mm3 (cuts clipped at 0)",
        ),
        (
            "thermal_drift",
            "the physical TCP drifts by amplitude_mm·(1 − e^(−t/tau_s)) along +z unseen by the encoders (defaults amplitude_mm=0.4, tau_s=300): xy-face touch_normal gap = −drift(t); measured heights shift by −drift(t) and each pass's infeed loses the drift increment",
        ),
        (
            "compliance",
            "depth-dependent compliance: each infeed pass's real cut is reduced by k·nominal_doc_mm² (k in 1/mm, default k=0.2: −18 µm at δ′=0.3, −2 µm at 0.1); with a covariate (compliance:nominal_doc_mm=k=…) the catalogue form k·nominal_doc_mm is added to cut_depth instead",
        ),
        (
            "backlash",
            "reversal error: touches shift by b_mm/2·dir in the face's normal-axis coordinate, dir = sign along that +axis of the last move before the approach (half the approaches follow an outward move, a reversal; default b_mm=0.12); touch_normal gap = b·dir/2 (AE-derived and probe touches alike)",
        ),
        (
            "<catalogue>:<covariate>",
            "any catalogue shape added directly to an observable's real value with the pipeline's parameter names (required, no defaults): touch_normal for covariates x_mm, y_mm, z_mm, approach_mm_s, approach_normal_mm_s, t_s, dir (offset, scale, drift, lag, backlash, bow, periodic, squareness:x_mm,y_mm); cut_depth for pass, nominal_doc_mm, removed_mm3, feed_mm_s (wear, compliance, lag, offset is touch-only)",
        ),
    ]
}

/// A catalogue shape added directly to an observable.
#[derive(Debug, Clone)]
struct DirectEffect {
    kind: Kind,
    covariate: String,
    covariate2: Option<String>,
    params: BTreeMap<String, f64>,
}

impl DirectEffect {
    fn value(&self, cov: &dyn Fn(&str) -> f64) -> f64 {
        let c = [cov(&self.covariate)];
        let c2 = self.covariate2.as_deref().map(|n| [cov(n)]);
        shape_value(self.kind, &self.params, &c, c2.as_ref().map(|a| &a[..]))[0]
    }
}

/// Resolved effect parameters of a fleet (zero = absent).
#[derive(Debug, Clone, Default)]
struct Effects {
    latency_s: f64,
    wear_k_mm_per_mm3: f64,
    drift: Option<(f64, f64)>,
    compliance_k_per_mm: f64,
    backlash_b_mm: f64,
    touch: Vec<DirectEffect>,
    cut: Vec<DirectEffect>,
}

impl Effects {
    fn drift_mm(&self, t_s: f64) -> f64 {
        match self.drift {
            Some((a, tau)) => a * (1.0 - (-t_s / tau).exp()),
            None => 0.0,
        }
    }
}

fn check_keys(spec: &EffectSpec, known: &[&str]) -> Result<()> {
    spec.check_params(known).map_err(anyhow::Error::msg)
}

fn check_cov(spec: &EffectSpec, allowed: &[&str]) -> Result<()> {
    if let Some(c) = &spec.covariate {
        if !allowed.contains(&c.as_str()) {
            bail!(
                "effect `{}`: covariate `{c}` does not apply (allowed: {})",
                spec.key(),
                allowed.join(", ")
            );
        }
    }
    Ok(())
}

fn positive(spec: &EffectSpec, key: &str, v: f64) -> Result<f64> {
    if !(v.is_finite() && v > 0.0) {
        bail!("effect `{}`: `{key}` must be > 0, got {v}", spec.key());
    }
    Ok(v)
}

fn known_names() -> String {
    "trigger_latency, wheel_wear, thermal_drift, compliance, backlash, or a catalogue shape \
     with a covariate (offset, scale, drift, lag, backlash, bow, periodic, squareness, wear, compliance)"
        .to_string()
}

fn resolve_effects(
    specs: &[EffectSpec],
    bow_range: &dyn Fn(&str) -> (f64, f64),
) -> Result<Effects> {
    let mut fx = Effects::default();
    for spec in specs {
        match (spec.name.as_str(), spec.covariate.as_deref()) {
            ("trigger_latency", _) => {
                check_cov(spec, &["approach_normal_mm_s", "approach_mm_s"])?;
                check_keys(spec, &["latency_s"])?;
                let l = spec.param_or("latency_s", DEF_LATENCY_S);
                if !(0.0..=0.5).contains(&l) {
                    bail!("effect `trigger_latency`: latency_s must be in [0, 0.5] s, got {l}");
                }
                fx.latency_s += l;
            }
            ("wheel_wear", _) => {
                check_cov(spec, &["removed_mm3"])?;
                check_keys(spec, &["k_mm_per_mm3"])?;
                fx.wear_k_mm_per_mm3 += spec.param_or("k_mm_per_mm3", DEF_WEAR_K_MM_PER_MM3);
            }
            ("thermal_drift", _) => {
                check_cov(spec, &["t_s"])?;
                check_keys(spec, &["amplitude_mm", "tau_s"])?;
                if fx.drift.is_some() {
                    bail!("effect `thermal_drift` given twice");
                }
                let a = spec.param_or("amplitude_mm", DEF_DRIFT_AMPLITUDE_MM);
                let tau = positive(spec, "tau_s", spec.param_or("tau_s", DEF_DRIFT_TAU_S))?;
                if a.abs() > 0.8 {
                    bail!("effect `thermal_drift`: |amplitude_mm| must be ≤ 0.8 (the approach standoff), got {a}");
                }
                fx.drift = Some((a, tau));
            }
            ("compliance", None) => {
                check_keys(spec, &["k"])?;
                fx.compliance_k_per_mm += spec.param_or("k", DEF_COMPLIANCE_K_PER_MM);
            }
            ("backlash", None) | ("backlash", Some("dir")) => {
                check_keys(spec, &["b_mm"])?;
                let b = spec.param_or("b_mm", DEF_BACKLASH_B_MM);
                if b.abs() > 1.0 {
                    bail!("effect `backlash`: |b_mm| must be ≤ 1.0, got {b}");
                }
                fx.backlash_b_mm += b;
            }
            (name, cov) => {
                let kind = Kind::from_name(name).ok_or_else(|| {
                    anyhow::anyhow!("unknown effect `{name}` (known: {})", known_names())
                })?;
                let (keys, required): (&[&str], &[&str]) = match kind {
                    Kind::Offset => (&["offset_mm"], &["offset_mm"]),
                    Kind::Scale | Kind::Lag | Kind::Wear | Kind::Compliance | Kind::Squareness => {
                        (&["k"], &["k"])
                    }
                    Kind::Backlash => (&["b_mm"], &["b_mm"]),
                    Kind::Drift => (&["amplitude_mm", "tau_s"], &["amplitude_mm", "tau_s"]),
                    Kind::Bow => (&["amplitude_mm", "c0", "c1"], &["amplitude_mm"]),
                    Kind::Periodic => (
                        &["amplitude_mm", "lambda", "phase_rad"],
                        &["amplitude_mm", "lambda"],
                    ),
                    Kind::Inertia | Kind::Edge | Kind::Thermal => bail!(
                        "effect `{}`: not applicable to robot observables (no acceleration, path-end or temperature covariate); known: {}",
                        spec.key(),
                        known_names()
                    ),
                };
                check_keys(spec, keys)?;
                for r in required {
                    if spec.param(r).is_none() {
                        bail!(
                            "effect `{}`: catalogue shapes applied directly need their parameters ({}); missing `{r}`",
                            spec.key(),
                            required.join(", ")
                        );
                    }
                }
                for k in ["tau_s", "lambda"] {
                    if let Some(v) = spec.param(k) {
                        positive(spec, k, v)?;
                    }
                }
                let (c1, c2) = match (kind, cov) {
                    (Kind::Offset, None) => ("x_mm".to_string(), None),
                    (Kind::Offset, Some(c)) => bail!(
                        "effect `offset` takes no covariate, got `{c}`"
                    ),
                    (_, None) => bail!(
                        "effect `{name}`: a catalogue shape needs a covariate, e.g. `{name}:{}` (touch_normal: {}; cut_depth: {})",
                        default_cov(kind),
                        TOUCH_COVARIATES.join(", "),
                        CUT_COVARIATES.join(", ")
                    ),
                    (Kind::Squareness, Some(c)) => {
                        let (a, b) = c.split_once(',').ok_or_else(|| {
                            anyhow::anyhow!("effect `squareness` needs two positions, e.g. squareness:x_mm,y_mm")
                        })?;
                        (a.trim().to_string(), Some(b.trim().to_string()))
                    }
                    (_, Some(c)) => (c.to_string(), None),
                };
                let on_touch = TOUCH_COVARIATES.contains(&c1.as_str());
                let on_cut = CUT_COVARIATES.contains(&c1.as_str());
                if !on_touch && !on_cut {
                    bail!(
                        "effect `{}`: covariate `{c1}` is not a robot observable covariate (touch_normal: {}; cut_depth: {})",
                        spec.key(),
                        TOUCH_COVARIATES.join(", "),
                        CUT_COVARIATES.join(", ")
                    );
                }
                if let Some(c2) = &c2 {
                    if !matches!(c1.as_str(), "x_mm" | "y_mm" | "z_mm")
                        || !matches!(c2.as_str(), "x_mm" | "y_mm" | "z_mm")
                    {
                        bail!(
                            "effect `{}`: squareness needs two of x_mm, y_mm, z_mm",
                            spec.key()
                        );
                    }
                }
                // The kind must apply to that covariate (CONTRACTS.md table).
                if kind != Kind::Offset
                    && kind != Kind::Squareness
                    && !sparkout_pipeline::diagnose::effect::kinds_for(&c1).contains(&kind)
                {
                    bail!(
                        "effect `{}`: `{name}` does not apply to covariate `{c1}` (docs/formats.md, effect catalogue)",
                        spec.key()
                    );
                }
                let mut params = spec.params.clone();
                if kind == Kind::Bow {
                    let (lo, hi) = bow_range(&c1);
                    params.entry("c0".into()).or_insert(lo);
                    params.entry("c1".into()).or_insert(hi);
                }
                let d = DirectEffect {
                    kind,
                    covariate: c1,
                    covariate2: c2,
                    params,
                };
                if on_touch {
                    fx.touch.push(d);
                } else {
                    fx.cut.push(d);
                }
            }
        }
    }
    Ok(fx)
}

fn default_cov(kind: Kind) -> &'static str {
    match kind {
        Kind::Drift => "t_s",
        Kind::Lag => "approach_normal_mm_s",
        Kind::Backlash => "dir",
        Kind::Wear => "removed_mm3",
        Kind::Compliance => "nominal_doc_mm",
        _ => "x_mm",
    }
}

// ---------------------------------------------------------------------------
// Geometry and plan

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Face {
    Xy,
    Yz,
    Zx,
}

impl Face {
    const ALL: [Face; 3] = [Face::Xy, Face::Yz, Face::Zx];
    fn label(self) -> &'static str {
        match self {
            Face::Xy => "xy",
            Face::Yz => "yz",
            Face::Zx => "zx",
        }
    }
    /// Index of the face's normal axis (the observable's normal coordinate).
    fn axis(self) -> usize {
        match self {
            Face::Xy => 2,
            Face::Yz => 0,
            Face::Zx => 1,
        }
    }
    /// Outward unit normal of the nominal face (the block is on the other side).
    fn normal(self) -> V3 {
        match self {
            Face::Xy => V3::new(0.0, 0.0, 1.0),
            Face::Yz => V3::new(-1.0, 0.0, 0.0),
            Face::Zx => V3::new(0.0, -1.0, 0.0),
        }
    }
    /// Nominal point `id` (0–3 outer, 4–7 middle, 8–11 inner square; corners
    /// counter-clockwise from (−,−)) relative to the datum.
    fn point(self, id: usize) -> V3 {
        let h = SQUARE_HALF_MM[id / 4];
        let (su, sv) = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)][id % 4];
        match self {
            Face::Xy => V3::new(BLOCK_X_MM / 2.0 + su * h, BLOCK_Y_MM / 2.0 + sv * h, 0.0),
            Face::Yz => V3::new(0.0, BLOCK_Y_MM / 2.0 + su * h, -BLOCK_H_MM / 2.0 + sv * h),
            Face::Zx => V3::new(BLOCK_X_MM / 2.0 + su * h, 0.0, -BLOCK_H_MM / 2.0 + sv * h),
        }
    }
}

#[derive(Debug, Clone)]
struct PlanRow {
    /// Plan order = motion segment; −1 for the comparison methods' program
    /// (not in plan.parquet).
    seq: i32,
    method: &'static str,
    face: Face,
    point: i32,
    trial: i32,
    speed_mm_s: f64,
    nom: V3,
    /// Unit approach direction (= −outward normal).
    dir: V3,
}

/// Program order: repeated sweeps (trial, then speed) over all three faces
/// and 12 points. Sweeping the whole pattern per repeat spreads each face's
/// touches over the whole probing time, so a slow drift is not absorbed
/// into a face's plane fit, and repeats of a point are not back to back.
fn build_plan(cfg: &RobotFleetConfig) -> Vec<PlanRow> {
    let datum = V3::from(DATUM_NOM_MM);
    let mut plan = Vec::new();
    for trial in 0..cfg.trials {
        for &v in &cfg.speeds_mm_s {
            for face in Face::ALL {
                for p in 0..12 {
                    plan.push(PlanRow {
                        seq: plan.len() as i32,
                        method: "ae",
                        face,
                        point: p as i32,
                        trial: trial as i32,
                        speed_mm_s: v,
                        nom: datum + face.point(p),
                        dir: -face.normal(),
                    });
                }
            }
        }
    }
    plan
}

/// The comparison methods' program: every nominal point `trials` times per
/// method, sweeping the pattern like the AE plan; segment −1 (not a plan row).
fn build_other_program(cfg: &RobotFleetConfig) -> Vec<PlanRow> {
    let datum = V3::from(DATUM_NOM_MM);
    let mut rows = Vec::new();
    for m in &cfg.other_methods {
        let method = m.label();
        for trial in 0..cfg.trials {
            for face in Face::ALL {
                for p in 0..12 {
                    rows.push(PlanRow {
                        seq: -1,
                        method,
                        face,
                        point: p as i32,
                        trial: trial as i32,
                        speed_mm_s: m.speed_mm_s,
                        nom: datum + face.point(p),
                        dir: -face.normal(),
                    });
                }
            }
        }
    }
    rows
}

/// σ of a method's registered touches at an approach speed.
fn touch_sigma_mm(method: &str, v_mm_s: f64) -> f64 {
    match method {
        "mechanical" => MECHANICAL_RANGE_MM.0 / D2_N12 * v_mm_s / MECHANICAL_RANGE_MM.1,
        "electrical" => ELECTRICAL_RANGE_MM.0 / D2_N12 * v_mm_s / ELECTRICAL_RANGE_MM.1,
        _ => ae_touch_sigma_mm(v_mm_s),
    }
}

/// σ of the AE method's registered touches at an approach speed: the
/// thesis's ranges (MODELS.md §1.1) as σ = range/d2(12), interpolated
/// log-log in speed (25 µm @ 5 → 85 µm @ 10 mm/s: σ ∝ v^1.77).
fn ae_touch_sigma_mm(v_mm_s: f64) -> f64 {
    let s5 = AE_RANGE_5_MM / D2_N12;
    let p = (AE_RANGE_10_MM / AE_RANGE_5_MM).ln() / 2f64.ln();
    s5 * (v_mm_s / 5.0).powf(p)
}

// ---------------------------------------------------------------------------
// Motion: piecewise constant-acceleration pieces of the commanded path

#[derive(Debug, Clone)]
struct Piece {
    t0: f64,
    t1: f64,
    p0: V3,
    v0: V3,
    a: V3,
    segment: i32,
}

impl Piece {
    fn pos(&self, t: f64) -> V3 {
        let dt = t - self.t0;
        self.p0 + self.v0 * dt + self.a * (0.5 * dt * dt)
    }
    fn speed(&self, t: f64) -> f64 {
        (self.v0 + self.a * (t - self.t0)).norm()
    }
}

struct CmdPath {
    pieces: Vec<Piece>,
    t: f64,
    pos: V3,
}

impl CmdPath {
    fn line(&mut self, to: V3, speed: f64, segment: i32) {
        let d = to - self.pos;
        let len = d.norm();
        if len < 1e-12 {
            return;
        }
        let dt = len / speed;
        self.pieces.push(Piece {
            t0: self.t,
            t1: self.t + dt,
            p0: self.pos,
            v0: d * (speed / len),
            a: V3::zeros(),
            segment,
        });
        self.t += dt;
        self.pos = to;
    }
    fn dwell(&mut self, dt: f64) {
        self.pieces.push(Piece {
            t0: self.t,
            t1: self.t + dt,
            p0: self.pos,
            v0: V3::zeros(),
            a: V3::zeros(),
            segment: -1,
        });
        self.t += dt;
    }
}

// ---------------------------------------------------------------------------
// Truth

#[derive(Debug, Clone, Serialize)]
struct FaceTruth {
    /// Outward unit normal of the true face.
    normal: [f64; 3],
    /// n·p = d on the face.
    d: f64,
}

#[derive(Debug, Clone, Serialize)]
struct ContactTruth {
    seq: i32,
    /// Controller time of the true contact, s.
    t_s: f64,
    /// AE recorder time of the burst onset (= t_s − clock offset), s.
    ae_t_s: f64,
    /// Controller time the touch was registered (t_s + latency), s.
    registered_t_s: f64,
    /// Where the motion log puts the TCP at t_s (what an ideal AE ingest
    /// recovers): the true contact point in the controller's frame.
    x_mm: f64,
    y_mm: f64,
    z_mm: f64,
    /// The physical contact point on the true surface (equals x/y/z without
    /// thermal drift, backlash or direct touch effects).
    surface_x_mm: f64,
    surface_y_mm: f64,
    surface_z_mm: f64,
    /// Sign, along the face's +normal axis, of the last move before the
    /// approach (the plugin's `dir` covariate; a move outward of the block
    /// is a reversal before the inward approach).
    dir: i32,
    /// Burst peak amplitude, V.
    ae_amplitude_v: f64,
}

#[derive(Debug, Clone, Serialize)]
struct PassTruth {
    pass: i32,
    /// True cut of the pass, mm.
    cut_mm: f64,
    /// The compliance model's cut with the true α (no effects), mm.
    model_cut_mm: f64,
    /// Cumulative true removal before the pass, mm³.
    removed_mm3: f64,
}

#[derive(Debug, Clone, Serialize)]
struct RunTruth {
    run: String,
    run_index: usize,
    seed: u64,
    block_origin_mm: [f64; 3],
    block_rotation_rad: [f64; 3],
    block_offset_mm: [f64; 3],
    faces: BTreeMap<&'static str, FaceTruth>,
    trigger_latency_s: BTreeMap<&'static str, f64>,
    /// σ of the registered AE touches' normal coordinate per approach speed.
    touch_sigma_mm: BTreeMap<String, f64>,
    /// σ of the comparison methods' registered touches, per method.
    other_method_sigma_mm: BTreeMap<String, f64>,
    ae_clock_offset_s: f64,
    ae_sample_rate_hz: f64,
    ae_carrier_hz: f64,
    ae_noise_v: f64,
    has_probe: bool,
    contacts: Vec<ContactTruth>,
    alpha: f64,
    passes: Vec<PassTruth>,
    effects: Vec<EffectSpec>,
}

// ---------------------------------------------------------------------------
// AE streaming

#[derive(Debug, Clone)]
struct AeWindow {
    n0: u64,
    n1: u64,
    onset_s: f64,
    amp_v: f64,
    carrier_hz: f64,
    phase: f64,
}

struct AeBatches {
    windows: Vec<AeWindow>,
    wi: usize,
    n: u64,
    fs: f64,
    noise_v: f64,
    rng: ChaCha8Rng,
    schema: SchemaRef,
}

impl Iterator for AeBatches {
    type Item = sparkout_pipeline::Result<RecordBatch>;
    fn next(&mut self) -> Option<Self::Item> {
        let mut t = Vec::with_capacity(AE_BATCH_ROWS);
        let mut v = Vec::with_capacity(AE_BATCH_ROWS);
        while t.len() < AE_BATCH_ROWS && self.wi < self.windows.len() {
            let w = &self.windows[self.wi];
            if self.n < w.n0 {
                self.n = w.n0;
            }
            let end = w.n1.min(self.n + (AE_BATCH_ROWS - t.len()) as u64);
            let omega = 2.0 * PI * w.carrier_hz;
            for n in self.n..end {
                let ts = n as f64 / self.fs;
                let z: f64 = self.rng.sample(StandardNormal);
                let dt = ts - w.onset_s;
                let burst = if dt >= 0.0 {
                    w.amp_v
                        * (1.0 - (-dt / AE_TAU_RISE_S).exp())
                        * (-dt / AE_TAU_DECAY_S).exp()
                        * (omega * dt + w.phase).sin()
                } else {
                    0.0
                };
                t.push(ts);
                v.push((self.noise_v * z + burst) as f32);
            }
            self.n = end;
            if self.n >= w.n1 {
                self.wi += 1;
            }
        }
        if t.is_empty() {
            return None;
        }
        Some(
            RecordBatch::try_new(
                self.schema.clone(),
                vec![
                    Arc::new(Float64Array::from(t)),
                    Arc::new(Float32Array::from(v)),
                ],
            )
            .map_err(anyhow::Error::from),
        )
    }
}

// ---------------------------------------------------------------------------
// Generation

fn run_rng(seed: u64, run_index: usize, stream: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream((run_index as u64) * 4 + stream);
    rng
}

fn uniform(rng: &mut ChaCha8Rng, half: f64) -> f64 {
    half * (2.0 * rng.random::<f64>() - 1.0)
}

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    rng.sample(StandardNormal)
}

/// Generate the fleet under `<root>/<machine>/r0000 …`; returns the run dirs
/// in run order. Runs are generated in parallel and are byte-identical for a
/// seed whatever the thread count.
pub fn generate_fleet(
    root: &Path,
    cfg: &RobotFleetConfig,
    effects: &[EffectSpec],
) -> Result<Vec<PathBuf>> {
    cfg.validate()?;
    let plan = build_plan(cfg);
    let bow_range = |c: &str| -> (f64, f64) {
        let vals: Vec<f64> = plan
            .iter()
            .map(|r| match c {
                "x_mm" => r.nom.x,
                "y_mm" => r.nom.y,
                "z_mm" => r.nom.z,
                "approach_mm_s" => r.speed_mm_s,
                "approach_normal_mm_s" => r.speed_mm_s * r.dir[r.face.axis()],
                _ => 0.0,
            })
            .collect();
        let lo = vals.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = vals.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        if hi > lo {
            (lo, hi)
        } else {
            (lo, lo + 1.0)
        }
    };
    let fx = resolve_effects(effects, &bow_range)?;
    let other = build_other_program(cfg);
    let machine_dir = root.join(&cfg.machine);
    (0..cfg.runs)
        .into_par_iter()
        .map(|i| {
            let dir = machine_dir.join(format!("r{i:04}"));
            generate_run(&dir, cfg, &plan, &other, &fx, effects, i)
                .with_context(|| format!("generating robot run {}", dir.display()))?;
            Ok(dir)
        })
        .collect()
}

struct Touch {
    row: usize,
    t_c: f64,
    t_r: f64,
    act_c: V3,
    surface: V3,
    registered: V3,
    dir_b: i32,
}

fn generate_run(
    dir: &Path,
    cfg: &RobotFleetConfig,
    plan: &[PlanRow],
    other: &[PlanRow],
    fx: &Effects,
    specs: &[EffectSpec],
    index: usize,
) -> Result<()> {
    let mut rng = run_rng(cfg.seed, index, 0);
    let run_id = format!("r{index:04}");

    // True block pose: offset + small rotation about the nominal datum.
    let datum_nom = V3::from(DATUM_NOM_MM);
    let offset = V3::new(
        uniform(&mut rng, cfg.pose_offset_mm),
        uniform(&mut rng, cfg.pose_offset_mm),
        uniform(&mut rng, cfg.pose_offset_mm),
    );
    let angles = [
        uniform(&mut rng, cfg.pose_rotation_rad),
        uniform(&mut rng, cfg.pose_rotation_rad),
        uniform(&mut rng, cfg.pose_rotation_rad),
    ];
    let rot = Rotation3::from_euler_angles(angles[0], angles[1], angles[2]);
    let datum_true = datum_nom + offset;
    let plane = |f: Face| -> (V3, f64) {
        let n = rot * f.normal();
        (n, n.dot(&datum_true))
    };
    let alpha = cfg.alpha_min + (cfg.alpha_max - cfg.alpha_min) * rng.random::<f64>();
    let clock_offset_s = CLOCK_OFFSET_RANGE_S.0
        + (CLOCK_OFFSET_RANGE_S.1 - CLOCK_OFFSET_RANGE_S.0) * rng.random::<f64>();
    let has_probe = cfg.with_probe.has_probe(index);

    // ---- probing: commanded path, contacts, registrations
    let safe_z = datum_nom.z + SAFE_CLEARANCE_MM;
    let home = datum_nom + V3::new(BLOCK_X_MM / 2.0, BLOCK_Y_MM / 2.0, SAFE_CLEARANCE_MM + 30.0);
    let mut path = CmdPath {
        pieces: Vec::new(),
        t: 0.0,
        pos: home,
    };
    path.dwell(1.0);
    // The AE program, then (runs with probe.parquet only) the comparison
    // methods' program; `Touch::row` indexes `program`. The second program
    // draws from its own RNG stream, so the AE program's draws (and the AE
    // signal after them) do not depend on it.
    let program: Vec<PlanRow> = if has_probe {
        plan.iter().chain(other).cloned().collect()
    } else {
        plan.to_vec()
    };
    let mut rng_other = run_rng(cfg.seed, index, 4);
    let mut touches = Vec::with_capacity(program.len());
    for (ri, row) in program.iter().enumerate() {
        let rng = if row.method == "ae" {
            &mut rng
        } else {
            &mut rng_other
        };
        let n = row.face.normal();
        let start = row.nom + n * cfg.standoff_mm;
        let dir_b: i32 = if rng.random::<bool>() { 1 } else { -1 };
        let leg_start = if dir_b < 0 {
            start + n * LEG_OUT_MM
        } else {
            start - n * OVERTRAVEL_MM
        };
        // Safe transit: up, across, down, then the short leg along the normal.
        let p = path.pos;
        path.line(V3::new(p.x, p.y, safe_z.max(p.z)), TRANSIT_MM_S, -1);
        path.line(V3::new(leg_start.x, leg_start.y, safe_z), TRANSIT_MM_S, -1);
        path.line(leg_start, TRANSIT_MM_S, -1);
        path.line(start, LEG_MM_S, -1);
        path.pieces.push(Piece {
            t0: path.t,
            t1: path.t + SETTLE_S,
            p0: start,
            v0: V3::zeros(),
            a: V3::zeros(),
            segment: row.seq,
        });
        path.t += SETTLE_S;

        // Approach along dir at v: solve for the contact of the physical
        // wheel (cmd − o(t)) with the true plane (+ contact scatter).
        let v = row.speed_mm_s;
        let t_a = path.t;
        let (n_true, d_true) = plane(row.face);
        let e_c = CONTACT_SCATTER_MM * normal(rng);
        let mut t_c = t_a;
        let mut o = V3::zeros();
        for _ in 0..4 {
            o = frame_offset(fx, row, dir_b, t_c);
            let denom = v * n_true.dot(&row.dir);
            let tau = (d_true + e_c - n_true.dot(&(start - o))) / denom;
            t_c = t_a + tau;
        }
        let tau = t_c - t_a;
        let max_travel = cfg.standoff_mm + 1.0;
        if !(tau > 0.0 && tau * v < max_travel) {
            bail!(
                "seq {}: the wheel would meet the {} face {:.3} mm into the approach (allowed (0, {max_travel}] mm): pose spread or injected offsets exceed the standoff",
                row.seq,
                row.face.label(),
                tau * v
            );
        }
        // The leg start must be clear of the surface too (reversal legs come closer).
        let leg_clear = n_true.dot(&(leg_start - frame_offset(fx, row, dir_b, t_a))) - d_true;
        if leg_clear <= 0.0 {
            bail!(
                "seq {}: the leg before the approach would enter the {} face: pose spread or injected offsets exceed the standoff",
                row.seq,
                row.face.label()
            );
        }
        let t_r = t_c + fx.latency_s;
        let act_c = start + row.dir * (v * tau);
        let surface = act_c - o;
        let sigma = touch_sigma_mm(row.method, v);
        let reg_noise = (sigma * sigma - CONTACT_SCATTER_MM * CONTACT_SCATTER_MM)
            .max(0.0)
            .sqrt()
            * normal(rng);
        let registered = act_c + row.dir * (v * fx.latency_s + reg_noise);
        // Approach piece until registration, then the stop.
        let p_r = start + row.dir * (v * (t_r - t_a));
        path.pieces.push(Piece {
            t0: t_a,
            t1: t_r,
            p0: start,
            v0: row.dir * v,
            a: V3::zeros(),
            segment: row.seq,
        });
        let t_stop = v / STOP_DECEL_MM_S2;
        path.pieces.push(Piece {
            t0: t_r,
            t1: t_r + t_stop,
            p0: p_r,
            v0: row.dir * v,
            a: -row.dir * STOP_DECEL_MM_S2,
            segment: row.seq,
        });
        path.t = t_r + t_stop;
        path.pos = p_r + row.dir * (0.5 * v * t_stop);
        path.dwell(DWELL_S);
        path.line(start + n * LEG_OUT_MM, LEG_MM_S, -1);
        touches.push(Touch {
            row: ri,
            t_c,
            t_r,
            act_c,
            surface,
            registered,
            dir_b,
        });
    }
    let last = path.pos;
    path.line(
        V3::new(last.x, last.y, safe_z.max(last.z)),
        TRANSIT_MM_S,
        -1,
    );
    path.line(home, TRANSIT_MM_S, -1);
    path.dwell(0.5);
    let t_probe_end = path.t;

    // ---- motion.parquet at the controller rate
    // Own RNG streams for the motion noise and the height readings: an
    // effect that moves the timeline (and so the number of motion samples)
    // leaves the other tables' noise draws unchanged, so a fleet with an
    // effect differs from its effect-free twin by the effect alone.
    let motion = motion_batch(
        &path.pieces,
        cfg.motion_rate_hz,
        &mut run_rng(cfg.seed, index, 2),
    );

    // ---- grinding cycle
    let (passes_batch, pass_truth) = passes(
        cfg,
        fx,
        alpha,
        t_probe_end,
        &mut run_rng(cfg.seed, index, 3),
    );

    // ---- AE windows (their own RNG stream: AE size does not shift the rest)
    let fs = cfg.ae_sample_rate_hz;
    let carrier = cfg.ae_carrier_hz.min(AE_CARRIER_MAX_FRAC * fs);
    let mut windows: Vec<AeWindow> = Vec::with_capacity(touches.len());
    let mut contacts = Vec::with_capacity(touches.len());
    for tc in touches.iter().filter(|t| program[t.row].method == "ae") {
        let onset = tc.t_c - clock_offset_s;
        let n0 = ((onset - cfg.ae_pre_s) * fs).ceil().max(0.0) as u64;
        let n1 = ((onset + cfg.ae_post_s) * fs).floor() as u64 + 1;
        let n0 = n0.max(windows.last().map(|w: &AeWindow| w.n1).unwrap_or(0));
        let amp = cfg.ae_noise_v * cfg.ae_burst_sigmas * (0.8 + 0.45 * rng.random::<f64>());
        windows.push(AeWindow {
            n0,
            n1: n1.max(n0),
            onset_s: onset,
            amp_v: amp,
            carrier_hz: carrier * (0.95 + 0.1 * rng.random::<f64>()),
            phase: 2.0 * PI * rng.random::<f64>(),
        });
        let row = &program[tc.row];
        contacts.push(ContactTruth {
            seq: row.seq,
            t_s: tc.t_c,
            ae_t_s: onset,
            registered_t_s: tc.t_r,
            x_mm: tc.act_c.x,
            y_mm: tc.act_c.y,
            z_mm: tc.act_c.z,
            surface_x_mm: tc.surface.x,
            surface_y_mm: tc.surface.y,
            surface_z_mm: tc.surface.z,
            dir: tc.dir_b * row.face.normal()[row.face.axis()] as i32,
            ae_amplitude_v: amp,
        });
    }

    // ---- write
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    write_parquet_atomic(&dir.join("plan.parquet"), &plan_batch(plan))?;
    write_parquet_atomic(&dir.join("motion.parquet"), &motion)?;
    write_parquet_atomic(&dir.join("passes.parquet"), &passes_batch)?;
    let probe_path = dir.join("probe.parquet");
    if has_probe {
        write_parquet_atomic(&probe_path, &probe_batch(&program, &touches))?;
    } else if probe_path.exists() {
        // A stale probe table from an earlier generation would change the run.
        std::fs::remove_file(&probe_path)
            .with_context(|| format!("cannot remove stale {}", probe_path.display()))?;
    }
    let ae_schema: SchemaRef = Arc::new(Schema::new(vec![
        Field::new("t_s", DataType::Float64, false),
        Field::new("ae_v", DataType::Float32, false),
    ]));
    write_parquet_batches_atomic(
        &dir.join("ae.parquet"),
        ae_schema.clone(),
        AeBatches {
            windows,
            wi: 0,
            n: 0,
            fs,
            noise_v: cfg.ae_noise_v,
            rng: run_rng(cfg.seed, index, 1),
            schema: ae_schema,
        },
    )?;

    let mut faces = BTreeMap::new();
    for f in Face::ALL {
        let (n, d) = plane(f);
        faces.insert(
            f.label(),
            FaceTruth {
                normal: [n.x, n.y, n.z],
                d,
            },
        );
    }
    let truth = RunTruth {
        run: run_id.clone(),
        run_index: index,
        seed: cfg.seed,
        block_origin_mm: [datum_true.x, datum_true.y, datum_true.z],
        block_rotation_rad: angles,
        block_offset_mm: [offset.x, offset.y, offset.z],
        faces,
        // A trigger latency is the controller's: every registered method has it.
        trigger_latency_s: std::iter::once("ae")
            .chain(cfg.other_methods.iter().map(ProbeMethod::label))
            .map(|m| (m, fx.latency_s))
            .collect(),
        touch_sigma_mm: cfg
            .speeds_mm_s
            .iter()
            .map(|&v| (format!("{v}"), ae_touch_sigma_mm(v)))
            .collect(),
        other_method_sigma_mm: if has_probe {
            cfg.other_methods
                .iter()
                .map(|m| {
                    (
                        format!("{}@{}", m.name, m.speed_mm_s),
                        touch_sigma_mm(&m.name, m.speed_mm_s),
                    )
                })
                .collect()
        } else {
            BTreeMap::new()
        },
        ae_clock_offset_s: clock_offset_s,
        ae_sample_rate_hz: fs,
        ae_carrier_hz: carrier,
        ae_noise_v: cfg.ae_noise_v,
        has_probe,
        contacts,
        alpha,
        passes: pass_truth,
        effects: specs.to_vec(),
    };
    write_json_atomic(&dir.join("truth.json"), &truth)?;
    write_atomic(
        &dir.join("run.toml"),
        run_toml(cfg, &run_id, index, clock_offset_s).as_bytes(),
    )?;
    Ok(())
}

/// act − physical at a touch: what the encoders cannot see (thermal drift of
/// the structure, backlash) plus any catalogue shape applied directly to
/// touch_normal. The observable's "normal coordinate" is the coordinate of
/// the face's normal axis (z, x, y for xy, yz, zx) as the robot plugin reads
/// it, so direct shapes act along +axis and their covariates use the +axis
/// sign convention (approach_normal_mm_s = v·dir_axis, dir = sign of the
/// last move along +axis).
fn frame_offset(fx: &Effects, row: &PlanRow, dir_b: i32, t_s: f64) -> V3 {
    let n = row.face.normal();
    let ax = row.face.axis();
    // TCP physically higher by D → the controller reads D lower.
    let mut o = V3::new(0.0, 0.0, -fx.drift_mm(t_s));
    // b/2 along the outward normal per the outward-relative dir_b equals
    // b/2·dir_axis along +axis: the catalogue's b·dir/2 in the plugin's frame.
    o += n * (fx.backlash_b_mm / 2.0 * dir_b as f64);
    if !fx.touch.is_empty() {
        let cov = |c: &str| -> f64 {
            match c {
                "x_mm" => row.nom.x,
                "y_mm" => row.nom.y,
                "z_mm" => row.nom.z,
                "approach_mm_s" => row.speed_mm_s,
                "approach_normal_mm_s" => row.speed_mm_s * row.dir[ax],
                "t_s" => t_s,
                "dir" => dir_b as f64 * n[ax],
                _ => 0.0,
            }
        };
        let g: f64 = fx.touch.iter().map(|e| e.value(&cov)).sum();
        let mut e = V3::zeros();
        e[ax] = 1.0;
        o += e * g;
    }
    o
}

fn motion_batch(pieces: &[Piece], rate_hz: f64, rng: &mut ChaCha8Rng) -> RecordBatch {
    let t_end = pieces.last().map(|p| p.t1).unwrap_or(0.0);
    let n = (t_end * rate_hz).floor() as usize + 1;
    let mut cols: [Vec<f64>; 8] = Default::default();
    let mut seg = Vec::with_capacity(n);
    let mut pi = 0;
    for k in 0..n {
        let t = k as f64 / rate_hz;
        while pi + 1 < pieces.len() && t >= pieces[pi].t1 {
            pi += 1;
        }
        let p = &pieces[pi];
        let tt = t.min(p.t1);
        let c = p.pos(tt);
        cols[0].push(t);
        for ax in 0..3 {
            cols[1 + ax].push(c[ax]);
        }
        for ax in 0..3 {
            cols[4 + ax].push(c[ax] + ACT_NOISE_MM * normal(rng));
        }
        cols[7].push(p.speed(tt));
        seg.push(if t < p.t1 { p.segment } else { -1 });
    }
    let [t, cx, cy, cz, ax, ay, az, feed] = cols;
    BatchBuilder::new()
        .f64("t_s", t)
        .f64("cmd_x_mm", cx)
        .f64("cmd_y_mm", cy)
        .f64("cmd_z_mm", cz)
        .f64("act_x_mm", ax)
        .f64("act_y_mm", ay)
        .f64("act_z_mm", az)
        .f64("feed_mm_s", feed)
        .i32("segment", seg)
        .build()
}

fn plan_batch(plan: &[PlanRow]) -> RecordBatch {
    let faces: Vec<&str> = plan.iter().map(|r| r.face.label()).collect();
    let methods = vec!["ae"; plan.len()];
    let f = |g: &dyn Fn(&PlanRow) -> f64| plan.iter().map(g).collect::<Vec<f64>>();
    BatchBuilder::new()
        .i32("seq", plan.iter().map(|r| r.seq).collect())
        .str("face", &faces)
        .i32("point", plan.iter().map(|r| r.point).collect())
        .i32("trial", plan.iter().map(|r| r.trial).collect())
        .str("method", &methods)
        .f64("approach_mm_s", f(&|r| r.speed_mm_s))
        .f64("nom_x_mm", f(&|r| r.nom.x))
        .f64("nom_y_mm", f(&|r| r.nom.y))
        .f64("nom_z_mm", f(&|r| r.nom.z))
        .f64("dir_x", f(&|r| r.dir.x))
        .f64("dir_y", f(&|r| r.dir.y))
        .f64("dir_z", f(&|r| r.dir.z))
        .build()
}

fn probe_batch(plan: &[PlanRow], touches: &[Touch]) -> RecordBatch {
    let rows: Vec<&PlanRow> = touches.iter().map(|t| &plan[t.row]).collect();
    let faces: Vec<&str> = rows.iter().map(|r| r.face.label()).collect();
    let methods: Vec<&str> = rows.iter().map(|r| r.method).collect();
    BatchBuilder::new()
        .f64("t_s", touches.iter().map(|t| t.t_r).collect())
        .str("face", &faces)
        .i32("point", rows.iter().map(|r| r.point).collect())
        .i32("trial", rows.iter().map(|r| r.trial).collect())
        .str("method", &methods)
        .f64("approach_mm_s", rows.iter().map(|r| r.speed_mm_s).collect())
        .f64("nom_x_mm", rows.iter().map(|r| r.nom.x).collect())
        .f64("nom_y_mm", rows.iter().map(|r| r.nom.y).collect())
        .f64("nom_z_mm", rows.iter().map(|r| r.nom.z).collect())
        .f64("x_mm", touches.iter().map(|t| t.registered.x).collect())
        .f64("y_mm", touches.iter().map(|t| t.registered.y).collect())
        .f64("z_mm", touches.iter().map(|t| t.registered.z).collect())
        .build()
}

/// The weld-repair cycle (MODELS.md §1.4). The compliance model as a
/// recursion on the carried deflection: the interference of pass i is the
/// new infeed δ′ᵢ plus the deflection α·δᵢ₋₁ left by the previous pass, and
/// splits into cut and deflection, δᵢ = Iᵢ/(1+α). With a constant δ′ this is
/// exactly δᵢ = [1 − (α/(1+α))ⁱ]·δ′; spark-out passes (δ′ = 0) remove
/// (α/(1+α))·δᵢ₋₁; finishing continues the recursion with δ′ = doc_finish.
/// Effects: thermal drift lifts the wheel between passes (the infeed loses
/// the drift increment) and shifts every height reading by −drift(t); wear
/// and depth-dependent compliance remove less than the compliance model says
/// (the shortfall is not carried as deflection, so the cut_depth gap is the
/// effect's own form).
fn passes(
    cfg: &RobotFleetConfig,
    fx: &Effects,
    alpha: f64,
    t_probe_end: f64,
    rng: &mut ChaCha8Rng,
) -> (RecordBatch, Vec<PassTruth>) {
    let mut stages = Vec::new();
    stages.extend(std::iter::repeat_n(
        ("rough", cfg.doc_rough_mm),
        cfg.rough_passes,
    ));
    stages.extend(std::iter::repeat_n(
        ("finish", cfg.doc_finish_mm),
        cfg.finish_passes,
    ));
    stages.extend(std::iter::repeat_n(("spark", 0.0), cfg.spark_passes));
    let duration = PASS_LENGTH_MM / cfg.grind_feed_mm_s;
    let mut t = t_probe_end + GRIND_START_DELAY_S;
    let mut h = cfg.weld_mm;
    let mut removed_mm3 = 0.0;
    let mut prev_comp = 0.0;
    let mut prev_model = 0.0;
    let mut prev_drift: Option<f64> = None;
    let mut cols = (
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
    );
    let mut truth = Vec::new();
    for (i, &(stage, doc)) in stages.iter().enumerate() {
        let pass = i as i32 + 1;
        let (t0, t1) = (t, t + duration);
        let d_mid = fx.drift_mm(0.5 * (t0 + t1));
        let d_inc = prev_drift.map(|p| d_mid - p).unwrap_or(0.0);
        prev_drift = Some(d_mid);
        let model = (alpha * prev_model + doc) / (1.0 + alpha);
        prev_model = model;
        let comp = ((alpha * prev_comp + doc - d_inc) / (1.0 + alpha)).max(0.0);
        prev_comp = comp;
        let cov = |c: &str| -> f64 {
            match c {
                "pass" => pass as f64,
                "nominal_doc_mm" => doc,
                "removed_mm3" => removed_mm3,
                "feed_mm_s" => cfg.grind_feed_mm_s,
                _ => 0.0,
            }
        };
        let direct: f64 = fx.cut.iter().map(|e| e.value(&cov)).sum();
        let real = (comp - fx.compliance_k_per_mm * doc * doc - fx.wear_k_mm_per_mm3 * removed_mm3
            + direct)
            .max(0.0);
        truth.push(PassTruth {
            pass,
            cut_mm: real,
            model_cut_mm: model,
            removed_mm3,
        });
        let before = h - fx.drift_mm(t0) + cfg.height_noise_mm * normal(rng);
        h -= real;
        let after = h - fx.drift_mm(t1) + cfg.height_noise_mm * normal(rng);
        removed_mm3 += real * cfg.contact_area_mm2;
        cols.0.push(pass);
        cols.1.push(stage);
        cols.2.push(doc);
        cols.3.push(cfg.grind_feed_mm_s);
        cols.4.push(before);
        cols.5.push(after);
        cols.6.push(t0);
        cols.7.push(t1);
        t = t1 + PASS_PAUSE_S;
    }
    let batch = BatchBuilder::new()
        .i32("pass", cols.0)
        .str("stage", &cols.1)
        .f64("nominal_doc_mm", cols.2)
        .f64("feed_mm_s", cols.3)
        .f64("height_before_mm", cols.4)
        .f64("height_after_mm", cols.5)
        .f64("t_start_s", cols.6)
        .f64("t_end_s", cols.7)
        .build();
    (batch, truth)
}

/// `started`: 2026-11-20T08:00:00Z plus 15 minutes per run index.
fn started(index: usize) -> String {
    let minutes = 8 * 60 + 15 * index as i64;
    let days = minutes.div_euclid(24 * 60);
    let rem = minutes.rem_euclid(24 * 60);
    // Civil date from days since 2026-11-20 (Hinnant's days_from_civil inverse).
    let z = days_from_civil(2026, 11, 20) + days;
    let (y, m, d) = civil_from_days(z);
    format!("{y:04}-{m:02}-{d:02}T{:02}:{:02}:00Z", rem / 60, rem % 60)
}

fn days_from_civil(y: i64, m: i64, d: i64) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (m + 9) % 12;
    let doy = (153 * mp + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146097 + doe - 719468
}

fn civil_from_days(z: i64) -> (i64, i64, i64) {
    let z = z + 719468;
    let era = z.div_euclid(146097);
    let doe = z - era * 146097;
    let yoe = (doe - doe / 1460 + doe / 36524 - doe / 146096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + if m <= 2 { 1 } else { 0 };
    (y, m, d)
}

fn run_toml(cfg: &RobotFleetConfig, run_id: &str, index: usize, clock_offset_s: f64) -> String {
    format!(
        r#"# Generated by sparkout-datasets (robot fleet generator, seed {seed}).
[run]
id = "{run_id}"
machine = "{machine}"
plugin = "robot"
started = "{started}"

[process]
weld_mm = {weld:?}
contact_area_mm2 = {area:?}
doc_rough_mm = {dr:?}
doc_finish_mm = {df:?}
rough_passes = {nr}
finish_passes = {nf}
spark_passes = {ns}
feed_mm_s = {feed:?}
pass_length_mm = {plen:?}
standoff_mm = {standoff:?}
motion_rate_hz = {mrate:?}
block_size_mm = [{bx:?}, {by:?}, {bh:?}]

[ae]
sample_rate_hz = {fs:?}
kind = "raw"
clock_offset_s = {off:?}
"#,
        seed = cfg.seed,
        machine = cfg.machine,
        started = started(index),
        weld = cfg.weld_mm,
        area = cfg.contact_area_mm2,
        dr = cfg.doc_rough_mm,
        df = cfg.doc_finish_mm,
        nr = cfg.rough_passes,
        nf = cfg.finish_passes,
        ns = cfg.spark_passes,
        feed = cfg.grind_feed_mm_s,
        plen = PASS_LENGTH_MM,
        standoff = cfg.standoff_mm,
        mrate = cfg.motion_rate_hz,
        bx = BLOCK_X_MM,
        by = BLOCK_Y_MM,
        bh = BLOCK_H_MM,
        fs = cfg.ae_sample_rate_hz,
        off = clock_offset_s,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thesis_repeatability_is_reproduced() {
        assert!((ae_touch_sigma_mm(5.0) * D2_N12 - 0.025).abs() < 1e-12);
        assert!((ae_touch_sigma_mm(10.0) * D2_N12 - 0.085).abs() < 1e-12);
    }

    #[test]
    fn plan_has_the_thesis_pattern() {
        let cfg = RobotFleetConfig::demo();
        let plan = build_plan(&cfg);
        assert_eq!(plan.len(), 3 * 12 * cfg.trials * cfg.speeds_mm_s.len());
        for f in Face::ALL {
            let pts: Vec<&PlanRow> = plan.iter().filter(|r| r.face == f).collect();
            // Points lie on the nominal face and the approach is into it.
            for r in &pts {
                let n = f.normal();
                assert!((n.dot(&(r.nom - V3::from(DATUM_NOM_MM)))).abs() < 1e-12);
                assert!((r.dir + n).norm() < 1e-12);
            }
            // Three concentric squares: distances from the face centre.
            let c = (f.point(0) + f.point(2)) / 2.0;
            for (sq, half) in SQUARE_HALF_MM.iter().enumerate() {
                for k in 0..4 {
                    let d = (f.point(sq * 4 + k) - c).norm();
                    assert!((d - half * 2f64.sqrt()).abs() < 1e-9);
                }
            }
        }
    }

    #[test]
    fn compliance_recursion_matches_the_thesis_sequence() {
        // MODELS.md §1.4: α = 0.5, δ′ = 0.3 → 0.200, 0.2667, 0.2889, ...
        let cfg = RobotFleetConfig {
            height_noise_mm: 0.0,
            ..RobotFleetConfig::default()
        };
        let mut rng = run_rng(1, 0, 0);
        let (_, truth) = passes(&cfg, &Effects::default(), 0.5, 0.0, &mut rng);
        let want = [0.200, 0.2667, 0.2889, 0.2963, 0.2988, 0.2996, 0.2999];
        for (p, w) in truth.iter().zip(want) {
            assert!((p.cut_mm - w).abs() < 1e-4, "{} vs {w}", p.cut_mm);
        }
        // 2.27 − Σ rough = 0.3199 (thesis).
        let rough: f64 = truth[..7].iter().map(|p| p.cut_mm).sum();
        assert!((2.27 - rough - 0.3199).abs() < 2e-4);
        // Spark-out removes α/(1+α) of the previous cut.
        let n = truth.len();
        assert!((truth[n - 1].cut_mm / truth[n - 2].cut_mm - 1.0 / 3.0).abs() < 1e-9);
    }

    #[test]
    fn effects_resolve_with_defaults_and_reject_unknowns() {
        let range = |_: &str| (0.0, 1.0);
        let specs: Vec<EffectSpec> = [
            "trigger_latency",
            "wheel_wear",
            "thermal_drift",
            "compliance",
            "backlash",
        ]
        .iter()
        .map(|s| s.parse().unwrap())
        .collect();
        let fx = resolve_effects(&specs, &range).unwrap();
        assert_eq!(fx.latency_s, DEF_LATENCY_S);
        assert_eq!(fx.wear_k_mm_per_mm3, DEF_WEAR_K_MM_PER_MM3);
        assert_eq!(fx.drift, Some((DEF_DRIFT_AMPLITUDE_MM, DEF_DRIFT_TAU_S)));
        assert_eq!(fx.compliance_k_per_mm, DEF_COMPLIANCE_K_PER_MM);
        assert_eq!(fx.backlash_b_mm, DEF_BACKLASH_B_MM);

        let err = resolve_effects(&["chatter".parse().unwrap()], &range)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("unknown effect `chatter`") && err.contains("wheel_wear"),
            "{err}"
        );
        let err = resolve_effects(&["wheel_wear=k=1".parse().unwrap()], &range)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("unknown parameter `k`") && err.contains("k_mm_per_mm3"),
            "{err}"
        );
        let err = resolve_effects(&["drift:t_s=amplitude_mm=0.1".parse().unwrap()], &range)
            .unwrap_err()
            .to_string();
        assert!(err.contains("tau_s"), "{err}");
        let err = resolve_effects(&["inertia:a_mm_s2=k=1".parse().unwrap()], &range)
            .unwrap_err()
            .to_string();
        assert!(err.contains("not applicable"), "{err}");

        let fx = resolve_effects(
            &[
                "wear:removed_mm3=k=-1e-4".parse().unwrap(),
                "drift:t_s=amplitude_mm=0.05,tau_s=100".parse().unwrap(),
                "bow:x_mm=amplitude_mm=0.02".parse().unwrap(),
            ],
            &range,
        )
        .unwrap();
        assert_eq!(fx.cut.len(), 1);
        assert_eq!(fx.touch.len(), 2);
        assert_eq!(fx.touch[1].params["c1"], 1.0);
    }

    #[test]
    fn started_dates_roll_over() {
        assert_eq!(started(0), "2026-11-20T08:00:00Z");
        assert_eq!(started(4 * 16), "2026-11-21T00:00:00Z");
        assert_eq!(started(4 * 24 * 41 - 32), "2026-12-31T00:00:00Z");
    }

    #[test]
    fn config_validation() {
        RobotFleetConfig::default().validate().unwrap();
        RobotFleetConfig::demo().validate().unwrap();
        let bad = RobotFleetConfig {
            pose_offset_mm: 2.0,
            ..RobotFleetConfig::default()
        };
        assert!(bad.validate().unwrap_err().to_string().contains("standoff"));
        let bad = RobotFleetConfig {
            speeds_mm_s: vec![],
            ..RobotFleetConfig::default()
        };
        assert!(bad.validate().is_err());
        assert_eq!("alternate".parse::<ProbeMode>(), Ok(ProbeMode::Alternate));
    }
}

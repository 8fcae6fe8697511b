//! Fixed cell geometry, process constants and effect defaults. (Part of the robot generator; see mod.rs.)

// Fixed cell geometry and process constants (documented, not configurable:
// they define the thesis-like cell; the knobs users need are in the config).

/// Nominal datum (the block corner where the three probed faces meet), in a
/// KR16 base frame, mm. Arbitrary but inside a KR16's 1.6 m reach.
pub(super) const DATUM_NOM_MM: [f64; 3] = [450.0, -40.0, 180.0];
/// Block extent from the datum: +x, +y, and downward −z (mm). The top face
/// (`xy`) is z = datum z; the side faces `yz` (x = datum x) and `zx`
/// (y = datum y) face −x and −y.
pub(super) const BLOCK_X_MM: f64 = 80.0;
pub(super) const BLOCK_Y_MM: f64 = 80.0;
pub(super) const BLOCK_H_MM: f64 = 60.0;
/// Half sides of the thesis's three concentric squares (outer, middle,
/// inner), 4 points each (docs/models.md §1.3), mm.
pub(super) const SQUARE_HALF_MM: [f64; 3] = [24.0, 16.0, 8.0];
/// Transit speed between probe points, mm/s.
pub(super) const TRANSIT_MM_S: f64 = 100.0;
/// Exact stop at a corner between two straight moves, s (two 4 ms replay
/// cycles: the velocity goes to zero before it turns).
pub(super) const CORNER_STOP_S: f64 = 0.008;
/// Speed of the short normal leg before an approach and of the retract, mm/s.
pub(super) const LEG_MM_S: f64 = 20.0;
/// Length of the normal leg when it arrives from outside (inward move), mm.
pub(super) const LEG_OUT_MM: f64 = 2.0;
/// When the leg arrives from inside (outward move, a reversal before the
/// inward approach), it starts this much closer to the surface than the
/// approach start, mm.
pub(super) const OVERTRAVEL_MM: f64 = 0.5;
/// Clearance above the top face for transit between faces, mm.
pub(super) const SAFE_CLEARANCE_MM: f64 = 15.0;
/// Deceleration after the touch is registered, mm/s².
pub(super) const STOP_DECEL_MM_S2: f64 = 1000.0;
/// Settle at the approach start before the slow probing move, s. Logged
/// with the approach's segment, so the move before the segment's first
/// sample is the leg (what a reader takes as the `dir` of the approach).
pub(super) const SETTLE_S: f64 = 0.02;
/// Dwell after the stop before retracting, s.
pub(super) const DWELL_S: f64 = 0.05;
/// Scatter of the contact itself along the normal (grain protrusion, surface
/// roughness), mm: the only scatter an ideal AE-derived touch has.
pub(super) const CONTACT_SCATTER_MM: f64 = 0.002;
/// Encoder/servo noise of the measured TCP (`act_*`), mm per axis.
pub(super) const ACT_NOISE_MM: f64 = 0.0003;
/// Thesis repeatability of the AE method (range of N repeated touches),
/// docs/models.md §1.1: 25 µm at 5 mm/s, 85 µm at 10 mm/s.
pub(super) const AE_RANGE_5_MM: f64 = 0.025;
pub(super) const AE_RANGE_10_MM: f64 = 0.085;
/// Thesis repeatability of the comparison methods (docs/models.md §1.1): 700 µm
/// for the mechanical dial gauge at 100 mm/s, 163 µm for the electrical
/// contact circuit at 10 mm/s (ranges; σ = range/d2(12)). Scaled linearly
/// with speed around those points: a method probed at another speed
/// overshoots proportionally more or less before it registers.
pub(super) const MECHANICAL_RANGE_MM: (f64, f64) = (0.700, 100.0);
pub(super) const ELECTRICAL_RANGE_MM: (f64, f64) = (0.163, 10.0);
/// d2 (expected range / σ of a normal sample) for N = 12, the middle of the
/// thesis's 10–15 repeats: converts a range into a standard deviation.
pub(super) const D2_N12: f64 = 3.258;
/// AE burst: rise and decay time constants, s (a few ms of rubbing).
pub(super) const AE_TAU_RISE_S: f64 = 20e-6;
pub(super) const AE_TAU_DECAY_S: f64 = 2.5e-3;
/// Carrier kept below 0.3 × sample rate (no aliasing at low demo rates).
pub(super) const AE_CARRIER_MAX_FRAC: f64 = 0.3;
/// Conditioned RMS AE (`--ae-signal rms`): the logger's default rate, Hz.
pub const AE_RMS_DEFAULT_RATE_HZ: f64 = 250.0;
/// RMS: entry (the wheel engages: the level rises with this time constant,
/// s, over `AE_RMS_ENTRY_S`), then the cut until the wheel leaves the
/// surface, then the exit (the RMS converter decays with this constant).
pub const AE_RMS_TAU_RISE_S: f64 = 0.004;
pub const AE_RMS_ENTRY_S: f64 = 0.012;
pub const AE_RMS_TAU_EXIT_S: f64 = 0.025;
/// RMS: multiplicative (log-normal) scatter of the level in air and in the
/// cut, and the cut's drop-outs (a grain losing contact for a moment):
/// probability per sample and the level's factor during one.
pub const AE_RMS_SCATTER_AIR: f64 = 0.15;
pub const AE_RMS_SCATTER_CUT: f64 = 0.3;
pub const AE_RMS_DROPOUT_P: f64 = 0.05;
pub const AE_RMS_DROPOUT_FACTOR: f64 = 0.05;
/// RMS: continuous recording goes on this long after the last AE contact, s.
pub const AE_RMS_TAIL_S: f64 = 1.0;
/// RMS: recording seconds per planned touch, for the size prediction
/// (measured: a default run's AE program lasts ~2.6 s per touch).
pub const AE_RMS_SECONDS_PER_TOUCH: f64 = 3.0;
/// AE recorder clock offset range (controller t = AE t + offset), s.
pub(super) const CLOCK_OFFSET_RANGE_S: (f64, f64) = (0.02, 0.2);
/// Grinding: pass length over the block and pause between passes (the
/// heights are measured in the pause), mm and s.
pub(super) const PASS_LENGTH_MM: f64 = 80.0;
pub(super) const PASS_PAUSE_S: f64 = 20.0;
/// AE rows per streamed batch (one Parquet row group each at most): keeps
/// generation memory bounded whatever the fleet size.
pub(super) const AE_BATCH_ROWS: usize = 1 << 17;
/// Pause between the end of probing and the first grinding pass, s.
pub(super) const GRIND_START_DELAY_S: f64 = 30.0;

// Effect defaults, sized for SNR ≳ 3 against the default noise (see
// `known_effects` for the arithmetic).
pub(super) const DEF_LATENCY_S: f64 = 0.024;
pub(super) const DEF_WEAR_K_MM_PER_MM3: f64 = 1e-4;
pub(super) const DEF_DRIFT_AMPLITUDE_MM: f64 = 0.4;
pub(super) const DEF_DRIFT_TAU_S: f64 = 300.0;
pub(super) const DEF_COMPLIANCE_K_PER_MM: f64 = 0.2;
pub(super) const DEF_BACKLASH_B_MM: f64 = 0.12;

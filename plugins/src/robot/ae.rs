//! The AE contact detector (docs/models.md §1.2): an envelope (RMS over a window of `w` samples
//! — or the signal itself when it is already a conditioned RMS), then
//! contact events where the envelope exceeds `centre + k·σ` of
//! the block's quiet start for a minimum dwell, with hysteresis and a merge
//! gap so one contact gives one event.
//!
//! The noise floor is robust: `centre` is the median of the envelope over
//! the calibration span and `σ = 1.4826·MAD` (the median absolute deviation
//! scaled to a normal σ), so a contact that overlaps up to half of the span
//! does not drag the threshold up, and a calibration span of a few dozen
//! samples (a 250 Hz RMS log) still gives a usable scale.
//!
//! Every length has a default derived from the sample rate
//! ([`AeParams::derive`]): seconds where the physics sets the time scale
//! (a raw carrier needs a ~1 ms RMS window), with floors in sample periods
//! where the sampling does (at 250 Hz a 0.5 ms dwell would be one sample,
//! and every noise spike a contact).
//!
//! This is the ingest stage's hot loop (AE logs are 10⁶–10⁸ samples per run),
//! so the detector is a streaming state machine: chunks from `AeStream` are
//! fed one after another and the envelope (its running sum of squares and the
//! last `w` samples) is carried across chunk boundaries. No allocation per
//! sample; f32 input, f64 accumulation. The running sum is updated by
//! `+x[i]² − x[i−w]²`; to keep rounding from accumulating (a large burst
//! followed by a quiet floor would otherwise leave the burst's rounding error
//! in the floor's sum) it is recomputed exactly every `RECOMPUTE_EVERY`
//! samples of the stream (at fixed *global* sample indices, so the result
//! does not depend on how the stream is chunked).
//!
//! Comparisons are done on the sum of squares (`sum > w·T²`), so the hot
//! loop has no square root.
//!
//! Length (~970 lines of code, ~510 of tests beside it): the envelope and
//! the event detector are one streaming kernel (a deliberate hot loop, see
//! benches/ae_kernel.rs) with the parameter derivation and the robust noise
//! floor it needs; the tests pin it against a plain reference.

/// Exact recomputation period of the running sum (samples of the stream).
pub const RECOMPUTE_EVERY: u64 = 1 << 16;

/// What the recorded signal is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SignalKind {
    /// The sensor voltage: a carrier of tens to hundreds of kHz that needs
    /// rectifying and smoothing (the RMS envelope) before a threshold.
    Raw,
    /// An already conditioned RMS (or envelope) signal, non-negative and
    /// typically sampled at 100 Hz – 10 kHz: thresholded as it is.
    Rms,
}

impl SignalKind {
    pub fn label(self) -> &'static str {
        match self {
            SignalKind::Raw => "raw",
            SignalKind::Rms => "rms",
        }
    }
    /// A raw AE voltage swings about zero; a conditioned RMS never goes
    /// below it. So a stretch of signal without a negative sample is taken
    /// for an RMS (used only when neither the user nor run.toml says).
    pub fn guess(first: &[f32]) -> SignalKind {
        if !first.is_empty() && first.iter().all(|&x| x >= 0.0) {
            SignalKind::Rms
        } else {
            SignalKind::Raw
        }
    }
}

/// Default raw-AE RMS window: a few hundred periods of a 100 kHz–1 MHz
/// carrier, short against a contact's few ms of rubbing.
pub const RAW_WINDOW_S: f64 = 1e-3;
/// Default minimum dwell, and its floor in samples: a contact must last
/// several samples so that one noise sample above the threshold is not one.
pub const MIN_DWELL_S: f64 = 0.5e-3;
pub const MIN_DWELL_SAMPLES: usize = 3;
/// Default merge gap: contacts closer than this many envelope windows (raw)
/// or this many seconds (rms: the signal has no window of ours, and an RMS
/// converter's output wanders about the threshold for tens of ms as a cut
/// ends) — and never closer than `MERGE_GAP_SAMPLES` samples — are one
/// contact (a cut whose level dips below the release for an instant).
pub const MERGE_GAP_WINDOWS: f64 = 2.0;
pub const RMS_MERGE_GAP_S: f64 = 0.05;
pub const MERGE_GAP_SAMPLES: usize = 10;
/// Default noise-calibration span, and its floor in samples: the MAD of
/// fewer than a few dozen samples is too rough a scale for k = 8.
pub const NOISE_WINDOW_S: f64 = 5e-3;
pub const NOISE_WINDOW_SAMPLES: usize = 64;

/// The detector's settings as a user gives them: `None` is "derive it from
/// the sample rate and the signal kind" ([`AeParams::derive`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct AeSettings {
    pub window_s: Option<f64>,
    pub k_sigma: f64,
    pub min_dwell_s: Option<f64>,
    pub hysteresis: f64,
    pub noise_window_s: Option<f64>,
    pub merge_gap_s: Option<f64>,
}

/// Detector parameters, in samples (the stage converts from seconds).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AeParams {
    /// RMS window length `w`, samples (≥ 1; 1 = the signal is its own
    /// envelope, as for a conditioned RMS).
    pub window: usize,
    /// Threshold = centre + k·σ of the envelope over the noise window.
    pub k_sigma: f64,
    /// Envelope must stay above the threshold this many samples (≥ 1).
    pub min_dwell: usize,
    /// Re-arm when the envelope falls below centre + hysteresis·k·σ (0..=1).
    pub hysteresis: f64,
    /// Envelope samples used to estimate the noise floor at the start of
    /// each contiguous recording block (after the window has filled).
    pub noise_window: usize,
    /// A contact starting at most this many samples after the previous one
    /// ended (same block) extends it instead (0: never merge).
    pub merge_gap: usize,
    /// Threshold crossings too short for the dwell, each starting at most
    /// this many samples after the previous one ended, add up towards the
    /// dwell (0: never). Derived only for a signal without an envelope
    /// window: an RMS window already bridges dips shorter than itself,
    /// and chaining noise crossings there would move onsets early.
    pub chain_gap: usize,
}

impl AeParams {
    /// From seconds and a sample rate (e.g. a 1 ms window), exactly as
    /// given: no floors, no merging, no chaining.
    pub fn from_seconds(
        sample_rate_hz: f64,
        window_s: f64,
        k_sigma: f64,
        min_dwell_s: f64,
        hysteresis: f64,
        noise_window_s: f64,
    ) -> AeParams {
        AeParams {
            window: ((window_s * sample_rate_hz).round() as usize).max(1),
            k_sigma,
            min_dwell: ((min_dwell_s * sample_rate_hz).ceil() as usize).max(1),
            hysteresis,
            noise_window: ((noise_window_s * sample_rate_hz).round() as usize).max(2),
            merge_gap: 0,
            chain_gap: 0,
        }
    }

    /// The parameters for a signal of `kind` sampled at `fs` Hz: each
    /// setting the user gave is converted as it is; each one left out is
    /// derived — window 1 ms (raw) or 1 sample (rms: no envelope), dwell
    /// max(0.5 ms, 3 samples), merge gap max(2 windows (raw) or 50 ms
    /// (rms), 10 samples), noise window max(5 ms, 64 samples); crossings
    /// chain within the dwell (capped by the merge gap) when the window is
    /// one sample.
    pub fn derive(fs: f64, kind: SignalKind, s: &AeSettings) -> AeParams {
        let samples = |sec: f64| sec * fs;
        let window = match (s.window_s, kind) {
            (Some(w), _) => (samples(w).round() as usize).max(1),
            (None, SignalKind::Raw) => (samples(RAW_WINDOW_S).round() as usize).max(1),
            (None, SignalKind::Rms) => 1,
        };
        let min_dwell = match s.min_dwell_s {
            Some(d) => (samples(d).ceil() as usize).max(1),
            None => Self::default_min_dwell(fs),
        };
        let merge_gap = match (s.merge_gap_s, kind) {
            (Some(g), _) => samples(g).round() as usize,
            (None, SignalKind::Raw) => {
                ((MERGE_GAP_WINDOWS * window as f64).round() as usize).max(MERGE_GAP_SAMPLES)
            }
            (None, SignalKind::Rms) => {
                (samples(RMS_MERGE_GAP_S).round() as usize).max(MERGE_GAP_SAMPLES)
            }
        };
        let chain_gap = if window == 1 {
            min_dwell.min(merge_gap)
        } else {
            0
        };
        let noise_window = match s.noise_window_s {
            Some(n) => (samples(n).round() as usize).max(2),
            None => (samples(NOISE_WINDOW_S).round() as usize).max(NOISE_WINDOW_SAMPLES),
        };
        AeParams {
            window,
            k_sigma: s.k_sigma,
            min_dwell,
            hysteresis: s.hysteresis,
            noise_window,
            merge_gap,
            chain_gap,
        }
    }

    /// The minimum dwell the defaults give at `fs` (what the fragmentation
    /// check measures contacts against, whatever the user set).
    pub fn default_min_dwell(fs: f64) -> usize {
        ((MIN_DWELL_S * fs).ceil() as usize).max(MIN_DWELL_SAMPLES)
    }
}

/// Noise floor of one recording block: the robust centre (median) and
/// scale (1.4826·MAD) of the envelope (V) and the thresholds derived from
/// them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseFloor {
    pub centre_v: f64,
    pub sigma_v: f64,
    /// Envelope level that starts a contact (V).
    pub threshold_v: f64,
    /// Envelope level that ends it (V).
    pub release_v: f64,
}

/// One contact event.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AeEvent {
    /// Global sample index of the first above-threshold sample of the event.
    pub onset_index: u64,
    /// Time of that sample (the recorder's clock).
    pub onset_t_s: f64,
    /// Time of the first sample back below the release level (or of the
    /// last sample of the block when it ended first).
    pub end_t_s: f64,
    /// Global sample index of that sample.
    pub end_index: u64,
    /// Peak envelope during the event (V).
    pub peak_v: f64,
    /// Noise floor and thresholds in force.
    pub floor: NoiseFloor,
}

impl AeEvent {
    pub fn duration_s(&self) -> f64 {
        self.end_t_s - self.onset_t_s
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    /// Filling the first window of a block.
    Warmup,
    /// Estimating the noise floor.
    Calibrate,
    /// Armed, below threshold.
    Idle,
    /// Above threshold since `start`, not yet for the full dwell.
    Candidate,
    /// In contact.
    Active,
}

/// Samples per block of the fast paths (a multiple of [`LANES`]).
const BLOCK: usize = 16;
/// Independent accumulators per block (so the sums vectorise).
const LANES: usize = 4;

/// Over one block of new samples `xs` and the samples `os` leaving the
/// window: Σd, Σmax(d, 0) and (when `NEG`) Σmin(d, 0) of d = x² − o², each
/// in LANES lane-wise partial sums added as ((0 + 1) + (2 + 3)). Both fast
/// paths use these to decide whether a block can cross a threshold
/// without replaying it sample by sample; `NEG` is a const so the armed
/// path does not pay for the sum it does not need.
#[inline(always)]
fn block_sums<const NEG: bool>(xs: &[f32], os: &[f32]) -> [f64; 3] {
    let mut tot = [0.0f64; LANES];
    let mut pos = [0.0f64; LANES];
    let mut neg = [0.0f64; LANES];
    for (xc, oc) in xs.chunks_exact(LANES).zip(os.chunks_exact(LANES)) {
        for k in 0..LANES {
            let x = xc[k] as f64;
            let o = oc[k] as f64;
            let d = x * x - o * o;
            tot[k] += d;
            pos[k] += d.max(0.0);
            if NEG {
                neg[k] += d.min(0.0);
            }
        }
    }
    let fold = |a: [f64; LANES]| (a[0] + a[1]) + (a[2] + a[3]);
    [fold(tot), fold(pos), fold(neg)]
}

/// Streaming detector state. Feed contiguous samples with [`AeDetector::feed`];
/// call [`AeDetector::reset`] at a gap in the recording (a new block: the
/// window restarts and the noise floor is re-estimated) and
/// [`AeDetector::finish`] at the end of the stream.
#[derive(Debug, Clone)]
pub struct AeDetector {
    p: AeParams,
    /// The last `window` samples before the current chunk, oldest first
    /// (ring: `hist[(head + j) % window]`).
    hist: Vec<f32>,
    head: usize,
    /// Samples seen in the current block.
    block_seen: u64,
    /// Samples seen in the whole stream (global index of the next sample).
    global: u64,
    sum: f64,
    phase: Phase,
    /// Envelope samples of the noise calibration so far (capacity
    /// `noise_window`, reused from block to block).
    cal: Vec<f64>,
    floor: Option<NoiseFloor>,
    /// `window·threshold²` and `window·release²`.
    on_sum: f64,
    off_sum: f64,
    // candidate / active event
    start_index: u64,
    start_t: f64,
    dwell: usize,
    peak_sum: f64,
    last_t: f64,
    /// Noise floors of every block, in order (for the "no contact" message
    /// and the contacts table).
    floors: Vec<NoiseFloor>,
    /// Largest envelope seen while armed (V²·w), for diagnostics.
    max_sum_armed: f64,
    /// The last finished event, held back while a next one may still start
    /// within the merge gap.
    pending: Option<AeEvent>,
    /// Threshold crossings that fell back before the minimum dwell.
    short_crossings: u64,
    /// Those of them farther than the merge gap from every contact of
    /// their block (not the ripple at a contact's start or end).
    stray_crossings: u64,
    /// End indices of dropped crossings not within the merge gap after the
    /// block's last contact, until a contact starting within the merge gap
    /// absorbs them or the block ends.
    unresolved: std::collections::VecDeque<u64>,
    /// End index of the block's last contact.
    last_end: Option<u64>,
    /// The latest of them (with the ones chained before it), while a chain
    /// gap is in force.
    dropped: Option<Dropped>,
}

/// A run of dropped threshold crossings, each within the chain gap of the
/// next (global sample indices).
#[derive(Debug, Clone, Copy)]
struct Dropped {
    start: u64,
    start_t: f64,
    end: u64,
    peak_sum: f64,
    /// Samples above the threshold over the whole chain.
    dwell: usize,
}

impl AeDetector {
    pub fn new(p: AeParams) -> AeDetector {
        assert!(p.window >= 1 && p.min_dwell >= 1 && p.noise_window >= 2);
        AeDetector {
            p,
            hist: vec![0.0; p.window],
            head: 0,
            block_seen: 0,
            global: 0,
            sum: 0.0,
            phase: Phase::Warmup,
            cal: Vec::with_capacity(p.noise_window),
            floor: None,
            on_sum: f64::INFINITY,
            off_sum: f64::INFINITY,
            start_index: 0,
            start_t: 0.0,
            dwell: 0,
            peak_sum: 0.0,
            last_t: f64::NAN,
            floors: Vec::new(),
            max_sum_armed: 0.0,
            pending: None,
            short_crossings: 0,
            stray_crossings: 0,
            unresolved: std::collections::VecDeque::new(),
            last_end: None,
            dropped: None,
        }
    }

    pub fn params(&self) -> &AeParams {
        &self.p
    }

    /// Noise floors estimated so far (one per block that got past calibration).
    pub fn floors(&self) -> &[NoiseFloor] {
        &self.floors
    }

    /// Largest envelope (V) seen while armed — what "no contact" reports.
    pub fn max_envelope_armed_v(&self) -> f64 {
        (self.max_sum_armed / self.p.window as f64).sqrt()
    }

    /// Global index of the next sample.
    pub fn samples_seen(&self) -> u64 {
        self.global
    }

    /// Threshold crossings that did not last the minimum dwell (dropped):
    /// many of them against few contacts say the signal hovers about the
    /// threshold — a contact breaking up, or a threshold in the noise.
    pub fn short_crossings(&self) -> u64 {
        self.short_crossings
    }

    /// Dropped crossings farther than the merge gap from every contact of
    /// their block: the ones that say the threshold sits in the noise (the
    /// rest are a contact's own ripple as it starts or ends). Counted when
    /// resolved: complete after [`AeDetector::finish`].
    pub fn stray_crossings(&self) -> u64 {
        self.stray_crossings
    }

    /// A gap in the recording: close any open event at the last sample seen,
    /// restart the window and the noise-floor estimate.
    pub fn reset(&mut self, out: &mut Vec<AeEvent>) {
        self.close_open(out);
        self.hist.iter_mut().for_each(|h| *h = 0.0);
        self.head = 0;
        self.block_seen = 0;
        self.sum = 0.0;
        self.phase = Phase::Warmup;
        self.cal.clear();
        self.dropped = None;
        self.last_end = None;
        self.floor = None;
        self.on_sum = f64::INFINITY;
        self.off_sum = f64::INFINITY;
    }

    /// End of the stream: an event still open ends at the last sample.
    pub fn finish(&mut self, out: &mut Vec<AeEvent>) {
        self.close_open(out);
    }

    /// Close an open event at the last sample seen and release the held
    /// one: a block boundary (or the end) is never merged across.
    fn close_open(&mut self, out: &mut Vec<AeEvent>) {
        match self.phase {
            Phase::Active => {
                let e = self.event(self.last_t, self.global.saturating_sub(1));
                self.emit(e, out);
            }
            Phase::Candidate => {
                self.short_crossings += 1;
                self.stray_crossings += 1;
            }
            _ => {}
        }
        // The block ends: no contact will absorb what is left.
        self.stray_crossings += self.unresolved.len() as u64;
        self.unresolved.clear();
        if matches!(self.phase, Phase::Active | Phase::Candidate) {
            self.phase = Phase::Idle;
        }
        out.extend(self.pending.take());
    }

    fn event(&self, end_t: f64, end_index: u64) -> AeEvent {
        AeEvent {
            onset_index: self.start_index,
            onset_t_s: self.start_t,
            end_t_s: end_t,
            end_index,
            peak_v: (self.peak_sum / self.p.window as f64).sqrt(),
            floor: self.floor.expect("armed only after calibration"),
        }
    }

    /// A finished event: merged into the held one when it starts within the
    /// merge gap of its end, else the held one is released and this one
    /// held. Without a merge gap events go straight out.
    fn emit(&mut self, e: AeEvent, out: &mut Vec<AeEvent>) {
        self.last_end = Some(e.end_index);
        if self.p.merge_gap == 0 {
            out.push(e);
            return;
        }
        match self.pending.as_mut() {
            Some(p) if e.onset_index.saturating_sub(p.end_index) <= self.p.merge_gap as u64 => {
                p.end_t_s = e.end_t_s;
                p.end_index = e.end_index;
                p.peak_v = p.peak_v.max(e.peak_v);
            }
            _ => {
                out.extend(self.pending.take());
                self.pending = Some(e);
            }
        }
    }

    /// The sample `window` positions before chunk index `i`: in the chunk
    /// or in the carried history.
    #[inline(always)]
    fn old(&self, v: &[f32], i: usize) -> f32 {
        let w = self.p.window;
        if i >= w {
            v[i - w]
        } else {
            self.hist[(self.head + i) % w]
        }
    }

    /// Exact sum of squares of the `window` samples ending at chunk index
    /// `i` (inclusive), with four accumulators.
    fn exact_sum(&self, v: &[f32], i: usize) -> f64 {
        let w = self.p.window;
        let mut acc = [0.0f64; 4];
        let lo_chunk = (i + 1).saturating_sub(w);
        let from_hist = w - (i + 1 - lo_chunk); // samples taken from history
        for j in 0..from_hist {
            // the newest `from_hist` history samples
            let h = self.hist[(self.head + w - from_hist + j) % w] as f64;
            acc[j & 3] += h * h;
        }
        let s = &v[lo_chunk..=i];
        let mut it = s.chunks_exact(4);
        for c in &mut it {
            for k in 0..4 {
                let x = c[k] as f64;
                acc[k] += x * x;
            }
        }
        for (k, &x) in it.remainder().iter().enumerate() {
            acc[k] += (x as f64) * (x as f64);
        }
        (acc[0] + acc[1]) + (acc[2] + acc[3])
    }

    /// Feed contiguous samples (`t_s[i]` is the time of `v[i]`). Events that
    /// end within this chunk are pushed to `out`; an open event carries over.
    pub fn feed(&mut self, t_s: &[f64], v: &[f32], out: &mut Vec<AeEvent>) {
        assert_eq!(t_s.len(), v.len(), "t_s and ae_v lengths differ");
        let n = v.len();
        if n == 0 {
            return;
        }
        let w = self.p.window;
        let mut i = 0usize;
        while i < n {
            // Run up to the next exact-recompute point (global index) or the
            // end of the chunk; the phase's loop may stop earlier.
            let to_recompute = RECOMPUTE_EVERY - (self.global + i as u64) % RECOMPUTE_EVERY;
            let end = (i as u64 + to_recompute).min(n as u64) as usize;
            i = match self.phase {
                Phase::Idle => {
                    let (j, crossed) = self.run_idle(v, i, end);
                    if crossed {
                        // The crossing sample (j − 1) starts a candidate.
                        self.start_candidate(t_s, j - 1);
                        if self.dwell >= self.p.min_dwell {
                            self.confirm();
                        }
                    }
                    j
                }
                Phase::Active => {
                    let (j, ended) = self.run_active(v, i, end);
                    if ended {
                        let e = self.event(t_s[j - 1], self.global + (j - 1) as u64);
                        self.emit(e, out);
                        self.phase = Phase::Idle;
                    }
                    j
                }
                _ => self.run_slow(t_s, v, i, end, out),
            };
            if i > 0 && (self.global + i as u64).is_multiple_of(RECOMPUTE_EVERY) {
                // Re-synchronise the running sum with the exact one (the
                // window ends at the previous sample; history zeros before
                // a block's first full window contribute nothing).
                self.sum = self.exact_sum(v, i - 1);
            }
        }
        // Carry the last `w` samples into the history ring.
        if n >= w {
            self.hist.copy_from_slice(&v[n - w..]);
            self.head = 0;
        } else {
            for &x in v {
                self.hist[self.head] = x;
                self.head = (self.head + 1) % w;
            }
        }
        self.block_seen += n as u64;
        self.global += n as u64;
        self.last_t = t_s[n - 1];
    }

    /// A candidate that fell back before the dwell, at global index `end`.
    /// With a chain gap it is remembered (chained to the previous dropped
    /// one when that ended within the gap), so a contact confirmed soon
    /// after can start where the first of them did.
    fn drop_candidate(&mut self, end: u64) {
        self.short_crossings += 1;
        let gap = self.p.merge_gap as u64;
        // Any contact still to come starts after this crossing: the ones
        // more than the gap before it can no longer be absorbed (this also
        // bounds the queue to the crossings of one merge gap).
        while let Some(&e) = self.unresolved.front() {
            if self.start_index.saturating_sub(e) <= gap {
                break;
            }
            self.unresolved.pop_front();
            self.stray_crossings += 1;
        }
        match self.last_end {
            // The ripple as the block's last contact ends.
            Some(le) if self.start_index.saturating_sub(le) <= gap => {}
            _ => self.unresolved.push_back(end),
        }
        if self.p.chain_gap == 0 {
            return;
        }
        // `self.dwell` already counts the chain's samples (start_candidate).
        let (start, start_t, peak) = match self.dropped {
            Some(d) if self.start_index.saturating_sub(d.end) <= self.p.chain_gap as u64 => {
                (d.start, d.start_t, d.peak_sum.max(self.peak_sum))
            }
            _ => (self.start_index, self.start_t, self.peak_sum),
        };
        self.dropped = Some(Dropped {
            start,
            start_t,
            end,
            peak_sum: peak,
            dwell: self.dwell,
        });
    }

    /// The candidate has lasted the dwell — its own samples above the
    /// threshold plus those of the dropped crossings chained to it within
    /// the chain gap: a contact. Its onset is the first of those crossings:
    /// a contact whose level dips during its first samples (a cut's entry,
    /// a slow RMS log) starts when it first crossed, not after its last dip.
    fn confirm(&mut self) {
        self.phase = Phase::Active;
        // Dropped crossings within the merge gap before this contact are
        // its ripple as it starts (taking the chained ones' onset into
        // account below makes no difference: they are within the gap).
        let gap = self.p.merge_gap as u64;
        for e in self.unresolved.drain(..) {
            if self.start_index.saturating_sub(e) > gap {
                self.stray_crossings += 1;
            }
        }
        if let Some(d) = self.dropped.take() {
            if self.start_index.saturating_sub(d.end) <= self.p.chain_gap as u64 {
                self.start_index = d.start;
                self.start_t = d.start_t;
                self.peak_sum = self.peak_sum.max(d.peak_sum);
            }
        }
    }

    fn start_candidate(&mut self, t_s: &[f64], i: usize) {
        self.phase = Phase::Candidate;
        self.start_index = self.global + i as u64;
        self.start_t = t_s[i];
        // Samples above the threshold of the dropped crossings just before
        // (within the chain gap) count towards the dwell.
        self.dwell = 1 + match self.dropped {
            Some(d) if self.start_index.saturating_sub(d.end) <= self.p.chain_gap as u64 => d.dwell,
            _ => 0,
        };
        self.peak_sum = self.sum;
    }

    /// The fast path: armed and below threshold. Returns the index after the
    /// last sample processed; stops right after a sample whose envelope
    /// crosses the threshold.
    #[inline(never)]
    fn run_idle(&mut self, v: &[f32], start: usize, end: usize) -> (usize, bool) {
        let w = self.p.window;
        let on = self.on_sum;
        let mut sum = self.sum;
        let mut mx = self.max_sum_armed;
        let mut i = start;
        // One sample: add x² − o², stop right after a crossing.
        macro_rules! step {
            ($x:expr, $o:expr) => {{
                let (x, o) = ($x as f64, $o as f64);
                sum += x * x - o * o;
                i += 1;
                if sum > on {
                    self.sum = sum;
                    self.max_sum_armed = mx.max(sum);
                    return (i, true);
                }
                mx = mx.max(sum);
            }};
        }
        // Samples whose outgoing partner is in the history ring.
        while i < end.min(w) {
            step!(v[i], self.hist[(self.head + i) % w]);
        }
        // Both samples in the chunk: the hot loop, in blocks of BLOCK samples.
        // Within a block the sum of the squared differences and the sum of
        // their positive parts are lane-wise reductions (vectorisable, no
        // dependency on the running sum); `sum + Σ max(d, 0)` bounds every
        // running sum inside the block from above, so when it stays below
        // the threshold no sample can cross and the block costs one
        // loop-carried addition. Otherwise the block is replayed sample by
        // sample to find the exact crossing. (The largest envelope seen while
        // armed, kept for the "no contact" message, is sampled per block.)
        while i + BLOCK <= end {
            let xs = &v[i..i + BLOCK];
            let os = &v[i - w..i - w + BLOCK];
            let [tot, pos, _] = block_sums::<false>(xs, os);
            let bound = sum + pos;
            if bound > on {
                for k in 0..BLOCK {
                    step!(xs[k], os[k]);
                }
            } else {
                sum += tot;
                mx = mx.max(sum);
                i += BLOCK;
            }
        }
        while i < end {
            step!(v[i], v[i - w]);
        }
        self.sum = sum;
        self.max_sum_armed = mx;
        (end, false)
    }

    /// In contact: track the peak until the envelope falls below the release
    /// level. Returns the index after the last sample processed and whether
    /// the contact ended (at the sample before that index). Same block
    /// bounds as [`Self::run_idle`]: a block whose running sums can neither
    /// fall below the release level (`sum + Σ min(d, 0) ≥ off`) nor exceed
    /// the peak (`sum + Σ max(d, 0) ≤ peak`) costs one addition; any other
    /// is replayed sample by sample, so the peak and the end are exact.
    #[inline(never)]
    fn run_active(&mut self, v: &[f32], start: usize, end: usize) -> (usize, bool) {
        let w = self.p.window;
        let off = self.off_sum;
        let mut sum = self.sum;
        let mut peak = self.peak_sum;
        let mut i = start;
        macro_rules! step {
            ($x:expr, $o:expr) => {{
                let (x, o) = ($x as f64, $o as f64);
                sum += x * x - o * o;
                i += 1;
                if sum < off {
                    self.sum = sum;
                    self.peak_sum = peak;
                    return (i, true);
                }
                peak = peak.max(sum);
            }};
        }
        while i < end.min(w) {
            step!(v[i], self.hist[(self.head + i) % w]);
        }
        while i + BLOCK <= end {
            let xs = &v[i..i + BLOCK];
            let os = &v[i - w..i - w + BLOCK];
            let [tot, pos, neg] = block_sums::<true>(xs, os);
            let hi = sum + pos;
            let lo = sum + neg;
            if lo >= off && hi <= peak {
                sum += tot;
                i += BLOCK;
            } else {
                for k in 0..BLOCK {
                    step!(xs[k], os[k]);
                }
            }
        }
        while i < end {
            step!(v[i], v[i - w]);
        }
        self.sum = sum;
        self.peak_sum = peak;
        (i, false)
    }

    /// Every other phase, sample by sample (warm-up, calibration and contacts
    /// are a small share of the samples). Returns where it stopped: `end`, or
    /// earlier when the phase became Idle (so the fast path takes over).
    fn run_slow(
        &mut self,
        t_s: &[f64],
        v: &[f32],
        start: usize,
        end: usize,
        out: &mut Vec<AeEvent>,
    ) -> usize {
        let w = self.p.window;
        let wf = w as f64;
        let mut i = start;
        while i < end {
            let x = v[i] as f64;
            let o = self.old(v, i) as f64;
            self.sum += x * x - o * o;
            let seen = self.block_seen + i as u64 + 1; // samples of the block incl. this one
            match self.phase {
                Phase::Warmup => {
                    if seen >= w as u64 {
                        // The first full window: make the sum exact.
                        self.sum = self.exact_sum(v, i);
                        self.phase = Phase::Calibrate;
                        self.cal.clear();
                    }
                }
                Phase::Calibrate => {
                    let env = (self.sum.max(0.0) / wf).sqrt();
                    self.cal.push(env);
                    if self.cal.len() >= self.p.noise_window {
                        let (centre, sigma) = robust_floor(&mut self.cal);
                        let thr = centre + self.p.k_sigma * sigma;
                        let rel = centre + self.p.hysteresis * self.p.k_sigma * sigma;
                        let floor = NoiseFloor {
                            centre_v: centre,
                            sigma_v: sigma,
                            threshold_v: thr,
                            release_v: rel,
                        };
                        self.floor = Some(floor);
                        self.floors.push(floor);
                        self.on_sum = wf * thr * thr;
                        self.off_sum = wf * rel * rel;
                        self.phase = Phase::Idle;
                        return i + 1;
                    }
                }
                Phase::Idle => {
                    self.max_sum_armed = self.max_sum_armed.max(self.sum);
                    if self.sum > self.on_sum {
                        self.start_candidate(t_s, i);
                        if self.dwell >= self.p.min_dwell {
                            self.confirm();
                        }
                    } else {
                        return i + 1;
                    }
                }
                Phase::Candidate => {
                    if self.sum > self.on_sum {
                        self.dwell += 1;
                        self.peak_sum = self.peak_sum.max(self.sum);
                        if self.dwell >= self.p.min_dwell {
                            self.confirm();
                        }
                    } else {
                        // Too short: not a contact (yet: see `confirm`).
                        self.drop_candidate(self.global + i as u64);
                        self.phase = Phase::Idle;
                        return i + 1;
                    }
                }
                Phase::Active => {
                    self.peak_sum = self.peak_sum.max(self.sum);
                    if self.sum < self.off_sum {
                        let e = self.event(t_s[i], self.global + i as u64);
                        self.emit(e, out);
                        self.phase = Phase::Idle;
                        return i + 1;
                    }
                }
            }
            i += 1;
        }
        end
    }
}

/// The median of `v` (reordered in place; the mean of the two middle
/// values when the length is even).
fn median_in_place(v: &mut [f64]) -> f64 {
    let n = v.len();
    let mid = n / 2;
    let (lo, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    let m = *m;
    if n % 2 == 1 {
        m
    } else {
        let below = lo.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        0.5 * (below + m)
    }
}

/// Robust centre and scale of the calibration envelope (consumed: it is
/// reordered and overwritten). The scale is 1.4826·MAD; where more than
/// half the samples are identical (a quantised, perfectly quiet logger) the
/// MAD is 0 and the mean absolute deviation (×1.2533, the normal-consistent
/// factor) stands in, so one step of the logger is not a contact; last,
/// σ is never below 0.1 % of the centre (a flat floor would make any
/// rounding a contact).
pub fn robust_floor(cal: &mut [f64]) -> (f64, f64) {
    let centre = median_in_place(cal);
    for x in cal.iter_mut() {
        *x = (*x - centre).abs();
    }
    let mad = median_in_place(cal);
    let scale = if mad > 0.0 {
        1.4826 * mad
    } else {
        1.2533 * cal.iter().sum::<f64>() / cal.len() as f64
    };
    (centre, scale.max(1e-3 * centre.abs()).max(1e-12))
}

/// Split a chunk's times into contiguous runs: a new run starts where the
/// step exceeds `max_step_s` (a gap in a triggered recording). Returns the
/// start indices of runs after the first.
pub fn gaps(t_s: &[f64], prev_t: Option<f64>, max_step_s: f64) -> Vec<usize> {
    let mut out = Vec::new();
    if let (Some(p), Some(&t0)) = (prev_t, t_s.first()) {
        if t0 - p > max_step_s {
            out.push(0);
        }
    }
    out.extend(
        t_s.windows(2)
            .enumerate()
            .filter(|(_, w)| w[1] - w[0] > max_step_s)
            .map(|(i, _)| i + 1),
    );
    out
}

/// Reference RMS envelope (trailing window, partial at the start), computed
/// naively — for tests and reports, not the hot path.
pub fn rms_envelope(v: &[f32], window: usize) -> Vec<f64> {
    let mut out = Vec::with_capacity(v.len());
    for i in 0..v.len() {
        let lo = (i + 1).saturating_sub(window);
        let s: f64 = v[lo..=i].iter().map(|&x| (x as f64) * (x as f64)).sum();
        out.push((s / (i + 1 - lo) as f64).sqrt());
    }
    out
}

/// Detect events on one contiguous slice (convenience over the streaming
/// detector; splits at gaps larger than `max_step_s`).
pub fn detect_events(
    t_s: &[f64],
    v: &[f32],
    p: AeParams,
    max_step_s: f64,
) -> (Vec<AeEvent>, AeDetector) {
    let mut det = AeDetector::new(p);
    let mut out = Vec::new();
    let mut lo = 0;
    for g in gaps(t_s, None, max_step_s) {
        det.feed(&t_s[lo..g], &v[lo..g], &mut out);
        det.reset(&mut out);
        lo = g;
    }
    det.feed(&t_s[lo..], &v[lo..], &mut out);
    det.finish(&mut out);
    (out, det)
}

#[cfg(test)]
pub(crate) mod tests;

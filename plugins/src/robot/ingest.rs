//! `ingest`: touches from probe.parquet, or from the AE signal (docs/models.md
//! §1.2): stream ae.parquet through the envelope/event detector, map each
//! contact's time (+ `[ae].clock_offset_s`) to a position by interpolating
//! motion.parquet and to its face/point/trial through plan.parquet (the
//! motion `segment` active at that time is the plan's `seq`).
//!
//! Writes `touches` (probe.parquet's columns, plus `seq`, `dir_*`,
//! `prev_move_dir`, `source`), `contacts` (one row per AE event) and, when
//! both recorded and AE-derived touches exist, `touch_compare`.
//!
//! ingest/plan_motion.rs reads the plan and interpolates motion;
//! ingest/compare.rs compares both sources and writes `contacts`.

use std::collections::BTreeMap;
use std::path::Path;

use crate::robot::tables::PLAN;
use crate::robot::tables::PROBE;
use crate::Context;
use nalgebra::Vector3;
use serde_json::Value;
use sparkout_pipeline::config_check::{flags_to_table, read_section, Check, Section, SectionCheck};
use sparkout_pipeline::contracts::schema::{AE, MOTION};
use sparkout_pipeline::contracts::{AeKind, AeStream, BatchBuilder, Table, TimeOrigin};
use sparkout_pipeline::{
    InputError, Result, Stage, StageArgs, StageContext, StageOutput, StageSpec,
};

use super::ae::{gaps, AeDetector, AeEvent, AeParams, AeSettings, SignalKind};
use super::planes::Face;
use super::summary::{AeParamsSummary, AeSummary, ContactSummary, IngestStandalone, IngestSummary};
use super::touches::{self, Touch};

mod plan_motion;
pub use plan_motion::*;
mod compare;
use compare::*;
#[cfg(test)]
mod tests;

pub struct IngestStage;

/// `[robot.ingest]`: detector settings, in seconds. The lengths left out
/// are derived from the sample rate and the signal kind
/// ([`AeParams::derive`]), so one config serves a 250 Hz conditioned RMS
/// and a 1 MHz raw signal alike.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IngestConfig {
    /// `raw`, `rms`, or `auto`: run.toml's `[ae].kind` when it says, else a
    /// signal without a negative sample in its first batch is an RMS.
    pub signal: String,
    pub window_s: Option<f64>,
    pub k_sigma: f64,
    pub min_dwell_s: Option<f64>,
    pub hysteresis: f64,
    pub noise_window_s: Option<f64>,
    pub merge_gap_s: Option<f64>,
    /// How far (s) from an approach segment a contact may fall and still be
    /// assigned to it (the robot may already be stopping when AE fires);
    /// default max(5 ms, 2 sample periods): a 250 Hz onset is only known
    /// to a sample or two.
    pub segment_tolerance_s: Option<f64>,
}

impl Default for IngestConfig {
    fn default() -> Self {
        IngestConfig {
            signal: "auto".into(),
            window_s: None,
            k_sigma: 8.0,
            min_dwell_s: None,
            hysteresis: 0.5,
            noise_window_s: None,
            merge_gap_s: None,
            segment_tolerance_s: None,
        }
    }
}

impl Section for IngestConfig {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("signal", Check::OneOf(&["auto", "raw", "rms"])),
        ("window_s", Check::Positive),
        ("k_sigma", Check::Positive),
        ("min_dwell_s", Check::Positive),
        ("hysteresis", Check::Fraction),
        ("noise_window_s", Check::Positive),
        ("merge_gap_s", Check::NonNegative),
        ("segment_tolerance_s", Check::NonNegative),
    ];
}

/// Default segment tolerance floor, s.
const SEGMENT_TOLERANCE_S: f64 = 0.005;

impl IngestConfig {
    fn settings(&self) -> AeSettings {
        AeSettings {
            window_s: self.window_s,
            k_sigma: self.k_sigma,
            min_dwell_s: self.min_dwell_s,
            hysteresis: self.hysteresis,
            noise_window_s: self.noise_window_s,
            merge_gap_s: self.merge_gap_s,
        }
    }
    /// The signal kind the user asked for (`None`: auto).
    fn signal_kind(&self) -> Option<SignalKind> {
        match self.signal.as_str() {
            "raw" => Some(SignalKind::Raw),
            "rms" => Some(SignalKind::Rms),
            _ => None,
        }
    }
    fn segment_tolerance_s(&self, fs_hz: f64) -> f64 {
        self.segment_tolerance_s
            .unwrap_or_else(|| SEGMENT_TOLERANCE_S.max(2.0 / fs_hz))
    }
}

/// Where the signal kind came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KindSource {
    Config,
    RunToml,
    Guessed,
}

impl KindSource {
    fn label(self) -> &'static str {
        match self {
            KindSource::Config => "config",
            KindSource::RunToml => "run.toml",
            KindSource::Guessed => "guessed from the signal",
        }
    }
}

/// What the AE path found.
pub struct AeResult {
    pub events: Vec<AeEvent>,
    pub detector: AeDetector,
    pub samples: u64,
    pub blocks: usize,
    pub clock_offset_s: f64,
    pub fs_hz: f64,
    pub kind: SignalKind,
    pub kind_source: KindSource,
    /// The first negative sample of a signal read as an RMS: (file row,
    /// value). An RMS is never negative, so the log is probably raw.
    pub first_negative: Option<(usize, f32)>,
}

impl AeResult {
    /// The parameters in force, in samples and seconds (summaries, JSON).
    pub fn params_summary(&self) -> AeParamsSummary {
        let p = self.detector.params();
        let s = |n: usize| n as f64 / self.fs_hz;
        AeParamsSummary {
            signal: self.kind.label().into(),
            signal_from: self.kind_source.label().into(),
            sample_rate_hz: self.fs_hz,
            window_samples: p.window,
            window_s: s(p.window),
            min_dwell_samples: p.min_dwell,
            min_dwell_s: s(p.min_dwell),
            merge_gap_samples: p.merge_gap,
            merge_gap_s: s(p.merge_gap),
            noise_window_samples: p.noise_window,
            noise_window_s: s(p.noise_window),
            k_sigma: p.k_sigma,
            hysteresis: p.hysteresis,
        }
    }

    /// A signal read as an RMS that goes negative: the warning names the
    /// file, the column and the first such row.
    pub fn signal_warnings(&self, path: &Path, column: &str) -> Vec<String> {
        self.first_negative
            .map(|(row, v)| {
                InputError::new(
                    path,
                    format!(
                        "the signal is read as a conditioned RMS ({}) but this sample is negative ({v}): an RMS never is. If it is the raw sensor voltage, say --signal raw (or [ae].kind = \"raw\")",
                        self.kind_source.label()
                    ),
                )
                .column(column)
                .row(row)
                .to_string()
            })
            .into_iter()
            .collect()
    }

    /// Warnings that the contacts look fragmented: one contact broken into
    /// many. Two signs: (1) many would-be contacts shorter than the minimum
    /// dwell the defaults give at this rate — contacts kept only because a
    /// shorter dwell was set, plus dropped crossings away from any contact
    /// (a contact's own ripple as it starts and ends, merged into it, does
    /// not count) — at least as many as the contacts and at least 5; (2)
    /// with a plan, at least twice as many contacts as planned touches (and
    /// 3 more).
    pub fn fragmentation_warnings(&self, planned: Option<usize>) -> Vec<String> {
        let mut out = Vec::new();
        let p = self.detector.params();
        let default_dwell = AeParams::default_min_dwell(self.fs_hz);
        let floor_s = default_dwell as f64 / self.fs_hz;
        let n = self.events.len();
        let short_kept = self
            .events
            .iter()
            .filter(|e| ((e.end_index - e.onset_index) as usize) < default_dwell)
            .count();
        let stray = self.detector.stray_crossings() as usize;
        let short = short_kept + stray;
        if short >= n.max(5) {
            out.push(format!(
                "contacts look fragmented: {short} threshold crossings lasted less than {:.3} ms ({default_dwell} samples at {} Hz; {short_kept} kept as contacts with the minimum dwell of {} samples, {stray} dropped away from any contact) against {n} contacts. The envelope hovers about the threshold: check the signal kind (--signal raw|rms, now {}), and leave window_s, min_dwell_s, merge_gap_s and noise_window_s to their defaults or raise them",
                floor_s * 1e3,
                self.fs_hz,
                p.min_dwell,
                self.kind.label()
            ));
        }
        if let Some(k) = planned.filter(|&k| n >= 2 * k && n >= k + 3) {
            out.push(format!(
                "contacts look fragmented: {n} contacts for {k} planned touches. Check the signal kind (--signal raw|rms, now {}), min_dwell_s and merge_gap_s",
                self.kind.label()
            ));
        }
        out
    }
}

/// Stream a run's ae.parquet through the detector with bounded memory; a
/// run without any contact is an error that says what the detector saw.
pub fn detect_file(
    path: &Path,
    fs_hz: f64,
    run_kind: Option<AeKind>,
    cfg: &IngestConfig,
    clock_offset_s: f64,
    origin: &TimeOrigin,
) -> Result<AeResult> {
    let stream = AeStream::open_at(path, origin, AeStream::DEFAULT_BATCH_ROWS)?;
    // The user's setting, else what run.toml says, else a guess.
    let kind = match (cfg.signal_kind(), run_kind) {
        (Some(k), _) => Some((k, KindSource::Config)),
        (None, Some(AeKind::Raw)) => Some((SignalKind::Raw, KindSource::RunToml)),
        (None, Some(AeKind::Rms)) => Some((SignalKind::Rms, KindSource::RunToml)),
        (None, None) => None,
    };
    let r = detect_stream(stream, fs_hz, kind, cfg, clock_offset_s)?;
    if r.events.is_empty() {
        let p = r.detector.params();
        let (samples, blocks) = (r.samples, r.blocks);
        let envelope = match p.window {
            1 => format!("the {} signal itself", r.kind.label()),
            w => format!("RMS envelope over {:.3} ms", w as f64 / fs_hz * 1e3),
        };
        let msg = match r.detector.floors().first() {
            None => format!(
                "no contact found: no recording block was long enough to estimate the noise floor ({} samples of window + {} samples of noise window at {fs_hz} Hz; {samples} samples in {blocks} block(s))",
                p.window, p.noise_window
            ),
            Some(f) => format!(
                "no contact found in {samples} samples ({blocks} recording block(s)): noise floor ({envelope}) median {:.6e} V, σ (1.4826·MAD) {:.6e} V; threshold {:.6e} V (median + {}·σ) held for {:.3} ms; the largest envelope seen was {:.6e} V",
                f.centre_v,
                f.sigma_v,
                f.threshold_v,
                p.k_sigma,
                p.min_dwell as f64 / fs_hz * 1e3,
                r.detector.max_envelope_armed_v()
            ),
        };
        return Err(InputError::new(path, msg).column("ae_v").into());
    }
    Ok(r)
}

/// The detector over any validated signal stream (a gap in the time stamps
/// starts a new recording block with its own noise floor).
/// `kind` `None` guesses it from the first batch ([`SignalKind::guess`]).
pub fn detect_stream(
    stream: AeStream,
    fs_hz: f64,
    kind: Option<(SignalKind, KindSource)>,
    cfg: &IngestConfig,
    clock_offset_s: f64,
) -> Result<AeResult> {
    let max_step = 1.5 / fs_hz;
    let mut stream = stream.peekable();
    let (kind, kind_source) = match kind {
        Some(k) => k,
        None => {
            let first = match stream.peek() {
                Some(Ok(c)) => SignalKind::guess(&c.ae_v),
                _ => SignalKind::Raw,
            };
            (first, KindSource::Guessed)
        }
    };
    let p = AeParams::derive(fs_hz, kind, &cfg.settings());
    let mut det = AeDetector::new(p);
    let mut events = Vec::new();
    let mut prev_t: Option<f64> = None;
    let mut blocks = 1usize;
    let mut first_negative = None;
    for chunk in stream {
        let chunk = chunk?;
        if kind == SignalKind::Rms && first_negative.is_none() {
            first_negative = chunk
                .ae_v
                .iter()
                .position(|&x| x < 0.0)
                .map(|i| (chunk.first_row + i, chunk.ae_v[i]));
        }
        let mut lo = 0;
        // The decoder measured the chunk's largest step while validating
        // it: without a gap inside, only the step from the previous chunk
        // is left to check (the scan was 4 % of ingest, on this thread).
        let inner = if chunk.max_step_s > max_step {
            &chunk.t_s[..]
        } else {
            &chunk.t_s[..chunk.t_s.len().min(1)]
        };
        for g in gaps(inner, prev_t, max_step) {
            det.feed(&chunk.t_s[lo..g], &chunk.ae_v[lo..g], &mut events);
            det.reset(&mut events);
            blocks += 1;
            lo = g;
        }
        det.feed(&chunk.t_s[lo..], &chunk.ae_v[lo..], &mut events);
        prev_t = chunk.t_s.last().copied().or(prev_t);
    }
    det.finish(&mut events);
    let samples = det.samples_seen();
    Ok(AeResult {
        events,
        detector: det,
        samples,
        blocks,
        clock_offset_s,
        fs_hz,
        kind,
        kind_source,
        first_negative,
    })
}

/// `sparkout stage ingest --ae FILE --sample-rate-hz F [--column C]
/// [--signal raw|rms|auto --window-s S --k-sigma K --min-dwell-s S
/// --hysteresis H --noise-window-s S --merge-gap-s S] --json`: contact
/// events of any signal column (default `ae_v`) of any Parquet file, time
/// from its `t_s` column or from the sample rate. No contact is an empty
/// list, not an error; the parameters in force and any fragmentation
/// warning are printed beside them.
fn standalone(args: &StageArgs) -> Result<Value> {
    const INPUTS: [&str; 3] = ["ae", "sample-rate-hz", "column"];
    let path = Path::new(args.get("ae").ok_or_else(|| {
        crate::err!(
            "stage ingest: give --run DIR, or --ae FILE.parquet --sample-rate-hz F [--column ae_v]"
        )
    })?);
    let fs_hz = args
        .get("sample-rate-hz")
        .ok_or_else(|| crate::err!("stage ingest --ae: --sample-rate-hz F is required"))?
        .parse::<f64>()
        .ok()
        .filter(|f| f.is_finite() && *f > 0.0)
        .ok_or_else(|| crate::err!("stage ingest: --sample-rate-hz must be a number > 0"))?;
    let column = args.get("column").map(|s| s.as_str()).unwrap_or("ae_v");
    let t = flags_to_table(args, &INPUTS);
    let cfg: IngestConfig = read_section(&t).map_err(|e| {
        crate::err!("stage ingest: flag {e} (flags: --ae, --sample-rate-hz, --column and the detector keys with dashes)")
    })?;
    let kind = cfg.signal_kind().map(|k| (k, KindSource::Config));
    let r = detect_stream(
        AeStream::open_series(path, column, fs_hz)?,
        fs_hz,
        kind,
        &cfg,
        0.0,
    )?;
    let contacts: Vec<ContactSummary> = r
        .events
        .iter()
        .map(|e| ContactSummary {
            start_s: e.onset_t_s,
            end_s: e.end_t_s,
            peak: e.peak_v,
        })
        .collect();
    let mut warnings = r.signal_warnings(path, column);
    warnings.extend(r.fragmentation_warnings(None));
    for w in &warnings {
        tracing::warn!("{}: {w}", path.display());
    }
    Ok(serde_json::to_value(IngestStandalone {
        contacts,
        threshold: r.detector.floors().first().map(|f| f.threshold_v),
        params: r.params_summary(),
        warnings,
    })?)
}

/// Role of each AE event.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    Touch,
    Extra,
    Unassigned,
}

impl Role {
    fn label(self) -> &'static str {
        match self {
            Role::Touch => "touch",
            Role::Extra => "extra",
            Role::Unassigned => "unassigned",
        }
    }
}

/// The AE path's touches, detector result and each event's (seq, role).
type AePath = (Vec<Touch>, AeResult, Vec<(i32, Role)>);

/// AE-derived touches, each event's (seq, role), and the plan rows missed.
type AeTouches = (Vec<Touch>, Vec<(i32, Role)>, Vec<i32>);

/// AE events → touches (first event of each approach segment).
fn ae_touches(
    r: &AeResult,
    motion: &Motion,
    plan: &[PlanRow],
    tol: f64,
    ae_path: &Path,
) -> Result<AeTouches> {
    let by_seq: BTreeMap<i32, &PlanRow> = plan.iter().map(|p| (p.seq, p)).collect();
    let mut taken: BTreeMap<i32, usize> = BTreeMap::new();
    let mut roles = Vec::with_capacity(r.events.len());
    let mut out = Vec::new();
    for e in &r.events {
        let tc = e.onset_t_s + r.clock_offset_s;
        let Some(p) = motion.position_at(tc) else {
            let (a, b) = motion.span_s();
            return Err(InputError::new(
                &motion.path,
                format!(
                    "the motion log ({a} s to {b} s) does not cover the contact at controller time {tc} s (AE t_s {} s + clock offset {} s, ae.parquet row {} of {})",
                    e.onset_t_s,
                    r.clock_offset_s,
                    e.onset_index,
                    ae_path.display()
                ),
            )
            .column("t_s")
            .into());
        };
        let seg = motion.segment_at(tc, tol);
        match seg.and_then(|s| by_seq.get(&s).map(|row| (s, *row))) {
            None => roles.push((seg.unwrap_or(-1), Role::Unassigned)),
            Some((s, row)) => {
                if taken.contains_key(&s) {
                    roles.push((s, Role::Extra));
                    continue;
                }
                taken.insert(s, out.len());
                roles.push((s, Role::Touch));
                out.push(Touch {
                    t_s: tc,
                    face: row.face,
                    point: row.point,
                    trial: row.trial,
                    method: row.method.clone(),
                    approach_mm_s: row.approach_mm_s,
                    nom: row.nom,
                    p,
                    seq: s,
                    dir: row.dir,
                    prev_move_dir: motion.prev_move_sign(s, row.face.normal_axis()),
                    source: "ae".into(),
                });
            }
        }
    }
    let missed: Vec<i32> = plan
        .iter()
        .map(|p| p.seq)
        .filter(|s| !taken.contains_key(s) && motion.segment_span_s(*s).is_some())
        .collect();
    Ok((out, roles, missed))
}

/// probe.parquet → touches, matched to plan rows when there is a plan.
fn probe_touches(
    t: &Table,
    plan: Option<&[PlanRow]>,
    motion: Option<&Motion>,
    machine: &sparkout_pipeline::contracts::MachineConfig,
) -> Result<Vec<Touch>> {
    let ts = t.f64("t_s")?;
    let c = PointColumns::read(t)?;
    let (x, y, z) = (t.f64("x_mm")?, t.f64("y_mm")?, t.f64("z_mm")?);
    type Key = (Face, i32, i32, String, u64);
    let key = |f: Face, p: i32, tr: i32, m: &str, v: f64| -> Key {
        (f, p, tr, m.to_string(), v.to_bits())
    };
    let plan_by_key: BTreeMap<Key, &PlanRow> = plan
        .unwrap_or(&[])
        .iter()
        .map(|r| (key(r.face, r.point, r.trial, &r.method, r.approach_mm_s), r))
        .collect();
    let mut out = Vec::with_capacity(t.len());
    for i in 0..t.len() {
        let f = c.face[i];
        let row = plan_by_key.get(&key(
            f,
            c.point[i],
            c.trial[i],
            c.method[i],
            c.approach_mm_s[i],
        ));
        let (seq, dir) = match row {
            Some(r) => (r.seq, r.dir),
            None => (-1, default_dir(machine, f)),
        };
        let prev = match (motion, seq) {
            (Some(m), s) if s >= 0 => m.prev_move_sign(s, f.normal_axis()),
            _ => None,
        };
        out.push(Touch {
            t_s: ts[i],
            face: f,
            point: c.point[i],
            trial: c.trial[i],
            method: c.method[i].to_string(),
            approach_mm_s: c.approach_mm_s[i],
            nom: c.nom(i),
            p: Vector3::new(x[i], y[i], z[i]),
            seq,
            dir,
            prev_move_dir: prev,
            source: "probe".into(),
        });
    }
    Ok(out)
}

const SPEC: StageSpec = StageSpec {
    name: "ingest",
    // 2: noise floor from median/MAD, lengths derived from the sample
    // rate and signal kind, merge gap (contacts may move by a sample).
    version: 2,
    reads: &[&PROBE, &AE, &MOTION, &PLAN],
    reads_artifacts: &[],
    writes: &["touches", "contacts", "touch_compare"],
    reads_augmented_model: false,
    about: "touches from probe.parquet or from AE contacts mapped through motion + plan (docs/models.md §1.2)",
    config: SectionCheck::of::<IngestConfig>(),
};

impl Stage for IngestStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run_standalone(&self, args: &StageArgs) -> Option<Result<Value>> {
        Some(standalone(args))
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let run = ctx.run;
        let cfg = ctx.section::<IngestConfig>()?;
        let plan = match run.table(&PLAN)? {
            Some(t) => Some(read_plan(&t)?),
            None => None,
        };
        let motion = match run.table(&MOTION)? {
            Some(t) => Some(Motion::from_table(&t)?),
            None => None,
        };
        let probe = run.table(&PROBE)?;
        let has_ae = run.has_table(&AE);

        // The AE path: whenever the signal, the motion log and the plan are
        // all there (for the touches, or to check the recorded ones).
        let mut ae_summary: Option<AeSummary> = None;
        let mut ae_out: Option<AePath> = None;
        if let (true, Some(motion), Some(plan)) = (has_ae, motion.as_ref(), plan.as_ref()) {
            let ae_path = run.table_path(&AE);
            let spec = run.spec.ae.as_ref().ok_or_else(|| {
                InputError::new(
                    run.spec.run_toml_path(),
                    "ae.parquet is present but run.toml has no [ae] table with sample_rate_hz (docs/formats.md)",
                )
                .column("ae.sample_rate_hz")
            })?;
            if !motion.has_segments() {
                return Err(InputError::new(
                    run.table_path(&MOTION),
                    "motion.parquet has no `segment` column: AE contacts cannot be matched to plan rows",
                )
                .column("segment")
                .into());
            }
            let r = detect_file(
                &ae_path,
                spec.sample_rate_hz,
                spec.kind_given.then_some(spec.kind),
                cfg,
                spec.clock_offset_s,
                &run.spec.time_origin(),
            )
            .context("AE contact detection")?;
            let tol = cfg.segment_tolerance_s(spec.sample_rate_hz);
            let (touches, roles, missed) = ae_touches(&r, motion, plan, tol, &ae_path)?;
            // Planned touches the recorder could see: rows the motion log
            // approaches (what `missed` is counted against).
            let planned = plan
                .iter()
                .filter(|p| motion.segment_span_s(p.seq).is_some())
                .count();
            let mut warnings = r.signal_warnings(&ae_path, "ae_v");
            warnings.extend(r.fragmentation_warnings(Some(planned)));
            for w in &warnings {
                tracing::warn!("{}: {w}", ae_path.display());
            }
            let f0 = r.detector.floors()[0];
            let count = |role: Role| roles.iter().filter(|x| x.1 == role).count();
            ae_summary = Some(AeSummary {
                samples: r.samples,
                recording_blocks: r.blocks,
                window_samples: r.detector.params().window,
                params: r.params_summary(),
                events: r.events.len(),
                short_crossings: r.detector.short_crossings(),
                stray_crossings: r.detector.stray_crossings(),
                warnings,
                touches: count(Role::Touch),
                extra_events: count(Role::Extra),
                unassigned_events: count(Role::Unassigned),
                missed_seq: missed.iter().take(100).copied().collect(),
                n_missed: missed.len(),
                noise_floor_v: f0.centre_v,
                noise_sigma_v: f0.sigma_v,
                threshold_v: f0.threshold_v,
                k_sigma: cfg.k_sigma,
                clock_offset_s: r.clock_offset_s,
                positions: if motion.measured { "act" } else { "cmd" }.into(),
            });
            ae_out = Some((touches, r, roles));
        }

        let (touches, source, compare_out) = match (probe, ae_out.as_ref()) {
            (Some(p), ae) => {
                let t = probe_touches(&p, plan.as_deref(), motion.as_ref(), &run.machine)?;
                let cmp = ae.and_then(|(a, _, _)| compare(&t, a));
                (t, "probe", cmp)
            }
            (None, Some((a, _, _))) => (a.clone(), "ae", None),
            (None, None) => {
                return Err(InputError::new(
                    run.dir(),
                    "the robot plugin needs probe.parquet, or ae.parquet + motion.parquet + plan.parquet (docs/formats.md)",
                )
                .into())
            }
        };
        let mut touches = touches;
        touches.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
        if touches.is_empty() {
            return Err(InputError::new(
                run.dir(),
                "no touches: nothing was registered or detected",
            )
            .into());
        }
        let mut per_face = BTreeMap::new();
        for t in &touches {
            *per_face.entry(t.face.label().to_string()).or_insert(0usize) += 1;
        }
        let summary = IngestSummary {
            touch_source: source.into(),
            n_touches: touches.len(),
            per_face,
            ae: ae_summary,
            compare: compare_out.as_ref().map(|c| c.1.clone()),
        };
        let contacts = match &ae_out {
            Some((_, r, roles)) => contacts_batch(r, roles),
            None => empty_contacts(),
        };
        let mut out = StageOutput::typed(&summary)?
            .with("touches", touches::to_batch(&touches))
            .with("contacts", contacts);
        if let Some((b, _)) = compare_out {
            out = out.with("touch_compare", b);
        }
        Ok(out)
    }
}

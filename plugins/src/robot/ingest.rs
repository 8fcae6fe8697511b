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

use anyhow::Context;
use nalgebra::Vector3;
use serde_json::{json, Value};
use sparkout_pipeline::config_check::{flags_to_table, read_section, Check, Section, SectionCheck};
use sparkout_pipeline::contracts::schema::{AE, MOTION, PLAN, PROBE};
use sparkout_pipeline::contracts::{AeKind, AeStream, BatchBuilder, Table, TimeOrigin};
use sparkout_pipeline::{
    InputError, Result, Stage, StageArgs, StageContext, StageOutput, StageSpec,
};

use super::ae::{gaps, AeDetector, AeEvent, AeParams};
use super::planes::Face;
use super::touches::{self, Touch};

mod plan_motion;
pub use plan_motion::*;
mod compare;
use compare::*;

pub struct IngestStage;

/// `[robot.ingest]`: detector settings, in seconds (docs/models.md §1.2).
#[derive(Debug, Clone, Copy, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IngestConfig {
    pub window_s: f64,
    pub k_sigma: f64,
    pub min_dwell_s: f64,
    pub hysteresis: f64,
    pub noise_window_s: f64,
    /// How far (s) from an approach segment a contact may fall and still be
    /// assigned to it (the robot may already be stopping when AE fires).
    pub segment_tolerance_s: f64,
}

impl Default for IngestConfig {
    fn default() -> Self {
        IngestConfig {
            window_s: 0.001,
            k_sigma: 8.0,
            min_dwell_s: 0.0005,
            hysteresis: 0.5,
            noise_window_s: 0.005,
            segment_tolerance_s: 0.005,
        }
    }
}

impl Section for IngestConfig {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("window_s", Check::Positive),
        ("k_sigma", Check::Positive),
        ("min_dwell_s", Check::Positive),
        ("hysteresis", Check::Fraction),
        ("noise_window_s", Check::Positive),
        ("segment_tolerance_s", Check::NonNegative),
    ];
}

/// What the AE path found.
pub struct AeResult {
    pub events: Vec<AeEvent>,
    pub detector: AeDetector,
    pub samples: u64,
    pub blocks: usize,
    pub clock_offset_s: f64,
}

/// Stream a run's ae.parquet through the detector with bounded memory; a
/// run without any contact is an error that says what the detector saw.
pub fn detect_file(
    path: &Path,
    fs_hz: f64,
    kind: AeKind,
    cfg: &IngestConfig,
    clock_offset_s: f64,
    origin: &TimeOrigin,
) -> Result<AeResult> {
    // An RMS log (kind = "rms") goes through the same envelope: the RMS of
    // an RMS signal over a short window is a smoothed RMS.
    let _ = kind;
    let stream = AeStream::open_at(path, origin, AeStream::DEFAULT_BATCH_ROWS)?;
    let r = detect_stream(stream, fs_hz, cfg, clock_offset_s)?;
    if r.events.is_empty() {
        let p = r.detector.params();
        let (samples, blocks) = (r.samples, r.blocks);
        let msg = match r.detector.floors().first() {
            None => format!(
                "no contact found: no recording block was long enough to estimate the noise floor ({} samples of window + {} samples of noise window at {fs_hz} Hz; {samples} samples in {blocks} block(s))",
                p.window, p.noise_window
            ),
            Some(f) => format!(
                "no contact found in {samples} samples ({blocks} recording block(s)): noise floor (RMS envelope over {:.3} ms) mean {:.6e} V, σ {:.6e} V; threshold {:.6e} V (mean + {}·σ) held for {:.3} ms; the largest envelope seen was {:.6e} V",
                cfg.window_s * 1e3,
                f.mean_v,
                f.sigma_v,
                f.threshold_v,
                cfg.k_sigma,
                cfg.min_dwell_s * 1e3,
                r.detector.max_envelope_armed_v()
            ),
        };
        return Err(InputError::new(path, msg).column("ae_v").into());
    }
    Ok(r)
}

/// The detector over any validated signal stream (a gap in the time stamps
/// starts a new recording block with its own noise floor).
pub fn detect_stream(
    stream: AeStream,
    fs_hz: f64,
    cfg: &IngestConfig,
    clock_offset_s: f64,
) -> Result<AeResult> {
    let p = AeParams::from_seconds(
        fs_hz,
        cfg.window_s,
        cfg.k_sigma,
        cfg.min_dwell_s,
        cfg.hysteresis,
        cfg.noise_window_s,
    );
    let max_step = 1.5 / fs_hz;
    let mut det = AeDetector::new(p);
    let mut events = Vec::new();
    let mut prev_t: Option<f64> = None;
    let mut blocks = 1usize;
    for chunk in stream {
        let chunk = chunk?;
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
    })
}

/// `sparkout stage ingest --ae FILE --sample-rate-hz F [--column C]
/// [--window-s S --k-sigma K --min-dwell-s S --hysteresis H
/// --noise-window-s S] --json`: contact events of any signal column
/// (default `ae_v`) of any Parquet file, time from its `t_s` column or
/// from the sample rate. No contact is an empty list, not an error.
fn standalone(args: &StageArgs) -> Result<Value> {
    const INPUTS: [&str; 3] = ["ae", "sample-rate-hz", "column"];
    let path = Path::new(args.get("ae").ok_or_else(|| {
        anyhow::anyhow!(
            "stage ingest: give --run DIR, or --ae FILE.parquet --sample-rate-hz F [--column ae_v]"
        )
    })?);
    let fs_hz = args
        .get("sample-rate-hz")
        .ok_or_else(|| anyhow::anyhow!("stage ingest --ae: --sample-rate-hz F is required"))?
        .parse::<f64>()
        .ok()
        .filter(|f| f.is_finite() && *f > 0.0)
        .ok_or_else(|| anyhow::anyhow!("stage ingest: --sample-rate-hz must be a number > 0"))?;
    let column = args.get("column").map(|s| s.as_str()).unwrap_or("ae_v");
    let t = flags_to_table(args, &INPUTS);
    let cfg: IngestConfig = read_section(&t).map_err(|e| {
        anyhow::anyhow!("stage ingest: flag {e} (flags: --ae, --sample-rate-hz, --column and the detector keys with dashes)")
    })?;
    let r = detect_stream(
        AeStream::open_series(path, column, fs_hz)?,
        fs_hz,
        &cfg,
        0.0,
    )?;
    let contacts: Vec<Value> = r
        .events
        .iter()
        .map(|e| json!({"start_s": e.onset_t_s, "end_s": e.end_t_s, "peak": e.peak_v}))
        .collect();
    Ok(json!({
        "contacts": contacts,
        "threshold": r.detector.floors().first().map(|f| f.threshold_v),
    }))
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
    version: 1,
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
        let mut ae_summary = Value::Null;
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
                spec.kind,
                &cfg,
                spec.clock_offset_s,
                &run.spec.time_origin(),
            )
            .context("AE contact detection")?;
            let (touches, roles, missed) =
                ae_touches(&r, motion, plan, cfg.segment_tolerance_s, &ae_path)?;
            let f0 = r.detector.floors()[0];
            let count = |role: Role| roles.iter().filter(|x| x.1 == role).count();
            ae_summary = json!({
                "samples": r.samples,
                "recording_blocks": r.blocks,
                "window_samples": r.detector.params().window,
                "events": r.events.len(),
                "touches": count(Role::Touch),
                "extra_events": count(Role::Extra),
                "unassigned_events": count(Role::Unassigned),
                "missed_seq": missed.iter().take(100).collect::<Vec<_>>(),
                "n_missed": missed.len(),
                "noise_floor_v": f0.mean_v,
                "noise_sigma_v": f0.sigma_v,
                "threshold_v": f0.threshold_v,
                "k_sigma": cfg.k_sigma,
                "clock_offset_s": r.clock_offset_s,
                "positions": if motion.measured { "act" } else { "cmd" },
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
            *per_face.entry(t.face.label()).or_insert(0usize) += 1;
        }
        let summary = json!({
            "touch_source": source,
            "n_touches": touches.len(),
            "per_face": per_face,
            "ae": ae_summary,
            "compare": compare_out.as_ref().map(|c| c.1.clone()).unwrap_or(Value::Null),
        });
        let contacts = match &ae_out {
            Some((_, r, roles)) => contacts_batch(r, roles),
            None => empty_contacts(),
        };
        let mut out = StageOutput::new(summary)
            .with("touches", touches::to_batch(&touches))
            .with("contacts", contacts);
        if let Some((b, _)) = compare_out {
            out = out.with("touch_compare", b);
        }
        Ok(out)
    }
}

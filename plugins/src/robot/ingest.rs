//! `ingest`: touches from probe.parquet, or from the AE signal (MODELS.md
//! §1.2): stream ae.parquet through the envelope/event detector, map each
//! contact's time (+ `[ae].clock_offset_s`) to a position by interpolating
//! motion.parquet and to its face/point/trial through plan.parquet (the
//! motion `segment` active at that time is the plan's `seq`).
//!
//! Writes `touches` (probe.parquet's columns, plus `seq`, `dir_*`,
//! `prev_move_dir`, `source`), `contacts` (one row per AE event) and, when
//! both recorded and AE-derived touches exist, `touch_compare`.
//!
//! Length (over 700 lines): both touch sources (probe.parquet, and the AE
//! chain: plan, motion interpolation, contact detection, the comparison of
//! the two) map to the same `Touch`; `Motion` and `compare` are the next
//! candidates for their own files.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Context;
use nalgebra::Vector3;
use serde_json::{json, Value};
use sparkout_pipeline::contracts::schema::{AE, MOTION, PLAN, PROBE};
use sparkout_pipeline::contracts::{AeKind, AeStream, BatchBuilder, Table};
use sparkout_pipeline::{InputError, Result, Stage, StageContext, StageOutput, StageSpec};

use super::ae::{gaps, AeDetector, AeEvent, AeParams};
use super::config::{check_config, Check};
use super::planes::Face;
use super::touches::{self, Touch};

pub struct IngestStage;

const KEYS: &[(&str, Check)] = &[
    ("window_s", Check::Positive),
    ("k_sigma", Check::Positive),
    ("min_dwell_s", Check::Positive),
    ("hysteresis", Check::Fraction),
    ("noise_window_s", Check::Positive),
    ("segment_tolerance_s", Check::NonNegative),
];

/// Detector settings of a stage config, in seconds (MODELS.md §1.2).
#[derive(Debug, Clone, Copy)]
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

impl IngestConfig {
    pub fn from_ctx(ctx: &StageContext) -> IngestConfig {
        IngestConfig {
            window_s: ctx.cfg_f64("window_s", 0.001),
            k_sigma: ctx.cfg_f64("k_sigma", 8.0),
            min_dwell_s: ctx.cfg_f64("min_dwell_s", 0.0005),
            hysteresis: ctx.cfg_f64("hysteresis", 0.5),
            noise_window_s: ctx.cfg_f64("noise_window_s", 0.005),
            segment_tolerance_s: ctx.cfg_f64("segment_tolerance_s", 0.005),
        }
    }
}

/// One plan row.
#[derive(Debug, Clone)]
pub struct PlanRow {
    pub seq: i32,
    pub face: Face,
    pub point: i32,
    pub trial: i32,
    pub method: String,
    pub approach_mm_s: f64,
    pub nom: Vector3<f64>,
    pub dir: Vector3<f64>,
}

fn unknown_face(path: &Path, label: &str, row: usize) -> InputError {
    InputError::new(
        path,
        format!(
            "unknown face label `{label}` (expected xy, yz or zx: the faces with normal Z, X, Y)"
        ),
    )
    .column("face")
    .row(row)
}

pub fn read_plan(t: &Table) -> Result<Vec<PlanRow>> {
    let path = t.path();
    let seq = t.i32("seq")?;
    let face = t.str("face")?;
    let point = t.i32("point")?;
    let trial = t.i32("trial")?;
    let method = t.str("method")?;
    let v = t.f64("approach_mm_s")?;
    let (nx, ny, nz) = (t.f64("nom_x_mm")?, t.f64("nom_y_mm")?, t.f64("nom_z_mm")?);
    let (dx, dy, dz) = (t.f64("dir_x")?, t.f64("dir_y")?, t.f64("dir_z")?);
    let mut out = Vec::with_capacity(t.len());
    let mut seen = BTreeMap::new();
    for i in 0..t.len() {
        let f = Face::parse(face[i]).ok_or_else(|| unknown_face(path, face[i], i))?;
        let d = Vector3::new(dx[i], dy[i], dz[i]);
        let n = d.norm();
        if !(n > 1e-9) {
            return Err(InputError::new(path, "approach direction is zero")
                .column("dir_x")
                .row(i)
                .into());
        }
        if let Some(prev) = seen.insert(seq[i], i) {
            return Err(InputError::new(
                path,
                format!("seq {} appears twice (rows {prev} and {i})", seq[i]),
            )
            .column("seq")
            .row(i)
            .into());
        }
        out.push(PlanRow {
            seq: seq[i],
            face: f,
            point: point[i],
            trial: trial[i],
            method: method[i].to_string(),
            approach_mm_s: v[i],
            nom: Vector3::new(nx[i], ny[i], nz[i]),
            dir: d / n,
        });
    }
    Ok(out)
}

/// The machine's default approach direction of a face (when no plan says):
/// `[probing].approach_dir_<face>` in the machine config, else −normal axis
/// (the block below/behind the face).
pub fn default_dir(
    machine: &sparkout_pipeline::contracts::MachineConfig,
    face: Face,
) -> Vector3<f64> {
    let key = format!("probing.approach_dir_{}", face.label());
    if let Some(a) = machine.get(&key).and_then(|v| v.as_array()) {
        let v: Vec<f64> = a
            .iter()
            .filter_map(|x| x.as_float().or_else(|| x.as_integer().map(|i| i as f64)))
            .collect();
        if v.len() == 3 {
            let d = Vector3::new(v[0], v[1], v[2]);
            if d.norm() > 0.0 {
                return d.normalize();
            }
        }
    }
    let mut d = Vector3::zeros();
    d[face.normal_axis()] = -1.0;
    d
}

/// The motion log as the AE mapping needs it.
pub struct Motion {
    path: std::path::PathBuf,
    t: Vec<f64>,
    pos: [Vec<f64>; 3],
    cmd: [Vec<f64>; 3],
    segment: Option<Vec<i32>>,
    /// First sample index of each segment value ≥ 0.
    seg_first: BTreeMap<i32, usize>,
    /// Index range of each segment value ≥ 0 (first, last).
    seg_span: BTreeMap<i32, (usize, usize)>,
    /// Whether positions are measured (`act_*`) rather than commanded.
    pub measured: bool,
}

impl Motion {
    pub fn from_table(t: &Table) -> Result<Motion> {
        let ts = t.f64("t_s")?.to_vec();
        let cmd = [
            t.f64("cmd_x_mm")?.to_vec(),
            t.f64("cmd_y_mm")?.to_vec(),
            t.f64("cmd_z_mm")?.to_vec(),
        ];
        let has_act = ["act_x_mm", "act_y_mm", "act_z_mm"].iter().all(|c| {
            t.has(c)
                && t.batch()
                    .column_by_name(c)
                    .is_some_and(|a| a.null_count() == 0)
        });
        let pos = if has_act {
            let v = [t.f64("act_x_mm")?, t.f64("act_y_mm")?, t.f64("act_z_mm")?];
            for (k, c) in v.iter().enumerate() {
                if let Some(i) = c.iter().position(|x| !x.is_finite()) {
                    return Err(InputError::new(t.path(), "NaN or infinite position")
                        .column(["act_x_mm", "act_y_mm", "act_z_mm"][k])
                        .row(i)
                        .into());
                }
            }
            [v[0].to_vec(), v[1].to_vec(), v[2].to_vec()]
        } else {
            cmd.clone()
        };
        let segment = t.opt_i32("segment").map(|s| s.to_vec());
        let mut seg_first = BTreeMap::new();
        let mut seg_span = BTreeMap::new();
        if let Some(s) = &segment {
            for (i, &v) in s.iter().enumerate() {
                if v >= 0 {
                    seg_first.entry(v).or_insert(i);
                    seg_span
                        .entry(v)
                        .and_modify(|e: &mut (usize, usize)| e.1 = i)
                        .or_insert((i, i));
                }
            }
        }
        Ok(Motion {
            path: t.path().to_path_buf(),
            t: ts,
            pos,
            cmd,
            segment,
            seg_first,
            seg_span,
            measured: has_act,
        })
    }

    pub fn has_segments(&self) -> bool {
        self.segment.is_some()
    }

    pub fn span_s(&self) -> (f64, f64) {
        (self.t[0], self.t[self.t.len() - 1])
    }

    /// Linear interpolation of the TCP position at controller time `t`;
    /// `None` outside the log.
    pub fn position_at(&self, t: f64) -> Option<Vector3<f64>> {
        let n = self.t.len();
        if !(t >= self.t[0] && t <= self.t[n - 1]) {
            return None;
        }
        let j = self.t.partition_point(|&x| x <= t).clamp(1, n - 1);
        let (t0, t1) = (self.t[j - 1], self.t[j]);
        let w = if t1 > t0 { (t - t0) / (t1 - t0) } else { 0.0 };
        let at = |k: usize| self.pos[k][j - 1] + w * (self.pos[k][j] - self.pos[k][j - 1]);
        Some(Vector3::new(at(0), at(1), at(2)))
    }

    /// The plan `seq` being approached at time `t`: the segment of the last
    /// sample at or before `t`; when that is −1 (the robot already stopping
    /// or retracting), the segment whose samples lie within `tol` of `t`.
    pub fn segment_at(&self, t: f64, tol: f64) -> Option<i32> {
        let seg = self.segment.as_ref()?;
        let j = self.t.partition_point(|&x| x <= t);
        if j > 0 && seg[j - 1] >= 0 {
            return Some(seg[j - 1]);
        }
        let mut best: Option<(f64, i32)> = None;
        let lo = self.t.partition_point(|&x| x < t - tol);
        let hi = self.t.partition_point(|&x| x <= t + tol);
        for (ti, &s) in self.t[lo..hi].iter().zip(&seg[lo..hi]) {
            if s >= 0 {
                let d = (ti - t).abs();
                if best.is_none_or(|b| d < b.0) {
                    best = Some((d, s));
                }
            }
        }
        best.map(|b| b.1)
    }

    /// Sign (±1) of the last commanded move along `axis` before segment
    /// `seq` began (for backlash: the direction the axis was last driven).
    pub fn prev_move_sign(&self, seq: i32, axis: usize) -> Option<f64> {
        let first = *self.seg_first.get(&seq)?;
        let c = &self.cmd[axis];
        let mut i = first;
        while i > 0 {
            let d = c[i] - c[i - 1];
            if d.abs() > 1e-9 {
                return Some(d.signum());
            }
            i -= 1;
        }
        None
    }

    /// Time span of a segment.
    pub fn segment_span_s(&self, seq: i32) -> Option<(f64, f64)> {
        self.seg_span
            .get(&seq)
            .map(|&(a, b)| (self.t[a], self.t[b]))
    }
}

/// What the AE path found.
pub struct AeResult {
    pub events: Vec<AeEvent>,
    pub detector: AeDetector,
    pub samples: u64,
    pub blocks: usize,
    pub clock_offset_s: f64,
}

/// Stream ae.parquet through the detector with bounded memory.
pub fn detect_file(
    path: &Path,
    fs_hz: f64,
    kind: AeKind,
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
    // An RMS log (kind = "rms") goes through the same envelope: the RMS of
    // an RMS signal over a short window is a smoothed RMS.
    let _ = kind;
    let max_step = 1.5 / fs_hz;
    let mut det = AeDetector::new(p);
    let mut events = Vec::new();
    let mut prev_t: Option<f64> = None;
    let mut blocks = 1usize;
    for chunk in AeStream::open(path)? {
        let chunk = chunk?;
        let mut lo = 0;
        for g in gaps(&chunk.t_s, prev_t, max_step) {
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
    if events.is_empty() {
        let msg = match det.floors().first() {
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
                det.max_envelope_armed_v()
            ),
        };
        return Err(InputError::new(path, msg).column("ae_v").into());
    }
    Ok(AeResult {
        events,
        detector: det,
        samples,
        blocks,
        clock_offset_s,
    })
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
    let path = t.path();
    let ts = t.f64("t_s")?;
    let face = t.str("face")?;
    let point = t.i32("point")?;
    let trial = t.i32("trial")?;
    let method = t.str("method")?;
    let v = t.f64("approach_mm_s")?;
    let (nx, ny, nz) = (t.f64("nom_x_mm")?, t.f64("nom_y_mm")?, t.f64("nom_z_mm")?);
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
        let f = Face::parse(face[i]).ok_or_else(|| unknown_face(path, face[i], i))?;
        let row = plan_by_key.get(&key(f, point[i], trial[i], method[i], v[i]));
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
            point: point[i],
            trial: trial[i],
            method: method[i].to_string(),
            approach_mm_s: v[i],
            nom: Vector3::new(nx[i], ny[i], nz[i]),
            p: Vector3::new(x[i], y[i], z[i]),
            seq,
            dir,
            prev_move_dir: prev,
            source: "probe".into(),
        });
    }
    Ok(out)
}

/// Recorded vs AE-derived touches of the same plan row.
fn compare(probe: &[Touch], ae: &[Touch]) -> Option<(arrow::record_batch::RecordBatch, Value)> {
    let ae_by_seq: BTreeMap<i32, &Touch> = ae.iter().map(|t| (t.seq, t)).collect();
    let pairs: Vec<(&Touch, &Touch)> = probe
        .iter()
        .filter(|p| p.seq >= 0)
        .filter_map(|p| ae_by_seq.get(&p.seq).map(|a| (p, *a)))
        .collect();
    if pairs.is_empty() {
        return None;
    }
    let d: Vec<Vector3<f64>> = pairs.iter().map(|(p, a)| p.p - a.p).collect();
    let dn: Vec<f64> = pairs.iter().map(|(p, a)| p.normal() - a.normal()).collect();
    let dt: Vec<f64> = pairs.iter().map(|(p, a)| p.t_s - a.t_s).collect();
    let dist: Vec<f64> = d.iter().map(|v| v.norm()).collect();
    let batch = BatchBuilder::new()
        .i32("seq", pairs.iter().map(|(p, _)| p.seq).collect())
        .str(
            "face",
            &pairs
                .iter()
                .map(|(p, _)| p.face.label())
                .collect::<Vec<_>>(),
        )
        .i32("point", pairs.iter().map(|(p, _)| p.point).collect())
        .i32("trial", pairs.iter().map(|(p, _)| p.trial).collect())
        .str(
            "method",
            &pairs
                .iter()
                .map(|(p, _)| p.method.as_str())
                .collect::<Vec<_>>(),
        )
        .f64(
            "approach_mm_s",
            pairs.iter().map(|(p, _)| p.approach_mm_s).collect(),
        )
        .f64("dt_s", dt.clone())
        .f64("dx_mm", d.iter().map(|v| v.x).collect())
        .f64("dy_mm", d.iter().map(|v| v.y).collect())
        .f64("dz_mm", d.iter().map(|v| v.z).collect())
        .f64("dnormal_mm", dn.clone())
        .f64("dist_mm", dist.clone())
        .build();
    let n = pairs.len() as f64;
    let mean = |v: &[f64]| v.iter().sum::<f64>() / n;
    // The controller registers a touch L seconds after the contact the AE
    // shows: the time difference estimates the trigger latency directly.
    let summary = json!({
        "n": pairs.len(),
        "rms_dist_mm": (dist.iter().map(|x| x * x).sum::<f64>() / n).sqrt(),
        "max_dist_mm": dist.iter().fold(0.0f64, |m, x| m.max(*x)),
        "mean_dnormal_mm": mean(&dn),
        "mean_dt_s": mean(&dt),
        "by_speed": by_speed(&pairs, &dn, &dt),
    });
    Some((batch, summary))
}

fn by_speed(pairs: &[(&Touch, &Touch)], dn: &[f64], dt: &[f64]) -> Value {
    let mut g: BTreeMap<(String, u64), (f64, Vec<usize>)> = BTreeMap::new();
    for (i, (p, _)) in pairs.iter().enumerate() {
        g.entry((p.method.clone(), p.approach_mm_s.to_bits()))
            .or_insert((p.approach_mm_s, Vec::new()))
            .1
            .push(i);
    }
    Value::Array(
        g.into_iter()
            .map(|((m, _), (v, idx))| {
                let n = idx.len() as f64;
                json!({
                    "method": m,
                    "approach_mm_s": v,
                    "n": idx.len(),
                    "mean_dnormal_mm": idx.iter().map(|&i| dn[i]).sum::<f64>() / n,
                    "mean_dt_s": idx.iter().map(|&i| dt[i]).sum::<f64>() / n,
                })
            })
            .collect(),
    )
}

fn contacts_batch(r: &AeResult, roles: &[(i32, Role)]) -> arrow::record_batch::RecordBatch {
    let e = &r.events;
    BatchBuilder::new()
        .f64(
            "t_s",
            e.iter().map(|x| x.onset_t_s + r.clock_offset_s).collect(),
        )
        .f64("ae_t_s", e.iter().map(|x| x.onset_t_s).collect())
        .i64("ae_row", e.iter().map(|x| x.onset_index as i64).collect())
        .f64("peak_v", e.iter().map(|x| x.peak_v).collect())
        .f64("duration_s", e.iter().map(|x| x.duration_s()).collect())
        .f64(
            "threshold_v",
            e.iter().map(|x| x.floor.threshold_v).collect(),
        )
        .f64("release_v", e.iter().map(|x| x.floor.release_v).collect())
        .f64("noise_mean_v", e.iter().map(|x| x.floor.mean_v).collect())
        .f64("noise_sigma_v", e.iter().map(|x| x.floor.sigma_v).collect())
        .i32("seq", roles.iter().map(|r| r.0).collect())
        .str(
            "role",
            &roles.iter().map(|r| r.1.label()).collect::<Vec<_>>(),
        )
        .build()
}

fn empty_contacts() -> arrow::record_batch::RecordBatch {
    let r = AeResult {
        events: Vec::new(),
        detector: AeDetector::new(AeParams::from_seconds(1.0, 1.0, 1.0, 1.0, 1.0, 2.0)),
        samples: 0,
        blocks: 0,
        clock_offset_s: 0.0,
    };
    contacts_batch(&r, &[])
}

const SPEC: StageSpec = StageSpec {
    name: "ingest",
    version: 1,
    reads: &[&PROBE, &AE, &MOTION, &PLAN],
    reads_artifacts: &[],
    writes: &["touches", "contacts", "touch_compare"],
    about: "touches from probe.parquet or from AE contacts mapped through motion + plan (MODELS.md §1.2)",
};

impl Stage for IngestStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn validate_config(&self, config: &toml::Table) -> Result<()> {
        check_config(config, KEYS)
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let run = ctx.run;
        let cfg = IngestConfig::from_ctx(ctx);
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
                    "ae.parquet is present but run.toml has no [ae] table with sample_rate_hz (CONTRACTS.md §1)",
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
                    "the robot plugin needs probe.parquet, or ae.parquet + motion.parquet + plan.parquet (CONTRACTS.md §3)",
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

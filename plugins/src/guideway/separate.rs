//! `separate`: three-probe error separation of a run (docs/models.md §3.1), the
//! published recursion or one least-squares solve over the whole travel
//! (`[guideway.separate] method`, default `lsq`; see three_probe.rs).
//!
//! Artifact `separation`, one row per sample: n, x_mm, h_mm (workpiece
//! under probe A), dz_mm, beta_rad, and for `lsq` h_sigma_mm, dz_sigma_mm,
//! beta_sigma_rad (1σ, propagated); plus what the later stages need from the
//! readings: t_s, dir, pass, infeed_count, j (grid index), temp_c (when
//! recorded). The only stage that reads guideway.parquet: later stages work
//! on this artifact, so a resampled run stays consistent downstream.

use crate::guideway::tables::GUIDEWAY;
use crate::{err, Context};
use arrow::array::{Array, Float64Array, Int32Array, Int64Array, Int8Array};
use arrow::record_batch::RecordBatch;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use sparkout_pipeline::config_check::{read_section, SectionCheck};
use sparkout_pipeline::contracts::{batch_f64, batch_i32, BatchBuilder};
use sparkout_pipeline::{Result, Stage, StageArgs, StageContext, StageOutput, StageSpec};

use super::config::{flags_to_table, machine_f64, machine_section, MachineProbes, SeparateSection};
use super::input::{self, Geometry, Readings};
use super::three_probe::{self, straightness_rms, Method, Separation};

pub struct SeparateStage;

fn rms(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

/// The `separation` artifact.
pub fn batch(r: &Readings, s: &Separation) -> RecordBatch {
    let mut b = BatchBuilder::new()
        .i64("n", r.n.clone())
        .f64("x_mm", r.x_mm.clone())
        .f64("h_mm", s.h_at_samples(r))
        .f64("dz_mm", s.dz_mm.clone())
        .f64("beta_rad", s.beta_rad.clone());
    if let (Some(hs), Some(ds), Some(bs)) = (
        s.h_sigma_at_samples(r),
        s.dz_sigma_mm.as_ref(),
        s.beta_sigma_rad.as_ref(),
    ) {
        b = b
            .f64("h_sigma_mm", hs)
            .f64("dz_sigma_mm", ds.clone())
            .f64("beta_sigma_rad", bs.clone());
    }
    b = b
        .f64("t_s", r.t_s.clone())
        .i8("dir", r.dir.iter().map(|d| *d as i8).collect())
        .i32("pass", r.pass.clone())
        .i32("infeed_count", r.infeed_count.clone())
        .i32("j", r.j.iter().map(|j| *j as i32).collect());
    if let Some(t) = &r.temp_c {
        b = b.f64("temp_c", t.clone());
    }
    b.build()
}

/// The separation artifact read back by the later stages.
#[derive(Debug, Clone)]
pub struct SepData {
    pub n: Vec<i64>,
    pub x_mm: Vec<f64>,
    pub h_mm: Vec<f64>,
    pub dz_mm: Vec<f64>,
    pub t_s: Vec<f64>,
    pub dir: Vec<f64>,
    pub pass: Vec<i32>,
    pub infeed_count: Vec<i32>,
    pub j: Vec<usize>,
    pub temp_c: Option<Vec<f64>>,
}

impl SepData {
    pub fn from_batch(b: &RecordBatch) -> Result<SepData> {
        let col = |name: &str| {
            b.column_by_name(name)
                .with_context(|| format!("separation artifact has no column `{name}`"))
        };
        let n = col("n")?
            .as_any()
            .downcast_ref::<Int64Array>()
            .context("separation.n must be int64")?
            .values()
            .to_vec();
        let dir = col("dir")?
            .as_any()
            .downcast_ref::<Int8Array>()
            .context("separation.dir must be int8")?
            .values()
            .iter()
            .map(|d| *d as f64)
            .collect();
        let temp_c = match b.column_by_name("temp_c") {
            Some(c) => Some(
                c.as_any()
                    .downcast_ref::<Float64Array>()
                    .context("separation.temp_c must be float64")?
                    .values()
                    .to_vec(),
            ),
            None => None,
        };
        let j = col("j")?
            .as_any()
            .downcast_ref::<Int32Array>()
            .filter(|a| a.null_count() == 0)
            .context("separation.j must be int32")?
            .values()
            .iter()
            .map(|v| *v as usize)
            .collect();
        Ok(SepData {
            n,
            x_mm: batch_f64(b, "x_mm")?.to_vec(),
            h_mm: batch_f64(b, "h_mm")?.to_vec(),
            dz_mm: batch_f64(b, "dz_mm")?.to_vec(),
            t_s: batch_f64(b, "t_s")?.to_vec(),
            dir,
            pass: batch_i32(b, "pass")?.to_vec(),
            infeed_count: batch_i32(b, "infeed_count")?.to_vec(),
            j,
            temp_c,
        })
    }
    pub fn len(&self) -> usize {
        self.n.len()
    }
    pub fn is_empty(&self) -> bool {
        self.n.is_empty()
    }
}

/// `separate.json` (and what `stage separate --json` prints): method, n,
/// h_rms_mm, dz_rms_mm; plus geometry, noise and the other method's
/// figures. Numbers that cannot be computed are `null` (NaN when read).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SeparateSummary {
    /// `lsq` or `recursion`.
    pub method: String,
    /// Samples.
    pub n: usize,
    /// RMS of h about its line, of δz, and of β.
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub h_rms_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub dz_rms_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub beta_rms_rad: f64,
    /// Reference of h (`first_readings`: the recursion's own start values).
    pub reference: String,
    /// Workpiece grid points.
    pub positions: usize,
    pub passes: usize,
    /// Probe spacing in sample steps.
    pub k: usize,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub sample_step_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub probe_spacing_mm: f64,
    pub resampled: bool,
    pub t_recorded: bool,
    /// Reading noise behind the bands (`null`: none), and where it came from.
    pub sigma_mm: Option<f64>,
    pub sigma_source: Option<String>,
    /// Residual degrees of freedom of the LS solve.
    pub dof: usize,
    /// Largest 1σ of h and of δz (`null` without uncertainties).
    pub h_sigma_max_mm: Option<f64>,
    pub dz_sigma_max_mm: Option<f64>,
    /// The other method's figures (`null` when it failed).
    pub other: Option<OtherMethod>,
}

/// `separate.json` `other`: the other method on the same readings.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct OtherMethod {
    pub method: String,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub h_rms_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub dz_rms_mm: f64,
    /// RMS of the two h's difference beyond a line.
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub h_difference_rms_mm: f64,
}

/// The stage's summary of a separation `s` (and the other method's).
pub fn summary(r: &Readings, s: &Separation, other: Option<&Separation>) -> SeparateSummary {
    let max = |v: &Option<Vec<f64>>| v.as_ref().map(|v| v.iter().cloned().fold(0.0, f64::max));
    let other = other.map(|o| {
        let dh: f64 = {
            let a: Vec<f64> = s.h_mm.iter().zip(&o.h_mm).map(|(a, b)| a - b).collect();
            straightness_rms(&a)
        };
        OtherMethod {
            method: o.method.as_str().to_string(),
            h_rms_mm: straightness_rms(&o.h_mm),
            dz_rms_mm: rms(&o.dz_mm),
            h_difference_rms_mm: dh,
        }
    });
    SeparateSummary {
        method: s.method.as_str().to_string(),
        n: r.len(),
        h_rms_mm: straightness_rms(&s.h_mm),
        dz_rms_mm: rms(&s.dz_mm),
        beta_rms_rad: rms(&s.beta_rad),
        reference: s
            .reference
            .map(|x| x.as_str())
            .unwrap_or("first_readings")
            .to_string(),
        positions: s.h_mm.len(),
        passes: r.passes(),
        k: r.k,
        sample_step_mm: r.step_mm,
        probe_spacing_mm: r.spacing_mm,
        resampled: r.resampled,
        t_recorded: r.t_recorded,
        sigma_mm: s.sigma_mm,
        sigma_source: s.sigma_source.map(String::from),
        dof: s.dof,
        h_sigma_max_mm: max(&s.h_sigma_mm),
        dz_sigma_max_mm: max(&s.dz_sigma_mm),
        other,
    }
}

const SPEC: StageSpec = StageSpec {
    name: "separate",
    version: 1,
    reads: &[&GUIDEWAY],
    reads_artifacts: &[],
    writes: &["separation"],
    reads_augmented_model: false,
    about: "three-probe error separation: workpiece h, table motion error δz, pitch β — published recursion or one LS solve with uncertainty (docs/models.md §3.1)",
    config: SectionCheck::of::<SeparateSection>(),
};

impl Stage for SeparateStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let cfg: &SeparateSection = ctx.section()?;
        let sigma_mm = cfg.probe_sigma_mm.unwrap_or_else(|| {
            machine_f64(machine_section::<MachineProbes>(ctx.run).sigma_mm, 1e-4)
        });
        let r = input::load(ctx.run, &cfg.input())?;
        let s = three_probe::separate(&r, cfg.method, cfg.reference, sigma_mm)?;
        let other_method = match cfg.method {
            Method::Lsq => Method::Recursion,
            Method::Recursion => Method::Lsq,
        };
        let other = three_probe::separate(&r, other_method, cfg.reference, sigma_mm).ok();
        Ok(StageOutput::typed(&summary(&r, &s, other.as_ref()))?.with("separation", batch(&r, &s)))
    }
    fn run_standalone(&self, args: &StageArgs) -> Option<Result<Value>> {
        Some(standalone(args))
    }
}

/// The stage's own flags of the run-less form; the others are config keys.
const INPUTS: &[&str] = &["guideway", "spacing-mm", "step-mm", "speed-mm-s"];

/// `sparkout stage separate --guideway FILE --spacing-mm L --step-mm ΔL
/// [--method recursion] [--reference ends] [--interpolate true] --json`.
fn standalone(args: &StageArgs) -> Result<Value> {
    let path = args.get("guideway").ok_or_else(|| {
        err!("stage separate: give --run DIR, or --guideway FILE.parquet --spacing-mm L --step-mm ΔL")
    })?;
    let num = |k: &str| -> Result<Option<f64>> {
        match args.get(k) {
            None => Ok(None),
            Some(v) => v
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite() && *x > 0.0)
                .map(Some)
                .ok_or_else(|| err!("stage separate: --{k} must be a number > 0, got `{v}`")),
        }
    };
    let need = |k: &str| -> Result<f64> {
        num(k)?.ok_or_else(|| err!("stage separate: --{k} is required with --guideway"))
    };
    let g = Geometry {
        spacing_mm: need("spacing-mm")?,
        step_mm: need("step-mm")?,
        speed_mm_s: num("speed-mm-s")?.unwrap_or(20_000.0 / 60.0),
    };
    let t = flags_to_table(args, INPUTS);
    let cfg = read_section::<SeparateSection>(&t).map_err(|e| err!("stage separate: flag {e}"))?;
    let sigma_mm = cfg.probe_sigma_mm.unwrap_or(1e-4);
    let r = input::load_file(std::path::Path::new(path), &g, &cfg.input())?;
    let s = three_probe::separate(&r, cfg.method, cfg.reference, sigma_mm)?;
    let other = match cfg.method {
        Method::Lsq => three_probe::separate_recursion(&r).ok(),
        Method::Recursion => three_probe::separate_lsq(&r, cfg.reference, sigma_mm).ok(),
    };
    Ok(serde_json::to_value(summary(&r, &s, other.as_ref()))?)
}

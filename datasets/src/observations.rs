//! Synthetic observation fleets (docs/formats.md §7) for the gap diagnosis and
//! `sparkout validate`: `real` = `sim` + injected
//! effects + noise σ, on a realistic measuring layout:
//!
//! - an x/y grid measured along raster paths whose direction changes from
//!   pass to pass and run to run (serpentine: `dir` = ±1 per line);
//! - time `t_s` from the path speed, a dwell per measurement and pauses
//!   between passes; feed `feed_mm_s` and load `force_n` varying per line,
//!   independently (so `lag` and `compliance` are separable);
//! - acceleration `a_mm_s2` near the path ends (positive accelerating,
//!   negative braking — antisymmetric, unlike `edge`), `path_end_mm` the
//!   distance to the nearer end;
//! - cumulative removal `removed_mm3` at a depth that changes per pass (so it
//!   is not proportional to time), `pass`, a warming `temp_c` with a run's own
//!   start, rise and wander (so `thermal` is not `drift`);
//! - replicates: a share of points is measured twice in a row (`trial` 1,
//!   same `point`), which gives the diagnosis its repeatability.
//!
//! Everything is drawn from one ChaCha8 stream seeded by the config: the same
//! config gives the same fleet, bit for bit.

use std::collections::BTreeMap;
use std::fs::File;
use std::path::Path;
use std::sync::Arc;

use crate::generator::{no_ae_rate, GenerateOptions, Generated, Generator, Predicted};
use crate::{bail, err, Context};
use arrow::array::{ArrayRef, Float64Array, Int32Array, RecordBatch, StringArray};
use arrow::datatypes::{DataType, Field, Schema};
use parquet::arrow::ArrowWriter;
use parquet::basic::{Compression, ZstdLevel};
use parquet::file::properties::WriterProperties;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use sparkout_pipeline::contracts::write_parquet_atomic;
use sparkout_pipeline::diagnose::{shape_value, Kind};
use sparkout_pipeline::{EffectSpec, Result};

/// Shape of a generated fleet.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ObsFleetConfig {
    pub runs: usize,
    pub seed: u64,
    /// Measurement noise σ (mm).
    pub noise_mm: f64,
    /// Grid points along x and y, and their spacing (mm).
    pub nx: usize,
    pub ny: usize,
    pub spacing_mm: f64,
    pub passes: usize,
    /// Share of points measured twice in a row (replicates).
    pub replicate_fraction: f64,
    pub observable: String,
}

impl Default for ObsFleetConfig {
    fn default() -> Self {
        ObsFleetConfig {
            runs: 6,
            seed: 0,
            noise_mm: 0.001,
            nx: 16,
            ny: 10,
            spacing_mm: 5.0,
            passes: 3,
            replicate_fraction: 0.15,
            observable: "surface_z".into(),
        }
    }
}

/// The generated rows before `real` is composed: covariates, ids and `sim`.
#[derive(Debug, Clone)]
pub struct ObsLayout {
    pub run: Vec<String>,
    pub trial: Vec<i32>,
    pub point: Vec<i32>,
    /// Covariates by name: x_mm, y_mm, t_s, feed_mm_s, force_n, a_mm_s2,
    /// path_end_mm, dir, removed_mm3, pass, temp_c.
    pub cols: BTreeMap<String, Vec<f64>>,
    pub sim: Vec<f64>,
}

impl ObsLayout {
    pub fn len(&self) -> usize {
        self.run.len()
    }
    pub fn is_empty(&self) -> bool {
        self.run.is_empty()
    }
    pub fn col(&self, name: &str) -> Result<&[f64]> {
        self.cols
            .get(name)
            .map(|v| v.as_slice())
            .ok_or_else(|| err!("no covariate `{name}` in the generated layout"))
    }
}

/// Row-wise builder for one layout.
#[derive(Default)]
struct Rows {
    run: Vec<String>,
    trial: Vec<i32>,
    point: Vec<i32>,
    c: [Vec<f64>; 11],
}

const COLS: [&str; 11] = [
    "x_mm",
    "y_mm",
    "t_s",
    "feed_mm_s",
    "force_n",
    "a_mm_s2",
    "path_end_mm",
    "dir",
    "removed_mm3",
    "pass",
    "temp_c",
];

/// Builds the measuring layout (no effect, no noise).
pub fn layout(cfg: &ObsFleetConfig) -> Result<ObsLayout> {
    if cfg.runs == 0 || cfg.nx < 2 || cfg.ny < 2 || cfg.passes == 0 {
        bail!("observation fleet needs ≥ 1 run, a grid of at least 2×2 and ≥ 1 pass");
    }
    if cfg.spacing_mm.is_nan()
        || cfg.spacing_mm <= 0.0
        || cfg.noise_mm.is_nan()
        || cfg.noise_mm < 0.0
    {
        bail!("spacing_mm must be > 0 and noise_mm ≥ 0");
    }
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let mut rows = Rows::default();
    let (lx, ly) = (
        (cfg.nx - 1) as f64 * cfg.spacing_mm,
        (cfg.ny - 1) as f64 * cfg.spacing_mm,
    );
    let width_mm = 8.0;
    for r in 0..cfg.runs {
        let run_id = format!("r{:04}", r + 1);
        let mut t: f64 = rng.random_range(0.0..30.0);
        let mut removed = 0.0;
        let temp0 = rng.random_range(19.0..22.0);
        let temp_rise = rng.random_range(0.3..3.0);
        let temp_tau = rng.random_range(200.0..1500.0);
        let mut wander = 0.0;
        let start_corner: u32 = rng.random_range(0..4);
        for p in 1..=cfg.passes {
            let along_x = (r + p) % 2 == 0;
            let doc = if p == 1 {
                rng.random_range(0.02..0.05)
            } else {
                rng.random_range(0.002..0.02)
            };
            let base_feed = rng.random_range(20.0..80.0);
            let (n_lines, n_along, line_len) = if along_x {
                (cfg.ny, cfg.nx, lx)
            } else {
                (cfg.nx, cfg.ny, ly)
            };
            for line in 0..n_lines {
                let feed: f64 = base_feed * rng.random_range(0.75..1.25);
                let force: f64 = rng.random_range(20.0..200.0);
                let d_acc: f64 = rng.random_range(3.0..12.0);
                let a_peak = feed * feed / (2.0 * d_acc);
                // Serpentine, mirrored by the run's start corner.
                let forward = (line % 2 == 0) ^ (start_corner & 1 == 1);
                let line_idx = if start_corner & 2 == 2 {
                    n_lines - 1 - line
                } else {
                    line
                };
                let dir = if forward { 1.0 } else { -1.0 };
                for k in 0..n_along {
                    let kk = if forward { k } else { n_along - 1 - k };
                    let s = k as f64 * cfg.spacing_mm; // distance from the line's start
                    let (ix, iy) = if along_x {
                        (kk, line_idx)
                    } else {
                        (line_idx, kk)
                    };
                    let x = ix as f64 * cfg.spacing_mm;
                    let y = iy as f64 * cfg.spacing_mm;
                    let a = a_peak * ((-s / d_acc).exp() - (-(line_len - s) / d_acc).exp());
                    let path_end = s.min(line_len - s);
                    if k > 0 {
                        t += cfg.spacing_mm / feed;
                        removed += doc * width_mm * cfg.spacing_mm;
                    }
                    t += 2.0; // dwell while the point is measured
                    wander += rng.random_range(-1.0..1.0) * 0.01;
                    let temp = temp0 + temp_rise * (1.0 - (-t / temp_tau).exp()) + wander;
                    let point = (p * 100_000 + iy * cfg.nx + ix) as i32;
                    let repeats = if rng.random_bool(cfg.replicate_fraction.clamp(0.0, 1.0)) {
                        2
                    } else {
                        1
                    };
                    for trial in 0..repeats {
                        let tt = t + 0.5 * trial as f64;
                        rows.run.push(run_id.clone());
                        rows.trial.push(trial);
                        rows.point.push(point);
                        let v = [
                            x, y, tt, feed, force, a, path_end, dir, removed, p as f64, temp,
                        ];
                        for (c, v) in rows.c.iter_mut().zip(v) {
                            c.push(v);
                        }
                    }
                }
                t += 3.0; // line change
            }
            t += rng.random_range(120.0..400.0); // between passes
        }
    }
    let mut cols = BTreeMap::new();
    for (name, v) in COLS.iter().zip(rows.c) {
        cols.insert(name.to_string(), v);
    }
    // The nominal model's prediction: a smooth surface form (mm).
    let (x, y) = (&cols["x_mm"], &cols["y_mm"]);
    let sim = x
        .iter()
        .zip(y)
        .map(|(x, y)| 0.01 * (x / 40.0).sin() + 0.004 * (y / 25.0).cos() + 1e-5 * x * y / 10.0)
        .collect();
    Ok(ObsLayout {
        run: rows.run,
        trial: rows.trial,
        point: rows.point,
        cols,
        sim,
    })
}

/// The default covariate of an effect kind when a spec names none.
pub fn default_covariate(name: &str) -> Option<&'static str> {
    Some(match name {
        "scale" => "x_mm",
        "drift" => "t_s",
        "lag" => "feed_mm_s",
        "inertia" => "a_mm_s2",
        "backlash" => "dir",
        "wear" => "removed_mm3",
        "compliance" => "force_n",
        "bow" => "y_mm",
        "periodic" => "x_mm",
        "edge" => "path_end_mm",
        "squareness" => "x_mm,y_mm",
        "thermal" => "temp_c",
        "step" => "x_mm",
        "bump" => "x_mm,y_mm",
        "product" => "feed_mm_s,force_n",
        _ => return None,
    })
}

/// Parameters that scale with the effect's size (the rest are shape: τ, λ,
/// phase, positions). [`scale_spec`] multiplies these.
pub const AMPLITUDE_PARAMS: [&str; 6] = [
    "k",
    "b_mm",
    "amplitude_mm",
    "k_mm",
    "offset_mm",
    "height_mm",
];

/// Out-of-catalogue effects the validation uses to test honesty.
pub const OUT_OF_CATALOGUE: [&str; 3] = ["step", "bump", "product"];

/// The value of one effect on every row of a layout. Catalogue effects use
/// the docs/formats.md forms (defaults filled in from the layout: bow's c0/c1
/// are the covariate's range); also `step` (height_mm·[c ≥ at]), `bump`
/// (amplitude_mm·exp(−r²/2·radius_mm²) around x0,y0) and `product`
/// (k·c1·c2 of two non-position covariates) — outside the catalogue.
pub fn apply_effect(spec: &EffectSpec, l: &ObsLayout) -> Result<Vec<f64>> {
    let cov = spec
        .covariate
        .clone()
        .or_else(|| default_covariate(&spec.name).map(String::from));
    let covs: Vec<String> = cov
        .as_deref()
        .map(|c| c.split(',').map(|s| s.trim().to_string()).collect())
        .unwrap_or_default();
    let c = |i: usize| -> Result<&[f64]> {
        let name = covs
            .get(i)
            .ok_or_else(|| err!("effect `{}` needs a covariate", spec.name))?;
        l.col(name)
    };
    let range = |v: &[f64]| {
        v.iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                (a.min(*x), b.max(*x))
            })
    };
    let mut params = spec.params.clone();
    let g = |p: &BTreeMap<String, f64>, k: &str, d: f64| p.get(k).copied().unwrap_or(d);
    match spec.name.as_str() {
        "offset" => Ok(vec![g(&params, "offset_mm", 0.01); l.len()]),
        "step" => {
            let v = c(0)?;
            let (lo, hi) = range(v);
            let at = g(&params, "at", lo + 0.37 * (hi - lo));
            let h = g(&params, "height_mm", 0.01);
            Ok(v.iter().map(|x| if *x >= at { h } else { 0.0 }).collect())
        }
        "bump" => {
            let (x, y) = (c(0)?, c(1)?);
            let ((x0l, x0h), (y0l, y0h)) = (range(x), range(y));
            let x0 = g(&params, "x0", x0l + 0.3 * (x0h - x0l));
            let y0 = g(&params, "y0", y0l + 0.6 * (y0h - y0l));
            let w = g(&params, "radius_mm", 0.12 * (x0h - x0l).max(y0h - y0l));
            let a = g(&params, "amplitude_mm", 0.01);
            Ok(x.iter()
                .zip(y)
                .map(|(x, y)| a * (-((x - x0).powi(2) + (y - y0).powi(2)) / (2.0 * w * w)).exp())
                .collect())
        }
        "product" => {
            let (a, b) = (c(0)?, c(1)?);
            let k = g(&params, "k", 1e-6);
            Ok(a.iter().zip(b).map(|(a, b)| k * a * b).collect())
        }
        name => {
            let kind = Kind::from_name(name).ok_or_else(|| {
                err!("unknown effect `{name}` (catalogue kinds, step, bump or product)")
            })?;
            let v = c(0)?;
            let (lo, hi) = range(v);
            // Defaults give each kind a visible shape on this layout.
            let defaults: &[(&str, f64)] = match kind {
                Kind::Scale => &[("k", 2e-4)],
                Kind::Lag => &[("k", 1e-4)],
                Kind::Inertia => &[("k", 2e-6)],
                Kind::Wear => &[("k", 1e-6)],
                Kind::Compliance => &[("k", 5e-5)],
                Kind::Thermal => &[("k", 3e-3)],
                Kind::Squareness => &[("k", 1e-6)],
                Kind::Backlash => &[("b_mm", 0.004)],
                Kind::Bow => &[("amplitude_mm", 0.01)],
                Kind::Drift => &[("amplitude_mm", 0.01), ("tau_s", 600.0)],
                Kind::Edge => &[("k_mm", 0.01), ("lambda_mm", 6.0)],
                Kind::Periodic => &[("amplitude_mm", 0.005), ("phase_rad", 0.5)],
                Kind::Offset => &[],
            };
            for (k, d) in defaults {
                params.entry(k.to_string()).or_insert(*d);
            }
            if kind == Kind::Bow {
                params.entry("c0".into()).or_insert(lo);
                params.entry("c1".into()).or_insert(hi);
            }
            if kind == Kind::Periodic {
                params.entry("lambda".into()).or_insert((hi - lo) / 3.3);
            }
            let c2 = if kind == Kind::Squareness {
                Some(c(1)?)
            } else {
                None
            };
            Ok(shape_value(kind, &params, v, c2))
        }
    }
}

/// The parameters an effect was generated with, defaults filled in (what
/// [`apply_effect`] used): for parameter-recovery scoring.
pub fn resolved_spec(spec: &EffectSpec, l: &ObsLayout) -> Result<EffectSpec> {
    let mut s = spec.clone();
    if s.covariate.is_none() {
        s.covariate = default_covariate(&s.name).map(String::from);
    }
    if let (Some(kind), Some(cov)) = (Kind::from_name(&s.name), s.covariate.clone()) {
        let first = cov.split(',').next().unwrap_or("").to_string();
        let v = l.col(&first)?;
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                (a.min(*x), b.max(*x))
            });
        let defaults: Vec<(&str, f64)> = match kind {
            Kind::Scale => vec![("k", 2e-4)],
            Kind::Lag => vec![("k", 1e-4)],
            Kind::Inertia => vec![("k", 2e-6)],
            Kind::Wear => vec![("k", 1e-6)],
            Kind::Compliance => vec![("k", 5e-5)],
            Kind::Thermal => vec![("k", 3e-3), ("t0_c", 20.0)],
            Kind::Squareness => vec![("k", 1e-6)],
            Kind::Backlash => vec![("b_mm", 0.004)],
            Kind::Bow => vec![("amplitude_mm", 0.01), ("c0", lo), ("c1", hi)],
            Kind::Drift => vec![("amplitude_mm", 0.01), ("tau_s", 600.0)],
            Kind::Edge => vec![("k_mm", 0.01), ("lambda_mm", 6.0)],
            Kind::Periodic => vec![
                ("amplitude_mm", 0.005),
                ("phase_rad", 0.5),
                ("lambda", (hi - lo) / 3.3),
            ],
            Kind::Offset => vec![("offset_mm", 0.01)],
        };
        for (k, d) in defaults {
            s.params.entry(k.to_string()).or_insert(d);
        }
    }
    Ok(s)
}

/// Multiplies a spec's amplitude parameters by `factor`.
pub fn scale_spec(spec: &EffectSpec, factor: f64) -> EffectSpec {
    let mut s = spec.clone();
    for (k, v) in s.params.iter_mut() {
        if AMPLITUDE_PARAMS.contains(&k.as_str()) {
            *v *= factor;
        }
    }
    s
}

pub fn rms(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

/// Rescales an effect so that its RMS over the layout is `snr`·σ
/// (the validation's SNR = effect RMS / noise σ). Returns the scaled spec
/// (defaults resolved) and its values.
pub fn scale_to_snr(
    spec: &EffectSpec,
    l: &ObsLayout,
    snr: f64,
    sigma_mm: f64,
) -> Result<(EffectSpec, Vec<f64>)> {
    let base = resolved_spec(spec, l)?;
    let v = apply_effect(&base, l)?;
    let r = rms(&v);
    if r.is_nan() || r <= 0.0 {
        bail!("effect {} is zero on this layout", spec.key());
    }
    let f = snr * sigma_mm / r;
    Ok((scale_spec(&base, f), v.iter().map(|x| x * f).collect()))
}

/// The table of docs/formats.md §7 from a layout and the `real` column.
pub fn to_batch(l: &ObsLayout, real: &[f64], observable: &str) -> Result<RecordBatch> {
    if real.len() != l.len() {
        bail!("{} real values for {} rows", real.len(), l.len());
    }
    let mut fields = vec![
        Field::new("run", DataType::Utf8, false),
        Field::new("observable", DataType::Utf8, false),
        Field::new("sim", DataType::Float64, false),
        Field::new("real", DataType::Float64, false),
        Field::new("trial", DataType::Int32, false),
        Field::new("point", DataType::Int32, false),
    ];
    let mut cols: Vec<ArrayRef> = vec![
        Arc::new(StringArray::from(l.run.clone())),
        Arc::new(StringArray::from(vec![observable; l.len()])),
        Arc::new(Float64Array::from(l.sim.clone())),
        Arc::new(Float64Array::from(real.to_vec())),
        Arc::new(Int32Array::from(l.trial.clone())),
        Arc::new(Int32Array::from(l.point.clone())),
    ];
    for (name, v) in &l.cols {
        if name == "pass" || name == "dir" {
            // Integers as in the source tables (pass int32, dir int8 → int32).
            fields.push(Field::new(name, DataType::Int32, false));
            cols.push(Arc::new(Int32Array::from(
                v.iter().map(|x| *x as i32).collect::<Vec<_>>(),
            )));
        } else {
            fields.push(Field::new(name, DataType::Float64, false));
            cols.push(Arc::new(Float64Array::from(v.clone())));
        }
    }
    Ok(RecordBatch::try_new(Arc::new(Schema::new(fields)), cols)?)
}

/// Noise N(0, σ) per row from the fleet's seed (a stream apart from the
/// layout's, so changing effects never changes the noise).
pub fn noise(cfg: &ObsFleetConfig, n: usize) -> Vec<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x5EED_0F0B_5E40_u64);
    match Normal::new(0.0, cfg.noise_mm) {
        Ok(d) => (0..n).map(|_| d.sample(&mut rng)).collect(),
        Err(_) => vec![0.0; n],
    }
}

/// One run's share of the observations table at the defaults, measured
/// (debug build, `--runs 1000`: 20.6 MB written, 198 MB peak RSS above the
/// program's own): on disk, and held while it is built.
const DISK_BYTES_PER_RUN: u64 = 20_640;
const MEMORY_BYTES_PER_RUN: u64 = 203_000;

/// `sparkout generate observations`: a paired-observations table (no
/// machine; every catalogue effect applies) for `sparkout diagnose`.
pub struct ObservationsGenerator;

impl Generator for ObservationsGenerator {
    fn name(&self) -> &'static str {
        "observations"
    }
    fn writes_file(&self) -> bool {
        true
    }
    fn known_effects(&self) -> Vec<(&'static str, &'static str)> {
        Kind::all()
            .into_iter()
            .map(|k| (k.name(), "catalogue effect (docs/formats.md)"))
            .collect()
    }
    fn effects_listing(&self) -> String {
        let names: Vec<&str> = Kind::all().into_iter().map(Kind::name).collect();
        format!(
            "any catalogue effect (docs/formats.md): {} — as NAME:COVARIATE=KEY=VALUE,...\n",
            names.join(", ")
        )
    }
    fn predicted_size(&self, opts: &GenerateOptions) -> Predicted {
        table_size(opts)
    }
    fn generate(&self, out: &Path, opts: &GenerateOptions, fx: &[EffectSpec]) -> Result<Generated> {
        no_ae_rate(self.name(), opts)?;
        let cfg = ObsFleetConfig {
            runs: opts.runs,
            seed: opts.seed,
            ..Default::default()
        };
        let batch = generate(&cfg, fx)?;
        write_parquet_atomic(out, &batch)?;
        Ok(Generated {
            runs: opts.runs,
            summary: format!(
                "generated {} observations over {} runs in {}",
                batch.num_rows(),
                opts.runs,
                out.display()
            ),
        })
    }
}

/// A whole fleet: layout, `real` = sim + Σ effects + noise.
pub fn generate(cfg: &ObsFleetConfig, effects: &[EffectSpec]) -> Result<RecordBatch> {
    compose(cfg, &layout(cfg)?, effects)
}

/// `real` = sim + Σ effects + noise on a layout, as the table.
pub fn compose(cfg: &ObsFleetConfig, l: &ObsLayout, effects: &[EffectSpec]) -> Result<RecordBatch> {
    let mut real: Vec<f64> = l.sim.clone();
    for e in effects {
        let v = apply_effect(e, l).with_context(|| format!("effect {}", e.key()))?;
        for (r, x) in real.iter_mut().zip(v) {
            *r += x;
        }
    }
    for (r, e) in real.iter_mut().zip(noise(cfg, l.len())) {
        *r += e;
    }
    to_batch(l, &real, &cfg.observable)
}

/// Lines of a raster run ([`raster_layout`]).
pub const RASTER_LINES: usize = 40;

/// Line-start heights of raster scans on a sample that warms while it is
/// scanned: each run steps `RASTER_LINES` lines across x (`spacing_mm`
/// apart), measuring the height where each line starts, so the line's
/// position `x_mm` advances with time while `temp_c` rises (warm-up
/// 1 − exp(−t/τ), τ = 4000 s, plus a small wander). Like the scans it
/// models the table has no clock column: position and temperature are
/// what the diagnosis can tell apart, or not.
///
/// - `varied = false`: every run starts cold at the first line and scans
///   the same way, so within every run x_mm and temp_c move together — a
///   thermal effect and an effect of position fit these runs equally.
/// - `varied = true`: odd runs scan the lines in reverse, and every run
///   starts at its own point of the warm-up (0–1500 s in) and its own
///   start temperature, so the runs decorrelate position and temperature.
///
/// `sim` is a smooth form of x; replicates as in [`layout`].
pub fn raster_layout(cfg: &ObsFleetConfig, varied: bool) -> Result<ObsLayout> {
    if cfg.runs == 0 || cfg.spacing_mm.is_nan() || cfg.spacing_mm <= 0.0 {
        bail!("a raster fleet needs ≥ 1 run and spacing_mm > 0");
    }
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x7A57_E125_CA11);
    let (mut run, mut trial, mut point) = (Vec::new(), Vec::new(), Vec::new());
    let (mut xs, mut temps) = (Vec::new(), Vec::new());
    let line_s = 13.0; // scan one line, return, step to the next
    let (tau_s, rise_c) = (4000.0, 16.0);
    for r in 0..cfg.runs {
        let run_id = format!("r{:04}", r + 1);
        let reverse = varied && r % 2 == 1;
        let (t0, temp0) = if varied {
            (rng.random_range(0.0..1500.0), rng.random_range(19.5..20.5))
        } else {
            (0.0, 20.0 + rng.random_range(-0.02..0.02))
        };
        let mut wander = 0.0;
        for line in 0..RASTER_LINES {
            let ix = if reverse {
                RASTER_LINES - 1 - line
            } else {
                line
            };
            let t = t0 + line as f64 * line_s;
            wander += rng.random_range(-1.0..1.0) * 0.001;
            let temp = temp0 + rise_c * (1.0 - (-t / tau_s).exp()) + wander;
            let repeats = if rng.random_bool(cfg.replicate_fraction.clamp(0.0, 1.0)) {
                2
            } else {
                1
            };
            for k in 0..repeats {
                run.push(run_id.clone());
                trial.push(k);
                point.push(ix as i32);
                xs.push(ix as f64 * cfg.spacing_mm);
                temps.push(temp);
            }
        }
    }
    let sim = xs.iter().map(|x| 0.01 * (x / 40.0).sin()).collect();
    let mut cols = BTreeMap::new();
    cols.insert("x_mm".to_string(), xs);
    cols.insert("temp_c".to_string(), temps);
    Ok(ObsLayout {
        run,
        trial,
        point,
        cols,
        sim,
    })
}

/// `sparkout generate raster` / `raster-varied`: line-start heights of
/// raster scans ([`raster_layout`]) with the effects given, for `sparkout
/// diagnose` — the one where position and temperature move together, and
/// the one whose runs vary direction and start time.
pub struct RasterGenerator {
    pub varied: bool,
}

/// One table of every run's rows, built whole in memory: both sizes grow
/// with the run count (bytes per run measured at the observation
/// generator's defaults; a raster run has fewer rows, so this bounds it).
fn table_size(opts: &GenerateOptions) -> Predicted {
    let runs = opts.runs as u64;
    Predicted {
        write_bytes: runs.saturating_mul(DISK_BYTES_PER_RUN),
        peak_memory_bytes: runs.saturating_mul(MEMORY_BYTES_PER_RUN),
    }
}

impl Generator for RasterGenerator {
    fn predicted_size(&self, opts: &GenerateOptions) -> Predicted {
        table_size(opts)
    }
    fn name(&self) -> &'static str {
        if self.varied {
            "raster-varied"
        } else {
            "raster"
        }
    }
    fn writes_file(&self) -> bool {
        true
    }
    fn known_effects(&self) -> Vec<(&'static str, &'static str)> {
        vec![
            ("thermal:temp_c", "k·(temp_c − t0_c): the sample's warm-up"),
            ("scale:x_mm", "k·x_mm: a position error along the lines"),
            ("bow:x_mm", "a bow across the lines"),
        ]
    }
    fn generate(&self, out: &Path, opts: &GenerateOptions, fx: &[EffectSpec]) -> Result<Generated> {
        no_ae_rate(self.name(), opts)?;
        let cfg = ObsFleetConfig {
            runs: opts.runs,
            seed: opts.seed,
            observable: "line_start_z".into(),
            ..Default::default()
        };
        let batch = compose(&cfg, &raster_layout(&cfg, self.varied)?, fx)?;
        write_parquet_atomic(out, &batch)?;
        Ok(Generated {
            runs: opts.runs,
            summary: format!(
                "generated {} line-start heights over {} {} runs in {}",
                batch.num_rows(),
                opts.runs,
                self.name(),
                out.display()
            ),
        })
    }
}

/// Writes a batch as zstd Parquet, atomically (temp file + rename).
pub fn write_parquet(batch: &RecordBatch, path: &Path) -> Result<()> {
    let tmp = path.with_extension("parquet.tmp");
    {
        let f = File::create(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
        let props = WriterProperties::builder()
            .set_compression(Compression::ZSTD(ZstdLevel::default()))
            .build();
        let mut w = ArrowWriter::try_new(f, batch.schema(), Some(props))?;
        w.write(batch)?;
        w.close()?;
    }
    std::fs::rename(&tmp, path).with_context(|| format!("renaming to {}", path.display()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deterministic_and_complete() {
        let cfg = ObsFleetConfig {
            runs: 2,
            ..Default::default()
        };
        let e: EffectSpec = "drift:t_s=amplitude_mm=0.02,tau_s=600".parse().unwrap();
        let a = generate(&cfg, std::slice::from_ref(&e)).unwrap();
        let b = generate(&cfg, &[e]).unwrap();
        assert_eq!(a, b);
        for c in [
            "run",
            "observable",
            "sim",
            "real",
            "trial",
            "point",
            "x_mm",
            "t_s",
            "dir",
            "pass",
            "temp_c",
        ] {
            assert!(a.column_by_name(c).is_some(), "{c}");
        }
        let l = layout(&cfg).unwrap();
        assert!(l.trial.contains(&1), "replicates present");
        let t = l.col("t_s").unwrap();
        // time non-decreasing within a run
        for i in 1..l.len() {
            if l.run[i] == l.run[i - 1] {
                assert!(t[i] >= t[i - 1]);
            }
        }
    }

    /// Within-run correlation of x_mm and temp_c, pooled over runs.
    fn within_run_r(l: &ObsLayout) -> f64 {
        let (x, t) = (l.col("x_mm").unwrap(), l.col("temp_c").unwrap());
        let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
        let mut s = 0;
        for i in 1..=l.len() {
            if i == l.len() || l.run[i] != l.run[s] {
                let m = (i - s) as f64;
                let mx = x[s..i].iter().sum::<f64>() / m;
                let mt = t[s..i].iter().sum::<f64>() / m;
                for j in s..i {
                    sxy += (x[j] - mx) * (t[j] - mt);
                    sxx += (x[j] - mx).powi(2);
                    syy += (t[j] - mt).powi(2);
                }
                s = i;
            }
        }
        sxy / (sxx * syy).sqrt()
    }

    #[test]
    fn raster_moves_position_with_temperature_unless_runs_vary() {
        let cfg = ObsFleetConfig {
            runs: 4,
            seed: 9,
            ..Default::default()
        };
        let same = raster_layout(&cfg, false).unwrap();
        assert_eq!(same.cols.keys().collect::<Vec<_>>(), ["temp_c", "x_mm"]);
        assert!(within_run_r(&same) > 0.99, "{}", within_run_r(&same));
        let varied = raster_layout(&cfg, true).unwrap();
        assert!(
            within_run_r(&varied).abs() < 0.5,
            "{}",
            within_run_r(&varied)
        );
        // Deterministic, and every run measures every line.
        assert_eq!(varied.cols, raster_layout(&cfg, true).unwrap().cols);
        for r in ["r0001", "r0004"] {
            let n = varied
                .run
                .iter()
                .zip(&varied.trial)
                .filter(|(x, t)| *x == r && **t == 0)
                .count();
            assert_eq!(n, RASTER_LINES);
        }
    }

    #[test]
    fn snr_scaling_hits_target() {
        let l = layout(&ObsFleetConfig::default()).unwrap();
        for name in [
            "bow",
            "periodic",
            "edge",
            "step",
            "bump",
            "product",
            "wear:pass",
        ] {
            let s: EffectSpec = name.parse().unwrap();
            let (_, v) = scale_to_snr(&s, &l, 3.0, 0.001).unwrap();
            assert!((rms(&v) - 0.003).abs() < 1e-12, "{name}");
        }
    }
}

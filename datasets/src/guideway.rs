//! Synthetic guide-way grinder fleet (docs/models.md §3; tables docs/formats.md §4).
//!
//! Each run grinds one workpiece of `points` grid points (ΔL = 30 mm; 80
//! points = the source's 2.4 m) in `passes` strokes back and forth, one
//! infeed per pass, while probes A, B, C (spacing L = k·ΔL) read
//!
//! ```text
//! Z_A = h(j) + δz(n) + o_A + e,  Z_B = h(j+k) + δz + L·β + o_B + e,
//! Z_C = h(j+2k) + δz + 2L·β + o_C + e
//! ```
//!
//! - h: the workpiece shape (bow + waviness, new per run);
//! - δz = s(x) + u(n) + effects: s the guide-way straightness (a machine
//!   property: the same in every run), u a trending AR process — AR(4)
//!   innovations integrated twice with a pole ρ (ρ = 1 is exactly docs/models.md
//!   §3.2's Φ(B)(1 − B)²δz = ε; the default 0.98 keeps the trend bounded
//!   over a run), scaled to `ar_rms_mm`;
//! - β: the table pitch, a smooth function of x (machine property);
//! - o: probe zero offsets (per run), e: reading noise.
//!
//! Injectable effects (all common-mode, i.e. in δz): `thermal_infeed`
//! (workpiece thermal growth k per infeed — the source's "depends mainly on
//! the infeed value and number of infeeds"), `reversal` (table reversal
//! error c: δz += c/2·dir), and any catalogue shape on the motion-error
//! covariates x_mm, t_s, dir, temp_c, infeed_count (e.g. `thermal:temp_c`,
//! `drift:t_s`). truth.json holds h, δz, β, the offsets and the effects.
//!
//! Deterministic: every run draws from its own ChaCha8 stream keyed by
//! (seed, run index); the machine's straightness from a fleet stream.

use std::collections::BTreeMap;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use crate::generator::{DemoFleet, FleetGenerator, RunSize};
use crate::rng::{normal, stream_rng, uniform};
use crate::{bail, Context, Result};
use arrow::record_batch::RecordBatch;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sparkout_pipeline::contracts::{
    write_atomic, write_json_atomic, write_parquet_atomic, BatchBuilder,
};
use sparkout_pipeline::diagnose::{shape_value, Kind};
use sparkout_pipeline::EffectSpec;

/// Effect defaults, sized for SNR ≳ 5 against the default noise
/// (probe noise 0.1 µm, AR trend 0.15 µm RMS).
const DEF_THERMAL_K_MM: f64 = 0.0004;
const DEF_REVERSAL_C_MM: f64 = 0.002;
/// Covariates of `motion_error` a catalogue shape may be injected on.
const COVARIATES: &[&str] = &["x_mm", "t_s", "dir", "temp_c", "infeed_count"];

/// Settings of a generated guide-way fleet.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GuidewayFleetConfig {
    pub runs: usize,
    pub seed: u64,
    pub machine: String,
    /// Workpiece grid points (80 × 30 mm = 2.4 m).
    pub points: usize,
    pub passes: usize,
    pub step_mm: f64,
    /// Probe spacing in sample steps (L = k·ΔL; the source: 1).
    pub k: usize,
    /// Table speed (20 m/min) and dwell at each reversal.
    pub speed_mm_s: f64,
    pub dwell_s: f64,
    pub probe_noise_mm: f64,
    /// Zero offsets: common and linear parts uniform in ±this, per run.
    pub zero_offset_mm: f64,
    /// Residual o_A − 2o_B + o_C after zeroing, uniform in ±this (mm).
    pub zero_curvature_mm: f64,
    /// AR(4) coefficients of the table error's second difference.
    pub ar_coefficients: Vec<f64>,
    pub ar_pole: f64,
    pub ar_rms_mm: f64,
    /// Amplitudes of the guide-way straightness and the workpiece shape.
    pub straightness_mm: f64,
    pub shape_mm: f64,
    pub pitch_rad: f64,
    pub infeed_mm: f64,
    /// Workshop temperature swing over a run (°C), written as temp_c.
    pub temp_swing_c: f64,
}

impl Default for GuidewayFleetConfig {
    fn default() -> Self {
        GuidewayFleetConfig {
            runs: 4,
            seed: 0,
            machine: "guideway-grinder".into(),
            points: 80,
            passes: 12,
            step_mm: 30.0,
            k: 1,
            speed_mm_s: 20_000.0 / 60.0,
            dwell_s: 1.0,
            probe_noise_mm: 1e-4,
            zero_offset_mm: 5e-4,
            zero_curvature_mm: 2e-8,
            ar_coefficients: vec![0.45, -0.25, 0.15, -0.1],
            ar_pole: 0.98,
            ar_rms_mm: 1.5e-4,
            straightness_mm: 3e-3,
            shape_mm: 4e-3,
            pitch_rad: 2e-6,
            infeed_mm: 0.005,
            temp_swing_c: 0.3,
        }
    }
}

impl GuidewayFleetConfig {
    pub fn validate(&self) -> Result<()> {
        if self.runs == 0 {
            bail!("--runs must be at least 1");
        }
        if self.k == 0 || self.points < 2 * self.k + 10 {
            bail!(
                "points ({}) must exceed 2·k + 10 (k = {})",
                self.points,
                self.k
            );
        }
        if self.passes == 0 {
            bail!("passes must be at least 1");
        }
        for (name, v) in [("step_mm", self.step_mm), ("speed_mm_s", self.speed_mm_s)] {
            if !(v.is_finite() && v > 0.0) {
                bail!("{name} must be > 0, got {v}");
            }
        }
        for (name, v) in [
            ("probe_noise_mm", self.probe_noise_mm),
            ("zero_offset_mm", self.zero_offset_mm),
            ("zero_curvature_mm", self.zero_curvature_mm),
            ("ar_rms_mm", self.ar_rms_mm),
            ("dwell_s", self.dwell_s),
            ("infeed_mm", self.infeed_mm),
            ("temp_swing_c", self.temp_swing_c),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                bail!("{name} must be ≥ 0, got {v}");
            }
        }
        if !(self.ar_pole > 0.0 && self.ar_pole <= 1.0) {
            bail!("ar_pole must be in (0, 1], got {}", self.ar_pole);
        }
        Ok(())
    }
    /// Probe A positions per pass.
    pub fn positions(&self) -> usize {
        self.points - 2 * self.k
    }
}

/// The injectable effects, for `--list-effects`.
pub fn known_effects() -> Vec<(&'static str, &'static str)> {
    vec![
        (
            "thermal_infeed",
            "workpiece thermal growth with the number of infeeds (docs/models.md §3.4): δz += k_mm·(infeed_count − 1), default k_mm=0.0004 (4.4 µm by pass 12); diagnosis name thermal_infeed:infeed_count",
        ),
        (
            "reversal",
            "table reversal error: δz += c_mm/2·dir, default c_mm=0.002; diagnosis name backlash:dir (alias: backlash=b_mm=…)",
        ),
        (
            "<catalogue>:<covariate>",
            "any catalogue shape added to δz with the pipeline's parameter names (required), on x_mm, t_s, dir, temp_c or infeed_count — e.g. thermal:temp_c=k=0.003, drift:t_s=amplitude_mm=0.002,tau_s=60",
        ),
    ]
}

#[derive(Debug, Clone)]
struct Direct {
    kind: Kind,
    covariate: String,
    params: BTreeMap<String, f64>,
}

/// Resolved effects of a fleet.
#[derive(Debug, Clone, Default)]
pub struct Effects {
    thermal_k_mm: f64,
    reversal_c_mm: f64,
    direct: Vec<Direct>,
}

fn check_keys(spec: &EffectSpec, known: &[&str]) -> Result<()> {
    spec.check_params(known).map_err(crate::Error::msg)
}

/// Check the `--effect` specs and fill defaults.
pub fn resolve_effects(specs: &[EffectSpec]) -> Result<Effects> {
    let mut fx = Effects::default();
    for spec in specs {
        match (spec.name.as_str(), spec.covariate.as_deref()) {
            ("thermal_infeed", None | Some("infeed_count")) => {
                check_keys(spec, &["k_mm"])?;
                fx.thermal_k_mm += spec.param_or("k_mm", DEF_THERMAL_K_MM);
            }
            ("reversal", None | Some("dir")) => {
                check_keys(spec, &["c_mm"])?;
                fx.reversal_c_mm += spec.param_or("c_mm", DEF_REVERSAL_C_MM);
            }
            ("backlash", None) => {
                check_keys(spec, &["b_mm"])?;
                fx.reversal_c_mm += spec.param_or("b_mm", DEF_REVERSAL_C_MM);
            }
            (name, cov) => {
                let kind = Kind::from_name(name).ok_or_else(|| {
                    crate::err!(
                        "unknown effect `{name}` (known: thermal_infeed, reversal, or a catalogue shape on {})",
                        COVARIATES.join(", ")
                    )
                })?;
                let cov = cov.ok_or_else(|| {
                    crate::err!(
                        "effect `{name}`: a catalogue shape needs a covariate, e.g. `{name}:t_s` (one of {})",
                        COVARIATES.join(", ")
                    )
                })?;
                if !COVARIATES.contains(&cov) {
                    bail!(
                        "effect `{}`: covariate `{cov}` is not a motion_error covariate ({})",
                        spec.key(),
                        COVARIATES.join(", ")
                    );
                }
                if !sparkout_pipeline::diagnose::effect::kinds_for(cov).contains(&kind) {
                    bail!(
                        "effect `{}`: `{name}` does not apply to `{cov}` (docs/formats.md, effect catalogue)",
                        spec.key()
                    );
                }
                if spec.params.is_empty() {
                    bail!(
                        "effect `{}`: catalogue shapes need their parameters, e.g. k=…, amplitude_mm=…",
                        spec.key()
                    );
                }
                check_keys(
                    spec,
                    &[
                        "k",
                        "b_mm",
                        "amplitude_mm",
                        "tau_s",
                        "lambda",
                        "phase_rad",
                        "c0",
                        "c1",
                        "t0_c",
                    ],
                )?;
                fx.direct.push(Direct {
                    kind,
                    covariate: cov.to_string(),
                    params: spec.params.clone(),
                });
            }
        }
    }
    Ok(fx)
}

/// One generated run: the guideway table's columns and the truth.
#[derive(Debug, Clone, Serialize)]
pub struct GuidewayRun {
    pub run: String,
    pub n: Vec<i64>,
    pub x_mm: Vec<f64>,
    pub z_mm: [Vec<f64>; 3],
    pub dir: Vec<i8>,
    pub t_s: Vec<f64>,
    pub temp_c: Vec<f64>,
    pub infeed_count: Vec<i32>,
    pub truth: Truth,
}

/// truth.json, written and read back through this type.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Truth {
    pub generator: String,
    pub seed: u64,
    pub run: String,
    pub effects: Vec<String>,
    pub probe_spacing_mm: f64,
    pub sample_step_mm: f64,
    pub zero_offsets_mm: [f64; 3],
    pub probe_noise_mm: f64,
    pub ar_coefficients: Vec<f64>,
    pub ar_pole: f64,
    /// Per workpiece grid point.
    pub h_mm: Vec<f64>,
    /// Per sample: total δz and its parts.
    pub dz_mm: Vec<f64>,
    pub straightness_mm: Vec<f64>,
    pub ar_mm: Vec<f64>,
    pub effects_mm: Vec<f64>,
    pub beta_rad: Vec<f64>,
}

/// The trending AR process: AR(4) innovations integrated twice with pole
/// ρ, scaled to RMS `rms` (zero stays zero).
pub fn trending_ar(coef: &[f64], pole: f64, len: usize, rms: f64, r: &mut ChaCha8Rng) -> Vec<f64> {
    let burn = 200;
    let mut v: Vec<f64> = Vec::with_capacity(len + burn);
    for t in 0..len + burn {
        let mut x = normal(r);
        for (i, a) in coef.iter().enumerate() {
            if t > i {
                x += a * v[t - 1 - i];
            }
        }
        v.push(x);
    }
    let mut u = v[burn..].to_vec();
    for _ in 0..2 {
        let mut acc = 0.0;
        for x in u.iter_mut() {
            acc = pole * acc + *x;
            *x = acc;
        }
    }
    let m = (u.iter().map(|x| x * x).sum::<f64>() / len.max(1) as f64).sqrt();
    let s = if m > 0.0 { rms / m } else { 0.0 };
    u.iter().map(|x| x * s).collect()
}

/// Simulate run `index` of a fleet (no files).
pub fn simulate(
    cfg: &GuidewayFleetConfig,
    fx: &Effects,
    specs: &[EffectSpec],
    index: usize,
) -> GuidewayRun {
    let mut r = stream_rng(cfg.seed, index as u64 * 4 + 1);
    let mut machine = stream_rng(cfg.seed, u64::MAX / 2);
    let step = cfg.step_mm;
    let l = cfg.k as f64 * step;
    let length = (cfg.points - 1) as f64 * step;
    // Machine: guide-way straightness s(x) and pitch β(x).
    let (sb, sw, sl, sp) = (
        uniform(&mut machine, 0.6, 1.0),
        uniform(&mut machine, 0.2, 0.35),
        uniform(&mut machine, 400.0, 900.0),
        uniform(&mut machine, 0.0, 2.0 * PI),
    );
    let (bl, bp) = (
        uniform(&mut machine, 600.0, 1500.0),
        uniform(&mut machine, 0.0, 2.0 * PI),
    );
    let s_of = |x: f64| {
        cfg.straightness_mm
            * (sb * 4.0 * x * (length - x) / (length * length)
                + sw * (2.0 * PI * x / sl + sp).sin())
    };
    let beta_of = |x: f64| cfg.pitch_rad * (2.0 * PI * x / bl + bp).sin();
    // Workpiece shape, new per run.
    let (hb, hw, hl, hp) = (
        uniform(&mut r, -1.0, 1.0),
        uniform(&mut r, 0.1, 0.3),
        uniform(&mut r, 250.0, 700.0),
        uniform(&mut r, 0.0, 2.0 * PI),
    );
    let h: Vec<f64> = (0..cfg.points)
        .map(|j| {
            let u = j as f64 * step;
            cfg.shape_mm
                * (hb * 4.0 * u * (length - u) / (length * length)
                    + hw * (2.0 * PI * u / hl + hp).sin())
        })
        .collect();
    // Zero offsets: a common and a linear part (indistinguishable from δz
    // and β, harmless) and the residual second difference c = o_A − 2o_B +
    // o_C left after zeroing, which both separations integrate into a
    // parabola c·j²/2 in h (docs/models.md §3.1's weakness).
    let (oa, ob) = (
        uniform(&mut r, -cfg.zero_offset_mm, cfg.zero_offset_mm),
        uniform(&mut r, -cfg.zero_offset_mm, cfg.zero_offset_mm) / 2.0,
    );
    let oc = uniform(&mut r, -cfg.zero_curvature_mm, cfg.zero_curvature_mm);
    let offsets = [oa, oa + ob, oa + 2.0 * ob + oc];
    let temp_phase = uniform(&mut r, 0.0, 2.0 * PI);
    let m = cfg.positions();
    let len = m * cfg.passes;
    let u = trending_ar(
        &cfg.ar_coefficients,
        cfg.ar_pole,
        len,
        cfg.ar_rms_mm,
        &mut r,
    );
    let mut out = GuidewayRun {
        run: format!("r{index:04}"),
        n: Vec::with_capacity(len),
        x_mm: Vec::with_capacity(len),
        z_mm: Default::default(),
        dir: Vec::with_capacity(len),
        t_s: Vec::with_capacity(len),
        temp_c: Vec::with_capacity(len),
        infeed_count: Vec::with_capacity(len),
        truth: Truth {
            generator: "sparkout-datasets guideway".into(),
            seed: cfg.seed,
            run: format!("r{index:04}"),
            effects: specs.iter().map(|s| s.to_string()).collect(),
            probe_spacing_mm: l,
            sample_step_mm: step,
            zero_offsets_mm: offsets,
            probe_noise_mm: cfg.probe_noise_mm,
            ar_coefficients: cfg.ar_coefficients.clone(),
            ar_pole: cfg.ar_pole,
            h_mm: h.clone(),
            dz_mm: Vec::new(),
            straightness_mm: Vec::new(),
            ar_mm: Vec::new(),
            effects_mm: Vec::new(),
            beta_rad: Vec::new(),
        },
    };
    let dt = step / cfg.speed_mm_s;
    let duration = len as f64 * dt + cfg.passes as f64 * cfg.dwell_s;
    let mut t = 0.0;
    for p in 0..cfg.passes {
        let forward = p % 2 == 0;
        let js: Vec<usize> = if forward {
            (0..m).collect()
        } else {
            (0..m).rev().collect()
        };
        if p > 0 {
            t += cfg.dwell_s;
        }
        for j in js {
            let i = out.n.len();
            let x = j as f64 * step;
            let dir = if forward { 1.0 } else { -1.0 };
            let count = p as i32 + 1;
            let temp = 20.0
                + cfg.temp_swing_c * (2.0 * PI * t / duration + temp_phase).sin()
                + 0.002 * normal(&mut r);
            let cov = |c: &str| match c {
                "x_mm" => x,
                "t_s" => t,
                "dir" => dir,
                "temp_c" => temp,
                _ => count as f64,
            };
            let mut e = fx.thermal_k_mm * (count - 1) as f64 + fx.reversal_c_mm / 2.0 * dir;
            for d in &fx.direct {
                e += shape_value(d.kind, &d.params, &[cov(&d.covariate)], None)[0];
            }
            let s = s_of(x);
            let dz = s + u[i] + e;
            let beta = beta_of(x);
            let zs = [
                h[j] + dz + offsets[0],
                h[j + cfg.k] + dz + l * beta + offsets[1],
                h[j + 2 * cfg.k] + dz + 2.0 * l * beta + offsets[2],
            ];
            for (c, z) in zs.iter().enumerate() {
                out.z_mm[c].push(z + cfg.probe_noise_mm * normal(&mut r));
            }
            out.n.push(i as i64);
            out.x_mm.push(x);
            out.dir.push(dir as i8);
            out.t_s.push(t);
            out.temp_c.push(temp);
            out.infeed_count.push(count);
            out.truth.dz_mm.push(dz);
            out.truth.straightness_mm.push(s);
            out.truth.ar_mm.push(u[i]);
            out.truth.effects_mm.push(e);
            out.truth.beta_rad.push(beta);
            t += dt;
        }
    }
    out
}

/// guideway.parquet of a generated run (infeed_count is not written: the
/// plugin derives it, one infeed per pass).
pub fn table(run: &GuidewayRun) -> RecordBatch {
    BatchBuilder::new()
        .i64("n", run.n.clone())
        .f64("x_mm", run.x_mm.clone())
        .f64("za_mm", run.z_mm[0].clone())
        .f64("zb_mm", run.z_mm[1].clone())
        .f64("zc_mm", run.z_mm[2].clone())
        .i8("dir", run.dir.clone())
        .f64("t_s", run.t_s.clone())
        .f64("temp_c", run.temp_c.clone())
        .build()
}

/// A guide-way fleet's first run starts at 08:00, the next every 15 minutes.
const FIRST_START: crate::started::FirstStart = crate::started::FirstStart::at(2026, 11, 20, 8);

fn run_toml(cfg: &GuidewayFleetConfig, id: &str, index: usize) -> String {
    format!(
        r#"# Generated by sparkout-datasets (guideway fleet generator, seed {seed}).
[run]
id = "{id}"
machine = "{machine}"
plugin = "guideway"
started = "{started}"

[process]
probe_spacing_mm = {l:?}
sample_step_mm = {step:?}
infeed_mm = {infeed:?}
passes = {passes}
"#,
        seed = cfg.seed,
        machine = cfg.machine,
        started = crate::started::started_at(FIRST_START, 15, index),
        l = cfg.k as f64 * cfg.step_mm,
        step = cfg.step_mm,
        infeed = cfg.infeed_mm,
        passes = cfg.passes,
    )
}

/// `sparkout generate guideway` and the guideway fleet of `sparkout demo`.
pub const GENERATOR: FleetGenerator<GuidewayFleetConfig> = FleetGenerator {
    name: "guideway",
    known_effects,
    config: |runs, seed| GuidewayFleetConfig {
        runs,
        seed,
        ..GuidewayFleetConfig::default()
    },
    generate_fleet,
    demo: Some(DemoFleet {
        runs: 6,
        seed: 1,
        effect: "thermal_infeed",
    }),
    run_size: RunSize {
        disk_bytes: 158_019,
        memory_bytes: 7_400_000,
    },
};

/// Generate the fleet under `<root>/<machine>/r0000 …`.
pub fn generate_fleet(
    root: &Path,
    cfg: &GuidewayFleetConfig,
    specs: &[EffectSpec],
) -> Result<Vec<PathBuf>> {
    cfg.validate()?;
    let fx = resolve_effects(specs)?;
    let dir = root.join(&cfg.machine);
    (0..cfg.runs)
        .into_par_iter()
        .map(|i| {
            let run = simulate(cfg, &fx, specs, i);
            let d = dir.join(&run.run);
            (|| -> Result<()> {
                write_parquet_atomic(&d.join("guideway.parquet"), &table(&run))?;
                write_json_atomic(&d.join("truth.json"), &run.truth)?;
                // run.toml last: a run directory is complete once it exists.
                write_atomic(&d.join("run.toml"), run_toml(cfg, &run.run, i).as_bytes())
            })()
            .with_context(|| format!("generating guideway run {}", d.display()))?;
            Ok(d)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn effects_resolve_and_reject_unknowns() {
        let p = |s: &str| s.parse::<EffectSpec>().unwrap();
        let fx = resolve_effects(&[p("thermal_infeed"), p("reversal=c_mm=0.003")]).unwrap();
        assert_eq!(
            (fx.thermal_k_mm, fx.reversal_c_mm),
            (DEF_THERMAL_K_MM, 0.003)
        );
        assert!(resolve_effects(&[p("thermal:temp_c=k=0.001")]).is_ok());
        assert!(resolve_effects(&[p("wobble")]).is_err());
        assert!(resolve_effects(&[p("drift:x_mm=amplitude_mm=1,tau_s=1")]).is_err());
        assert!(resolve_effects(&[p("reversal=k=1")]).is_err());
    }

    #[test]
    fn readings_follow_the_three_probe_model() {
        let cfg = GuidewayFleetConfig {
            probe_noise_mm: 0.0,
            ..Default::default()
        };
        let fx = resolve_effects(&[]).unwrap();
        let a = simulate(&cfg, &fx, &[], 0);
        let b = simulate(&cfg, &fx, &[], 0);
        assert_eq!(a.z_mm, b.z_mm);
        let t = &a.truth;
        let i = 100;
        let j = (a.x_mm[i] / cfg.step_mm).round() as usize;
        let want = t.h_mm[j] + t.dz_mm[i] + t.zero_offsets_mm[0];
        assert!((a.z_mm[0][i] - want).abs() < 1e-15);
        assert_eq!(a.n.len(), cfg.positions() * cfg.passes);
        let rms = (t.ar_mm.iter().map(|x| x * x).sum::<f64>() / t.ar_mm.len() as f64).sqrt();
        assert!((rms - cfg.ar_rms_mm).abs() < 1e-12);
        assert!(a.t_s.windows(2).all(|w| w[1] > w[0]));
    }

    #[test]
    fn truth_json_reads_back_through_its_type() {
        let d = tempfile::tempdir().unwrap();
        let cfg = GuidewayFleetConfig {
            runs: 2,
            ..Default::default()
        };
        generate_fleet(d.path(), &cfg, &["thermal_infeed".parse().unwrap()]).unwrap();
        assert_eq!(
            crate::generator::truth_files_round_trip::<Truth>(d.path()),
            2
        );
    }
}

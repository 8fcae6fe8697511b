//! Synthetic volumetric-verification fleet of an XFYZ mill (docs/models.md §5;
//! tables docs/formats.md §4: tracker, thermal).
//!
//! One machine (the built-in `xfyz-mill`) with known error functions: 18
//! Legendre series of the machine's degree in the identification gauge (see
//! `sparkout_plugins::mill::chain::min_order`: what no tracker data can
//! tell apart is drawn as zero, so truth and estimate compare coefficient by
//! coefficient) and 3 squareness terms, drawn once per fleet from the seed.
//! Each run places the tracker anew (a Rodrigues rotation + translation),
//! measures `points` random positions in the workspace with the reflector at
//! the machine's tool offsets in turn, in a random order (randomising the
//! order decorrelates warm-up drift from position, so a drift is not taken
//! for a geometric error), one point every `point_period_s`, with isotropic
//! tracker noise; every `replicate_every`-th point is measured twice in a
//! row (tracker.parquet `trial` 0 and 1, same point id), which gives the
//! diagnosis a replicate noise floor. thermal.parquet logs a spindle and a
//! bed sensor.
//!
//! Injectable effects (outside the identified model, so they stay in the
//! tracker gap):
//! - `thermal_growth` — spindle growth along +z, amplitude_mm·(1 − e^(−t/tau_s))
//!   (defaults 0.025 mm, 600 s); the spindle sensor warms by
//!   delta_c·(1 − e^(−t/tau_s)) (default 6 °C).
//! - `x_waviness` — a periodic z straightness of X beyond any low polynomial
//!   degree: amplitude_mm·sin(2π·x/lambda_mm + phase_rad) (defaults 0.006 mm,
//!   75 mm, 0).
//!
//! Determinism: per-run ChaCha8 streams keyed by (seed, run index): the files
//! are byte-identical for a seed whatever the thread count.

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use crate::generator::{DemoFleet, FleetGenerator, RunSize};
use crate::rng::{normal, stream_rng, uniform};
use crate::{bail, Context, Result};
use nalgebra::Vector3;
use rand::Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sparkout_pipeline::contracts::{
    write_atomic, write_json_atomic, write_parquet_atomic, BatchBuilder, MachineConfig,
};
use sparkout_pipeline::EffectSpec;
use sparkout_plugins::mill::chain::{is_rotation, Model, Point, AXES, SQUARENESS};
use sparkout_plugins::mill::config::MillMachine;
use sparkout_plugins::mill::XFYZ_MILL_TOML;

type V3 = Vector3<f64>;

/// Fleet settings.
#[derive(Debug, Clone)]
pub struct MillFleetConfig {
    pub runs: usize,
    pub seed: u64,
    /// Tracker points per run.
    pub points: usize,
    /// Time between two points, s.
    pub point_period_s: f64,
    /// Per-coordinate tracker noise, mm (default: the machine's
    /// `[tracker] sigma_mm`).
    pub noise_mm: Option<f64>,
    /// Write thermal.parquet.
    pub thermal: bool,
    /// Re-measure every k-th point right away (trial 1): the replicates give
    /// the diagnosis its noise floor. 0 = none.
    pub replicate_every: usize,
}

impl Default for MillFleetConfig {
    fn default() -> Self {
        MillFleetConfig {
            runs: 4,
            seed: 0,
            points: 240,
            point_period_s: 10.0,
            noise_mm: None,
            thermal: true,
            replicate_every: 4,
        }
    }
}

impl MillFleetConfig {
    pub fn validate(&self) -> Result<()> {
        if self.runs == 0 {
            bail!("--runs must be ≥ 1");
        }
        if self.points < 30 {
            bail!(
                "points per run must be ≥ 30 (the 21-error model has ~60 parameters), got {}",
                self.points
            );
        }
        if !(self.point_period_s.is_finite() && self.point_period_s > 0.0) {
            bail!("point_period_s must be > 0");
        }
        if let Some(s) = self.noise_mm {
            if !(s.is_finite() && s >= 0.0) {
                bail!("noise_mm must be ≥ 0");
            }
        }
        Ok(())
    }
}

pub const MACHINE_ID: &str = "xfyz-mill";

/// The injectable effects, for `--list-effects`.
pub fn known_effects() -> Vec<(&'static str, &'static str)> {
    vec![
        (
            "thermal_growth",
            "spindle growth along +z while measuring: amplitude_mm·(1 − e^(−t/tau_s)) (defaults amplitude_mm=0.025, tau_s=600); the spindle sensor warms by delta_c·(1 − e^(−t/tau_s)) (default delta_c=6); tracker_dz gap ≈ the growth minus its mean",
        ),
        (
            "x_waviness",
            "periodic z straightness of X beyond the polynomial degree: amplitude_mm·sin(2π·x_mm/lambda_mm + phase_rad) (defaults amplitude_mm=0.006, lambda_mm=75, phase_rad=0); tracker_dz gap ≈ periodic in x_mm",
        ),
    ]
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
struct Effects {
    /// (amplitude_mm, tau_s, delta_c)
    growth: Option<(f64, f64, f64)>,
    /// (amplitude_mm, lambda_mm, phase_rad)
    waviness: Option<(f64, f64, f64)>,
}

fn check_keys(spec: &EffectSpec, known: &[&str]) -> Result<()> {
    spec.check_params(known).map_err(crate::Error::msg)
}

fn resolve(specs: &[EffectSpec]) -> Result<Effects> {
    let mut fx = Effects::default();
    for s in specs {
        match (s.name.as_str(), s.covariate.as_deref()) {
            ("thermal_growth", None | Some("t_s")) => {
                check_keys(s, &["amplitude_mm", "tau_s", "delta_c"])?;
                let tau = s.param_or("tau_s", 600.0);
                if tau <= 0.0 {
                    bail!("effect `thermal_growth`: tau_s must be > 0, got {tau}");
                }
                let a = s.param_or("amplitude_mm", 0.025);
                if a.abs() > 1.0 {
                    bail!("effect `thermal_growth`: |amplitude_mm| must be ≤ 1, got {a}");
                }
                if fx.growth.is_some() {
                    bail!("effect `thermal_growth` given twice");
                }
                fx.growth = Some((a, tau, s.param_or("delta_c", 6.0)));
            }
            ("x_waviness", None | Some("x_mm")) => {
                check_keys(s, &["amplitude_mm", "lambda_mm", "phase_rad"])?;
                let l = s.param_or("lambda_mm", 75.0);
                if l <= 0.0 {
                    bail!("effect `x_waviness`: lambda_mm must be > 0, got {l}");
                }
                if fx.waviness.is_some() {
                    bail!("effect `x_waviness` given twice");
                }
                fx.waviness = Some((
                    s.param_or("amplitude_mm", 0.006),
                    l,
                    s.param_or("phase_rad", 0.0),
                ));
            }
            _ => bail!(
                "unknown mill effect `{}` (known: thermal_growth, x_waviness; see `sparkout generate mill --list-effects`)",
                s.key()
            ),
        }
    }
    Ok(fx)
}

impl Effects {
    /// Machine-frame displacement of the tool point the model does not hold.
    fn offset(&self, q: &[f64; 3], t_s: f64) -> V3 {
        let mut d = V3::zeros();
        if let Some((a, tau, _)) = self.growth {
            d.z += a * (1.0 - (-t_s / tau).exp());
        }
        if let Some((a, l, ph)) = self.waviness {
            d.z += a * (2.0 * PI * q[0] / l + ph).sin();
        }
        d
    }
    fn spindle_warming_c(&self, t_s: f64) -> f64 {
        match self.growth {
            Some((_, tau, dc)) => dc * (1.0 - (-t_s / tau).exp()),
            None => 0.0,
        }
    }
}

/// The built-in machine.
pub fn machine() -> Result<MillMachine> {
    let cfg = MachineConfig {
        id: MACHINE_ID.into(),
        source: "built-in machine `xfyz-mill`".into(),
        table: XFYZ_MILL_TOML.parse()?,
        text: XFYZ_MILL_TOML.into(),
        ..Default::default()
    };
    Ok(MillMachine::from_config(&cfg)?)
}

/// The fleet's machine: error coefficients and squareness of realistic size
/// (positioning ~10 µm, straightness ~6 µm, rotations ~25 µrad per Legendre
/// order, falling as 1/order; squareness ~30 µrad). The tracker frame is
/// left at zero (it is per run).
pub fn true_machine(m: &MillMachine, seed: u64) -> Model {
    let mut rng = stream_rng(seed, u64::MAX);
    let layout = sparkout_plugins::mill::chain::Layout::new(m.degree, m.travels, &[]);
    let mut model = Model::zeros(layout);
    for i in 0..model.layout.coef.len() {
        let (f, order) = model.layout.coef[i];
        let kind = f % 6;
        let scale = if is_rotation(f) {
            25e-6
        } else if kind == f / 6 {
            0.010
        } else {
            0.006
        };
        model.params[i] = scale / (order.max(1) as f64) * normal(&mut rng);
    }
    let si = model.layout.sq_index();
    for k in 0..3 {
        model.params[si + k] = 30e-6 * normal(&mut rng);
    }
    model
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Param {
    name: String,
    value: f64,
}

/// truth.json, written and read back through this type.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct RunTruth {
    run: String,
    run_index: usize,
    seed: u64,
    machine: String,
    degree: usize,
    noise_mm: f64,
    points: usize,
    tools_mm: Vec<[f64; 3]>,
    /// Every identified parameter by its `kinematic_params` name (the
    /// tracker frame included).
    params: Vec<Param>,
    squareness_rad: std::collections::BTreeMap<String, f64>,
    tracker_rotation_vector_rad: [f64; 3],
    tracker_translation_mm: [f64; 3],
    effects: Vec<EffectSpec>,
}

/// `sparkout generate mill` and the mill fleet of `sparkout demo`.
pub const GENERATOR: FleetGenerator<MillFleetConfig> = FleetGenerator {
    name: "mill",
    known_effects,
    config: |runs, seed| MillFleetConfig {
        runs,
        seed,
        ..MillFleetConfig::default()
    },
    generate_fleet,
    demo: Some(DemoFleet {
        runs: 6,
        seed: 1,
        effect: "thermal_growth",
    }),
    run_size: RunSize {
        disk_bytes: 37_667,
        memory_bytes: 9_100_000,
    },
};

/// Generate `<root>/xfyz-mill/r0000 …`; returns the run dirs in order.
pub fn generate_fleet(
    root: &Path,
    cfg: &MillFleetConfig,
    effects: &[EffectSpec],
) -> Result<Vec<PathBuf>> {
    cfg.validate()?;
    let fx = resolve(effects)?;
    let m = machine()?;
    let truth = true_machine(&m, cfg.seed);
    let dir = root.join(MACHINE_ID);
    (0..cfg.runs)
        .into_par_iter()
        .map(|i| {
            let d = dir.join(format!("r{i:04}"));
            generate_run(&d, cfg, &m, &truth, &fx, effects, i)
                .with_context(|| format!("generating mill run {}", d.display()))?;
            Ok(d)
        })
        .collect()
}

/// One tracker measurement.
struct Row {
    point: i32,
    trial: i32,
    q: [f64; 3],
    tool: usize,
    t_s: f64,
    m: V3,
}

/// A mill fleet's first run starts on 2026-11-01 at 08:00 (ten a day).
const FIRST_START: crate::started::FirstStart = crate::started::FirstStart::at(2026, 11, 1, 8);

fn generate_run(
    dir: &Path,
    cfg: &MillFleetConfig,
    m: &MillMachine,
    truth: &Model,
    fx: &Effects,
    specs: &[EffectSpec],
    index: usize,
) -> Result<()> {
    let mut rng = stream_rng(cfg.seed, index as u64);
    let run_id = format!("r{index:04}");
    let noise = cfg.noise_mm.unwrap_or(m.tracker_sigma_mm);
    // Tracker placed anew: a random axis and angle, a few metres away.
    let axis = V3::new(normal(&mut rng), normal(&mut rng), normal(&mut rng)).normalize();
    let angle = 0.2 + 2.8 * rng.random::<f64>();
    let w = axis * angle;
    let t = V3::new(1500.0, -600.0, 200.0)
        + V3::new(
            600.0 * rng.random::<f64>() - 300.0,
            600.0 * rng.random::<f64>() - 300.0,
            200.0 * rng.random::<f64>() - 100.0,
        );
    let mut model = truth.clone();
    model.set_frame(&w, &t);
    let q_rot = sparkout_plugins::mill::chain::rotation(&w);
    let n = cfg.points;
    let mut rows: Vec<Row> = Vec::with_capacity(n + n / cfg.replicate_every.max(1));
    for i in 0..n {
        let q = [0, 1, 2].map(|a| {
            let (lo, hi) = m.travels[a];
            uniform(&mut rng, lo, hi)
        });
        let tool = i % m.tools.len();
        let pt = Point {
            q,
            tool: m.tools[tool],
        };
        let slot = i as f64 * cfg.point_period_s;
        let t0 = slot + 0.3 * cfg.point_period_s * rng.random::<f64>();
        let replicate = cfg.replicate_every > 0 && i % cfg.replicate_every == 0;
        let trials: &[(i32, f64)] = if replicate {
            &[(0, t0), (1, slot + 0.5 * cfg.point_period_s)]
        } else {
            &[(0, t0)]
        };
        for &(trial, t_s) in trials {
            let p = model.machine_point(&pt) + fx.offset(&q, t_s);
            let e = V3::new(normal(&mut rng), normal(&mut rng), normal(&mut rng)) * noise;
            rows.push(Row {
                point: i as i32,
                trial,
                q,
                tool,
                t_s,
                m: q_rot * p + t + e,
            });
        }
    }
    let col = |f: &dyn Fn(&Row) -> f64| -> Vec<f64> { rows.iter().map(f).collect() };
    let tracker = BatchBuilder::new()
        .i32("point", rows.iter().map(|r| r.point).collect())
        .i32("trial", rows.iter().map(|r| r.trial).collect())
        .f64("x_mm", col(&|r| r.q[0]))
        .f64("y_mm", col(&|r| r.q[1]))
        .f64("z_mm", col(&|r| r.q[2]))
        .f64("mx_mm", col(&|r| r.m.x))
        .f64("my_mm", col(&|r| r.m.y))
        .f64("mz_mm", col(&|r| r.m.z))
        .f64("t_s", col(&|r| r.t_s))
        .i32("tool", rows.iter().map(|r| r.tool as i32).collect())
        .build();
    write_parquet_atomic(&dir.join("tracker.parquet"), &tracker)?;
    if cfg.thermal {
        let end = rows.last().map(|r| r.t_s).unwrap_or(0.0) + 30.0;
        let (mut ts, mut sensor, mut temp) = (Vec::new(), Vec::new(), Vec::new());
        let mut k = 0;
        loop {
            let t = 30.0 * k as f64;
            if t > end {
                break;
            }
            for (name, base) in [("bed", 20.2), ("spindle", 20.0)] {
                let warm = if name == "spindle" {
                    fx.spindle_warming_c(t)
                } else {
                    0.0
                };
                ts.push(t);
                sensor.push(name);
                temp.push(base + warm + 0.01 * normal(&mut rng));
            }
            k += 1;
        }
        let thermal = BatchBuilder::new()
            .f64("t_s", ts)
            .str("sensor", &sensor)
            .f64("temp_c", temp)
            .build();
        write_parquet_atomic(&dir.join("thermal.parquet"), &thermal)?;
    }
    let layout = &model.layout;
    let truth_json = RunTruth {
        run: run_id.clone(),
        run_index: index,
        seed: cfg.seed,
        machine: MACHINE_ID.into(),
        degree: layout.degree,
        noise_mm: noise,
        points: rows.len(),
        tools_mm: m.tools.iter().map(|t| [t.x, t.y, t.z]).collect(),
        params: (0..layout.n_params())
            .map(|i| Param {
                name: layout.param_name(i),
                value: model.params[i],
            })
            .collect(),
        squareness_rad: (0..3)
            .map(|k| {
                (
                    SQUARENESS[k].to_string(),
                    model.params[layout.sq_index() + k],
                )
            })
            .collect(),
        tracker_rotation_vector_rad: [w.x, w.y, w.z],
        tracker_translation_mm: [t.x, t.y, t.z],
        effects: specs.to_vec(),
    };
    write_json_atomic(&dir.join("truth.json"), &truth_json)?;
    let run_toml = format!(
        "# Generated by sparkout-datasets (mill fleet generator, seed {seed}).\n[run]\nid = \"{run_id}\"\nmachine = \"{MACHINE_ID}\"\nplugin = \"mill\"\nstarted = \"{started}\"\n\n[process]\npoints = {n}\npoint_period_s = {pp:?}\naxes = \"{axes}\"\n",
        seed = cfg.seed,
        // Ten runs a day, hourly from 08:00.
        started = crate::started::started_after(
            FIRST_START,
            (index / 10) as i64 * 24 * 60 + (index % 10) as i64 * 60
        ),
        pp = cfg.point_period_s,
        axes = AXES.join(""),
    );
    write_atomic(&dir.join("run.toml"), run_toml.as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn effects_resolve_with_defaults_and_reject_unknowns() {
        let s: Vec<EffectSpec> = vec!["thermal_growth".parse().unwrap()];
        let fx = resolve(&s).unwrap();
        assert_eq!(fx.growth, Some((0.025, 600.0, 6.0)));
        assert!(resolve(&["thermal_growth=tau=3".parse().unwrap()]).is_err());
        assert!(resolve(&["drift:t_s".parse().unwrap()]).is_err());
        let w = resolve(&["x_waviness=lambda_mm=50".parse().unwrap()]).unwrap();
        assert_eq!(w.waviness, Some((0.006, 50.0, 0.0)));
        let d = w.offset(&[12.5, 0.0, 0.0], 0.0);
        assert!((d.z - 0.006).abs() < 1e-12);
    }

    #[test]
    fn fleet_is_deterministic() {
        let a = tempfile::tempdir().unwrap();
        let b = tempfile::tempdir().unwrap();
        let cfg = MillFleetConfig {
            runs: 2,
            seed: 4,
            points: 40,
            ..Default::default()
        };
        let fx: Vec<EffectSpec> = vec!["thermal_growth".parse().unwrap()];
        generate_fleet(a.path(), &cfg, &fx).unwrap();
        generate_fleet(b.path(), &cfg, &fx).unwrap();
        assert_eq!(
            crate::generator::truth_files_round_trip::<RunTruth>(a.path()),
            2
        );
        for f in [
            "tracker.parquet",
            "thermal.parquet",
            "truth.json",
            "run.toml",
        ] {
            let p = format!("{MACHINE_ID}/r0001/{f}");
            assert_eq!(
                std::fs::read(a.path().join(&p)).unwrap(),
                std::fs::read(b.path().join(&p)).unwrap(),
                "{f}"
            );
        }
    }
}

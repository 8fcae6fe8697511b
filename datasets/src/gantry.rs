//! Synthetic gantry runs (docs/models.md §2): the gantry plugin's own forward
//! model plus injected effects and measurement noise, seeded and
//! deterministic.
//!
//! Each run: a `pattern` state (a reference surface ±a few µm), an
//! `after_grind` state (the machine's modelled Z error τ_dynamic printed
//! into the stone, plus random waviness), the polishing raster that was run
//! (motion.parquet) and the `after_polish` state: the ground surface minus
//! the Preston removal of that path. Effects act during polishing through
//! the disc's contact pressure, per path sample (the spring-loaded disc
//! turns any tool height change δ into a pressure change −δ/compression):
//! - `thermal_bow`: the bridge bows upward as it warms, 4A(y−c0)(c1−y)/(c1−c0)²
//!   · (1 − e^(−t/τ)) over the piece's y range (defaults amplitude_mm=0.05,
//!   tau_s=150): less pressure, less removal in the middle of the bridge;
//! - `raster_end_pressure`: pressure rises by k·e^(−d/λ) near raster ends
//!   (d = distance to the pass end; defaults k=0.3, lambda_mm=60);
//! - `tool_wear`: the pad's Preston coefficient falls by k·V (V = volume the
//!   tool has removed, mm³; default k_per_mm3=2e-6);
//! - `spindle_drift`: the spindle grows downward by A(1 − e^(−t/τ)) (defaults
//!   amplitude_mm=0.03, tau_s=120): more pressure as the run goes on.

use std::path::{Path, PathBuf};

use crate::generator::{DemoFleet, FleetGenerator, RunSize};
use crate::rng::{normal, stream_rng};
use crate::{bail, Context, Result};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sparkout_pipeline::contracts::{
    write_atomic, write_json_atomic, write_parquet_atomic, BatchBuilder, MachineConfig,
    MotionColumns,
};
use sparkout_pipeline::EffectSpec;
use sparkout_plugins::gantry::grid::Grid;
use sparkout_plugins::gantry::machine::{Gantry, PassAxis};
use sparkout_plugins::gantry::matrices::topography;
use sparkout_plugins::gantry::removal::plan_raster;
use sparkout_plugins::gantry::tool_influence::{dwell_map, removal_of_dwell};
use sparkout_plugins::gantry::{builtin_machine, APLM_GANTRY_TOML};

/// Settings of a generated gantry fleet (small defaults: tests are fast).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GantryFleetConfig {
    pub runs: usize,
    pub seed: u64,
    pub machine: String,
    /// Grid: nx × ny nodes every `step_mm` from (x0, y0), machine frame.
    pub nx: usize,
    pub ny: usize,
    pub x0_mm: f64,
    pub y0_mm: f64,
    pub step_mm: f64,
    pub tool_radius_mm: f64,
    pub step_over_mm: f64,
    /// Polishing feed drawn per run in [lo, hi], mm/s.
    pub feed_mm_s: (f64, f64),
    /// Height measurement noise σ, mm.
    pub noise_mm: f64,
    /// Pattern surface form amplitude, mm.
    pub pattern_mm: f64,
    /// Ground-surface waviness amplitude, mm.
    pub waviness_mm: f64,
}

impl Default for GantryFleetConfig {
    fn default() -> Self {
        GantryFleetConfig {
            runs: 8,
            seed: 0,
            machine: "aplm-gantry".into(),
            nx: 41,
            ny: 31,
            x0_mm: 600.0,
            y0_mm: 450.0,
            step_mm: 30.0,
            tool_radius_mm: 100.0,
            step_over_mm: 50.0,
            feed_mm_s: (80.0, 120.0),
            noise_mm: 0.0005,
            pattern_mm: 0.005,
            waviness_mm: 0.01,
        }
    }
}

impl GantryFleetConfig {
    pub fn validate(&self) -> Result<()> {
        if self.runs == 0 {
            bail!("gantry generator: runs must be at least 1");
        }
        if self.nx < 3 || self.ny < 3 {
            bail!("gantry generator: the grid needs at least 3 × 3 nodes");
        }
        for (n, v) in [
            ("step_mm", self.step_mm),
            ("tool_radius_mm", self.tool_radius_mm),
            ("step_over_mm", self.step_over_mm),
            ("feed_mm_s (low)", self.feed_mm_s.0),
        ] {
            if !(v.is_finite() && v > 0.0) {
                bail!("gantry generator: {n} must be a positive number, got {v}");
            }
        }
        if self.feed_mm_s.1 < self.feed_mm_s.0 {
            bail!("gantry generator: feed range must be low ≤ high");
        }
        if self.noise_mm < 0.0 || self.pattern_mm < 0.0 || self.waviness_mm < 0.0 {
            bail!("gantry generator: noise, pattern and waviness amplitudes must be ≥ 0");
        }
        Ok(())
    }
    pub fn grid(&self) -> Grid {
        Grid::new(
            self.x0_mm,
            self.step_mm,
            self.nx,
            self.y0_mm,
            self.step_mm,
            self.ny,
        )
    }
}

/// The injectable effects, for `--help`.
pub fn known_effects() -> Vec<(&'static str, &'static str)> {
    vec![
        ("thermal_bow", "bridge bows up by amplitude_mm·4(y−c0)(c1−y)/(c1−c0)²·(1−e^(−t/tau_s)) over the piece's y range while polishing (defaults amplitude_mm=0.05, tau_s=150); the spring-loaded disc loses pressure δ/compression → surface_z gap ∝ bow(y)·drift(t)"),
        ("raster_end_pressure", "pressure rises by k·e^(−d/lambda_mm) within the raster ends (d = distance along the pass to its end; defaults k=0.3, lambda_mm=60) → more removal near path ends"),
        ("tool_wear", "Preston coefficient falls by k_per_mm3 × volume removed so far (default k_per_mm3=2e-6) → less removal late in the run"),
        ("spindle_drift", "spindle grows down by amplitude_mm·(1−e^(−t/tau_s)) (defaults amplitude_mm=0.03, tau_s=120) → more pressure, more removal as the run goes on"),
    ]
}

#[derive(Debug, Clone, Copy, Default)]
struct Effects {
    bow: Option<(f64, f64)>,
    end: Option<(f64, f64)>,
    wear: Option<f64>,
    drift: Option<(f64, f64)>,
}

fn resolve(specs: &[EffectSpec]) -> Result<Effects> {
    let mut e = Effects::default();
    for s in specs {
        match s.name.as_str() {
            "thermal_bow" => {
                e.bow = Some((s.param_or("amplitude_mm", 0.05), s.param_or("tau_s", 150.0)))
            }
            "raster_end_pressure" => {
                e.end = Some((s.param_or("k", 0.3), s.param_or("lambda_mm", 60.0)))
            }
            "tool_wear" => e.wear = Some(s.param_or("k_per_mm3", 2e-6)),
            "spindle_drift" => {
                e.drift = Some((s.param_or("amplitude_mm", 0.03), s.param_or("tau_s", 120.0)))
            }
            other => {
                let names: Vec<&str> = known_effects().iter().map(|k| k.0).collect();
                bail!(
                    "gantry generator: unknown effect `{other}` (known: {})",
                    names.join(", ")
                )
            }
        }
    }
    Ok(e)
}

/// truth.json, written and read back through this type.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct RunTruth {
    run: String,
    run_index: usize,
    seed: u64,
    polish_feed_mm_s: f64,
    polish_duration_s: f64,
    removal_mean_mm: f64,
    noise_mm: f64,
    effects: Vec<EffectSpec>,
}

/// A smooth random surface: a few low-order waves of total amplitude ≈ amp.
fn smooth(rng: &mut ChaCha8Rng, grid: &Grid, amp: f64) -> Vec<f64> {
    let (lx, ly) = (grid.x_max() - grid.x0, grid.y_max() - grid.y0);
    let waves: Vec<(f64, f64, f64, f64)> = (0..4)
        .map(|_| {
            (
                amp / 2.0 * (2.0 * rng.random::<f64>() - 1.0),
                rng.random_range(0.5..2.0) * std::f64::consts::PI / lx,
                rng.random_range(0.5..2.0) * std::f64::consts::PI / ly,
                rng.random_range(0.0..std::f64::consts::TAU),
            )
        })
        .collect();
    (0..grid.len())
        .map(|k| {
            let (x, y) = grid.xy(k);
            waves
                .iter()
                .map(|(a, kx, ky, ph)| {
                    a * (kx * (x - grid.x0) + ph).sin() * (ky * (y - grid.y0) + 0.5 * ph).cos()
                })
                .sum()
        })
        .collect()
}

/// `sparkout generate gantry` and the gantry fleet of `sparkout demo`.
pub const GENERATOR: FleetGenerator<GantryFleetConfig> = FleetGenerator {
    name: "gantry",
    known_effects,
    config: |runs, seed| GantryFleetConfig {
        runs,
        seed,
        ..GantryFleetConfig::default()
    },
    generate_fleet,
    demo: Some(DemoFleet {
        runs: 6,
        seed: 1,
        effect: "thermal_bow",
    }),
    run_size: RunSize {
        disk_bytes: 57_648,
        memory_bytes: 12_300_000,
    },
};

/// Generate the fleet under `<root>/<machine>/r0000 …`.
pub fn generate_fleet(
    root: &Path,
    cfg: &GantryFleetConfig,
    effects: &[EffectSpec],
) -> Result<Vec<PathBuf>> {
    cfg.validate()?;
    let fx = resolve(effects)?;
    let dir = root.join(&cfg.machine);
    (0..cfg.runs)
        .into_par_iter()
        .map(|i| {
            let d = dir.join(format!("r{i:04}"));
            generate_run(&d, cfg, &fx, effects, i)
                .with_context(|| format!("generating gantry run {}", d.display()))?;
            Ok(d)
        })
        .collect()
}

/// A gantry fleet runs once a day at 08:00 from 2026-11-01.
const FIRST_START: crate::started::FirstStart = crate::started::FirstStart::at(2026, 11, 1, 8);

fn run_toml(cfg: &GantryFleetConfig, id: &str, index: usize, feed: f64) -> String {
    format!(
        r#"# Generated by sparkout-datasets (gantry fleet generator, seed {seed}).
[run]
id = "{id}"
machine = "{machine}"
plugin = "gantry"
started = "{started}"

[process]
tool_radius_mm = {r:?}
step_over_mm = {so:?}
feed_mm_s = {feed:?}
"#,
        seed = cfg.seed,
        machine = cfg.machine,
        started = crate::started::started_at(FIRST_START, 24 * 60, index),
        r = cfg.tool_radius_mm,
        so = cfg.step_over_mm,
    )
}

fn generate_run(
    dir: &Path,
    cfg: &GantryFleetConfig,
    fx: &Effects,
    specs: &[EffectSpec],
    index: usize,
) -> Result<()> {
    let mut rng = stream_rng(cfg.seed, index as u64 * 4 + 1);
    let id = format!("r{index:04}");
    let feed = rng.random_range(cfg.feed_mm_s.0..=cfg.feed_mm_s.1);
    let text = run_toml(cfg, &id, index, feed);
    let spec = sparkout_pipeline::contracts::RunSpec::parse(dir, &text)?;
    let m: MachineConfig = if cfg.machine == "aplm-gantry" {
        builtin_machine()?
    } else {
        MachineConfig {
            id: cfg.machine.clone(),
            source: "generator".into(),
            table: APLM_GANTRY_TOML.parse()?,
            text: APLM_GANTRY_TOML.into(),
            ..Default::default()
        }
    };
    let g = Gantry::from_run(&m, &spec)?;
    let grid = cfg.grid();
    let noise = |rng: &mut ChaCha8Rng| cfg.noise_mm * normal(rng);

    let pattern_true = smooth(&mut rng, &grid, cfg.pattern_mm);
    let tau = topography(&g, &grid, true)?.tau;
    let wav = smooth(&mut rng, &grid, cfg.waviness_mm);
    let ground: Vec<f64> = (0..grid.len()).map(|k| tau[k] + wav[k]).collect();

    let axis_x = g.pass_axis == PassAxis::X;
    let path = plan_raster(&grid, &g.polish, axis_x);
    let vol_rate = g.polish.volume_rate_mm3_s();
    let comp = g.polish.spring_compression_mm;
    let (c0, c1) = (grid.y0, grid.y_max());
    let mut cum = 0.0;
    let mult: Vec<f64> = path
        .iter()
        .map(|p| {
            let mut m = 1.0;
            if let Some((a, tau)) = fx.bow {
                let bow = 4.0 * a * (p.y_mm - c0) * (c1 - p.y_mm) / (c1 - c0).powi(2);
                m -= bow * (1.0 - (-p.t_s / tau).exp()) / comp;
            }
            if let Some((a, tau)) = fx.drift {
                m += a * (1.0 - (-p.t_s / tau).exp()) / comp;
            }
            if let Some((k, lam)) = fx.end {
                if p.segment >= 0 && p.path_end_mm.is_finite() {
                    m += k * (-p.path_end_mm / lam).exp();
                }
            }
            if let Some(k) = fx.wear {
                m -= k * cum * vol_rate;
            }
            cum += p.dt_s;
            m.max(0.0)
        })
        .collect();
    let removal = removal_of_dwell(&grid, &g.polish, &dwell_map(&grid, &path, |k| mult[k]));

    let mut rows: (Vec<&str>, Vec<f64>, Vec<f64>, Vec<f64>) = Default::default();
    let mut push = |state: &'static str, z: &[f64], rng: &mut ChaCha8Rng| {
        for (k, zz) in z.iter().enumerate() {
            let (x, y) = grid.xy(k);
            rows.0.push(state);
            rows.1.push(x);
            rows.2.push(y);
            rows.3.push(zz + noise(rng));
        }
    };
    push("pattern", &pattern_true, &mut rng);
    push("after_grind", &ground, &mut rng);
    let polished: Vec<f64> = (0..grid.len()).map(|k| ground[k] - removal[k]).collect();
    push("after_polish", &polished, &mut rng);
    let topo = BatchBuilder::new()
        .str("state", &rows.0)
        .f64("x_mm", rows.1)
        .f64("y_mm", rows.2)
        .f64("z_mm", rows.3)
        .build();
    write_parquet_atomic(&dir.join("topography.parquet"), &topo)?;
    let motion = MotionColumns {
        t_s: path.iter().map(|p| p.t_s).collect(),
        cmd_mm: [
            path.iter().map(|p| p.x_mm).collect(),
            path.iter().map(|p| p.y_mm).collect(),
            vec![0.0; path.len()],
        ],
        act_mm: None,
        feed_mm_s: Some(vec![feed; path.len()]),
        segment: Some(path.iter().map(|p| p.segment).collect()),
    };
    write_parquet_atomic(&dir.join("motion.parquet"), &motion.into_batch())?;
    let truth = RunTruth {
        run: id.clone(),
        run_index: index,
        seed: cfg.seed,
        polish_feed_mm_s: feed,
        polish_duration_s: path.last().map(|p| p.t_s).unwrap_or(0.0),
        removal_mean_mm: removal.iter().sum::<f64>() / removal.len() as f64,
        noise_mm: cfg.noise_mm,
        effects: specs.to_vec(),
    };
    write_json_atomic(&dir.join("truth.json"), &truth)?;
    write_atomic(&dir.join("run.toml"), text.as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_bytes_and_effects_change_the_polished_state() {
        let d = tempfile::tempdir().unwrap();
        let cfg = GantryFleetConfig {
            runs: 1,
            nx: 15,
            ny: 11,
            ..Default::default()
        };
        let a = generate_fleet(&d.path().join("a"), &cfg, &[]).unwrap();
        let b = generate_fleet(&d.path().join("b"), &cfg, &[]).unwrap();
        let read = |p: &Path| std::fs::read(p.join("topography.parquet")).unwrap();
        assert_eq!(read(&a[0]), read(&b[0]));
        let e: EffectSpec = "thermal_bow".parse().unwrap();
        let c = generate_fleet(&d.path().join("c"), &cfg, &[e]).unwrap();
        assert_ne!(read(&a[0]), read(&c[0]));
        assert_eq!(
            crate::generator::truth_files_round_trip::<RunTruth>(&d.path().join("c")),
            1
        );
        assert!(generate_fleet(&d.path().join("x"), &cfg, &["nope".parse().unwrap()]).is_err());
    }
}

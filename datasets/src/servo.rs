//! Synthetic servo traces (docs/servo.md): a three-axis machine (the
//! built-in `servo-mill`) runs a ballbar-like program — circles in XY at
//! random radius, feed and sense, joined by XY moves and Z lifts, every
//! move with a smooth (1 − cos) velocity profile — and logs commanded and
//! actual positions, velocities and commanded accelerations
//! (motion.parquet v1.1) at `sample_rate_hz`.
//!
//! The actual axis follows the plugin's own first-order servo model
//! (`sparkout_plugins::servo::model`), so an effect-free fleet has no gap
//! beyond encoder noise and logging resolution. Injectable effects (what
//! the real machine does and the model lacks), per axis alike:
//! - `servo_lag` — the axis lags k_s seconds less than the model (k_s < 0:
//!   more): its true gain is 1/Kv' = 1/Kv − k_s/(1 − ff). Following-error
//!   gap ≈ k_s·v (the diagnosis' `servo_lag:cmd_v_mm_s` k).
//! - `backlash` — lost motion b_mm: actual += b_mm·dir/2.
//! - `reversal_spike` — friction at a reversal: actual +=
//!   amplitude_mm·dir·e^(−d/lambda_mm), d = distance since the reversal.
//! - `accel_lag` — actual += k_s2·a_cmd (a loop that is not first order).
//!
//! Determinism: per-run ChaCha8 streams keyed by (seed, run index).

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use crate::{bail, Context, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sparkout_pipeline::contracts::{
    write_atomic, write_json_atomic, write_parquet_atomic, BatchBuilder, MachineConfig,
};
use sparkout_pipeline::EffectSpec;

use crate::{DemoFleet, FleetGenerator, RunSize};
use sparkout_plugins::servo::config::ServoMachine;
use sparkout_plugins::servo::model::{simulate, AxisServo};
use sparkout_plugins::servo::trace::{derivative, direction};
use sparkout_plugins::servo::SERVO_MILL_TOML;

pub const MACHINE_ID: &str = "servo-mill";

/// Fleet settings.
#[derive(Debug, Clone)]
pub struct ServoFleetConfig {
    pub runs: usize,
    pub seed: u64,
    /// Circles per run.
    pub circles: usize,
    pub sample_rate_hz: f64,
    /// Encoder noise of the actual position, mm (before the logging
    /// resolution rounds it).
    pub noise_mm: f64,
}

impl Default for ServoFleetConfig {
    fn default() -> Self {
        ServoFleetConfig {
            runs: 4,
            seed: 0,
            circles: 3,
            sample_rate_hz: 50.0,
            noise_mm: 0.0003,
        }
    }
}

impl ServoFleetConfig {
    pub fn validate(&self) -> Result<()> {
        if self.runs == 0 {
            bail!("--runs must be ≥ 1");
        }
        if self.circles == 0 || self.circles > 100 {
            bail!("circles per run must be in 1..=100, got {}", self.circles);
        }
        if !(self.sample_rate_hz.is_finite() && (1.0..=10_000.0).contains(&self.sample_rate_hz)) {
            bail!(
                "sample_rate_hz must be in 1..=10000, got {}",
                self.sample_rate_hz
            );
        }
        if !(self.noise_mm.is_finite() && self.noise_mm >= 0.0) {
            bail!("noise_mm must be ≥ 0");
        }
        Ok(())
    }
}

/// The injectable effects, for `--list-effects`.
pub fn known_effects() -> Vec<(&'static str, &'static str)> {
    vec![
        (
            "servo_lag",
            "every axis lags k_s seconds less than the model (negative: more) (default k_s=0.005); following_error gap ≈ k_s·cmd_v_mm_s",
        ),
        (
            "backlash",
            "lost motion at reversals: actual += b_mm·dir/2 (default b_mm=0.004)",
        ),
        (
            "reversal_spike",
            "friction spike after each reversal: actual += amplitude_mm·dir·e^(−d/lambda_mm), d = distance since the reversal (defaults amplitude_mm=0.006, lambda_mm=0.5)",
        ),
        (
            "accel_lag",
            "error ∝ commanded acceleration: actual += k_s2·cmd_a (default k_s2=0.0005)",
        ),
    ]
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
struct Effects {
    lag_k_s: Option<f64>,
    backlash_mm: Option<f64>,
    /// (amplitude_mm, lambda_mm)
    spike: Option<(f64, f64)>,
    accel_k_s2: Option<f64>,
}

fn resolve(specs: &[EffectSpec], m: &ServoMachine) -> Result<Effects> {
    let mut fx = Effects::default();
    let twice = |name: &str| crate::err!("effect `{name}` given twice");
    for s in specs {
        let keys = |k: &[&str]| s.check_params(k).map_err(crate::Error::msg);
        match (s.name.as_str(), s.covariate.as_deref()) {
            ("servo_lag", None | Some("cmd_v_mm_s")) => {
                keys(&["k_s"])?;
                let k = s.param_or("k_s", 0.005);
                let min_lag = m.axes.iter().map(|a| a.lag_s()).fold(f64::INFINITY, f64::min);
                if k >= min_lag {
                    bail!("effect `servo_lag`: k_s must be < the model's lag {min_lag} s (the axis cannot lead), got {k}");
                }
                if fx.lag_k_s.replace(k).is_some() {
                    return Err(twice("servo_lag"));
                }
            }
            ("backlash", None | Some("dir")) => {
                keys(&["b_mm"])?;
                let b = s.param_or("b_mm", 0.004);
                if b.abs() > 1.0 {
                    bail!("effect `backlash`: |b_mm| must be ≤ 1, got {b}");
                }
                if fx.backlash_mm.replace(b).is_some() {
                    return Err(twice("backlash"));
                }
            }
            ("reversal_spike", None) => {
                keys(&["amplitude_mm", "lambda_mm"])?;
                let l = s.param_or("lambda_mm", 0.5);
                if l <= 0.0 {
                    bail!("effect `reversal_spike`: lambda_mm must be > 0, got {l}");
                }
                if fx.spike.replace((s.param_or("amplitude_mm", 0.006), l)).is_some() {
                    return Err(twice("reversal_spike"));
                }
            }
            ("accel_lag", None | Some("cmd_a_mm_s2")) => {
                keys(&["k_s2"])?;
                if fx.accel_k_s2.replace(s.param_or("k_s2", 0.0005)).is_some() {
                    return Err(twice("accel_lag"));
                }
            }
            _ => bail!(
                "unknown servo effect `{}` (known: servo_lag, backlash, reversal_spike, accel_lag; see `sparkout generate servo --list-effects`)",
                s.key()
            ),
        }
    }
    Ok(fx)
}

/// The built-in machine.
pub fn machine() -> Result<ServoMachine> {
    let cfg = MachineConfig {
        id: MACHINE_ID.into(),
        source: "built-in machine `servo-mill`".into(),
        table: SERVO_MILL_TOML.parse()?,
        text: SERVO_MILL_TOML.into(),
        ..Default::default()
    };
    Ok(ServoMachine::from_config(&cfg)?)
}

/// Commanded motion: per axis position, velocity, acceleration; feed and
/// segment per sample.
#[derive(Default)]
struct Path3 {
    t: Vec<f64>,
    p: [Vec<f64>; 3],
    v: [Vec<f64>; 3],
    a: [Vec<f64>; 3],
    feed: Vec<f64>,
    segment: Vec<i32>,
}

impl Path3 {
    fn push(&mut self, p: [f64; 3], v: [f64; 3], a: [f64; 3], feed: f64, seg: i32) {
        self.t.push(0.0); // set from the sample index when the program is done
        for k in 0..3 {
            self.p[k].push(p[k]);
            self.v[k].push(v[k]);
            self.a[k].push(a[k]);
        }
        self.feed.push(feed);
        self.segment.push(seg);
    }
    fn last(&self) -> [f64; 3] {
        [0, 1, 2].map(|k| *self.p[k].last().expect("path starts with a dwell"))
    }
}

/// A move from the current point to `to` in `dur` s with a (1 − cos)
/// velocity profile (zero velocity and acceleration at both ends), sampled
/// every `dt`.
fn line(path: &mut Path3, to: [f64; 3], dur: f64, dt: f64, seg: i32) {
    let from = path.last();
    let n = (dur / dt).round().max(1.0) as usize;
    let dur = n as f64 * dt;
    let d: Vec<f64> = (0..3).map(|k| to[k] - from[k]).collect();
    let len = d.iter().map(|x| x * x).sum::<f64>().sqrt();
    for i in 1..=n {
        let s = i as f64 * dt / dur;
        let u = s - (2.0 * PI * s).sin() / (2.0 * PI);
        let du = (1.0 - (2.0 * PI * s).cos()) / dur;
        let ddu = 2.0 * PI * (2.0 * PI * s).sin() / (dur * dur);
        path.push(
            [0, 1, 2].map(|k| from[k] + d[k] * u),
            [0, 1, 2].map(|k| d[k] * du),
            [0, 1, 2].map(|k| d[k] * ddu),
            len / dur,
            seg,
        );
    }
}

fn dwell(path: &mut Path3, dur: f64, dt: f64, seg: i32) {
    let p = path.last();
    for _ in 0..(dur / dt).round() as usize {
        path.push(p, [0.0; 3], [0.0; 3], 0.0, seg);
    }
}

/// 1.25 turns of a circle about `c` (radius r, feed f, sense ±1) from the
/// current point (which must be on it at angle 0), with smooth angular
/// ramps of `ramp_s` at both ends.
#[allow(clippy::too_many_arguments)]
fn circle(
    path: &mut Path3,
    c: [f64; 2],
    r: f64,
    f: f64,
    sense: f64,
    ramp_s: f64,
    dt: f64,
    seg: i32,
) {
    let w = f / r;
    let total = 2.5 * PI;
    let dur = total / w + ramp_s;
    // The last sample lands on the end of the circle (at rest), so the
    // next move starts where and as this one ends.
    let n = (dur / dt).ceil() as usize;
    let z = path.last()[2];
    // θ, θ', θ'' of the ramped profile (θ' = w·(1 − cos(πt/T))/2 on the ramps).
    let up = |t: f64| {
        (
            w * (t / 2.0 - ramp_s / (2.0 * PI) * (PI * t / ramp_s).sin()),
            w * (1.0 - (PI * t / ramp_s).cos()) / 2.0,
            w * PI / (2.0 * ramp_s) * (PI * t / ramp_s).sin(),
        )
    };
    for i in 1..=n {
        let t = (i as f64 * dt).min(dur);
        let (th, dth, ddth) = if t < ramp_s {
            up(t)
        } else if t <= dur - ramp_s {
            (w * (ramp_s / 2.0 + (t - ramp_s)), w, 0.0)
        } else {
            let (a, b, c) = up(dur - t);
            (total - a, b, -c)
        };
        let (th, dth, ddth) = (sense * th, sense * dth, sense * ddth);
        let (s, co) = th.sin_cos();
        path.push(
            [c[0] + r * co, c[1] + r * s, z],
            [-r * s * dth, r * co * dth, 0.0],
            [
                -r * co * dth * dth - r * s * ddth,
                -r * s * dth * dth + r * co * ddth,
                0.0,
            ],
            f,
            seg,
        );
    }
}

fn program(cfg: &ServoFleetConfig, rng: &mut ChaCha8Rng) -> Path3 {
    let dt = 1.0 / cfg.sample_rate_hz;
    let mut path = Path3::default();
    let centre = [200.0, 150.0];
    let z0 = 50.0;
    let r0 = 20.0 + 40.0 * rng.random::<f64>();
    path.push([centre[0] + r0, centre[1], z0], [0.0; 3], [0.0; 3], 0.0, 0);
    dwell(&mut path, 0.5, dt, 0);
    let mut r = r0;
    for c in 0..cfg.circles {
        let seg = 2 * c as i32 + 1;
        let f = 15.0 + 25.0 * rng.random::<f64>();
        let sense = if rng.random::<bool>() { 1.0 } else { -1.0 };
        circle(&mut path, centre, r, f, sense, 0.3, dt, seg);
        // Lift, move to the next circle's start, lower.
        let next_r = 20.0 + 40.0 * rng.random::<f64>();
        let p = path.last();
        line(&mut path, [p[0], p[1], z0 + 5.0], 1.0, dt, seg + 1);
        line(
            &mut path,
            [centre[0] + next_r, centre[1], z0 + 5.0],
            1.0,
            dt,
            seg + 1,
        );
        line(
            &mut path,
            [centre[0] + next_r, centre[1], z0],
            1.0,
            dt,
            seg + 1,
        );
        dwell(&mut path, 0.3, dt, seg + 1);
        r = next_r;
    }
    for (i, t) in path.t.iter_mut().enumerate() {
        *t = i as f64 * dt;
    }
    path
}

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    rng.sample(StandardNormal)
}

/// Round to a logging step (0 = as is).
fn quantise(v: f64, step: f64) -> f64 {
    if step > 0.0 {
        (v / step).round() * step
    } else {
        v
    }
}

/// truth.json, written and read back through this type.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct RunTruth {
    run: String,
    seed: u64,
    machine: String,
    samples: usize,
    sample_rate_hz: f64,
    noise_mm: f64,
    effects: Vec<EffectSpec>,
    resolved: Effects,
}

/// `sparkout generate servo` and the demo's 4-run servo fleet.
pub const GENERATOR: FleetGenerator<ServoFleetConfig> = FleetGenerator {
    name: "servo",
    known_effects,
    config: |runs, seed| ServoFleetConfig {
        runs,
        seed,
        ..ServoFleetConfig::default()
    },
    generate_fleet,
    demo: Some(DemoFleet {
        runs: 4,
        seed: 1,
        effect: "servo_lag",
    }),
    run_size: RunSize {
        disk_bytes: 175_854,
        memory_bytes: 9_600_000,
    },
};

/// Generate `<root>/servo-mill/r0000 …`; returns the run dirs in order.
pub fn generate_fleet(
    root: &Path,
    cfg: &ServoFleetConfig,
    effects: &[EffectSpec],
) -> Result<Vec<PathBuf>> {
    cfg.validate()?;
    let m = machine()?;
    let fx = resolve(effects, &m)?;
    let dir = root.join(MACHINE_ID);
    (0..cfg.runs)
        .into_par_iter()
        .map(|i| {
            let d = dir.join(format!("r{i:04}"));
            generate_run(&d, cfg, &m, &fx, effects, i)
                .with_context(|| format!("generating servo run {}", d.display()))?;
            Ok(d)
        })
        .collect()
}

fn generate_run(
    dir: &Path,
    cfg: &ServoFleetConfig,
    m: &ServoMachine,
    fx: &Effects,
    specs: &[EffectSpec],
    index: usize,
) -> Result<()> {
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    rng.set_stream(index as u64);
    let path = program(cfg, &mut rng);
    let t = &path.t;
    let n = t.len();
    let (q_pos, q_vel) = (m.position.fixed, m.velocity.fixed);
    let mut b = BatchBuilder::new().f64("t_s", t.clone());
    let names = ["x", "y", "z"];
    let mut cols: Vec<(String, Vec<f64>)> = Vec::new();
    for (k, &a) in names.iter().enumerate() {
        let s = m.axes[k];
        let true_servo = match fx.lag_k_s {
            Some(lag) => AxisServo {
                kv_1_s: (1.0 - s.ff) / (s.lag_s() - lag),
                ff: s.ff,
            },
            None => s,
        };
        let (e, edot) = simulate(true_servo, t, &path.v[k]);
        let (dir_k, dist) = direction(t, &path.v[k], 1e-3);
        let jerk = derivative(t, &path.a[k]);
        let mut act = Vec::with_capacity(n);
        let mut act_v = Vec::with_capacity(n);
        for i in 0..n {
            let (mut x, mut xv) = (path.p[k][i] + e[i], path.v[k][i] + edot[i]);
            if let Some(bl) = fx.backlash_mm {
                x += bl * dir_k[i] / 2.0;
            }
            if let Some((amp, lambda)) = fx.spike {
                let g = amp * dir_k[i] * (-dist[i] / lambda).exp();
                x += g;
                xv -= g * path.v[k][i].abs() / lambda;
            }
            if let Some(ka) = fx.accel_k_s2 {
                x += ka * path.a[k][i];
                xv += ka * jerk[i];
            }
            act.push(quantise(x + cfg.noise_mm * normal(&mut rng), q_pos));
            act_v.push(quantise(
                xv + cfg.noise_mm * cfg.sample_rate_hz * normal(&mut rng) / 10.0,
                q_vel,
            ));
        }
        cols.push((
            format!("cmd_{a}_mm"),
            path.p[k].iter().map(|v| quantise(*v, q_pos)).collect(),
        ));
        cols.push((format!("act_{a}_mm"), act));
        cols.push((
            format!("cmd_v_{a}_mm_s"),
            path.v[k].iter().map(|v| quantise(*v, q_vel)).collect(),
        ));
        cols.push((format!("act_v_{a}_mm_s"), act_v));
        cols.push((format!("cmd_a_{a}_mm_s2"), path.a[k].clone()));
    }
    for (name, v) in cols {
        b = b.f64(&name, v);
    }
    b = b
        .f64("feed_mm_s", path.feed.clone())
        .i32("segment", path.segment.clone());
    let run_id = format!("r{index:04}");
    write_parquet_atomic(&dir.join("motion.parquet"), &b.build())?;
    let run_toml = format!(
        "[run]\nid = \"{run_id}\"\nmachine = \"{MACHINE_ID}\"\nplugin = \"servo\"\nstarted = \"2026-11-20T08:00:00Z\"\n"
    );
    write_atomic(&dir.join("run.toml"), run_toml.as_bytes())?;
    write_json_atomic(
        &dir.join("truth.json"),
        &RunTruth {
            run: run_id,
            seed: cfg.seed,
            machine: MACHINE_ID.to_string(),
            samples: n,
            sample_rate_hz: cfg.sample_rate_hz,
            noise_mm: cfg.noise_mm,
            effects: specs.to_vec(),
            resolved: *fx,
        },
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    // Stencils over i−1..=i+1 of several arrays: index loops read best.
    #[allow(clippy::needless_range_loop)]
    fn program_is_continuous_and_consistent() {
        let cfg = ServoFleetConfig::default();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let p = program(&cfg, &mut rng);
        let dt = 1.0 / cfg.sample_rate_hz;
        for k in 0..3 {
            let v = derivative(&p.t, &p.p[k]);
            for i in 1..p.t.len() - 1 {
                if p.segment[i - 1] != p.segment[i + 1] {
                    continue; // a junction: the last sample of a circle is clamped to its end
                }
                // Commanded velocity is the derivative of commanded position;
                // a central difference errs by up to dt·|a| over its stencil
                // (at the start of an acceleration a[i] itself is still 0).
                let a_max = (i - 1..=i + 1).map(|j| p.a[k][j].abs()).fold(0.0, f64::max);
                assert!(
                    (v[i] - p.v[k][i]).abs() < 0.05 * (1.0 + p.v[k][i].abs()) + 2.0 * dt * a_max,
                    "axis {k} sample {i}: {} vs {}",
                    v[i],
                    p.v[k][i]
                );
                assert!((p.p[k][i] - p.p[k][i - 1]).abs() < 2.0, "jump at {i}");
            }
        }
        // Reversals on every axis.
        for k in 0..3 {
            let (d, _) = direction(&p.t, &p.v[k], 1e-3);
            assert!(
                d.windows(2).any(|w| w[0] != w[1]),
                "axis {k} never reverses"
            );
        }
    }

    #[test]
    fn unknown_and_bad_effects_are_refused() {
        let m = machine().unwrap();
        let e = |s: &str| resolve(&[s.parse().unwrap()], &m);
        assert!(e("servo_lag=k_s=0.004").is_ok());
        assert!(e("servo_lag=k_s=0.1").is_err());
        assert!(e("backlash=c=1").is_err());
        assert!(e("wobble").is_err());
    }

    #[test]
    fn truth_json_reads_back_through_its_type() {
        let d = tempfile::tempdir().unwrap();
        let cfg = ServoFleetConfig {
            runs: 2,
            circles: 1,
            ..Default::default()
        };
        generate_fleet(d.path(), &cfg, &["servo_lag".parse().unwrap()]).unwrap();
        assert_eq!(
            crate::generator::truth_files_round_trip::<RunTruth>(d.path()),
            2
        );
    }
}

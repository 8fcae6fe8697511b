//! Synthetic form-grinding fleet (docs/models.md §4): one run per ground part.
//!
//! The wheel starts new (the machine's largest radius) and is dressed every
//! `parts_per_dressing` parts, losing `dressing_mm` of radius each time;
//! when the next dressing would leave the usable range, a new wheel is
//! mounted (as a shop does), so a fleet of any length stays in range.
//! Each part is ground with the program of the segment its dressed radius
//! falls into (the segmentation strategy of the source: N programs, each
//! for its segment's mean radius). Parts alternate between elliptical
//! sections (ellipses placed on a cylinder: the section of a cylinder of
//! radius b cut at an angle α has semi-axes b/cos α and b) and a tangent
//! cam with straight flanks.
//!
//! "Real" = the plugin's model δ(φ) for the dressed radius + injected
//! effects + measurement noise, along the profile normal; written as
//! measured radius vectors r = R(φ) + (δ + e + noise)/cos γ0. The model
//! (sim) knows the dressed radius only.

use std::path::{Path, PathBuf};

use crate::generator::{DemoFleet, FleetGenerator, RunSize};
use crate::rng::{normal, stream_rng};
use crate::{bail, Context, Result};
use arrow::array::{ArrayRef, Float64Array, StringArray};
use arrow::datatypes::{DataType, Field, Schema};
use arrow::record_batch::RecordBatch;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sparkout_pipeline::contracts::{write_atomic, write_json_atomic, write_parquet_atomic};
use sparkout_pipeline::diagnose::{shape_value, Kind};
use sparkout_pipeline::EffectSpec;
use sparkout_plugins::form::curvature::{CurvatureConfig, Profile};
use sparkout_plugins::form::model::{centre_path, profile_error, WheelRange};
use sparkout_plugins::form::shapes::{ellipse_r, sample, TangentCam};

/// Fleet settings.
#[derive(Debug, Clone)]
pub struct FormFleetConfig {
    pub runs: usize,
    pub seed: u64,
    pub machine: String,
    /// Profile points per part (design and measured).
    pub points: usize,
    pub parts_per_dressing: usize,
    /// Radius lost per dressing (mm).
    pub dressing_mm: f64,
    /// The wheel's usable range (the built-in machine's).
    pub range: WheelRange,
    /// Programs per wheel (segments of the usable range).
    pub segments: usize,
    /// Measurement noise (mm, 1σ, along the normal).
    pub noise_mm: f64,
    /// Radial stock removed per part (mm) and grinding width (mm): the
    /// wheel's usage removed_mm3 = stock × width × arc length.
    pub stock_mm: f64,
    pub width_mm: f64,
    pub feed_mm_s: f64,
}

impl Default for FormFleetConfig {
    fn default() -> Self {
        FormFleetConfig {
            runs: 12,
            seed: 0,
            machine: "form-grinder".into(),
            points: 360,
            parts_per_dressing: 3,
            dressing_mm: 1.5,
            range: WheelRange {
                r_max_mm: 175.0,
                range_mm: 50.0,
            },
            segments: 5,
            noise_mm: 0.0005,
            stock_mm: 0.05,
            width_mm: 20.0,
            feed_mm_s: 5.0,
        }
    }
}

impl FormFleetConfig {
    pub fn validate(&self) -> Result<()> {
        if self.runs == 0 {
            bail!("--runs must be ≥ 1");
        }
        if self.points < 32 {
            bail!("points per profile must be ≥ 32, found {}", self.points);
        }
        if self.parts_per_dressing == 0 {
            bail!("parts_per_dressing must be ≥ 1");
        }
        self.range.check().map_err(|m| crate::err!(m))?;
        if !(self.dressing_mm > 0.0 && self.dressing_mm <= self.range.range_mm) {
            bail!(
                "dressing_mm must be > 0 and at most the wheel's usable range ({} mm), found {}",
                self.range.range_mm,
                self.dressing_mm
            );
        }
        if !(self.noise_mm >= 0.0
            && self.stock_mm > 0.0
            && self.width_mm > 0.0
            && self.feed_mm_s > 0.0)
        {
            bail!("noise_mm must be ≥ 0 and stock_mm, width_mm, feed_mm_s > 0");
        }
        Ok(())
    }

    /// Dressings a wheel takes, counting the new wheel as dressing 0:
    /// every radius r_max − d·dressing_mm that stays in the usable range.
    pub fn dressings_per_wheel(&self) -> usize {
        // 1e-9: a range that is an exact multiple of dressing_mm keeps its
        // last dressing despite rounding (50 / 1.25 = 40 dressings).
        (self.range.range_mm / self.dressing_mm + 1e-9).floor() as usize + 1
    }

    /// Part `index`'s wheel (0 = the first), dressing on that wheel and
    /// part since that dressing.
    pub fn wheel_dressing_part(&self, index: usize) -> (usize, usize, usize) {
        let dressing = index / self.parts_per_dressing;
        let per_wheel = self.dressings_per_wheel();
        (
            dressing / per_wheel,
            dressing % per_wheel,
            index % self.parts_per_dressing,
        )
    }
}

/// The injectable effects, for `--list-effects`.
pub fn known_effects() -> Vec<(&'static str, &'static str)> {
    vec![
        (
            "wheel_wear",
            "the wheel wears between dressings in proportion to the volume it removes (grinding ratio): its true radius is k_mm_per_mm3·removed_mm3 below the dressed radius the controller knows (default k_mm_per_mm3=1.5e-5, ≈ 14 µm after 3 parts); profile_error gap = +k·removed_mm3 (material left along the normal)",
        ),
        (
            "runout",
            "work-spindle run-out / cyclic error: amplitude_mm·sin(lobes·φ + phase_rad) along the normal (defaults amplitude_mm=0.004, lobes=3, phase_rad=0.5); gap periodic in phi_rad",
        ),
        (
            "wheel_runout",
            "wheel run-out: an eccentric wheel's radius varies with the wheel angle, seen along the profile as amplitude_mm·sin(2π·t/period_s + phase_rad) (defaults amplitude_mm=0.004, period_s=10, phase_rad=0); gap periodic in t_s",
        ),
        (
            "<catalogue>:<covariate>",
            "any catalogue shape added to profile_error's real value with the pipeline's parameter names (required): covariates phi_rad, t_s, removed_mm3, wheel_radius_mm",
        ),
    ]
}

const COVARIATES: &[&str] = &["phi_rad", "t_s", "removed_mm3", "wheel_radius_mm"];

#[derive(Debug, Clone, Default)]
struct Effects {
    wear_k: f64,
    runout: Option<(f64, f64, f64)>,
    wheel_runout: Option<(f64, f64, f64)>,
    shapes: Vec<(Kind, String, std::collections::BTreeMap<String, f64>)>,
}

fn resolve(effects: &[EffectSpec]) -> Result<Effects> {
    let mut fx = Effects::default();
    for e in effects {
        match (e.name.as_str(), e.covariate.as_deref()) {
            ("wheel_wear", None) => fx.wear_k = e.param_or("k_mm_per_mm3", 1.5e-5),
            ("runout", None) => {
                fx.runout = Some((e.param_or("amplitude_mm", 0.004), e.param_or("lobes", 3.0), e.param_or("phase_rad", 0.5)))
            }
            ("wheel_runout", None) => {
                let p = e.param_or("period_s", 10.0);
                if p.is_nan() || p <= 0.0 {
                    bail!("--effect wheel_runout: period_s must be > 0");
                }
                fx.wheel_runout = Some((e.param_or("amplitude_mm", 0.004), p, e.param_or("phase_rad", 0.0)))
            }
            (name, Some(cov)) => {
                let kind = Kind::from_name(name).with_context(|| format!("--effect {}: unknown effect `{name}`", e.key()))?;
                if !COVARIATES.contains(&cov) {
                    bail!("--effect {}: the form generator's covariates are {}", e.key(), COVARIATES.join(", "));
                }
                if e.params.is_empty() {
                    bail!("--effect {}: give the shape's parameters (e.g. k=…, amplitude_mm=…)", e.key());
                }
                fx.shapes.push((kind, cov.to_string(), e.params.clone()));
            }
            (name, None) => bail!(
                "--effect `{name}`: unknown form effect (known: wheel_wear, runout, wheel_runout, or <catalogue>:<covariate>)"
            ),
        }
    }
    Ok(fx)
}

/// truth.json, written and read back through this type.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct RunTruth {
    run: String,
    run_index: usize,
    seed: u64,
    shape: String,
    shape_params: std::collections::BTreeMap<String, f64>,
    z_mm: f64,
    /// The wheel the part was ground with (0 = the first; a new one is
    /// mounted when the next dressing would leave the usable range).
    wheel: usize,
    /// Dressings of that wheel before the part.
    dressing: usize,
    part_in_dressing: usize,
    dressed_radius_mm: f64,
    nominal_radius_mm: f64,
    removed_before_mm3: f64,
    removed_per_part_mm3: f64,
    wear_k_mm_per_mm3: f64,
    wear_max_mm: f64,
    model_max_error_mm: f64,
    noise_mm: f64,
    effects: Vec<EffectSpec>,
}

/// The part's design profile: (shape name, parameters, z, φ, R).
#[allow(clippy::type_complexity)]
fn design(
    cfg: &FormFleetConfig,
    index: usize,
    rng: &mut ChaCha8Rng,
) -> Result<(
    String,
    std::collections::BTreeMap<String, f64>,
    f64,
    Vec<f64>,
    Vec<f64>,
)> {
    let z = 10.0 * index as f64;
    if index.is_multiple_of(2) {
        // An elliptical section of a cylinder of radius b cut at angle α.
        let b = 40.0;
        let alpha = (30.0 + 15.0 * rng.random::<f64>()).to_radians();
        let a = b / alpha.cos();
        let (phi, r) = sample(cfg.points, |p| ellipse_r(p, a, b));
        Ok((
            "ellipse".into(),
            [
                ("a_mm".to_string(), a),
                ("b_mm".to_string(), b),
                ("alpha_rad".to_string(), alpha),
            ]
            .into(),
            z,
            phi,
            r,
        ))
    } else {
        let cam = TangentCam {
            base: 40.0,
            nose: 12.0 + 4.0 * rng.random::<f64>(),
            lift_centre: 36.0,
        };
        cam.check().map_err(|m| crate::err!(m))?;
        let (phi, r) = sample(cfg.points, |p| cam.r(p));
        Ok((
            "tangent_cam".into(),
            [
                ("base_mm".to_string(), cam.base),
                ("nose_mm".to_string(), cam.nose),
                ("lift_centre_mm".to_string(), cam.lift_centre),
            ]
            .into(),
            z,
            phi,
            r,
        ))
    }
}

/// `sparkout generate form` and the form fleet of `sparkout demo`.
pub const GENERATOR: FleetGenerator<FormFleetConfig> = FleetGenerator {
    name: "form",
    known_effects,
    config: |runs, seed| FormFleetConfig {
        runs,
        seed,
        ..FormFleetConfig::default()
    },
    generate_fleet,
    demo: Some(DemoFleet {
        runs: 9,
        seed: 1,
        effect: "wheel_wear",
    }),
    run_size: RunSize {
        disk_bytes: 19_970,
        memory_bytes: 7_600_000,
    },
};

/// Generate the fleet under `root/<machine>/rNNNN/`.
pub fn generate_fleet(
    root: &Path,
    cfg: &FormFleetConfig,
    effects: &[EffectSpec],
) -> Result<Vec<PathBuf>> {
    cfg.validate()?;
    let fx = resolve(effects)?;
    let machine_dir = root.join(&cfg.machine);
    (0..cfg.runs)
        .into_par_iter()
        .map(|i| {
            let dir = machine_dir.join(format!("r{i:04}"));
            generate_run(&dir, cfg, &fx, effects, i)
                .with_context(|| format!("generating form run {}", dir.display()))?;
            Ok(dir)
        })
        .collect()
}

/// A form fleet's first run starts at 06:00, the next every 20 minutes.
const FIRST_START: crate::started::FirstStart = crate::started::FirstStart::at(2026, 11, 20, 6);

fn generate_run(
    dir: &Path,
    cfg: &FormFleetConfig,
    fx: &Effects,
    specs: &[EffectSpec],
    index: usize,
) -> Result<()> {
    let mut rng = stream_rng(cfg.seed, index as u64 + 1);
    let run_id = format!("r{index:04}");
    let (shape, params, z, phi, r) = design(cfg, index, &mut rng)?;
    let (wheel_no, dressing, part) = cfg.wheel_dressing_part(index);
    let rk = cfg.range.r_max_mm - dressing as f64 * cfg.dressing_mm;
    // The program of the segment the dressed radius falls into.
    let width = cfg.range.range_mm / cfg.segments as f64;
    let seg = (((cfg.range.r_max_mm - rk) / width).floor() as usize).min(cfg.segments - 1);
    let r_kn = cfg.range.r_max_mm - (seg as f64 + 0.5) * width;

    let p = Profile::new(&phi, &r, &CurvatureConfig::default()).map_err(|e| crate::err!("{e}"))?;
    let path = centre_path(&p, r_kn);
    let delta = profile_error(&p, &path, rk)
        .map_err(|i| crate::err!("wheel cannot follow the profile at point {i}"))?;
    let arc = p.arc_length_mm();
    let perimeter = arc[arc.len() - 1] + {
        let (a, b) = (p.point(p.len() - 1), p.point(0));
        (b[0] - a[0]).hypot(b[1] - a[1])
    };
    let per_part = cfg.stock_mm * cfg.width_mm * perimeter;
    let removed_before = part as f64 * per_part;
    let n = phi.len();
    let removed: Vec<f64> = arc
        .iter()
        .map(|s| removed_before + cfg.stock_mm * cfg.width_mm * s)
        .collect();
    let t_s: Vec<f64> = arc.iter().map(|s| s / cfg.feed_mm_s).collect();
    let wheel = vec![rk; n];

    let mut e = vec![0.0; n];
    for i in 0..n {
        e[i] += fx.wear_k * removed[i];
        if let Some((a, lobes, ph)) = fx.runout {
            e[i] += a * (lobes * phi[i] + ph).sin();
        }
        if let Some((a, period, ph)) = fx.wheel_runout {
            e[i] += a * (std::f64::consts::TAU * t_s[i] / period + ph).sin();
        }
    }
    for (kind, cov, prm) in &fx.shapes {
        let c: &[f64] = match cov.as_str() {
            "phi_rad" => &phi,
            "t_s" => &t_s,
            "removed_mm3" => &removed,
            _ => &wheel,
        };
        for (o, v) in e.iter_mut().zip(shape_value(*kind, prm, c, None)) {
            *o += v;
        }
    }
    let measured: Vec<f64> = (0..n)
        .map(|i| {
            let noise: f64 = cfg.noise_mm * normal(&mut rng);
            r[i] + (delta[i] + e[i] + noise) / p.gamma0_rad[i].cos()
        })
        .collect();

    // profile.parquet: design rows then measured rows.
    let mut state = vec!["design"; n];
    state.extend(vec!["measured"; n]);
    let mut phis = phi.clone();
    phis.extend(&phi);
    let mut rs = r.clone();
    rs.extend(&measured);
    let wr: Vec<Option<f64>> = (0..2 * n).map(|k| (k >= n).then_some(rk)).collect();
    let schema = Schema::new(vec![
        Field::new("state", DataType::Utf8, false),
        Field::new("phi_rad", DataType::Float64, false),
        Field::new("r_mm", DataType::Float64, false),
        Field::new("wheel_radius_mm", DataType::Float64, true),
    ]);
    let cols: Vec<ArrayRef> = vec![
        std::sync::Arc::new(StringArray::from(state)),
        std::sync::Arc::new(Float64Array::from(phis)),
        std::sync::Arc::new(Float64Array::from(rs)),
        std::sync::Arc::new(Float64Array::from(wr)),
    ];
    let batch = RecordBatch::try_new(std::sync::Arc::new(schema), cols)?;
    std::fs::create_dir_all(dir)?;
    write_parquet_atomic(&dir.join("profile.parquet"), &batch)?;

    let truth = RunTruth {
        run: run_id.clone(),
        run_index: index,
        seed: cfg.seed,
        shape: shape.clone(),
        shape_params: params,
        z_mm: z,
        wheel: wheel_no,
        dressing,
        part_in_dressing: part,
        dressed_radius_mm: rk,
        nominal_radius_mm: r_kn,
        removed_before_mm3: removed_before,
        removed_per_part_mm3: per_part,
        wear_k_mm_per_mm3: fx.wear_k,
        wear_max_mm: fx.wear_k * removed[n - 1],
        model_max_error_mm: delta.iter().fold(0.0_f64, |m, d| m.max(d.abs())),
        noise_mm: cfg.noise_mm,
        effects: specs.to_vec(),
    };
    write_json_atomic(&dir.join("truth.json"), &truth)?;
    let toml = format!(
        r#"# Generated by sparkout-datasets (form fleet generator, seed {seed}).
[run]
id = "{run_id}"
machine = "{machine}"
plugin = "form"
started = "{started}"

[process]
shape = "{shape}"
z_mm = {z:?}
dressing = {dressing}
part_in_dressing = {part}
wheel_radius_mm = {rk:?}
nominal_wheel_radius_mm = {r_kn:?}
removed_before_mm3 = {removed_before:?}
stock_mm = {stock:?}
width_mm = {width:?}
feed_mm_s = {feed:?}
"#,
        seed = cfg.seed,
        machine = cfg.machine,
        started = crate::started::started_at(FIRST_START, 20, index),
        stock = cfg.stock_mm,
        width = cfg.width_mm,
        feed = cfg.feed_mm_s,
    );
    write_atomic(&dir.join("run.toml"), toml.as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fleet_is_deterministic_and_dresses_the_wheel() {
        let d = tempfile::tempdir().unwrap();
        let cfg = FormFleetConfig {
            runs: 7,
            seed: 5,
            points: 64,
            ..Default::default()
        };
        let fx: Vec<EffectSpec> = vec!["wheel_wear".parse().unwrap()];
        generate_fleet(&d.path().join("a"), &cfg, &fx).unwrap();
        generate_fleet(&d.path().join("b"), &cfg, &fx).unwrap();
        for r in ["r0000", "r0006"] {
            for f in ["profile.parquet", "truth.json", "run.toml"] {
                let a = std::fs::read(d.path().join("a/form-grinder").join(r).join(f)).unwrap();
                let b = std::fs::read(d.path().join("b/form-grinder").join(r).join(f)).unwrap();
                assert_eq!(a, b, "{r}/{f}");
            }
        }
        assert_eq!(
            crate::generator::truth_files_round_trip::<RunTruth>(&d.path().join("a")),
            7
        );
        let t: RunTruth = sparkout_pipeline::files::json::read_json(
            &d.path().join("a/form-grinder/r0006/truth.json"),
        )
        .unwrap();
        assert_eq!(t.dressing, 2);
        assert_eq!(t.dressed_radius_mm, 172.0);
        assert_eq!(t.nominal_radius_mm, 170.0);
        assert!(t.wear_max_mm > 0.0);
    }

    /// 34 dressed radii per wheel at the defaults (175 … 125.5 mm), 3 parts
    /// each: part 102 is the second wheel's first, new again.
    #[test]
    fn a_worn_out_wheel_is_replaced() {
        let cfg = FormFleetConfig {
            runs: 200,
            ..Default::default()
        };
        cfg.validate().unwrap();
        assert_eq!(cfg.dressings_per_wheel(), 34);
        assert_eq!(cfg.wheel_dressing_part(101), (0, 33, 2));
        assert_eq!(cfg.wheel_dressing_part(102), (1, 0, 0));
        assert_eq!(cfg.wheel_dressing_part(199), (1, 32, 1));
        let exact = FormFleetConfig {
            dressing_mm: 1.25,
            ..Default::default()
        };
        assert_eq!(exact.dressings_per_wheel(), 41);
        let d = tempfile::tempdir().unwrap();
        let cfg = FormFleetConfig {
            runs: 104,
            points: 64,
            ..Default::default()
        };
        generate_fleet(d.path(), &cfg, &[]).unwrap();
        let t: RunTruth = sparkout_pipeline::files::json::read_json(
            &d.path().join("form-grinder/r0103/truth.json"),
        )
        .unwrap();
        assert_eq!((t.wheel, t.dressing, t.dressed_radius_mm), (1, 0, 175.0));
    }

    #[test]
    fn bad_settings_are_rejected() {
        let cfg = FormFleetConfig {
            dressing_mm: 60.0,
            ..Default::default()
        };
        assert!(cfg.validate().is_err());
        assert!(resolve(&["nonsense".parse().unwrap()]).is_err());
        assert!(resolve(&["scale:x_mm=k=1".parse().unwrap()]).is_err());
        assert!(resolve(&["periodic:phi_rad=amplitude_mm=0.01,lambda=2"
            .parse()
            .unwrap()])
        .is_ok());
    }
}

//! The run-less metrology forms of `sparkout stage`:
//!
//! - `stage profile --profile FILE [--lambda-c MM] [--sampling-lengths N]
//!   [--x COL --z COL] [--x-unit U --z-unit U]`: straightness, P and R
//!   figures of a line profile ([`super::profile`]);
//! - `stage flatness --surface FILE` on a text height matrix
//!   ([`super::readers::read_matrix`]): the same output as on a Parquet
//!   surface, with the header's units.
//!
//! The profile stage has no run form (no run table holds a free profile):
//! it is offered to `sparkout stage` through
//! `MachinePlugin::standalone_stages`, so no run's DAG carries it.

use std::path::Path;

use anyhow::{anyhow, Context};
use serde_json::{json, Value};
use sparkout_pipeline::config_check::{NoKeys, SectionCheck};
use sparkout_pipeline::{Result, Stage, StageArgs, StageContext, StageOutput, StageSpec};

use super::plane::flatness;
use super::profile::{analyse, Settings, DEFAULT_SAMPLING_LENGTHS};
use super::readers::{is_text_matrix, read_matrix, read_profile, ProfileSpec};
use super::{areal, profile};

pub struct ProfileStage;

const SPEC: StageSpec = StageSpec {
    name: "profile",
    version: 1,
    reads: &[],
    reads_artifacts: &[],
    writes: &[],
    reads_augmented_model: false,
    about: "run-less: straightness and ISO 21920-2 profile parameters (Pt, Pq, Pa; Rq, Ra, Rz, Rt, Rsk, Rku with a Gaussian λc filter) of a line profile file (docs/metrology.md)",
    config: SectionCheck::of::<NoKeys>(),
};

const FLAGS: [&str; 7] = [
    "profile",
    "lambda-c",
    "sampling-lengths",
    "x",
    "z",
    "x-unit",
    "z-unit",
];

impl Stage for ProfileStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, _ctx: &StageContext) -> Result<StageOutput> {
        anyhow::bail!("stage `profile` has only a run-less form: sparkout stage profile --profile FILE [--lambda-c MM]")
    }
    fn run_standalone(&self, args: &StageArgs) -> Option<Result<Value>> {
        Some(profile_standalone(args))
    }
    fn console(&self, result: &Value) -> Option<String> {
        Some(profile::console(result))
    }
}

fn profile_standalone(args: &StageArgs) -> Result<Value> {
    if let Some(k) = args.keys().find(|k| !FLAGS.contains(&k.as_str())) {
        anyhow::bail!(
            "unknown flag --{k} for `profile` (known: --profile FILE, --lambda-c MM, --sampling-lengths N, --x COL, --z COL, --x-unit U, --z-unit U)"
        );
    }
    let file = args.get("profile").ok_or_else(|| {
        anyhow!("stage `profile` needs --profile FILE (a Parquet, CSV or instrument text profile)")
    })?;
    let number = |flag: &str| -> Result<Option<f64>> {
        args.get(flag)
            .map(|s| {
                s.parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite() && *v > 0.0)
                    .ok_or_else(|| anyhow!("--{flag} `{s}` is not a number > 0"))
            })
            .transpose()
    };
    let lambda_c = number("lambda-c")?;
    let sampling_lengths = match args.get("sampling-lengths") {
        None => DEFAULT_SAMPLING_LENGTHS,
        Some(s) => s
            .parse::<usize>()
            .ok()
            .filter(|&n| n >= 1)
            .ok_or_else(|| anyhow!("--sampling-lengths `{s}` is not a whole number ≥ 1"))?,
    };
    let spec = ProfileSpec {
        x: args.get("x").map(String::as_str),
        z: args.get("z").map(String::as_str),
        x_unit: args.get("x-unit").map(String::as_str),
        z_unit: args.get("z-unit").map(String::as_str),
    };
    let path = Path::new(file);
    let p = read_profile(path, &spec)?;
    let mut out = analyse(
        &p.x_mm,
        &p.z_mm,
        Settings {
            lambda_c,
            sampling_lengths,
        },
    )
    .with_context(|| path.display().to_string())?;
    out["input"] = p.json(path);
    Ok(out)
}

/// `flatness --surface FILE` when FILE is a text height matrix: `None` for
/// any other file (the Parquet surface reader takes it).
pub fn matrix_flatness(args: &StageArgs) -> Option<Result<Value>> {
    let file = args.get("surface")?;
    if !is_text_matrix(Path::new(file)) {
        return None;
    }
    Some((|| {
        const KNOWN: [&str; 4] = ["surface", "x-unit", "y-unit", "z-unit"];
        if let Some(k) = args.keys().find(|k| !KNOWN.contains(&k.as_str())) {
            anyhow::bail!("unknown flag --{k} for `flatness --surface` on a text height matrix (known: --surface FILE, --x-unit U, --y-unit U, --z-unit U)");
        }
        let path = Path::new(file);
        let m = read_matrix(
            path,
            args.get("x-unit").map(String::as_str),
            args.get("y-unit").map(String::as_str),
            args.get("z-unit").map(String::as_str),
        )?;
        let keep: Vec<usize> = (0..m.z_mm.len())
            .filter(|&i| m.z_mm[i].is_finite())
            .collect();
        if keep.len() < 3 {
            anyhow::bail!(
                "{}: {} measured points; flatness needs at least 3",
                path.display(),
                keep.len()
            );
        }
        let pick = |v: &[f64]| keep.iter().map(|&i| v[i]).collect::<Vec<f64>>();
        let f = flatness(&pick(&m.x_mm), &pick(&m.y_mm), &pick(&m.z_mm))
            .with_context(|| path.display().to_string())?;
        Ok(json!({
            "least_squares_mm": f.least_squares.width_mm,
            "min_zone_mm": f.min_zone.width_mm,
            "n": keep.len(),
            "areal": areal::surface_report(&m.x_mm, &m.y_mm, &m.z_mm)
                .with_context(|| path.display().to_string())?,
            "input": m.input,
        }))
    })())
}

/// Console text of a `flatness --surface` result that carries `areal`.
pub fn surface_console(result: &Value) -> Option<String> {
    let a = result.get("areal")?;
    let mut s = String::new();
    if let Some(f) = result["input"]["file"].as_str() {
        s += &format!("{f}\n");
    }
    s += &format!(
        "flatness: LS {}  min-zone {}  ({} points)\n",
        super::console_length(result["least_squares_mm"].as_f64().unwrap_or(f64::NAN)),
        super::console_length(result["min_zone_mm"].as_f64().unwrap_or(f64::NAN)),
        result["n"]
    );
    s += &areal::console(a);
    Some(s)
}

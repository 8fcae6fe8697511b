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

use crate::{err, Context};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use sparkout_pipeline::config_check::{NoKeys, SectionCheck};
use sparkout_pipeline::{Result, Stage, StageArgs, StageContext, StageOutput, StageSpec};

use super::areal::ArealReport;
use super::plane::flatness;
use super::profile::ProfileReport;
use super::profile::{analyse, Settings, DEFAULT_SAMPLING_LENGTHS};
use super::readers::{is_text_matrix, read_matrix, read_profile, MatrixInput, ProfileSpec};
use super::{areal, nan, profile};

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
        crate::bail!("stage `profile` has only a run-less form: sparkout stage profile --profile FILE [--lambda-c MM]")
    }
    fn run_standalone(&self, args: &StageArgs) -> Option<Result<Value>> {
        Some(profile_standalone(args))
    }
    fn console(&self, result: &Value) -> Option<String> {
        let r: ProfileReport = serde_json::from_value(result.clone()).ok()?;
        Some(profile::console(&r))
    }
}

fn profile_standalone(args: &StageArgs) -> Result<Value> {
    if let Some(k) = args.keys().find(|k| !FLAGS.contains(&k.as_str())) {
        crate::bail!(
            "unknown flag --{k} for `profile` (known: --profile FILE, --lambda-c MM, --sampling-lengths N, --x COL, --z COL, --x-unit U, --z-unit U)"
        );
    }
    let file = args.get("profile").ok_or_else(|| {
        err!("stage `profile` needs --profile FILE (a Parquet, CSV or instrument text profile)")
    })?;
    let number = |flag: &str| -> Result<Option<f64>> {
        args.get(flag)
            .map(|s| {
                s.parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite() && *v > 0.0)
                    .ok_or_else(|| err!("--{flag} `{s}` is not a number > 0"))
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
            .ok_or_else(|| err!("--sampling-lengths `{s}` is not a whole number ≥ 1"))?,
    };
    let spec = ProfileSpec {
        x: args.get("x").map(String::as_str),
        z: args.get("z").map(String::as_str),
        x_unit: args.get("x-unit").map(String::as_str),
        z_unit: args.get("z-unit").map(String::as_str),
    };
    let path = Path::new(file);
    let p = read_profile(path, &spec)?;
    let out = analyse(
        &p.x_mm,
        &p.z_mm,
        Settings {
            lambda_c,
            sampling_lengths,
        },
    )
    .with_context(|| path.display().to_string())?;
    let out = ProfileReport {
        input: Some(p.input(path)),
        ..out
    };
    Ok(serde_json::to_value(out)?)
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
            crate::bail!("unknown flag --{k} for `flatness --surface` on a text height matrix (known: --surface FILE, --x-unit U, --y-unit U, --z-unit U)");
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
            crate::bail!(
                "{}: {} measured points; flatness needs at least 3",
                path.display(),
                keep.len()
            );
        }
        let pick = |v: &[f64]| keep.iter().map(|&i| v[i]).collect::<Vec<f64>>();
        let f = flatness(&pick(&m.x_mm), &pick(&m.y_mm), &pick(&m.z_mm))
            .with_context(|| path.display().to_string())?;
        let out = SurfaceFlatness {
            least_squares_mm: f.least_squares.width_mm,
            min_zone_mm: f.min_zone.width_mm,
            n: keep.len(),
            areal: areal::surface_report(&m.x_mm, &m.y_mm, &m.z_mm)
                .with_context(|| path.display().to_string())?,
            input: Some(m.input),
        };
        Ok(serde_json::to_value(out)?)
    })())
}

/// What `flatness --surface` prints: the flatness of the points, their
/// areal figures, and (for a text height matrix) the file as read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SurfaceFlatness {
    #[serde(deserialize_with = "nan")]
    pub least_squares_mm: f64,
    #[serde(deserialize_with = "nan")]
    pub min_zone_mm: f64,
    pub n: usize,
    pub areal: ArealReport,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub input: Option<MatrixInput>,
}

/// Console text of a `flatness --surface` result ([`SurfaceFlatness`]);
/// `None` for any other result (a topography's flatness has no `areal`).
pub fn surface_console(result: &Value) -> Option<String> {
    let r: SurfaceFlatness = serde_json::from_value(result.clone()).ok()?;
    let mut s = String::new();
    if let Some(i) = &r.input {
        s += &format!("{}\n", i.file);
    }
    s += &format!(
        "flatness: LS {}  min-zone {}  ({} points)\n",
        super::console_length(r.least_squares_mm),
        super::console_length(r.min_zone_mm),
        r.n
    );
    s += &areal::console(&r.areal);
    Some(s)
}

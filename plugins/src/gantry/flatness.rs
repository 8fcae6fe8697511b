//! `flatness`: least-squares reference plane (peak-to-valley of the
//! residuals) and exact minimum-zone flatness (docs/models.md §2.4) of any
//! topography state (`state` key, default the last state in the order
//! pattern → before → after_grind → after_polish → final).
//!
//! The plane fits themselves live in `crate::metrology::plane` (shared
//! with the profile and spike figures).

use crate::gantry::tables::TOPOGRAPHY;
use crate::{err, Context};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use sparkout_pipeline::config_check::SectionCheck;
use sparkout_pipeline::contracts::{BatchBuilder, Table};
use sparkout_pipeline::{Result, Stage, StageArgs, StageContext, StageOutput, StageSpec};

use super::config::FlatnessConfig;
use super::grid;
use super::surface::{read_surface, SurfaceSpec};
pub use crate::metrology::plane::{flatness, least_squares, min_zone, Flatness, PlaneFit};

fn state_points(t: &Table, state: &str) -> Result<(Vec<f64>, Vec<f64>, Vec<f64>)> {
    let st = t.str("state")?;
    let (xs, ys, zs) = (t.f64("x_mm")?, t.f64("y_mm")?, t.f64("z_mm")?);
    let rows: Vec<usize> = (0..t.len()).filter(|&r| st[r] == state).collect();
    if rows.len() < 3 {
        let have = grid::states(t)?;
        return Err(sparkout_pipeline::InputError::new(
            t.path(),
            format!(
                "state `{state}` has {} points; flatness needs at least 3 (states present: {})",
                rows.len(),
                have.join(", ")
            ),
        )
        .column("state")
        .into());
    }
    Ok((
        rows.iter().map(|&r| xs[r]).collect(),
        rows.iter().map(|&r| ys[r]).collect(),
        rows.iter().map(|&r| zs[r]).collect(),
    ))
}

/// Flatness of every state (artifact rows) and the JSON of the chosen one.
pub fn analyse(
    t: &Table,
    state: Option<&str>,
) -> Result<(Vec<(String, Flatness)>, FlatnessSummary)> {
    let states = grid::states(t)?;
    let chosen = match state {
        Some(s) => s.to_string(),
        None => states
            .last()
            .cloned()
            .ok_or_else(|| err!("topography has no rows"))?,
    };
    if !states.contains(&chosen) {
        return Err(sparkout_pipeline::InputError::new(
            t.path(),
            format!(
                "no rows with state `{chosen}` (states present: {})",
                states.join(", ")
            ),
        )
        .column("state")
        .into());
    }
    let mut all = Vec::new();
    for s in &states {
        let (x, y, z) = state_points(t, s)?;
        all.push((
            s.clone(),
            flatness(&x, &y, &z).with_context(|| format!("state `{s}`"))?,
        ));
    }
    let f = all
        .iter()
        .find(|(s, _)| *s == chosen)
        .expect("chosen state")
        .1;
    let states = all
        .iter()
        .map(|(s, f)| StateFlatness {
            state: s.clone(),
            least_squares_mm: f.least_squares.width_mm,
            min_zone_mm: f.min_zone.width_mm,
        })
        .collect();
    let summary = FlatnessSummary {
        state: chosen,
        least_squares_mm: f.least_squares.width_mm,
        min_zone_mm: f.min_zone.width_mm,
        plane: f.min_zone.plane,
        least_squares_plane: f.least_squares.plane,
        states,
    };
    Ok((all, summary))
}

/// `flatness.json` (and `stage flatness --topography FILE --json`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FlatnessSummary {
    /// The state the figures are of.
    pub state: String,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub least_squares_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub min_zone_mm: f64,
    /// Minimum-zone plane z = a·x + b·y + c (mm).
    #[serde(deserialize_with = "crate::typed_summary::arr_or_nan")]
    pub plane: [f64; 3],
    #[serde(deserialize_with = "crate::typed_summary::arr_or_nan")]
    pub least_squares_plane: [f64; 3],
    /// Every state of the topography.
    pub states: Vec<StateFlatness>,
}

/// `flatness.json` `states[]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StateFlatness {
    pub state: String,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub least_squares_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub min_zone_mm: f64,
}

/// `stage flatness --surface FILE --json`: any surface's flatness and its
/// areal parameters.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SurfaceFlatness {
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub least_squares_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub min_zone_mm: f64,
    /// Points.
    pub n: usize,
    /// ISO 25178-2 heights, spikes and the evaluation area, as metrology
    /// reports them (docs/metrology.md).
    pub areal: Value,
}

pub struct FlatnessStage;

const SPEC: StageSpec = StageSpec {
    name: "flatness",
    version: 1,
    reads: &[&TOPOGRAPHY],
    reads_artifacts: &[],
    writes: &["flatness"],
    reads_augmented_model: false,
    about:
        "least-squares and exact minimum-zone flatness of a topography state (docs/models.md §2.4)",
    config: SectionCheck::of::<FlatnessConfig>(),
};

impl Stage for FlatnessStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let t = ctx.run.require(&TOPOGRAPHY)?;
        let cfg: &FlatnessConfig = ctx.section()?;
        let (all, summary) = analyse(&t, cfg.state.as_deref())?;
        Ok(StageOutput::typed(&summary)?.with("flatness", batch(&all)))
    }
    /// `sparkout stage flatness --topography FILE [--state NAME] --json`
    /// (a topography table), or `--surface FILE [--x COL --y COL --z COL]
    /// [--x-unit U --y-unit U --z-unit U] --json` (any x/y/z table or
    /// gridded map; `--unit-scale F` is a deprecated alias).
    fn run_standalone(&self, args: &StageArgs) -> Option<Result<Value>> {
        if let Some(r) = crate::metrology::stage::matrix_flatness(args) {
            return Some(r);
        }
        if args.contains_key("surface") {
            return Some(surface_flatness(args));
        }
        let file = args.get("topography")?;
        Some((|| {
            for k in args.keys() {
                if k != "topography" && k != "state" {
                    crate::bail!("unknown flag --{k} for `flatness` (known: --topography FILE, --state NAME; or --surface FILE, --x/--y/--z COL, --x-unit/--y-unit/--z-unit U)");
                }
            }
            let t = Table::read(std::path::Path::new(file), &TOPOGRAPHY)?;
            Ok(serde_json::to_value(
                analyse(&t, args.get("state").map(|s| s.as_str()))?.1,
            )?)
        })())
    }
    fn console(&self, result: &Value) -> Option<String> {
        crate::metrology::stage::surface_console(result)
    }
}

/// `{"least_squares_mm", "min_zone_mm", "n", "areal"}` of any surface file.
fn surface_flatness(args: &StageArgs) -> Result<Value> {
    const KNOWN: [&str; 8] = [
        "surface",
        "x",
        "y",
        "z",
        "x-unit",
        "y-unit",
        "z-unit",
        "unit-scale",
    ];
    if let Some(k) = args.keys().find(|k| !KNOWN.contains(&k.as_str())) {
        crate::bail!("unknown flag --{k} for `flatness --surface` (known: --surface FILE, --x COL, --y COL, --z COL, --x-unit U, --y-unit U, --z-unit U)");
    }
    let unit_scale = match args.get("unit-scale") {
        Some(s) => {
            eprintln!("warning: --unit-scale is deprecated: give each axis its unit (--x-unit um --y-unit um --z-unit nm) or name it in the column (x_um, z_nm)");
            s.parse::<f64>()
                .map_err(|_| err!("--unit-scale `{s}` is not a number"))?
        }
        None => 1.0,
    };
    let spec = SurfaceSpec {
        x: args.get("x").map(|s| s.as_str()),
        y: args.get("y").map(|s| s.as_str()),
        z: args.get("z").map(|s| s.as_str()),
        unit_scale,
        x_unit: args.get("x-unit").map(|s| s.as_str()),
        y_unit: args.get("y-unit").map(|s| s.as_str()),
        z_unit: args.get("z-unit").map(|s| s.as_str()),
    };
    let path = std::path::Path::new(&args["surface"]);
    let p = read_surface(path, &spec)?;
    let f = flatness(&p.x_mm, &p.y_mm, &p.z_mm).with_context(|| path.display().to_string())?;
    let out = SurfaceFlatness {
        least_squares_mm: f.least_squares.width_mm,
        min_zone_mm: f.min_zone.width_mm,
        n: p.z_mm.len(),
        // ISO 25178-2 heights, spikes and the evaluation area (docs/metrology.md).
        areal: crate::metrology::areal::report_read_points(&p.x_mm, &p.y_mm, &p.z_mm)
            .with_context(|| path.display().to_string())?,
    };
    Ok(serde_json::to_value(out)?)
}

fn batch(all: &[(String, Flatness)]) -> arrow::record_batch::RecordBatch {
    BatchBuilder::new()
        .str(
            "state",
            &all.iter().map(|a| a.0.as_str()).collect::<Vec<_>>(),
        )
        .f64(
            "least_squares_mm",
            all.iter().map(|a| a.1.least_squares.width_mm).collect(),
        )
        .f64(
            "min_zone_mm",
            all.iter().map(|a| a.1.min_zone.width_mm).collect(),
        )
        .f64(
            "plane_a",
            all.iter().map(|a| a.1.min_zone.plane[0]).collect(),
        )
        .f64(
            "plane_b",
            all.iter().map(|a| a.1.min_zone.plane[1]).collect(),
        )
        .f64(
            "plane_c_mm",
            all.iter().map(|a| a.1.min_zone.plane[2]).collect(),
        )
        .build()
}

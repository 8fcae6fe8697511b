//! `sparkout validate`: the diagnosis checked on fleets whose effect is known.

use std::path::PathBuf;

use anyhow::Context;
use sparkout_pipeline::contracts::{write_atomic, write_json_atomic};
use sparkout_pipeline::diagnose::DiagnoseConfig;
use sparkout_pipeline::report::trend::TrendConfig;

use crate::cli::ConfigArgs;
use crate::registry;

/// The checked config and its `[diagnose]`: the same settings as `run` and
/// `diagnose`.
fn settings(
    config: &ConfigArgs,
) -> anyhow::Result<(sparkout_pipeline::engine::PipelineConfig, DiagnoseConfig)> {
    let pc = registry::config(config)?;
    let diagnose = DiagnoseConfig::from_toml(&pc.section("diagnose"))
        .with_context(|| format!("config {}: [diagnose]", pc.source))?;
    Ok((pc, diagnose))
}

pub fn validate(
    quick: bool,
    out: Option<PathBuf>,
    seed: u64,
    json: bool,
    cells: Option<u32>,
    config: &ConfigArgs,
) -> anyhow::Result<u8> {
    let (_, diagnose) = settings(config)?;
    let cfg = sparkout_datasets::validate::ValidateConfig {
        diagnose,
        cells: cells.map(|b| b as usize),
        ..sparkout_datasets::validate::ValidateConfig::new(quick, seed)
    };
    let report = sparkout_datasets::validate::run(&cfg)?;
    let text = sparkout_datasets::validate::render_text(&report);
    emit(&report, &text, out.as_deref(), "validation", json)
}

/// A validation report: `<out>/<stem>.txt` and `.json` with --out, the text
/// (or with --json the JSON) on standard output.
fn emit(
    report: &impl serde::Serialize,
    text: &str,
    out: Option<&std::path::Path>,
    stem: &str,
    json: bool,
) -> anyhow::Result<u8> {
    if let Some(out) = out {
        write_atomic(&out.join(format!("{stem}.txt")), text.as_bytes())?;
        write_json_atomic(&out.join(format!("{stem}.json")), report)?;
    }
    if json {
        println!("{}", serde_json::to_string_pretty(report)?);
    } else {
        print!("{text}");
    }
    Ok(0)
}

/// `sparkout validate --nights`: the trend's alert rule on generated nights
/// (false alerts per 100 stationary night-fleets, detection delays).
pub fn validate_nights(
    quick: bool,
    out: Option<PathBuf>,
    seed: u64,
    json: bool,
    config: &ConfigArgs,
) -> anyhow::Result<u8> {
    let (pc, diagnose) = settings(config)?;
    let trend = TrendConfig::from_toml(&pc.section("trend"))
        .with_context(|| format!("config {}: [trend]", pc.source))?;
    use sparkout_datasets::validate::nights;
    let cfg = nights::NightsConfig {
        diagnose,
        trend,
        ..nights::NightsConfig::new(quick, seed)
    };
    let report = nights::run(&cfg)?;
    let text = nights::render_text(&report);
    emit(&report, &text, out.as_deref(), "nights", json)
}

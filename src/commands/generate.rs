//! `sparkout generate`: synthetic fleets with injected effects, from the
//! generator registry (`sparkout_datasets::all_generators`).

use std::path::PathBuf;

use anyhow::{bail, Context};
use sparkout_datasets::GenerateOptions;
use sparkout_pipeline::EffectSpec;

pub fn parse_effects(effects: &[String]) -> anyhow::Result<Vec<EffectSpec>> {
    effects
        .iter()
        .map(|e| e.parse::<EffectSpec>().map_err(|m| anyhow::anyhow!(m)))
        .collect()
}

pub fn generate(
    what: &str,
    opts: &GenerateOptions,
    out: Option<PathBuf>,
    effects: &[String],
    list_effects: bool,
) -> anyhow::Result<u8> {
    let effects = parse_effects(effects)?;
    let Some(g) = sparkout_datasets::generator(what) else {
        let plugins: Vec<&str> = sparkout_plugins::all_plugins()
            .iter()
            .map(|p| p.name())
            .collect();
        let generators: Vec<&str> = sparkout_datasets::all_generators()
            .iter()
            .map(|g| g.name())
            .collect();
        bail!(
            "no generator for `{what}` (plugins registered: {}; generators: {})",
            plugins.join(", "),
            generators.join(", ")
        )
    };
    if list_effects {
        print!("{}", g.effects_listing());
        return Ok(0);
    }
    let out = out.context("--out is required (a fleet root; a .parquet file for observations)")?;
    println!("{}", g.generate(&out, opts, &effects)?.summary);
    Ok(0)
}

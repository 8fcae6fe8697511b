//! `sparkout generate`: synthetic fleets with injected effects, from the
//! generator registry (`sparkout_datasets::all_generators`).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use sparkout_datasets::GenerateOptions;
use sparkout_pipeline::contracts::{discover_runs, RunSpec};
use sparkout_pipeline::EffectSpec;

use crate::bounds;

pub fn parse_effects(effects: &[String]) -> anyhow::Result<Vec<EffectSpec>> {
    effects
        .iter()
        .map(|e| e.parse::<EffectSpec>().map_err(|m| anyhow::anyhow!(m)))
        .collect()
}

/// `generate` never overwrites silently: runs of the same plugin already
/// under the fleet root (their ids would be reused: r0000, r0001, ...) or an
/// existing observations file need `--force`. Other plugins' runs under the
/// same root are fine (a mixed fleet is generated one plugin at a time).
fn refuse_overwrite(what: &str, writes_file: bool, out: &Path) -> anyhow::Result<()> {
    if writes_file {
        if out.exists() {
            bail!(
                "{} already exists; pass --force to overwrite it",
                out.display()
            );
        }
        return Ok(());
    }
    if !out.is_dir() {
        return Ok(());
    }
    let existing: Vec<String> = discover_runs(out)
        .unwrap_or_default()
        .into_iter()
        .filter(|d| RunSpec::load(d).is_ok_and(|s| s.plugin == what))
        .map(|d| d.display().to_string())
        .collect();
    if !existing.is_empty() {
        bail!(
            "{} already holds {} {what} run(s) ({}{}); generating would overwrite them. Pass --force to overwrite, or choose another --out",
            out.display(),
            existing.len(),
            existing[..existing.len().min(3)].join(", "),
            if existing.len() > 3 { ", ..." } else { "" }
        );
    }
    Ok(())
}

/// What `generate` may do beyond its defaults.
#[derive(Debug, Clone, Copy)]
pub struct Overrides {
    /// Overwrite runs (or an observations file) already at --out.
    pub force: bool,
    /// Generate a fleet predicted to be too large (crate::bounds).
    pub force_size: bool,
}

pub fn generate(
    what: &str,
    opts: &GenerateOptions,
    out: Option<PathBuf>,
    effects: &[String],
    list_effects: bool,
    overrides: Overrides,
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
    let out = out.context(
        "--out is required (a fleet root; a .parquet file for observations, raster, raster-varied)",
    )?;
    bounds::check_size(
        &format!(
            "generate {what} --runs {}{}",
            opts.runs,
            opts.ae_rate_hz
                .map(|r| format!(" --ae-rate-hz {r}"))
                .unwrap_or_default()
                + &opts
                    .ae_signal
                    .as_ref()
                    .map(|s| format!(" --ae-signal {s}"))
                    .unwrap_or_default()
        ),
        g.predicted_size(opts),
        bounds::machine_memory_bytes(),
        overrides.force_size,
    )?;
    if !overrides.force {
        refuse_overwrite(what, g.writes_file(), &out)?;
    }
    println!("{}", g.generate(&out, opts, &effects)?.summary);
    Ok(0)
}

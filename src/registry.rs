//! The plugin registry: the one place that names concrete plugins.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;

use sparkout_pipeline::contracts::MachineResolver;
use sparkout_pipeline::engine::{Engine, PipelineConfig};
use sparkout_pipeline::MachinePlugin;

use crate::config_args::ConfigArgs;

pub fn plugins() -> Vec<Arc<dyn MachinePlugin>> {
    sparkout_plugins::all_plugins()
}

/// The tables every registered plugin records, with the shared ones.
pub fn tables() -> anyhow::Result<sparkout_pipeline::contracts::TableRegistry> {
    let plugins = plugins();
    Ok(sparkout_pipeline::contracts::TableRegistry::of(
        plugins.iter().map(|p| (p.name(), p.tables())),
    )?)
}

pub fn resolver(machines: Option<PathBuf>) -> MachineResolver {
    let builtins: BTreeMap<String, String> = plugins()
        .iter()
        .flat_map(|p| p.builtin_machines())
        .map(|(id, text)| (id.to_string(), text.to_string()))
        .collect();
    MachineResolver::new(machines, builtins)
}

/// The pipeline config from --config (or the built-in nightly.toml) with
/// every --set applied, unchecked.
fn load_config(args: &ConfigArgs) -> anyhow::Result<PipelineConfig> {
    let mut c = match &args.config {
        Some(p) => PipelineConfig::load(p)?,
        None => PipelineConfig::builtin(),
    };
    for s in &args.set {
        c.set(s)?;
    }
    Ok(c)
}

/// The pipeline config, checked as `run` checks it: every command that takes
/// --config/--set refuses unknown sections and keys the same way, whether or
/// not it reads them.
pub fn config(args: &ConfigArgs) -> anyhow::Result<PipelineConfig> {
    Ok(engine(args)?.config().clone())
}

/// `--machines` must name a directory of machine configs: a file (or a typo)
/// would otherwise be ignored and the built-in machines used silently.
fn machines_dir(args: &ConfigArgs) -> anyhow::Result<Option<PathBuf>> {
    match &args.machines {
        Some(d) if !d.is_dir() => anyhow::bail!(
            "--machines {}: not a directory; pass the directory that holds <machine>.toml files (e.g. configs/machines)",
            d.display()
        ),
        other => Ok(other.clone()),
    }
}

/// An engine with the config checked against every plugin and stage.
pub fn engine(args: &ConfigArgs) -> anyhow::Result<Engine> {
    Ok(Engine::new(
        plugins(),
        resolver(machines_dir(args)?),
        load_config(args)?,
    )?)
}

//! `--help` texts that list what the registries hold: the generators of
//! `generate`, the stages of `stage`, the effects and plugins of `diagnose`
//! and `run`. Built at run time from the registries, not kept by hand, so a
//! new generator, stage or effect shows up in `--help` the day it is
//! registered (tests/e2e/help_lists_registry.rs holds this).

use clap::Command;
use sparkout_pipeline::diagnose::effect::Kind;

use crate::registry;

/// The command line with every registry listing appended to the help of
/// the subcommand it belongs to.
pub fn with_registry(cmd: Command) -> Command {
    cmd.mut_subcommand("generate", |c| append(c, &generators()))
        .mut_subcommand("stage", |c| append(c, &stages()))
        .mut_subcommand("diagnose", |c| append(c, &effects()))
        .mut_subcommand("run", |c| append(c, &plugins()))
}

/// The subcommand's `after_help` (its examples) followed by `text`.
fn append(c: Command, text: &str) -> Command {
    let before = c
        .get_after_help()
        .map(|s| s.to_string())
        .unwrap_or_default();
    let joined = if before.is_empty() {
        text.to_string()
    } else {
        format!("{before}\n\n{text}")
    };
    c.after_help(joined)
}

/// Every generator with the effects it can inject.
fn generators() -> String {
    let mut s = String::from("Generators (WHAT) in this build:");
    for g in sparkout_datasets::all_generators() {
        let fx: Vec<&str> = g.known_effects().into_iter().map(|(n, _)| n).collect();
        s.push_str(&format!("\n  {:<14} effects: {}", g.name(), fx.join(", ")));
    }
    s
}

/// Every stage of every plugin, with its one-line description.
fn stages() -> String {
    let mut s = String::from("Stages (NAME) in this build, by plugin:");
    for p in registry::plugins() {
        s.push_str(&format!("\n  {}:", p.name()));
        for st in p.stages() {
            let spec = st.spec();
            s.push_str(&format!("\n    {:<14} {}", spec.name, spec.about));
        }
    }
    s
}

/// The catalogue every observable gets, and each plugin's composites.
fn effects() -> String {
    let kinds: Vec<&str> = Kind::all().into_iter().map(|k| k.name()).collect();
    let mut s = format!(
        "Catalogue effects (--effects): {}\nPlugins (--plugin) and their composite effects:",
        kinds.join(", ")
    );
    for p in registry::plugins() {
        // One name may have a form per family of observables (the
        // servo's lag): listed once.
        let mut fx: Vec<String> = Vec::new();
        for e in p.effects() {
            if !fx.iter().any(|n| n == e.name()) {
                fx.push(e.name().to_string());
            }
        }
        s.push_str(&format!("\n  {:<10} {}", p.name(), fx.join(", ")));
    }
    s
}

/// The plugins a run directory's `plugin =` may name.
fn plugins() -> String {
    let names: Vec<&str> = registry::plugins().iter().map(|p| p.name()).collect();
    format!("Plugins in this build: {}", names.join(", "))
}

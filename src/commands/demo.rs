//! `sparkout demo`: the embedded default — a small fleet of every machine
//! type, each with one withheld (unmodelled) effect, through the whole DAG
//! and the fleet diagnosis; prints what was injected and what was named.

use std::path::Path;

use sparkout_pipeline::EffectSpec;

use crate::cli::ConfigArgs;
use crate::progress::BatchProgress;
use crate::registry;

pub fn demo(out: &Path) -> anyhow::Result<u8> {
    let runs_dir = out.join("runs");
    let results = out.join("out");
    // Every registered generator with a demo fleet, in registry order.
    let mut injected = Vec::new();
    for g in sparkout_datasets::all_generators() {
        let Some(fleet) = g.demo() else { continue };
        let effects: Vec<EffectSpec> = vec![fleet
            .effect
            .parse()
            .map_err(|e: String| anyhow::anyhow!(e))?];
        let n = g.generate_demo(&runs_dir, &effects)?.runs;
        eprintln!(
            "sparkout demo: generated {n} {} runs whose machine has an unmodelled effect: {}",
            g.name(),
            fleet.effect
        );
        injected.push(format!("{} → {}", g.name(), fleet.effect));
    }
    let engine = registry::engine(&ConfigArgs {
        config: None,
        set: Vec::new(),
        machines: None,
    })?;
    let progress = BatchProgress::new();
    let outcome = engine.run_fleet(&runs_dir, &results, None, &progress)?;
    progress.finish();
    println!("demo fleet: {}", runs_dir.display());
    super::run::print_outcome(&outcome);
    println!(
        "injected (withheld from the model): {}",
        injected.join(", ")
    );
    println!(
        "next: open {} in a browser (the night's failures, the fleet report and every run), or try `sparkout stage datum --run {} --json`",
        results.join("index.html").display(),
        outcome
            .runs
            .first()
            .map(|r| r.run_dir.clone())
            .unwrap_or_else(|| runs_dir.display().to_string())
    );
    Ok(outcome.exit_code() as u8)
}

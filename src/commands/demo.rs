//! `sparkout demo`: the embedded default — generate a small fleet with one
//! withheld effect, run the whole DAG, print where everything is.

use std::path::Path;

use sparkout_pipeline::EffectSpec;

use crate::cli::ConfigArgs;
use crate::progress::BatchProgress;
use crate::registry;

pub fn demo(out: &Path) -> anyhow::Result<u8> {
    let runs_dir = out.join("runs");
    let results = out.join("out");
    let cfg = sparkout_datasets::robot::RobotFleetConfig::demo();
    // The demo's "real" machine wears its wheel; the model does not know.
    let effects: Vec<EffectSpec> = vec!["wheel_wear"
        .parse()
        .map_err(|e: String| anyhow::anyhow!(e))?];
    eprintln!(
        "sparkout demo: generating {} robot runs (seed {}) with an unmodelled effect: {}",
        cfg.runs, cfg.seed, effects[0]
    );
    sparkout_datasets::robot::generate_fleet(&runs_dir, &cfg, &effects)?;
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
        "next: open {} in a browser, or try `sparkout stage datum --run {} --json`",
        results.join("fleet").join("report.html").display(),
        outcome
            .runs
            .first()
            .map(|r| r.run_dir.clone())
            .unwrap_or_else(|| runs_dir.display().to_string())
    );
    Ok(outcome.exit_code() as u8)
}

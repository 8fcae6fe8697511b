//! `sparkout validate-input`: every problem of every run; writes nothing.

use std::path::Path;

use crate::cli::ConfigArgs;
use crate::registry;

pub fn validate_input(root: &Path, config: &ConfigArgs) -> anyhow::Result<u8> {
    let engine = registry::engine(config)?;
    let (runs, problems) = engine.validate_input(root)?;
    for p in &problems {
        println!("{}: {}", p.run_dir, p.message);
    }
    let bad: std::collections::BTreeSet<&str> =
        problems.iter().map(|p| p.run_dir.as_str()).collect();
    println!(
        "{runs} runs checked: {} clean, {} with problems ({} problems)",
        runs - bad.len(),
        bad.len(),
        problems.len()
    );
    Ok(if problems.is_empty() {
        super::ALL_GOOD
    } else {
        super::SOME_RUNS_FAILED
    })
}

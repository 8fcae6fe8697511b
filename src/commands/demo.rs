//! `sparkout demo`: the embedded default — a small fleet of every machine
//! type, each with one withheld (unmodelled) effect, through the whole DAG
//! and the fleet diagnosis; prints what was injected and what was named.

use std::path::Path;

use sparkout_pipeline::EffectSpec;

use crate::cli::ConfigArgs;
use crate::progress::BatchProgress;
use crate::registry;

/// One demo fleet: plugin, runs, the effect its "real" machine has.
struct DemoFleet {
    plugin: &'static str,
    runs: usize,
    effect: &'static str,
}

/// Sized to generate and run in a few seconds in release; each effect is
/// one the plugin's end-to-end test names first at this fleet size.
const FLEETS: [DemoFleet; 6] = [
    DemoFleet {
        plugin: "robot",
        runs: 4,
        effect: "wheel_wear",
    },
    DemoFleet {
        plugin: "gantry",
        runs: 6,
        effect: "thermal_bow",
    },
    DemoFleet {
        plugin: "guideway",
        runs: 6,
        effect: "thermal_infeed",
    },
    DemoFleet {
        plugin: "mill",
        runs: 6,
        effect: "thermal_growth",
    },
    DemoFleet {
        plugin: "form",
        runs: 9,
        effect: "wheel_wear",
    },
    DemoFleet {
        plugin: "servo",
        runs: 4,
        effect: "servo_lag",
    },
];

fn generate(f: &DemoFleet, root: &Path, effects: &[EffectSpec]) -> anyhow::Result<usize> {
    use sparkout_datasets as d;
    let seed = 1;
    let dirs = match f.plugin {
        "robot" => d::robot::generate_fleet(root, &d::robot::RobotFleetConfig::demo(), effects)?,
        "gantry" => d::gantry::generate_fleet(
            root,
            &d::gantry::GantryFleetConfig {
                runs: f.runs,
                seed,
                ..Default::default()
            },
            effects,
        )?,
        "guideway" => d::guideway::generate_fleet(
            root,
            &d::guideway::GuidewayFleetConfig {
                runs: f.runs,
                seed,
                ..Default::default()
            },
            effects,
        )?,
        "mill" => d::mill::generate_fleet(
            root,
            &d::mill::MillFleetConfig {
                runs: f.runs,
                seed,
                ..Default::default()
            },
            effects,
        )?,
        "form" => d::form::generate_fleet(
            root,
            &d::form::FormFleetConfig {
                runs: f.runs,
                seed,
                ..Default::default()
            },
            effects,
        )?,
        "servo" => d::servo::generate_fleet(
            root,
            &d::servo::ServoFleetConfig {
                runs: f.runs,
                seed,
                ..Default::default()
            },
            effects,
        )?,
        other => anyhow::bail!("demo: no generator for `{other}`"),
    };
    Ok(dirs.len())
}

pub fn demo(out: &Path) -> anyhow::Result<u8> {
    let runs_dir = out.join("runs");
    let results = out.join("out");
    for f in &FLEETS {
        let effects: Vec<EffectSpec> =
            vec![f.effect.parse().map_err(|e: String| anyhow::anyhow!(e))?];
        let n = generate(f, &runs_dir, &effects)?;
        eprintln!(
            "sparkout demo: generated {n} {} runs whose machine has an unmodelled effect: {}",
            f.plugin, f.effect
        );
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
        FLEETS
            .iter()
            .map(|f| format!("{} → {}", f.plugin, f.effect))
            .collect::<Vec<_>>()
            .join(", ")
    );
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

//! `sparkout generate`: synthetic fleets with injected effects.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use sparkout_pipeline::contracts::{discover_runs, write_parquet_atomic, RunSpec};
use sparkout_pipeline::EffectSpec;

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
fn refuse_overwrite(what: &str, out: &Path) -> anyhow::Result<()> {
    if what == "observations" {
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

#[allow(clippy::too_many_arguments)]
pub fn generate(
    what: &str,
    runs: usize,
    seed: u64,
    out: Option<PathBuf>,
    effects: &[String],
    ae_rate_hz: Option<f64>,
    list_effects: bool,
    force: bool,
) -> anyhow::Result<u8> {
    let effects = parse_effects(effects)?;
    if let (Some(out), false, false) = (&out, list_effects, force) {
        refuse_overwrite(what, out)?;
    }
    match what {
        "robot" => {
            if list_effects {
                for (name, about) in sparkout_datasets::robot::known_effects() {
                    println!("{name:18} {about}");
                }
                return Ok(0);
            }
            let out = out.context("--out <fleet root> is required")?;
            let mut cfg = sparkout_datasets::robot::RobotFleetConfig {
                runs,
                seed,
                ..Default::default()
            };
            if let Some(r) = ae_rate_hz {
                cfg.ae_sample_rate_hz = r;
            }
            cfg.validate()?;
            let dirs = sparkout_datasets::robot::generate_fleet(&out, &cfg, &effects)?;
            println!(
                "generated {} robot runs under {}",
                dirs.len(),
                out.display()
            );
            Ok(0)
        }
        "guideway" => {
            if list_effects {
                for (name, about) in sparkout_datasets::guideway::known_effects() {
                    println!("{name:18} {about}");
                }
                return Ok(0);
            }
            let out = out.context("--out <fleet root> is required")?;
            let cfg = sparkout_datasets::guideway::GuidewayFleetConfig {
                runs,
                seed,
                ..Default::default()
            };
            let dirs = sparkout_datasets::guideway::generate_fleet(&out, &cfg, &effects)?;
            println!(
                "generated {} guideway runs under {}",
                dirs.len(),
                out.display()
            );
            Ok(0)
        }
        "mill" => {
            if list_effects {
                for (name, about) in sparkout_datasets::mill::known_effects() {
                    println!("{name:18} {about}");
                }
                return Ok(0);
            }
            if ae_rate_hz.is_some() {
                bail!("--ae-rate-hz applies to `generate robot` only (a mill run has no AE log)");
            }
            let out = out.context("--out <fleet root> is required")?;
            let cfg = sparkout_datasets::mill::MillFleetConfig {
                runs,
                seed,
                ..Default::default()
            };
            let dirs = sparkout_datasets::mill::generate_fleet(&out, &cfg, &effects)?;
            println!("generated {} mill runs under {}", dirs.len(), out.display());
            Ok(0)
        }
        "form" => {
            if list_effects {
                for (name, about) in sparkout_datasets::form::known_effects() {
                    println!("{name:24} {about}");
                }
                return Ok(0);
            }
            let out = out.context("--out <fleet root> is required")?;
            let cfg = sparkout_datasets::form::FormFleetConfig {
                runs,
                seed,
                ..Default::default()
            };
            cfg.validate()?;
            let dirs = sparkout_datasets::form::generate_fleet(&out, &cfg, &effects)?;
            println!("generated {} form runs under {}", dirs.len(), out.display());
            Ok(0)
        }
        "gantry" => {
            if list_effects {
                for (name, about) in sparkout_datasets::gantry::known_effects() {
                    println!("{name:20} {about}");
                }
                return Ok(0);
            }
            let out = out.context("--out <fleet root> is required")?;
            let cfg = sparkout_datasets::gantry::GantryFleetConfig {
                runs,
                seed,
                ..Default::default()
            };
            let dirs = sparkout_datasets::gantry::generate_fleet(&out, &cfg, &effects)?;
            println!(
                "generated {} gantry runs under {}",
                dirs.len(),
                out.display()
            );
            Ok(0)
        }
        "observations" => {
            if list_effects {
                println!("any catalogue effect (CONTRACTS.md): offset, scale, drift, lag, inertia, backlash, wear, compliance, bow, periodic, edge, squareness, thermal — as NAME:COVARIATE=KEY=VALUE,...");
                return Ok(0);
            }
            let out = out.context("--out <file.parquet> is required")?;
            let cfg = sparkout_datasets::observations::ObsFleetConfig {
                runs,
                seed,
                ..Default::default()
            };
            let batch = sparkout_datasets::observations::generate(&cfg, &effects)?;
            write_parquet_atomic(&out, &batch)?;
            println!(
                "generated {} observations over {runs} runs in {}",
                batch.num_rows(),
                out.display()
            );
            Ok(0)
        }
        other => {
            let plugins: Vec<&str> = sparkout_plugins::all_plugins()
                .iter()
                .map(|p| p.name())
                .collect();
            bail!(
                "no generator for `{other}` (plugins registered: {}; generators: robot, guideway, mill, form, gantry, observations)",
                plugins.join(", ")
            )
        }
    }
}

//! `sparkout generate`: synthetic fleets with injected effects.

use std::path::PathBuf;

use anyhow::{bail, Context};
use sparkout_pipeline::contracts::write_parquet_atomic;
use sparkout_pipeline::EffectSpec;

pub fn parse_effects(effects: &[String]) -> anyhow::Result<Vec<EffectSpec>> {
    effects
        .iter()
        .map(|e| e.parse::<EffectSpec>().map_err(|m| anyhow::anyhow!(m)))
        .collect()
}

pub fn generate(
    what: &str,
    runs: usize,
    seed: u64,
    out: Option<PathBuf>,
    effects: &[String],
    ae_rate_hz: Option<f64>,
    list_effects: bool,
) -> anyhow::Result<u8> {
    let effects = parse_effects(effects)?;
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
        "servo" => {
            if list_effects {
                for (name, about) in sparkout_datasets::servo::known_effects() {
                    println!("{name:18} {about}");
                }
                return Ok(0);
            }
            let out = out.context("--out <fleet root> is required")?;
            let cfg = sparkout_datasets::servo::ServoFleetConfig {
                runs,
                seed,
                ..Default::default()
            };
            let dirs = sparkout_datasets::servo::generate_fleet(&out, &cfg, &effects)?;
            println!(
                "generated {} servo runs under {}",
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
                "no generator for `{other}` (plugins registered: {}; generators: robot, guideway, mill, form, gantry, servo, observations)",
                plugins.join(", ")
            )
        }
    }
}

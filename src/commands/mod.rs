//! One file per subcommand.

mod can;
mod demo;
mod diagnose;
mod generate;
mod import;
mod replay;
mod run;
mod stage;
mod trend;
mod validate;
mod validate_input;

use crate::cli::{Cli, Command};

pub const ALL_GOOD: u8 = 0;
pub const USAGE_OR_CONFIG_ERROR: u8 = 1;
pub const SOME_RUNS_FAILED: u8 = 2;

pub fn dispatch(cli: Cli) -> anyhow::Result<u8> {
    match cli.command {
        Command::Run {
            config,
            input,
            out,
            work,
            jobs,
            shard,
            balance,
            history,
            night,
            events,
            augment,
            snapshot,
        } => match shard {
            None => {
                let places = run::Places::resolve(&input, &out, work.as_deref(), None)?;
                run::run(
                    &config,
                    &places,
                    jobs,
                    history.map(|h| (h, night, events)),
                    (augment.as_deref(), snapshot.as_deref()),
                )
            }
            Some(s) => run::run_shard(
                &config,
                (&input, &out, work.as_deref()),
                jobs,
                (&s, &balance),
                snapshot.as_deref(),
            ),
        },
        Command::Snapshot { input, out, work } => run::snapshot(&input, &out, work.as_deref()),
        Command::Trend {
            config,
            events,
            history,
            out,
            json,
        } => trend::trend(&config, &history, &out, &events, json),
        Command::Aggregate {
            config,
            shards,
            out,
            work,
        } => run::aggregate(&config, &shards, &out, work.as_deref()),
        Command::Sync { from, to } => run::sync(&from, &to),
        Command::Stage {
            name,
            run,
            out,
            json,
            config,
            extra,
        } => stage::stage(&name, run, out, json, config, &extra),
        Command::ValidateInput { root, config } => validate_input::validate_input(&root, &config),
        Command::Generate {
            what,
            runs,
            seed,
            out,
            effects,
            ae_rate_hz,
            ae_signal,
            list_effects,
            force,
            force_size,
        } => {
            let opts = sparkout_datasets::GenerateOptions {
                // clap bounds it to 1..=MAX_RUNS.
                runs: runs as usize,
                seed,
                ae_rate_hz,
                ae_signal,
            };
            generate::generate(
                &what,
                &opts,
                out,
                &effects,
                list_effects,
                generate::Overrides { force, force_size },
            )
        }
        Command::Import {
            files,
            out,
            mapping,
            maps,
            table,
            machine,
            plugin,
            sample_period_s,
            list_mappings,
        } => import::import(&import::ImportArgs {
            files: &files,
            out: out.as_deref(),
            mapping: mapping.as_deref(),
            maps: &maps,
            table: table.as_deref(),
            machine: machine.as_deref(),
            plugin: plugin.as_deref(),
            sample_period_s,
            list_mappings,
        }),
        Command::Demo { out } => demo::demo(&out),
        Command::Diagnose {
            observations,
            out,
            flags,
            history,
            night,
            events,
        } => diagnose::diagnose(&observations, &out, &flags).and_then(|code| {
            match (history, night) {
                (Some(h), Some(n)) => trend::append(
                    &flags,
                    &trend::Night {
                        history: &h,
                        night: &n,
                        events: &events,
                    },
                    &out.join("diagnosis.json"),
                    &out.join("trend"),
                )
                .map(|()| code),
                _ => Ok(code),
            }
        }),
        Command::Validate {
            quick,
            nights,
            out,
            seed,
            json,
            config,
            ..
        } if nights => validate::validate_nights(quick, out, seed, json, &config),
        Command::Validate {
            quick,
            out,
            seed,
            json,
            cells,
            config,
            ..
        } => validate::validate(quick, out, seed, json, cells, &config),
        Command::Replay(args) => replay::replay(&args),
        Command::Can(crate::cli::CanCommand::Decode {
            log,
            format,
            out,
            eds,
        }) => can::decode(&log, &format, out.as_deref(), &eds),
        Command::Can(crate::cli::CanCommand::Compare {
            log,
            eds,
            axes,
            max_step_mm,
            max_step_change_mm,
            counts_per_mm,
            cycle_ms,
            json,
        }) => can::compare(&can::CompareArgs {
            log,
            eds,
            axes,
            max_step_mm,
            max_step_change_mm,
            counts_per_mm,
            cycle_ms,
            json,
        }),
        Command::Can(crate::cli::CanCommand::Describe { file, node, json }) => {
            can::describe(&file, node, json)
        }
    }
}

//! sparkout: a thin main. Parsing lives in `cli`, each subcommand in
//! `commands/`, the plugin list in `registry`.

mod bounds;
mod cli;
mod commands;
mod config_args;
mod help;
mod progress;
mod registry;

use std::process::ExitCode;

fn main() -> ExitCode {
    sparkout_pipeline::alloc::keep_freed_memory();
    let cli = match cli::parse() {
        Ok(cli) => cli,
        Err(code) => return code,
    };
    progress::init_logging(cli.verbose);
    match commands::dispatch(cli) {
        Ok(code) => ExitCode::from(code),
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(commands::USAGE_OR_CONFIG_ERROR)
        }
    }
}

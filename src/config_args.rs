//! The config flags every batch command shares (`--config`, `--set`,
//! `--machines`). Apart from cli.rs so that the registry, which builds the
//! engine from them, does not depend on the whole command line (cli.rs
//! depends on the registry for its help listings).

use std::path::PathBuf;

use clap::Args;

#[derive(Args, Debug, Clone)]
pub struct ConfigArgs {
    /// Pipeline config (TOML). Default: the built-in configs/nightly.toml.
    #[arg(long, value_name = "TOML")]
    pub config: Option<PathBuf>,
    /// Override a config key, e.g. --set robot.ingest.k_sigma=8 (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Directory of machine configs (<machine>.toml); also SPARKOUT_MACHINES.
    #[arg(long, value_name = "DIR")]
    pub machines: Option<PathBuf>,
}

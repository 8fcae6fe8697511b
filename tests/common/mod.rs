//! Shared by the end-to-end tests: run the `sparkout` binary quietly.

use std::process::{Command, Output};

pub fn sparkout(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sparkout"))
        .args(args)
        .env("SPARKOUT_LOG", "warn")
        .output()
        .expect("run sparkout")
}

//! Any text as run.toml, and its [process] against a plugin's keys.
//! The body is `sparkout_pipeline::fuzz_entry::run_toml`, which the test suite
//! also replays over this target's corpus.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sparkout_pipeline::fuzz_entry;

fuzz_target!(|data: &[u8]| fuzz_entry::run_toml(data));

//! Any bytes as observations.parquet, the diagnosis input.
//! The body is `sparkout_pipeline::fuzz_entry::observations`, which the test suite
//! also replays over this target's corpus.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sparkout_pipeline::fuzz_entry;

fuzz_target!(|data: &[u8]| fuzz_entry::observations(data, &std::env::temp_dir()));

//! Any text as an EDS: the PDO-mapping check answers, never panics.
//! The body is `sparkout_pipeline::fuzz_entry::eds`, which the test suite
//! also replays over this target's corpus.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sparkout_pipeline::fuzz_entry;

fuzz_target!(|data: &[u8]| fuzz_entry::eds(data));

//! Any text as a candump -l log: every line parses or is refused, and a
//! parsed frame prints back to a line that parses to the same frame.
//! The body is `sparkout_pipeline::fuzz_entry::candump`, which the test suite
//! also replays over this target's corpus.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sparkout_pipeline::fuzz_entry;

fuzz_target!(|data: &[u8]| fuzz_entry::candump(data));

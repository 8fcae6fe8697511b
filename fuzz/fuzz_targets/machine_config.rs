//! Any text as a machine config, checked against each built-in machine.
//! The body is `sparkout_pipeline::fuzz_entry::machine_config`, which the test suite
//! also replays over this target's corpus.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sparkout_pipeline::fuzz_entry;

const BUILTINS: [(&str, &str); 5] = [
    ("robot", include_str!("../../configs/machines/kr16-lab.toml")),
    ("gantry", include_str!("../../configs/machines/aplm-gantry.toml")),
    ("guideway", include_str!("../../configs/machines/guideway-grinder.toml")),
    ("mill", include_str!("../../configs/machines/xfyz-mill.toml")),
    ("form", include_str!("../../configs/machines/form-grinder.toml")),
];

fuzz_target!(|data: &[u8]| fuzz_entry::machine_config(data, &BUILTINS));

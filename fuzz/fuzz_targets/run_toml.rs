//! Any text as run.toml, and its [process] against a plugin's keys.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sparkout_pipeline::config_check::Check;
use sparkout_pipeline::contracts::config_keys::check_process;
use sparkout_pipeline::contracts::RunSpec;

const KEYS: sparkout_pipeline::ProcessKeys = &[
    ("probe_spacing_mm", Check::Positive),
    ("sample_step_mm", Check::Positive),
];

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(spec) = RunSpec::parse(std::path::Path::new("fuzz"), text) {
        let _ = check_process(&spec, "guideway", Some(KEYS));
    }
});

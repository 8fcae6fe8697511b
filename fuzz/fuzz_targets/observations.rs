//! Any bytes as observations.parquet, the diagnosis input.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sparkout_pipeline::diagnose::observations::read_observations;

fuzz_target!(|data: &[u8]| {
    let path = std::env::temp_dir().join(format!(
        "sparkout-fuzz-{}-observations.parquet",
        std::process::id()
    ));
    std::fs::write(&path, data).unwrap();
    let _ = read_observations(&path);
});

//! Any text as an EDS: the PDO-mapping check answers, never panics.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sparkout_pipeline::replay::canopen::check_eds;

fuzz_target!(|data: &[u8]| {
    let _ = check_eds(&String::from_utf8_lossy(data));
});

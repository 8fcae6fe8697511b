//! Any text as a candump -l log: every line parses or is refused, and a
//! parsed frame prints back to a line that parses to the same frame.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sparkout_pipeline::replay::log_bus::{format_line, parse_line};

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    for line in text.lines() {
        if let Ok(Some(f)) = parse_line(line) {
            let again = parse_line(&format_line(&f, "can0")).expect("own output parses");
            assert_eq!(again, Some(f));
        }
    }
});

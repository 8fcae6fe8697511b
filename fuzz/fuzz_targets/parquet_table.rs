//! Any bytes as a contract table (the first byte picks the table): the
//! validated reader answers with a table or an error naming the file, never
//! a panic. The AE log goes through its streaming reader.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sparkout_pipeline::contracts::{AeStream, Table, ALL_TABLES};

fuzz_target!(|data: &[u8]| {
    let Some((&pick, bytes)) = data.split_first() else {
        return;
    };
    let schema = &ALL_TABLES[pick as usize % ALL_TABLES.len()];
    let path = std::env::temp_dir().join(format!(
        "sparkout-fuzz-{}-{}",
        std::process::id(),
        schema.file_name()
    ));
    std::fs::write(&path, bytes).unwrap();
    if schema.name == "ae" {
        if let Ok(mut s) = AeStream::open_with_batch(&path, 64) {
            for chunk in &mut s {
                if chunk.is_err() {
                    break;
                }
            }
        }
    } else if let Err(e) = Table::read(&path, schema) {
        assert_eq!(e.file, path);
    }
});

//! Any bytes as a contract table (the first byte picks the table): the
//! validated reader answers with a table or an error naming the file, never
//! a panic. The AE log goes through its streaming reader.
//! The body is `sparkout_pipeline::fuzz_entry::parquet_table`, which the test suite
//! also replays over this target's corpus.
#![no_main]

use std::sync::LazyLock;

use libfuzzer_sys::fuzz_target;
use sparkout_pipeline::contracts::TableRegistry;
use sparkout_pipeline::fuzz_entry;

/// The shared tables and every plugin's, as the engine registers them.
static TABLES: LazyLock<TableRegistry> = LazyLock::new(|| {
    let plugins = sparkout_plugins::all_plugins();
    TableRegistry::of(plugins.iter().map(|p| (p.name(), p.tables()))).expect("plugins' tables")
});

fuzz_target!(|data: &[u8]| fuzz_entry::parquet_table(data, &std::env::temp_dir(), &TABLES));

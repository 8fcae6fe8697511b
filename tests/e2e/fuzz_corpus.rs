//! Every file of the fuzz corpora (`fuzz/corpus/TARGET/`) replayed through
//! the fuzz targets' own bodies (`sparkout_pipeline::fuzz_entry`): the
//! instrumented fuzz runs stay a documented script (docs/reliability.md "Fuzzing"), but
//! what they found — every finding becomes a corpus file — is checked on
//! every test run. A panic fails the test and names the file.

use std::path::{Path, PathBuf};

use sparkout_pipeline::fuzz_entry;

fn corpus(target: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz/corpus")
        .join(target);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    assert!(!files.is_empty(), "empty corpus {}", dir.display());
    files
}

/// Each corpus file through `body`; the files whose replay panicked.
fn replay(target: &str, body: &dyn Fn(&[u8])) {
    let mut panicked = Vec::new();
    let files = corpus(target);
    for f in &files {
        let data = std::fs::read(f).unwrap();
        if std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| body(&data))).is_err() {
            panicked.push(f.display().to_string());
        }
    }
    assert!(
        panicked.is_empty(),
        "{} of {} {target} corpus files panic: {panicked:?}",
        panicked.len(),
        files.len()
    );
}

#[test]
fn text_parsers_survive_their_corpora() {
    replay("run_toml", &fuzz_entry::run_toml);
    replay("candump", &fuzz_entry::candump);
    replay("eds", &fuzz_entry::eds);
    let plugins = sparkout_plugins::all_plugins();
    let builtins: Vec<(&str, &str)> = plugins
        .iter()
        .flat_map(|p| {
            p.builtin_machines()
                .into_iter()
                .map(move |(_, t)| (p.name(), t))
        })
        .collect();
    replay("machine_config", &|d| {
        fuzz_entry::machine_config(d, &builtins)
    });
}

#[test]
fn table_readers_survive_their_corpora() {
    let scratch = tempfile::tempdir().unwrap();
    let plugins = sparkout_plugins::all_plugins();
    let tables = sparkout_pipeline::contracts::TableRegistry::of(
        plugins.iter().map(|p| (p.name(), p.tables())),
    )
    .unwrap();
    replay("parquet_table", &|d| {
        fuzz_entry::parquet_table(d, scratch.path(), &tables)
    });
    replay("observations", &|d| {
        fuzz_entry::observations(d, scratch.path())
    });
}

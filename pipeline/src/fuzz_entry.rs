//! The bodies of the cargo-fuzz targets (`fuzz/fuzz_targets/`), one function
//! per parser a user's file reaches. The instrumented fuzz runs call them
//! from libFuzzer; the ordinary test suite replays every file of
//! `fuzz/corpus/TARGET/` through the same functions (tests/e2e/fuzz_corpus.rs),
//! so a finding, once in the corpus, stays a regression test. Each answers
//! with `Ok` or an error; a panic is the finding.

use std::path::Path;

use crate::contracts::config_keys::{check_process, load_machine};
use crate::contracts::{AeStream, MachineConfig, RunSpec, Table, TableRegistry};

/// Any text as run.toml, and its `[process]` against a plugin's keys.
pub fn run_toml(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(spec) = RunSpec::parse(Path::new("fuzz"), text) {
        const KEYS: crate::ProcessKeys = &[
            ("probe_spacing_mm", crate::config_check::Check::Positive),
            ("sample_step_mm", crate::config_check::Check::Positive),
        ];
        let _ = check_process(&spec, "guideway", KEYS);
    }
}

/// Any bytes as a contract table (the first byte picks one of `tables`: the
/// shared ones and the registered plugins'), written
/// to `scratch` and read back by the validated reader: a table or an error
/// naming the file. The AE log goes through its streaming reader.
pub fn parquet_table(data: &[u8], scratch: &Path, tables: &TableRegistry) {
    let Some((&pick, bytes)) = data.split_first() else {
        return;
    };
    let all: Vec<_> = tables.iter().collect();
    let schema = all[pick as usize % all.len()];
    let path = scratch.join(format!(
        "sparkout-fuzz-{}-{}",
        std::process::id(),
        schema.file_name()
    ));
    std::fs::write(&path, bytes).expect("scratch file");
    if schema.name == "ae" {
        if let Ok(mut s) = AeStream::open_with_batch(&path, 64) {
            for chunk in &mut s {
                if chunk.is_err() {
                    break;
                }
            }
        }
    } else if let Err(e) = Table::read(&path, schema) {
        assert_eq!(e.file, path, "the error names the file");
    }
}

/// Any bytes as a paired-observations table.
pub fn observations(data: &[u8], scratch: &Path) {
    let path = scratch.join(format!(
        "sparkout-fuzz-{}-observations.parquet",
        std::process::id()
    ));
    std::fs::write(&path, data).expect("scratch file");
    let _ = crate::diagnose::observations::read_observations(&path);
}

/// Any text (after a first byte that picks the plugin) as a machine config,
/// checked against that plugin's built-in machine; `builtins` is (plugin,
/// built-in machine TOML).
pub fn machine_config(data: &[u8], builtins: &[(&str, &str)]) {
    let Some((&pick, rest)) = data.split_first() else {
        return;
    };
    let Ok(text) = std::str::from_utf8(rest) else {
        return;
    };
    let Ok(table) = text.parse::<toml::Table>() else {
        return;
    };
    if builtins.is_empty() {
        return;
    }
    let (plugin, builtin) = builtins[pick as usize % builtins.len()];
    let mut m = MachineConfig {
        id: "fuzz".into(),
        source: "fuzz.toml".into(),
        table,
        text: text.to_string(),
        ..MachineConfig::default()
    };
    let _ = load_machine(&mut m, plugin, &[builtin], &[]);
}

/// Any text as candump -l lines: what parses formats back to itself.
pub fn candump(data: &[u8]) {
    use crate::replay::log_bus::{format_line, parse_line};
    let text = String::from_utf8_lossy(data);
    for line in text.lines() {
        if let Ok(Some(f)) = parse_line(line) {
            let again = parse_line(&format_line(&f, "can0")).expect("own output parses");
            assert_eq!(again, Some(f));
        }
    }
}

/// Any text as an EDS file through the drive check.
pub fn eds(data: &[u8]) {
    let _ = crate::replay::canopen::check_eds(&String::from_utf8_lossy(data));
}

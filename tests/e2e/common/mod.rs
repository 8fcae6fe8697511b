//! Shared by the end-to-end tests: run the `sparkout` binary quietly.

// Each test binary uses a different subset of these helpers.
#![allow(dead_code)]

use std::path::Path;
use std::process::{Command, Output};

pub fn sparkout(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sparkout"))
        .args(args)
        .env("SPARKOUT_LOG", "warn")
        .output()
        .expect("run sparkout")
}

/// `sparkout generate <plugin> --runs N --seed S --out DIR/runs [--effect E]
/// [extra...]`, then `sparkout run` into DIR/out; the fleet's diagnosis.json.
pub fn diagnose_generated_fleet(
    dir: &std::path::Path,
    plugin: &str,
    runs: usize,
    seed: u64,
    effect: Option<&str>,
    extra_generate_args: &[&str],
) -> serde_json::Value {
    let root = dir.join("runs");
    let out = dir.join("out");
    let (runs, seed) = (runs.to_string(), seed.to_string());
    let mut args = vec![
        "generate",
        plugin,
        "--runs",
        &runs,
        "--seed",
        &seed,
        "--out",
        root.to_str().unwrap(),
    ];
    if let Some(e) = effect {
        args.extend(["--effect", e]);
    }
    args.extend(extra_generate_args);
    let g = sparkout(&args);
    assert!(g.status.success(), "{}", String::from_utf8_lossy(&g.stderr));
    run_fleet_diagnosis(&root, &out)
}

/// `sparkout run --input INPUT --out OUT` (must succeed), then the fleet's
/// diagnosis.json.
pub fn run_fleet_diagnosis(input: &Path, out: &Path) -> serde_json::Value {
    let r = sparkout(&[
        "run",
        "--input",
        input.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        r.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&r.stdout),
        String::from_utf8_lossy(&r.stderr)
    );
    serde_json::from_slice(&std::fs::read(out.join("fleet/diagnosis.json")).unwrap()).unwrap()
}

/// The first effect of the fleet's `selected` list ("" when none).
pub fn first_selected(d: &serde_json::Value) -> String {
    d["selected"]
        .as_array()
        .and_then(|a| a.first())
        .and_then(|s| s.as_str())
        .unwrap_or("")
        .to_string()
}

/// The `effects` entry of a selected effect, by its `name:covariate` key.
pub fn selected_entry<'a>(d: &'a serde_json::Value, key: &str) -> Option<&'a serde_json::Value> {
    d["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["selected"].as_bool() == Some(true))
        .find(|e| match e["covariate"].as_str() {
            Some(c) => format!("{}:{c}", e["name"].as_str().unwrap()) == key,
            None => e["name"].as_str().unwrap() == key,
        })
}

/// A selected effect's held-out shrink (NaN when not selected).
pub fn shrink_of(d: &serde_json::Value, key: &str) -> f64 {
    selected_entry(d, key)
        .and_then(|e| e["shrink"].as_f64())
        .unwrap_or(f64::NAN)
}

/// A command's exit status, standard output and standard error, for an
/// assertion's message.
pub fn text(o: &Output) -> String {
    format!(
        "status {:?}\nstdout:\n{}\nstderr:\n{}",
        o.status.code(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// Asserts the command succeeded; its standard output then standard error.
pub fn ok(o: Output) -> String {
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(o.status.success(), "{text}");
    text
}

/// The tables the CLI knows: the shared ones and every registered plugin's.
pub fn tables() -> sparkout_pipeline::contracts::TableRegistry {
    let plugins = sparkout_plugins::all_plugins();
    sparkout_pipeline::contracts::TableRegistry::of(plugins.iter().map(|p| (p.name(), p.tables())))
        .unwrap()
}

/// Every file under `dir`, at any depth (none when it does not exist).
pub fn files_under(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut files = Vec::new();
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                files.extend(files_under(&p));
            } else {
                files.push(p);
            }
        }
    }
    files
}

//! configs/nightly.toml against the code's defaults: the
//! values nightly.toml writes for a stage must be what the stage does with no
//! section at all, or the two silently disagree. A small fleet of every
//! generator is run twice — with the built-in nightly.toml and with a config
//! that has no stage sections — and every per-run artifact and summary must
//! be byte-identical. A third run that changes one value proves the
//! comparison sees a difference.

use crate::common::sparkout;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

fn ok(out: &std::process::Output) {
    assert!(
        out.status.success(),
        "exit {:?}\nstdout:\n{}\nstderr:\n{}",
        out.status.code(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Every per-run stage output (artifacts and summaries) under `out`, by
/// path relative to it; caches, manifests and fleet outputs left out (they
/// hold the config's cache keys or depend on them only through these).
fn stage_outputs(out: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut files = BTreeMap::new();
    let mut stack = vec![out.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            let rel = p.strip_prefix(out).unwrap().to_path_buf();
            if p.is_dir() {
                if rel != Path::new("fleet") {
                    stack.push(p);
                }
                continue;
            }
            let name = p.file_name().unwrap().to_string_lossy().to_string();
            let top_level = rel.components().count() == 1;
            if !top_level
                && (name.ends_with(".parquet") || name.ends_with(".json"))
                && !name.starts_with(".sparkout")
            {
                files.insert(rel, std::fs::read(&p).unwrap());
            }
        }
    }
    files
}

fn differing(a: &BTreeMap<PathBuf, Vec<u8>>, b: &BTreeMap<PathBuf, Vec<u8>>) -> Vec<String> {
    let mut d: Vec<String> = a
        .iter()
        .filter(|(k, v)| b.get(*k) != Some(*v))
        .map(|(k, _)| k.display().to_string())
        .collect();
    d.extend(
        b.keys()
            .filter(|k| !a.contains_key(*k))
            .map(|k| k.display().to_string()),
    );
    d
}

#[test]
fn nightly_toml_writes_the_code_defaults() {
    let dir = tempfile::tempdir().unwrap();
    let runs = dir.path().join("runs");
    for g in sparkout_datasets::all_generators() {
        if g.demo().is_none() {
            continue;
        }
        let mut args = vec!["generate", g.name(), "--runs", "2", "--seed", "3"];
        args.extend(["--out", runs.to_str().unwrap()]);
        if g.name() == "robot" {
            args.extend(["--ae-rate-hz", "100000"]);
        }
        ok(&sparkout(&args));
    }
    // nightly.toml without any plugin's stage sections.
    let mut bare: toml::Table = sparkout_pipeline::engine::config::NIGHTLY_TOML
        .parse()
        .unwrap();
    let plugins: Vec<&str> = sparkout_plugins::all_plugins()
        .iter()
        .map(|p| p.name())
        .collect();
    let mut removed = 0;
    for p in &plugins {
        removed += bare.remove(*p).is_some() as usize;
    }
    assert!(
        removed >= 4,
        "nightly.toml has sections of {removed} plugins"
    );
    let bare_path = dir.path().join("bare.toml");
    std::fs::write(&bare_path, toml::to_string(&bare).unwrap()).unwrap();

    let run = |out: &str, extra: &[&str]| -> BTreeMap<PathBuf, Vec<u8>> {
        let out = dir.path().join(out);
        let mut args = vec!["run", "--input", runs.to_str().unwrap()];
        args.extend(["--out", out.to_str().unwrap()]);
        args.extend(extra);
        ok(&sparkout(&args));
        stage_outputs(&out)
    };
    let nightly = run("nightly", &[]);
    let defaults = run("defaults", &["--config", bare_path.to_str().unwrap()]);
    assert!(nightly.len() > 50, "{} stage outputs", nightly.len());
    let d = differing(&nightly, &defaults);
    assert!(
        d.is_empty(),
        "nightly.toml and the code's defaults disagree: these outputs differ: {d:?}"
    );
    // The comparison sees a changed value.
    let changed = run(
        "changed",
        &[
            "--config",
            bare_path.to_str().unwrap(),
            "--set",
            "gantry.polish_plan.tolerance_mm=0.002",
        ],
    );
    let d = differing(&defaults, &changed);
    assert!(
        d.iter().any(|f| f.contains("polish_plan")),
        "changing tolerance_mm changed nothing: {d:?}"
    );
}

/// The lines of nightly.toml's `[name]` block (up to the next header).
fn block<'a>(text: &'a str, name: &str) -> Option<Vec<&'a str>> {
    let header = format!("[{name}]");
    let mut lines = text.lines().skip_while(|l| l.trim() != header);
    lines.next()?;
    Some(
        lines
            .take_while(|l| !l.trim_start().starts_with('['))
            .collect(),
    )
}

/// `# key = value` lines of a block: the keys nightly.toml documents without
/// setting (their default comes from the machine or the run).
fn commented_keys(lines: &[&str]) -> Vec<String> {
    lines
        .iter()
        .filter_map(|l| l.trim().strip_prefix('#'))
        .filter_map(|l| {
            let (k, _) = l.split_once('=')?;
            let k = k.trim();
            (!k.is_empty() && k.chars().all(|c| c.is_ascii_alphanumeric() || c == '_'))
                .then(|| k.to_string())
        })
        .collect()
}

fn same_value(a: &toml::Value, b: &toml::Value) -> bool {
    match (
        sparkout_pipeline::toml_f64(a),
        sparkout_pipeline::toml_f64(b),
    ) {
        (Some(x), Some(y)) => x == y,
        _ => a == b,
    }
}

/// What is wrong with one section of nightly.toml against its struct.
fn section_disagreements(
    name: &str,
    text: &str,
    spec: &sparkout_pipeline::config_check::SectionCheck,
) -> Vec<String> {
    let mut bad = Vec::new();
    let Some(lines) = block(text, name) else {
        return vec![format!(
            "[{name}] is missing (every section documents its keys)"
        )];
    };
    let table: toml::Table = lines.join("\n").parse().unwrap();
    match (spec.read(&table), spec.read(&toml::Table::new())) {
        (Err(e), _) => bad.push(format!("[{name}] is refused: {e}")),
        (_, Err(e)) => bad.push(format!("[{name}]'s defaults are refused: {e}")),
        // Writing the defaults out is the same effective config (the same
        // cache key) as leaving them out.
        (Ok(written), Ok(omitted)) if written.effective() != omitted.effective() => {
            bad.push(format!(
                "[{name}]'s effective config {} is not the defaults' {}",
                written.effective(),
                omitted.effective()
            ))
        }
        _ => {}
    }
    let defaults = (spec.defaults)();
    let keys = (spec.keys)();
    let commented = commented_keys(&lines);
    for (k, v) in &table {
        match defaults.get(k) {
            Some(d) if same_value(d, v) => {}
            Some(d) => bad.push(format!("[{name}] {k} = {v}, the code's default is {d}")),
            None => bad.push(format!(
                "[{name}] sets {k} = {v}, which has no default in the code (write it commented)"
            )),
        }
    }
    for k in keys {
        let set = table.contains_key(*k);
        let documented = commented.iter().any(|c| c == k);
        if defaults.contains_key(*k) && !set {
            bad.push(format!("[{name}] does not write {k} = {}", defaults[*k]));
        }
        if !defaults.contains_key(*k) && !set && !documented {
            bad.push(format!(
                "[{name}] does not document {k} (a `# {k} = …` line)"
            ));
        }
    }
    for c in &commented {
        if !keys.contains(&c.as_str()) {
            bad.push(format!(
                "[{name}] documents `{c}`, which is not a key of the section"
            ));
        } else if defaults.contains_key(c) {
            bad.push(format!(
                "[{name}] comments out `{c}`, which has a default: write it uncommented"
            ));
        }
    }
    bad
}

/// Every registered stage's section struct, `[diagnose]` and `[trend]` against
/// configs/nightly.toml: each value written is the struct's default, every
/// default is written, every key without one is documented in a comment,
/// and nothing else is (so the shipped config cannot disagree with the code
/// or fall behind it).
#[test]
fn nightly_toml_sections_are_the_section_structs() {
    use sparkout_pipeline::config_check::SectionCheck;
    let text = sparkout_pipeline::engine::config::NIGHTLY_TOML;
    let mut bad = section_disagreements(
        "diagnose",
        text,
        &SectionCheck::of::<sparkout_pipeline::diagnose::DiagnoseConfig>(),
    );
    bad.extend(section_disagreements(
        "trend",
        text,
        &SectionCheck::of::<sparkout_pipeline::report::trend::TrendConfig>(),
    ));
    let mut stages = 0;
    for p in sparkout_plugins::all_plugins() {
        for s in p.stages() {
            let name = format!("{}.{}", p.name(), s.name());
            bad.extend(section_disagreements(&name, text, &s.spec().config));
            stages += 1;
        }
    }
    assert!(stages >= 20, "{stages} stages");
    assert!(bad.is_empty(), "configs/nightly.toml:\n{}", bad.join("\n"));
    // The check sees a wrong value, a missing default and a stale comment.
    let spec = SectionCheck::of::<sparkout_pipeline::diagnose::DiagnoseConfig>();
    let wrong = text.replace("folds = 5 ", "folds = 4 ");
    assert!(!section_disagreements("diagnose", &wrong, &spec).is_empty());
    let stale = text.replace("seed = 0 ", "# seed = 0 ");
    assert!(!section_disagreements("diagnose", &stale, &spec).is_empty());
}

//! `--help` lists what the registries hold, so nobody keeps a list by hand:
//! every registered generator in `generate --help`, every plugin's stages in
//! `stage --help`, every catalogue kind and plugin composite in
//! `diagnose --help`, every plugin in `run --help` (src/help.rs).

use sparkout_pipeline::diagnose::effect::Kind;

use super::common::sparkout;

fn help(cmd: &str) -> String {
    let out = sparkout(&[cmd, "--help"]);
    assert!(out.status.success(), "{cmd} --help failed");
    String::from_utf8(out.stdout).unwrap()
}

/// `name` appears in `text` as a word (not only inside a longer name).
fn has_word(text: &str, name: &str) -> bool {
    text.match_indices(name).any(|(i, _)| {
        let ok = |c: Option<char>| c.is_none_or(|c| !(c.is_alphanumeric() || c == '_' || c == '-'));
        ok(text[..i].chars().next_back()) && ok(text[i + name.len()..].chars().next())
    })
}

#[test]
fn generate_help_lists_every_generator() {
    let text = help("generate");
    let gens = sparkout_datasets::all_generators();
    assert!(gens.len() >= 7, "expected the seven-plus generators");
    let missing: Vec<&str> = gens
        .iter()
        .map(|g| g.name())
        .filter(|n| !has_word(&text, n))
        .collect();
    assert!(
        missing.is_empty(),
        "generate --help lacks {missing:?}:\n{text}"
    );
}

#[test]
fn stage_help_lists_every_stage_of_every_plugin() {
    let text = help("stage");
    let mut missing = Vec::new();
    for p in sparkout_plugins::all_plugins() {
        if !has_word(&text, p.name()) {
            missing.push(p.name().to_string());
        }
        for s in p.stages() {
            if !has_word(&text, s.spec().name) {
                missing.push(format!("{}.{}", p.name(), s.spec().name));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "stage --help lacks {missing:?}:\n{text}"
    );
}

#[test]
fn diagnose_and_run_help_list_effects_and_plugins() {
    let text = help("diagnose");
    let mut missing: Vec<String> = Kind::all()
        .into_iter()
        .map(|k| k.name().to_string())
        .filter(|n| !has_word(&text, n))
        .collect();
    for p in sparkout_plugins::all_plugins() {
        for e in p.effects() {
            if !has_word(&text, e.name()) {
                missing.push(format!("{}:{}", p.name(), e.name()));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "diagnose --help lacks {missing:?}:\n{text}"
    );
    let run = help("run");
    for p in sparkout_plugins::all_plugins() {
        assert!(
            has_word(&run, p.name()),
            "run --help lacks plugin {}",
            p.name()
        );
    }
}

//! `sparkout stage <name>`: one stage of one run, or a run-less stage fed by
//! its own flags.

use std::path::PathBuf;

use anyhow::{bail, Context};
use sparkout_pipeline::contracts::{write_json_atomic, write_parquet_atomic};
use sparkout_pipeline::{ConfigError, StageArgs};

use crate::cli::ConfigArgs;
use crate::registry;

/// `--key value` / `--key=value` / bare `--flag` → map (bare flags get "true").
fn parse_stage_flags(extra: &[String]) -> anyhow::Result<StageArgs> {
    let mut args = StageArgs::new();
    let mut i = 0;
    while i < extra.len() {
        let a = &extra[i];
        let Some(key) = a.strip_prefix("--") else {
            bail!("unexpected argument `{a}`; stage flags look like --name value");
        };
        if let Some((k, v)) = key.split_once('=') {
            args.insert(k.to_string(), v.to_string());
            i += 1;
        } else if i + 1 < extra.len() && !is_flag(&extra[i + 1]) {
            args.insert(key.to_string(), extra[i + 1].clone());
            i += 2;
        } else {
            args.insert(key.to_string(), "true".to_string());
            i += 1;
        }
    }
    Ok(args)
}

/// A flag (`--name`, `-x`), not a value that begins with `-`: engineers
/// type negative numbers and lists of them (`--planes "-0.0076,-1,0,12;..."`,
/// `--x -0.5`, `--offset -.5`), so anything whose first character after the
/// dash is not a letter is a value.
fn is_flag(s: &str) -> bool {
    if s.parse::<f64>().is_ok() {
        return false;
    }
    match s.strip_prefix("--") {
        Some(rest) => rest.chars().next().is_some_and(|c| c.is_alphabetic()),
        None => {
            let mut c = s.chars();
            c.next() == Some('-') && c.next().is_some_and(|c| c.is_alphabetic())
        }
    }
}

/// `stage NAME --run DIR --key value`: each leftover `--key value` becomes
/// `--set <plugin>.<NAME>.<key>=value` (dashes in the key read as
/// underscores) when the stage's config accepts that key — its own
/// `read_config` decides — e.g. `stage separate --run R --method
/// recursion`. Flags it rejects stay in `args` (and are reported below);
/// a known key with a bad value is an error naming the flag.
fn flags_as_config(
    engine: &sparkout_pipeline::engine::Engine,
    run_dir: &std::path::Path,
    name: &str,
    args: &mut StageArgs,
) -> anyhow::Result<Vec<String>> {
    let (_, plugin) = engine.open_run(run_dir)?;
    let Some(stage) = plugin.stages().into_iter().find(|s| s.name() == name) else {
        return Ok(Vec::new());
    };
    let mut sets = Vec::new();
    for (flag, value) in args.clone() {
        let key = flag.replace('-', "_");
        let set = format!("{}.{name}.{key}={value}", plugin.name());
        let mut probe = sparkout_pipeline::engine::PipelineConfig::parse("", "flags")?;
        probe.set(&set)?;
        let section = probe.section(&format!("{}.{name}", plugin.name()));
        match stage.read_config(&section) {
            Ok(_) => {
                args.remove(&flag);
                sets.push(set);
            }
            Err(e) if ConfigError::is_unknown_key(&e) => bail!(
                "stage flag --{flag}: {e} in [{}.{name}]; with --run, stage flags are that section's config keys (see configs/nightly.toml), or use --set {}.{name}.<key>=<value>",
                plugin.name(),
                plugin.name()
            ),
            Err(e) => bail!("--{flag} {value}: {e}"),
        }
    }
    Ok(sets)
}

pub fn stage(
    name: &str,
    run: Option<PathBuf>,
    out: Option<PathBuf>,
    json: bool,
    mut config: ConfigArgs,
    extra: &[String],
) -> anyhow::Result<u8> {
    let mut args = parse_stage_flags(extra)?;
    // Our own flags may land among the trailing ones; take them back.
    let json = json || args.remove("json").is_some();
    let run = run.or_else(|| args.remove("run").map(PathBuf::from));
    let out = out.or_else(|| args.remove("out").map(PathBuf::from));
    if let Some(s) = args.remove("set") {
        config.set.push(s);
    }
    let mut engine = registry::engine(&config)?;
    if let Some(run_dir) = run.as_ref().filter(|_| !args.is_empty()) {
        // With --run, leftover stage flags become config keys of that stage.
        for set in flags_as_config(&engine, run_dir, name, &mut args)? {
            config.set.push(set);
        }
        engine = registry::engine(&config)?;
    }
    match run {
        None => {
            let stage = engine
                .find_stage(name)
                .with_context(|| format!("unknown stage `{name}`; see `sparkout stage --help`"))?;
            let result = stage.run_standalone(&args).with_context(|| {
                format!(
                    "stage `{name}` needs --run <run dir> (it has no run-less form with these flags)"
                )
            })??;
            if let Some(out) = &out {
                write_json_atomic(&out.join(format!("{name}.json")), &result)?;
            }
            match stage.console(&result).filter(|_| !json) {
                Some(text) => print!("{text}"),
                None if json || out.is_none() => {
                    println!("{}", serde_json::to_string_pretty(&result)?)
                }
                None => {}
            }
            Ok(0)
        }
        Some(run_dir) => {
            if !args.is_empty() {
                let keys: Vec<&String> = args.keys().collect();
                let section = engine
                    .open_run(&run_dir)
                    .map(|(_, p)| format!("{}.{name}", p.name()))
                    .unwrap_or_else(|_| format!("<plugin>.{name}"));
                bail!(
                    "stage flags {keys:?} are not config keys of [{section}]; with --run, flags map to that section's keys (see configs/nightly.toml), or use --set {section}.<key>=<value>"
                );
            }
            let (stage, output) = engine.run_single_stage(&run_dir, name)?;
            if let Some(out) = &out {
                for (artifact, batch) in &output.artifacts {
                    write_parquet_atomic(&out.join(format!("{artifact}.parquet")), batch)?;
                }
                write_json_atomic(&out.join(format!("{}.json", stage.name())), &output.summary)?;
            }
            if json {
                println!("{}", serde_json::to_string_pretty(&output.summary)?);
            } else {
                let names: Vec<&str> = output.artifacts.iter().map(|a| a.0.as_str()).collect();
                match &out {
                    Some(o) => eprintln!("stage {name}: wrote {} to {}", names.join(", "), o.display()),
                    None => eprintln!(
                        "stage {name}: computed {} (nothing written: pass --out DIR, or --json to print the summary)",
                        names.join(", ")
                    ),
                }
            }
            Ok(0)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stage_flags_parse() {
        let v: Vec<String> = [
            "--weld-mm",
            "2.27",
            "--json",
            "--planes=1,2,3,4",
            "--x",
            "-0.5",
            "--planes2",
            "-0.0076,-0.0018,-1,12.44463;1,0,0,-20",
            "--offset",
            "-.5",
            "--scale",
            "-1e-3",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let a = parse_stage_flags(&v).unwrap();
        assert_eq!(a["weld-mm"], "2.27");
        assert_eq!(a["json"], "true");
        assert_eq!(a["planes"], "1,2,3,4");
        assert_eq!(a["x"], "-0.5");
        assert_eq!(a["planes2"], "-0.0076,-0.0018,-1,12.44463;1,0,0,-20");
        assert_eq!(a["offset"], "-.5");
        assert_eq!(a["scale"], "-1e-3");
        assert!(is_flag("--json") && is_flag("-v") && !is_flag("-") && !is_flag("-1,2"));
        assert!(parse_stage_flags(&["oops".to_string()]).is_err());
    }
}

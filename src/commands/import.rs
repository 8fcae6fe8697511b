//! `sparkout import`: CSV / Parquet with foreign column names → recorded
//! runs (docs/import.md). The named mappings are built into the binary.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use sparkout_pipeline::import::{import_files, Mapping};

/// Named mappings (configs/imports/<name>.toml), built in.
pub const BUILTIN_MAPPINGS: &[(&str, &str)] = &[(
    "umich_cnc",
    include_str!("../../configs/imports/umich_cnc.toml"),
)];

pub struct ImportArgs<'a> {
    pub files: &'a [PathBuf],
    pub out: Option<&'a Path>,
    pub mapping: Option<&'a str>,
    pub maps: &'a [String],
    pub table: Option<&'a str>,
    pub machine: Option<&'a str>,
    pub plugin: Option<&'a str>,
    pub sample_period_s: Option<f64>,
    pub list_mappings: bool,
}

/// A mapping by built-in name or TOML path.
fn load_mapping(name: &str) -> anyhow::Result<Mapping> {
    if let Some((_, text)) = BUILTIN_MAPPINGS.iter().find(|(n, _)| *n == name) {
        return Ok(Mapping::from_toml(
            text,
            &format!("`{name}` (built in)"),
            &crate::registry::tables()?,
        )?);
    }
    let p = Path::new(name);
    if p.is_file() {
        let text = std::fs::read_to_string(p)
            .with_context(|| format!("cannot read mapping {}", p.display()))?;
        return Ok(Mapping::from_toml(
            &text,
            &p.display().to_string(),
            &crate::registry::tables()?,
        )?);
    }
    let known: Vec<&str> = BUILTIN_MAPPINGS.iter().map(|(n, _)| *n).collect();
    bail!(
        "--mapping {name}: neither a built-in mapping ({}) nor a TOML file",
        known.join(", ")
    )
}

pub fn import(a: &ImportArgs) -> anyhow::Result<u8> {
    if a.list_mappings {
        for (name, text) in BUILTIN_MAPPINGS {
            let m = Mapping::from_toml(text, name, &crate::registry::tables()?)?;
            println!(
                "{name:12} → table {}, machine {}, plugin {} ({} columns)",
                m.table,
                m.machine,
                m.plugin,
                m.columns.len()
            );
        }
        return Ok(super::ALL_GOOD);
    }
    let out = a.out.context("--out <fleet root> is required")?;
    if a.files.is_empty() {
        bail!("no input files: `sparkout import FILE... --out DIR --mapping NAME`");
    }
    let mut m = match a.mapping {
        Some(name) => load_mapping(name)?,
        None => {
            let (Some(table), Some(machine), Some(plugin)) = (a.table, a.machine, a.plugin) else {
                bail!("without --mapping, give --table, --machine and --plugin (and --map SRC=DEST[*FACTOR] per column)");
            };
            Mapping::from_flags(table, machine, plugin, &crate::registry::tables()?)
        }
    };
    // Flags override the mapping file's settings.
    if let Some(t) = a.table {
        m.table = t.to_string();
    }
    if let Some(v) = a.machine {
        m.machine = v.to_string();
    }
    if let Some(v) = a.plugin {
        m.plugin = v.to_string();
    }
    if a.sample_period_s.is_some() {
        m.sample_period_s = a.sample_period_s;
    }
    for f in a.maps {
        m.apply_flag(f)?;
    }
    m.validate().context("the import mapping")?;
    let outcome = import_files(a.files, &m, out)?;
    for r in &outcome.runs {
        println!("{} rows → {}", r.rows, r.dir.display());
    }
    for (p, e) in &outcome.failures {
        eprintln!("refused {}: {e}", p.display());
    }
    println!(
        "imported {} runs of machine `{}` (plugin {}) under {}; {} files refused",
        outcome.runs.len(),
        m.machine,
        m.plugin,
        out.display(),
        outcome.failures.len()
    );
    Ok(if outcome.failures.is_empty() {
        super::ALL_GOOD
    } else {
        super::SOME_RUNS_FAILED
    })
}

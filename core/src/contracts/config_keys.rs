//! Config typos are never silent: a machine config's sections and keys are
//! checked against the plugin's built-in machines (they are the reference
//! of what a machine of that type has), and run.toml `[process]` against the
//! keys the plugin reads. Without this, `[whel] radius_mm = 40` or
//! `repeatability_mm = "0.5 um"` fell back to the built-in default, exit 0.

use std::collections::BTreeMap;

use super::run::{MachineConfig, RunSpec};
use crate::config_check::{Check, SectionCheck};
use crate::error::InputError;
use crate::{toml_f64, ProcessKeys};

/// Dotted leaf keys of a TOML table with their values.
fn leaves<'a>(t: &'a toml::Table, prefix: &str, out: &mut BTreeMap<String, &'a toml::Value>) {
    for (k, v) in t {
        let key = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        match v {
            toml::Value::Table(inner) => leaves(inner, &key, out),
            _ => {
                out.insert(key, v);
            }
        }
    }
}

/// Every number in a value (arrays included) is finite.
fn all_finite(v: &toml::Value) -> bool {
    match v {
        toml::Value::Float(f) => f.is_finite(),
        toml::Value::Array(a) => a.iter().all(all_finite),
        _ => true,
    }
}

fn kind(v: &toml::Value) -> &'static str {
    match v {
        toml::Value::Integer(_) | toml::Value::Float(_) => "a number",
        toml::Value::String(_) => "a string",
        toml::Value::Boolean(_) => "a boolean",
        toml::Value::Array(_) => "an array",
        toml::Value::Datetime(_) => "a date-time",
        toml::Value::Table(_) => "a table",
    }
}

/// Keys that describe the machine rather than parametrise a model.
const DESCRIPTIVE: [&str; 3] = ["machine.id", "machine.plugin", "machine.description"];

/// Positions and offsets may be negative (latencies are 0 in the
/// built-in machines, so unconstrained).
fn may_be_negative(key: &str) -> bool {
    let leaf = key.rsplit('.').next().unwrap_or(key);
    ["x_mm", "y_mm", "z_mm"].contains(&leaf)
        || ["_x_mm", "_y_mm", "_z_mm", "_pos_mm"]
            .iter()
            .any(|s| leaf.ends_with(s))
        || leaf.contains("offset")
}

/// Names of sizes, rates and periods: zero is as impossible as negative
/// (docs/formats.md lists them; a test keeps the two alike).
pub const POSITIVE_NAMES: [&str; 13] = [
    "radius", "period", "feed", "depth", "stock", "_hz", "speed", "spacing", "width", "area",
    "length", "rpm", "step",
];

/// The range of a machine-config number, from the built-in machine's value
/// for the same key (docs/formats.md "Machine configs"): a position or
/// offset any finite number; a size, rate or period the built-in gives
/// positive > 0; any other number the built-in gives positive ≥ 0; else
/// any finite number.
pub fn machine_check(key: &str, reference: &toml::Value) -> Check {
    let leaf = key.rsplit('.').next().unwrap_or(key);
    let positive_reference = toml_f64(reference).is_some_and(|r| r > 0.0);
    if !positive_reference || may_be_negative(key) {
        Check::Number
    } else if POSITIVE_NAMES.iter().any(|n| leaf.contains(n)) {
        Check::Positive
    } else {
        Check::NonNegative
    }
}

/// Check a resolved machine config against the built-in machines of the
/// run's plugin (`builtins`: their TOML texts). Built-in machines pass.
/// `[tolerance]` and `[replay]` are left to their own readers.
pub fn check_machine(m: &MachineConfig, plugin: &str, builtins: &[&str]) -> Result<(), InputError> {
    let err = |key: &str, msg: String| InputError::new(&m.source, msg).column(key.to_string());
    if m.table.is_empty() {
        return Err(InputError::new(
            &m.source,
            format!(
                "machine config `{}` is empty; copy a built-in machine of plugin `{plugin}` (configs/machines/) and edit it",
                m.id
            ),
        ));
    }
    if let Some(p) = m.table.get("machine").and_then(|t| t.get("plugin")) {
        if p.as_str() != Some(plugin) {
            return Err(err(
                "machine.plugin",
                format!(
                    "machine `{}` is for plugin {p}, but the run is a `{plugin}` run",
                    m.id
                ),
            ));
        }
    }
    let mut known: BTreeMap<String, &toml::Value> = BTreeMap::new();
    let parsed: Vec<toml::Table> = builtins
        .iter()
        .filter_map(|t| t.parse::<toml::Table>().ok())
        .collect();
    for t in &parsed {
        leaves(t, "", &mut known);
    }
    if known.is_empty() {
        return Ok(()); // nothing to compare against
    }
    let mut mine = BTreeMap::new();
    leaves(&m.table, "", &mut mine);
    // [replay] (EDS files per node, drive axes) is checked by the replay
    // that reads it; no plugin's built-in machine has one. `[tolerance]` is
    // the same table in every machine type: read by its own list
    // ([`load_machine`]), not against the built-in machines.
    mine.retain(|k, _| !k.starts_with("replay.") && !k.starts_with("tolerance."));
    for (key, v) in &mine {
        if !all_finite(v) {
            return Err(err(key, format!("`{key}` must be finite, found {v}")));
        }
        if DESCRIPTIVE.contains(&key.as_str()) {
            continue;
        }
        let Some(reference) = known.get(key) else {
            let section = key.rsplit_once('.').map(|(s, _)| s).unwrap_or("");
            let in_section: Vec<&str> = known
                .keys()
                .filter(|k| k.rsplit_once('.').map(|(s, _)| s).unwrap_or("") == section)
                .map(|k| k.rsplit('.').next().unwrap_or(k))
                .collect();
            let msg = if in_section.is_empty() {
                let mut sections: Vec<&str> = known
                    .keys()
                    .map(|k| k.rsplit_once('.').map(|(s, _)| s).unwrap_or(""))
                    .filter(|s| !s.is_empty())
                    .collect();
                sections.dedup();
                format!(
                    "unknown section [{section}] (key `{key}`); a `{plugin}` machine has the sections {}",
                    sections
                        .iter()
                        .map(|s| format!("[{s}]"))
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            } else {
                format!(
                    "unknown key `{key}`; [{section}] of a `{plugin}` machine has: {}",
                    in_section.join(", ")
                )
            };
            return Err(err(key, msg));
        };
        if kind(reference) != kind(v) {
            return Err(err(
                key,
                format!(
                    "`{key}` must be {} (like {reference} in the built-in machine), found {v}",
                    kind(reference)
                ),
            ));
        }
        if toml_f64(v).is_some() {
            let check = machine_check(key, reference);
            if !check.accepts(v) {
                return Err(err(
                    key,
                    format!("`{key}` must be {}, found {v}", check.describe()),
                ));
            }
        }
    }
    Ok(())
}

/// Load a resolved machine config for a run, once: [`check_machine`]
/// against the plugin's built-in machines (every key known, of the
/// built-in's type, in the range its value implies), then `[tolerance]`
/// and each section the plugin declares (`sections`: name and serde
/// struct) read into their typed values, kept in the config for the
/// stages ([`MachineConfig::section`]). An absent declared section holds
/// its struct's defaults. Any error names the machine config and the key
/// as the column `<section>.<key>`.
pub fn load_machine(
    m: &mut MachineConfig,
    plugin: &str,
    builtins: &[&str],
    sections: &[(&str, SectionCheck)],
) -> Result<(), InputError> {
    check_machine(m, plugin, builtins)?;
    let err = |key: String, msg: String| InputError::new(&m.source, msg).column(key);
    let tolerance = match m.table.get("tolerance") {
        None => BTreeMap::new(),
        Some(t) => super::tolerance::check_tolerance(t).map_err(|(k, msg)| err(k, msg))?,
    };
    let mut typed = BTreeMap::new();
    for (name, check) in sections {
        let table = match m.table.get(*name) {
            None => toml::Table::new(),
            Some(toml::Value::Table(t)) => t.clone(),
            Some(_) => return Err(err(name.to_string(), format!("[{name}] must be a table"))),
        };
        let value = check.read(&table).map_err(|e| {
            let column = e
                .config()
                .and_then(|c| c.key())
                .map_or_else(|| name.to_string(), |k| format!("{name}.{k}"));
            err(column, format!("[{name}]: {e:#}"))
        })?;
        typed.insert(name.to_string(), value);
    }
    m.tolerance = tolerance;
    m.sections = typed;
    Ok(())
}

/// Check run.toml `[process]` against the keys the plugin reads and their
/// ranges (a plugin that reads none declares none): an unknown key, a
/// wrong type or a value out of range is an error naming run.toml and the
/// key (as the column `process.<key>`).
pub fn check_process(spec: &RunSpec, plugin: &str, known: ProcessKeys) -> Result<(), InputError> {
    let err = |k: &str, msg: String| {
        InputError::new(spec.run_toml_path(), msg).column(format!("process.{k}"))
    };
    for (k, v) in &spec.process {
        if !all_finite(v) {
            return Err(err(k, format!("[process].{k} must be finite, found {v}")));
        }
        let Some((_, check)) = known.iter().find(|(name, _)| name == k) else {
            let names: Vec<&str> = known.iter().map(|(n, _)| *n).collect();
            let names = if names.is_empty() {
                "none".to_string()
            } else {
                names.join(", ")
            };
            return Err(err(
                k,
                format!("unknown key [process].{k} for a `{plugin}` run (known: {names})"),
            ));
        };
        if !check.accepts(v) {
            return Err(err(
                k,
                format!(
                    "[process].{k} must be {}, found {v} (docs/formats.md lists each key's range)",
                    check.describe()
                ),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const BUILTIN: &str = "[machine]\nid = \"g\"\nplugin = \"guideway\"\n[table]\nrepeatability_mm = 0.0005\nspeed_mm_s = 333.0\n[probes]\nspacing_mm = 30.0\n";

    fn machine(text: &str) -> MachineConfig {
        MachineConfig {
            id: "g".into(),
            source: "g.toml".into(),
            table: text.parse().unwrap(),
            text: text.into(),
            ..MachineConfig::default()
        }
    }

    #[test]
    fn process_keys_are_checked_by_type_range_and_name() {
        const KEYS: ProcessKeys = &[
            ("passes", Check::WholeIn(1, 100)),
            ("infeed_mm", Check::Positive),
            ("shape", Check::Text),
        ];
        let spec = |process: &str| {
            RunSpec::parse(
                std::path::Path::new("runs/g/r1"),
                &format!("[run]\nid = \"r1\"\nmachine = \"g\"\nplugin = \"guideway\"\n[process]\n{process}\n"),
            )
            .unwrap()
        };
        check_process(
            &spec("passes = 3\ninfeed_mm = 0.01\nshape = \"ellipse\""),
            "guideway",
            KEYS,
        )
        .unwrap();
        for (bad, key, needle) in [
            // A wrong type is an error, never the default.
            (
                "infeed_mm = \"0.01\"",
                "infeed_mm",
                "must be a number > 0, found \"0.01\"",
            ),
            (
                "passes = \"3\"",
                "passes",
                "must be a whole number in 1..=100",
            ),
            ("passes = 2.5", "passes", "must be a whole number"),
            ("shape = 5", "shape", "must be a string"),
            ("infeed_mm = [1.0]", "infeed_mm", "must be a number > 0"),
            ("infeed_mm = -1", "infeed_mm", "must be a number > 0"),
            (
                "infed_mm = 0.01",
                "infed_mm",
                "unknown key [process].infed_mm",
            ),
        ] {
            let e = check_process(&spec(bad), "guideway", KEYS).unwrap_err();
            assert_eq!(
                e.column.as_deref(),
                Some(format!("process.{key}").as_str()),
                "{bad}"
            );
            let text = e.to_string();
            assert!(
                text.contains("runs/g/r1/run.toml") && text.contains(needle),
                "{bad}: {text}"
            );
        }
        // A plugin that reads no [process] key refuses any.
        let e = check_process(&spec("gain = 2"), "servo", &[]).unwrap_err();
        assert!(e.to_string().contains("unknown key [process].gain"), "{e}");
    }

    /// `[probes]` as a plugin declares it: a serde struct, a range per key.
    #[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
    #[serde(deny_unknown_fields, default)]
    struct Probes {
        spacing_mm: Option<f64>,
        count: Option<u32>,
    }

    impl crate::config_check::Section for Probes {
        const CHECKS: &'static [(&'static str, Check)] = &[
            ("spacing_mm", Check::Positive),
            ("count", Check::WholeIn(3, 3)),
        ];
    }

    const SECTIONS: &[(&str, SectionCheck)] = &[("probes", SectionCheck::of::<Probes>())];

    fn load(text: &str) -> Result<MachineConfig, InputError> {
        let builtin = format!("{BUILTIN}count = 3\n");
        let mut m = machine(text);
        load_machine(&mut m, "guideway", &[&builtin], SECTIONS).map(|()| m)
    }

    #[test]
    fn machine_sections_are_read_once_into_their_types() {
        let m = load(&format!(
            "{BUILTIN}count = 3\n[tolerance]\nguideway_residual_um = 4.0\n"
        ))
        .unwrap();
        let p = m.section::<Probes>().unwrap();
        assert_eq!((p.spacing_mm, p.count), (Some(30.0), Some(3)));
        assert_eq!(m.tolerance.get("guideway_residual_um"), Some(&4.0));
        // An absent section holds its struct's defaults.
        let m = load("[machine]\nid = \"g\"\nplugin = \"guideway\"\n").unwrap();
        assert_eq!(m.section::<Probes>(), Some(&Probes::default()));
        assert!(m.tolerance.is_empty());
        // An unknown key, a wrong type, a value out of range (the built-in
        // machine's range, or the section's own), a section that is not a
        // table: each refused naming the file and `section.key`.
        for (bad, column, needle) in [
            (
                "[probes]\nspacing = 30.0\n",
                "probes.spacing",
                "unknown key `probes.spacing`",
            ),
            (
                "[probes]\nspacing_mm = \"30 mm\"\n",
                "probes.spacing_mm",
                "must be a number",
            ),
            (
                "[probes]\ncount = 3.5\n",
                "probes.count",
                "must be a whole number in 3..=3",
            ),
            (
                "[probes]\nspacing_mm = 0\n",
                "probes.spacing_mm",
                "must be a number > 0",
            ),
            (
                "[probes]\ncount = 4\n",
                "probes.count",
                "must be a whole number in 3..=3",
            ),
            (
                "[tolerance]\nflatnes_um = 5\n",
                "tolerance.flatnes_um",
                "unknown key [tolerance].flatnes_um",
            ),
        ] {
            let text = format!("[machine]\nid = \"g\"\nplugin = \"guideway\"\n{bad}");
            let e = load(&text).unwrap_err();
            assert_eq!(e.column.as_deref(), Some(column), "{bad}: {e}");
            let msg = e.to_string();
            assert!(
                msg.contains("g.toml") && msg.contains(needle),
                "{bad}: {msg}"
            );
        }
    }

    #[test]
    fn builtin_passes_typos_do_not() {
        check_machine(&machine(BUILTIN), "guideway", &[BUILTIN]).unwrap();
        // `[tolerance]` is accepted in any machine, checked by its own list.
        let with_tol = format!("{BUILTIN}[tolerance]\nguideway_residual_um = 4.0\n");
        let mut m = machine(&with_tol);
        load_machine(&mut m, "guideway", &[BUILTIN], &[]).unwrap();
        for (bad, needle) in [
            (
                "[tabel]\nrepeatability_mm = 0.5\n",
                "unknown section [tabel]",
            ),
            (
                "[table]\nrepeatability = 0.5\n",
                "unknown key `table.repeatability`",
            ),
            (
                "[table]\nrepeatability_mm = \"0.5 um\"\n",
                "must be a number",
            ),
            ("[table]\nrepeatability_mm = -0.5\n", "must be a number ≥ 0"),
            ("[table]\nspeed_mm_s = -1\n", "must be a number > 0"),
            ("[table]\nspeed_mm_s = 0\n", "must be a number > 0"),
            ("[probes]\nspacing_mm = 0.0\n", "must be a number > 0"),
            ("[table]\nrepeatability_mm = nan\n", "must be finite"),
            ("", "is empty"),
            ("[machine]\nplugin = \"robot\"\n", "for plugin"),
            (
                "[table]\nspeed_mm_s = 1.0\n[tolerance]\nflatnes_um = 5\n",
                "unknown key [tolerance].flatnes_um",
            ),
        ] {
            let e = load_machine(&mut machine(bad), "guideway", &[BUILTIN], &[])
                .unwrap_err()
                .to_string();
            assert!(e.contains(needle), "{bad:?}: {e}");
            assert!(e.contains("g.toml"), "{e}");
        }
    }
}

//! Checking a stage's config section (`[<plugin>.<stage>]`): every key
//! known, every value of the right type and range, with an error that names
//! the key. Shared by every plugin (a plugin knows no other plugin).

use crate::Result;
use anyhow::bail;

/// What a key's value must be.
#[derive(Debug, Clone, Copy)]
pub enum Check {
    /// A number > 0.
    Positive,
    /// A number ≥ 0.
    NonNegative,
    /// A number in (0, 1].
    Fraction,
    /// A number in (0, 1).
    Probability,
    /// A boolean.
    Bool,
    /// One of these strings.
    OneOf(&'static [&'static str]),
    /// A number ≥ 1.
    AtLeastOne,
}

fn number(v: &toml::Value) -> Option<f64> {
    match v {
        toml::Value::Float(f) => Some(*f),
        toml::Value::Integer(i) => Some(*i as f64),
        _ => None,
    }
}

/// Check a stage's section against its known keys.
pub fn check_config(config: &toml::Table, keys: &[(&str, Check)]) -> Result<()> {
    for (k, v) in config {
        let Some((_, check)) = keys.iter().find(|(name, _)| name == k) else {
            let known: Vec<&str> = keys.iter().map(|(n, _)| *n).collect();
            bail!(
                "unknown key `{k}` (known: {})",
                if known.is_empty() {
                    "none".to_string()
                } else {
                    known.join(", ")
                }
            );
        };
        let ok = match check {
            Check::Positive => number(v).is_some_and(|x| x.is_finite() && x > 0.0),
            Check::NonNegative => number(v).is_some_and(|x| x.is_finite() && x >= 0.0),
            Check::Fraction => number(v).is_some_and(|x| x > 0.0 && x <= 1.0),
            Check::Probability => number(v).is_some_and(|x| x > 0.0 && x < 1.0),
            Check::AtLeastOne => number(v).is_some_and(|x| x.is_finite() && x >= 1.0),
            Check::Bool => v.is_bool(),
            Check::OneOf(opts) => v.as_str().is_some_and(|s| opts.contains(&s)),
        };
        if !ok {
            let want = match check {
                Check::Positive => "a number > 0".to_string(),
                Check::NonNegative => "a number ≥ 0".to_string(),
                Check::Fraction => "a number in (0, 1]".to_string(),
                Check::Probability => "a number in (0, 1)".to_string(),
                Check::AtLeastOne => "a number ≥ 1".to_string(),
                Check::Bool => "true or false".to_string(),
                Check::OneOf(opts) => format!("one of {}", opts.join(", ")),
            };
            bail!("key `{k}` must be {want}, found {v}");
        }
    }
    Ok(())
}

/// Run-less stage flags (`--p-max 20`) as a config table (`p_max = 20`):
/// dashes read as underscores, values as TOML (numbers, booleans), else
/// text; the flags in `inputs` are the stage's own and are left out.
pub fn flags_to_table(args: &crate::StageArgs, inputs: &[&str]) -> toml::Table {
    let mut t = toml::Table::new();
    for (k, v) in args {
        if inputs.contains(&k.as_str()) {
            continue;
        }
        let value = format!("v = {v}")
            .parse::<toml::Table>()
            .ok()
            .and_then(|mut x| x.remove("v"))
            .unwrap_or_else(|| toml::Value::String(v.clone()));
        t.insert(k.replace('-', "_"), value);
    }
    t
}

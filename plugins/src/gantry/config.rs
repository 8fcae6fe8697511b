//! Checking `[gantry.<stage>]` config sections: every key known, every value
//! of the right type and range, with an error that names the key and says
//! what to write instead.

use anyhow::bail;
use sparkout_pipeline::Result;

/// What a key's value must be.
#[derive(Debug, Clone, Copy)]
pub enum Check {
    /// A number > 0.
    Positive,
    /// A number ≥ 0.
    NonNegative,
    /// A number in (0, 1).
    Probability,
    /// A number ≥ 1.
    AtLeastOne,
    /// One of these strings.
    OneOf(&'static [&'static str]),
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
            Check::Probability => number(v).is_some_and(|x| x > 0.0 && x < 1.0),
            Check::AtLeastOne => number(v).is_some_and(|x| x.is_finite() && x >= 1.0),
            Check::OneOf(opts) => v.as_str().is_some_and(|s| opts.contains(&s)),
        };
        if !ok {
            let want = match check {
                Check::Positive => "a number > 0".to_string(),
                Check::NonNegative => "a number ≥ 0".to_string(),
                Check::Probability => "a number in (0, 1)".to_string(),
                Check::AtLeastOne => "a number ≥ 1".to_string(),
                Check::OneOf(opts) => format!("one of {}", opts.join(", ")),
            };
            bail!("key `{k}` must be {want}, found {v}");
        }
    }
    Ok(())
}

/// Topography states in the order a workpiece goes through them
/// (CONTRACTS.md §1, topography.parquet).
pub const STATES: [&str; 5] = ["pattern", "before", "after_grind", "after_polish", "final"];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_unknown_keys_and_bad_values() {
        let keys = [
            ("tol_mm", Check::Positive),
            ("state", Check::OneOf(&STATES)),
        ];
        let ok: toml::Table = "tol_mm = 0.01\nstate = \"before\"".parse().unwrap();
        assert!(check_config(&ok, &keys).is_ok());
        let bad: toml::Table = "tol = 0.01".parse().unwrap();
        assert!(check_config(&bad, &keys)
            .unwrap_err()
            .to_string()
            .contains("unknown key `tol`"));
        let neg: toml::Table = "tol_mm = -1".parse().unwrap();
        assert!(check_config(&neg, &keys).is_err());
        let st: toml::Table = "state = \"polished\"".parse().unwrap();
        assert!(check_config(&st, &keys)
            .unwrap_err()
            .to_string()
            .contains("one of"));
    }
}

//! Checking a stage's config section (`[<plugin>.<stage>]`): every key
//! known, every value of the right type and range, with an error that names
//! the key. Shared by every plugin (a plugin knows no other plugin).

use serde::de::{DeserializeOwned, Visitor};
use std::cell::Cell;

use crate::error::ConfigError;
use crate::values::toml_f64;

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
    /// A whole number in lo..=hi (a TOML integer, or a float without a
    /// fractional part as `--set` may write one).
    WholeIn(i64, i64),
    /// An odd whole number ≥ lo (a window of points centred on one).
    OddAtLeast(i64),
}

/// How a stage's config section is checked before anything runs (its
/// `StageSpec::config`).
#[derive(Debug, Clone, Copy)]
pub enum SectionCheck {
    /// Against these keys and what each value must be.
    Keys(&'static [(&'static str, Check)]),
    /// By parsing it: a serde struct with `deny_unknown_fields` read by
    /// [`parse_section`], then its range checks.
    Parsed(fn(&toml::Table) -> crate::Result<()>),
}

impl SectionCheck {
    pub fn check(&self, config: &toml::Table) -> crate::Result<()> {
        match self {
            SectionCheck::Keys(keys) => check_config(config, keys),
            SectionCheck::Parsed(parse) => parse(config),
        }
    }
}

/// A TOML integer, or a float with no fractional part.
pub fn whole_number(v: &toml::Value) -> Option<i64> {
    match v {
        toml::Value::Integer(i) => Some(*i),
        toml::Value::Float(f) if f.fract() == 0.0 && f.is_finite() => Some(*f as i64),
        _ => None,
    }
}

/// One key, if present, a whole number in lo..=hi.
pub fn check_whole(config: &toml::Table, key: &str, lo: i64, hi: i64) -> crate::Result<()> {
    match config.get(key) {
        Some(v) => check_config(
            &toml::Table::from_iter([(key.to_string(), v.clone())]),
            &[(key, Check::WholeIn(lo, hi))],
        ),
        None => Ok(()),
    }
}

/// Check a stage's section against its known keys. The error is a
/// [`ConfigError`] (downcast to tell an unknown key from a bad value).
pub fn check_config(config: &toml::Table, keys: &[(&str, Check)]) -> crate::Result<()> {
    for (k, v) in config {
        let Some((_, check)) = keys.iter().find(|(name, _)| name == k) else {
            return Err(ConfigError::UnknownKey {
                key: k.clone(),
                known: keys.iter().map(|(n, _)| n.to_string()).collect(),
            }
            .into());
        };
        let ok = match check {
            Check::Positive => toml_f64(v).is_some_and(|x| x.is_finite() && x > 0.0),
            Check::NonNegative => toml_f64(v).is_some_and(|x| x.is_finite() && x >= 0.0),
            Check::Fraction => toml_f64(v).is_some_and(|x| x > 0.0 && x <= 1.0),
            Check::Probability => toml_f64(v).is_some_and(|x| x > 0.0 && x < 1.0),
            Check::AtLeastOne => toml_f64(v).is_some_and(|x| x.is_finite() && x >= 1.0),
            Check::WholeIn(lo, hi) => whole_number(v).is_some_and(|i| (*lo..=*hi).contains(&i)),
            Check::OddAtLeast(lo) => whole_number(v).is_some_and(|i| i >= *lo && i % 2 == 1),
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
                Check::WholeIn(lo, hi) => format!("a whole number in {lo}..={hi}"),
                Check::OddAtLeast(lo) => format!("an odd whole number ≥ {lo}"),
                Check::Bool => "true or false".to_string(),
                Check::OneOf(opts) => format!("one of {}", opts.join(", ")),
            };
            return Err(ConfigError::bad_value(k, want, v).into());
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

/// Read a config section into its serde struct: a key the struct does not
/// have is [`ConfigError::UnknownKey`] (listing the struct's fields), a
/// value of the wrong type [`ConfigError::Invalid`]. The struct's own range
/// checks run after this (its `validate()`).
pub fn parse_section<T: DeserializeOwned>(config: &toml::Table) -> Result<T, ConfigError> {
    let fields = struct_fields::<T>();
    if let Some(k) = config.keys().find(|k| !fields.contains(&k.as_str())) {
        return Err(ConfigError::UnknownKey {
            key: k.clone(),
            known: fields.iter().map(|f| f.to_string()).collect(),
        });
    }
    toml::Value::Table(config.clone())
        .try_into()
        .map_err(|e: toml::de::Error| ConfigError::Invalid(e.to_string().trim().to_string()))
}

/// The field names serde knows for struct `T` (what `deny_unknown_fields`
/// accepts), found by asking `T` to deserialize from a probe that records
/// the names serde passes to `deserialize_struct` and stops there.
pub fn struct_fields<T: DeserializeOwned>() -> &'static [&'static str] {
    let seen = Cell::new(&[][..]);
    let _ = T::deserialize(FieldProbe(&seen));
    seen.get()
}

struct FieldProbe<'a>(&'a Cell<&'static [&'static str]>);

#[derive(Debug)]
struct ProbeStop;

impl std::fmt::Display for ProbeStop {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("field probe")
    }
}
impl std::error::Error for ProbeStop {}
impl serde::de::Error for ProbeStop {
    fn custom<M: std::fmt::Display>(_: M) -> Self {
        ProbeStop
    }
}

impl<'de> serde::Deserializer<'de> for FieldProbe<'_> {
    type Error = ProbeStop;
    fn deserialize_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, ProbeStop> {
        Err(ProbeStop)
    }
    fn deserialize_struct<V: Visitor<'de>>(
        self,
        _name: &'static str,
        fields: &'static [&'static str],
        _visitor: V,
    ) -> Result<V::Value, ProbeStop> {
        self.0.set(fields);
        Err(ProbeStop)
    }
    serde::forward_to_deserialize_any! {
        bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string
        bytes byte_buf option unit unit_struct newtype_struct seq tuple
        tuple_struct map enum identifier ignored_any
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, serde::Deserialize, PartialEq)]
    #[serde(deny_unknown_fields)]
    struct Section {
        tol_mm: Option<f64>,
        #[serde(default)]
        passes: u32,
    }

    #[test]
    fn sections_parse_and_unknown_keys_are_typed() {
        assert_eq!(struct_fields::<Section>(), &["tol_mm", "passes"]);
        let t = |s: &str| s.parse::<toml::Table>().unwrap();
        let ok: Section = parse_section(&t("tol_mm = 0.5\npasses = 3")).unwrap();
        assert_eq!((ok.tol_mm, ok.passes), (Some(0.5), 3));
        let e = parse_section::<Section>(&t("tol = 0.5")).unwrap_err();
        assert_eq!(e.to_string(), "unknown key `tol` (known: tol_mm, passes)");
        assert!(ConfigError::is_unknown_key(&anyhow::Error::from(e)));
        let e = parse_section::<Section>(&t("passes = \"many\"")).unwrap_err();
        assert!(matches!(e, ConfigError::Invalid(_)), "{e}");
        let e = check_config(&t("tol_mm = -1"), &[("tol_mm", Check::Positive)]).unwrap_err();
        assert_eq!(e.to_string(), "key `tol_mm` must be a number > 0, found -1");
        assert!(!ConfigError::is_unknown_key(&e));
        assert!(check_whole(&t("n = 3.0"), "n", 1, 5).is_ok());
        let e = check_whole(&t("n = 3.5"), "n", 1, 5).unwrap_err();
        assert_eq!(
            e.to_string(),
            "key `n` must be a whole number in 1..=5, found 3.5"
        );
        assert!(check_whole(&t("n = 6"), "n", 1, 5).is_err());
        let odd = [("w", Check::OddAtLeast(5))];
        assert!(check_config(&t("w = 7"), &odd).is_ok());
        assert!(check_config(&t("w = 7.0"), &odd).is_ok());
        for bad in ["w = 6", "w = 3", "w = 7.5", "w = -7"] {
            let e = check_config(&t(bad), &odd).unwrap_err();
            assert!(
                e.to_string().contains("an odd whole number ≥ 5"),
                "{bad}: {e}"
            );
        }
    }
}

//! Checking a stage's config section (`[<plugin>.<stage>]`): every key
//! known, every value of the right type and range, with an error that names
//! the key. Shared by every plugin (a plugin knows no other plugin).

use serde::de::{DeserializeOwned, Visitor};
use serde::Serialize;
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
    /// Any finite number (a position, which may be negative).
    Number,
    /// Any string (a label kept for provenance).
    Text,
    /// An array of this many numbers, each > 0 (a block's size per axis).
    PositiveArray(usize),
}

impl Check {
    /// Whether `v` is what this check wants.
    pub fn accepts(&self, v: &toml::Value) -> bool {
        let finite = |v: &toml::Value| toml_f64(v).filter(|x| x.is_finite());
        match self {
            Check::Positive => finite(v).is_some_and(|x| x > 0.0),
            Check::NonNegative => finite(v).is_some_and(|x| x >= 0.0),
            Check::Fraction => toml_f64(v).is_some_and(|x| x > 0.0 && x <= 1.0),
            Check::Probability => toml_f64(v).is_some_and(|x| x > 0.0 && x < 1.0),
            Check::AtLeastOne => finite(v).is_some_and(|x| x >= 1.0),
            Check::WholeIn(lo, hi) => whole_number(v).is_some_and(|i| (*lo..=*hi).contains(&i)),
            Check::OddAtLeast(lo) => whole_number(v).is_some_and(|i| i >= *lo && i % 2 == 1),
            Check::Bool => v.is_bool(),
            Check::OneOf(opts) => v.as_str().is_some_and(|s| opts.contains(&s)),
            Check::Number => finite(v).is_some(),
            Check::Text => v.is_str(),
            Check::PositiveArray(n) => v.as_array().is_some_and(|a| {
                a.len() == *n && a.iter().all(|x| finite(x).is_some_and(|x| x > 0.0))
            }),
        }
    }

    /// What the check wants, as the error message and docs/formats.md say
    /// it ("a number > 0").
    pub fn describe(&self) -> String {
        match self {
            Check::Positive => "a number > 0".to_string(),
            Check::NonNegative => "a number ≥ 0".to_string(),
            Check::Fraction => "a number in (0, 1]".to_string(),
            Check::Probability => "a number in (0, 1)".to_string(),
            Check::AtLeastOne => "a number ≥ 1".to_string(),
            Check::WholeIn(lo, hi) => format!("a whole number in {lo}..={hi}"),
            Check::OddAtLeast(lo) => format!("an odd whole number ≥ {lo}"),
            Check::Bool => "true or false".to_string(),
            Check::OneOf(opts) => format!("one of {}", opts.join(", ")),
            Check::Number => "a finite number".to_string(),
            Check::Text => "a string".to_string(),
            Check::PositiveArray(n) => format!("an array of {n} numbers > 0"),
        }
    }
}

/// A config section as a serde struct: the one way a stage (and the
/// diagnosis) declares its settings. Defaults live in `Default` only (the
/// struct carries `#[serde(deny_unknown_fields, default)]`), per-key ranges
/// in [`Section::CHECKS`] (checked on the TOML before serde reads it, so the
/// error names the key and the range), checks across keys in
/// [`Section::validate`]. configs/nightly.toml is tested against
/// [`SectionCheck::defaults`] for every registered stage.
pub trait Section: DeserializeOwned + Serialize + Default {
    /// What each key's value must be; a key absent here is checked by its
    /// type alone. Every name must be a field (checked at registration).
    const CHECKS: &'static [(&'static str, Check)] = &[];
    /// Checks across keys, or beyond a [`Check`], after parsing.
    fn validate(&self) -> crate::Result<()> {
        Ok(())
    }
}

/// A section with no keys (`[gantry.matrices]`: everything is in the
/// machine config).
#[derive(Debug, Clone, Default, PartialEq, Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoKeys {}

impl Section for NoKeys {}

/// Read and check a section: unknown key → [`ConfigError::UnknownKey`]
/// (listing the struct's fields), a value outside its [`Check`] →
/// [`ConfigError::BadValue`], a wrong type → [`ConfigError::Invalid`], then
/// [`Section::validate`]. An absent key takes the struct's default.
pub fn read_section<T: Section>(config: &toml::Table) -> crate::Result<T> {
    let fields = struct_fields::<T>();
    if let Some(k) = config.keys().find(|k| !fields.contains(&k.as_str())) {
        return Err(ConfigError::UnknownKey {
            key: k.clone(),
            known: fields.iter().map(|f| f.to_string()).collect(),
        }
        .into());
    }
    let mut table = config.clone();
    for (k, v) in table.iter_mut() {
        if let Some((_, check)) = T::CHECKS.iter().find(|(name, _)| name == k) {
            check_value(k, v, check)?;
            // `--set n=3.0` is the whole number 3 for an integer field.
            if matches!(check, Check::WholeIn(..) | Check::OddAtLeast(_)) {
                if let Some(i) = whole_number(v) {
                    *v = toml::Value::Integer(i);
                }
            }
        }
    }
    let section: T = parse_section(&table)?;
    section.validate()?;
    Ok(section)
}

/// Check settings built in code (not read from a config) as if they had
/// been: serialised to their section and read back through
/// [`read_section`], so the ranges live in [`Section::CHECKS`] only.
pub fn check_settings<T: Section>(settings: &T) -> crate::Result<()> {
    let table = match toml::Value::try_from(settings) {
        Ok(toml::Value::Table(t)) => t,
        Ok(_) => anyhow::bail!("settings do not serialise to a section"),
        Err(e) => anyhow::bail!("settings do not serialise to a section: {e}"),
    };
    read_section::<T>(&table).map(drop)
}

/// How a stage's config section (`[<plugin>.<stage>]`) is read: its
/// [`Section`] struct, as function pointers a `const` [`StageSpec`] can hold
/// (`SectionCheck::of::<RemovalConfig>()`).
///
/// [`StageSpec`]: crate::StageSpec
#[derive(Debug, Clone, Copy)]
pub struct SectionCheck {
    /// Read and check a section (the value is dropped: the stage reads it
    /// again with [`read_section`] when it runs).
    pub check: fn(&toml::Table) -> crate::Result<()>,
    /// The defaults as TOML (an `Option` field whose default is `None` is
    /// absent: its default comes from the machine or the run).
    pub defaults: fn() -> toml::Table,
    /// The keys the section accepts.
    pub keys: fn() -> &'static [&'static str],
    /// [`Section::CHECKS`] names that are not fields (a plugin bug, refused
    /// when the stage is registered).
    pub undeclared_checks: fn() -> Vec<&'static str>,
}

impl SectionCheck {
    pub const fn of<T: Section>() -> SectionCheck {
        SectionCheck {
            check: check_section::<T>,
            defaults: section_defaults::<T>,
            keys: struct_fields::<T>,
            undeclared_checks: undeclared_checks::<T>,
        }
    }
    pub fn check(&self, config: &toml::Table) -> crate::Result<()> {
        (self.check)(config)
    }
}

fn check_section<T: Section>(config: &toml::Table) -> crate::Result<()> {
    read_section::<T>(config).map(drop)
}

fn section_defaults<T: Section>() -> toml::Table {
    match toml::Value::try_from(T::default()) {
        Ok(toml::Value::Table(t)) => t,
        // A section struct serialises to a table; anything else is a bug
        // the registry test catches (no defaults to compare).
        _ => toml::Table::new(),
    }
}

fn undeclared_checks<T: Section>() -> Vec<&'static str> {
    let fields = struct_fields::<T>();
    T::CHECKS
        .iter()
        .map(|(k, _)| *k)
        .filter(|k| !fields.contains(k))
        .collect()
}

/// A TOML integer, or a float with no fractional part.
pub fn whole_number(v: &toml::Value) -> Option<i64> {
    match v {
        toml::Value::Integer(i) => Some(*i),
        toml::Value::Float(f) if f.fract() == 0.0 && f.is_finite() => Some(*f as i64),
        _ => None,
    }
}

/// One key's value against what it must be.
fn check_value(k: &str, v: &toml::Value, check: &Check) -> Result<(), ConfigError> {
    if check.accepts(v) {
        return Ok(());
    }
    Err(ConfigError::bad_value(k, check.describe(), v))
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

/// A run-less stage's own flags (`stage cycle --weld-mm 2.27 --rough 7`)
/// checked like config keys: each flag named in `flags` with what its value
/// must be; an unknown flag or a value outside its [`Check`] is an error
/// naming the stage and the flag. Returns the values as TOML by flag name
/// (dashes kept); an absent flag is absent.
pub fn read_flags(
    stage: &str,
    args: &crate::StageArgs,
    flags: &[(&str, Check)],
) -> crate::Result<toml::Table> {
    let table = flags_to_table(args, &[]);
    let mut out = toml::Table::new();
    for (k, v) in table {
        let flag = k.replace('_', "-");
        let Some((_, check)) = flags.iter().find(|(name, _)| *name == flag) else {
            anyhow::bail!(
                "stage {stage}: unknown option --{flag} (known: {})",
                flags
                    .iter()
                    .map(|(f, _)| format!("--{f}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        };
        if !check.accepts(&v) {
            anyhow::bail!(
                "stage {stage}: --{flag} must be {}, got {}",
                check.describe(),
                args.get(&flag).map(String::as_str).unwrap_or("?")
            );
        }
        out.insert(flag, v);
    }
    Ok(out)
}

/// Read a config section into its serde struct: a key the struct does not
/// have is [`ConfigError::UnknownKey`] (listing the struct's fields), a
/// value of the wrong type [`ConfigError::Invalid`]. The struct's own range
/// checks run after this (its `validate()`).
fn parse_section<T: DeserializeOwned>(config: &toml::Table) -> Result<T, ConfigError> {
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

    #[derive(Debug, serde::Deserialize, Serialize, PartialEq)]
    #[serde(deny_unknown_fields, default)]
    struct Sample {
        tol_mm: Option<f64>,
        passes: u32,
        window: u32,
    }

    impl Default for Sample {
        fn default() -> Self {
            Sample {
                tol_mm: None,
                passes: 3,
                window: 9,
            }
        }
    }

    impl Section for Sample {
        const CHECKS: &'static [(&'static str, Check)] = &[
            ("tol_mm", Check::Positive),
            ("passes", Check::WholeIn(1, 5)),
            ("window", Check::OddAtLeast(5)),
        ];
        fn validate(&self) -> crate::Result<()> {
            if self.tol_mm.is_some_and(|t| t > self.window as f64) {
                anyhow::bail!("tol_mm must not exceed window");
            }
            Ok(())
        }
    }

    #[derive(Debug, serde::Deserialize, Serialize, Default)]
    #[serde(deny_unknown_fields, default)]
    struct Typo {
        tol_mm: f64,
    }
    impl Section for Typo {
        const CHECKS: &'static [(&'static str, Check)] = &[("tol", Check::Positive)];
    }

    #[test]
    fn sections_parse_and_errors_are_typed() {
        assert_eq!(struct_fields::<Sample>(), &["tol_mm", "passes", "window"]);
        let t = |s: &str| s.parse::<toml::Table>().unwrap();
        let ok: Sample = read_section(&t("tol_mm = 0.5\npasses = 4")).unwrap();
        assert_eq!((ok.tol_mm, ok.passes, ok.window), (Some(0.5), 4, 9));
        // `--set passes=3.0` is the whole number 3.
        assert_eq!(
            read_section::<Sample>(&t("passes = 3.0")).unwrap().passes,
            3
        );
        let e = read_section::<Sample>(&t("tol = 0.5")).unwrap_err();
        assert_eq!(
            e.to_string(),
            "unknown key `tol` (known: tol_mm, passes, window)"
        );
        assert!(ConfigError::is_unknown_key(&e));
        let e = read_section::<Sample>(&t("tol_mm = -1")).unwrap_err();
        assert_eq!(e.to_string(), "key `tol_mm` must be a number > 0, found -1");
        assert!(!ConfigError::is_unknown_key(&e));
        let e = read_section::<Sample>(&t("passes = 3.5")).unwrap_err();
        assert_eq!(
            e.to_string(),
            "key `passes` must be a whole number in 1..=5, found 3.5"
        );
        assert!(read_section::<Sample>(&t("passes = 6")).is_err());
        for bad in ["window = 6", "window = 3", "window = 7.5", "window = -7"] {
            let e = read_section::<Sample>(&t(bad)).unwrap_err();
            assert!(
                e.to_string().contains("an odd whole number ≥ 5"),
                "{bad}: {e}"
            );
        }
        assert_eq!(
            read_section::<Sample>(&t("window = 7.0")).unwrap().window,
            7
        );
        // A key without a check is checked by its type.
        let e = read_section::<Typo>(&t("tol_mm = \"many\"")).unwrap_err();
        assert!(
            matches!(
                e.downcast_ref::<ConfigError>(),
                Some(ConfigError::Invalid(_))
            ),
            "{e}"
        );
        // Across keys.
        let e = read_section::<Sample>(&t("tol_mm = 10")).unwrap_err();
        assert_eq!(e.to_string(), "tol_mm must not exceed window");
        assert!(read_section::<Sample>(&t("tol_mm = 10\nwindow = 11")).is_ok());
    }

    #[test]
    fn a_section_declares_its_defaults_keys_and_checks() {
        let spec = SectionCheck::of::<Sample>();
        let d = (spec.defaults)();
        // An Option whose default is None is absent: it has no default.
        assert_eq!(d.keys().collect::<Vec<_>>(), ["passes", "window"]);
        assert_eq!(d["passes"].as_integer(), Some(3));
        assert_eq!((spec.keys)(), ["tol_mm", "passes", "window"]);
        assert!((spec.undeclared_checks)().is_empty());
        assert_eq!((SectionCheck::of::<Typo>().undeclared_checks)(), ["tol"]);
        assert!((SectionCheck::of::<NoKeys>().keys)().is_empty());
        assert!(SectionCheck::of::<NoKeys>()
            .check(&"x = 1".parse().unwrap())
            .is_err());
    }
}

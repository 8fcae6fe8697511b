//! Checking a stage's config section (`[<plugin>.<stage>]`): every key
//! known, every value of the right type and range, with an error that names
//! the key. Shared by every plugin (a plugin knows no other plugin).

use serde::de::{DeserializeOwned, Visitor};
use serde::Serialize;
use std::any::Any;
use std::cell::Cell;
use std::sync::Arc;

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
pub trait Section: DeserializeOwned + Serialize + Default + Send + Sync + 'static {
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
/// [`ConfigError::BadValue`], a wrong type → [`ConfigError::WrongType`], then
/// [`Section::validate`]. An absent key takes the struct's default. The
/// unknown-key check is made here once, for the error that lists the
/// fields; serde's `deny_unknown_fields` never sees one after it.
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
    let section: T = match toml::Value::Table(table.clone()).try_into() {
        Ok(s) => s,
        Err(e) => return Err(type_error::<T>(&table, e).into()),
    };
    section.validate()?;
    Ok(section)
}

/// A value serde could not read, naming the key: the first key that fails
/// on its own (each is read alone, the others at their defaults) — the
/// error message of serde's whole-table read does not always name it.
fn type_error<T: Section>(table: &toml::Table, e: toml::de::Error) -> ConfigError {
    let msg = e.to_string().trim().to_string();
    let culprit = table.iter().find(|(k, v)| {
        let one = toml::Table::from_iter([((*k).clone(), (*v).clone())]);
        toml::Value::Table(one).try_into::<T>().is_err()
    });
    match culprit {
        Some((k, _)) => ConfigError::WrongType {
            key: k.clone(),
            message: msg,
        },
        None => ConfigError::Invalid(msg),
    }
}

/// Check settings built in code (not read from a config) as if they had
/// been: serialised to their section and read back through
/// [`read_section`], so the ranges live in [`Section::CHECKS`] only.
pub fn check_settings<T: Section>(settings: &T) -> crate::Result<()> {
    let table = match toml::Value::try_from(settings) {
        Ok(toml::Value::Table(t)) => t,
        Ok(_) => crate::bail!("settings do not serialise to a section"),
        Err(e) => crate::bail!("settings do not serialise to a section: {e}"),
    };
    read_section::<T>(&table).map(drop)
}

/// A section read and checked once ([`read_section`]): its typed value,
/// handed to the stage as it is ([`CheckedSection::get`]), and its
/// effective config — the value serialised canonically (every field, the
/// defaults applied, object keys sorted) — which the cache key hashes, so
/// a changed default recomputes what it affects and a default written out
/// keeps the same key as the default left out.
#[derive(Clone)]
pub struct CheckedSection {
    value: Arc<dyn Any + Send + Sync>,
    effective: String,
}

impl std::fmt::Debug for CheckedSection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CheckedSection")
            .field("effective", &self.effective)
            .finish()
    }
}

impl CheckedSection {
    /// Read and check `config` as `T` ([`read_section`]).
    pub fn read<T: Section>(config: &toml::Table) -> crate::Result<CheckedSection> {
        Ok(Checked::<T>::read(config)?.erase())
    }
    /// The typed value; `None` when the section is not a `T` (a stage
    /// asking for another struct than its spec declares).
    pub fn get<T: Section>(&self) -> Option<&T> {
        self.value.downcast_ref::<T>()
    }
    /// The effective config: canonical JSON of the checked value.
    pub fn effective(&self) -> &str {
        &self.effective
    }
}

/// A section of a known type, read and checked once (the settings of the
/// diagnosis, `[pipeline]`, `[report]`): only [`Checked::read`] and
/// [`Checked::check`] make one, so holding it is proof the checks ran; it
/// dereferences to the value and carries its effective config.
#[derive(Debug)]
pub struct Checked<T> {
    value: Arc<T>,
    effective: Arc<str>,
}

impl<T> Clone for Checked<T> {
    fn clone(&self) -> Self {
        Checked {
            value: self.value.clone(),
            effective: self.effective.clone(),
        }
    }
}

impl<T: Section> Checked<T> {
    /// Read and check a section ([`read_section`]).
    pub fn read(config: &toml::Table) -> crate::Result<Checked<T>> {
        Checked::wrap(read_section::<T>(config)?)
    }
    /// Settings built in code, held to the section's checks
    /// ([`check_settings`]).
    pub fn check(value: T) -> crate::Result<Checked<T>> {
        check_settings(&value)?;
        Checked::wrap(value)
    }
    /// A value its own code has just checked another way (the diagnosis
    /// allows any u64 seed in code, more than a TOML section holds).
    pub fn checked_by_caller(value: T) -> crate::Result<Checked<T>> {
        Checked::wrap(value)
    }
    fn wrap(value: T) -> crate::Result<Checked<T>> {
        let effective = effective_config(&value)?;
        Ok(Checked {
            value: Arc::new(value),
            effective: effective.into(),
        })
    }
    /// The effective config: canonical JSON of the checked value.
    pub fn effective(&self) -> &str {
        &self.effective
    }
    /// The same value, type-erased for a map of stages' sections.
    pub fn erase(&self) -> CheckedSection {
        CheckedSection {
            value: self.value.clone(),
            effective: self.effective.to_string(),
        }
    }
}

impl<T> std::ops::Deref for Checked<T> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.value
    }
}

/// A checked value serialised canonically: JSON with every object's keys
/// sorted, every field present (a `None` is `null`), numbers as serde_json
/// writes them (shortest round-trip form). Independent of the order the
/// keys were written in the config and of whether a default was written.
pub fn effective_config<T: Serialize>(value: &T) -> crate::Result<String> {
    let v =
        serde_json::to_value(value).map_err(|e| crate::err!("config does not serialise: {e}"))?;
    let mut out = String::new();
    write_canonical(&v, &mut out);
    Ok(out)
}

fn write_canonical(v: &serde_json::Value, out: &mut String) {
    match v {
        serde_json::Value::Object(m) => {
            let mut keys: Vec<&String> = m.keys().collect();
            keys.sort();
            out.push('{');
            for (i, k) in keys.into_iter().enumerate() {
                if i > 0 {
                    out.push(',');
                }
                out.push_str(&serde_json::Value::String(k.clone()).to_string());
                out.push(':');
                write_canonical(&m[k], out);
            }
            out.push('}');
        }
        serde_json::Value::Array(a) => {
            out.push('[');
            for (i, x) in a.iter().enumerate() {
                if i > 0 {
                    out.push(',');
                }
                write_canonical(x, out);
            }
            out.push(']');
        }
        other => out.push_str(&other.to_string()),
    }
}

/// How a stage's config section (`[<plugin>.<stage>]`) is read: its
/// [`Section`] struct, as function pointers a `const` [`StageSpec`] can hold
/// (`SectionCheck::of::<RemovalConfig>()`).
///
/// [`StageSpec`]: crate::StageSpec
#[derive(Debug, Clone, Copy)]
pub struct SectionCheck {
    /// Read and check a section into its typed value (the engine does it
    /// once per batch and hands the value to the stage).
    pub read: fn(&toml::Table) -> crate::Result<CheckedSection>,
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
            read: CheckedSection::read::<T>,
            defaults: section_defaults::<T>,
            keys: struct_fields::<T>,
            undeclared_checks: undeclared_checks::<T>,
        }
    }
    pub fn read(&self, config: &toml::Table) -> crate::Result<CheckedSection> {
        (self.read)(config)
    }
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
            crate::bail!(
                "stage {stage}: unknown option --{flag} (known: {})",
                flags
                    .iter()
                    .map(|(f, _)| format!("--{f}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        };
        if !check.accepts(&v) {
            crate::bail!(
                "stage {stage}: --{flag} must be {}, got {}",
                check.describe(),
                args.get(&flag).map(String::as_str).unwrap_or("?")
            );
        }
        out.insert(flag, v);
    }
    Ok(out)
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
                crate::bail!("tol_mm must not exceed window");
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
                e.config(),
                Some(ConfigError::WrongType { key, .. }) if key == "tol_mm"
            ),
            "{e}"
        );
        // Across keys.
        let e = read_section::<Sample>(&t("tol_mm = 10")).unwrap_err();
        assert_eq!(e.to_string(), "tol_mm must not exceed window");
        assert!(read_section::<Sample>(&t("tol_mm = 10\nwindow = 11")).is_ok());
    }

    #[test]
    fn the_effective_config_is_the_checked_value_written_canonically() {
        let t = |s: &str| s.parse::<toml::Table>().unwrap();
        let key = |s: &str| {
            Checked::<Sample>::read(&t(s))
                .unwrap()
                .effective()
                .to_string()
        };
        // Every field, defaults applied, keys sorted.
        assert_eq!(key(""), r#"{"passes":3,"tol_mm":null,"window":9}"#);
        // A default written out, keys in another order, `--set`'s 3.0 for
        // an integer: the same effective config.
        assert_eq!(key(""), key("window = 9\npasses = 3"));
        assert_eq!(key("passes = 3.0"), key(""));
        assert_eq!(
            key("tol_mm = 0.5\nwindow = 11"),
            key("window = 11\ntol_mm = 0.5")
        );
        // Another value: another effective config.
        assert_ne!(key("passes = 4"), key(""));
        assert_ne!(key("tol_mm = 0.5"), key(""));
        // A changed default changes the effective config of a section that
        // does not write the key.
        let changed = Sample {
            passes: 4,
            ..Sample::default()
        };
        assert_ne!(effective_config(&changed).unwrap(), key(""));
        // Erased, the value and its effective config are kept.
        let erased = Checked::<Sample>::read(&t("passes = 2")).unwrap().erase();
        assert_eq!(erased.get::<Sample>().map(|s| s.passes), Some(2));
        assert!(erased.get::<Typo>().is_none());
        assert_eq!(erased.effective(), key("passes = 2"));
    }

    #[test]
    fn a_wrong_type_names_its_key() {
        let t = |s: &str| s.parse::<toml::Table>().unwrap();
        let e = read_section::<Typo>(&t("tol_mm = [1]")).unwrap_err();
        assert!(e.to_string().starts_with("key `tol_mm`: "), "{e}");
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
            .read(&"x = 1".parse().unwrap())
            .is_err());
    }
}

//! Units as data: what a column's unit is, where that was stated, and the
//! exact conversion into the contracts' units (lengths in mm, times in s,
//! speeds in mm/s).
//!
//! A unit can be stated in five places, strongest first (docs/formats.md
//! "Units"): a per-axis CLI flag, a per-column unit in an import mapping,
//! Parquet field metadata (key `unit`), the observations `unit` column, and
//! a unit suffix in the column's name. Two places that state different
//! units are a conflict and an error — a silent choice between them is how
//! a µm file becomes a "mm" result.
//!
//! Conversions are one correctly rounded operation: a factor of ten to a
//! power is applied by dividing or multiplying by the exact power
//! (`v / 1e6` for nm → mm), never by a rounded reciprocal (`v * 1e-6`
//! rounds twice).

use std::fmt;

pub mod format;

/// What a unit measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Kind {
    Length,
    Time,
    Speed,
}

impl Kind {
    /// The contracts' unit of this kind.
    pub fn canonical(self) -> Unit {
        match self {
            Kind::Length => Unit::MM,
            Kind::Time => Unit::S,
            Kind::Speed => Unit::MM_S,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Kind::Length => "length",
            Kind::Time => "time",
            Kind::Speed => "speed",
        }
    }
}

/// How a value in this unit becomes the canonical unit: one exact
/// operation.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Scale {
    Mul(f64),
    Div(f64),
}

/// A unit sparkout can convert. `symbol` is how it is written in outputs
/// (`µm`), `ascii` how it is written in names and files (`um`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Unit {
    pub kind: Kind,
    pub ascii: &'static str,
    pub symbol: &'static str,
    scale: Scale,
}

impl Eq for Unit {}

impl fmt::Display for Unit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.symbol)
    }
}

impl Unit {
    pub const NM: Unit = Unit::new(Kind::Length, "nm", "nm", Scale::Div(1e6));
    pub const UM: Unit = Unit::new(Kind::Length, "um", "µm", Scale::Div(1e3));
    pub const MM: Unit = Unit::new(Kind::Length, "mm", "mm", Scale::Mul(1.0));
    pub const M: Unit = Unit::new(Kind::Length, "m", "m", Scale::Mul(1e3));
    pub const S: Unit = Unit::new(Kind::Time, "s", "s", Scale::Mul(1.0));
    pub const MS: Unit = Unit::new(Kind::Time, "ms", "ms", Scale::Div(1e3));
    pub const US: Unit = Unit::new(Kind::Time, "us", "µs", Scale::Div(1e6));
    pub const MM_S: Unit = Unit::new(Kind::Speed, "mm_s", "mm/s", Scale::Mul(1.0));
    pub const MM_MIN: Unit = Unit::new(Kind::Speed, "mm_min", "mm/min", Scale::Div(60.0));
    pub const UM_S: Unit = Unit::new(Kind::Speed, "um_s", "µm/s", Scale::Div(1e3));

    /// Every unit, in the order docs/formats.md lists them.
    pub const ALL: [Unit; 10] = [
        Unit::NM,
        Unit::UM,
        Unit::MM,
        Unit::M,
        Unit::S,
        Unit::MS,
        Unit::US,
        Unit::MM_S,
        Unit::MM_MIN,
        Unit::UM_S,
    ];

    const fn new(kind: Kind, ascii: &'static str, symbol: &'static str, scale: Scale) -> Unit {
        Unit {
            kind,
            ascii,
            symbol,
            scale,
        }
    }

    /// A value in this unit, in the canonical unit of its kind (mm, s,
    /// mm/s), correctly rounded.
    pub fn to_canonical(self, v: f64) -> f64 {
        match self.scale {
            Scale::Mul(f) => v * f,
            Scale::Div(d) => v / d,
        }
    }

    /// A canonical value (mm, s, mm/s) in this unit, correctly rounded.
    pub fn from_canonical(self, v: f64) -> f64 {
        match self.scale {
            Scale::Mul(f) => v / f,
            Scale::Div(d) => v * d,
        }
    }

    /// A unit as people write it in flags, headers and unit columns:
    /// `nm`, `um`, `µm`, `μm`, `micron(s)`, `microns`, `mm`, `m`, `s`,
    /// `ms`, `us`, `µs`, `mm/s`, `mm_s`, `mm/min`, `um/s`, … Case matters
    /// only where it must (`m` metre vs `M`, nothing else is ambiguous),
    /// so `MM` and `Mm` are refused rather than guessed.
    pub fn parse(text: &str) -> Option<Unit> {
        let t = text.trim();
        let t = t
            .trim_start_matches(['(', '['])
            .trim_end_matches([')', ']']);
        // Greek mu (U+03BC) and micro sign (U+00B5) are both in use.
        let norm: String = t
            .chars()
            .map(|c| match c {
                'µ' | 'μ' => 'u',
                _ => c,
            })
            .collect::<String>()
            .replace(' ', "");
        let lower = norm.to_ascii_lowercase();
        let word = match lower.as_str() {
            "micron" | "microns" | "micrometer" | "micrometers" | "micrometre" | "micrometres" => {
                "um"
            }
            "nanometer" | "nanometers" | "nanometre" | "nanometres" => "nm",
            "millimeter" | "millimeters" | "millimetre" | "millimetres" => "mm",
            "meter" | "meters" | "metre" | "metres" => "m",
            "second" | "seconds" | "sec" => "s",
            "millisecond" | "milliseconds" => "ms",
            "microsecond" | "microseconds" => "us",
            _ => "",
        };
        let key = if word.is_empty() { norm.as_str() } else { word };
        let key = key.replace('/', "_");
        Unit::ALL.into_iter().find(|u| u.ascii == key)
    }

    /// The unit a column's name states by its suffix (`z_nm`, `t_ms`,
    /// `feed_mm_s`): the longest matching suffix wins, so `feed_mm_s` is a
    /// speed and not a time in seconds. `None` when the name states none.
    pub fn from_suffix(column: &str) -> Option<Unit> {
        Unit::ALL
            .into_iter()
            .filter(|u| {
                column.len() > u.ascii.len() + 1
                    && column.ends_with(u.ascii)
                    && column.as_bytes()[column.len() - u.ascii.len() - 1] == b'_'
            })
            .max_by_key(|u| u.ascii.len())
    }
}

/// Where a unit was stated, strongest first (the order of the variants is
/// the order of precedence).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Source {
    /// A per-axis CLI flag (`--z-unit nm`).
    Flag,
    /// A per-column unit in an import mapping.
    Mapping,
    /// Parquet/Arrow field metadata, key `unit`.
    FieldMetadata,
    /// The observations table's `unit` column.
    UnitColumn,
    /// A unit suffix in the column's name.
    NameSuffix,
}

impl fmt::Display for Source {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Source::Flag => "command-line flag",
            Source::Mapping => "import mapping",
            Source::FieldMetadata => "Parquet field metadata `unit`",
            Source::UnitColumn => "`unit` column",
            Source::NameSuffix => "column-name suffix",
        })
    }
}

/// Why a column's unit could not be settled.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum UnitError {
    #[error("column `{column}`: unit `{text}` ({stated_in}) is not one sparkout converts (lengths nm, um, mm, m; times s, ms, us; speeds mm/s, mm/min, um/s)")]
    Unknown {
        column: String,
        text: String,
        stated_in: Source,
    },
    #[error("column `{column}`: the {a_source} says `{a}` but the {b_source} says `{b}`; state one unit (or make them agree)")]
    Conflict {
        column: String,
        a: String,
        a_source: Source,
        b: String,
        b_source: Source,
    },
    #[error("column `{column}`: `{unit}` is a {got} unit but this column holds a {want}")]
    WrongKind {
        column: String,
        unit: String,
        got: &'static str,
        want: &'static str,
    },
    #[error("column `{column}`: its unit cannot be known — no flag, mapping, field metadata or name suffix states it; give it with {fix}")]
    Unstated { column: String, fix: String },
}

/// One statement of a column's unit: the text as written and where.
#[derive(Debug, Clone, PartialEq)]
pub struct Stated {
    pub text: String,
    pub source: Source,
}

/// The unit of `column`, of kind `want`, from every place that states one
/// (the name suffix is read here; pass the others). The strongest
/// statement is the answer; any two that differ are a conflict. `Ok(None)`
/// when nothing states a unit — the caller decides whether the contract's
/// unit may be assumed there or the column must be refused
/// ([`UnitError::Unstated`]).
pub fn resolve(
    column: &str,
    want: Kind,
    stated: &[Stated],
) -> Result<Option<(Unit, Source)>, UnitError> {
    let mut all: Vec<(Unit, Source, String)> = Vec::new();
    for s in stated {
        let u = Unit::parse(&s.text).ok_or_else(|| UnitError::Unknown {
            column: column.into(),
            text: s.text.clone(),
            stated_in: s.source,
        })?;
        all.push((u, s.source, s.text.clone()));
    }
    // A suffix of another kind is not a statement about this column's unit
    // (`t_s` may hold a length in a table whose caller says so); only a
    // suffix of the wanted kind counts.
    if let Some(u) = Unit::from_suffix(column).filter(|u| u.kind == want) {
        all.push((u, Source::NameSuffix, u.ascii.to_string()));
    }
    all.sort_by_key(|(_, s, _)| *s);
    let Some((first, first_source, first_text)) = all.first().cloned() else {
        return Ok(None);
    };
    if first.kind != want {
        return Err(UnitError::WrongKind {
            column: column.into(),
            unit: first_text,
            got: first.kind.name(),
            want: want.name(),
        });
    }
    for (u, s, t) in &all[1..] {
        if *u != first {
            return Err(UnitError::Conflict {
                column: column.into(),
                a: first_text,
                a_source: first_source,
                b: t.clone(),
                b_source: *s,
            });
        }
    }
    Ok(Some((first, first_source)))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn st(text: &str, source: Source) -> Stated {
        Stated {
            text: text.into(),
            source,
        }
    }

    #[test]
    fn parses_what_instruments_write() {
        for (t, u) in [
            ("nm", Unit::NM),
            ("µm", Unit::UM),
            ("μm", Unit::UM),
            ("um", Unit::UM),
            ("microns", Unit::UM),
            ("(microns)", Unit::UM),
            ("m", Unit::M),
            ("mm", Unit::MM),
            ("ms", Unit::MS),
            ("µs", Unit::US),
            ("mm/s", Unit::MM_S),
            ("mm_s", Unit::MM_S),
            ("mm/min", Unit::MM_MIN),
            ("um/s", Unit::UM_S),
            (" s ", Unit::S),
        ] {
            assert_eq!(Unit::parse(t), Some(u), "{t}");
        }
        for bad in ["", "inch", "M", "MM", "mm/h", "px"] {
            assert_eq!(Unit::parse(bad), None, "{bad}");
        }
    }

    #[test]
    fn longest_suffix_wins() {
        assert_eq!(Unit::from_suffix("feed_mm_s"), Some(Unit::MM_S));
        assert_eq!(Unit::from_suffix("feed_mm_min"), Some(Unit::MM_MIN));
        assert_eq!(Unit::from_suffix("v_um_s"), Some(Unit::UM_S));
        assert_eq!(Unit::from_suffix("z_nm"), Some(Unit::NM));
        assert_eq!(Unit::from_suffix("y_um"), Some(Unit::UM));
        assert_eq!(Unit::from_suffix("t_s"), Some(Unit::S));
        assert_eq!(Unit::from_suffix("t_ms"), Some(Unit::MS));
        assert_eq!(Unit::from_suffix("t_us"), Some(Unit::US));
        assert_eq!(Unit::from_suffix("x_m"), Some(Unit::M));
        // A bare unit is a name, not a suffix; no underscore, no suffix.
        assert_eq!(Unit::from_suffix("mm"), None);
        assert_eq!(Unit::from_suffix("zmm"), None);
        assert_eq!(Unit::from_suffix("height"), None);
        assert_eq!(Unit::from_suffix("items"), None);
    }

    #[test]
    fn conversions_are_exact_powers_of_ten() {
        // 1 nm = 1e-6 mm exactly as the nearest double to 1e-6; multiplying
        // by a rounded 1e-3 twice would not give it.
        assert_eq!(Unit::NM.to_canonical(1.0), 1e-6);
        assert_eq!(Unit::NM.to_canonical(13.0), 13.0 / 1e6);
        assert_eq!(Unit::UM.to_canonical(700.0), 0.7);
        assert_eq!(Unit::M.to_canonical(1.6655563e-8), 1.6655563e-8 * 1e3);
        assert_eq!(Unit::MS.to_canonical(2.5), 0.0025);
        assert_eq!(Unit::MM_MIN.to_canonical(600.0), 10.0);
        assert_eq!(Unit::UM.from_canonical(0.7), 700.0);
        for u in Unit::ALL {
            assert_eq!(u.kind.canonical().to_canonical(3.25), 3.25);
        }
    }

    #[test]
    fn strongest_statement_wins_and_conflicts_are_errors() {
        assert_eq!(
            resolve("z_nm", Kind::Length, &[]).unwrap(),
            Some((Unit::NM, Source::NameSuffix))
        );
        assert_eq!(
            resolve("z", Kind::Length, &[st("nm", Source::Flag)]).unwrap(),
            Some((Unit::NM, Source::Flag))
        );
        assert_eq!(
            resolve("z_nm", Kind::Length, &[st("nm", Source::FieldMetadata)]).unwrap(),
            Some((Unit::NM, Source::FieldMetadata))
        );
        assert!(matches!(
            resolve("z_nm", Kind::Length, &[st("um", Source::Flag)]),
            Err(UnitError::Conflict { .. })
        ));
        assert!(matches!(
            resolve("z", Kind::Length, &[st("s", Source::Flag)]),
            Err(UnitError::WrongKind { .. })
        ));
        assert!(matches!(
            resolve("z", Kind::Length, &[st("furlong", Source::Mapping)]),
            Err(UnitError::Unknown { .. })
        ));
        assert_eq!(resolve("height", Kind::Length, &[]).unwrap(), None);
        // A time suffix says nothing about a length column.
        assert_eq!(resolve("t_s", Kind::Length, &[]).unwrap(), None);
        let e = resolve("z_nm", Kind::Length, &[st("um", Source::Flag)])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("z_nm") && e.contains("um") && e.contains("nm"),
            "{e}"
        );
    }
}

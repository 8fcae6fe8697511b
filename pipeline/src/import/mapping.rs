//! The import mapping (a TOML file or `--map` flags): which source column
//! becomes which contract column, with what unit factor, how rows split into
//! runs, and which machine and plugin the runs belong to. Checked before any
//! row is read: unknown keys and bad values are errors that say what to do.

use std::collections::BTreeMap;

use crate::{bail, err, Context};
use serde::Deserialize;

use crate::contracts::{ColumnKind, TableRegistry};
use crate::units::{resolve, Source, Stated, Unit};
use crate::Result;

/// Where a contract column's values come from.
#[derive(Debug, Clone, PartialEq)]
pub enum SourceRef {
    /// A source column by its header name.
    Name(String),
    /// A source column by position (0-based), for headerless or unnamed
    /// columns such as a leading sample index.
    Index(usize),
}

impl std::fmt::Display for SourceRef {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SourceRef::Name(n) => write!(f, "`{n}`"),
            SourceRef::Index(i) => write!(f, "#{i}"),
        }
    }
}

/// Type of a destination column that the contract does not define (an
/// extra column, passed through like any extra column).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ExtraKind {
    F64,
    I32,
    Utf8,
}

/// One destination column: source, unit factor (value × factor, e.g. 25.4
/// for inches → mm, 1/60 for mm/min → mm/s) and offset added after.
#[derive(Debug, Clone, PartialEq)]
pub struct ColumnMap {
    pub dest: String,
    pub source: SourceRef,
    pub factor: f64,
    pub offset: f64,
    /// For a destination outside the contract table: its type (f64 default).
    pub extra_kind: Option<ExtraKind>,
    /// The source column's unit as the mapping states it (`unit = "um"`).
    pub unit_text: Option<String>,
    /// The source's unit when it is not the destination's — from
    /// `unit_text`, else from a unit suffix of the source header
    /// (`pos_um` → `cmd_x_mm`) — converted exactly on import
    /// ([`ColumnMap::convert`]). Set by [`Mapping::settle_units`].
    pub unit: Option<Unit>,
}

impl ColumnMap {
    /// A source value in the destination's unit: the stated unit's exact
    /// conversion, or the mapping's factor; then the offset.
    pub fn convert(&self, v: f64) -> f64 {
        let v = match self.unit {
            Some(u) => match Unit::from_suffix(&self.dest).filter(|d| d.kind == u.kind) {
                Some(d) if d != d.kind.canonical() => d.from_canonical(u.to_canonical(v)),
                _ => u.to_canonical(v),
            },
            None => v * self.factor,
        };
        v + self.offset
    }
}

/// How rows become runs.
#[derive(Debug, Clone, PartialEq)]
pub enum RunSplit {
    /// One run per input file, named by the file stem (`experiment_01.csv`
    /// → run `experiment_01`).
    PerFile,
    /// A new run wherever this source column changes value; run id =
    /// `<file stem>_<value>`, t_s rebased to the run's first row.
    ByColumn(SourceRef),
}

/// A checked mapping.
#[derive(Debug, Clone, PartialEq)]
pub struct Mapping {
    /// Contract table the rows become (docs/formats.md §4), e.g. `motion`.
    pub table: String,
    pub machine: String,
    pub plugin: String,
    pub split: RunSplit,
    /// When `t_s` is not mapped: t_s = row index × this period.
    pub sample_period_s: Option<f64>,
    pub delimiter: u8,
    pub columns: Vec<ColumnMap>,
    /// Copied to each run's run.toml `[process]`.
    pub process: toml::Table,
    /// The tables a mapping may fill: the shared ones and the registered
    /// plugins' (`MachinePlugin::tables`).
    pub tables: TableRegistry,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MappingToml {
    import: ImportToml,
    columns: BTreeMap<String, ColumnToml>,
    #[serde(default)]
    process: toml::Table,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ImportToml {
    table: String,
    machine: String,
    plugin: String,
    split_by: Option<String>,
    sample_period_s: Option<f64>,
    delimiter: Option<String>,
    /// Free text: where the data come from, licence (kept for the reader).
    #[allow(dead_code)]
    source: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum ColumnToml {
    Name(String),
    Full(ColumnFullToml),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ColumnFullToml {
    from: Option<String>,
    col: Option<usize>,
    factor: Option<f64>,
    offset: Option<f64>,
    #[serde(rename = "type")]
    kind: Option<ExtraKind>,
    /// The source column's unit (docs/formats.md "Units").
    unit: Option<String>,
}

/// `#3` → position 3; anything else is a header name.
fn source_ref(s: &str) -> SourceRef {
    match s.strip_prefix('#').and_then(|d| d.parse::<usize>().ok()) {
        Some(i) => SourceRef::Index(i),
        None => SourceRef::Name(s.to_string()),
    }
}

impl Mapping {
    /// Parse a mapping TOML (`what` names it in errors).
    pub fn from_toml(text: &str, what: &str, tables: &TableRegistry) -> Result<Mapping> {
        let m: MappingToml =
            toml::from_str(text).with_context(|| format!("import mapping {what}"))?;
        let mut columns = Vec::new();
        for (dest, c) in m.columns {
            let cm = match c {
                ColumnToml::Name(n) => ColumnMap {
                    dest: dest.clone(),
                    source: source_ref(&n),
                    factor: 1.0,
                    offset: 0.0,
                    extra_kind: None,
                    unit_text: None,
                    unit: None,
                },
                ColumnToml::Full(f) => {
                    let source = match (f.from, f.col) {
                        (Some(n), None) => SourceRef::Name(n),
                        (None, Some(i)) => SourceRef::Index(i),
                        _ => bail!(
                            "import mapping {what}: [columns].{dest} needs exactly one of `from` (a header name) or `col` (a 0-based position)"
                        ),
                    };
                    ColumnMap {
                        dest: dest.clone(),
                        source,
                        factor: f.factor.unwrap_or(1.0),
                        offset: f.offset.unwrap_or(0.0),
                        extra_kind: f.kind,
                        unit_text: f.unit,
                        unit: None,
                    }
                }
            };
            columns.push(cm);
        }
        let delimiter = match m.import.delimiter.as_deref() {
            None => b',',
            Some("\\t") | Some("\t") | Some("tab") => b'\t',
            Some(d) if d.len() == 1 => d.as_bytes()[0],
            Some(d) => bail!(
                "import mapping {what}: [import].delimiter must be one character (or \"tab\"), found {d:?}"
            ),
        };
        let mapping = Mapping {
            table: m.import.table,
            machine: m.import.machine,
            plugin: m.import.plugin,
            split: match m.import.split_by {
                None => RunSplit::PerFile,
                Some(c) => RunSplit::ByColumn(source_ref(&c)),
            },
            sample_period_s: m.import.sample_period_s,
            delimiter,
            columns,
            process: m.process,
            tables: tables.clone(),
        };
        let mut mapping = mapping;
        mapping
            .validate()
            .and_then(|_| mapping.settle_units())
            .with_context(|| format!("import mapping {what}"))?;
        Ok(mapping)
    }

    /// A mapping from flags alone (no file): every column from `--map`.
    pub fn from_flags(table: &str, machine: &str, plugin: &str, tables: &TableRegistry) -> Mapping {
        Mapping {
            table: table.to_string(),
            machine: machine.to_string(),
            plugin: plugin.to_string(),
            split: RunSplit::PerFile,
            sample_period_s: None,
            delimiter: b',',
            columns: Vec::new(),
            process: toml::Table::new(),
            tables: tables.clone(),
        }
    }

    /// Apply one `--map SRC=DEST[*factor]` flag (replaces an existing
    /// mapping of DEST). `SRC` may be `#N` for the N-th column (0-based).
    pub fn apply_flag(&mut self, flag: &str) -> Result<()> {
        let (src, rest) = flag.split_once('=').ok_or_else(|| {
            err!("--map {flag:?}: expected SRC=DEST or SRC=DEST*FACTOR, e.g. --map X1_CommandPosition=cmd_x_mm or --map feed=feed_mm_s*0.0166667")
        })?;
        let (dest, factor) = match rest.split_once('*') {
            None => (rest, 1.0),
            Some((d, f)) => (
                d,
                f.trim().parse::<f64>().map_err(|_| {
                    err!("--map {flag:?}: the factor after `*` must be a number, found {f:?}")
                })?,
            ),
        };
        let dest = dest.trim();
        self.columns.retain(|c| c.dest != dest);
        self.columns.push(ColumnMap {
            dest: dest.to_string(),
            source: source_ref(src.trim()),
            factor,
            offset: 0.0,
            extra_kind: None,
            unit_text: None,
            unit: None,
        });
        self.settle_units()
    }

    /// Each column's source unit, where it is stated (the mapping's `unit`,
    /// else a unit suffix of the source header) and differs from the
    /// destination's: a `pos_um` header mapped to `cmd_x_mm` is converted,
    /// not copied. A mapping `unit` that contradicts the header's suffix,
    /// or is of another kind than the destination, is an error; a `unit`
    /// together with a `factor` is one conversion too many.
    pub fn settle_units(&mut self) -> Result<()> {
        for c in &mut self.columns {
            let dest = Unit::from_suffix(&c.dest);
            if c.unit_text.is_some() && c.factor != 1.0 {
                bail!(
                    "column `{}`: give `unit` or `factor`, not both (`unit` converts exactly)",
                    c.dest
                );
            }
            let Some(kind) = dest.map(|d| d.kind) else {
                if let Some(t) = &c.unit_text {
                    bail!(
                        "column `{}`: `unit = {t:?}` needs a destination whose name states its unit (`_mm`, `_s`, `_mm_s`)",
                        c.dest
                    );
                }
                continue;
            };
            // An explicit factor is the mapping's own conversion: a header
            // suffix is not applied on top of it.
            if c.unit_text.is_none() && c.factor != 1.0 {
                continue;
            }
            let stated: Vec<Stated> = c
                .unit_text
                .iter()
                .map(|t| Stated {
                    text: t.clone(),
                    source: Source::Mapping,
                })
                .collect();
            let name = match &c.source {
                SourceRef::Name(n) => n.clone(),
                // A position has no name, so no suffix.
                SourceRef::Index(i) => format!("#{i}"),
            };
            let got = resolve(&name, kind, &stated)
                .map_err(|e| err!("column `{}` (source {}): {e}", c.dest, c.source))?;
            c.unit = got.map(|(u, _)| u).filter(|u| Some(*u) != dest);
        }
        Ok(())
    }

    /// The destination kind of a column: the contract's, else the declared
    /// extra kind (f64 by default).
    pub fn dest_kind(&self, c: &ColumnMap) -> ColumnKind {
        let schema = self.tables.get(&self.table).expect("validated table");
        match schema.column(&c.dest) {
            Some(spec) => spec.kind,
            None => match c.extra_kind.unwrap_or(ExtraKind::F64) {
                ExtraKind::F64 => ColumnKind::F64,
                ExtraKind::I32 => ColumnKind::I32,
                ExtraKind::Utf8 => ColumnKind::Utf8,
            },
        }
    }

    /// Everything that can be checked without the data.
    pub fn validate(&self) -> Result<()> {
        let schema = self.tables.get(&self.table).ok_or_else(|| {
            let known = self.tables.names();
            err!(
                "unknown contract table `{}` (known: {})",
                self.table,
                known.join(", ")
            )
        })?;
        for (what, v) in [("machine", &self.machine), ("plugin", &self.plugin)] {
            if v.trim().is_empty() || v.contains(['/', '\\']) {
                bail!("{what} must be a non-empty name without path separators, found {v:?}");
            }
        }
        if let Some(p) = self.sample_period_s {
            if !(p.is_finite() && p > 0.0) {
                bail!("[import].sample_period_s must be > 0, found {p}");
            }
        }
        let mut seen = std::collections::BTreeSet::new();
        for c in &self.columns {
            if !seen.insert(c.dest.as_str()) {
                bail!("column `{}` is mapped twice", c.dest);
            }
            if !(c.factor.is_finite() && c.factor != 0.0 && c.offset.is_finite()) {
                bail!(
                    "column `{}`: factor must be a non-zero number and offset finite (got factor {}, offset {})",
                    c.dest,
                    c.factor,
                    c.offset
                );
            }
            if let Some(spec) = schema.column(&c.dest) {
                if c.extra_kind.is_some() {
                    bail!(
                        "column `{}` is a `{}` contract column of type {}: `type` is only for extra columns",
                        c.dest,
                        self.table,
                        spec.kind.label()
                    );
                }
                let numeric = spec.kind != ColumnKind::Utf8;
                if !numeric && (c.factor != 1.0 || c.offset != 0.0) {
                    bail!(
                        "column `{}` is text: a factor or offset does not apply",
                        c.dest
                    );
                }
            }
        }
        let t_mapped = self.columns.iter().any(|c| c.dest == "t_s");
        for spec in schema.columns.iter().filter(|s| s.required) {
            let mapped = self.columns.iter().any(|c| c.dest == spec.name)
                || (spec.name == "t_s" && self.sample_period_s.is_some());
            if !mapped {
                let hint = if spec.name == "t_s" {
                    " (map a time column, or set [import].sample_period_s for t_s = row × period)"
                } else {
                    ""
                };
                bail!(
                    "required `{}` column `{}` is not mapped{hint} — see docs/import.md",
                    self.table,
                    spec.name
                );
            }
        }
        if t_mapped && self.sample_period_s.is_some() {
            bail!("t_s is mapped from a column and [import].sample_period_s is set: keep one");
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TOML: &str = r##"
[import]
table = "motion"
machine = "m1"
plugin = "servo"
sample_period_s = 0.1
[columns]
cmd_x_mm = "X_cmd"
cmd_y_mm = { from = "Y_cmd", factor = 25.4 }
cmd_z_mm = { col = 3 }
act_x_mm = "#4"
"##;

    #[test]
    fn parses_names_positions_and_factors() {
        let m = Mapping::from_toml(TOML, "test", &TableRegistry::shared()).unwrap();
        assert_eq!(m.table, "motion");
        let y = m.columns.iter().find(|c| c.dest == "cmd_y_mm").unwrap();
        assert_eq!(y.factor, 25.4);
        let z = m.columns.iter().find(|c| c.dest == "cmd_z_mm").unwrap();
        assert_eq!(z.source, SourceRef::Index(3));
        let a = m.columns.iter().find(|c| c.dest == "act_x_mm").unwrap();
        assert_eq!(a.source, SourceRef::Index(4));
    }

    #[test]
    fn rejects_unknown_keys_missing_required_and_bad_flags() {
        let bad = TOML.replace("sample_period_s", "sample_perod_s");
        let e = format!(
            "{:#}",
            Mapping::from_toml(&bad, "test", &TableRegistry::shared()).unwrap_err()
        );
        assert!(e.contains("sample_perod_s"), "{e}");
        let no_t = TOML.replace("sample_period_s = 0.1\n", "");
        let e = format!(
            "{:#}",
            Mapping::from_toml(&no_t, "test", &TableRegistry::shared()).unwrap_err()
        );
        assert!(e.contains("t_s"), "{e}");
        let mut m = Mapping::from_flags("motion", "m", "servo", &TableRegistry::shared());
        assert!(m.apply_flag("a=b*x").is_err());
        m.apply_flag("feed=feed_mm_s*0.5").unwrap();
        assert_eq!(m.columns[0].factor, 0.5);
        assert!(m.validate().is_err(), "cmd_x_mm etc. unmapped");
    }

    #[test]
    fn a_stated_unit_converts_exactly_and_a_conflict_is_an_error() {
        let with = |cols: &str| {
            Mapping::from_toml(
                &TOML.replace("act_x_mm = \"#4\"\n", &format!("act_x_mm = \"#4\"\n{cols}")),
                "test",
                &TableRegistry::shared(),
            )
        };
        let m = with("feed_mm_s = { from = \"F\", unit = \"mm/min\" }\nact_y_mm = \"pos_um\"\nact_z_mm = { from = \"Z\", unit = \"nm\" }\n").unwrap();
        let c = |d: &str| m.columns.iter().find(|c| c.dest == d).unwrap().clone();
        assert_eq!(c("feed_mm_s").convert(600.0), 10.0);
        // The header's suffix states µm: converted, not copied.
        assert_eq!(c("act_y_mm").convert(700.0), 0.7);
        assert_eq!(c("act_z_mm").convert(13.0), 13.0 / 1e6);
        // No unit stated: the factor, as before.
        assert_eq!(c("cmd_y_mm").convert(2.0), 2.0 * 25.4);
        let e = format!(
            "{:#}",
            with("act_y_mm = { from = \"pos_um\", unit = \"nm\" }\n").unwrap_err()
        );
        assert!(
            e.contains("pos_um") && e.contains("nm") && e.contains("um"),
            "{e}"
        );
        let e = format!(
            "{:#}",
            with("act_y_mm = { from = \"Y\", unit = \"s\" }\n").unwrap_err()
        );
        assert!(e.contains("act_y_mm") && e.contains("time"), "{e}");
        let e = format!(
            "{:#}",
            with("act_y_mm = { from = \"Y\", unit = \"um\", factor = 2.0 }\n").unwrap_err()
        );
        assert!(e.contains("not both"), "{e}");
    }
}

//! Line profiles and height matrices as instruments and scripts write them,
//! with the unit of every axis read from where the file states it.
//!
//! Profiles (`sparkout stage profile --profile FILE`):
//!
//! - **Parquet** (recognised by its magic bytes): columns `--x`/`--z`, else
//!   the first column named `x` or `x_…` and the first named `z`, `z_…`,
//!   `height` or `height_…` (any case). Units: `--x-unit/--z-unit`, the
//!   field metadata key `unit`, a unit suffix in the name (`z_nm`), ranked
//!   and checked for conflicts by `sparkout_pipeline::units::resolve`.
//! - **Text** (CSV, whitespace or tab columns, `#` comment lines): an
//!   optional first line of units only (`µm µm`), optionally followed by a
//!   line holding the point count; or a header of column names, which may
//!   carry a unit (`X_(microns)`, `height [nm]`, `z_um`); or no header at
//!   all (Bruker Dektak's two-column export). `# Value units: U` states the
//!   height unit. Columns are picked by `--x`/`--z` (a header name or a
//!   1-based number), else the first two.
//!
//! A unit the file does not state must be given by flag; a flag that
//! contradicts the file is an error. Empty, `NaN` or null heights are
//! points that were not measured: counted and left out. Positions must be
//! finite and increase strictly (a stylus trace); a break is an error
//! naming the file, column and row or line.
//!
//! Height matrices (`sparkout stage flatness --surface FILE`): `#` header
//! lines `Width: 10 µm`, `Height: 10 µm`, `Value units: m` and then one
//! row of heights per line. Pixel size = Width / columns and
//! Height / rows; point (row i, column j) is at x = j·Δx, y = i·Δy.

use std::path::Path;

use arrow::record_batch::RecordBatch;
use serde::{Deserialize, Serialize};
use sparkout_pipeline::contracts::{column_names, numeric_column, read_parquet};
use sparkout_pipeline::units::{resolve, Kind, Source, Stated, Unit, UnitError};
use sparkout_pipeline::{InputError, Result};

/// Which columns and what units the user named (`None`: from the file).
#[derive(Debug, Clone, Default)]
pub struct ProfileSpec<'a> {
    pub x: Option<&'a str>,
    pub z: Option<&'a str>,
    pub x_unit: Option<&'a str>,
    pub z_unit: Option<&'a str>,
}

/// One axis as read: its column, unit and where the unit was stated.
#[derive(Debug, Clone, PartialEq)]
pub struct Axis {
    pub column: String,
    pub unit: Unit,
    pub stated_in: String,
}

impl Axis {
    fn input(&self) -> AxisInput {
        AxisInput {
            column: self.column.clone(),
            unit: self.unit.symbol.to_string(),
            stated_in: self.stated_in.clone(),
        }
    }
}

/// One axis of an [`ProfileInput`]: its column, unit and where the unit
/// was stated.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AxisInput {
    pub column: String,
    pub unit: String,
    pub stated_in: String,
}

/// The `input` echo of the `profile` stage: the file as read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProfileInput {
    pub file: String,
    pub format: String,
    pub n_points: usize,
    pub n_not_measured: usize,
    pub x: AxisInput,
    pub z: AxisInput,
    pub notes: Vec<String>,
}

/// A profile in mm, x strictly increasing, only measured points.
#[derive(Debug, Clone)]
pub struct ProfileData {
    pub x_mm: Vec<f64>,
    pub z_mm: Vec<f64>,
    pub x: Axis,
    pub z: Axis,
    pub format: &'static str,
    pub not_measured: usize,
    pub notes: Vec<String>,
}

impl ProfileData {
    /// The `input` echo of the stage's output.
    pub fn input(&self, path: &Path) -> ProfileInput {
        ProfileInput {
            file: path.display().to_string(),
            format: self.format.into(),
            n_points: self.x_mm.len(),
            n_not_measured: self.not_measured,
            x: self.x.input(),
            z: self.z.input(),
            notes: self.notes.clone(),
        }
    }
}

fn is_parquet(path: &Path) -> Result<bool> {
    use std::io::Read;
    let mut f = std::fs::File::open(path)
        .map_err(|e| InputError::new(path, format!("cannot open: {e}")))?;
    let mut magic = [0u8; 4];
    Ok(f.read_exact(&mut magic).is_ok() && &magic == b"PAR1")
}

/// A length unit given by flag, checked.
fn flag_unit(flag: &str, text: &str) -> Result<Unit> {
    match Unit::parse(text) {
        Some(u) if u.kind == Kind::Length => Ok(u),
        _ => crate::bail!("--{flag} `{text}` is not a length unit (nm, um or µm, mm, m)"),
    }
}

/// The unit of one axis from the flag and what the file states (`where`
/// says where, for messages), refusing a contradiction or silence.
fn settle(
    path: &Path,
    column: &str,
    flag: &str,
    given: Option<&str>,
    stated: Option<(Unit, String)>,
) -> Result<Axis> {
    let given = given.map(|t| flag_unit(flag, t)).transpose()?;
    let (unit, stated_in) = match (given, stated) {
        (Some(g), Some((s, w))) if g != s => {
            return Err(InputError::new(
                path,
                format!(
                    "{w} states `{}` but --{flag} says `{}`; drop the flag or make them agree",
                    s.symbol, g.symbol
                ),
            )
            .column(column)
            .into())
        }
        (Some(g), Some((_, w))) => (g, format!("--{flag} and {w}")),
        (Some(g), None) => (g, format!("--{flag}")),
        (None, Some((s, w))) => (s, w),
        (None, None) => {
            return Err(InputError::new(
                path,
                format!(
                    "the file does not state this column's unit; give it with --{flag} U (nm, um, mm or m)"
                ),
            )
            .column(column)
            .into())
        }
    };
    Ok(Axis {
        column: column.into(),
        unit,
        stated_in,
    })
}

/// A length unit a column's name carries: `X_(microns)`, `height [nm]`,
/// `z_um`. A bracket that holds no unit (`(a.u.)`) states nothing.
pub fn unit_in_name(name: &str) -> Option<Unit> {
    let t = name.trim();
    for (open, close) in [('(', ')'), ('[', ']')] {
        if t.ends_with(close) {
            if let Some(i) = t.rfind(open) {
                return Unit::parse(&t[i + 1..t.len() - 1]).filter(|u| u.kind == Kind::Length);
            }
        }
    }
    Unit::from_suffix(t).filter(|u| u.kind == Kind::Length)
}

/// Read a line profile (see the module notes).
pub fn read_profile(path: &Path, spec: &ProfileSpec) -> Result<ProfileData> {
    let mut p = if is_parquet(path)? {
        parquet_profile(path, spec)?
    } else {
        text_profile(path, spec)?
    };
    if p.x_mm.len() < 3 {
        return Err(InputError::new(
            path,
            format!(
                "{} measured points; a profile needs at least 3",
                p.x_mm.len()
            ),
        )
        .into());
    }
    if p.not_measured > 0 {
        p.notes.push(format!(
            "{} points without a height (empty, NaN or null) were not measured and are left out",
            p.not_measured
        ));
    }
    Ok(p)
}

/// Values, where each one came from (row or line, for messages), the
/// kind of place ("row"/"line").
struct Columns {
    x: Vec<f64>,
    z: Vec<f64>,
    at: Vec<usize>,
    place: &'static str,
}

/// Convert, drop unmeasured heights, check x; all errors name the place.
fn finish(
    path: &Path,
    c: Columns,
    x: Axis,
    z: Axis,
    format: &'static str,
    notes: Vec<String>,
) -> Result<ProfileData> {
    let mut xs = Vec::with_capacity(c.x.len());
    let mut zs = Vec::with_capacity(c.x.len());
    let mut ats: Vec<usize> = Vec::new();
    let mut not_measured = 0;
    for i in 0..c.x.len() {
        let at = c.at[i];
        // Parquet rows go in the error's row; text lines in its message.
        let (pre, row) = match c.place {
            "line" => (format!("line {at}: "), None),
            _ => (String::new(), Some(at)),
        };
        let locate = |e: InputError| match row {
            Some(r) => e.row(r),
            None => e,
        };
        if !c.x[i].is_finite() {
            return Err(locate(
                InputError::new(path, format!("{pre}the position is not a finite number"))
                    .column(&x.column),
            )
            .into());
        }
        if !c.z[i].is_finite() {
            if c.z[i].is_infinite() {
                return Err(locate(
                    InputError::new(path, format!("{pre}an infinite height")).column(&z.column),
                )
                .into());
            }
            not_measured += 1;
            continue;
        }
        let xv = x.unit.to_canonical(c.x[i]);
        if let Some(&prev) = xs.last() {
            if xv <= prev {
                return Err(locate(InputError::new(
                    path,
                    format!(
                        "{pre}x = {} does not increase (the previous point, {} {}, is at {}); a profile's positions must increase strictly",
                        c.x[i], c.place, ats.last().unwrap(), x.unit.from_canonical(prev)
                    ),
                )
                .column(&x.column))
                .into());
            }
        }
        xs.push(xv);
        zs.push(z.unit.to_canonical(c.z[i]));
        ats.push(at);
    }
    Ok(ProfileData {
        x_mm: xs,
        z_mm: zs,
        x,
        z,
        format,
        not_measured,
        notes,
    })
}

// ---- Parquet ----

fn find_column(b: &RecordBatch, stems: &[&str]) -> Option<String> {
    column_names(b)
        .into_iter()
        .find(|n| {
            let l = n.to_ascii_lowercase();
            stems
                .iter()
                .any(|s| l == *s || l.starts_with(&format!("{s}_")))
        })
        .map(str::to_string)
}

fn parquet_profile(path: &Path, spec: &ProfileSpec) -> Result<ProfileData> {
    let b = read_parquet(path)?;
    let pick = |given: Option<&str>, stems: &[&str], flag: &str| -> Result<String> {
        match given {
            Some(g) => Ok(g.to_string()),
            None => find_column(&b, stems).ok_or_else(|| {
                InputError::new(
                    path,
                    format!(
                        "no {flag} column found by name ({}); name it with --{flag} COL (columns present: {})",
                        stems.join("/"),
                        column_names(&b).join(", ")
                    ),
                )
                .into()
            }),
        }
    };
    let xc = pick(spec.x, &["x"], "x")?;
    let zc = pick(spec.z, &["z", "height"], "z")?;
    let axis = |col: &str, flag: &str, given: Option<&str>| -> Result<Axis> {
        let mut stated = Vec::new();
        if let Some(g) = given {
            flag_unit(flag, g)?;
            stated.push(Stated {
                text: g.into(),
                source: Source::Flag,
            });
        }
        if let Some(u) = b
            .schema_ref()
            .field_with_name(col)
            .ok()
            .and_then(|f| f.metadata().get("unit"))
        {
            stated.push(Stated {
                text: u.clone(),
                source: Source::FieldMetadata,
            });
        }
        // A UnitError names its column itself.
        let unit_err = |e: UnitError| InputError::new(path, e.to_string());
        match resolve(col, Kind::Length, &stated).map_err(unit_err)? {
            Some((unit, source)) => Ok(Axis {
                column: col.into(),
                unit,
                stated_in: source.to_string(),
            }),
            None => Err(unit_err(UnitError::Unstated {
                column: col.into(),
                fix: format!("--{flag} U (nm, um, mm or m), field metadata `unit`, or a suffix such as `{col}_um`"),
            })
            .into()),
        }
    };
    let x = axis(&xc, "x-unit", spec.x_unit)?;
    let z = axis(&zc, "z-unit", spec.z_unit)?;
    let xs = numeric_column(path, &b, &xc, "a profile column")?
        .into_iter()
        .map(|v| v.unwrap_or(f64::NAN))
        .collect::<Vec<f64>>();
    let zs = numeric_column(path, &b, &zc, "a profile column")?
        .into_iter()
        .map(|v| v.unwrap_or(f64::NAN))
        .collect::<Vec<f64>>();
    let at = (0..xs.len()).collect();
    finish(
        path,
        Columns {
            x: xs,
            z: zs,
            at,
            place: "row",
        },
        x,
        z,
        "parquet",
        vec![],
    )
}

// ---- Text ----

/// A content line split into fields: `,` when the line has one, else `;`,
/// else tabs, else runs of spaces.
fn fields(line: &str) -> Vec<&str> {
    let t = line.trim();
    let parts: Vec<&str> = if t.contains(',') {
        t.split(',').collect()
    } else if t.contains(';') {
        t.split(';').collect()
    } else if t.contains('\t') {
        t.split('\t').collect()
    } else {
        t.split_whitespace().collect()
    };
    parts.into_iter().map(str::trim).collect()
}

/// A number field; empty or NaN is "not measured" (NaN).
fn number(s: &str) -> Option<f64> {
    if s.is_empty() {
        return Some(f64::NAN);
    }
    s.parse::<f64>().ok()
}

/// The text of a file with lines numbered from 1, without a BOM.
fn lines(path: &Path) -> Result<Vec<(usize, String)>> {
    let bytes =
        std::fs::read(path).map_err(|e| InputError::new(path, format!("cannot read: {e}")))?;
    let text = String::from_utf8(bytes).map_err(|e| {
        InputError::new(
            path,
            format!(
                "not UTF-8 text (byte {}); a profile is Parquet or a text export",
                e.utf8_error().valid_up_to()
            ),
        )
    })?;
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    Ok(text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.to_string()))
        .collect())
}

/// `# Key: value` comment lines, keys lower-cased.
fn comment_keys(lines: &[(usize, String)]) -> Vec<(usize, String, String)> {
    lines
        .iter()
        .filter_map(|(n, l)| {
            let c = l.trim().strip_prefix('#')?;
            let (k, v) = c.split_once(':')?;
            Some((*n, k.trim().to_ascii_lowercase(), v.trim().to_string()))
        })
        .collect()
}

fn text_profile(path: &Path, spec: &ProfileSpec) -> Result<ProfileData> {
    let all = lines(path)?;
    let keys = comment_keys(&all);
    let content: Vec<&(usize, String)> = all
        .iter()
        .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'))
        .collect();
    let Some(first) = content.first() else {
        return Err(InputError::new(path, "no data lines").into());
    };
    let mut notes = Vec::new();
    let mut body = &content[..];
    let mut header: Option<Vec<String>> = None;
    let mut line_units: Option<(usize, Vec<Unit>)> = None;
    let f0 = fields(&first.1);
    let units: Vec<Option<Unit>> = f0.iter().map(|t| Unit::parse(t)).collect();
    if units
        .iter()
        .all(|u| u.is_some_and(|u| u.kind == Kind::Length))
    {
        line_units = Some((first.0, units.into_iter().flatten().collect()));
        body = &body[1..];
        // An optional count line, e.g. `23`.
        if let Some(second) = body.first() {
            let f = fields(&second.1);
            if f.len() == 1 {
                if let Ok(count) = f[0].parse::<usize>() {
                    let rows = body.len() - 1;
                    if count != rows {
                        notes.push(format!(
                            "line {} states {count} points; the file holds {rows} data lines, all read",
                            second.0
                        ));
                    }
                    body = &body[1..];
                }
            }
        }
    } else if f0.iter().any(|t| number(t).is_none()) {
        header = Some(f0.iter().map(|s| s.to_string()).collect());
        body = &body[1..];
    }
    let Some(data0) = body.first() else {
        return Err(InputError::new(path, "no data lines after the header").into());
    };
    let width = fields(&data0.1).len();
    let col_name = |i: usize| match &header {
        Some(h) => h
            .get(i)
            .cloned()
            .unwrap_or_else(|| format!("column {}", i + 1)),
        None => format!("column {}", i + 1),
    };
    // Pick a column by header name or 1-based number.
    let pick = |given: Option<&str>, default: usize, flag: &str| -> Result<usize> {
        let Some(g) = given else {
            if default >= width {
                return Err(InputError::new(
                    path,
                    format!(
                        "line {}: {width} column(s); a profile needs an x and a z column",
                        data0.0
                    ),
                )
                .into());
            }
            return Ok(default);
        };
        if let Some(h) = &header {
            if let Some(i) = h.iter().position(|n| n == g) {
                return Ok(i);
            }
        }
        match g.parse::<usize>() {
            Ok(k) if k >= 1 && k <= width => Ok(k - 1),
            _ => Err(InputError::new(
                path,
                format!(
                    "--{flag} `{g}` is neither a column name ({}) nor a column number 1..{width}",
                    header
                        .as_ref()
                        .map(|h| h.join(", "))
                        .unwrap_or_else(|| "the file has no header".into())
                ),
            )
            .into()),
        }
    };
    let xi = pick(spec.x, 0, "x")?;
    let zi = pick(spec.z, if xi == 0 { 1 } else { 0 }, "z")?;
    let (xn, zn) = (col_name(xi), col_name(zi));
    // What the file states about each column's unit.
    let stated = |i: usize, name: &str, is_z: bool| -> Result<Option<(Unit, String)>> {
        let mut s: Vec<(Unit, String)> = Vec::new();
        if let Some((n, u)) = &line_units {
            match u.get(i) {
                Some(&unit) => s.push((unit, format!("line {n} (units line)"))),
                None => {
                    return Err(InputError::new(
                        path,
                        format!(
                            "line {n}: the units line has {} unit(s), but column {} is read",
                            u.len(),
                            i + 1
                        ),
                    )
                    .column(name)
                    .into())
                }
            }
        }
        if header.is_some() {
            if let Some(u) = unit_in_name(name) {
                s.push((u, "the column name".into()));
            }
        }
        if is_z {
            if let Some((n, _, v)) = keys.iter().find(|(_, k, _)| k == "value units") {
                let u = Unit::parse(v)
                    .filter(|u| u.kind == Kind::Length)
                    .ok_or_else(|| {
                        InputError::new(
                            path,
                            format!("line {n}: `Value units: {v}` is not a length unit"),
                        )
                    })?;
                s.push((u, format!("line {n} (`Value units`)")));
            }
        }
        if let Some(w) = s.iter().skip(1).find(|o| o.0 != s[0].0) {
            return Err(InputError::new(
                path,
                format!(
                    "{} states `{}` but {} states `{}`",
                    s[0].1, s[0].0.symbol, w.1, w.0.symbol
                ),
            )
            .column(name)
            .into());
        }
        Ok(s.into_iter().next())
    };
    let x = settle(path, &xn, "x-unit", spec.x_unit, stated(xi, &xn, false)?)?;
    let z = settle(path, &zn, "z-unit", spec.z_unit, stated(zi, &zn, true)?)?;
    let mut c = Columns {
        x: Vec::with_capacity(body.len()),
        z: Vec::with_capacity(body.len()),
        at: Vec::with_capacity(body.len()),
        place: "line",
    };
    for (n, l) in body {
        let f = fields(l);
        if f.len() != width {
            return Err(InputError::new(
                path,
                format!(
                    "line {n}: {} field(s), the first data line (line {}) has {width}",
                    f.len(),
                    data0.0
                ),
            )
            .into());
        }
        for (i, name) in [(xi, &xn), (zi, &zn)] {
            if number(f[i]).is_none() {
                return Err(
                    InputError::new(path, format!("line {n}: `{}` is not a number", f[i]))
                        .column(name.as_str())
                        .into(),
                );
            }
        }
        c.x.push(number(f[xi]).unwrap_or(f64::NAN));
        c.z.push(number(f[zi]).unwrap_or(f64::NAN));
        c.at.push(*n);
    }
    let format = match (&line_units, &header) {
        (Some(_), _) => "text with a units line",
        (None, Some(_)) => "text table with a header",
        (None, None) => "text columns without a header",
    };
    finish(path, c, x, z, format, notes)
}

// ---- Height matrices ----

/// A height map from a text matrix, in mm; NaN heights are not measured.
#[derive(Debug, Clone)]
pub struct Matrix {
    pub x_mm: Vec<f64>,
    pub y_mm: Vec<f64>,
    pub z_mm: Vec<f64>,
    pub rows: usize,
    pub cols: usize,
    pub input: MatrixInput,
}

/// The unit of one axis of a height matrix and where it was stated.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UnitInput {
    pub unit: String,
    pub stated_in: String,
}

/// The `input` echo of `flatness --surface` on a text height matrix.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MatrixInput {
    pub file: String,
    pub format: String,
    pub rows: usize,
    pub columns: usize,
    pub pixel_x: super::Figure,
    pub pixel_y: super::Figure,
    pub layout: String,
    pub x: UnitInput,
    pub y: UnitInput,
    pub z: UnitInput,
}

/// A text file whose first non-blank line is a `#` comment: the matrix
/// export that `flatness --surface` reads here (Parquet and other shapes
/// go to the table reader).
pub fn is_text_matrix(path: &Path) -> bool {
    let Ok(bytes) = std::fs::read(path) else {
        return false;
    };
    if bytes.starts_with(b"PAR1") {
        return false;
    }
    let Ok(text) = std::str::from_utf8(&bytes) else {
        return false;
    };
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    text.lines()
        .map(str::trim)
        .find(|l| !l.is_empty())
        .is_some_and(|l| l.starts_with('#'))
}

/// `10 µm` → (10, µm).
fn length_with_unit(text: &str) -> Option<(f64, Option<Unit>)> {
    let t = text.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || matches!(c, '.' | '-' | '+' | 'e' | 'E')))
        .unwrap_or(t.len());
    let v = t[..split].trim().parse::<f64>().ok()?;
    let rest = t[split..].trim();
    if rest.is_empty() {
        return Some((v, None));
    }
    let u = Unit::parse(rest).filter(|u| u.kind == Kind::Length)?;
    Some((v, Some(u)))
}

/// Read a height matrix; `x_unit`/`y_unit`/`z_unit` are flags that state
/// or confirm the header's units.
pub fn read_matrix(
    path: &Path,
    x_unit: Option<&str>,
    y_unit: Option<&str>,
    z_unit: Option<&str>,
) -> Result<Matrix> {
    let all = lines(path)?;
    let keys = comment_keys(&all);
    let size = |key: &str, flag: &str, given: Option<&str>| -> Result<(f64, Axis)> {
        let Some((n, _, v)) = keys.iter().find(|(_, k, _)| k == key) else {
            return Err(InputError::new(
                path,
                format!(
                    "no `# {}: <length> <unit>` header line; the pixel size comes from it",
                    capital(key)
                ),
            )
            .into());
        };
        let (len, unit) = length_with_unit(v).ok_or_else(|| {
            InputError::new(
                path,
                format!("line {n}: `{v}` is not a length with a unit (e.g. `10 µm`)"),
            )
        })?;
        if !(len.is_finite() && len > 0.0) {
            return Err(InputError::new(path, format!("line {n}: the {key} must be > 0")).into());
        }
        let a = settle(
            path,
            key,
            flag,
            given,
            unit.map(|u| (u, format!("line {n} (`{}`)", capital(key)))),
        )?;
        Ok((len, a))
    };
    let (width, ax) = size("width", "x-unit", x_unit)?;
    let (height, ay) = size("height", "y-unit", y_unit)?;
    let zs = match keys.iter().find(|(_, k, _)| k == "value units") {
        Some((n, _, v)) => Some((
            Unit::parse(v)
                .filter(|u| u.kind == Kind::Length)
                .ok_or_else(|| {
                    InputError::new(
                        path,
                        format!("line {n}: `Value units: {v}` is not a length unit"),
                    )
                })?,
            format!("line {n} (`Value units`)"),
        )),
        None => None,
    };
    let az = settle(path, "values", "z-unit", z_unit, zs)?;
    let mut grid: Vec<Vec<f64>> = Vec::new();
    let mut first_line = 0;
    for (n, l) in &all {
        let t = l.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        let row: Vec<f64> = t
            .split_whitespace()
            .enumerate()
            .map(|(j, s)| {
                s.parse::<f64>().map_err(|_| {
                    InputError::new(path, format!("line {n}: `{s}` is not a number"))
                        .column(format!("column {}", j + 1))
                })
            })
            .collect::<Result<_, _>>()?;
        if let Some(r0) = grid.first() {
            if row.len() != r0.len() {
                return Err(InputError::new(
                    path,
                    format!(
                        "line {n}: {} values, the first matrix row (line {first_line}) has {}",
                        row.len(),
                        r0.len()
                    ),
                )
                .into());
            }
        } else {
            first_line = *n;
        }
        grid.push(row);
    }
    let rows = grid.len();
    let cols = grid.first().map_or(0, Vec::len);
    if rows < 2 || cols < 2 {
        return Err(InputError::new(
            path,
            format!("a {rows} × {cols} matrix; a surface needs at least 2 rows and 2 columns"),
        )
        .into());
    }
    let (dx, dy) = (width / cols as f64, height / rows as f64);
    let unit = |a: &Axis| UnitInput {
        unit: a.unit.symbol.to_string(),
        stated_in: a.stated_in.clone(),
    };
    let mut m = Matrix {
        x_mm: Vec::with_capacity(rows * cols),
        y_mm: Vec::with_capacity(rows * cols),
        z_mm: Vec::with_capacity(rows * cols),
        rows,
        cols,
        input: MatrixInput {
            file: path.display().to_string(),
            format: "height matrix (text, `#` header)".into(),
            rows,
            columns: cols,
            pixel_x: super::Figure::mm(ax.unit.to_canonical(dx)),
            pixel_y: super::Figure::mm(ay.unit.to_canonical(dy)),
            layout: "row i, column j at x = j·Width/columns, y = i·Height/rows".into(),
            x: unit(&ax),
            y: unit(&ay),
            z: unit(&az),
        },
    };
    for (i, row) in grid.iter().enumerate() {
        for (j, &v) in row.iter().enumerate() {
            m.x_mm.push(ax.unit.to_canonical(j as f64 * dx));
            m.y_mm.push(ay.unit.to_canonical(i as f64 * dy));
            m.z_mm.push(if v.is_finite() {
                az.unit.to_canonical(v)
            } else {
                f64::NAN
            });
        }
    }
    Ok(m)
}

fn capital(key: &str) -> String {
    let mut c = key.chars();
    c.next()
        .map(|f| f.to_ascii_uppercase().to_string() + c.as_str())
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn file(text: &str, ext: &str) -> tempfile::NamedTempFile {
        let mut f = tempfile::Builder::new().suffix(ext).tempfile().unwrap();
        f.write_all(text.as_bytes()).unwrap();
        f
    }

    #[test]
    fn units_come_from_the_units_line_the_header_or_the_flags() {
        let f = file("µm µm\n3\n1.0, 2.0\n2.0, 2.5\n3.0, 2.0\n4.0, 2.1\n", ".txt");
        let p = read_profile(f.path(), &ProfileSpec::default()).unwrap();
        assert_eq!(p.x_mm, [0.001, 0.002, 0.003, 0.004]);
        assert_eq!(p.z_mm[1], 0.0025);
        assert!(p.notes[0].contains("states 3 points"), "{:?}", p.notes);
        assert_eq!(p.z.unit, Unit::UM);

        let f = file("X_(microns),y1\n1,5\n2,6\n3,7\n", ".csv");
        let e = read_profile(f.path(), &ProfileSpec::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("`y1`") && e.contains("--z-unit"), "{e}");
        let spec = ProfileSpec {
            z_unit: Some("nm"),
            ..Default::default()
        };
        let p = read_profile(f.path(), &spec).unwrap();
        assert_eq!(p.x.unit, Unit::UM);
        assert_eq!(p.z_mm[0], 5e-6);
        // A flag that contradicts the file is refused.
        let spec = ProfileSpec {
            x_unit: Some("mm"),
            z_unit: Some("nm"),
            ..Default::default()
        };
        let e = read_profile(f.path(), &spec).unwrap_err().to_string();
        assert!(
            e.contains("column name states `µm`") && e.contains("--x-unit"),
            "{e}"
        );

        let f = file("0 1e-9\n1e-6 2e-9\n2e-6 NaN\n3e-6 1e-9\n", ".txt");
        let e = read_profile(f.path(), &ProfileSpec::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("--x-unit"), "{e}");
        let spec = ProfileSpec {
            x_unit: Some("m"),
            z_unit: Some("m"),
            ..Default::default()
        };
        let p = read_profile(f.path(), &spec).unwrap();
        assert_eq!(p.not_measured, 1);
        assert_eq!(p.x_mm, [0.0, 0.001, 0.003]);
    }

    #[test]
    fn bad_lines_are_named() {
        let f = file("x_mm,z_um\n0,1\n1,oops\n", ".csv");
        let e = read_profile(f.path(), &ProfileSpec::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("`z_um`") && e.contains("line 3"), "{e}");
        let f = file("x_mm,z_um\n0,1\n2,1\n1,1\n", ".csv");
        let e = read_profile(f.path(), &ProfileSpec::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("`x_mm`") && e.contains("line 4") && e.contains("increase"),
            "{e}"
        );
        let f = file("x_mm,z_um\n0,1\n2\n", ".csv");
        let e = read_profile(f.path(), &ProfileSpec::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 3"), "{e}");
    }

    #[test]
    fn a_matrix_reads_its_header_units() {
        let f = file(
            "# Width: 4 mm\n# Height: 20 µm\n# Value units: nm\n1 2 3 4\n5 NaN 7 8\n",
            ".txt",
        );
        assert!(is_text_matrix(f.path()));
        let m = read_matrix(f.path(), None, None, None).unwrap();
        assert_eq!((m.rows, m.cols), (2, 4));
        assert_eq!(m.x_mm[..4], [0.0, 1.0, 2.0, 3.0]);
        assert_eq!(m.y_mm[4], 0.01);
        assert_eq!(m.z_mm[0], 1e-6);
        assert!(m.z_mm[5].is_nan());
        let e = read_matrix(f.path(), None, None, Some("um"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("--z-unit"), "{e}");
        let f = file("# Width: 4\n# Height: 20 µm\n1 2\n3 4\n", ".txt");
        let e = read_matrix(f.path(), None, None, None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("--x-unit"), "{e}");
    }
}

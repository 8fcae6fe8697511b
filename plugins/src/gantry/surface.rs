//! Any surface measurement as points, for the run-less
//! `sparkout stage flatness --surface FILE` (docs/formats.md, "Ad hoc
//! inputs"): an x/y/z table (a CMM, profilometer or interferometer point
//! export, any column names, units per axis) or a gridded height map (an
//! interferometer export: one column per x position, one row per y
//! position). Which of the two a table is follows from its columns; a
//! table that could be either, or a 1-D profile, is refused rather than
//! guessed — a point table read as a grid gave a "flatness" of metres.
//!
//! Flatness (docs/models.md §2.4) is invariant to how x and y are scaled, so a
//! grid without coordinates (x = column index, y = row index) gives the
//! right answer as long as its steps are uniform.

use std::path::Path;

use arrow::record_batch::RecordBatch;
use sparkout_pipeline::contracts::{numeric_column, read_parquet};
use sparkout_pipeline::units::format::show_length;
use sparkout_pipeline::units::{resolve, Kind, Source, Stated, Unit, UnitError};
use sparkout_pipeline::{InputError, Result};

/// Points of a surface, in mm.
#[derive(Debug, Clone, Default)]
pub struct Points {
    pub x_mm: Vec<f64>,
    pub y_mm: Vec<f64>,
    pub z_mm: Vec<f64>,
}

/// Which columns hold x, y and z (`None`: found by name), the unit each
/// axis is in when a flag states it (`--x-unit um`), and the deprecated
/// `--unit-scale` factor (1: not given).
#[derive(Debug, Clone)]
pub struct SurfaceSpec<'a> {
    pub x: Option<&'a str>,
    pub y: Option<&'a str>,
    pub z: Option<&'a str>,
    pub unit_scale: f64,
    pub x_unit: Option<&'a str>,
    pub y_unit: Option<&'a str>,
    pub z_unit: Option<&'a str>,
}

impl Default for SurfaceSpec<'_> {
    fn default() -> Self {
        SurfaceSpec {
            x: None,
            y: None,
            z: None,
            unit_scale: 1.0,
            x_unit: None,
            y_unit: None,
            z_unit: None,
        }
    }
}

const AXES: [&str; 3] = ["x", "y", "z"];

/// The names an axis is recognised by, before any unit suffix (`x_um`,
/// `Y`, `height_nm`).
fn axis_of(name: &str) -> Option<usize> {
    let stem = match Unit::from_suffix(name).filter(|u| u.kind == Kind::Length) {
        Some(u) => &name[..name.len() - u.ascii.len() - 1],
        None => name,
    };
    match stem.to_ascii_lowercase().as_str() {
        "x" => Some(0),
        "y" => Some(1),
        "z" | "height" => Some(2),
        _ => None,
    }
}

/// The unit a legacy `--unit-scale F` states when F is an exact power of
/// ten sparkout names (1e-6 nm, 1e-3 µm, 1 mm, 1e3 m).
fn scale_unit(f: f64) -> Option<Unit> {
    [Unit::NM, Unit::UM, Unit::MM, Unit::M]
        .into_iter()
        .find(|u| (u.to_canonical(1.0) - f).abs() <= 1e-12 * f.abs())
}

/// How the flags and the file state each axis' unit.
struct Units<'a> {
    flags: [Option<&'a str>; 3],
    /// `--unit-scale F` that names no unit: multiplies every coordinate.
    factor: Option<f64>,
}

impl<'a> Units<'a> {
    fn new(spec: &SurfaceSpec<'a>) -> Result<Units<'a>> {
        let flags = [spec.x_unit, spec.y_unit, spec.z_unit];
        let f = spec.unit_scale;
        if f == 1.0 {
            return Ok(Units {
                flags,
                factor: None,
            });
        }
        if !(f.is_finite() && f > 0.0) {
            crate::bail!(
                "--unit-scale must be a number > 0 (deprecated: give the unit per axis, --x-unit um --y-unit um --z-unit nm)"
            );
        }
        if flags.iter().any(Option::is_some) {
            crate::bail!(
                "--unit-scale is deprecated and cannot be combined with --x-unit/--y-unit/--z-unit: give every axis its unit instead"
            );
        }
        Ok(match scale_unit(f) {
            // The alias of one unit for every axis: a column that states
            // another unit conflicts with it.
            Some(u) => Units {
                flags: [Some(u.ascii); 3],
                factor: None,
            },
            None => Units {
                flags,
                factor: Some(f),
            },
        })
    }

    /// The unit of `column` holding axis `k`: the flag, the column's
    /// Parquet field metadata `unit`, its name suffix (strongest first; a
    /// conflict is an error naming the column and both statements).
    fn resolve(
        &self,
        path: &Path,
        b: &RecordBatch,
        column: &str,
        k: usize,
    ) -> Result<Option<Unit>> {
        let mut stated = Vec::new();
        if let Some(t) = self.flags[k] {
            stated.push(Stated {
                text: t.to_string(),
                source: Source::Flag,
            });
        }
        if let Some(t) = field_unit(b, column) {
            stated.push(Stated {
                text: t,
                source: Source::FieldMetadata,
            });
        }
        // The unit error names the column itself.
        let r = resolve(column, Kind::Length, &stated)
            .map_err(|e| InputError::new(path, e.to_string()))?;
        if r.is_some() && self.factor.is_some() {
            return Err(InputError::new(
                path,
                "the column states its unit; --unit-scale (deprecated) would scale it again — drop it, or give --x-unit/--y-unit/--z-unit",
            )
            .column(column)
            .into());
        }
        Ok(r.map(|(u, _)| u))
    }
}

/// A column's Parquet/Arrow field metadata `unit`, when it has one.
fn field_unit(b: &RecordBatch, column: &str) -> Option<String> {
    b.schema_ref()
        .field_with_name(column)
        .ok()
        .and_then(|f| f.metadata().get("unit").cloned())
}

/// Numeric columns that may hold data (pandas' index column is not one).
fn numeric(b: &RecordBatch) -> Vec<&str> {
    b.schema_ref()
        .fields()
        .iter()
        .filter(|f| f.data_type().is_numeric() && !f.name().starts_with("__index_level_"))
        .map(|f| f.name().as_str())
        .collect()
}

/// What a table is, decided from its columns before any value is read.
enum Shape<'b> {
    /// One point per row, columns x, y, z.
    Points([&'b str; 3]),
    /// One column per x position, one row per y (`y` column when given).
    Grid(Option<&'b str>),
}

fn shape<'b>(path: &Path, b: &'b RecordBatch, spec: &SurfaceSpec<'b>) -> Result<Shape<'b>> {
    let given = [spec.x, spec.y, spec.z];
    if given.iter().any(Option::is_some) {
        return match given {
            [Some(x), Some(y), Some(z)] => Ok(Shape::Points([x, y, z])),
            _ => Err(InputError::new(
                path,
                "give all of --x, --y and --z (or none: x/y/z columns such as x_um/y_um/z_nm are found by name, a gridded map by its columns)",
            )
            .into()),
        };
    }
    let num = numeric(b);
    let mut found: [Vec<&str>; 3] = Default::default();
    for n in &num {
        if let Some(k) = axis_of(n) {
            found[k].push(n);
        }
    }
    let list = |v: &[&str]| {
        v.iter()
            .map(|n| format!("`{n}`"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    for (k, f) in found.iter().enumerate() {
        if f.len() > 1 {
            return Err(InputError::new(
                path,
                format!(
                    "ambiguous table: {} could each be {}; name the columns with --x COL --y COL --z COL",
                    list(f),
                    AXES[k]
                ),
            )
            .into());
        }
    }
    let [x, y, z] = found.map(|f| f.first().copied());
    if let (Some(x), Some(y), Some(z)) = (x, y, z) {
        return Ok(Shape::Points([x, y, z]));
    }
    // Two numeric columns, one of them x: a line, not a surface.
    if num.len() == 2 && x.is_some() && y.is_none() {
        return Err(InputError::new(
            path,
            format!(
                "a 1-D profile (columns {}), not a surface: flatness needs x, y and z. Use `sparkout stage profile --profile FILE` for a profile",
                list(&num)
            ),
        )
        .into());
    }
    if x.is_some() || z.is_some() {
        let have: Vec<&str> = [x, y, z].into_iter().flatten().collect();
        let missing: Vec<&str> = (0..3)
            .filter(|&k| [x, y, z][k].is_none())
            .map(|k| AXES[k])
            .collect();
        return Err(InputError::new(
            path,
            format!(
                "ambiguous table: {} found but no {} column among {}; name the columns with --x COL --y COL --z COL (a gridded map has one column per x position named by it)",
                list(&have),
                missing.join("/"),
                list(&num)
            ),
        )
        .into());
    }
    let data: Vec<&str> = num.iter().copied().filter(|n| Some(*n) != y).collect();
    let numbered = data
        .iter()
        .filter(|n| n.trim().parse::<f64>().is_ok())
        .count();
    if data.len() < 2
        || (numbered > 0 && numbered < data.len())
        || (numbered == 0 && data.len() < 3)
    {
        return Err(InputError::new(
            path,
            format!(
                "neither an x/y/z table (no x/y/z columns by name, e.g. x_mm/y_um/z_nm: name them with --x COL --y COL --z COL) nor a gridded map (one numeric column per x position, named by it); numeric columns: {}",
                list(&num)
            ),
        )
        .into());
    }
    Ok(Shape::Grid(y))
}

/// Read a surface file as points (mm). Every coordinate is converted from
/// the unit its axis states (flag, field metadata, name suffix) in one
/// exact operation; a table whose shape or units cannot be told is
/// refused, and so is a result no sample could give.
pub fn read_surface(path: &Path, spec: &SurfaceSpec) -> Result<Points> {
    let units = Units::new(spec)?;
    let b = read_parquet(path)?;
    let (p, positions) = match shape(path, &b, spec)? {
        Shape::Points(cols) => {
            // Every column exists and holds numbers before its unit matters.
            let mut p = xyz(path, &b, cols)?;
            let mut u: [Option<Unit>; 3] = [None; 3];
            for k in 0..3 {
                u[k] = units.resolve(path, &b, cols[k], k)?;
            }
            // Units matter once one axis states one: µm positions with
            // heights of no stated unit are not "mm" heights.
            if u.iter().any(Option::is_some) {
                if let Some(k) = (0..3).find(|&k| u[k].is_none()) {
                    return Err(InputError::new(
                        path,
                        UnitError::Unstated {
                            column: cols[k].into(),
                            fix: format!(
                                "--{}-unit UNIT (nm, um, mm, m), or a unit suffix in its name",
                                AXES[k]
                            ),
                        }
                        .to_string(),
                    )
                    .into());
                }
            }
            for (v, u) in [&mut p.x_mm, &mut p.y_mm, &mut p.z_mm].into_iter().zip(u) {
                convert(v, u, units.factor);
            }
            if p.z_mm.len() != b.num_rows() {
                return Err(InputError::new(
                    path,
                    format!(
                        "{} points from {} rows: a point table has one point per row",
                        p.z_mm.len(),
                        b.num_rows()
                    ),
                )
                .into());
            }
            (p, true)
        }
        Shape::Grid(y) => grid(path, &b, y, &units)?,
    };
    if p.z_mm.len() < 3 {
        return Err(InputError::new(
            path,
            format!(
                "{} measured points; flatness needs at least 3",
                p.z_mm.len()
            ),
        )
        .into());
    }
    if positions {
        p.check(path)?;
    }
    Ok(p)
}

/// Values in `unit` (none stated: the contract's mm) into mm, exactly;
/// or the deprecated `--unit-scale` factor.
fn convert(v: &mut [f64], unit: Option<Unit>, factor: Option<f64>) {
    match (unit, factor) {
        (Some(u), _) => v.iter_mut().for_each(|c| *c = u.to_canonical(*c)),
        (None, Some(f)) => v.iter_mut().for_each(|c| *c *= f),
        (None, None) => {}
    }
}

impl Points {
    /// Lateral extent: the larger of the x and y ranges, mm.
    pub fn extent_mm(&self) -> f64 {
        let range = |v: &[f64]| {
            let (lo, hi) = v
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &c| {
                    (l.min(c), h.max(c))
                });
            hi - lo
        };
        range(&self.x_mm).max(range(&self.y_mm))
    }

    /// A height range wider than the sample is impossible for a surface:
    /// the units are wrong (heights in nm or µm read as mm, or positions
    /// in mm read as µm). The minimum-zone flatness is never wider than
    /// the height range (a level pair of planes encloses the points), so
    /// this refuses an impossible flatness too.
    pub fn check(&self, path: &Path) -> Result<()> {
        let (lo, hi) = self
            .z_mm
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &c| {
                (l.min(c), h.max(c))
            });
        self.check_width(path, "height range", hi - lo)
    }

    /// `what` (a height range, a flatness) of `width_mm` against the
    /// sample's lateral extent.
    pub fn check_width(&self, path: &Path, what: &str, width_mm: f64) -> Result<()> {
        let extent = self.extent_mm();
        if extent > 0.0 && width_mm > extent {
            return Err(InputError::new(
                path,
                format!(
                    "{what} {} on a sample {} across is impossible: the units are wrong — state them with --x-unit/--y-unit/--z-unit (nm, um, mm, m) or a unit suffix in the column names (x_um, z_nm)",
                    show_length(width_mm),
                    show_length(extent)
                ),
            )
            .into());
        }
        Ok(())
    }
}

/// One point per row; a null or non-finite value is an error naming it.
fn xyz(path: &Path, b: &RecordBatch, names: [&str; 3]) -> Result<Points> {
    let mut out: [Vec<f64>; 3] = Default::default();
    for (k, name) in names.iter().enumerate() {
        let c = numeric_column(path, b, name, "a surface column")?;
        if let Some(i) = c.iter().position(|v| !v.is_some_and(f64::is_finite)) {
            let what = if c[i].is_none() {
                "null"
            } else {
                "non-finite value"
            };
            return Err(InputError::new(path, format!("{what} in a surface column"))
                .column(*name)
                .row(i)
                .into());
        }
        out[k] = c.into_iter().flatten().collect();
    }
    let [x_mm, y_mm, z_mm] = out;
    Ok(Points { x_mm, y_mm, z_mm })
}

/// A height map: every other numeric column is one x position (its name
/// when that is a number, in `--x-unit`, else its index); rows are y
/// positions (`y_col` when the file has one, in its stated unit, else the
/// row index). Heights are in `--z-unit`, else the unit every height
/// column's field metadata states, else mm. Null / NaN cells are points
/// that were not measured and are left out.
fn grid(
    path: &Path,
    b: &RecordBatch,
    y_col: Option<&str>,
    units: &Units,
) -> Result<(Points, bool)> {
    let mut ys: Vec<f64> = match y_col {
        Some(name) => numeric_column(path, b, name, "a surface column")?
            .into_iter()
            .enumerate()
            .map(|(i, v)| {
                v.filter(|v| v.is_finite()).ok_or_else(|| {
                    InputError::new(
                        path,
                        "the y column of a gridded map needs a value in every row",
                    )
                    .column(name)
                    .row(i)
                })
            })
            .collect::<Result<_, _>>()?,
        None => (0..b.num_rows()).map(|i| i as f64).collect(),
    };
    let y_unit = match y_col {
        Some(name) => units.resolve(path, b, name, 1)?,
        None => None,
    };
    convert(&mut ys, y_unit, units.factor);
    let data: Vec<&str> = numeric(b)
        .into_iter()
        .filter(|n| Some(*n) != y_col)
        .collect();
    // The heights' unit: the flag, else the height columns' metadata (one
    // unit for all of them).
    let mut meta: Option<(String, &str)> = None;
    for n in &data {
        if let Some(u) = field_unit(b, n) {
            match &meta {
                Some((m, first)) if *m != u => {
                    return Err(InputError::new(
                        path,
                        format!("field metadata says `{u}` here but `{m}` for column `{first}`: one unit for every height"),
                    )
                    .column(*n)
                    .into())
                }
                Some(_) => {}
                None => meta = Some((u, n)),
            }
        }
    }
    let mut stated = Vec::new();
    if let Some(t) = units.flags[2] {
        stated.push(Stated {
            text: t.to_string(),
            source: Source::Flag,
        });
    }
    if let Some((t, _)) = &meta {
        stated.push(Stated {
            text: t.clone(),
            source: Source::FieldMetadata,
        });
    }
    let z_unit = resolve("heights", Kind::Length, &stated)
        .map_err(|e| InputError::new(path, e.to_string()))?
        .map(|(u, _)| u);
    let x_unit = match units.flags[0] {
        Some(t) => Some(
            Unit::parse(t)
                .filter(|u| u.kind == Kind::Length)
                .ok_or_else(|| {
                    crate::err!(
                        "--x-unit `{t}` is not a length unit sparkout converts (nm, um, mm, m)"
                    )
                })?,
        ),
        None => None,
    };
    let by_name = data.iter().all(|n| n.trim().parse::<f64>().is_ok());
    let mut p = Points::default();
    for (k, name) in data.iter().enumerate() {
        let x = if by_name {
            name.trim().parse::<f64>().expect("checked")
        } else {
            k as f64
        };
        for (i, v) in numeric_column(path, b, name, "a surface column")?
            .into_iter()
            .enumerate()
        {
            if let Some(z) = v.filter(|v| v.is_finite()) {
                p.x_mm.push(x);
                p.y_mm.push(ys[i]);
                p.z_mm.push(z);
            }
        }
    }
    convert(&mut p.x_mm, x_unit, units.factor.filter(|_| by_name));
    convert(&mut p.z_mm, z_unit, units.factor);
    // x or y an index, not a position: there is no lateral extent to
    // judge the heights against (flatness does not depend on it).
    Ok((p, by_name && y_col.is_some()))
}

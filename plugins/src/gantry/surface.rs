//! Any surface measurement as points, for the run-less
//! `sparkout stage flatness --surface FILE` (docs/formats.md, "Ad hoc
//! inputs"): an x/y/z table (a CMM or profilometer export, any column
//! names) or a gridded height map (an interferometer export: one column per
//! x position, one row per y position).
//!
//! Flatness (docs/models.md §2.4) is invariant to how x and y are scaled, so a
//! grid without coordinates (x = column index, y = row index) gives the
//! right answer as long as its steps are uniform.

use std::path::Path;

use arrow::array::{Array, AsArray};
use arrow::datatypes::{DataType, Float64Type};
use arrow::record_batch::RecordBatch;
use sparkout_pipeline::contracts::convert::{normalise, type_accepted, TimeOrigin};
use sparkout_pipeline::contracts::{read_parquet, ColumnKind};
use sparkout_pipeline::{InputError, Result};

/// Points of a surface, in mm.
#[derive(Debug, Clone, Default)]
pub struct Points {
    pub x_mm: Vec<f64>,
    pub y_mm: Vec<f64>,
    pub z_mm: Vec<f64>,
}

/// Which columns hold x, y and z (`None`: found by name), and the factor
/// that turns the file's length unit into mm (0.001 for µm).
#[derive(Debug, Clone)]
pub struct SurfaceSpec<'a> {
    pub x: Option<&'a str>,
    pub y: Option<&'a str>,
    pub z: Option<&'a str>,
    pub unit_scale: f64,
}

const X_NAMES: [&str; 3] = ["x_mm", "x", "X"];
const Y_NAMES: [&str; 3] = ["y_mm", "y", "Y"];
const Z_NAMES: [&str; 5] = ["z_mm", "z", "Z", "height_mm", "height"];

/// A numeric column as float64 (`None` for a null row).
fn column(path: &Path, b: &RecordBatch, name: &str) -> Result<Vec<Option<f64>>, InputError> {
    let col = b.column_by_name(name).ok_or_else(|| {
        let have: Vec<&str> = b
            .schema_ref()
            .fields()
            .iter()
            .map(|f| f.name().as_str())
            .collect();
        InputError::new(
            path,
            format!("no such column (columns present: {})", have.join(", ")),
        )
        .column(name)
    })?;
    if !type_accepted(ColumnKind::F64, name, col.data_type())
        || matches!(col.data_type(), DataType::Timestamp(..))
    {
        return Err(InputError::new(
            path,
            format!(
                "wrong type {} (a surface column is a number)",
                col.data_type()
            ),
        )
        .column(name));
    }
    let f = normalise(path, name, col, &DataType::Float64, &TimeOrigin::TableStart)?;
    let f = f.as_primitive::<Float64Type>();
    Ok((0..f.len())
        .map(|i| f.is_valid(i).then(|| f.value(i)))
        .collect())
}

fn pick<'a>(b: &RecordBatch, given: Option<&'a str>, names: &[&'a str]) -> Option<&'a str> {
    given.or_else(|| {
        names
            .iter()
            .copied()
            .find(|n| b.column_by_name(n).is_some())
    })
}

/// Read a surface file as points (mm).
pub fn read_surface(path: &Path, spec: &SurfaceSpec) -> Result<Points> {
    if !(spec.unit_scale.is_finite() && spec.unit_scale > 0.0) {
        anyhow::bail!(
            "--unit-scale must be a number > 0 (the file's length unit in mm, e.g. 0.001 for µm)"
        );
    }
    let b = read_parquet(path)?;
    let cols = (
        pick(&b, spec.x, &X_NAMES),
        pick(&b, spec.y, &Y_NAMES),
        pick(&b, spec.z, &Z_NAMES),
    );
    let named = spec.x.is_some() || spec.y.is_some() || spec.z.is_some();
    let mut p = match cols {
        (Some(x), Some(y), Some(z)) => xyz(path, &b, [x, y, z])?,
        _ if named => return Err(InputError::new(
            path,
            "give all of --x, --y and --z (or none, for a gridded map or x_mm/y_mm/z_mm columns)",
        )
        .into()),
        (_, y, _) => grid(path, &b, y)?,
    };
    for v in [&mut p.x_mm, &mut p.y_mm, &mut p.z_mm] {
        v.iter_mut().for_each(|c| *c *= spec.unit_scale);
    }
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
    Ok(p)
}

/// One point per row; a null or non-finite value is an error naming it.
fn xyz(path: &Path, b: &RecordBatch, names: [&str; 3]) -> Result<Points> {
    let mut out: [Vec<f64>; 3] = Default::default();
    for (k, name) in names.iter().enumerate() {
        let c = column(path, b, name)?;
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
/// when that is a number, else its index); rows are y positions (`y_col`
/// when the file has one, else the row index). Null / NaN cells are points
/// that were not measured and are left out.
fn grid(path: &Path, b: &RecordBatch, y_col: Option<&str>) -> Result<Points> {
    let ys: Vec<f64> = match y_col {
        Some(name) => column(path, b, name)?
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
    let mut p = Points::default();
    let mut columns = 0;
    for (k, f) in b.schema_ref().fields().iter().enumerate() {
        let name = f.name().as_str();
        // pandas' index column and non-numeric columns are not grid columns.
        if Some(name) == y_col || name.starts_with("__index_level_") || !f.data_type().is_numeric()
        {
            continue;
        }
        let x = name.trim().parse::<f64>().unwrap_or(k as f64);
        for (i, v) in column(path, b, name)?.into_iter().enumerate() {
            if let Some(z) = v.filter(|v| v.is_finite()) {
                p.x_mm.push(x);
                p.y_mm.push(ys[i]);
                p.z_mm.push(z);
            }
        }
        columns += 1;
    }
    if columns < 2 {
        return Err(InputError::new(
            path,
            "neither an x/y/z table (no x_mm/y_mm/z_mm or x/y/z columns: name them with --x --y --z) nor a gridded map (at least two numeric columns)",
        )
        .into());
    }
    Ok(p)
}

//! The fleet history on disk: one Parquet partition per night,
//! `<history>/night=YYYY-MM-DD/diagnosis.parquet`, each row stamped with the
//! history version that wrote it (`history_version`). A night written by an
//! older version is upgraded as it is read (what it lacks is derived where
//! it can be, else unknown, and the trend says so in its notes); a night of
//! a newer version is refused — never mixed in silently.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::{bail, Context};
use arrow::array::UInt32Array;
use arrow::array::{Array, AsArray, BooleanArray, Float64Array, RecordBatch, StringArray};
use arrow::datatypes::{DataType, Field, Float64Type, Schema, UInt32Type};

use super::{check_night, Z95};
use crate::contracts::write_parquet_atomic;
use crate::diagnose::{Diagnosis, ObservableSummary};
use crate::error::Result;

/// Version of a history row. 1: no version column, no explained RMS,
/// selection p-value, minor flag, machines or config fingerprint. 2: those.
pub const HISTORY_VERSION: u32 = 2;

/// One history row: a parameter of a selected (or minor) effect on one
/// night, or — with an empty `effect` — the observable itself (so a night
/// that diagnosed an observable and selected nothing tells "disappeared"
/// from "not measured").
#[derive(Debug, Clone, PartialEq)]
pub struct HistoryRow {
    /// The history version that wrote the row.
    pub version: u32,
    pub night: String,
    pub observable: String,
    pub unit: String,
    /// `name:covariate`, or "" for the observable row.
    pub effect: String,
    /// A machine's own fit, or "" for the fleet-wide fit.
    pub machine: String,
    pub param: String,
    pub value: f64,
    pub se: f64,
    pub lo95: f64,
    pub hi95: f64,
    pub shrink: f64,
    pub gap_rms: f64,
    pub noise_floor: f64,
    pub n_runs: f64,
    /// RMS (in `unit`) the effect explains on held-out runs at its
    /// selection step: √(before² − after²). NaN when unknown.
    pub explained_rms: f64,
    /// p-value of the effect's selection test.
    pub p_value: f64,
    /// The diagnosis listed the effect as minor (selected robustly but not
    /// material): recorded, never "present".
    pub minor: bool,
    /// Observable rows: the machines whose runs it was measured on,
    /// comma-separated.
    pub machines: String,
    /// Fingerprint of the settings the night ran with ("" when unknown).
    pub config: String,
}

/// √(before² − after²): what an effect explains of the held-out gap.
fn explained(before: f64, after: f64) -> f64 {
    if before.is_finite() && after.is_finite() {
        (before * before - after * after).max(0.0).sqrt()
    } else {
        f64::NAN
    }
}

/// The rows of one night's diagnosis (diagnosis.json through its type);
/// `config` fingerprints the settings it ran with.
pub fn rows_of(diagnosis: &Diagnosis, night: &str, config: &str) -> Vec<HistoryRow> {
    let mut rows = Vec::new();
    let per: BTreeMap<&str, &ObservableSummary> = diagnosis
        .per_observable
        .iter()
        .map(|o| (o.observable.as_str(), o))
        .collect();
    let unit_of = |o: &str| -> String { per.get(o).map_or("mm", |p| p.unit.as_str()).to_string() };
    let nan = |x: Option<f64>| x.unwrap_or(f64::NAN);
    let blank = HistoryRow {
        version: HISTORY_VERSION,
        night: night.into(),
        observable: String::new(),
        unit: String::new(),
        effect: String::new(),
        machine: String::new(),
        param: String::new(),
        value: f64::NAN,
        se: f64::NAN,
        lo95: f64::NAN,
        hi95: f64::NAN,
        shrink: f64::NAN,
        gap_rms: f64::NAN,
        noise_floor: f64::NAN,
        n_runs: f64::NAN,
        explained_rms: f64::NAN,
        p_value: f64::NAN,
        minor: false,
        machines: String::new(),
        config: config.into(),
    };
    for (o, p) in &per {
        rows.push(HistoryRow {
            observable: o.to_string(),
            unit: unit_of(o),
            shrink: p.shrink,
            gap_rms: p.rms_mm,
            noise_floor: p.noise_floor_mm,
            n_runs: p.runs as f64,
            machines: p.machines.join(","),
            ..blank.clone()
        });
    }
    for e in diagnosis.effects.iter().filter(|e| e.selected || e.minor) {
        let obs = e.observable.as_str();
        let p = per.get(obs);
        let base = HistoryRow {
            observable: obs.into(),
            unit: unit_of(obs),
            effect: e.key(),
            shrink: nan(e.shrink),
            gap_rms: p.map_or(f64::NAN, |p| p.rms_mm),
            noise_floor: p.map_or(f64::NAN, |p| p.noise_floor_mm),
            n_runs: p.map_or(f64::NAN, |p| p.runs as f64),
            explained_rms: explained(nan(e.cv_rms_before_mm), nan(e.cv_rms_after_mm)),
            p_value: nan(e.p_value),
            minor: e.minor,
            ..blank.clone()
        };
        for (k, &value) in &e.params {
            let iv = e.intervals.as_ref().and_then(|i| i.get(k));
            rows.push(HistoryRow {
                param: k.clone(),
                value,
                se: iv.map_or(f64::NAN, |i| i.se),
                lo95: iv.map_or(f64::NAN, |i| i.lo),
                hi95: iv.map_or(f64::NAN, |i| i.hi),
                ..base.clone()
            });
        }
        // A machine's own fit, where the diagnosis reports one. It carries
        // no standard error (diagnosis.json `per_machine` has none), so its
        // interval is unknown.
        for m in e.per_machine.iter().flatten() {
            for (k, &value) in &m.params {
                let se = f64::NAN;
                rows.push(HistoryRow {
                    machine: m.machine.clone(),
                    param: k.clone(),
                    value,
                    se,
                    lo95: value - Z95 * se,
                    hi95: value + Z95 * se,
                    ..base.clone()
                });
            }
        }
    }
    rows
}

fn batch_of(rows: &[HistoryRow]) -> Result<RecordBatch> {
    let text = |g: fn(&HistoryRow) -> &str| -> Arc<dyn Array> {
        Arc::new(StringArray::from_iter_values(rows.iter().map(g)))
    };
    let num = |g: fn(&HistoryRow) -> f64| -> Arc<dyn Array> {
        // NaN is "no value": null in the file (no non-finite number is
        // ever written).
        Arc::new(Float64Array::from_iter(rows.iter().map(|r| {
            let v = g(r);
            v.is_finite().then_some(v)
        })))
    };
    let columns: Vec<(&str, Arc<dyn Array>)> = vec![
        (
            "history_version",
            Arc::new(UInt32Array::from_iter_values(
                rows.iter().map(|r| r.version),
            )),
        ),
        ("night", text(|r| &r.night)),
        ("observable", text(|r| &r.observable)),
        ("unit", text(|r| &r.unit)),
        ("effect", text(|r| &r.effect)),
        ("machine", text(|r| &r.machine)),
        ("param", text(|r| &r.param)),
        ("value", num(|r| r.value)),
        ("se", num(|r| r.se)),
        ("lo95", num(|r| r.lo95)),
        ("hi95", num(|r| r.hi95)),
        ("shrink", num(|r| r.shrink)),
        ("gap_rms", num(|r| r.gap_rms)),
        ("noise_floor", num(|r| r.noise_floor)),
        ("n_runs", num(|r| r.n_runs)),
        ("explained_rms", num(|r| r.explained_rms)),
        ("p_value", num(|r| r.p_value)),
        (
            "minor",
            Arc::new(BooleanArray::from(
                rows.iter().map(|r| r.minor).collect::<Vec<_>>(),
            )),
        ),
        ("machines", text(|r| &r.machines)),
        ("config", text(|r| &r.config)),
    ];
    let schema = Schema::new(
        columns
            .iter()
            .map(|(n, a)| {
                Field::new(
                    *n,
                    a.data_type().clone(),
                    a.data_type() == &DataType::Float64,
                )
            })
            .collect::<Vec<_>>(),
    );
    Ok(RecordBatch::try_new(
        Arc::new(schema),
        columns.into_iter().map(|(_, a)| a).collect(),
    )?)
}

/// Writes (or replaces, atomically) one night's partition.
pub fn write_night(history: &Path, night: &str, rows: &[HistoryRow]) -> Result<PathBuf> {
    check_night(night)?;
    let dir = history.join(format!("night={night}"));
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let path = dir.join("diagnosis.parquet");
    write_parquet_atomic(&path, &batch_of(rows)?)?;
    Ok(path)
}

/// Appends (or replaces, atomically) one night's partition from its
/// diagnosis.
pub fn append_night(
    history: &Path,
    night: &str,
    diagnosis: &Diagnosis,
    config: &str,
) -> Result<PathBuf> {
    write_night(history, night, &rows_of(diagnosis, night, config))
}

/// The nights of a history, oldest first, each with its partition file.
fn nights_of(history: &Path) -> Result<Vec<(String, PathBuf)>> {
    let mut nights: Vec<(String, PathBuf)> = Vec::new();
    let entries = std::fs::read_dir(history).with_context(|| {
        format!(
            "cannot read the history {} (written by `sparkout run --history DIR`)",
            history.display()
        )
    })?;
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        if let Some(night) = name.strip_prefix("night=") {
            if check_night(night).is_ok() {
                nights.push((night.to_string(), e.path().join("diagnosis.parquet")));
            }
        }
    }
    nights.sort();
    if nights.is_empty() {
        bail!(
            "{} holds no night=YYYY-MM-DD/diagnosis.parquet: append nights with `sparkout run --history {}`",
            history.display(),
            history.display()
        );
    }
    Ok(nights)
}

/// Every night of a history, oldest first, upgraded to [`HISTORY_VERSION`];
/// and a note per night read from an older version.
pub fn read_history(history: &Path) -> Result<(Vec<HistoryRow>, Vec<String>)> {
    let mut rows = Vec::new();
    let mut old: BTreeMap<u32, Vec<String>> = BTreeMap::new();
    for (night, path) in nights_of(history)? {
        let (version, night_rows) = read_night(&path, &night)?;
        if version < HISTORY_VERSION {
            old.entry(version).or_default().push(night);
        }
        rows.extend(night_rows);
    }
    let notes = old
        .into_iter()
        .map(|(v, nights)| {
            format!(
                "{} night(s) written by history version {v} ({} … {}), upgraded as read: an effect's explained RMS derived from its shrink and the observable's gap, no minor flags, no config fingerprint (config changes on those nights are not detected); rewrite a night with `sparkout run --history` to store it as version {HISTORY_VERSION}",
                nights.len(),
                nights.first().map_or("", |s| s.as_str()),
                nights.last().map_or("", |s| s.as_str()),
            )
        })
        .collect();
    Ok((rows, notes))
}

/// One partition: its version and rows, upgraded.
fn read_night(path: &Path, night: &str) -> Result<(u32, Vec<HistoryRow>)> {
    let batch = crate::contracts::parquet_file::open_parquet(path)
        .and_then(|b| crate::contracts::parquet_file::read_all(path, b))?;
    let missing = |name: &str| crate::InputError::new(path, "missing history column").column(name);
    let version = match batch.column_by_name("history_version") {
        None => 1,
        Some(a) => {
            let a = arrow::compute::cast(a, &DataType::UInt32)?;
            let a = a.as_primitive::<UInt32Type>();
            let mut v = None;
            for i in 0..a.len() {
                let vi = if a.is_null(i) { 0 } else { a.value(i) };
                if vi == 0 || v.is_some_and(|v| v != vi) {
                    return Err(crate::InputError::new(
                        path,
                        "history rows of different versions in one night: rewrite the night with `sparkout run --history`",
                    )
                    .column("history_version")
                    .row(i)
                    .into());
                }
                v = Some(vi);
            }
            v.unwrap_or(HISTORY_VERSION)
        }
    };
    if version > HISTORY_VERSION {
        return Err(crate::InputError::new(
            path,
            format!(
                "written by history version {version}; this sparkout reads versions 1 to {HISTORY_VERSION}: update sparkout, or start a new history directory"
            ),
        )
        .column("history_version")
        .into());
    }
    let text = |name: &str, required: bool| -> Result<Vec<String>> {
        let Some(a) = batch.column_by_name(name) else {
            if required {
                return Err(missing(name).into());
            }
            return Ok(vec![String::new(); batch.num_rows()]);
        };
        let a = arrow::compute::cast(a, &DataType::Utf8)?;
        Ok(a.as_string::<i32>()
            .iter()
            .map(|s| s.unwrap_or("").to_string())
            .collect())
    };
    let num = |name: &str, required: bool| -> Result<Vec<f64>> {
        let Some(a) = batch.column_by_name(name) else {
            if required {
                return Err(missing(name).into());
            }
            return Ok(vec![f64::NAN; batch.num_rows()]);
        };
        let a = arrow::compute::cast(a, &DataType::Float64)?;
        Ok(a.as_primitive::<Float64Type>()
            .iter()
            .map(|v| v.unwrap_or(f64::NAN))
            .collect())
    };
    // Version 2 columns are required of a version 2 night.
    let v2 = version >= 2;
    let (obs, unit, effect, machine, param) = (
        text("observable", true)?,
        text("unit", true)?,
        text("effect", true)?,
        text("machine", true)?,
        text("param", true)?,
    );
    let (value, se, lo, hi) = (
        num("value", true)?,
        num("se", true)?,
        num("lo95", true)?,
        num("hi95", true)?,
    );
    let (shrink, gap, floor, runs) = (
        num("shrink", true)?,
        num("gap_rms", true)?,
        num("noise_floor", true)?,
        num("n_runs", true)?,
    );
    let (explained_rms, p_value) = (num("explained_rms", v2)?, num("p_value", v2)?);
    let (machines, config) = (text("machines", v2)?, text("config", v2)?);
    let minor: Vec<bool> = match batch.column_by_name("minor") {
        Some(a) => {
            let a = arrow::compute::cast(a, &DataType::Boolean)?;
            a.as_boolean().iter().map(|b| b.unwrap_or(false)).collect()
        }
        None if v2 => return Err(missing("minor").into()),
        None => vec![false; batch.num_rows()],
    };
    let mut rows = Vec::with_capacity(batch.num_rows());
    for i in 0..batch.num_rows() {
        // Version 1 → 2: what an effect explains, from its shrink
        // (1 − after/before) and the observable's gap as "before".
        let explained_rms = if v2 || effect[i].is_empty() {
            explained_rms[i]
        } else {
            explained(gap[i], gap[i] * (1.0 - shrink[i]))
        };
        rows.push(HistoryRow {
            version: HISTORY_VERSION,
            night: night.to_string(),
            observable: obs[i].clone(),
            unit: unit[i].clone(),
            effect: effect[i].clone(),
            machine: machine[i].clone(),
            param: param[i].clone(),
            value: value[i],
            se: se[i],
            lo95: lo[i],
            hi95: hi[i],
            shrink: shrink[i],
            gap_rms: gap[i],
            noise_floor: floor[i],
            n_runs: runs[i],
            explained_rms,
            p_value: p_value[i],
            minor: minor[i],
            machines: machines[i].clone(),
            config: config[i].clone(),
        });
    }
    Ok((version, rows))
}

#[cfg(test)]
pub(super) mod tests_support {
    use super::*;

    /// The rows as history version 1 wrote them.
    pub fn v1_batch(rows: &[HistoryRow]) -> RecordBatch {
        let b = batch_of(rows).unwrap();
        let keep: Vec<usize> = b
            .schema()
            .fields()
            .iter()
            .enumerate()
            .filter(|(_, f)| {
                ![
                    "history_version",
                    "explained_rms",
                    "p_value",
                    "minor",
                    "machines",
                    "config",
                ]
                .contains(&f.name().as_str())
            })
            .map(|(i, _)| i)
            .collect();
        b.project(&keep).unwrap()
    }

    /// The rows stamped with another version.
    pub fn with_version(rows: &[HistoryRow], v: u32) -> RecordBatch {
        let rows: Vec<HistoryRow> = rows
            .iter()
            .map(|r| HistoryRow {
                version: v,
                ..r.clone()
            })
            .collect();
        batch_of(&rows).unwrap()
    }
}

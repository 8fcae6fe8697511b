//! `sparkout import`: foreign tables (a controller's CSV export, a Parquet
//! file with other column names) → recorded runs that follow the data
//! contracts (docs/formats.md §4). A [`Mapping`] says which source column
//! becomes which contract column with what unit factor, how rows split into
//! runs and which machine and plugin the runs belong to. Every value is
//! parsed and every run validated exactly as any input is read; a cell that
//! does not parse is an error naming the file, the column and the row.
//! Docs: docs/import.md.

mod csv;
pub mod mapping;
pub mod source;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow::array::{Array, ArrayRef, Float64Array, Int32Array, Int64Array, Int8Array, StringArray};
use arrow::datatypes::{Field, Schema};
use arrow::record_batch::RecordBatch;

pub use mapping::{ColumnMap, Mapping, RunSplit, SourceRef};
pub use source::SourceTable;

use crate::contracts::{write_atomic, write_parquet_atomic, ColumnKind, Table};
use crate::error::InputError;
use crate::Result;

/// One run written by the import.
#[derive(Debug, Clone)]
pub struct ImportedRun {
    pub id: String,
    pub dir: PathBuf,
    pub rows: usize,
    /// The source file it came from.
    pub source: PathBuf,
}

/// A run id that is a safe directory name: letters, digits, `_`, `-`, `.`.
fn run_id(s: &str) -> String {
    let id: String = s
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.') {
                c
            } else {
                '_'
            }
        })
        .collect();
    if id.is_empty() || id.starts_with('.') {
        format!("r{id}")
    } else {
        id
    }
}

fn file_stem(path: &Path) -> String {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "run".into());
    let lower = name.to_lowercase();
    for ext in [
        ".csv.gz", ".tsv.gz", ".txt.gz", ".gz", ".csv", ".tsv", ".txt", ".parquet", ".pq",
    ] {
        if lower.ends_with(ext) {
            return name[..name.len() - ext.len()].to_string();
        }
    }
    name
}

/// Rows `[start, end)` of one run and its id.
struct Group {
    id: String,
    rows: std::ops::Range<usize>,
}

fn groups(src: &SourceTable, m: &Mapping) -> Result<Vec<Group>, InputError> {
    let stem = run_id(&file_stem(&src.path));
    let n = src.n_rows();
    match &m.split {
        RunSplit::PerFile => Ok(vec![Group {
            id: stem,
            rows: 0..n,
        }]),
        RunSplit::ByColumn(r) => {
            let c = src.column(r)?;
            let col = &src.columns[c];
            let mut out: Vec<Group> = Vec::new();
            let mut start = 0;
            for i in 1..=n {
                if i == n || col[i] != col[start] {
                    let v = col[start].as_deref().unwrap_or("none");
                    out.push(Group {
                        id: run_id(&format!("{stem}_{v}")),
                        rows: start..i,
                    });
                    start = i;
                }
            }
            // A value that comes back later (A, B, A) would reuse a run id:
            // number the repeats rather than merge non-adjacent rows.
            let mut seen = BTreeSet::new();
            for g in &mut out {
                let base = g.id.clone();
                let mut k = 1;
                while !seen.insert(g.id.clone()) {
                    k += 1;
                    g.id = format!("{base}_{k}");
                }
            }
            Ok(out)
        }
    }
}

/// Parse one cell as a number, in the destination's unit (the mapping's
/// stated unit, or its factor) plus its offset.
fn number(src: &SourceTable, cm: &ColumnMap, row: usize, cell: &str) -> Result<f64, InputError> {
    let v: f64 = cell.parse().map_err(|_| {
        InputError::new(
            &src.path,
            format!(
                "{}: {cell:?} is not a number (source column {} → `{}`)",
                src.row_label(row),
                cm.source,
                cm.dest
            ),
        )
        .column(cm.dest.clone())
        .row(row)
    })?;
    if !v.is_finite() {
        return Err(InputError::new(
            &src.path,
            format!(
                "{}: {cell:?} is not a finite number (source column {} → `{}`)",
                src.row_label(row),
                cm.source,
                cm.dest
            ),
        )
        .column(cm.dest.clone())
        .row(row));
    }
    Ok(cm.convert(v))
}

/// One destination column over a run's rows.
fn convert(
    src: &SourceTable,
    m: &Mapping,
    cm: &ColumnMap,
    rows: std::ops::Range<usize>,
) -> Result<ArrayRef, InputError> {
    let col = &src.columns[src.column(&cm.source)?];
    let kind = m.dest_kind(cm);
    let cells = rows.clone().map(|i| (i, col[i].as_deref()));
    let int = |i: usize, s: &str, lo: f64, hi: f64| -> Result<f64, InputError> {
        let v = number(src, cm, i, s)?;
        if v.fract() != 0.0 || v < lo || v > hi {
            return Err(InputError::new(
                &src.path,
                format!(
                    "{}: {s:?} is not an integer in {lo}..={hi} (source column {} → `{}`, {})",
                    src.row_label(i),
                    cm.source,
                    cm.dest,
                    kind.label()
                ),
            )
            .column(cm.dest.clone())
            .row(i));
        }
        Ok(v)
    };
    Ok(match kind {
        ColumnKind::F64 | ColumnKind::F32 => {
            let v: Vec<Option<f64>> = cells
                .map(|(i, c)| c.map(|s| number(src, cm, i, s)).transpose())
                .collect::<Result<_, _>>()?;
            Arc::new(Float64Array::from(v))
        }
        ColumnKind::I32 => {
            let (lo, hi) = (i32::MIN as f64, i32::MAX as f64);
            let v: Vec<Option<i32>> = cells
                .map(|(i, c)| c.map(|s| int(i, s, lo, hi).map(|v| v as i32)).transpose())
                .collect::<Result<_, _>>()?;
            Arc::new(Int32Array::from(v))
        }
        ColumnKind::I64 => {
            // ±2^53: the largest integers an f64 parse keeps exact.
            let v: Vec<Option<i64>> = cells
                .map(|(i, c)| {
                    c.map(|s| int(i, s, -9.007e15, 9.007e15).map(|v| v as i64))
                        .transpose()
                })
                .collect::<Result<_, _>>()?;
            Arc::new(Int64Array::from(v))
        }
        ColumnKind::I8 => {
            let v: Vec<Option<i8>> = cells
                .map(|(i, c)| {
                    c.map(|s| int(i, s, -128.0, 127.0).map(|v| v as i8))
                        .transpose()
                })
                .collect::<Result<_, _>>()?;
            Arc::new(Int8Array::from(v))
        }
        ColumnKind::Utf8 => {
            let v: StringArray = cells.map(|(_, c)| c).collect();
            Arc::new(v)
        }
    })
}

/// Build and validate one run's contract table from a source table.
fn run_table(src: &SourceTable, m: &Mapping, g: &Group) -> Result<Table, InputError> {
    let schema = m.tables.get(&m.table).expect("validated mapping");
    let mut fields = Vec::new();
    let mut cols: Vec<ArrayRef> = Vec::new();
    let rebase = matches!(m.split, RunSplit::ByColumn(_));
    if let Some(p) = m.sample_period_s {
        let t: Vec<f64> = g
            .rows
            .clone()
            .map(|i| (i - if rebase { g.rows.start } else { 0 }) as f64 * p)
            .collect();
        fields.push(Field::new(
            "t_s",
            arrow::datatypes::DataType::Float64,
            false,
        ));
        cols.push(Arc::new(Float64Array::from(t)));
    }
    for cm in &m.columns {
        let mut a = convert(src, m, cm, g.rows.clone())?;
        if cm.dest == "t_s" && rebase {
            let t = a
                .as_any()
                .downcast_ref::<Float64Array>()
                .expect("t_s is f64");
            let t0 = if t.is_empty() || t.is_null(0) {
                0.0
            } else {
                t.value(0)
            };
            a = Arc::new(Float64Array::from_iter(t.iter().map(|v| v.map(|v| v - t0))));
        }
        let nullable = a.null_count() > 0 || schema.column(&cm.dest).is_none_or(|s| !s.required);
        fields.push(Field::new(&cm.dest, a.data_type().clone(), nullable));
        cols.push(a);
    }
    let batch = RecordBatch::try_new(Arc::new(Schema::new(fields)), cols)
        .map_err(|e| InputError::new(&src.path, format!("cannot assemble table: {e}")))?;
    // The same validation as any run's table (required values finite, t_s
    // non-decreasing ...); its rows are the run's, shifted back to the file's.
    Table::from_batch(&src.path, schema, batch).map_err(|mut e| {
        if let Some(r) = e.row {
            let row = r + g.rows.start;
            e.row = Some(row);
            e.message = format!("{} (run `{}`): {}", src.row_label(row), g.id, e.message);
        }
        e
    })
}

fn run_toml(m: &Mapping, id: &str, source: &Path) -> Result<String> {
    let mut run = toml::Table::new();
    run.insert("id".into(), toml::Value::String(id.to_string()));
    run.insert("machine".into(), toml::Value::String(m.machine.clone()));
    run.insert("plugin".into(), toml::Value::String(m.plugin.clone()));
    let mut doc = toml::Table::new();
    doc.insert("run".into(), toml::Value::Table(run));
    if !m.process.is_empty() {
        doc.insert("process".into(), toml::Value::Table(m.process.clone()));
    }
    let name = source
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    Ok(format!(
        "# imported from {name} by `sparkout import` (docs/import.md)\n{}",
        toml::to_string(&doc)?
    ))
}

/// Import one file: its runs under `<out>/<machine>/<run>/`. Nothing is
/// written for a file with a bad value (all its runs are checked first).
pub fn import_file(path: &Path, m: &Mapping, out: &Path) -> Result<Vec<ImportedRun>> {
    m.validate()?;
    let src = SourceTable::read(path, m.delimiter)?;
    if src.n_rows() == 0 {
        return Err(InputError::new(path, "no data rows after the header").into());
    }
    for cm in &m.columns {
        src.column(&cm.source)?;
    }
    let schema = m.tables.get(&m.table).expect("validated mapping");
    let groups = groups(&src, m)?;
    let tables: Vec<Table> = groups
        .iter()
        .map(|g| run_table(&src, m, g))
        .collect::<Result<_, _>>()?;
    let mut done = Vec::new();
    for (g, t) in groups.iter().zip(&tables) {
        let dir = out.join(&m.machine).join(&g.id);
        write_parquet_atomic(&dir.join(schema.file_name()), t.batch())?;
        write_atomic(&dir.join("run.toml"), run_toml(m, &g.id, path)?.as_bytes())?;
        done.push(ImportedRun {
            id: g.id.clone(),
            dir,
            rows: t.len(),
            source: path.to_path_buf(),
        });
    }
    Ok(done)
}

/// What a batch import did: the runs written and the files refused (bad
/// input), like a batch run: one bad file never stops the others.
#[derive(Debug, Default)]
pub struct ImportOutcome {
    pub runs: Vec<ImportedRun>,
    pub failures: Vec<(PathBuf, String)>,
}

/// Import every file; duplicate run ids across files are refused (a run is
/// unique within its machine, docs/formats.md §4).
pub fn import_files(paths: &[PathBuf], m: &Mapping, out: &Path) -> Result<ImportOutcome> {
    m.validate()?;
    let mut outcome = ImportOutcome::default();
    let mut ids = BTreeSet::new();
    for p in paths {
        match import_file(p, m, out) {
            Ok(runs) => {
                for r in runs {
                    if !ids.insert(r.id.clone()) {
                        outcome.failures.push((
                            p.clone(),
                            format!("run id `{}` already imported from another file (rename the file: a run id is unique within machine `{}`)", r.id, m.machine),
                        ));
                        continue;
                    }
                    outcome.runs.push(r);
                }
            }
            Err(e) => outcome.failures.push((p.clone(), format!("{e:#}"))),
        }
    }
    Ok(outcome)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mapping() -> Mapping {
        let mut m = Mapping::from_flags(
            "motion",
            "m1",
            "servo",
            &crate::contracts::TableRegistry::shared(),
        );
        for f in [
            "#0=t_s*0.1",
            "xc=cmd_x_mm",
            "yc=cmd_y_mm*25.4",
            "zc=cmd_z_mm",
            "seg=segment",
        ] {
            m.apply_flag(f).unwrap();
        }
        m
    }

    #[test]
    fn imports_csv_with_factors_and_positions() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("exp_01.csv");
        std::fs::write(&p, ",xc,yc,zc,seg\n0,1.0,1,0,3\n1,2.0,2,0,3.0\n2,3,3,0,4\n").unwrap();
        let runs = import_file(&p, &mapping(), &d.path().join("out")).unwrap();
        assert_eq!(runs.len(), 1);
        assert_eq!(runs[0].id, "exp_01");
        let t = Table::read(
            &runs[0].dir.join("motion.parquet"),
            &crate::contracts::schema::MOTION,
        )
        .unwrap();
        assert_eq!(t.f64("t_s").unwrap(), &[0.0, 0.1, 0.2]);
        let y = t.f64("cmd_y_mm").unwrap();
        assert!(
            (y[2] - 76.2).abs() < 1e-12 && (y[0] - 25.4).abs() < 1e-12,
            "{y:?}"
        );
        assert_eq!(t.i32("segment").unwrap(), &[3, 3, 4]);
        let spec = crate::contracts::RunSpec::load(&runs[0].dir).unwrap();
        assert_eq!(
            (spec.machine.as_str(), spec.plugin.as_str()),
            ("m1", "servo")
        );
    }

    #[test]
    fn bad_cell_names_file_column_and_row() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("bad.csv");
        std::fs::write(&p, ",xc,yc,zc,seg\n0,1,1,0,1\n1,1,x1,0,1\n").unwrap();
        let e = import_file(&p, &mapping(), d.path()).unwrap_err();
        let e = e.input().unwrap().clone();
        assert_eq!(e.column.as_deref(), Some("cmd_y_mm"));
        assert_eq!(e.row, Some(1));
        assert!(
            e.to_string().contains("bad.csv") && e.to_string().contains("line 3"),
            "{e}"
        );
        // Non-integer segment, then decreasing time.
        std::fs::write(&p, ",xc,yc,zc,seg\n0,1,1,0,1.5\n").unwrap();
        let e = import_file(&p, &mapping(), d.path())
            .unwrap_err()
            .to_string();
        assert!(e.contains("segment") && e.contains("integer"), "{e}");
        std::fs::write(&p, ",xc,yc,zc,seg\n1,1,1,0,1\n0,1,1,0,1\n").unwrap();
        let e = import_file(&p, &mapping(), d.path()).unwrap_err();
        let e = e.input().unwrap().clone();
        assert_eq!((e.column.as_deref(), e.row), (Some("t_s"), Some(1)));
    }

    #[test]
    fn splits_runs_by_a_column_and_rebases_time() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("log.csv");
        std::fs::write(
            &p,
            ",xc,yc,zc,seg,job\n0,1,1,0,1,a\n1,1,1,0,1,a\n2,1,1,0,1,b\n3,1,1,0,1,a\n",
        )
        .unwrap();
        let mut m = mapping();
        m.split = RunSplit::ByColumn(SourceRef::Name("job".into()));
        let runs = import_file(&p, &m, d.path()).unwrap();
        let ids: Vec<&str> = runs.iter().map(|r| r.id.as_str()).collect();
        assert_eq!(ids, ["log_a", "log_b", "log_a_2"]);
        let t = Table::read(
            &runs[2].dir.join("motion.parquet"),
            &crate::contracts::schema::MOTION,
        )
        .unwrap();
        assert_eq!(t.f64("t_s").unwrap(), &[0.0]);
    }
}

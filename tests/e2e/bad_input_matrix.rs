//! The bad-input matrix. One small generated fleet per plugin;
//! each case copies a good run under a new id and breaks one thing (a NaN,
//! a 1e300, metres for mm, degrees for rad, a typo'd key, ...). One
//! `sparkout run` over all of them must reject exactly the broken runs
//! (each failure naming its file and column), accept the good ones, write
//! no non-finite number anywhere — and `sparkout validate-input` must agree
//! with `run` on every directory (one shared validation, item 4).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow::array::{
    Array, ArrayRef, Float32Array, Float64Array, Int32Array, Int64Array, Int8Array, StringArray,
};
use arrow::datatypes::{DataType, Field, Schema};
use arrow::record_batch::RecordBatch;
use sparkout_pipeline::contracts::{read_parquet, write_parquet_atomic};

use crate::common::sparkout;

/// One way to break a run.
#[derive(Clone, Copy)]
enum Break {
    /// Set one row of a numeric column.
    Set(&'static str, &'static str, usize, f64),
    /// Null at one row.
    Null(&'static str, &'static str, usize),
    /// Multiply whole columns (a wrong unit).
    Scale(&'static str, &'static [&'static str], f64),
    /// Add a constant to a whole column (kelvin for °C).
    Shift(&'static str, &'static str, f64),
    Drop(&'static str, &'static str),
    AsText(&'static str, &'static str),
    Empty(&'static str),
    Truncate(&'static str),
    Garbage(&'static str),
    /// Swap rows 3 and 4 of t_s (time goes backwards).
    Backwards(&'static str),
    IsDir(&'static str),
    Remove(&'static str),
    /// Edit run.toml: replace the first `from` with `to` (append when
    /// `from` is empty).
    RunToml(&'static str, &'static str),
    /// A machine config of its own: the plugin's built-in one edited the
    /// same way (`from` empty: replace the whole text by `to`).
    Machine(&'static str, &'static str),
}

struct Case {
    name: &'static str,
    plugin: &'static str,
    brk: Break,
    /// Expected failure file suffix and column (None: not checked).
    file: Option<&'static str>,
    column: Option<&'static str>,
}

const fn case(
    name: &'static str,
    plugin: &'static str,
    brk: Break,
    file: Option<&'static str>,
    column: Option<&'static str>,
) -> Case {
    Case {
        name,
        plugin,
        brk,
        file,
        column,
    }
}

use Break::*;

const NAN: f64 = f64::NAN;
const INF: f64 = f64::INFINITY;
const DEG: f64 = 180.0 / std::f64::consts::PI;

const CASES: &[Case] = &[
    // robot: ae + motion + plan (+ passes)
    case(
        "rob-motion-nan",
        "robot",
        Set("motion", "cmd_x_mm", 5, NAN),
        Some("motion.parquet"),
        Some("cmd_x_mm"),
    ),
    case(
        "rob-motion-inf",
        "robot",
        Set("motion", "cmd_y_mm", 7, INF),
        Some("motion.parquet"),
        Some("cmd_y_mm"),
    ),
    case(
        "rob-motion-1e300",
        "robot",
        Set("motion", "cmd_z_mm", 9, 1e300),
        Some("motion.parquet"),
        Some("cmd_z_mm"),
    ),
    case(
        "rob-motion-metres",
        "robot",
        Scale(
            "motion",
            &[
                "cmd_x_mm", "cmd_y_mm", "cmd_z_mm", "act_x_mm", "act_y_mm", "act_z_mm",
            ],
            1e-3,
        ),
        Some("motion.parquet"),
        Some("cmd_x_mm"),
    ),
    case(
        "rob-motion-act-inf",
        "robot",
        Set("motion", "act_x_mm", 3, -INF),
        Some("motion.parquet"),
        Some("act_x_mm"),
    ),
    case(
        "rob-motion-feed-mm-min",
        "robot",
        Scale("motion", &["feed_mm_s"], 6e4),
        Some("motion.parquet"),
        Some("feed_mm_s"),
    ),
    case(
        "rob-motion-backwards",
        "robot",
        Backwards("motion"),
        Some("motion.parquet"),
        Some("t_s"),
    ),
    case(
        "rob-motion-drop",
        "robot",
        Drop("motion", "cmd_x_mm"),
        Some("motion.parquet"),
        Some("cmd_x_mm"),
    ),
    case(
        "rob-motion-text",
        "robot",
        AsText("motion", "cmd_y_mm"),
        Some("motion.parquet"),
        Some("cmd_y_mm"),
    ),
    case(
        "rob-motion-segment",
        "robot",
        Set("motion", "segment", 2, -7.0),
        Some("motion.parquet"),
        Some("segment"),
    ),
    case(
        "rob-ae-nan",
        "robot",
        Set("ae", "ae_v", 11, NAN),
        Some("ae.parquet"),
        Some("ae_v"),
    ),
    case(
        "rob-ae-counts",
        "robot",
        Set("ae", "ae_v", 13, 4096.0),
        Some("ae.parquet"),
        Some("ae_v"),
    ),
    case(
        "rob-ae-backwards",
        "robot",
        Backwards("ae"),
        Some("ae.parquet"),
        Some("t_s"),
    ),
    case(
        "rob-ae-empty",
        "robot",
        Empty("ae"),
        Some("ae.parquet"),
        None,
    ),
    case(
        "rob-ae-truncated",
        "robot",
        Truncate("ae"),
        Some("ae.parquet"),
        None,
    ),
    case("rob-ae-dir", "robot", IsDir("ae"), Some("ae.parquet"), None),
    case(
        "rob-ae-epoch",
        "robot",
        Shift("ae", "t_s", 1.7e9),
        Some("ae.parquet"),
        Some("t_s"),
    ),
    case(
        "rob-plan-dir",
        "robot",
        Set("plan", "dir_x", 0, 5.0),
        Some("plan.parquet"),
        Some("dir_x"),
    ),
    case(
        "rob-plan-speed",
        "robot",
        Set("plan", "approach_mm_s", 1, -5.0),
        Some("plan.parquet"),
        Some("approach_mm_s"),
    ),
    case(
        "rob-plan-nan",
        "robot",
        Set("plan", "nom_x_mm", 2, NAN),
        Some("plan.parquet"),
        Some("nom_x_mm"),
    ),
    case(
        "rob-plan-null",
        "robot",
        Null("plan", "nom_y_mm", 1),
        Some("plan.parquet"),
        Some("nom_y_mm"),
    ),
    case(
        "rob-plan-metres",
        "robot",
        Scale("plan", &["nom_x_mm", "nom_y_mm", "nom_z_mm"], 1e-3),
        Some("plan.parquet"),
        Some("nom_x_mm"),
    ),
    case(
        "rob-passes-doc-um",
        "robot",
        Scale("passes", &["nominal_doc_mm"], 1e3),
        Some("passes.parquet"),
        Some("nominal_doc_mm"),
    ),
    case(
        "rob-passes-zero",
        "robot",
        Set("passes", "pass", 0, 0.0),
        Some("passes.parquet"),
        Some("pass"),
    ),
    case(
        "rob-passes-nan",
        "robot",
        Set("passes", "height_after_mm", 0, NAN),
        Some("passes.parquet"),
        Some("height_after_mm"),
    ),
    case(
        "rob-started",
        "robot",
        RunToml("started = ", "started = \"yesterday\"\nx_started = "),
        Some("run.toml"),
        None,
    ),
    case(
        "rob-process-typo",
        "robot",
        RunToml("weld_mm", "weld_mmm"),
        Some("run.toml"),
        Some("process.weld_mmm"),
    ),
    case(
        "rob-ae-rate-zero",
        "robot",
        RunToml("sample_rate_hz = ", "sample_rate_hz = 0\nx_rate = "),
        Some("run.toml"),
        None,
    ),
    case(
        "rob-ae-key",
        "robot",
        RunToml("kind = ", "sample_rate = 5\nkind = "),
        Some("run.toml"),
        Some("ae.sample_rate"),
    ),
    case(
        "rob-machine-section",
        "robot",
        Machine("[wheel]", "[whel]"),
        Some(".toml"),
        None,
    ),
    case(
        "rob-machine-text",
        "robot",
        Machine("radius_mm = 50.0", "radius_mm = \"50 mm\""),
        Some(".toml"),
        Some("wheel.radius_mm"),
    ),
    case(
        "rob-machine-negative",
        "robot",
        Machine("radius_mm = 50.0", "radius_mm = -50.0"),
        Some(".toml"),
        Some("wheel.radius_mm"),
    ),
    case(
        "rob-machine-empty",
        "robot",
        Machine("", ""),
        Some(".toml"),
        None,
    ),
    case(
        "rob-machine-plugin",
        "robot",
        Machine("plugin = \"robot\"", "plugin = \"gantry\""),
        Some(".toml"),
        Some("machine.plugin"),
    ),
    // guideway
    case(
        "gw-nan",
        "guideway",
        Set("guideway", "za_mm", 4, NAN),
        Some("guideway.parquet"),
        Some("za_mm"),
    ),
    case(
        "gw-inf",
        "guideway",
        Set("guideway", "zb_mm", 4, INF),
        Some("guideway.parquet"),
        Some("zb_mm"),
    ),
    case(
        "gw-1e300",
        "guideway",
        Set("guideway", "zc_mm", 4, 1e300),
        Some("guideway.parquet"),
        Some("zc_mm"),
    ),
    case(
        "gw-nm",
        "guideway",
        Scale("guideway", &["za_mm", "zb_mm", "zc_mm"], 1e6),
        Some("guideway.parquet"),
        None,
    ),
    case(
        "gw-x-metres",
        "guideway",
        Scale("guideway", &["x_mm"], 1e-3),
        Some("guideway.parquet"),
        Some("x_mm"),
    ),
    case(
        "gw-dir",
        "guideway",
        Set("guideway", "dir", 0, 3.0),
        Some("guideway.parquet"),
        Some("dir"),
    ),
    case(
        "gw-n",
        "guideway",
        Set("guideway", "n", 0, -1.0),
        Some("guideway.parquet"),
        Some("n"),
    ),
    case(
        "gw-kelvin",
        "guideway",
        Shift("guideway", "temp_c", 273.15),
        Some("guideway.parquet"),
        Some("temp_c"),
    ),
    case(
        "gw-backwards",
        "guideway",
        Backwards("guideway"),
        Some("guideway.parquet"),
        Some("t_s"),
    ),
    case(
        "gw-drop",
        "guideway",
        Drop("guideway", "x_mm"),
        Some("guideway.parquet"),
        Some("x_mm"),
    ),
    case(
        "gw-null",
        "guideway",
        Null("guideway", "za_mm", 2),
        Some("guideway.parquet"),
        Some("za_mm"),
    ),
    case(
        "gw-garbage",
        "guideway",
        Garbage("guideway"),
        Some("guideway.parquet"),
        None,
    ),
    case("gw-missing", "guideway", Remove("guideway"), None, None),
    case(
        "gw-process-nan",
        "guideway",
        RunToml(
            "probe_spacing_mm = ",
            "probe_spacing_mm = nan\nx_spacing = ",
        ),
        Some("run.toml"),
        Some("process.probe_spacing_mm"),
    ),
    case(
        "gw-section-typo",
        "guideway",
        RunToml("[process]", "[proces]"),
        Some("run.toml"),
        Some("proces"),
    ),
    case(
        "gw-no-id",
        "guideway",
        RunToml("id = ", "idd = "),
        Some("run.toml"),
        Some("run.idd"),
    ),
    case(
        "gw-machine-string",
        "guideway",
        Machine("repeatability_mm = 0.0005", "repeatability_mm = \"0.5 um\""),
        Some(".toml"),
        Some("table.repeatability_mm"),
    ),
    case(
        "gw-machine-key",
        "guideway",
        Machine("repeatability_mm", "repeatabilty_mm"),
        Some(".toml"),
        Some("table.repeatabilty_mm"),
    ),
    case(
        "gw-machine-negative",
        "guideway",
        Machine("repeatability_mm = 0.0005", "repeatability_mm = -0.0005"),
        Some(".toml"),
        Some("table.repeatability_mm"),
    ),
    // gantry: topography + motion
    case(
        "gt-topo-nan",
        "gantry",
        Set("topography", "z_mm", 3, NAN),
        Some("topography.parquet"),
        Some("z_mm"),
    ),
    case(
        "gt-topo-1e300",
        "gantry",
        Set("topography", "z_mm", 3, 1e300),
        Some("topography.parquet"),
        Some("z_mm"),
    ),
    case(
        "gt-topo-um",
        "gantry",
        Scale("topography", &["z_mm"], 1e6),
        Some("topography.parquet"),
        Some("z_mm"),
    ),
    case(
        "gt-topo-text",
        "gantry",
        AsText("topography", "x_mm"),
        Some("topography.parquet"),
        Some("x_mm"),
    ),
    case(
        "gt-topo-empty",
        "gantry",
        Empty("topography"),
        Some("topography.parquet"),
        None,
    ),
    case(
        "gt-motion-inf",
        "gantry",
        Set("motion", "cmd_x_mm", 3, INF),
        Some("motion.parquet"),
        Some("cmd_x_mm"),
    ),
    case(
        "gt-motion-metres",
        "gantry",
        Scale("motion", &["cmd_x_mm", "cmd_y_mm", "cmd_z_mm"], 1e-3),
        Some("motion.parquet"),
        Some("cmd_x_mm"),
    ),
    // (docs/formats.md §5 lists motion as required for gantry, the plugin
    // requires topography only: a missing motion.parquet is not a case.)
    case(
        "gt-topo-null",
        "gantry",
        Null("topography", "y_mm", 2),
        Some("topography.parquet"),
        Some("y_mm"),
    ),
    case(
        "gt-bad-toml",
        "gantry",
        RunToml("[run]", "[run"),
        Some("run.toml"),
        None,
    ),
    // form: profile
    case(
        "fm-degrees",
        "form",
        Scale("profile", &["phi_rad"], DEG),
        Some("profile.parquet"),
        Some("phi_rad"),
    ),
    case(
        "fm-negative-r",
        "form",
        Set("profile", "r_mm", 2, -3.0),
        Some("profile.parquet"),
        Some("r_mm"),
    ),
    case(
        "fm-metres",
        "form",
        Scale("profile", &["r_mm", "wheel_radius_mm"], 1e-3),
        Some("profile.parquet"),
        Some("r_mm"),
    ),
    case(
        "fm-nan",
        "form",
        Set("profile", "phi_rad", 5, NAN),
        Some("profile.parquet"),
        Some("phi_rad"),
    ),
    case(
        "fm-wheel-1e300",
        "form",
        Set("profile", "wheel_radius_mm", 1, 1e300),
        Some("profile.parquet"),
        Some("wheel_radius_mm"),
    ),
    case(
        "fm-drop",
        "form",
        Drop("profile", "r_mm"),
        Some("profile.parquet"),
        Some("r_mm"),
    ),
    case(
        "fm-truncated",
        "form",
        Truncate("profile"),
        Some("profile.parquet"),
        None,
    ),
    case(
        "fm-plugin",
        "form",
        RunToml("plugin = \"form\"", "plugin = \"fomr\""),
        Some("run.toml"),
        Some("run.plugin"),
    ),
    // mill: tracker
    case(
        "ml-nan",
        "mill",
        Set("tracker", "mx_mm", 2, NAN),
        Some("tracker.parquet"),
        Some("mx_mm"),
    ),
    case(
        "ml-1e300",
        "mill",
        Set("tracker", "my_mm", 2, 1e300),
        Some("tracker.parquet"),
        Some("my_mm"),
    ),
    case(
        "ml-metres",
        "mill",
        Scale("tracker", &["x_mm", "y_mm", "z_mm"], 1e-3),
        Some("tracker.parquet"),
        Some("x_mm"),
    ),
    case(
        "ml-point",
        "mill",
        Set("tracker", "point", 1, -4.0),
        Some("tracker.parquet"),
        Some("point"),
    ),
    case(
        "ml-null",
        "mill",
        Null("tracker", "mz_mm", 0),
        Some("tracker.parquet"),
        Some("mz_mm"),
    ),
    case(
        "ml-machine-unknown",
        "mill",
        RunToml("machine = \"xfyz-mill\"", "machine = \"no-such-mill\""),
        Some("run.toml"),
        Some("run.machine"),
    ),
];

fn generate(root: &Path, plugin: &str, extra: &[&str]) {
    let mut args = vec![
        "generate",
        plugin,
        "--runs",
        "2",
        "--seed",
        "3",
        "--out",
        root.to_str().unwrap(),
    ];
    args.extend(extra);
    let g = sparkout(&args);
    assert!(g.status.success(), "{}", String::from_utf8_lossy(&g.stderr));
}

/// The first generated run of a plugin (a run.toml with that plugin).
fn good_run(root: &Path, plugin: &str) -> PathBuf {
    sparkout_pipeline::contracts::discover_runs(root)
        .unwrap()
        .into_iter()
        .find(|d| {
            std::fs::read_to_string(d.join("run.toml"))
                .unwrap()
                .contains(&format!("plugin = \"{plugin}\""))
        })
        .unwrap_or_else(|| panic!("no {plugin} run"))
}

/// Copy a run (hard links: the AE log is large; every mutation replaces a
/// file instead of writing into it).
fn copy_run(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dst = to.join(e.file_name());
        if std::fs::hard_link(e.path(), &dst).is_err() {
            std::fs::copy(e.path(), &dst).unwrap();
        }
    }
}

fn replace_file(path: &Path, bytes: &[u8]) {
    let _ = std::fs::remove_file(path);
    std::fs::write(path, bytes).unwrap();
}

fn write_batch(path: &Path, b: &RecordBatch) {
    let _ = std::fs::remove_file(path);
    write_parquet_atomic(path, b).unwrap();
}

/// The batch with column `name` replaced by `f(old)`.
fn with_column(
    b: &RecordBatch,
    name: &str,
    f: impl Fn(&ArrayRef) -> (DataType, ArrayRef),
) -> RecordBatch {
    let mut fields = Vec::new();
    let mut cols = Vec::new();
    for (fld, c) in b.schema().fields().iter().zip(b.columns()) {
        if fld.name() == name {
            let (t, nc) = f(c);
            fields.push(Field::new(name, t, true));
            cols.push(nc);
        } else {
            fields.push(fld.as_ref().clone());
            cols.push(c.clone());
        }
    }
    RecordBatch::try_new(Arc::new(Schema::new(fields)), cols).unwrap()
}

/// Numeric column → f64 values (None for null).
fn as_f64(c: &ArrayRef) -> Vec<Option<f64>> {
    let a = arrow::compute::cast(c, &DataType::Float64).unwrap();
    let a = a.as_any().downcast_ref::<Float64Array>().unwrap();
    (0..a.len())
        .map(|i| (!a.is_null(i)).then(|| a.value(i)))
        .collect()
}

/// f64 values back to the column's own type.
fn from_f64(t: &DataType, v: Vec<Option<f64>>) -> ArrayRef {
    match t {
        DataType::Float32 => Arc::new(Float32Array::from(
            v.into_iter()
                .map(|x| x.map(|x| x as f32))
                .collect::<Vec<_>>(),
        )),
        DataType::Int32 => Arc::new(Int32Array::from(
            v.into_iter()
                .map(|x| x.map(|x| x as i32))
                .collect::<Vec<_>>(),
        )),
        DataType::Int64 => Arc::new(Int64Array::from(
            v.into_iter()
                .map(|x| x.map(|x| x as i64))
                .collect::<Vec<_>>(),
        )),
        DataType::Int8 => Arc::new(Int8Array::from(
            v.into_iter()
                .map(|x| x.map(|x| x as i8))
                .collect::<Vec<_>>(),
        )),
        _ => Arc::new(Float64Array::from(v)),
    }
}

fn map_values(
    b: &RecordBatch,
    col: &str,
    f: impl Fn(usize, Option<f64>) -> Option<f64>,
) -> RecordBatch {
    with_column(b, col, |c| {
        let v: Vec<Option<f64>> = as_f64(c)
            .into_iter()
            .enumerate()
            .map(|(i, x)| f(i, x))
            .collect();
        (c.data_type().clone(), from_f64(c.data_type(), v))
    })
}

fn table(dir: &Path, t: &str) -> PathBuf {
    dir.join(format!("{t}.parquet"))
}

/// Apply a break to the run at `dir`; `machines` holds machine configs.
fn apply(dir: &Path, machines: &Path, name: &str, brk: Break) {
    let read = |t: &str| read_parquet(&table(dir, t)).unwrap();
    match brk {
        Set(t, col, row, v) => {
            let b = map_values(&read(t), col, |i, x| if i == row { Some(v) } else { x });
            write_batch(&table(dir, t), &b);
        }
        Null(t, col, row) => {
            let b = map_values(&read(t), col, |i, x| if i == row { None } else { x });
            write_batch(&table(dir, t), &b);
        }
        Scale(t, cols, k) => {
            let mut b = read(t);
            for c in cols {
                if b.column_by_name(c).is_some() {
                    b = map_values(&b, c, |_, x| x.map(|x| x * k));
                }
            }
            write_batch(&table(dir, t), &b);
        }
        Shift(t, col, k) => {
            let b = map_values(&read(t), col, |_, x| x.map(|x| x + k));
            write_batch(&table(dir, t), &b);
        }
        Drop(t, col) => {
            let b = read(t);
            let idx = b.schema().index_of(col).unwrap();
            let mut b2 = b.clone();
            b2.remove_column(idx);
            write_batch(&table(dir, t), &b2);
        }
        AsText(t, col) => {
            let b = with_column(&read(t), col, |c| {
                let s: Vec<String> = as_f64(c)
                    .iter()
                    .map(|x| format!("{} mm", x.unwrap_or(0.0)))
                    .collect();
                (DataType::Utf8, Arc::new(StringArray::from(s)) as ArrayRef)
            });
            write_batch(&table(dir, t), &b);
        }
        Empty(t) => {
            let b = read(t);
            write_batch(&table(dir, t), &b.slice(0, 0));
        }
        Truncate(t) => {
            let bytes = std::fs::read(table(dir, t)).unwrap();
            replace_file(&table(dir, t), &bytes[..bytes.len() / 2]);
        }
        Garbage(t) => replace_file(&table(dir, t), b"this is not parquet\n"),
        Backwards(t) => {
            let b = map_values(&read(t), "t_s", |i, x| match i {
                3 => x.map(|v| v + 10.0),
                _ => x,
            });
            write_batch(&table(dir, t), &b);
        }
        IsDir(t) => {
            std::fs::remove_file(table(dir, t)).unwrap();
            std::fs::create_dir_all(table(dir, t).join("part-0")).unwrap();
        }
        Remove(t) => std::fs::remove_file(table(dir, t)).unwrap(),
        RunToml(from, to) => {
            let p = dir.join("run.toml");
            let s = std::fs::read_to_string(&p).unwrap();
            assert!(s.contains(from), "{name}: run.toml lacks `{from}`:\n{s}");
            replace_file(&p, s.replacen(from, to, 1).as_bytes());
        }
        Machine(from, to) => {
            let p = dir.join("run.toml");
            let s = std::fs::read_to_string(&p).unwrap();
            let line = s.lines().find(|l| l.starts_with("machine = ")).unwrap();
            let builtin = line.trim_start_matches("machine = ").trim_matches('"');
            let id = format!("{builtin}-{name}");
            replace_file(
                &p,
                s.replacen(line, &format!("machine = \"{id}\""), 1)
                    .as_bytes(),
            );
            let text = std::fs::read_to_string(format!("configs/machines/{builtin}.toml")).unwrap();
            let edited = if from.is_empty() {
                to.to_string()
            } else {
                assert!(text.contains(from), "{name}: {builtin}.toml lacks `{from}`");
                text.replacen(from, to, 1)
            };
            std::fs::write(machines.join(format!("{id}.toml")), edited).unwrap();
        }
    }
}

/// Every float in every Parquet file and every JSON number under `dir` is
/// finite (serde_json writes a non-finite f64 as null, so a null where the
/// JSON has numbers is checked by the caller's schema; here Parquet).
fn assert_no_non_finite(dir: &Path) {
    for e in walk(dir) {
        if e.extension().is_some_and(|x| x == "parquet") {
            let b = read_parquet(&e).unwrap();
            for (f, c) in b.schema().fields().iter().zip(b.columns()) {
                if !matches!(f.data_type(), DataType::Float64 | DataType::Float32) {
                    continue;
                }
                for (i, v) in as_f64(c).into_iter().enumerate() {
                    if let Some(v) = v {
                        assert!(
                            v.is_finite(),
                            "{}: column {} row {i} is {v}",
                            e.display(),
                            f.name()
                        );
                    }
                }
            }
        }
    }
}

/// Every file under `dir`, recursively, sorted.
pub(crate) fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out.sort();
    out
}

#[test]
fn every_bad_input_is_rejected_by_run_and_validate_input_alike() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("runs");
    let machines = tmp.path().join("machines");
    std::fs::create_dir_all(&machines).unwrap();
    generate(&root, "robot", &["--ae-rate-hz", "200000"]);
    for p in ["guideway", "gantry", "form", "mill"] {
        generate(&root, p, &[]);
    }
    // The good run of each plugin, picked before any case directory exists
    // (a case directory would sort before it).
    let goods: Vec<(&str, PathBuf)> = ["robot", "guideway", "gantry", "form", "mill"]
        .into_iter()
        .map(|p| (p, good_run(&root, p)))
        .collect();
    let good_of =
        |plugin: &str| -> PathBuf { goods.iter().find(|(p, _)| *p == plugin).unwrap().1.clone() };
    let mut broken = BTreeSet::new();
    for c in CASES {
        let good = good_of(c.plugin);
        let dir = good.with_file_name(c.name);
        copy_run(&good, &dir);
        let toml = dir.join("run.toml");
        let s = std::fs::read_to_string(&toml).unwrap();
        let id_line = s.lines().find(|l| l.starts_with("id = ")).unwrap();
        replace_file(
            &toml,
            s.replacen(id_line, &format!("id = \"{}\"", c.name), 1)
                .as_bytes(),
        );
        apply(&dir, &machines, c.name, c.brk);
        broken.insert(dir.display().to_string());
    }
    assert!(CASES.len() >= 60, "{} kinds", CASES.len());

    let out = tmp.path().join("out");
    let r = sparkout(&[
        "run",
        "--input",
        root.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--machines",
        machines.to_str().unwrap(),
    ]);
    let report = format!(
        "{}\n{}",
        String::from_utf8_lossy(&r.stdout),
        String::from_utf8_lossy(&r.stderr)
    );
    assert_eq!(r.status.code(), Some(2), "{report}");
    let failures: Vec<serde_json::Value> =
        serde_json::from_slice(&std::fs::read(out.join("failures.json")).unwrap()).unwrap();
    let rejected: BTreeSet<String> = failures
        .iter()
        .map(|f| f["run_dir"].as_str().unwrap().to_string())
        .collect();
    let mut wrong = Vec::new();
    for c in CASES {
        let dir = good_of(c.plugin).with_file_name(c.name);
        let Some(f) = failures
            .iter()
            .find(|f| f["run_dir"].as_str() == dir.to_str())
        else {
            wrong.push(format!("{}: accepted", c.name));
            continue;
        };
        if let Some(file) = c.file {
            let got = f["file"].as_str().unwrap_or("");
            if !got.ends_with(file) {
                wrong.push(format!(
                    "{}: file `{got}`, expected …{file}: {}",
                    c.name, f["error"]
                ));
            }
        }
        if let Some(col) = c.column {
            if f["column"].as_str() != Some(col) {
                wrong.push(format!(
                    "{}: column {}, expected {col}: {}",
                    c.name, f["column"], f["error"]
                ));
            }
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
    assert_eq!(rejected, broken, "only the broken runs are rejected");
    assert_no_non_finite(&out);

    // validate-input: the same verdict on every directory.
    let v = sparkout(&[
        "validate-input",
        root.to_str().unwrap(),
        "--machines",
        machines.to_str().unwrap(),
    ]);
    assert_eq!(v.status.code(), Some(2));
    let stdout = String::from_utf8_lossy(&v.stdout);
    let all_dirs: Vec<String> = sparkout_pipeline::contracts::discover_runs(&root)
        .unwrap()
        .iter()
        .map(|d| d.display().to_string())
        .collect();
    let flagged: BTreeSet<String> = stdout
        .lines()
        .filter_map(|l| {
            all_dirs
                .iter()
                .find(|d| l.starts_with(&format!("{d}:")))
                .cloned()
        })
        .collect();
    assert_eq!(
        flagged, rejected,
        "validate-input and run disagree:\n{stdout}"
    );
}

/// observations.parquet: the diagnosis input refuses what would make its
/// summary non-finite or wrong.
#[test]
fn bad_observation_tables_are_rejected() {
    let tmp = tempfile::tempdir().unwrap();
    let good = tmp.path().join("obs.parquet");
    let g = sparkout(&[
        "generate",
        "observations",
        "--runs",
        "4",
        "--seed",
        "2",
        "--out",
        good.to_str().unwrap(),
    ]);
    assert!(g.status.success());
    let b = read_parquet(&good).unwrap();
    let covariate = b
        .schema()
        .fields()
        .iter()
        .map(|f| f.name().clone())
        .find(|n| n.ends_with("_mm") || n == "t_s")
        .expect("a covariate");
    let cases: Vec<(&str, RecordBatch, &str)> = vec![
        (
            "real-1e300",
            map_values(&b, "real", |i, x| if i == 3 { Some(1e300) } else { x }),
            "real",
        ),
        (
            "sim-nan",
            map_values(&b, "sim", |i, x| if i == 1 { Some(f64::NAN) } else { x }),
            "sim",
        ),
        (
            "real-inf",
            map_values(
                &b,
                "real",
                |i, x| if i == 1 { Some(f64::INFINITY) } else { x },
            ),
            "real",
        ),
        (
            "real-um",
            map_values(&b, "real", |_, x| x.map(|v| v * 1e6 + 2e4)),
            "real",
        ),
        (
            "cov-nan",
            map_values(
                &b,
                &covariate,
                |i, x| if i == 2 { Some(f64::NAN) } else { x },
            ),
            covariate.as_str(),
        ),
        (
            "cov-inf",
            map_values(&b, &covariate, |i, x| {
                if i == 2 {
                    Some(f64::NEG_INFINITY)
                } else {
                    x
                }
            }),
            covariate.as_str(),
        ),
    ];
    for (name, batch, col) in cases {
        let p = tmp.path().join(format!("{name}.parquet"));
        write_batch(&p, &batch);
        let o = sparkout(&[
            "diagnose",
            p.to_str().unwrap(),
            "--out",
            tmp.path().join(name).to_str().unwrap(),
        ]);
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{name} accepted");
        assert!(e.contains(&format!("column `{col}`")), "{name}: {e}");
    }
}

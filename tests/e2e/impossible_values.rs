//! Impossible values are refused, unbounded inputs bounded: a run.toml
//! `[process]` value outside its documented range (or of the wrong type), a
//! machine-config number outside its range, a table below its plugin's
//! minimum size and NaN in an optional column reject the run naming the
//! file and the column — `run` and `validate-input` alike; run-less stage
//! flags are checked the same way; CLI numbers that size work have upper
//! bounds, and work predicted to be too large needs `--force-size`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use arrow::array::{ArrayRef, Float64Array};
use arrow::datatypes::{DataType, Field, Schema};
use arrow::record_batch::RecordBatch;
use sparkout_pipeline::contracts::{discover_runs, read_parquet, write_parquet_atomic};

use crate::common::sparkout;

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// How a case breaks a good run.
enum Break {
    /// Set run.toml `[process] key = value` (the key's line replaced).
    Process(&'static str, &'static str),
    /// Keep only the first `n` rows of a table.
    Rows(&'static str, usize),
    /// NaN at row 1 of a float column.
    Nan(&'static str, &'static str),
    /// A machine config of its own: the built-in one with `from` replaced.
    Machine(&'static str, &'static str),
}

struct Case {
    name: &'static str,
    plugin: &'static str,
    brk: Break,
    /// The failure's file ends with this, its column is this.
    file: &'static str,
    column: Option<&'static str>,
}

const CASES: &[Case] = &[
    Case {
        name: "form-negative-stock",
        plugin: "form",
        brk: Break::Process("stock_mm", "-0.05"),
        file: "run.toml",
        column: Some("process.stock_mm"),
    },
    Case {
        name: "form-stock-as-text",
        plugin: "form",
        brk: Break::Process("stock_mm", "\"0.05 mm\""),
        file: "run.toml",
        column: Some("process.stock_mm"),
    },
    Case {
        name: "form-negative-wheel",
        plugin: "form",
        brk: Break::Process("wheel_radius_mm", "-150"),
        file: "run.toml",
        column: Some("process.wheel_radius_mm"),
    },
    Case {
        name: "gw-negative-infeed",
        plugin: "guideway",
        brk: Break::Process("infeed_mm", "-0.005"),
        file: "run.toml",
        column: Some("process.infeed_mm"),
    },
    Case {
        name: "mill-negative-period",
        plugin: "mill",
        brk: Break::Process("point_period_s", "-10"),
        file: "run.toml",
        column: Some("process.point_period_s"),
    },
    Case {
        name: "robot-zero-feed",
        plugin: "robot",
        brk: Break::Process("feed_mm_s", "0"),
        file: "run.toml",
        column: Some("process.feed_mm_s"),
    },
    Case {
        name: "robot-negative-doc",
        plugin: "robot",
        brk: Break::Process("doc_rough_mm", "-0.3"),
        file: "run.toml",
        column: Some("process.doc_rough_mm"),
    },
    Case {
        name: "robot-half-passes",
        plugin: "robot",
        brk: Break::Process("rough_passes", "7.5"),
        file: "run.toml",
        column: Some("process.rough_passes"),
    },
    Case {
        name: "servo-one-row",
        plugin: "servo",
        brk: Break::Rows("motion", 1),
        file: "motion.parquet",
        column: None,
    },
    Case {
        name: "gantry-nan-feed",
        plugin: "gantry",
        brk: Break::Nan("motion", "feed_mm_s"),
        file: "motion.parquet",
        column: Some("feed_mm_s"),
    },
    Case {
        name: "gw-zero-spacing",
        plugin: "guideway",
        brk: Break::Machine("spacing_mm = ", "spacing_mm = 0.0 #"),
        file: ".toml",
        column: Some("probes.spacing_mm"),
    },
];

fn generate(root: &Path, plugin: &str, extra: &[&str]) {
    let mut args = vec![
        "generate",
        plugin,
        "--runs",
        "2",
        "--seed",
        "5",
        "--out",
        root.to_str().unwrap(),
    ];
    args.extend(extra);
    let g = sparkout(&args);
    assert!(g.status.success(), "{}", text(&g.stderr));
}

/// Copy a run directory (hard links: every break replaces a file).
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

/// Replace the first line starting with `prefix` by `line`.
fn edit_line(path: &Path, prefix: &str, line: &str) {
    let s = std::fs::read_to_string(path).unwrap();
    let old = s
        .lines()
        .find(|l| l.starts_with(prefix))
        .unwrap_or_else(|| panic!("{} has no line `{prefix}`:\n{s}", path.display()));
    let new = s.replacen(old, line, 1);
    std::fs::remove_file(path).unwrap(); // a hard link: never write through it
    std::fs::write(path, new).unwrap();
}

fn replace_table(path: &Path, b: &RecordBatch) {
    std::fs::remove_file(path).unwrap();
    write_parquet_atomic(path, b).unwrap();
}

fn apply(dir: &Path, machines: &Path, case: &Case) {
    match case.brk {
        Break::Process(key, value) => edit_line(
            &dir.join("run.toml"),
            &format!("{key} = "),
            &format!("{key} = {value}"),
        ),
        Break::Rows(table, n) => {
            let p = dir.join(format!("{table}.parquet"));
            let b = read_parquet(&p).unwrap();
            replace_table(&p, &b.slice(0, n));
        }
        Break::Nan(table, col) => {
            let p = dir.join(format!("{table}.parquet"));
            let b = read_parquet(&p).unwrap();
            let i = b.schema().index_of(col).unwrap();
            let mut v: Vec<f64> = b
                .column(i)
                .as_any()
                .downcast_ref::<Float64Array>()
                .unwrap()
                .values()
                .to_vec();
            v[1] = f64::NAN;
            let mut cols: Vec<ArrayRef> = b.columns().to_vec();
            cols[i] = std::sync::Arc::new(Float64Array::from(v));
            let fields: Vec<Field> = b
                .schema()
                .fields()
                .iter()
                .map(|f| {
                    Field::new(f.name(), f.data_type().clone(), true)
                        .with_metadata(f.metadata().clone())
                })
                .collect();
            assert_eq!(fields[i].data_type(), &DataType::Float64);
            let b = RecordBatch::try_new(std::sync::Arc::new(Schema::new(fields)), cols).unwrap();
            replace_table(&p, &b);
        }
        Break::Machine(from, to) => {
            let toml = dir.join("run.toml");
            let s = std::fs::read_to_string(&toml).unwrap();
            let line = s.lines().find(|l| l.starts_with("machine = ")).unwrap();
            let builtin = line.trim_start_matches("machine = ").trim_matches('"');
            let id = format!("{builtin}-{}", case.name);
            edit_line(&toml, "machine = ", &format!("machine = \"{id}\""));
            let text = std::fs::read_to_string(format!("configs/machines/{builtin}.toml")).unwrap();
            assert!(text.contains(from), "{builtin}.toml lacks `{from}`");
            std::fs::write(
                machines.join(format!("{id}.toml")),
                text.replacen(from, to, 1),
            )
            .unwrap();
        }
    }
}

#[test]
fn impossible_values_are_refused_by_run_and_validate_input_alike() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("runs");
    let machines = tmp.path().join("machines");
    std::fs::create_dir_all(&machines).unwrap();
    generate(&root, "robot", &["--ae-rate-hz", "200000"]);
    for p in ["guideway", "gantry", "form", "mill", "servo"] {
        generate(&root, p, &[]);
    }
    let mut goods: BTreeMap<&str, PathBuf> = BTreeMap::new();
    for d in discover_runs(&root).unwrap() {
        let s = std::fs::read_to_string(d.join("run.toml")).unwrap();
        for p in ["robot", "guideway", "gantry", "form", "mill", "servo"] {
            if s.contains(&format!("plugin = \"{p}\"")) {
                goods.entry(p).or_insert(d.clone());
            }
        }
    }
    let mut broken = Vec::new();
    for c in CASES {
        let good = &goods[c.plugin];
        let dir = good.with_file_name(c.name);
        copy_run(good, &dir);
        edit_line(
            &dir.join("run.toml"),
            "id = ",
            &format!("id = \"{}\"", c.name),
        );
        apply(&dir, &machines, c);
        broken.push(dir);
    }

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
    let report = format!("{}{}", text(&r.stdout), text(&r.stderr));
    assert_eq!(r.status.code(), Some(2), "{report}");
    let failures: Vec<serde_json::Value> =
        serde_json::from_slice(&std::fs::read(out.join("failures.json")).unwrap()).unwrap();
    let mut wrong = Vec::new();
    for (c, dir) in CASES.iter().zip(&broken) {
        let Some(f) = failures
            .iter()
            .find(|f| f["run_dir"].as_str() == dir.to_str())
        else {
            wrong.push(format!("{}: accepted", c.name));
            continue;
        };
        let file = f["file"].as_str().unwrap_or("");
        if !file.ends_with(c.file) {
            wrong.push(format!(
                "{}: file `{file}`, expected …{}: {}",
                c.name, c.file, f["error"]
            ));
        }
        if c.column.is_some() && f["column"].as_str() != c.column {
            wrong.push(format!(
                "{}: column {}, expected {:?}: {}",
                c.name, f["column"], c.column, f["error"]
            ));
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
    assert_eq!(
        failures.len(),
        CASES.len(),
        "only the broken runs fail: {failures:#?}"
    );

    // validate-input flags exactly the same directories.
    let v = sparkout(&[
        "validate-input",
        root.to_str().unwrap(),
        "--machines",
        machines.to_str().unwrap(),
    ]);
    assert_eq!(v.status.code(), Some(2));
    let stdout = text(&v.stdout);
    for (c, dir) in CASES.iter().zip(&broken) {
        assert!(
            stdout.contains(&format!("{}:", dir.display())),
            "{}: not flagged by validate-input:\n{stdout}",
            c.name
        );
    }
    for good in goods.values() {
        assert!(
            !stdout.contains(&format!("{}:", good.display())),
            "a good run flagged:\n{stdout}"
        );
    }
}

#[test]
fn run_less_stage_flags_are_checked_like_config_keys() {
    let base = [
        "stage",
        "cycle",
        "--rough",
        "7",
        "--finish",
        "2",
        "--spark",
        "2",
        "--doc-rough",
        "0.3",
        "--doc-finish",
        "0.1",
        "--first-cut",
        "0.2",
        "--json",
    ];
    let ok = sparkout(&[&base[..], &["--weld-mm", "2.27"]].concat());
    assert!(ok.status.success(), "{}", text(&ok.stderr));
    for (flag, value, want) in [
        ("--weld-mm", "-2", "--weld-mm must be a number > 0, got -2"),
        (
            "--weld-mm",
            "lots",
            "--weld-mm must be a number > 0, got lots",
        ),
        (
            "--rough",
            "4000000000",
            "--rough must be a whole number in 0..=100000, got 4000000000",
        ),
    ] {
        let mut args: Vec<&str> = base.to_vec();
        if let Some(i) = args.iter().position(|a| *a == flag) {
            args[i + 1] = value;
        } else {
            args.extend([flag, value]);
        }
        let t = std::time::Instant::now();
        let o = sparkout(&args);
        assert_eq!(o.status.code(), Some(1), "{flag} {value}");
        let e = text(&o.stderr);
        assert!(e.contains(want), "{flag} {value}: {e}");
        assert!(t.elapsed().as_secs() < 30, "refused up front");
    }
}

#[test]
fn numbers_that_size_work_are_bounded_and_large_work_needs_force_size() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("fleet");
    let o = sparkout(&[
        "generate",
        "robot",
        "--runs",
        "1",
        "--ae-rate-hz",
        "1e12",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(text(&o.stderr).contains("1e12"), "{}", text(&o.stderr));
    assert!(!out.exists(), "nothing written");
    for (flag, value) in [("--runs", "100001"), ("--runs", "0")] {
        let o = sparkout(&[
            "generate",
            "gantry",
            flag,
            value,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert_eq!(o.status.code(), Some(1), "{flag} {value}");
        assert!(!out.exists());
    }
    // Inside every bound, and still too large: 10^5 runs at 10 MHz.
    let big = [
        "generate",
        "robot",
        "--runs",
        "100000",
        "--ae-rate-hz",
        "1e7",
        "--out",
        out.to_str().unwrap(),
    ];
    let o = sparkout(&big);
    assert_eq!(o.status.code(), Some(1));
    let e = text(&o.stderr);
    assert!(e.contains("GB") && e.contains("--force-size"), "{e}");
    assert!(!out.exists(), "nothing written");
    // The bounds are stated in --help.
    let h = text(&sparkout(&["generate", "--help"]).stdout);
    assert!(
        h.contains("100000") && h.contains("10 MHz") && h.contains("--force-size"),
        "{h}"
    );
    let h = text(&sparkout(&["diagnose", "--help"]).stdout);
    assert!(h.contains("2 to 1000"), "{h}");
    let h = text(&sparkout(&["stage", "--help"]).stdout);
    assert!(h.contains("0 to 100000 passes"), "{h}");
}

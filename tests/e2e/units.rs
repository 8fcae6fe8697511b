//! Units as data (docs/formats.md "Units"): a surface table whose columns
//! state their units (name suffix, Parquet field metadata, per-axis flags)
//! is read in those units, a conflict or an unknowable unit is refused, a
//! result no sample could give is an error; observations in nm are judged
//! and diagnosed as nm and their gaps printed in nm. The test tables are
//! written by pyarrow and the expected flatness is numpy's least squares.

use std::path::Path;
use std::process::Command;
use std::sync::Arc;

use arrow::array::{ArrayRef, Float64Array, RecordBatch, StringArray};
use arrow::datatypes::{DataType, Field, Schema};
use sparkout_datasets::observations::{generate, write_parquet, ObsFleetConfig};
use sparkout_pipeline::EffectSpec;

use crate::common::sparkout;

/// The surfaces: a 0.69 × 0.49 mm interferometer patch on a 10 µm lattice
/// (x, y in µm), heights in nm: a tilt, a 50 nm bow along x and a 5 nm
/// ripple along y. Written as `x_um/y_um/z_nm` (units by suffix), as
/// `x/y/z` with field metadata `unit`, as plain `x/y/z`, as a 1-D profile
/// and as `x_um/y_um/h` (no z by name). Prints numpy's least-squares
/// flatness in mm (the peak-to-valley of the residuals from the
/// least-squares plane; for this surface ≈ 59.76 nm).
const MAKE: &str = r#"
import json, sys
import numpy as np, pyarrow as pa, pyarrow.parquet as pq
d = sys.argv[1]
xs = np.arange(0, 700.0, 10.0); ys = np.arange(0, 500.0, 10.0)
X, Y = np.meshgrid(xs, ys); x = X.ravel(); y = Y.ravel()
z = 0.02 * x - 0.01 * y + 50 * ((x - 350) / 350) ** 2 + 5 * np.sin(y / 40)
pq.write_table(pa.table({"x_um": x, "y_um": y, "z_nm": z}), d + "/pts.parquet")
pq.write_table(pa.table({"x_um": x, "y_um": y, "z_um": z / 1e3}), d + "/pts_um.parquet")
meta = pa.schema([pa.field("x", pa.float64(), metadata={"unit": "um"}),
                  pa.field("y", pa.float64(), metadata={"unit": "um"}),
                  pa.field("z", pa.float64(), metadata={"unit": "um"})])
pq.write_table(pa.table({"x": x, "y": y, "z": z / 1e3}, schema=meta), d + "/pts_meta.parquet")
pq.write_table(pa.table({"x": x, "y": y, "z": z}), d + "/pts_plain.parquet")
pq.write_table(pa.table({"x_um": x, "y_um": y, "z_mm": z}), d + "/pts_wrong.parquet")
pq.write_table(pa.table({"x_um": xs, "z_nm": 50 * ((xs - 350) / 350) ** 2}), d + "/profile.parquet")
pq.write_table(pa.table({"x_um": x, "y_um": y, "h": z}), d + "/no_z.parquet")
A = np.c_[x, y, np.ones_like(x)]
c, *_ = np.linalg.lstsq(A, z, rcond=None)
r = z - A @ c
print(json.dumps({"least_squares_mm": float(r.max() - r.min()) / 1e6, "n": int(len(x))}))
"#;

/// The test files and numpy's answer; `None` (test skipped, said on
/// stderr) without python3, numpy and pyarrow.
fn surfaces(dir: &Path) -> Option<serde_json::Value> {
    let o = Command::new("python3")
        .args(["-c", MAKE, dir.to_str().unwrap()])
        .output()
        .ok()?;
    if !o.status.success() {
        eprintln!(
            "SKIPPED: python3 with numpy and pyarrow is needed: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        return None;
    }
    Some(serde_json::from_slice(&o.stdout).unwrap())
}

fn flatness(dir: &Path, file: &str, extra: &[&str]) -> std::process::Output {
    let f = dir.join(file);
    let mut args = vec!["stage", "flatness", "--surface", f.to_str().unwrap()];
    args.extend(extra);
    args.push("--json");
    sparkout(&args)
}

fn ok(o: &std::process::Output) -> serde_json::Value {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

fn err(o: &std::process::Output) -> String {
    assert!(
        !o.status.success(),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn same_flatness(got: &serde_json::Value, want: &serde_json::Value) {
    let (g, w) = (
        got["least_squares_mm"].as_f64().unwrap(),
        want["least_squares_mm"].as_f64().unwrap(),
    );
    // ≈ 5.976e-5 mm; the two least-squares solutions agree to rounding.
    assert!((g - w).abs() < 1e-9 * w, "{g} vs numpy {w}");
    assert!((w - 5.9757e-5).abs() < 1e-8, "numpy: {w}");
    assert_eq!(got["n"], want["n"], "one point per row");
    assert!(got["min_zone_mm"].as_f64().unwrap() <= g + 1e-15);
}

#[test]
fn a_point_table_in_um_and_nm_is_read_by_its_suffixes_flags_or_metadata() {
    let d = tempfile::tempdir().unwrap();
    let Some(want) = surfaces(d.path()) else {
        return;
    };
    // Without flags: the suffixes say µm and nm (before: a gridded map of
    // 3 × 3500 "points" and a flatness of metres).
    same_flatness(&ok(&flatness(d.path(), "pts.parquet", &[])), &want);
    // Flags that agree with the suffixes change nothing.
    same_flatness(
        &ok(&flatness(
            d.path(),
            "pts.parquet",
            &["--x-unit", "um", "--y-unit", "µm", "--z-unit", "nm"],
        )),
        &want,
    );
    // Field metadata `unit`.
    same_flatness(&ok(&flatness(d.path(), "pts_meta.parquet", &[])), &want);
    // Plain names: the flags state the units.
    same_flatness(
        &ok(&flatness(
            d.path(),
            "pts_plain.parquet",
            &["--x-unit", "um", "--y-unit", "um", "--z-unit", "nm"],
        )),
        &want,
    );
}

#[test]
fn conflicting_or_unknowable_units_are_refused() {
    let d = tempfile::tempdir().unwrap();
    if surfaces(d.path()).is_none() {
        return;
    }
    // The deprecated scale says µm, the column says nm: before, 1.363 "mm".
    let e = err(&flatness(
        d.path(),
        "pts.parquet",
        &[
            "--x",
            "x_um",
            "--y",
            "y_um",
            "--z",
            "z_nm",
            "--unit-scale",
            "0.001",
        ],
    ));
    assert!(
        e.contains("pts.parquet") && e.contains("`z_nm`") && e.contains("nm") && e.contains("um"),
        "{e}"
    );
    // A flag against a suffix.
    let e = err(&flatness(d.path(), "pts_um.parquet", &["--z-unit", "nm"]));
    assert!(
        e.contains("`z_um`") && e.contains("command-line flag") && e.contains("suffix"),
        "{e}"
    );
    // The deprecated scale together with a per-axis unit.
    let e = err(&flatness(
        d.path(),
        "pts_plain.parquet",
        &["--z-unit", "nm", "--unit-scale", "0.001"],
    ));
    assert!(e.contains("--unit-scale") && e.contains("--z-unit"), "{e}");
    // Positions in µm, heights of no stated unit: refused naming the flag.
    let e = err(&flatness(
        d.path(),
        "pts_plain.parquet",
        &["--x-unit", "um", "--y-unit", "um"],
    ));
    assert!(e.contains("`z`") && e.contains("--z-unit"), "{e}");
    // A unit sparkout does not convert.
    let e = err(&flatness(
        d.path(),
        "pts_plain.parquet",
        &["--z-unit", "inch"],
    ));
    assert!(e.contains("inch"), "{e}");
}

#[test]
fn profiles_ambiguous_tables_and_impossible_results_are_refused() {
    let d = tempfile::tempdir().unwrap();
    if surfaces(d.path()).is_none() {
        return;
    }
    let e = err(&flatness(d.path(), "profile.parquet", &[]));
    assert!(
        e.contains("1-D profile")
            && e.contains("`x_um`")
            && e.contains("`z_nm`")
            && e.contains("sparkout stage profile --profile"),
        "{e}"
    );
    let e = err(&flatness(d.path(), "no_z.parquet", &[]));
    assert!(
        e.contains("ambiguous") && e.contains("`h`") && e.contains("--z COL"),
        "{e}"
    );
    // Heights in nm labelled mm on a 0.69 mm sample: 60 "mm" of height.
    let e = err(&flatness(d.path(), "pts_wrong.parquet", &[]));
    assert!(
        e.contains("impossible") && e.contains("--z-unit") && e.contains("0.690 mm"),
        "{e}"
    );
}

/// A generated fleet whose sim and real are rescaled by `f` and labelled
/// `unit`.
fn fleet_in(unit: &str, f: f64) -> RecordBatch {
    let cfg = ObsFleetConfig {
        runs: 6,
        seed: 31,
        ..Default::default()
    };
    let e: Vec<EffectSpec> = vec!["lag:feed_mm_s=k=0.005".parse().unwrap()];
    let b = generate(&cfg, &e).unwrap();
    let s = b.schema();
    let mut fields: Vec<Field> = s.fields().iter().map(|f| f.as_ref().clone()).collect();
    let mut cols: Vec<ArrayRef> = b.columns().to_vec();
    for name in ["sim", "real"] {
        let i = s.index_of(name).unwrap();
        let v = b.column(i).as_any().downcast_ref::<Float64Array>().unwrap();
        cols[i] = Arc::new(Float64Array::from_iter_values(
            v.values().iter().map(|x| x * f),
        ));
    }
    fields.push(Field::new("unit", DataType::Utf8, true));
    cols.push(Arc::new(StringArray::from(vec![unit; b.num_rows()])));
    RecordBatch::try_new(Arc::new(Schema::new(fields)), cols).unwrap()
}

#[test]
fn observations_in_nm_are_judged_as_nm_and_their_gaps_printed_in_nm() {
    let d = tempfile::tempdir().unwrap();
    // The generator's numbers (gap ≈ 0.1, noise 0.001) taken as tens of
    // nanometres: × 100, unit nm. The same table in mm is the reference.
    let nm = d.path().join("nm.parquet");
    let mm = d.path().join("mm.parquet");
    write_parquet(&fleet_in("nm", 100.0), &nm).unwrap();
    write_parquet(&fleet_in("mm", 1e-4), &mm).unwrap();
    let run = |obs: &Path, out: &str, json: bool| {
        let out = d.path().join(out);
        let mut args = vec![
            "diagnose",
            obs.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        if json {
            args.push("--json");
        }
        let o = sparkout(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        o
    };
    let a: serde_json::Value = serde_json::from_slice(&run(&nm, "a", true).stdout).unwrap();
    let b: serde_json::Value = serde_json::from_slice(&run(&mm, "b", true).stdout).unwrap();
    // Converted at the edge: the diagnosis runs in mm either way.
    let (ga, gb) = (
        a["gap"]["rms_mm"].as_f64().unwrap(),
        b["gap"]["rms_mm"].as_f64().unwrap(),
    );
    assert!(ga > 0.0 && (ga - gb).abs() <= 1e-12 * gb, "{ga} vs {gb}");
    assert_eq!(a["selected"], b["selected"]);
    assert_eq!(a["selected"][0], "lag:feed_mm_s", "{}", a["selected"]);
    assert_eq!(a["per_observable"][0]["unit"], "mm");
    // Every parameter carries its canonical unit: a lag is a time.
    let lag = a["effects"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["selected"] == true)
        .unwrap();
    assert_eq!(lag["param_units"]["k"], "s", "{lag}");
    assert_eq!(lag["param_units"]["offset_mm"], "mm", "{lag}");
    // k = 0.005 nm per mm/s × 100 = 0.5 nm/(mm/s) = 0.5 µs.
    let k = lag["params"]["k"].as_f64().unwrap();
    assert!((k - 5e-7).abs() < 0.05 * 5e-7, "k = {k} s");
    // Printed in nm, the lag in µs.
    let text = String::from_utf8_lossy(&run(&nm, "c", false).stdout).into_owned();
    let first = text
        .lines()
        .find(|l| l.starts_with("gap RMS "))
        .unwrap_or_default();
    assert!(
        first.starts_with("gap RMS ")
            && first.contains(" nm, noise floor ")
            && !first.contains(" mm,"),
        "{text}"
    );
    assert!(text.contains("k = 0.") && text.contains(" µs"), "{text}");
    // Judged in its own unit: 2 m in nm is implausible, and said so in nm.
    let mut big = fleet_in("nm", 100.0);
    let i = big.schema().index_of("real").unwrap();
    let mut cols: Vec<ArrayRef> = big.columns().to_vec();
    let mut v: Vec<f64> = big
        .column(i)
        .as_any()
        .downcast_ref::<Float64Array>()
        .unwrap()
        .values()
        .to_vec();
    v[3] = 2e13;
    cols[i] = Arc::new(Float64Array::from(v));
    big = RecordBatch::try_new(big.schema(), cols).unwrap();
    let bad = d.path().join("bad.parquet");
    write_parquet(&big, &bad).unwrap();
    let o = sparkout(&[
        "diagnose",
        bad.to_str().unwrap(),
        "--out",
        d.path().join("e").to_str().unwrap(),
    ]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && e.contains("`real`") && e.contains("row 3") && e.contains(" nm"),
        "{e}"
    );
}

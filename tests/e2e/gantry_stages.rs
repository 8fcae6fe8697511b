//! Through the binary: the gantry stages on a generated run (with
//! --run and run-less), the compensation path for replay, and every bad
//! input the plugin documents rejected with a clear error while the batch goes
//! on.

use crate::common;
use common::sparkout;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow::array::{Array, Float64Array, StringArray};
use arrow::datatypes::{DataType, Field, Schema};
use arrow::record_batch::RecordBatch;

fn generate(root: &Path, runs: &str, seed: &str) -> PathBuf {
    let g = sparkout(&[
        "generate",
        "gantry",
        "--runs",
        runs,
        "--seed",
        seed,
        "--out",
        root.to_str().unwrap(),
    ]);
    assert!(g.status.success(), "{}", String::from_utf8_lossy(&g.stderr));
    root.join("aplm-gantry")
}

fn read_batch(p: &Path) -> RecordBatch {
    let f = std::fs::File::open(p).unwrap();
    let r = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(f)
        .unwrap()
        .build()
        .unwrap();
    let batches: Vec<RecordBatch> = r.map(|b| b.unwrap()).collect();
    arrow::compute::concat_batches(&batches[0].schema(), &batches).unwrap()
}

fn col<'a>(b: &'a RecordBatch, n: &str) -> &'a [f64] {
    b.column_by_name(n)
        .unwrap()
        .as_any()
        .downcast_ref::<Float64Array>()
        .unwrap()
        .values()
}

fn json_of(out: &std::process::Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn stages_on_a_generated_run() {
    let d = tempfile::tempdir().unwrap();
    let fleet = generate(&d.path().join("runs"), "1", "3");
    let run = fleet.join("r0000");
    let run_s = run.to_str().unwrap();

    // flatness: default = last state; --state maps to gantry.flatness.state.
    let f = json_of(&sparkout(&["stage", "flatness", "--run", run_s, "--json"]));
    assert_eq!(f["state"], "after_polish");
    let (ls, mz) = (
        f["least_squares_mm"].as_f64().unwrap(),
        f["min_zone_mm"].as_f64().unwrap(),
    );
    assert!(mz > 0.0 && mz <= ls + 1e-12, "{f}");
    assert_eq!(f["plane"].as_array().unwrap().len(), 3);
    let f2 = json_of(&sparkout(&[
        "stage",
        "flatness",
        "--run",
        run_s,
        "--state",
        "after_grind",
        "--json",
    ]));
    assert_eq!(f2["state"], "after_grind");
    let bad = sparkout(&["stage", "flatness", "--run", run_s, "--colour", "red"]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("unknown key `colour`"));

    // Run-less forms.
    let topo = run.join("topography.parquet");
    let f3 = json_of(&sparkout(&[
        "stage",
        "flatness",
        "--topography",
        topo.to_str().unwrap(),
        "--state",
        "pattern",
        "--json",
    ]));
    assert_eq!(f3["state"], "pattern");
    let p = json_of(&sparkout(&[
        "stage",
        "polish_plan",
        "--topography",
        topo.to_str().unwrap(),
        "--tolerance-mm",
        "0.005",
        "--json",
    ]));
    for k in [
        "placements",
        "selective_s",
        "raster_s",
        "ratio",
        "breakeven_area_fraction",
    ] {
        assert!(!p[k].is_null(), "{k} missing: {p}");
    }
    assert!(p["placements"].as_u64().unwrap() >= 1);
    assert_eq!(p["verdict"], "flatter", "{p}");
    let be = p["breakeven_area_fraction"].as_f64().unwrap();
    assert!(be > 0.0 && be <= 1.0, "{p}");

    let mr = json_of(&sparkout(&[
        "stage",
        "matrices",
        "--topography",
        topo.to_str().unwrap(),
        "--json",
    ]));
    assert!(mr["gamma_static_max_mm"].as_f64().unwrap() > 0.01, "{mr}");
    assert!(mr["cut_force_n"].as_f64().unwrap() > 0.0, "{mr}");

    // matrices with --out: Γ grids, controller table, compensation path.
    let out = d.path().join("m");
    let m = sparkout(&[
        "stage",
        "matrices",
        "--run",
        run_s,
        "--out",
        out.to_str().unwrap(),
        "--json",
    ]);
    let s = json_of(&m);
    assert!(s["gamma_static_max_mm"].as_f64().unwrap() > 0.01, "{s}");
    let st = read_batch(&out.join("static_matrix.parquet"));
    let dy = read_batch(&out.join("dynamic_matrix.parquet"));
    for b in [&st, &dy] {
        let (v, t, p0) = (col(b, "value_mm"), col(b, "tau_mm"), col(b, "pattern_mm"));
        let (s1, s2, br) = (
            col(b, "stringer1_mm"),
            col(b, "stringer2_mm"),
            col(b, "bridge_mm"),
        );
        for k in 0..v.len() {
            assert!((v[k] - (t[k] - p0[k])).abs() < 1e-12);
            assert!((t[k] - (s1[k] + s2[k] + br[k])).abs() < 1e-12);
        }
    }
    assert!(out.join("compensation_table.parquet").is_file());
    let cp = read_batch(&out.join("compensation_path.parquet"));
    let t = col(&cp, "t_s");
    assert!(t.windows(2).all(|w| w[1] > w[0]));
    assert!(col(&cp, "dz_mm")
        .iter()
        .all(|v| v.is_finite() && v.abs() < 1.0));
}

fn write_topo(path: &Path, rows: &[(&str, f64, f64, f64)]) {
    let schema = Arc::new(Schema::new(vec![
        Field::new("state", DataType::Utf8, false),
        Field::new("x_mm", DataType::Float64, false),
        Field::new("y_mm", DataType::Float64, false),
        Field::new("z_mm", DataType::Float64, false),
    ]));
    let b = RecordBatch::try_new(
        schema.clone(),
        vec![
            Arc::new(StringArray::from(
                rows.iter().map(|r| r.0).collect::<Vec<_>>(),
            )),
            Arc::new(Float64Array::from(
                rows.iter().map(|r| r.1).collect::<Vec<_>>(),
            )),
            Arc::new(Float64Array::from(
                rows.iter().map(|r| r.2).collect::<Vec<_>>(),
            )),
            Arc::new(Float64Array::from(
                rows.iter().map(|r| r.3).collect::<Vec<_>>(),
            )),
        ],
    )
    .unwrap();
    let f = std::fs::File::create(path).unwrap();
    let mut w = parquet::arrow::ArrowWriter::try_new(f, schema, None).unwrap();
    w.write(&b).unwrap();
    w.close().unwrap();
}

fn copy_run(from: &Path, to: &Path, id: &str) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        std::fs::copy(&p, to.join(p.file_name().unwrap())).unwrap();
    }
    let t = std::fs::read_to_string(to.join("run.toml")).unwrap();
    std::fs::write(
        to.join("run.toml"),
        t.replace("id = \"r0000\"", &format!("id = \"{id}\"")),
    )
    .unwrap();
}

fn grid_rows(
    states: &[&'static str],
    skip: Option<usize>,
    dup: bool,
    irregular: bool,
) -> Vec<(&'static str, f64, f64, f64)> {
    let mut v = Vec::new();
    for s in states {
        let mut k = 0;
        for j in 0..8 {
            for i in 0..10 {
                let x = 800.0 + 40.0 * i as f64 + if irregular && i == 9 { 13.0 } else { 0.0 };
                let y = 600.0 + 40.0 * j as f64;
                if Some(k) != skip {
                    v.push((*s, x, y, 1e-5 * x));
                }
                k += 1;
            }
        }
        if dup {
            v.push((*s, 840.0, 640.0, 0.0));
        }
    }
    v
}

#[test]
fn bad_inputs_are_rejected_and_the_batch_goes_on() {
    let d = tempfile::tempdir().unwrap();
    let fleet = generate(&d.path().join("runs"), "1", "4");
    let good = fleet.join("r0000");
    let mk = |id: &str| {
        let p = fleet.join(id);
        copy_run(&good, &p, id);
        p
    };
    let all = ["pattern", "after_grind", "after_polish"];
    write_topo(
        &mk("nopattern").join("topography.parquet"),
        &grid_rows(&["after_grind", "after_polish"], None, false, false),
    );
    write_topo(
        &mk("dup").join("topography.parquet"),
        &grid_rows(&all, None, true, false),
    );
    write_topo(
        &mk("irregular").join("topography.parquet"),
        &grid_rows(&all, None, false, true),
    );
    let big = mk("bigtool");
    let t = std::fs::read_to_string(big.join("run.toml")).unwrap();
    std::fs::write(
        big.join("run.toml"),
        t.replace("tool_radius_mm = 100.0", "tool_radius_mm = 5000.0"),
    )
    .unwrap();
    let neg = mk("negpressure");
    let t = std::fs::read_to_string(neg.join("run.toml")).unwrap();
    std::fs::write(neg.join("run.toml"), format!("{t}pressure_pa = -389.93\n")).unwrap();
    let kp = mk("negkp");
    let t = std::fs::read_to_string(kp.join("run.toml")).unwrap();
    std::fs::write(kp.join("run.toml"), format!("{t}k_p_per_pa = -1e-8\n")).unwrap();

    let out = d.path().join("out");
    let r = sparkout(&[
        "run",
        "--input",
        d.path().join("runs").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!r.status.success(), "some runs failed: exit code says so");
    let f: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("failures.json")).unwrap()).unwrap();
    let find = |id: &str| -> serde_json::Value {
        f.as_array()
            .unwrap()
            .iter()
            .find(|e| e["run"] == id)
            .cloned()
            .unwrap_or_else(|| panic!("{id} not rejected: {f:#}"))
    };
    let e = find("nopattern");
    assert!(
        e["error"].as_str().unwrap().contains("no `pattern` state"),
        "{e}"
    );
    assert_eq!(e["column"], "state");
    let e = find("dup");
    assert!(
        e["error"]
            .as_str()
            .unwrap()
            .contains("duplicated grid point (x = 840, y = 640)"),
        "{e}"
    );
    assert_eq!(e["row"], 80);
    let e = find("irregular");
    assert!(
        e["error"].as_str().unwrap().contains("irregular grid"),
        "{e}"
    );
    assert_eq!(e["column"], "x_mm");
    let e = find("bigtool");
    assert!(
        e["error"]
            .as_str()
            .unwrap()
            .contains("larger than the surface"),
        "{e}"
    );
    let e = find("negpressure");
    assert!(
        e["error"]
            .as_str()
            .unwrap()
            .contains("[process].pressure_pa must be a number > 0"),
        "{e}"
    );
    assert_eq!(e["column"], "process.pressure_pa");
    let e = find("negkp");
    assert!(
        e["error"]
            .as_str()
            .unwrap()
            .contains("[process].k_p_per_pa must be a number > 0"),
        "{e}"
    );
    // The good run went through.
    assert!(out.join("aplm-gantry/r0000/observations.parquet").is_file());
    let ps = read_batch(&out.join("aplm-gantry/r0000/polish_surface.parquet"));
    let (removal, before, after) = (
        col(&ps, "removal_mm"),
        col(&ps, "above_plane_mm"),
        col(&ps, "after_mm"),
    );
    // FFT rounding leaves ~1e-18 mm where nothing is removed.
    assert!(removal.iter().all(|v| *v >= -1e-12) && removal.iter().any(|v| *v > 1e-6));
    let pv = |v: &[f64]| {
        v.iter().cloned().fold(f64::MIN, f64::max) - v.iter().cloned().fold(f64::MAX, f64::min)
    };
    assert!(
        pv(after) < pv(before),
        "the selective plan leaves the surface flatter: {} vs {}",
        pv(after),
        pv(before)
    );
    assert_eq!(f.as_array().unwrap().len(), 6, "{f:#}");

    // A machine config missing a body.
    let machines = d.path().join("machines");
    std::fs::create_dir_all(&machines).unwrap();
    let toml = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/machines/aplm-gantry.toml"),
    )
    .unwrap();
    let start = toml.find("[bridge]").unwrap();
    let end = start + toml[start..].find("[spindle]").unwrap();
    std::fs::write(
        machines.join("aplm-gantry.toml"),
        format!("{}{}", &toml[..start], &toml[end..]),
    )
    .unwrap();
    let r = sparkout(&[
        "stage",
        "matrices",
        "--run",
        good.to_str().unwrap(),
        "--machines",
        machines.to_str().unwrap(),
    ]);
    assert!(!r.status.success());
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("no [bridge] table"), "{err}");
}

/// On generated runs (the demo's fleet: seed 1) the
/// selective plan halves the minimum-zone flatness of the ground surface
/// in less time than a raster of the same removal, and says so.
#[test]
fn selective_polishing_halves_the_minimum_zone_faster_than_raster() {
    let d = tempfile::tempdir().unwrap();
    let root = generate(d.path(), "3", "1");
    for r in ["r0000", "r0001", "r0002"] {
        let run = root.join(r);
        let out = sparkout(&[
            "stage",
            "polish_plan",
            "--run",
            run.to_str().unwrap(),
            "--state",
            "after_grind",
            "--json",
        ]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let p: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let f = &p["flatness"];
        let (mz0, mz1) = (
            f["before"]["min_zone_mm"].as_f64().unwrap(),
            f["selective"]["min_zone_mm"].as_f64().unwrap(),
        );
        let (ls0, ls1) = (
            f["before"]["least_squares_mm"].as_f64().unwrap(),
            f["selective"]["least_squares_mm"].as_f64().unwrap(),
        );
        eprintln!(
            "{r}: min zone {:.1} → {:.1} µm (LS {:.1} → {:.1}; raster {:.1}); selective {:.1} s vs raster {:.1} s",
            mz0 * 1e3,
            mz1 * 1e3,
            ls0 * 1e3,
            ls1 * 1e3,
            f["raster"]["min_zone_mm"].as_f64().unwrap() * 1e3,
            p["selective_s"].as_f64().unwrap(),
            p["raster_s"].as_f64().unwrap()
        );
        assert!(mz1 <= 0.5 * mz0, "{r}: min zone {mz0} → {mz1}");
        assert!(ls1 < ls0, "{r}: least squares {ls0} → {ls1}");
        assert_eq!(p["verdict"], "flatter", "{r}");
        assert!(p["warning"].is_null(), "{r}");
        let (sel, ras) = (
            p["selective_s"].as_f64().unwrap(),
            p["raster_s"].as_f64().unwrap(),
        );
        assert!(
            sel > 0.0 && sel < ras,
            "{r}: selective {sel} s vs raster {ras} s"
        );
    }
}

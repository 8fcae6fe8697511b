//! End to end through the binary: two machines of one type
//! whose runs carry identical ids (`r0000`…) stay apart in every output —
//! observations.parquet (a `machine` column), diagnosis.json (folds by
//! machine and run, `machine` cells, per-machine fits), diagnosis.parquet,
//! the fleet report and failures.json. Only the second machine's wheel
//! wears, so the gap is localised to it and the wear rate is reported per
//! machine.

use crate::common::sparkout;

use std::collections::BTreeSet;
use std::fs::File;
use std::path::Path;

use arrow::array::{Array, AsArray};
use arrow::datatypes::DataType;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;

fn generate(root: &Path, seed: u64, effect: Option<&str>) {
    let seed = seed.to_string();
    let mut args = vec![
        "generate",
        "form",
        "--runs",
        "6",
        "--seed",
        &seed,
        "--out",
        root.to_str().unwrap(),
    ];
    if let Some(e) = effect {
        args.extend(["--effect", e]);
    }
    let g = sparkout(&args);
    assert!(g.status.success(), "{}", String::from_utf8_lossy(&g.stderr));
}

/// Text columns of a Parquet file, by name.
fn text_columns(path: &Path, names: &[&str]) -> Vec<Vec<String>> {
    let r = ParquetRecordBatchReaderBuilder::try_new(File::open(path).unwrap())
        .unwrap()
        .build()
        .unwrap();
    let mut out = vec![Vec::new(); names.len()];
    for b in r {
        let b = b.unwrap();
        for (k, n) in names.iter().enumerate() {
            let a = b
                .column_by_name(n)
                .unwrap_or_else(|| panic!("{} has no column {n}", path.display()));
            let a = arrow::compute::cast(a, &DataType::Utf8).unwrap();
            let s = a.as_string::<i32>();
            out[k].extend((0..s.len()).map(|i| s.value(i).to_string()));
        }
    }
    out
}

/// A fleet root with the runs of `first` on `form-grinder` and those of
/// `second` on a second machine of the same type, `form-grinder-2`: the
/// same run ids on both. Returns (root, machines dir).
fn two_machine_fleet(
    dir: &Path,
    first: Option<&str>,
    second: Option<&str>,
) -> (std::path::PathBuf, std::path::PathBuf) {
    let (a, b) = (dir.join("a"), dir.join("b"));
    generate(&a, 44, first);
    generate(&b, 41, second);
    let root = dir.join("runs");
    std::fs::create_dir_all(&root).unwrap();
    std::fs::rename(a.join("form-grinder"), root.join("form-grinder")).unwrap();
    let other = root.join("form-grinder-2");
    std::fs::rename(b.join("form-grinder"), &other).unwrap();
    for e in std::fs::read_dir(&other).unwrap() {
        let p = e.unwrap().path().join("run.toml");
        let t = std::fs::read_to_string(&p).unwrap();
        let t = t.replace("machine = \"form-grinder\"", "machine = \"form-grinder-2\"");
        std::fs::write(&p, t).unwrap();
    }
    let machines = dir.join("machines");
    std::fs::create_dir_all(&machines).unwrap();
    let cfg = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/machines/form-grinder.toml"),
    )
    .unwrap();
    std::fs::write(machines.join("form-grinder-2.toml"), cfg).unwrap();
    (root, machines)
}

fn run_fleet(root: &Path, machines: &Path, out: &Path) -> std::process::Output {
    sparkout(&[
        "run",
        "--input",
        root.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--machines",
        machines.to_str().unwrap(),
    ])
}

fn diagnosis(out: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(out.join("fleet/diagnosis.json")).unwrap()).unwrap()
}

#[test]
fn two_machines_with_identical_run_ids_stay_apart() {
    let d = tempfile::tempdir().unwrap();
    // Only the second machine's wheel wears.
    let (root, machines) = two_machine_fleet(d.path(), None, Some("wheel_wear"));
    // The same run id is broken on both machines: two failures.
    for m in ["form-grinder", "form-grinder-2"] {
        std::fs::write(root.join(m).join("r0005/profile.parquet"), b"not parquet").unwrap();
    }
    let out = d.path().join("out");
    let r = run_fleet(&root, &machines, &out);
    assert_eq!(
        r.status.code(),
        Some(2),
        "{}\n{}",
        String::from_utf8_lossy(&r.stdout),
        String::from_utf8_lossy(&r.stderr)
    );

    // failures.json: one per machine, same run id.
    let f: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("failures.json")).unwrap()).unwrap();
    let fl = f
        .as_array()
        .or_else(|| f["failures"].as_array())
        .unwrap_or_else(|| panic!("{f:#}"));
    let failed: BTreeSet<(String, String)> = fl
        .iter()
        .map(|x| {
            (
                x["machine"].as_str().unwrap().to_string(),
                x["run"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    assert_eq!(
        failed,
        [
            ("form-grinder".to_string(), "r0005".to_string()),
            ("form-grinder-2".to_string(), "r0005".to_string())
        ]
        .into(),
        "{f:#}"
    );

    // observations.parquet: a machine column; 5 run ids, 10 runs.
    let cols = text_columns(&out.join("fleet/observations.parquet"), &["machine", "run"]);
    let runs: BTreeSet<&String> = cols[1].iter().collect();
    let pairs: BTreeSet<(&String, &String)> = cols[0].iter().zip(&cols[1]).collect();
    assert_eq!(runs.len(), 5);
    assert_eq!(pairs.len(), 10);
    let cols = text_columns(&out.join("fleet/diagnosis.parquet"), &["machine", "run"]);
    assert_eq!(cols[0].iter().collect::<BTreeSet<_>>().len(), 2);

    // diagnosis.json: runs are (machine, run) pairs, the gap is localised
    // to the worn machine, the wear rate is reported per machine.
    let diag = diagnosis(&out);
    assert_eq!(
        diag["machines"],
        serde_json::json!(["form-grinder", "form-grinder-2"])
    );
    assert_eq!(diag["cv"]["by"], "run");
    let po = &diag["per_observable"][0];
    assert_eq!(po["runs"], 10, "{po:#}");
    let machine_cells: Vec<&serde_json::Value> = diag["where"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["covariate"] == "machine")
        .collect();
    assert!(
        machine_cells.iter().any(|c| c["lo"] == "form-grinder-2"),
        "gap not localised to the worn machine: {:#}",
        diag["where"]
    );
    assert!(
        !machine_cells.iter().any(|c| c["lo"] == "form-grinder"),
        "the clean machine is flagged: {:#}",
        diag["where"]
    );
    // …and named on that machine's rows alone (machine_effects), never on
    // the clean one.
    let me = diag["machine_effects"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    assert!(
        me.iter().any(|e| e["machine"] == "form-grinder-2"),
        "the worn machine's effect is not named: {:#}",
        diag["machine_effects"]
    );
    assert!(
        me.iter().all(|e| e["machine"] == "form-grinder-2"),
        "{me:#?}"
    );
    let page = std::fs::read_to_string(out.join("fleet/report.html")).unwrap();
    assert!(
        page.contains("This machine alone"),
        "machine effect not on the fleet page"
    );
    // The fleet report groups by machine type, then machine (the
    // per-run gap table gave way to a section per machine).
    let html = std::fs::read_to_string(out.join("fleet/report.html")).unwrap();
    assert!(
        html.contains("<h2>Machine type form</h2>"),
        "no machine-type section"
    );
    assert!(
        html.contains("<h3>Machine form-grinder-2"),
        "no section of form-grinder-2"
    );
}

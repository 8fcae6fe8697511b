//! "A directory of runs whose Parquet files were written by pandas with
//! default settings runs end to end": datasets/fixtures/
//! pandas_fleet holds form-grinder and mill runs whose every table pandas
//! wrote back with its defaults (snappy, int64 ids, large_string text,
//! the mill's thermal log as wall-clock timestamps); made by
//! datasets/fixtures/make_fixtures.py --fleet.

use std::path::{Path, PathBuf};

use sparkout_pipeline::contracts::{
    discover_runs, read_parquet, write_parquet_atomic, RunSpec, Table,
};

use crate::common::sparkout;

fn fleet() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("datasets/fixtures/pandas_fleet")
}

fn run_ok(input: &Path, out: &Path) -> serde_json::Value {
    let o = sparkout(&[
        "run",
        "--input",
        input.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        o.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    let failures: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("failures.json")).unwrap()).unwrap();
    assert_eq!(failures, serde_json::json!([]));
    serde_json::from_slice(&std::fs::read(out.join("fleet/diagnosis.json")).unwrap()).unwrap()
}

#[test]
fn a_fleet_written_by_pandas_runs_end_to_end_and_matches_the_same_data_written_by_sparkout() {
    let d = tempfile::tempdir().unwrap();
    // The fixture really is pandas' output: snappy, large_string, timestamps.
    let thermal = fleet().join("xfyz-mill/r0001/thermal.parquet");
    let raw = read_parquet(&thermal).unwrap();
    assert!(matches!(
        raw.schema().field_with_name("t_s").unwrap().data_type(),
        arrow::datatypes::DataType::Timestamp(..)
    ));
    assert!(raw.schema().metadata().contains_key("pandas"));

    let diag = run_ok(&fleet(), &d.path().join("out"));
    let observables: Vec<&str> = diag["observables"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert!(observables.contains(&"profile_error"), "{observables:?}");
    assert!(
        observables.iter().any(|o| o.starts_with("tracker_")),
        "{observables:?}"
    );
    let runs = discover_runs(&fleet()).unwrap();
    assert_eq!(runs.len(), 8);
    for r in &runs {
        let rel = r.strip_prefix(fleet()).unwrap();
        assert!(d.path().join("out").join(rel).join("report.html").is_file());
    }

    // The same values written by sparkout (arrow-rs, zstd, contract types,
    // t_s in seconds) give the same paired observations, row for row.
    let copy = d.path().join("copy");
    for r in &runs {
        let spec = RunSpec::load(r).unwrap();
        let dest = copy.join(r.strip_prefix(fleet()).unwrap());
        std::fs::create_dir_all(&dest).unwrap();
        std::fs::copy(r.join("run.toml"), dest.join("run.toml")).unwrap();
        for e in std::fs::read_dir(r).unwrap() {
            let p = e.unwrap().path();
            let Some(stem) = p.file_stem().and_then(|s| s.to_str()) else {
                continue;
            };
            if let Some(schema) = crate::common::tables().get(stem) {
                let t = Table::read_at(&p, schema, &spec.time_origin()).unwrap();
                // Drop pandas' schema metadata: the copy is sparkout's own.
                let fields = t.batch().schema().fields().clone();
                let b = t
                    .batch()
                    .clone()
                    .with_schema(std::sync::Arc::new(arrow::datatypes::Schema::new(fields)))
                    .unwrap();
                write_parquet_atomic(&dest.join(format!("{stem}.parquet")), &b).unwrap();
            }
        }
    }
    let diag2 = run_ok(&copy, &d.path().join("out2"));
    let a = read_parquet(&d.path().join("out/fleet/observations.parquet")).unwrap();
    let b = read_parquet(&d.path().join("out2/fleet/observations.parquet")).unwrap();
    assert!(a.num_rows() > 0);
    assert_eq!(a, b);
    assert_eq!(diag["gap"], diag2["gap"]);
    assert_eq!(diag["selected"], diag2["selected"]);
}

//! Criterion bench of the fleet diagnosis with its memory budgets at 0
//! (docs/scale.md, "Memory of the fleet diagnosis"): the observable's
//! covariates read back from a column file a chunk at a time and the
//! folds' targets recomputed from the chosen effects' fits on every pass —
//! the path of an observable too large to hold, on the 10⁶-row fleet of
//! `diagnose`'s file-to-file bench (whose covariates also go to the file,
//! its targets stay columns). A target of its own: the budgets are read
//! from the environment once per process.

use criterion::{criterion_group, Criterion};
use sparkout_pipeline::config_check::Checked;
use sparkout_pipeline::contracts::write_parquet_atomic;
use sparkout_pipeline::diagnose::DiagnoseConfig;
use std::time::Duration;

mod common;

fn bench_streamed(c: &mut Criterion) {
    common::register_references(c, "diagnose_streamed");
    let obs = common::obs_fleet(20, 100, 100, 5, 1.0);
    assert_eq!(obs.num_rows(), 1_000_000);
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("observations.parquet");
    write_parquet_atomic(&path, &obs).expect("bench table");
    drop(obs);
    let checked = Checked::check(DiagnoseConfig {
        folds: 5,
        ..Default::default()
    })
    .expect("config");
    let mut g = c.benchmark_group("diagnose_streamed");
    g.sample_size(10);
    g.measurement_time(Duration::from_secs(60));
    common::bench_diagnose_file(
        &mut g,
        "1e6_rows_file_to_file_5_folds_budgets_0",
        &path,
        &checked,
    );
    g.finish();
}

criterion_group!(benches, bench_streamed);

fn main() {
    // Before anything reads them (each is read once per process).
    std::env::set_var("SPARKOUT_COVARIATES_MAX_BYTES", "0");
    std::env::set_var("SPARKOUT_TARGET_COLUMNS_MAX_BYTES", "0");
    common::run_or_scale(benches, || {});
}

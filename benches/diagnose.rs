//! Criterion bench of the gap diagnosis: 10⁶ observations
//! × the full catalogue × 5 folds by run, target ≤ 10 s on 2 cores.
//!
//! The fleet: 20 runs × 100×100 grid × 5 passes = 10⁶ rows with all eleven
//! covariates of the generator (so every catalogue candidate applies) and a
//! drift + backlash gap, so forward selection runs two rounds plus the stop
//! round — the realistic worst case rather than a no-gap shortcut.

use arrow::array::RecordBatch;
use criterion::{criterion_group, Criterion};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sparkout_pipeline::config_check::Checked;
use sparkout_pipeline::contracts::write_parquet_atomic;
use sparkout_pipeline::diagnose::run_length::RunLength;
use sparkout_pipeline::diagnose::{diagnose, fit, DiagnoseConfig};
use std::time::Duration;

mod common;

fn bench_diagnose(c: &mut Criterion) {
    common::register_references(c, "diagnose");
    let obs = common::obs_fleet(20, 100, 100, 5, 1.0);
    assert_eq!(obs.num_rows(), 1_000_000);
    let dcfg = DiagnoseConfig {
        folds: 5,
        ..Default::default()
    };
    let mut g = c.benchmark_group("diagnose");
    g.sample_size(10);
    g.measurement_time(Duration::from_secs(60));
    g.bench_function("1e6_rows_full_catalogue_5_folds", |b| {
        b.iter(|| diagnose(&obs, &dcfg, &[]).expect("diagnose"))
    });
    // The path a fleet's night takes: the table read from its file batch by
    // batch, the covariates one observable at a time, the per-row results
    // spilled per observable and diagnosis.parquet written a slice at a time.
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("observations.parquet");
    write_parquet_atomic(&path, &obs).expect("bench table");
    drop(obs);
    let checked = Checked::check(dcfg).expect("config");
    common::bench_diagnose_file(&mut g, "1e6_rows_file_to_file_5_folds", &path, &checked);
    g.finish();
}

/// The reduction the fleet diagnosis merges (docs/design.md §8): 10⁶ rows
/// of 500 runs (2 000 rows each), dealt to the 6 fold groups of 5-fold CV,
/// each run pooled into its partial cells on the fleet's grid and a group's
/// partials merged in run order — for 6 targets, on one covariate at the
/// CV folds' fine resolution (dense bins) and on two (sorted cells).
fn bench_pool(c: &mut Criterion) {
    let (runs, per_run) = (500, 2_000);
    let n = runs * per_run;
    // A run sweeps x back and forth over 400 mm; y steps once per pass.
    let x: Vec<f64> = (0..n)
        .map(|i| {
            let p = (i % per_run) as f64 / per_run as f64;
            400.0 * (1.0 - (2.0 * p - 1.0).abs()) + 1e-3 * (i % 97) as f64
        })
        .collect();
    let y: Vec<f64> = (0..n).map(|i| ((i % per_run) / 100) as f64 * 5.0).collect();
    let targets: Vec<Vec<f64>> = (0..6)
        .map(|t| {
            (0..n)
                .map(|i| ((i * (t + 3)) as f64 * 1e-3).sin())
                .collect()
        })
        .collect();
    let tref: Vec<&[f64]> = targets.iter().map(Vec::as_slice).collect();
    let mut groups: Vec<Vec<std::ops::Range<usize>>> = vec![Vec::new(); 6];
    for r in 0..runs {
        groups[r % 6].push(r * per_run..(r + 1) * per_run);
    }
    let mut g = c.benchmark_group("diagnose");
    g.sample_size(20);
    g.bench_function("pool_1e6_rows_500_runs_1_covariate", |b| {
        b.iter(|| fit::pool_rows(&[&x], &[0.0], &[0.05], None, &groups, &tref))
    });
    g.bench_function("pool_1e6_rows_500_runs_2_covariates", |b| {
        b.iter(|| fit::pool_rows(&[&x, &y], &[0.0, 0.0], &[0.5, 5.0], None, &groups, &tref))
    });
    // The same cells as a streamed pass makes them: the runs in canonical
    // order, each into its group (every group open at once), a group sealed
    // after its last run.
    let by_runs = |cols: &[&[f64]], res: &[f64]| {
        let mins = vec![0.0; cols.len()];
        let axes = fit::pool::spans(cols, &mins)
            .into_iter()
            .zip(res)
            .map(|(span, &r)| fit::pool::Axis::new(0.0, span, r))
            .collect();
        let mut cells = fit::CellPool::new(axes, tref.len(), groups.len());
        for r in 0..runs {
            cells.add_range(r % 6, r * per_run..(r + 1) * per_run, cols, None, &tref);
            if r + 6 >= runs {
                cells.seal(r % 6);
            }
        }
        cells.finish()
    };
    g.bench_function("pool_1e6_rows_500_runs_1_covariate_run_by_run", |b| {
        b.iter(|| by_runs(&[&x], &[0.05]))
    });
    g.bench_function("pool_1e6_rows_500_runs_2_covariates_run_by_run", |b| {
        b.iter(|| by_runs(&[&x, &y], &[0.5, 5.0]))
    });
    g.finish();
}

/// The table's key column (run unit per row) of a table whose rows are not
/// in run order — shuffled, as a writer that does not sort leaves it — read
/// at 10⁶ rows in run order, as gathering an observable and its noise floor
/// read it (500 runs of 2 000 rows). Held as stretches this was a bisection
/// per row over 10⁶ stretches; held as rows, an index.
fn bench_keys(c: &mut Criterion) {
    let (runs, per_run) = (500u32, 2_000usize);
    let n = runs as usize * per_run;
    // A fixed shuffle of the run of each row.
    let mut run: Vec<u32> = (0..n).map(|i| (i / per_run) as u32).collect();
    run.shuffle(&mut ChaCha8Rng::seed_from_u64(7));
    let col: RunLength<u32> = run.iter().copied().collect();
    let mut in_run_order: Vec<usize> = (0..n).collect();
    in_run_order.sort_by_key(|&i| run[i]);
    let mut g = c.benchmark_group("diagnose");
    g.sample_size(20);
    g.bench_function("keys_1e6_rows_shuffled_table_read_in_run_order", |b| {
        b.iter(|| col.at(&in_run_order))
    });
    g.finish();
}

/// A covariate's constants (extremes, median spacing of its distinct
/// values) over 10⁶ rows of 500 runs, as the gather computes them for
/// every covariate of an observable: a time base that repeats run after
/// run (2 000 distinct values: a hash set of the distinct values) and a
/// position that hardly repeats (every row sorted).
fn bench_constants(c: &mut Criterion) {
    let (runs, per_run) = (500usize, 2_000usize);
    let t_s: Vec<f64> = (0..runs * per_run)
        .map(|i| (i % per_run) as f64 * 1e-3)
        .collect();
    let x_mm: Vec<f64> = (0..runs * per_run)
        .map(|i| 50.0 * ((i as f64) * 1e-4).sin() + (i % 7919) as f64 * 1e-7)
        .collect();
    let mut g = c.benchmark_group("diagnose");
    g.sample_size(20);
    g.bench_function("constants_1e6_rows_repeating_time_base", |b| {
        b.iter(|| sparkout_pipeline::effect::CovStats::from_values(&t_s))
    });
    g.bench_function("constants_1e6_rows_continuous_position", |b| {
        b.iter(|| sparkout_pipeline::effect::CovStats::from_values(&x_mm))
    });
    g.finish();
}

/// A fleet table's keys as the night reads them (500 runs × 2 observables
/// × 1 000 rows, a `unit` column stating µm for one observable): indexed
/// from its file batch by batch, and spilled per observable with each row's
/// gap as the join streams it. Each row's keys are looked up once per
/// stretch of equal keys; looked up per row (a unit parsed and string maps
/// searched for every row) these took 2.4 and 3.9 times as long.
fn bench_index(c: &mut Criterion) {
    use arrow::array::{Float64Array, StringArray};
    use arrow::datatypes::{DataType, Field, Schema};
    use sparkout_pipeline::diagnose::observations_file::{index_observations_file, RowValueSpill};
    use std::sync::Arc;
    let (runs, per_obs) = (500usize, 1_000usize);
    let n = runs * 2 * per_obs;
    let (mut run, mut obs, mut unit) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    for r in 0..runs {
        for (o, u) in [("a", "um"), ("b", "mm")] {
            for _ in 0..per_obs {
                run.push(format!("r{r:04}"));
                obs.push(o);
                unit.push(u);
            }
        }
    }
    let f = |i: usize| (i % 1_013) as f64 * 1e-3;
    let batch = RecordBatch::try_new(
        Arc::new(Schema::new(vec![
            Field::new("run", DataType::Utf8, false),
            Field::new("observable", DataType::Utf8, false),
            Field::new("unit", DataType::Utf8, false),
            Field::new("sim", DataType::Float64, false),
            Field::new("real", DataType::Float64, false),
            Field::new("t_s", DataType::Float64, false),
        ])),
        vec![
            Arc::new(StringArray::from(run)),
            Arc::new(StringArray::from(obs)),
            Arc::new(StringArray::from(unit)),
            Arc::new(Float64Array::from_iter_values((0..n).map(|i| f(i) * 0.5))),
            Arc::new(Float64Array::from_iter_values((0..n).map(f))),
            Arc::new(Float64Array::from_iter_values(
                (0..n).map(|i| (i % (2 * per_obs)) as f64),
            )),
        ],
    )
    .expect("bench table");
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("observations.parquet");
    write_parquet_atomic(&path, &batch).expect("bench table");
    let mut g = c.benchmark_group("diagnose");
    g.sample_size(10);
    g.bench_function("index_1e6_rows_with_units_from_file", |b| {
        b.iter(|| index_observations_file(&path).expect("index"))
    });
    g.bench_function("spill_1e6_rows_with_units", |b| {
        b.iter(|| {
            let mut spill =
                RowValueSpill::create(&dir.path().join(".spill"), &batch.schema()).expect("spill");
            spill.push(&batch, &path).expect("push");
            spill.finish().expect("finish")
        })
    });
    g.finish();
}

criterion_group!(
    benches,
    bench_diagnose,
    bench_pool,
    bench_keys,
    bench_constants,
    bench_index
);

/// `SPARKOUT_BENCH_VALIDATE=1 cargo bench --bench diagnose` also times
/// `sparkout validate --quick` and the full validation (targets:
/// < 30 s and < 5 min in release on 2 cores) in the same release build.
fn main() {
    if std::env::var_os("SPARKOUT_BENCH_VALIDATE").is_some() {
        use sparkout_datasets::validate::{render_text, run, ValidateConfig};
        for quick in [true, false] {
            let t = std::time::Instant::now();
            let r = run(&ValidateConfig::new(quick, 0)).expect("validate");
            println!("{}", render_text(&r));
            println!(
                "validate {}: {:.1} s wall",
                if quick { "--quick" } else { "(full)" },
                t.elapsed().as_secs_f64()
            );
        }
    }
    common::run_or_scale(benches, scaling);
}

/// `SPARKOUT_BENCH_SCALING=1 cargo bench --bench diagnose`:
/// the diagnosis's cost against rows (more runs of one grid: 10⁴ … 10⁶
/// rows) and against grid density (20 runs of one 100 mm square sampled
/// ever finer), best of 3 (of 1 above 5·10⁵ rows), with the cost exponent
/// of each step — printed, not gated. `SPARKOUT_DIAGNOSE_SCALING_RUNS=500`
/// times that many runs only (no density sweep).
fn scaling() {
    let dcfg = DiagnoseConfig {
        folds: 5,
        ..Default::default()
    };
    let time = |obs: &RecordBatch| {
        let reps = if obs.num_rows() > 500_000 { 1 } else { 3 };
        common::best_of(reps, || {
            diagnose(obs, &dcfg, &[]).expect("diagnose");
        })
    };
    let report = |what: &str, points: &[(usize, f64)]| {
        let mut prev = None;
        for &(rows, secs) in points {
            let exponent = common::exponent_text(prev, rows as f64, secs);
            println!("diagnose scaling [{what}] {rows:>8} rows {secs:>7.3} s{exponent}");
            prev = Some((rows as f64, secs));
        }
    };
    // Rows by runs: 20×20 grid × 5 passes = 2 000 rows per run.
    // `SPARKOUT_DIAGNOSE_SCALING_RUNS=500` times one size alone (profiling).
    let runs = common::sizes_from_env("SPARKOUT_DIAGNOSE_SCALING_RUNS", "5,50,169,500");
    let by_runs: Vec<(usize, f64)> = runs
        .iter()
        .map(|&runs| {
            let obs = common::obs_fleet(runs, 20, 20, 5, 5.0);
            (obs.num_rows(), time(&obs))
        })
        .collect();
    report("runs", &by_runs);
    if std::env::var_os("SPARKOUT_DIAGNOSE_SCALING_RUNS").is_some() {
        return;
    }
    // Grid density: 20 runs × 5 passes of a 100 mm square at pitch 100/n mm.
    let by_density: Vec<(usize, f64)> = [10usize, 32, 100]
        .iter()
        .map(|&n| {
            let obs = common::obs_fleet(20, n, n, 5, 100.0 / n as f64);
            (obs.num_rows(), time(&obs))
        })
        .collect();
    report("grid density", &by_density);
}

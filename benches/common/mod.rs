//! Reference kernels every gated bench measures in its own process.
//! The machine's speed drifts (turbo, thermal, a neighbour's build),
//! so the gate compares `bench / reference` ratios, not absolute times: a
//! memory-bound reference for kernels that stream, a compute-bound FFT
//! reference for kernels that calculate. Both are fixed work, independent of
//! sparkout's code, so a ratio moves only when sparkout's kernel does.

#![allow(dead_code)] // each bench uses the references it needs

use criterion::Criterion;
use std::hint::black_box;

/// Words in the streamed buffer: 64 MiB of f64, far beyond every cache.
const STREAM_WORDS: usize = 8 << 20;
/// Points of the reference complex FFT.
const FFT_POINTS: usize = 1 << 16;

/// Registers `<group>_reference/stream_sum_64MiB` (memory bandwidth) and
/// `<group>_reference/fft_64k` (floating-point throughput) beside the bench.
pub fn register_references(c: &mut Criterion, group: &str) {
    let mut g = c.benchmark_group(format!("{group}_reference"));
    g.sample_size(20);
    let buffer: Vec<f64> = (0..STREAM_WORDS).map(|i| (i % 1024) as f64).collect();
    g.bench_function("stream_sum_64MiB", |b| {
        b.iter(|| {
            // Four accumulators so the adds are not latency-bound: the loop
            // then runs at memory bandwidth, which is what it stands for.
            let mut acc = [0.0f64; 4];
            for chunk in black_box(&buffer).chunks_exact(4) {
                for k in 0..4 {
                    acc[k] += chunk[k];
                }
            }
            black_box(acc.iter().sum::<f64>())
        })
    });
    let mut planner = rustfft::FftPlanner::<f64>::new();
    let fft = planner.plan_fft_forward(FFT_POINTS);
    let input: Vec<rustfft::num_complex::Complex<f64>> = (0..FFT_POINTS)
        .map(|i| rustfft::num_complex::Complex::new((i as f64 * 0.001).sin(), 0.0))
        .collect();
    let mut scratch = vec![rustfft::num_complex::Complex::default(); fft.get_inplace_scratch_len()];
    g.bench_function("fft_64k", |b| {
        let mut data = input.clone();
        b.iter(|| {
            data.copy_from_slice(&input);
            fft.process_with_scratch(black_box(&mut data), &mut scratch);
            black_box(data[1])
        })
    });
    g.finish();
}

/// Best wall time of `reps` calls of `f`, seconds (the scaling modes: the
/// minimum is the figure least disturbed by the rest of the machine).
pub fn best_of(reps: usize, mut f: impl FnMut()) -> f64 {
    (0..reps.max(1))
        .map(|_| {
            let t = std::time::Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

/// The cost exponent between two (size, seconds) points: log(t₁/t₀) /
/// log(n₁/n₀), as text for a scaling line ("" for the first point).
pub fn exponent_text(prev: Option<(f64, f64)>, size: f64, secs: f64) -> String {
    prev.map_or(String::new(), |(n0, s0)| {
        format!("  exponent {:.2}", (secs / s0).ln() / (size / n0).ln())
    })
}

/// A bench's `main`: `SPARKOUT_BENCH_SCALING=1` runs its scaling sweep
/// (printed, not gated), otherwise the criterion benches as
/// `criterion_main!` would.
pub fn run_or_scale(benches: fn(), scaling: fn()) {
    // As the `sparkout` binary does: the benches time its path.
    sparkout_pipeline::alloc::keep_freed_memory();
    if std::env::var_os("SPARKOUT_BENCH_SCALING").is_some() {
        scaling();
        return;
    }
    benches();
    Criterion::default().configure_from_args().final_summary();
}

/// A comma-separated list of sizes from the environment variable `var`
/// (e.g. `SPARKOUT_AE_SCALING_SAMPLES=10000000,100000000`), or `default`.
pub fn sizes_from_env(var: &str, default: &str) -> Vec<usize> {
    std::env::var(var)
        .unwrap_or_else(|_| default.into())
        .split(',')
        .map(|v| {
            v.trim()
                .parse()
                .unwrap_or_else(|_| panic!("{var}: comma-separated integers, got `{v}`"))
        })
        .collect()
}

/// The bench fleet: `runs` runs × nx×ny grid (1 mm pitch, `spacing_mm`
/// scales it) × `passes`, with a drift + backlash gap.
pub fn obs_fleet(
    runs: usize,
    nx: usize,
    ny: usize,
    passes: usize,
    spacing_mm: f64,
) -> arrow::array::RecordBatch {
    use sparkout_datasets::observations::{generate, ObsFleetConfig};
    use sparkout_pipeline::EffectSpec;
    let cfg = ObsFleetConfig {
        runs,
        seed: 7,
        noise_mm: 0.001,
        nx,
        ny,
        spacing_mm,
        passes,
        replicate_fraction: 0.0,
        observable: "surface_z".into(),
    };
    let effects: Vec<EffectSpec> = vec![
        "drift:t_s=amplitude_mm=0.01,tau_s=20000".parse().unwrap(),
        "backlash:dir=b_mm=0.004".parse().unwrap(),
    ];
    generate(&cfg, &effects).expect("fleet")
}

/// Benches `name` in `g`: the diagnosis of the observations file `path`
/// as a night takes it — the table read batch by batch, the per-row
/// results spilled beside the output and diagnosis.parquet written — into
/// `out/` beside the file.
pub fn bench_diagnose_file(
    g: &mut criterion::BenchmarkGroup<criterion::measurement::WallTime>,
    name: &str,
    path: &std::path::Path,
    cfg: &sparkout_pipeline::config_check::Checked<sparkout_pipeline::diagnose::DiagnoseConfig>,
) {
    let out = path.with_file_name("out");
    g.bench_function(name, |b| {
        b.iter(|| {
            let d = sparkout_pipeline::diagnose::diagnose_observations_file(
                path,
                cfg,
                &[],
                None,
                Some(&out.join(".r")),
                &|_| {},
            )
            .expect("diagnose");
            d.per_row
                .write_parquet(&out.join("diagnosis.parquet"))
                .expect("write");
        })
    });
}

//! Criterion bench of the guide-way three-probe separation:
//! the least-squares solve with its propagated uncertainty band, and
//! the published recursion, on 10⁵ workpiece points in two passes (2·10⁵
//! samples). Target: well under a second for the LS solve.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use sparkout_plugins::guideway::input::{prepare, Geometry, InputOptions, RawReadings};
use sparkout_plugins::guideway::three_probe::{separate_lsq, separate_recursion, Reference};
use std::hint::black_box;
use std::path::Path;

mod common;

const POINTS: usize = 100_000;
const STEP_MM: f64 = 30.0;

/// Two passes (forward, back) over a wavy workpiece with a drifting table.
fn readings() -> sparkout_plugins::guideway::input::Readings {
    let h = |j: usize| 2e-3 * (j as f64 * 0.21).sin() + 5e-3 * (j as f64 / POINTS as f64).powi(2);
    let mut raw = RawReadings::default();
    let mut n = 0i64;
    for pass in 0..2 {
        let js: Vec<usize> = if pass == 0 {
            (0..POINTS).collect()
        } else {
            (0..POINTS).rev().collect()
        };
        for j in js {
            let dz = 1e-3 * (n as f64 * 0.05).cos();
            let beta = 1e-6 * (n as f64 * 0.03).sin();
            let noise = 1e-5 * ((n as f64 * 12.9898).sin() * 43758.5453).fract();
            raw.n.push(n);
            raw.x_mm.push(j as f64 * STEP_MM);
            raw.z_mm[0].push(h(j) + dz + noise);
            raw.z_mm[1].push(h(j + 1) + dz + STEP_MM * beta);
            raw.z_mm[2].push(h(j + 2) + dz + 2.0 * STEP_MM * beta);
            n += 1;
        }
    }
    let g = Geometry {
        spacing_mm: STEP_MM,
        step_mm: STEP_MM,
        speed_mm_s: 20_000.0 / 60.0,
    };
    prepare(
        Path::new("bench.parquet"),
        raw,
        &g,
        &InputOptions::default(),
    )
    .expect("prepare")
}

fn bench(c: &mut Criterion) {
    common::register_references(c, "guideway_separate");
    let r = readings();
    let mut g = c.benchmark_group("guideway_separate");
    g.throughput(Throughput::Elements(POINTS as u64));
    g.sample_size(10);
    g.bench_function("lsq_with_uncertainty_1e5_points", |b| {
        b.iter(|| {
            let s = separate_lsq(black_box(&r), Reference::Line, 1e-4).expect("lsq");
            black_box(s.h_mm[POINTS / 2])
        })
    });
    g.bench_function("recursion_1e5_points", |b| {
        b.iter(|| {
            let s = separate_recursion(black_box(&r)).expect("recursion");
            black_box(s.h_mm[POINTS / 2])
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);

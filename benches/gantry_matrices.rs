//! Criterion bench of the gantry `matrices` kernel: τ_static
//! and τ_dynamic (piecewise quadratic straightness, beam deflections, the
//! moving-load series with adaptive truncation at 1e-10) with each body's
//! share on a 200 × 160 grid over the aplm-gantry's whole workspace.
//! Target ≤ 1 s.

use criterion::{criterion_group, criterion_main, Criterion};
use sparkout_pipeline::contracts::RunSpec;
use sparkout_plugins::gantry::grid::Grid;
use sparkout_plugins::gantry::machine::Gantry;
use sparkout_plugins::gantry::matrices::topography;
use std::hint::black_box;

mod common;

fn bench(c: &mut Criterion) {
    common::register_references(c, "gantry_matrices");
    let m = sparkout_plugins::gantry::builtin_machine().unwrap();
    let spec = RunSpec::parse(
        std::path::Path::new("."),
        "[run]\nid = \"b\"\nmachine = \"aplm-gantry\"\nplugin = \"gantry\"\n",
    )
    .unwrap();
    let g = Gantry::from_run(&m, &spec).unwrap();
    // 200 × 160 nodes inside the stringers' span (2400 mm) and the bridge (1800 mm).
    let grid = Grid::new(6.0, 11.94, 200, 5.0, 11.25, 160);
    c.bench_function("gantry matrices 200x160 (static + dynamic)", |b| {
        b.iter(|| {
            let s = topography(&g, black_box(&grid), false).unwrap();
            let d = topography(&g, black_box(&grid), true).unwrap();
            black_box((s, d))
        })
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench
}
criterion_main!(benches);

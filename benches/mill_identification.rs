//! Criterion bench of the mill identification: the 21 error
//! functions (degree 3) and the tracker frame — 60 parameters — identified by
//! Levenberg–Marquardt from 2000 tracker points measured with three tool
//! offsets, covariance included (docs/models.md §5).
//!
//! The machine is the generator's (`sparkout_datasets::mill::true_machine`);
//! points are uniform in the 600 × 400 × 300 mm workspace with 2 µm noise.

use criterion::{criterion_group, criterion_main, Criterion};
use sparkout_plugins::mill::chain::{Point, V3 as Vector3};
use sparkout_plugins::mill::identify::{identify, IdentOptions, Obs};
use std::hint::black_box;

mod common;

const N: usize = 2000;

fn points() -> (sparkout_plugins::mill::chain::Layout, Vec<Obs>) {
    let machine = sparkout_datasets::mill::machine().expect("built-in machine");
    let mut truth = sparkout_datasets::mill::true_machine(&machine, 1);
    truth.set_frame(
        &Vector3::new(0.3, -0.9, 1.7),
        &Vector3::new(1600.0, -500.0, 250.0),
    );
    let mut s: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut uni = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let obs = (0..N)
        .map(|i| {
            let q = [0, 1, 2].map(|a| {
                let (lo, hi) = machine.travels[a];
                lo + (hi - lo) * uni()
            });
            let pt = Point {
                q,
                tool: machine.tools[i % machine.tools.len()],
            };
            // Irwin–Hall(4) noise, σ = 2 µm.
            let mut g = || (uni() + uni() + uni() + uni() - 2.0) * 3f64.sqrt() * 0.002;
            let e = Vector3::new(g(), g(), g());
            Obs {
                pt,
                m: truth.tracker_point(&pt) + e,
            }
        })
        .collect();
    (truth.layout.clone(), obs)
}

fn bench(c: &mut Criterion) {
    common::register_references(c, "mill_identification");
    let (layout, obs) = points();
    let mut g = c.benchmark_group("mill_identification");
    g.sample_size(10);
    g.bench_function("2000_points_60_params", |b| {
        b.iter(|| {
            let id = identify(layout.clone(), black_box(&obs), &IdentOptions::default())
                .expect("identifiable");
            black_box(id.sigma_mm)
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);

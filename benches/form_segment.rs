//! Criterion bench of the form plugin's segmentation: the
//! curvature of a 2000-point design profile (a tangent cam with straight
//! flanks) and the segment sweep N = 1…10 over the source's wheel (175 mm,
//! usable range 50 mm), 11 radii sampled per segment — 55 segments ×
//! 11 radii × 2000 points = 1.21 M evaluations of δ(φ) per sweep.

use criterion::{criterion_group, criterion_main, Criterion};
use sparkout_plugins::form::curvature::{CurvatureConfig, Profile};
use sparkout_plugins::form::model::{DeltaModel, WheelRange};
use sparkout_plugins::form::segment::sweep;
use sparkout_plugins::form::shapes::{sample, TangentCam};
use std::hint::black_box;

mod common;

fn bench(c: &mut Criterion) {
    common::register_references(c, "form_segment");
    let cam = TangentCam {
        base: 40.0,
        nose: 14.0,
        lift_centre: 36.0,
    };
    let (phi, r) = sample(2000, |p| cam.r(p));
    let range = WheelRange {
        r_max_mm: 175.0,
        range_mm: 50.0,
    };
    let mut g = c.benchmark_group("form_segment");
    g.bench_function("curvature_2000", |b| {
        b.iter(|| {
            Profile::new(black_box(&phi), black_box(&r), &CurvatureConfig::default()).unwrap()
        })
    });
    let p = Profile::new(&phi, &r, &CurvatureConfig::default()).unwrap();
    g.bench_function("sweep_1_to_10_segments_2000_points", |b| {
        b.iter(|| sweep(black_box(&p), &range, 10, 11, DeltaModel::Published).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);

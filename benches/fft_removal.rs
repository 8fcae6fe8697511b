//! Criterion bench of the Preston removal convolution (issue 5, item 10): a
//! 2048 × 2048 dwell map convolved ("same") with the disc tool's influence
//! function (201 × 201 nodes: a 100 mm radius tool on a 1 mm grid) by FFT
//! (realfft rows + rustfft columns). Reference: benches/reference/fftconvolve.py
//! (scipy.signal.fftconvolve on the same sizes).

use criterion::{criterion_group, criterion_main, Criterion};
use sparkout_plugins::gantry::tool_influence::{fft_convolve_same, PolishTool};
use std::hint::black_box;

mod common;

const N: usize = 2048;

fn bench(c: &mut Criterion) {
    common::register_references(c, "fft_removal");
    let tool = PolishTool {
        k_p_per_pa: 1.7097e-8,
        pressure_pa: 389.93,
        radius_mm: 100.0,
        rev_per_s: 2.5,
        linear_speed_mm_s: 1000.0,
        spring_compression_mm: 0.5,
        feed_mm_s: 100.0,
        step_over_mm: 50.0,
        accel_mm_s2: 500.0,
    };
    let (ker, kx, ky) = tool.kernel(1.0, 1.0);
    let mut s: u64 = 0x9E37_79B9_7F4A_7C15;
    let dwell: Vec<f64> = (0..N * N)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 * 0.01
        })
        .collect();
    c.bench_function("fft removal 2048x2048 (201x201 tool)", |b| {
        b.iter(|| black_box(fft_convolve_same(black_box(&dwell), N, N, &ker, kx, ky)))
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench
}
criterion_main!(benches);

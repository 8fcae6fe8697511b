//! Criterion bench of the Preston removal convolution: a
//! 2048 × 2048 dwell map convolved ("same") with the disc tool's influence
//! function (201 × 201 nodes: a 100 mm radius tool on a 1 mm grid) by FFT
//! (realfft rows + rustfft columns). Reference: benches/reference/fftconvolve.py
//! (scipy.signal.fftconvolve on the same sizes).

use criterion::{criterion_group, Criterion};
use sparkout_plugins::gantry::tool_influence::{fft_convolve_same, Convolver, PolishTool};
use std::hint::black_box;

mod common;

const N: usize = 2048;

fn tool() -> PolishTool {
    PolishTool {
        k_p_per_pa: 1.7097e-8,
        pressure_pa: 389.93,
        radius_mm: 100.0,
        rev_per_s: 2.5,
        linear_speed_mm_s: 1000.0,
        spring_compression_mm: 0.5,
        feed_mm_s: 100.0,
        step_over_mm: 50.0,
        accel_mm_s2: 500.0,
    }
}

/// A uniform random n×n dwell map (xorshift64, fixed seed).
fn dwell(n: usize) -> Vec<f64> {
    let mut s: u64 = 0x9E37_79B9_7F4A_7C15;
    (0..n * n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 * 0.01
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    common::register_references(c, "fft_removal");
    let (ker, kx, ky) = tool().kernel(1.0, 1.0);
    let dwell = dwell(N);
    c.bench_function("fft removal 2048x2048 (201x201 tool)", |b| {
        b.iter(|| black_box(fft_convolve_same(black_box(&dwell), N, N, &ker, kx, ky)))
    });
    // Steady state: plans and the tool's spectrum kept
    // across calls, as the dwell solver and repeated removals use them.
    let conv = Convolver::new(N, N, &ker, kx, ky);
    c.bench_function(
        "fft removal 2048x2048 (201x201 tool), spectrum cached",
        |b| b.iter(|| black_box(conv.apply(black_box(&dwell)))),
    );
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench
}

fn main() {
    common::run_or_scale(benches, scaling);
}

/// `SPARKOUT_BENCH_SCALING=1 cargo bench --bench fft_removal`:
/// the same convolution for N = 512 … 4096 (201² tool), best of 3,
/// with the cost exponent of each doubling (N² log N predicts ≈ 2.1–2.2).
/// `python3 benches/reference/fftconvolve.py --scaling` times scipy alike.
fn scaling() {
    let (ker, kx, ky) = tool().kernel(1.0, 1.0);
    let mut prev: Option<(f64, f64)> = None;
    for n in [512usize, 1024, 2048, 4096] {
        let d = dwell(n);
        let secs = common::best_of(3, || {
            black_box(fft_convolve_same(black_box(&d), n, n, &ker, kx, ky));
        });
        let exponent = common::exponent_text(prev, n as f64, secs);
        println!(
            "fft_removal scaling N = {n:>4}: {:>8.1} ms{exponent}",
            secs * 1e3
        );
        prev = Some((n as f64, secs));
    }
}

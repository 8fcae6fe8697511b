//! Criterion bench of the AE kernel: RMS envelope + contact
//! events (threshold, dwell, hysteresis) over a raw 1 MHz signal from memory,
//! fed in `AeStream`-sized chunks. Target ≥ 300 M samples/s on one core.
//!
//! The signal: 8 Mi samples (8.4 s at 1 MHz) of Gaussian noise (5 mV) with a
//! contact burst (0.15 V, 250 kHz carrier, 2 ms decay) every 50 ms — a dense
//! probing log, so the slow in-contact path is exercised as in a real run.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use sparkout_plugins::robot::ae::{AeDetector, AeParams};
use std::hint::black_box;

mod common;

const N: usize = 8 << 20;
const FS: f64 = 1e6;
const CHUNK: usize = 1 << 18; // AeStream::DEFAULT_BATCH_ROWS

fn signal() -> (Vec<f64>, Vec<f32>) {
    let mut s: u64 = 0x2545_F491_4F6C_DD1D;
    let mut uni = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let t: Vec<f64> = (0..N).map(|i| i as f64 / FS).collect();
    let period = 50_000usize;
    let v: Vec<f32> = (0..N)
        .map(|i| {
            // Irwin–Hall(4) noise, scaled to σ ≈ 5 mV.
            let g = (uni() + uni() + uni() + uni() - 2.0) * 3f64.sqrt();
            let mut x = 0.005 * g;
            let k = i % period;
            if i >= period && k < 20_000 {
                let dt = k as f64 / FS;
                x += 0.15 * (-dt / 2e-3).exp() * (2.0 * std::f64::consts::PI * 250e3 * dt).sin();
            }
            x as f32
        })
        .collect();
    (t, v)
}

fn bench(c: &mut Criterion) {
    common::register_references(c, "ae_kernel");
    let (t, v) = signal();
    let p = AeParams::from_seconds(FS, 1e-3, 8.0, 0.5e-3, 0.5, 5e-3);
    let mut g = c.benchmark_group("ae_kernel");
    g.throughput(Throughput::Elements(N as u64));
    g.sample_size(20);
    g.bench_function("envelope_events_1MHz_chunked", |b| {
        let mut events = Vec::with_capacity(1024);
        b.iter(|| {
            events.clear();
            let mut det = AeDetector::new(p);
            for (tc, vc) in t.chunks(CHUNK).zip(v.chunks(CHUNK)) {
                det.feed(black_box(tc), black_box(vc), &mut events);
            }
            det.finish(&mut events);
            assert_eq!(
                events.len(),
                N / 50_000 - 1 + (!N.is_multiple_of(50_000)) as usize
            );
            black_box(events.len())
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);

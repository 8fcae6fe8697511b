//! Criterion bench of the guide-way predictor: AR order
//! search by FPE over p = 1..20 on the twice-differenced series, online RLS
//! of the chosen order, one-step prediction undone to δz, scalar Kalman
//! fusion and a 20-step forecast — over 10⁶ samples of δz.
//!
//! The series: ARIMA(4,2,0) (docs/models.md §3.2's Φ(B)(1 − B)²δz = ε) driven by
//! Irwin–Hall(4) noise from a xorshift64 generator, 1 µm innovations, in mm.
//! benches/reference/ar_fpe.py builds the identical series and times
//! statsmodels' AutoReg per order on it (target: ≥ 20× faster here).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use sparkout_plugins::guideway::config::PredictorConfig;
use sparkout_plugins::guideway::predictor::predict;
use sparkout_plugins::guideway::{ar_fpe, rls::Rls};
use std::hint::black_box;

mod common;

const N: usize = 1_000_000;
const AR: [f64; 4] = [0.5, -0.3, 0.25, -0.3];

/// Same generator as benches/reference/ar_fpe.py.
pub fn series() -> Vec<f64> {
    let mut s: u64 = 0x2545_F491_4F6C_DD1D;
    let mut uni = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut y = vec![0.0; N];
    for t in 0..N {
        let e = (uni() + uni() + uni() + uni() - 2.0) * 3f64.sqrt() * 1e-3;
        let mut v = e;
        for (i, a) in AR.iter().enumerate() {
            if t > i {
                v += a * y[t - 1 - i];
            }
        }
        y[t] = v;
    }
    for _ in 0..2 {
        let mut acc = 0.0;
        for v in y.iter_mut() {
            acc += *v;
            *v = acc;
        }
    }
    y
}

fn bench(c: &mut Criterion) {
    common::register_references(c, "guideway_predictor");
    let dz = series();
    let mut table = toml::Table::new();
    table.insert("p_max".into(), toml::Value::Integer(20));
    let cfg = PredictorConfig::from_table(&table, None).unwrap();
    // Once, untimed: what to compare with benches/reference/ar_fpe.py.
    let p = predict(&dz, &cfg).expect("predict");
    let fpe: Vec<String> = p.search.fpe[..5]
        .iter()
        .map(|v| format!("{v:.4e}"))
        .collect();
    eprintln!("order {}; FPE(1..5) {fpe:?}", p.search.order);
    let mut g = c.benchmark_group("guideway_predictor");
    g.throughput(Throughput::Elements(N as u64));
    g.sample_size(10);
    g.bench_function("fpe20_rls_kalman_1e6", |b| {
        b.iter(|| {
            let p = predict(black_box(&dz), &cfg).expect("predict");
            black_box(p.prediction_error_var_mm2)
        })
    });
    // The two kernels gated separately: the
    // FPE order search p ≤ 20 over the twice-differenced 10⁶ samples (the
    // numpy normal-equations reference in benches/reference/ar_fpe_numpy.py),
    // and RLS of the chosen order over the same samples.
    let y = ar_fpe::difference(&dz, cfg.d);
    g.bench_function("fpe_search_p20_1e6", |b| {
        b.iter(|| {
            let s = ar_fpe::fpe_search(black_box(&y), 20).expect("search");
            black_box(s.order)
        })
    });
    let order = p.search.order;
    g.bench_function("rls_chosen_order_1e6", |b| {
        b.iter(|| {
            let mut rls = Rls::new(order, cfg.p0, cfg.forgetting);
            let mut x = vec![0.0; order];
            let mut last = 0.0;
            for t in order..y.len() {
                for (i, v) in x.iter_mut().enumerate() {
                    *v = y[t - 1 - i];
                }
                last = rls.update(&x, y[t]);
            }
            black_box(last)
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);

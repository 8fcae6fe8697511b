//! Criterion bench of the gap diagnosis (issue 4, point 8): 10⁶ observations
//! × the full catalogue × 5 folds by run, target ≤ 10 s on 2 cores.
//!
//! The fleet: 20 runs × 100×100 grid × 5 passes = 10⁶ rows with all eleven
//! covariates of the generator (so every catalogue candidate applies) and a
//! drift + backlash gap, so forward selection runs two rounds plus the stop
//! round — the realistic worst case rather than a no-gap shortcut.

use criterion::{criterion_group, Criterion};
use sparkout_datasets::observations::{generate, ObsFleetConfig};
use sparkout_pipeline::diagnose::{diagnose, DiagnoseConfig};
use sparkout_pipeline::EffectSpec;
use std::time::Duration;

mod common;

fn bench_diagnose(c: &mut Criterion) {
    common::register_references(c, "diagnose");
    let cfg = ObsFleetConfig {
        runs: 20,
        seed: 7,
        noise_mm: 0.001,
        nx: 100,
        ny: 100,
        spacing_mm: 1.0,
        passes: 5,
        replicate_fraction: 0.0,
        observable: "surface_z".into(),
    };
    let effects: Vec<EffectSpec> = vec![
        "drift:t_s=amplitude_mm=0.01,tau_s=20000".parse().unwrap(),
        "backlash:dir=b_mm=0.004".parse().unwrap(),
    ];
    let obs = generate(&cfg, &effects).expect("fleet");
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
    g.finish();
}

criterion_group!(benches, bench_diagnose);

/// `SPARKOUT_BENCH_VALIDATE=1 cargo bench --bench diagnose` also times
/// `sparkout validate --quick` and the full validation (issue 4 point 6:
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
    benches();
    Criterion::default().configure_from_args().final_summary();
}

//! The guideway plugin's numerics on generated data (item 9), its
//! stages through the binary (items 1–4), and bad inputs (each a clear
//! error naming file, column and row; the batch goes on).

use crate::common;
use common::sparkout;

use std::path::Path;

use sparkout_datasets::guideway::{
    generate_fleet, resolve_effects, simulate, table, trending_ar, GuidewayFleetConfig, GuidewayRun,
};
use sparkout_pipeline::contracts::write_parquet_atomic;
use sparkout_plugins::guideway::ar_fpe::{batch_ls, difference};
use sparkout_plugins::guideway::config::PredictorConfig;
use sparkout_plugins::guideway::input::{prepare, Geometry, InputOptions, RawReadings, Readings};
use sparkout_plugins::guideway::predictor::predict;
use sparkout_plugins::guideway::three_probe::{
    separate_lsq, separate_recursion, Reference, Separation,
};

fn readings(run: &GuidewayRun, cfg: &GuidewayFleetConfig) -> Readings {
    let raw = RawReadings {
        n: run.n.clone(),
        x_mm: run.x_mm.clone(),
        z_mm: run.z_mm.clone(),
        dir: Some(run.dir.clone()),
        t_s: Some(run.t_s.clone()),
        temp_c: Some(run.temp_c.clone()),
        infeed_count: None,
    };
    let g = Geometry {
        spacing_mm: cfg.k as f64 * cfg.step_mm,
        step_mm: cfg.step_mm,
        speed_mm_s: cfg.speed_mm_s,
    };
    prepare(
        Path::new("guideway.parquet"),
        raw,
        &g,
        &InputOptions::default(),
    )
    .unwrap()
}

/// Least-squares line a + b·j through e.
fn line_fit(e: &[f64]) -> (f64, f64) {
    let n = e.len() as f64;
    let xm = (n - 1.0) / 2.0;
    let ym = e.iter().sum::<f64>() / n;
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (i, y) in e.iter().enumerate() {
        sxy += (i as f64 - xm) * (y - ym);
        sxx += (i as f64 - xm).powi(2);
    }
    let b = sxy / sxx;
    (ym - b * xm, b)
}

fn quiet_cfg(seed: u64) -> GuidewayFleetConfig {
    GuidewayFleetConfig {
        seed,
        passes: 4,
        probe_noise_mm: 0.0,
        zero_offset_mm: 0.0,
        zero_curvature_mm: 0.0,
        ..Default::default()
    }
}

#[test]
fn noise_free_separation_is_exact_up_to_a_line() {
    for seed in [1, 2] {
        let cfg = quiet_cfg(seed);
        let fx = resolve_effects(&[
            "reversal".parse().unwrap(),
            "thermal_infeed".parse().unwrap(),
        ])
        .unwrap();
        let run = simulate(&cfg, &fx, &[], 0);
        let r = readings(&run, &cfg);
        let sols: Vec<Separation> = vec![
            separate_recursion(&r).unwrap(),
            separate_lsq(&r, Reference::Line, 1e-4).unwrap(),
            separate_lsq(&r, Reference::Ends, 1e-4).unwrap(),
        ];
        for s in &sols {
            let e: Vec<f64> = s
                .h_mm
                .iter()
                .zip(&run.truth.h_mm)
                .map(|(a, b)| a - b)
                .collect();
            let (a, b) = line_fit(&e);
            let worst_h = e
                .iter()
                .enumerate()
                .map(|(j, v)| (v - a - b * j as f64).abs())
                .fold(0.0, f64::max);
            assert!(worst_h < 1e-10, "{:?}: h off a line by {worst_h}", s.method);
            // δz takes the complementary line at probe A's point.
            let worst_dz = (0..r.len())
                .map(|i| (s.dz_mm[i] - run.truth.dz_mm[i] + a + b * r.j[i] as f64).abs())
                .fold(0.0, f64::max);
            assert!(worst_dz < 1e-10, "{:?}: δz off by {worst_dz}", s.method);
        }
    }
}

/// RMS over a slice.
fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

#[test]
fn lsq_error_grows_more_slowly_along_the_travel_than_the_recursion() {
    // The error each method adds to h from reading noise, in its own
    // reference: method(noisy) − method(noise-free), same everything else.
    let (mut rec_end, mut lsq_end, mut rec_growth, mut lsq_growth) = (0.0, 0.0, 0.0, 0.0);
    let seeds = 6;
    for seed in 0..seeds {
        let exact = quiet_cfg(seed);
        let noisy = GuidewayFleetConfig {
            probe_noise_mm: 1e-4,
            ..exact.clone()
        };
        let fx = resolve_effects(&[]).unwrap();
        let (re, rn) = (
            readings(&simulate(&exact, &fx, &[], 0), &exact),
            readings(&simulate(&noisy, &fx, &[], 0), &noisy),
        );
        let err = |a: &Separation, b: &Separation| -> Vec<f64> {
            a.h_mm.iter().zip(&b.h_mm).map(|(x, y)| x - y).collect()
        };
        let e_rec = err(
            &separate_recursion(&rn).unwrap(),
            &separate_recursion(&re).unwrap(),
        );
        let e_lsq = err(
            &separate_lsq(&rn, Reference::Line, 1e-4).unwrap(),
            &separate_lsq(&re, Reference::Line, 1e-4).unwrap(),
        );
        let q = e_rec.len() / 4;
        let m = e_rec.len();
        rec_end += rms(&e_rec[m - q..]);
        lsq_end += rms(&e_lsq[m - q..]);
        rec_growth += rms(&e_rec[m - q..]) / rms(&e_rec[..q]).max(1e-15);
        lsq_growth += rms(&e_lsq[m - q..]) / rms(&e_lsq[..q]).max(1e-15);
    }
    let n = seeds as f64;
    let (rec_end, lsq_end, rec_growth, lsq_growth) =
        (rec_end / n, lsq_end / n, rec_growth / n, lsq_growth / n);
    eprintln!(
        "h error, last quarter: lsq {lsq_end:.3e} mm, recursion {rec_end:.3e} mm; growth last/first quarter: lsq {lsq_growth:.2}, recursion {rec_growth:.2}"
    );
    // The recursion starts exact and integrates the noise twice along the
    // travel; the LS solve spreads it over the travel and averages passes.
    assert!(
        lsq_end < 0.5 * rec_end,
        "error over the last quarter: lsq {lsq_end:e} vs recursion {rec_end:e}"
    );
    assert!(
        lsq_growth < 0.5 * rec_growth,
        "growth last/first quarter: lsq {lsq_growth} vs recursion {rec_growth}"
    );
}

fn ar4_series(seed: u64, len: usize) -> Vec<f64> {
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    // Φ(B)(1 − B)²δz = ε exactly (pole 1), 1 µm-scale innovations.
    trending_ar(&[0.5, -0.3, 0.25, -0.3], 1.0, len, 1.0, &mut rng)
        .iter()
        .map(|v| v * 1e-3)
        .collect()
}

#[test]
fn fpe_picks_the_true_order_of_an_ar4_in_most_seeds() {
    let cfg = PredictorConfig::from_table(&toml::Table::new(), None).unwrap();
    let mut hits = 0;
    let seeds = 10;
    for seed in 0..seeds {
        // Scale the integrated series so the innovations are ~1 µm.
        let dz = ar4_series(seed, 3000);
        let y = difference(&dz, 2);
        let s = (y.iter().map(|v| v * v).sum::<f64>() / y.len() as f64).sqrt();
        let dz: Vec<f64> = dz.iter().map(|v| v / s * 1e-3).collect();
        let p = predict(&dz, &cfg).unwrap();
        if p.search.order == 4 {
            hits += 1;
        }
    }
    assert!(
        hits * 10 >= seeds * 6,
        "FPE chose 4 in {hits} of {seeds} seeds"
    );
}

#[test]
fn rls_converges_to_the_batch_least_squares_coefficients() {
    let cfg = PredictorConfig::from_table(&toml::Table::new(), None).unwrap();
    let dz = ar4_series(3, 5000);
    let y = difference(&dz, 2);
    let s = (y.iter().map(|v| v * v).sum::<f64>() / y.len() as f64).sqrt();
    let dz: Vec<f64> = dz.iter().map(|v| v / s * 1e-3).collect();
    let p = predict(&dz, &cfg).unwrap();
    let order = p.search.order;
    let y = difference(&dz, 2);
    let batch = batch_ls(&y, order, order);
    for (a, b) in p.rls_coefficients.iter().zip(&batch) {
        assert!(
            (a - b).abs() < 1e-3,
            "rls {:?} vs batch {batch:?}",
            p.rls_coefficients
        );
    }
}

fn generate(root: &Path, runs: usize) {
    let cfg = GuidewayFleetConfig {
        runs,
        seed: 7,
        passes: 6,
        ..Default::default()
    };
    generate_fleet(root, &cfg, &[]).unwrap();
}

fn json(out: &std::process::Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn stages_run_alone_with_json_and_the_method_flag() {
    let d = tempfile::tempdir().unwrap();
    generate(d.path(), 1);
    let run = d.path().join("guideway-grinder/r0000");
    let run = run.to_str().unwrap();
    let s = json(&sparkout(&["stage", "separate", "--run", run, "--json"]));
    assert_eq!(s["method"], "lsq");
    assert!(s["n"].as_u64().unwrap() > 100);
    assert!(s["h_rms_mm"].as_f64().unwrap() > 0.0 && s["dz_rms_mm"].as_f64().unwrap() > 0.0);
    let s = json(&sparkout(&[
        "stage",
        "separate",
        "--run",
        run,
        "--method",
        "recursion",
        "--json",
    ]));
    assert_eq!(s["method"], "recursion");
    let bad = sparkout(&["stage", "separate", "--run", run, "--method", "fft"]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--method"));
    let out = d.path().join("pred");
    let p = json(&sparkout(&[
        "stage",
        "predictor",
        "--run",
        run,
        "--json",
        "--out",
        out.to_str().unwrap(),
    ]));
    assert_eq!(p["d"], 2);
    let order = p["order"].as_u64().unwrap() as usize;
    assert_eq!(p["coefficients"].as_array().unwrap().len(), order);
    assert_eq!(p["fpe"].as_array().unwrap().len(), 10);
    assert!(p["prediction_error_var_mm2"].as_f64().unwrap() > 0.0);
    for f in ["predictor.parquet", "ar_fpe.parquet", "forecast.parquet"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    // Run-less forms: a guideway.parquet with its geometry; any δz column.
    let gw = Path::new(run).join("guideway.parquet");
    let s = json(&sparkout(&[
        "stage",
        "separate",
        "--guideway",
        gw.to_str().unwrap(),
        "--spacing-mm",
        "30",
        "--step-mm",
        "30",
        "--method",
        "recursion",
        "--json",
    ]));
    assert_eq!(s["method"], "recursion");
    assert_eq!(s["other"]["method"], "lsq");
    let series = out.join("predictor.parquet");
    let q = json(&sparkout(&[
        "stage",
        "predictor",
        "--series",
        series.to_str().unwrap(),
        "--column",
        "dz_mm",
        "--p-max",
        "5",
        "--json",
    ]));
    assert_eq!(q["fpe"].as_array().unwrap().len(), 5);
    let bad = sparkout(&[
        "stage",
        "predictor",
        "--series",
        series.to_str().unwrap(),
        "--column",
        "nope",
    ]);
    assert!(String::from_utf8_lossy(&bad.stderr).contains("nope"));
    // The compensation curve is replayable: t_s strictly increasing, dz_mm.
    let cdir = d.path().join("comp");
    let c = json(&sparkout(&[
        "stage",
        "compensation",
        "--run",
        run,
        "--json",
        "--out",
        cdir.to_str().unwrap(),
    ]));
    assert!(c["rows"].as_u64().unwrap() > 100);
    let f = std::fs::File::open(cdir.join("compensation.parquet")).unwrap();
    let reader = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(f)
        .unwrap()
        .build()
        .unwrap();
    let mut t = Vec::new();
    for b in reader {
        let b = b.unwrap();
        assert!(b.column_by_name("dz_mm").is_some());
        let a = b
            .column_by_name("t_s")
            .unwrap()
            .as_any()
            .downcast_ref::<arrow::array::Float64Array>()
            .unwrap()
            .clone();
        t.extend(a.values().iter().copied());
    }
    assert!(t.windows(2).all(|w| w[1] > w[0]));
}

#[test]
fn bad_inputs_are_named_and_the_batch_goes_on() {
    let d = tempfile::tempdir().unwrap();
    let root = d.path().join("runs");
    generate(&root, 5);
    let m = root.join("guideway-grinder");
    let cfg = GuidewayFleetConfig {
        seed: 7,
        passes: 6,
        ..Default::default()
    };
    let fx = resolve_effects(&[]).unwrap();
    let base = |i: usize| simulate(&cfg, &fx, &[], i);
    // r0001: a gap in n at row 40.
    let mut r = base(1);
    for v in r.n[40..].iter_mut() {
        *v += 1;
    }
    write_parquet_atomic(&m.join("r0001/guideway.parquet"), &table(&r)).unwrap();
    // r0002: probe B stuck from row 100.
    let mut r = base(2);
    for v in r.z_mm[1][100..120].iter_mut() {
        *v = 0.0123;
    }
    write_parquet_atomic(&m.join("r0002/guideway.parquet"), &table(&r)).unwrap();
    // r0003: probe spacing 45 mm with a 30 mm step.
    let toml_path = m.join("r0003/run.toml");
    let t = std::fs::read_to_string(&toml_path)
        .unwrap()
        .replace("probe_spacing_mm = 30.0", "probe_spacing_mm = 45.0");
    std::fs::write(&toml_path, t).unwrap();
    // r0004: too short for p_max = 10 (20 samples; d + 2·p_max + 2 = 24).
    let mut r = base(4);
    for v in [&mut r.x_mm, &mut r.t_s, &mut r.temp_c] {
        v.truncate(20);
    }
    for v in r.z_mm.iter_mut() {
        v.truncate(20);
    }
    r.n.truncate(20);
    r.dir.truncate(20);
    write_parquet_atomic(&m.join("r0004/guideway.parquet"), &table(&r)).unwrap();

    let out = d.path().join("out");
    let o = sparkout(&[
        "run",
        "--input",
        root.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(
        o.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let f: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("failures.json")).unwrap()).unwrap();
    let by_run = |id: &str| {
        f.as_array()
            .unwrap()
            .iter()
            .find(|x| x["run"] == id)
            .unwrap_or_else(|| panic!("{id} not rejected: {f:#}"))
            .clone()
    };
    let e = by_run("r0001");
    assert_eq!(
        (e["column"].as_str(), e["row"].as_u64()),
        (Some("n"), Some(40)),
        "{e}"
    );
    assert!(e["file"].as_str().unwrap().ends_with("guideway.parquet"));
    let e = by_run("r0002");
    assert_eq!(
        (e["column"].as_str(), e["row"].as_u64()),
        (Some("zb_mm"), Some(100)),
        "{e}"
    );
    assert!(e["error"].as_str().unwrap().contains("stuck"));
    let e = by_run("r0003");
    assert!(
        e["error"].as_str().unwrap().contains("not a whole number"),
        "{e}"
    );
    let e = by_run("r0004");
    assert!(e["error"].as_str().unwrap().contains("too short"), "{e}");
    assert_eq!(e["column"], "n");
    // The good run went through; nothing of the rejected ones was written.
    assert!(out
        .join("guideway-grinder/r0000/compensation.parquet")
        .is_file());
    assert!(!out.join("guideway-grinder/r0001").exists());
    // Interpolation makes the 45 mm spacing usable.
    let o = sparkout(&[
        "stage",
        "separate",
        "--run",
        m.join("r0003").to_str().unwrap(),
        "--json",
        "--interpolate",
        "true",
    ]);
    let s = json(&o);
    assert_eq!(s["resampled"], true);
}

/// The default (least-squares) separation and the
/// predictor on a 30 000-sample trace (10 000 grid points, 3 passes).
#[test]
fn predictor_runs_on_a_30000_sample_trace_with_the_default_method() {
    let d = tempfile::tempdir().unwrap();
    let cfg = GuidewayFleetConfig {
        runs: 1,
        seed: 17,
        points: 10_002,
        passes: 3,
        ..Default::default()
    };
    generate_fleet(d.path(), &cfg, &[]).unwrap();
    let run = d.path().join("guideway-grinder/r0000");
    let run = run.to_str().unwrap();
    let s = json(&sparkout(&["stage", "separate", "--run", run, "--json"]));
    assert_eq!(s["method"], "lsq");
    assert_eq!(s["n"], 30_000);
    assert!(s["h_sigma_max_mm"].as_f64().unwrap() > 0.0);
    assert_eq!(s["sigma_source"], "residuals");
    let p = json(&sparkout(&["stage", "predictor", "--run", run, "--json"]));
    assert_eq!(p["n"], 30_000);
    assert_eq!(p["criterion"], "fpe");
    let order = p["order"].as_u64().unwrap();
    assert_eq!(p["orders"]["fpe"].as_u64().unwrap(), order);
    for c in ["fpe", "bic", "hq"] {
        assert_eq!(p[c].as_array().unwrap().len(), 10, "{c}");
        let o = p["orders"][c].as_u64().unwrap();
        assert!((1..=10).contains(&o), "{c}: {o}");
    }
    // The consistent criteria penalise each extra lag more than FPE does.
    assert!(p["orders"]["bic"].as_u64() <= p["orders"]["hq"].as_u64());
    let b = json(&sparkout(&[
        "stage",
        "predictor",
        "--run",
        run,
        "--criterion",
        "bic",
        "--json",
    ]));
    assert_eq!(b["criterion"], "bic");
    assert_eq!(b["order"], p["orders"]["bic"]);
    assert!(
        !sparkout(&["stage", "predictor", "--run", run, "--criterion", "aic"])
            .status
            .success()
    );
}

/// How often FPE, BIC and HQ pick the true order of
/// Φ(B)(1 − B)²δz = ε on 3 000-sample traces, 60 seeds per model (the
/// docs/guideway.md's table: `cargo test --workspace --test e2e order_selection --
/// --nocapture`).
#[test]
fn order_selection_hit_rates_of_fpe_bic_and_hq() {
    use rand::SeedableRng;
    use sparkout_plugins::guideway::ar_fpe::{fpe_search, Criterion};
    let models: [&[f64]; 4] = [
        &[0.6],
        &[0.5, -0.3],
        &[0.5, -0.3, 0.1],
        &[0.5, -0.3, 0.25, -0.3],
    ];
    let seeds = 60u64;
    let p_max = PredictorConfig::from_table(&toml::Table::new(), None)
        .unwrap()
        .p_max;
    println!("| true model | criterion | true order | under | over |");
    println!("|---|---|---|---|---|");
    let mut bic_hits_ar4 = 0;
    for coef in models {
        let p_true = coef.len();
        let mut tally = [[0usize; 3]; 3];
        for seed in 0..seeds {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1000 * p_true as u64 + seed);
            let dz: Vec<f64> = trending_ar(coef, 1.0, 3000, 1.0, &mut rng)
                .iter()
                .map(|v| v * 1e-3)
                .collect();
            let s = fpe_search(&difference(&dz, 2), p_max).unwrap();
            let (ob, oh) = (s.order_by(Criterion::Bic), s.order_by(Criterion::Hq));
            assert!(ob <= oh, "seed {seed}: BIC {ob} > HQ {oh}");
            for (c, t) in Criterion::ALL.iter().zip(tally.iter_mut()) {
                let o = s.order_by(*c);
                t[(o != p_true) as usize + (o > p_true) as usize] += 1;
            }
            if p_true == 4 && ob == 4 {
                bic_hits_ar4 += 1;
            }
        }
        for (c, t) in Criterion::ALL.iter().zip(tally) {
            println!(
                "| AR({p_true}) {coef:?} | {} | {}/{seeds} | {} | {} |",
                c.as_str().to_uppercase(),
                t[0],
                t[1],
                t[2]
            );
        }
    }
    // BIC is consistent: with 3 000 samples it should rarely miss an AR(4)
    // whose coefficients are all well away from zero.
    assert!(
        bic_hits_ar4 * 10 >= seeds as usize * 8,
        "BIC picked 4 in {bic_hits_ar4} of {seeds}"
    );
}

//! The synthetic robot fleet generator (datasets/src/robot.rs) against the
//! data contracts and docs/robot_data_spec.md: every table validates, output
//! is deterministic, the AE bursts, motion log and truth agree, and injected
//! effects show where the spec says they do.

use crate::common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use sparkout_datasets::robot::{generate_fleet, known_effects, ProbeMode, RobotFleetConfig};
use sparkout_pipeline::contracts::schema::MOTION;
use sparkout_pipeline::contracts::{AeStream, RunSpec, Table};
use sparkout_pipeline::EffectSpec;
use sparkout_plugins::robot::tables::PASSES;
use sparkout_plugins::robot::tables::PLAN;
use sparkout_plugins::robot::tables::PROBE;

fn tiny(seed: u64) -> RobotFleetConfig {
    RobotFleetConfig {
        runs: 2,
        seed,
        ae_sample_rate_hz: 100e3,
        trials: 2,
        ..RobotFleetConfig::default()
    }
}

fn fx(s: &str) -> EffectSpec {
    s.parse().unwrap()
}

fn truth(run: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(run.join("truth.json")).unwrap()).unwrap()
}

fn f64s(t: &Table, c: &str) -> Vec<f64> {
    t.f64(c).unwrap().to_vec()
}

/// Measured cut per pass (height_before − height_after).
fn cuts(run: &Path) -> Vec<f64> {
    let p = Table::read(&run.join("passes.parquet"), &PASSES).unwrap();
    let b = f64s(&p, "height_before_mm");
    let a = f64s(&p, "height_after_mm");
    b.iter().zip(&a).map(|(b, a)| b - a).collect()
}

/// Every file of a directory tree, relative path → bytes.
fn snapshot(root: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(
                    p.strip_prefix(root).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                );
            }
        }
    }
    out
}

fn read_ae(run: &Path) -> (Vec<f64>, Vec<f32>) {
    let mut t = Vec::new();
    let mut v = Vec::new();
    for c in AeStream::open(&run.join("ae.parquet")).unwrap() {
        let c = c.unwrap();
        t.extend_from_slice(&c.t_s);
        v.extend_from_slice(&c.ae_v);
    }
    (t, v)
}

#[test]
fn every_table_passes_contract_validation() {
    let dir = tempfile::tempdir().unwrap();
    let runs = generate_fleet(dir.path(), &tiny(7), &[]).unwrap();
    assert_eq!(runs.len(), 2);
    assert_eq!(runs[0], dir.path().join("kr16-lab").join("r0000"));
    for (i, run) in runs.iter().enumerate() {
        let spec = RunSpec::load(run).unwrap();
        assert_eq!(spec.id, format!("r{i:04}"));
        assert_eq!(spec.machine, "kr16-lab");
        assert_eq!(spec.plugin, "robot");
        let ae = spec.ae.clone().expect("[ae] present");
        assert_eq!(ae.sample_rate_hz, 100e3);
        assert!(ae.clock_offset_s > 0.0);
        assert_eq!(spec.process_f64("weld_mm", 0.0), 2.27);
        assert_eq!(spec.process_f64("contact_area_mm2", 0.0), 100.0);

        let plan = Table::read(&run.join("plan.parquet"), &PLAN).unwrap();
        assert_eq!(plan.len(), 3 * 12 * 2 * 2);
        let motion = Table::read(&run.join("motion.parquet"), &MOTION).unwrap();
        assert!(motion.len() > 10_000);
        Table::read(&run.join("passes.parquet"), &PASSES).unwrap();
        // ProbeMode::Alternate: even runs have probe.parquet, odd runs are AE-only.
        let probe = run.join("probe.parquet");
        if i % 2 == 0 {
            // The AE program's touches, then the comparison methods'
            // (electrical @ 10, mechanical @ 100 mm/s): every point, every trial.
            let p = Table::read(&probe, &PROBE).unwrap();
            let methods = p.str("method").unwrap();
            let v = f64s(&p, "approach_mm_s");
            let n = |m: &str| methods.iter().filter(|x| **x == m).count();
            assert_eq!(n("ae"), plan.len());
            assert_eq!(n("electrical"), 3 * 12 * 2);
            assert_eq!(n("mechanical"), 3 * 12 * 2);
            assert_eq!(p.len(), plan.len() + 2 * 3 * 12 * 2);
            for (m, s) in methods.iter().zip(&v) {
                match *m {
                    "electrical" => assert_eq!(*s, 10.0),
                    "mechanical" => assert_eq!(*s, 100.0),
                    _ => assert!(*s == 5.0 || *s == 10.0),
                }
            }
        } else {
            assert!(!probe.exists());
        }
        let mut n = 0;
        let mut stream = AeStream::open(&run.join("ae.parquet")).unwrap();
        let total = stream.total_rows();
        for c in &mut stream {
            n += c.unwrap().t_s.len();
        }
        assert_eq!(n, total);
        assert!(n > 100_000, "AE rows {n}");
    }
}

#[test]
fn same_seed_is_byte_identical_whatever_the_threads_and_seed_matters() {
    let a = tempfile::tempdir().unwrap();
    let b = tempfile::tempdir().unwrap();
    let c = tempfile::tempdir().unwrap();
    let effects = [fx("wheel_wear"), fx("thermal_drift=amplitude_mm=0.1")];
    generate_fleet(a.path(), &tiny(11), &effects).unwrap();
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| generate_fleet(b.path(), &tiny(11), &effects).unwrap());
    generate_fleet(c.path(), &tiny(12), &effects).unwrap();
    let (sa, sb, sc) = (snapshot(a.path()), snapshot(b.path()), snapshot(c.path()));
    assert_eq!(sa.len(), 7 + 6, "{:?}", sa.keys().collect::<Vec<_>>());
    assert_eq!(sa.keys().collect::<Vec<_>>(), sb.keys().collect::<Vec<_>>());
    for (k, v) in &sa {
        assert!(
            v == &sb[k],
            "{} differs between runs with the same seed",
            k.display()
        );
    }
    for name in [
        "ae.parquet",
        "motion.parquet",
        "truth.json",
        "passes.parquet",
    ] {
        let k = Path::new("kr16-lab/r0000").join(name);
        assert!(sa[&k] != sc[&k], "{name} identical for different seeds");
    }
}

#[test]
fn ae_bursts_start_at_the_truth_onsets() {
    let dir = tempfile::tempdir().unwrap();
    let runs = generate_fleet(dir.path(), &tiny(3), &[]).unwrap();
    let run = &runs[1];
    let tr = truth(run);
    let sigma = tr["ae_noise_v"].as_f64().unwrap();
    let fs = tr["ae_sample_rate_hz"].as_f64().unwrap();
    let (t, v) = read_ae(run);
    let rms = |lo: f64, hi: f64| -> f64 {
        let i0 = t.partition_point(|&x| x < lo);
        let i1 = t.partition_point(|&x| x < hi);
        assert!(i1 > i0 + 5, "window [{lo}, {hi}] not recorded");
        let s: f64 = v[i0..i1].iter().map(|&x| (x as f64).powi(2)).sum();
        (s / (i1 - i0) as f64).sqrt()
    };
    let contacts = tr["contacts"].as_array().unwrap();
    assert_eq!(contacts.len(), 144);
    for c in contacts {
        let onset = c["ae_t_s"].as_f64().unwrap();
        let ctrl = c["t_s"].as_f64().unwrap();
        let off = tr["ae_clock_offset_s"].as_f64().unwrap();
        assert!((onset + off - ctrl).abs() < 1e-9);
        let before = rms(onset - 0.005, onset - 1e-4);
        let after = rms(onset + 1e-4, onset + 0.001);
        assert!(before < 1.3 * sigma, "noise before onset {before}");
        assert!(after > 10.0 * sigma, "burst after onset {after}");
        // The envelope rises at the onset: the first sample beyond 6σ in the
        // 5 ms before and after lies within 3 samples after the onset.
        let i0 = t.partition_point(|&x| x < onset - 0.005);
        let first = (i0..t.len())
            .find(|&i| (v[i] as f64).abs() > 6.0 * sigma)
            .unwrap();
        assert!(
            t[first] >= onset && t[first] <= onset + 3.0 / fs,
            "first crossing at {} for onset {onset}",
            t[first]
        );
    }
}

/// Linear interpolation of a motion column at time `t`.
fn interp(ts: &[f64], x: &[f64], t: f64) -> f64 {
    let i = ts.partition_point(|&s| s <= t).clamp(1, ts.len() - 1);
    let w = (t - ts[i - 1]) / (ts[i] - ts[i - 1]);
    x[i - 1] + w * (x[i] - x[i - 1])
}

#[test]
fn motion_log_covers_contacts_with_the_plan_segment_and_the_true_point() {
    let dir = tempfile::tempdir().unwrap();
    let runs = generate_fleet(dir.path(), &tiny(5), &[]).unwrap();
    let run = &runs[0];
    let tr = truth(run);
    let m = Table::read(&run.join("motion.parquet"), &MOTION).unwrap();
    let ts = f64s(&m, "t_s");
    let seg = m.i32("segment").unwrap().to_vec();
    let act: Vec<Vec<f64>> = ["act_x_mm", "act_y_mm", "act_z_mm"]
        .iter()
        .map(|c| f64s(&m, c))
        .collect();
    let probe = Table::read(&run.join("probe.parquet"), &PROBE).unwrap();
    let probe_t = f64s(&probe, "t_s");
    let faces: BTreeMap<String, serde_json::Value> =
        serde_json::from_value(tr["faces"].clone()).unwrap();
    for (k, c) in tr["contacts"].as_array().unwrap().iter().enumerate() {
        let t = c["t_s"].as_f64().unwrap();
        let seq = c["seq"].as_i64().unwrap() as i32;
        let i = ts.partition_point(|&s| s <= t);
        assert!(i > 0 && i < ts.len(), "contact {t} outside the motion log");
        assert_eq!(seg[i - 1], seq, "segment before contact");
        assert_eq!(seg[i], seq, "segment after contact");
        let p: Vec<f64> = (0..3).map(|ax| interp(&ts, &act[ax], t)).collect();
        let want = [
            c["x_mm"].as_f64().unwrap(),
            c["y_mm"].as_f64().unwrap(),
            c["z_mm"].as_f64().unwrap(),
        ];
        let surf = [
            c["surface_x_mm"].as_f64().unwrap(),
            c["surface_y_mm"].as_f64().unwrap(),
            c["surface_z_mm"].as_f64().unwrap(),
        ];
        for ax in 0..3 {
            assert!(
                (p[ax] - want[ax]).abs() < 0.002,
                "act at contact {p:?} vs {want:?}"
            );
            // No effect injected: the controller's contact is the surface point.
            assert!((want[ax] - surf[ax]).abs() < 1e-9);
        }
        // The physical contact lies on the true plane (within the contact scatter).
        let plane = faces
            .values()
            .map(|f| {
                let n: Vec<f64> = serde_json::from_value(f["normal"].clone()).unwrap();
                (n[0] * surf[0] + n[1] * surf[1] + n[2] * surf[2] - f["d"].as_f64().unwrap()).abs()
            })
            .fold(f64::INFINITY, f64::min);
        assert!(plane < 0.012, "contact {plane} mm off every true face");
        // Baseline: zero trigger latency, registration at the contact.
        assert!((probe_t[k] - t).abs() < 1e-12);
    }
    for w in ts.windows(2) {
        assert!(w[1] > w[0]);
    }
    // truth `dir` is the sign, along the face's +normal axis, of the last
    // commanded move before the approach segment (the plugin's covariate).
    let plan = Table::read(&run.join("plan.parquet"), &PLAN).unwrap();
    let faces = plan.str("face").unwrap();
    let cmd: Vec<Vec<f64>> = ["cmd_x_mm", "cmd_y_mm", "cmd_z_mm"]
        .iter()
        .map(|c| f64s(&m, c))
        .collect();
    let mut signs = BTreeMap::new();
    for c in tr["contacts"].as_array().unwrap() {
        let seq = c["seq"].as_i64().unwrap() as usize;
        let ax = match faces[seq] {
            "xy" => 2,
            "yz" => 0,
            _ => 1,
        };
        let first = seg.iter().position(|&s| s == seq as i32).unwrap();
        let mut i = first;
        let sign = loop {
            let d = cmd[ax][i] - cmd[ax][i - 1];
            if d.abs() > 1e-9 {
                break d.signum();
            }
            i -= 1;
        };
        assert_eq!(sign, c["dir"].as_f64().unwrap(), "seq {seq}");
        *signs.entry(sign as i64).or_insert(0) += 1;
    }
    assert!(signs[&1] > 20 && signs[&-1] > 20, "{signs:?}");
}

#[test]
fn passes_reproduce_the_compliance_model_with_the_true_alpha() {
    let dir = tempfile::tempdir().unwrap();
    let runs = generate_fleet(dir.path(), &tiny(21), &[]).unwrap();
    for run in &runs {
        let alpha = truth(run)["alpha"].as_f64().unwrap();
        assert!((0.45..=0.55).contains(&alpha));
        let p = Table::read(&run.join("passes.parquet"), &PASSES).unwrap();
        let doc = f64s(&p, "nominal_doc_mm");
        let measured = cuts(run);
        assert_eq!(measured.len(), 11);
        let mut prev = 0.0;
        for (i, (&d, &m)) in doc.iter().zip(&measured).enumerate() {
            let model = (alpha * prev + d) / (1.0 + alpha);
            prev = model;
            // Two readings of 2 µm σ: 6σ of the difference ≈ 17 µm.
            assert!(
                (m - model).abs() < 0.017,
                "pass {} cut {m} vs model {model}",
                i + 1
            );
        }
        // Rough passes follow the closed form [1 − (α/(1+α))^i]·δ′.
        let r = alpha / (1.0 + alpha);
        for (i, &m) in measured.iter().take(7).enumerate() {
            let closed = (1.0 - r.powi(i as i32 + 1)) * 0.3;
            assert!((m - closed).abs() < 0.017);
        }
        // α from the first pass as the thesis does it.
        let alpha_first = 0.3 / measured[0] - 1.0;
        assert!(
            (alpha_first - alpha).abs() < 0.1,
            "{alpha_first} vs {alpha}"
        );
        let hb = f64s(&p, "height_before_mm");
        assert!((hb[0] - 2.27).abs() < 0.01);
        let t0 = f64s(&p, "t_start_s");
        let t1 = f64s(&p, "t_end_s");
        for i in 0..t0.len() {
            assert!(t1[i] > t0[i] && (i == 0 || t0[i] > t1[i - 1]));
        }
    }
}

#[test]
fn wheel_wear_makes_later_cuts_shallower() {
    let base = tempfile::tempdir().unwrap();
    let worn = tempfile::tempdir().unwrap();
    let b = generate_fleet(base.path(), &tiny(9), &[]).unwrap();
    let w = generate_fleet(worn.path(), &tiny(9), &[fx("wheel_wear")]).unwrap();
    for (b, w) in b.iter().zip(&w) {
        // Same seed: same pose, α and noise draws — the difference is the effect.
        let (cb, cw) = (cuts(b), cuts(w));
        let tr = truth(w);
        let removed: Vec<f64> = tr["passes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p["removed_mm3"].as_f64().unwrap())
            .collect();
        let model: Vec<f64> = tr["passes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p["model_cut_mm"].as_f64().unwrap())
            .collect();
        assert_eq!(cb[0], cw[0], "first pass has no prior removal");
        for i in 1..cb.len() {
            let shrink = cb[i] - cw[i];
            let want = (1e-4 * removed[i]).min(model[i]);
            assert!(
                (shrink - want).abs() < 1e-9,
                "pass {}: shrink {shrink} vs k·removed {want}",
                i + 1
            );
        }
        // Later cuts shallower than earlier ones relative to the model,
        // by ≥ 15 µm at the end of roughing (removed ≈ 170 mm³).
        assert!(cb[6] - cw[6] > 0.015);
        assert!(cb[6] - cw[6] > cb[2] - cw[2]);
    }
}

#[test]
fn trigger_latency_drift_and_backlash_show_in_the_touches() {
    let base = tempfile::tempdir().unwrap();
    let late = tempfile::tempdir().unwrap();
    let cfg = RobotFleetConfig {
        with_probe: ProbeMode::All,
        ..tiny(4)
    };
    let b = generate_fleet(base.path(), &cfg, &[]).unwrap();
    let l = generate_fleet(late.path(), &cfg, &[fx("trigger_latency=latency_s=0.02")]).unwrap();
    let pb = Table::read(&b[0].join("probe.parquet"), &PROBE).unwrap();
    let pl = Table::read(&l[0].join("probe.parquet"), &PROBE).unwrap();
    let v = f64s(&pb, "approach_mm_s");
    let faces = pb.str("face").unwrap();
    let tl = f64s(&pl, "t_s");
    let contacts_l = truth(&l[0])["contacts"].as_array().unwrap().clone();
    // The AE program's touches come first; the comparison methods have no
    // AE contact but are registered late all the same (the controller's
    // latency), checked after this loop.
    let methods = pb.str("method").unwrap();
    assert!(methods[..contacts_l.len()].iter().all(|m| *m == "ae"));
    for i in 0..pb.len() {
        if i >= contacts_l.len() {
            let (col, sign) = match faces[i] {
                "xy" => ("z_mm", 1.0),
                "yz" => ("x_mm", -1.0),
                _ => ("y_mm", -1.0),
            };
            let d = sign * (pl.f64(col).unwrap()[i] - pb.f64(col).unwrap()[i]);
            assert!((d + v[i] * 0.02).abs() < 1e-9, "{} row {i}", methods[i]);
            continue;
        }
        let tc = contacts_l[i]["t_s"].as_f64().unwrap();
        assert!(
            (tl[i] - tc - 0.02).abs() < 1e-9,
            "registration delayed by L"
        );
        // Overshoot v·L into the face: the normal coordinate along the
        // outward normal drops by v·L.
        let (col, sign) = match faces[i] {
            "xy" => ("z_mm", 1.0),
            "yz" => ("x_mm", -1.0),
            _ => ("y_mm", -1.0),
        };
        let d = sign * (pl.f64(col).unwrap()[i] - pb.f64(col).unwrap()[i]);
        assert!((d + v[i] * 0.02).abs() < 1e-9, "row {i}: {d} vs −v·L");
    }
    // The AE burst still marks the true contact: the motion log at the
    // burst's controller time is the same point as in the baseline.
    let cb = truth(&b[0]);
    for (x, y) in cb["contacts"].as_array().unwrap().iter().zip(&contacts_l) {
        for k in ["x_mm", "y_mm", "z_mm"] {
            assert!((x[k].as_f64().unwrap() - y[k].as_f64().unwrap()).abs() < 1e-9);
        }
        let off = truth(&l[0])["ae_clock_offset_s"].as_f64().unwrap();
        assert!((y["ae_t_s"].as_f64().unwrap() + off - y["t_s"].as_f64().unwrap()).abs() < 1e-9);
    }

    // Thermal drift (+z TCP) lowers xy-face touches by the drift; backlash
    // shifts every touch's normal-axis coordinate by b/2·dir (dir = sign of
    // the last move along +axis, the plugin's covariate).
    let d = tempfile::tempdir().unwrap();
    let r = generate_fleet(
        d.path(),
        &cfg,
        &[
            fx("thermal_drift=amplitude_mm=0.2,tau_s=100"),
            fx("backlash=b_mm=0.1"),
        ],
    )
    .unwrap();
    let tr = truth(&r[0]);
    for c in tr["contacts"].as_array().unwrap() {
        let t = c["t_s"].as_f64().unwrap();
        let drift = 0.2 * (1.0 - (-t / 100.0_f64).exp());
        let dir = c["dir"].as_f64().unwrap();
        let dz = c["z_mm"].as_f64().unwrap() - c["surface_z_mm"].as_f64().unwrap();
        let dx = c["x_mm"].as_f64().unwrap() - c["surface_x_mm"].as_f64().unwrap();
        let seq = c["seq"].as_i64().unwrap() as usize;
        match faces[seq] {
            "xy" => assert!((dz - (-drift + 0.05 * dir)).abs() < 1e-9),
            "yz" => {
                assert!((dz + drift).abs() < 1e-9);
                assert!((dx - 0.05 * dir).abs() < 1e-9);
            }
            _ => assert!((dz + drift).abs() < 1e-9),
        }
    }
}

#[test]
fn unknown_effects_and_parameters_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let err = generate_fleet(dir.path(), &tiny(1), &[fx("gremlins=k=1")])
        .unwrap_err()
        .to_string();
    assert!(err.contains("unknown effect `gremlins`"), "{err}");
    for name in [
        "trigger_latency",
        "wheel_wear",
        "thermal_drift",
        "compliance",
        "backlash",
    ] {
        assert!(err.contains(name), "{err} does not list {name}");
        assert!(known_effects().iter().any(|(n, _)| *n == name));
    }
    let err = generate_fleet(dir.path(), &tiny(1), &[fx("backlash=b=0.1")])
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("unknown parameter `b`") && err.contains("b_mm"),
        "{err}"
    );
    // Nothing was written.
    assert!(!dir.path().join("kr16-lab").exists());
}

/// Sizes and timings of the demo and default fleets (run by hand:
/// `cargo test --test generate_robot -- --ignored --nocapture`).
#[test]
#[ignore]
fn fleet_size_and_time_report() {
    for (name, cfg) in [
        ("demo", RobotFleetConfig::demo()),
        (
            "default (1 run)",
            RobotFleetConfig {
                runs: 1,
                ..RobotFleetConfig::default()
            },
        ),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let t0 = std::time::Instant::now();
        let runs = generate_fleet(dir.path(), &cfg, &[]).unwrap();
        let dt = t0.elapsed();
        let snap = snapshot(&runs[0]);
        let sizes: Vec<String> = snap
            .iter()
            .map(|(k, v)| format!("{}={}kB", k.display(), v.len() / 1024))
            .collect();
        let ae = AeStream::open(&runs[0].join("ae.parquet"))
            .unwrap()
            .total_rows();
        let m = Table::read(&runs[0].join("motion.parquet"), &MOTION)
            .unwrap()
            .len();
        println!(
            "{name}: {} runs in {:.2} s; run 0: ae rows {ae}, motion rows {m}; {}",
            runs.len(),
            dt.as_secs_f64(),
            sizes.join(" ")
        );
    }
}

#[test]
fn catalogue_shapes_apply_directly_to_the_observables() {
    let base = tempfile::tempdir().unwrap();
    let shaped = tempfile::tempdir().unwrap();
    // AE program only: a 10 ms lag on a 100 mm/s mechanical approach
    // would move the surface beyond the standoff (the generator refuses).
    let cfg = RobotFleetConfig {
        other_methods: vec![],
        ..tiny(6)
    };
    let b = generate_fleet(base.path(), &cfg, &[]).unwrap();
    let s = generate_fleet(
        shaped.path(),
        &cfg,
        &[
            fx("lag:approach_normal_mm_s=k=0.01"),
            fx("wear:pass=k=-0.001"),
        ],
    )
    .unwrap();
    let plan = Table::read(&b[0].join("plan.parquet"), &PLAN).unwrap();
    let faces = plan.str("face").unwrap();
    let v = f64s(&plan, "approach_mm_s");
    let dirs: Vec<Vec<f64>> = ["dir_x", "dir_y", "dir_z"]
        .iter()
        .map(|c| f64s(&plan, c))
        .collect();
    let (tb, ts) = (truth(&b[0]), truth(&s[0]));
    for (cb, cs) in tb["contacts"]
        .as_array()
        .unwrap()
        .iter()
        .zip(ts["contacts"].as_array().unwrap())
    {
        let seq = cs["seq"].as_i64().unwrap() as usize;
        let (ax, key) = match faces[seq] {
            "xy" => (2, "z_mm"),
            "yz" => (0, "x_mm"),
            _ => (1, "y_mm"),
        };
        let gap = cs[key].as_f64().unwrap() - cb[key].as_f64().unwrap();
        assert!(
            (gap - 0.01 * v[seq] * dirs[ax][seq]).abs() < 1e-9,
            "seq {seq}: {gap}"
        );
    }
    let (cb, cs) = (cuts(&b[0]), cuts(&s[0]));
    for i in 0..cb.len() {
        assert!(
            (cs[i] - cb[i] + 0.001 * (i + 1) as f64).abs() < 1e-9,
            "{cb:?} {cs:?}"
        );
    }
}

/// docs/models.md §1.1: the comparison methods. Through the
/// CLI on a generated run: repeatability per (method, speed) orders AE <
/// electrical < mechanical near the thesis's ranges; the datum is fitted
/// from the most precise method (`auto`), and pooling every method
/// (`method = "all"`) is worse; each method has its own observable.
#[test]
fn comparison_methods_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = RobotFleetConfig {
        runs: 1,
        trials: 4,
        with_probe: ProbeMode::All,
        ..tiny(11)
    };
    let runs = generate_fleet(dir.path(), &cfg, &[]).unwrap();
    let run = runs[0].to_str().unwrap();
    let json = |args: &[&str]| -> serde_json::Value {
        let o = common::sparkout(args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let rep = json(&["stage", "repeatability", "--run", run, "--json"]);
    let range = |m: &str| -> f64 {
        let g = rep["groups"]
            .as_array()
            .unwrap()
            .iter()
            .find(|g| g["method"] == m)
            .unwrap_or_else(|| panic!("no {m} group in {rep}"));
        g["mean_range_mm"].as_f64().unwrap()
    };
    let (ae, el, me) = (range("ae"), range("electrical"), range("mechanical"));
    assert!(
        ae < el && el < me,
        "ae {ae} electrical {el} mechanical {me}"
    );
    // 4 trials: expected range ≈ 2.06σ; thesis σ = range(12)/3.258.
    assert!(me > 0.15 && me < 0.9, "mechanical range {me}");
    assert!(el > 0.04 && el < 0.25, "electrical range {el}");

    let truth = truth(&runs[0]);
    let datum_err = |d: &serde_json::Value| -> f64 {
        let p = d["datum_mm"].as_array().unwrap();
        let t = truth["block_origin_mm"].as_array().unwrap();
        (0..3)
            .map(|k| (p[k].as_f64().unwrap() - t[k].as_f64().unwrap()).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let auto = json(&["stage", "datum", "--run", run, "--json"]);
    assert_eq!(auto["touch_method"], "ae");
    let pooled = json(&[
        "stage",
        "datum",
        "--run",
        run,
        "--json",
        "--set",
        "robot.datum.method=all",
    ]);
    assert_eq!(pooled["touch_method"], "all");
    let mech = json(&[
        "stage",
        "datum",
        "--run",
        run,
        "--json",
        "--set",
        "robot.datum.method=mechanical",
    ]);
    assert!(
        datum_err(&auto) < 0.02 && datum_err(&auto) < datum_err(&mech),
        "auto {} mechanical {}",
        datum_err(&auto),
        datum_err(&mech)
    );

    let out = dir.path().join("obs");
    let o = common::sparkout(&[
        "stage",
        "observe",
        "--run",
        run,
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let obs =
        sparkout_pipeline::contracts::read_parquet(&out.join("observations.parquet")).unwrap();
    let names = obs
        .column_by_name("observable")
        .unwrap()
        .as_any()
        .downcast_ref::<arrow::array::StringArray>()
        .unwrap();
    let count = |n: &str| names.iter().filter(|x| *x == Some(n)).count();
    assert_eq!(count("touch_normal"), 3 * 12 * 4 * 2);
    assert_eq!(count("touch_normal_electrical"), 3 * 12 * 4);
    assert_eq!(count("touch_normal_mechanical"), 3 * 12 * 4);
}

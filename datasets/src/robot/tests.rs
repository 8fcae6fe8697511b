use super::*;

#[test]
fn thesis_repeatability_is_reproduced() {
    assert!((ae_touch_sigma_mm(5.0) * D2_N12 - 0.025).abs() < 1e-12);
    assert!((ae_touch_sigma_mm(10.0) * D2_N12 - 0.085).abs() < 1e-12);
}

#[test]
fn plan_has_the_thesis_pattern() {
    let cfg = RobotFleetConfig::demo();
    let plan = build_plan(&cfg);
    assert_eq!(plan.len(), 3 * 12 * cfg.trials * cfg.speeds_mm_s.len());
    for f in Face::ALL {
        let pts: Vec<&PlanRow> = plan.iter().filter(|r| r.face == f).collect();
        // Points lie on the nominal face and the approach is into it.
        for r in &pts {
            let n = f.normal();
            assert!((n.dot(&(r.nom - V3::from(DATUM_NOM_MM)))).abs() < 1e-12);
            assert!((r.dir + n).norm() < 1e-12);
        }
        // Three concentric squares: distances from the face centre.
        let c = (f.point(0) + f.point(2)) / 2.0;
        for (sq, half) in SQUARE_HALF_MM.iter().enumerate() {
            for k in 0..4 {
                let d = (f.point(sq * 4 + k) - c).norm();
                assert!((d - half * 2f64.sqrt()).abs() < 1e-9);
            }
        }
    }
}

#[test]
fn compliance_recursion_matches_the_thesis_sequence() {
    // docs/models.md §1.4: α = 0.5, δ′ = 0.3 → 0.200, 0.2667, 0.2889, ...
    let cfg = RobotFleetConfig {
        height_noise_mm: 0.0,
        ..RobotFleetConfig::default()
    };
    let mut rng = run_rng(1, 0, 0);
    let (_, truth) = passes(&cfg, &Effects::default(), 0.5, 0.0, &mut rng);
    let want = [0.200, 0.2667, 0.2889, 0.2963, 0.2988, 0.2996, 0.2999];
    for (p, w) in truth.iter().zip(want) {
        assert!((p.cut_mm - w).abs() < 1e-4, "{} vs {w}", p.cut_mm);
    }
    // 2.27 − Σ rough = 0.3199 (thesis).
    let rough: f64 = truth[..7].iter().map(|p| p.cut_mm).sum();
    assert!((2.27 - rough - 0.3199).abs() < 2e-4);
    // Spark-out removes α/(1+α) of the previous cut.
    let n = truth.len();
    assert!((truth[n - 1].cut_mm / truth[n - 2].cut_mm - 1.0 / 3.0).abs() < 1e-9);
}

#[test]
fn effects_resolve_with_defaults_and_reject_unknowns() {
    let range = |_: &str| (0.0, 1.0);
    let specs: Vec<EffectSpec> = [
        "trigger_latency",
        "wheel_wear",
        "thermal_drift",
        "compliance",
        "backlash",
    ]
    .iter()
    .map(|s| s.parse().unwrap())
    .collect();
    let fx = resolve_effects(&specs, &range).unwrap();
    assert_eq!(fx.latency_s, DEF_LATENCY_S);
    assert_eq!(fx.wear_k_mm_per_mm3, DEF_WEAR_K_MM_PER_MM3);
    assert_eq!(fx.drift, Some((DEF_DRIFT_AMPLITUDE_MM, DEF_DRIFT_TAU_S)));
    assert_eq!(fx.compliance_k_per_mm, DEF_COMPLIANCE_K_PER_MM);
    assert_eq!(fx.backlash_b_mm, DEF_BACKLASH_B_MM);

    let err = resolve_effects(&["chatter".parse().unwrap()], &range)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("unknown effect `chatter`") && err.contains("wheel_wear"),
        "{err}"
    );
    let err = resolve_effects(&["wheel_wear=k=1".parse().unwrap()], &range)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("unknown parameter `k`") && err.contains("k_mm_per_mm3"),
        "{err}"
    );
    let err = resolve_effects(&["drift:t_s=amplitude_mm=0.1".parse().unwrap()], &range)
        .unwrap_err()
        .to_string();
    assert!(err.contains("tau_s"), "{err}");
    let err = resolve_effects(&["inertia:a_mm_s2=k=1".parse().unwrap()], &range)
        .unwrap_err()
        .to_string();
    assert!(err.contains("not applicable"), "{err}");

    let fx = resolve_effects(
        &[
            "wear:removed_mm3=k=-1e-4".parse().unwrap(),
            "drift:t_s=amplitude_mm=0.05,tau_s=100".parse().unwrap(),
            "bow:x_mm=amplitude_mm=0.02".parse().unwrap(),
        ],
        &range,
    )
    .unwrap();
    assert_eq!(fx.cut.len(), 1);
    assert_eq!(fx.touch.len(), 2);
    assert_eq!(fx.touch[1].params["c1"], 1.0);
}

#[test]
fn started_is_eight_oclock_plus_a_quarter_hour_a_run() {
    assert_eq!(started(0), "2026-11-20T08:00:00Z");
    assert_eq!(started(4 * 16), "2026-11-21T00:00:00Z");
}

#[test]
fn config_validation() {
    RobotFleetConfig::default().validate().unwrap();
    RobotFleetConfig::demo().validate().unwrap();
    let bad = RobotFleetConfig {
        pose_offset_mm: 2.0,
        ..RobotFleetConfig::default()
    };
    assert!(bad.validate().unwrap_err().to_string().contains("standoff"));
    let bad = RobotFleetConfig {
        speeds_mm_s: vec![],
        ..RobotFleetConfig::default()
    };
    assert!(bad.validate().is_err());
    assert_eq!("alternate".parse::<ProbeMode>(), Ok(ProbeMode::Alternate));
}

/// The size `sparkout generate robot` predicts (no generation): one run at
/// the defaults is what a debug build measured (33.8 MB), the AE log grows
/// with the rate, and runs add up.
#[test]
fn predicted_size_follows_rate_and_runs() {
    let opts = |runs, rate| GenerateOptions {
        runs,
        seed: 0,
        ae_rate_hz: rate,
        ae_signal: None,
    };
    let one = RobotGenerator.predicted_size(&opts(1, None)).write_bytes as f64;
    assert!((one / 33.8e6 - 1.0).abs() < 0.05, "{one}");
    let fast = RobotGenerator
        .predicted_size(&opts(1, Some(1e7)))
        .write_bytes as f64;
    assert!((fast - 11.86e6) / (one - 11.86e6) > 9.9, "{fast}");
    let many = RobotGenerator.predicted_size(&opts(100_000, Some(1e7)));
    assert!(many.write_bytes > 10_000_000_000_000);
    assert!(many.peak_memory_bytes < 100 * RUN_MEMORY_BYTES);
}

#[test]
fn truth_json_reads_back_through_its_type() {
    let d = tempfile::tempdir().unwrap();
    let cfg = RobotFleetConfig {
        runs: 1,
        ..RobotFleetConfig::demo()
    };
    generate_fleet(d.path(), &cfg, &[]).unwrap();
    assert_eq!(
        crate::generator::truth_files_round_trip::<RunTruth>(d.path()),
        1
    );
}

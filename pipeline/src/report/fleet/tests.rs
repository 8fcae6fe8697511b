use super::*;

#[test]
fn velocity_errors_are_shown_in_mm_per_s_and_positions_in_um() {
    assert_eq!(
        unit_of_observable("velocity_error_x").show(0.25),
        "0.250 mm/s"
    );
    assert_eq!(unit_of_observable("cut_depth").show(0.0145), "14.5 µm");
    assert_eq!(unit_of_observable("cut_depth").show(f64::NAN), "—");
}

#[test]
fn losers_say_why() {
    let winners: BTreeMap<usize, (String, f64)> = [(1, ("wear:removed_mm3".into(), 0.74))].into();
    let lost = serde_json::json!({"name": "drift", "covariate": "t_s", "shrink": 0.2, "p_value": 0.001, "step": 1, "selected": false});
    assert!(why_lost(&lost, &winners, "").contains("wear:removed_mm3 shrank the held-out gap more"));
    let worse = serde_json::json!({"name": "drift", "shrink": -0.1, "step": 1, "selected": false});
    assert!(why_lost(&worse, &winners, "").starts_with("held-out gap not smaller"));
    let skipped =
        serde_json::json!({"name": "drift", "skipped_reason": "no t_s column", "selected": false});
    assert_eq!(why_lost(&skipped, &winners, ""), "not tried: no t_s column");
}

#[test]
fn selected_parameters_carry_their_interval_and_unit() {
    let e = serde_json::json!({"name": "wear", "covariate": "removed_mm3", "params": {"k": -9.35e-5},
        "intervals": {"k": {"se": 0.9e-5, "lo": -1.22e-4, "hi": -6.5e-5}}});
    let p = params_text(&e);
    assert_eq!(p.len(), 1);
    assert!(
        p[0].contains("±") && p[0].contains("nm/mm³") && p[0].contains("95 %"),
        "{}",
        p[0]
    );
}

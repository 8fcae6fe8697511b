//! Nightly diagnoses appended to a fleet history, and the trend report's
//! ranked alerts — a wear rate rising beyond its night-to-night spread is
//! flagged, a steady one is not; a recorded event starts a new baseline;
//! `run --history` dates the night from the runs; a damaged history or
//! events file names its file; `validate --nights --quick` measures the
//! rule on generated nights.

use std::path::Path;

use super::common::{ok, sparkout};

/// One night: a generated observations table whose wear rate is `k`,
/// diagnosed and appended to `history`.
fn night(dir: &Path, history: &Path, n: u32, k: f64) -> String {
    night_with(dir, history, n, k, &[])
}

/// [`night`] with more `diagnose` flags (e.g. `--event SPEC`).
fn night_with(dir: &Path, history: &Path, n: u32, k: f64, more: &[&str]) -> String {
    let obs = dir.join(format!("obs{n}.parquet"));
    ok(sparkout(&[
        "generate",
        "observations",
        "--runs",
        "8",
        "--seed",
        &n.to_string(),
        "--out",
        obs.to_str().unwrap(),
        "--effect",
        &format!("wear:removed_mm3=k={k}"),
    ]));
    let out = dir.join(format!("d{n}"));
    let night = format!("2026-11-0{n}");
    let mut args = vec![
        "diagnose",
        obs.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--history",
        history.to_str().unwrap(),
        "--night",
        &night,
    ];
    args.extend_from_slice(more);
    ok(sparkout(&args))
}

fn trend_json(history: &Path, out: &Path) -> serde_json::Value {
    trend_json_with(history, out, &[])
}

fn trend_json_with(history: &Path, out: &Path, more: &[&str]) -> serde_json::Value {
    let mut args = vec![
        "trend",
        "--history",
        history.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--json",
    ];
    args.extend_from_slice(more);
    let o = sparkout(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let printed: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let written: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("trend.json")).unwrap()).unwrap();
    assert_eq!(printed, written);
    written
}

#[test]
fn a_rising_wear_rate_raises_an_alert_and_a_steady_one_does_not() {
    let d = tempfile::tempdir().unwrap();
    let history = d.path().join("history");
    for n in 1..=3 {
        night(d.path(), &history, n, 1.0e-5);
    }
    let steady = trend_json(&history, &d.path().join("t3"));
    assert_eq!(steady["nights"].as_array().unwrap().len(), 3);
    assert_eq!(steady["alerts"], serde_json::json!([]), "{steady:#}");
    let series = &steady["series"][0];
    assert_eq!(series["effect"], "wear:removed_mm3");
    assert_eq!(series["points"].as_array().unwrap().len(), 3);

    let text = night(d.path(), &history, 4, 1.6e-5);
    assert!(text.contains("ALERT 2026-11-04 #1 moved"), "{text}");
    let t = trend_json(&history, &d.path().join("t4"));
    assert_eq!(t["version"], 2);
    let alerts = t["alerts"].as_array().unwrap();
    assert_eq!(alerts.len(), 1, "{t:#}");
    let a = &alerts[0];
    assert_eq!(a["kind"], "moved");
    assert_eq!(a["effect"], "wear:removed_mm3");
    assert_eq!(a["param"], "k");
    assert_eq!(a["night"], "2026-11-04");
    assert_eq!(a["rank"], 1);
    assert!(a["value"].as_f64().unwrap() > a["baseline"].as_f64().unwrap());
    // Its size in the observable's unit and as a share of the gap: wear
    // is the whole effect here, so a 60 % rise moves about 60 % of what it
    // explains.
    let fraction = a["fraction_of_gap"].as_f64().unwrap();
    assert!(fraction > 0.2 && fraction < 1.0, "{a:#}");
    assert!(a["p_holm"].as_f64().unwrap() <= 0.01, "{a:#}");
    let html = std::fs::read_to_string(d.path().join("t4/trend.html")).unwrap();
    assert!(
        html.contains("<svg") && html.contains("moved"),
        "trend page"
    );
    // Re-running a night replaces its partition: still four nights.
    ok(sparkout(&[
        "diagnose",
        d.path().join("obs4.parquet").to_str().unwrap(),
        "--out",
        d.path().join("d4b").to_str().unwrap(),
        "--history",
        history.to_str().unwrap(),
        "--night",
        "2026-11-04",
    ]));
    let again = trend_json(&history, &d.path().join("t5"));
    assert_eq!(again["nights"].as_array().unwrap().len(), 4);
}

#[test]
fn run_history_dates_the_night_from_the_runs_and_writes_the_trend_page() {
    let d = tempfile::tempdir().unwrap();
    let root = d.path().join("runs");
    ok(sparkout(&[
        "generate",
        "servo",
        "--runs",
        "3",
        "--seed",
        "7",
        "--out",
        root.to_str().unwrap(),
        "--effect",
        "servo_lag=k_s=0.004",
    ]));
    let out = d.path().join("out");
    let history = d.path().join("history");
    let text = ok(sparkout(&[
        "run",
        "--input",
        root.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--history",
        history.to_str().unwrap(),
        "--event",
        "machine=servo-mill,kind=repair,note=new encoder",
    ]));
    let nights: Vec<String> = std::fs::read_dir(&history)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .filter(|n| n.starts_with("night="))
        .collect();
    assert_eq!(nights.len(), 1, "{nights:?}");
    assert!(nights[0].starts_with("night=20"), "{nights:?}");
    // The event is kept with the history, dated the night that was run.
    let events = std::fs::read_to_string(history.join("events.toml")).unwrap();
    assert!(
        events.contains(&format!("night = \"{}\"", &nights[0][6..]))
            && events.contains("servo-mill")
            && events.contains("new encoder"),
        "{events}"
    );
    // A bad event is refused before any run is processed.
    let o = sparkout(&[
        "run",
        "--input",
        root.to_str().unwrap(),
        "--out",
        d.path().join("out2").to_str().unwrap(),
        "--history",
        history.to_str().unwrap(),
        "--event",
        "machine=servo-mill,kind=lunch",
    ]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("wheel_change"));
    assert!(!d.path().join("out2/manifest.json").exists());
    assert!(out.join("trend/trend.html").is_file(), "{text}");
    assert!(out.join("trend/trend.json").is_file());
    // Written before the index, so the night's index links it.
    let index = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(
        index.contains("trend/trend.html"),
        "index does not link the trend"
    );
}

#[test]
fn a_damaged_history_names_its_file() {
    let d = tempfile::tempdir().unwrap();
    let history = d.path().join("history");
    let bad = history.join("night=2026-11-01");
    std::fs::create_dir_all(&bad).unwrap();
    std::fs::write(bad.join("diagnosis.parquet"), b"not parquet").unwrap();
    let o = sparkout(&[
        "trend",
        "--history",
        history.to_str().unwrap(),
        "--out",
        d.path().join("t").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("night=2026-11-01") && err.contains("diagnosis.parquet"),
        "{err}"
    );
    let empty = d.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let o = sparkout(&[
        "trend",
        "--history",
        empty.to_str().unwrap(),
        "--out",
        d.path().join("t2").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("no night="));
}

#[test]
fn a_recorded_wheel_change_starts_a_new_baseline_instead_of_alerting() {
    let d = tempfile::tempdir().unwrap();
    let history = d.path().join("history");
    for n in 1..=3 {
        night(d.path(), &history, n, 1.0e-5);
    }
    // The same step as above, but at a recorded wheel change.
    let text = night_with(
        d.path(),
        &history,
        4,
        1.6e-5,
        &["--event", "kind=wheel_change,note=new wheel, coarser grit"],
    );
    assert!(!text.contains("ALERT"), "{text}");
    assert!(
        text.contains("event 2026-11-04 wheel_change fleet"),
        "{text}"
    );
    let events = std::fs::read_to_string(history.join("events.toml")).unwrap();
    assert!(events.contains("new wheel, coarser grit"), "{events}");
    let t = trend_json(&history, &d.path().join("t"));
    assert_eq!(t["alerts"], serde_json::json!([]), "{t:#}");
    assert_eq!(t["events"][0]["kind"], "wheel_change");
    // Without the events file the step alerts; `trend --event` puts it back
    // for one report.
    std::fs::remove_file(history.join("events.toml")).unwrap();
    let t = trend_json(&history, &d.path().join("t2"));
    assert_eq!(t["alerts"].as_array().unwrap().len(), 1, "{t:#}");
    let t = trend_json_with(
        &history,
        &d.path().join("t3"),
        &["--event", "night=2026-11-04,kind=repair"],
    );
    assert_eq!(t["alerts"], serde_json::json!([]), "{t:#}");
    // A bad events file names the file and the entry.
    std::fs::write(
        history.join("events.toml"),
        "[[event]]\nnight = \"2026-11-04\"\nkind = \"coffee\"\n",
    )
    .unwrap();
    let o = sparkout(&[
        "trend",
        "--history",
        history.to_str().unwrap(),
        "--out",
        d.path().join("t4").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("events.toml") && err.contains("number 1") && err.contains("wheel_change"),
        "{err}"
    );
    assert!(!d.path().join("t4/trend.json").exists());
}

#[test]
fn validate_nights_quick_measures_false_alerts_and_a_40_per_cent_step() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("v");
    let text = ok(sparkout(&[
        "validate",
        "--nights",
        "--quick",
        "--out",
        out.to_str().unwrap(),
    ]));
    assert!(text.contains("stationary:"), "{text}");
    // nights.json, read back through the type that wrote it.
    let r: sparkout_datasets::validate::nights::NightsReport =
        sparkout_pipeline::files::json::read_json(&out.join("nights.json")).unwrap();
    // Six stationary nights of a four-machine fleet: no false alert.
    assert_eq!(r.stationary_night_fleets, 6, "{r:#?}");
    assert_eq!(r.stationary_false_alerts, 0, "{text}");
    // A 40 % step in the form machine's wear rate: raised the night it
    // happens, as that night's first alert.
    let step = &r.steps[0];
    assert_eq!(step.size, 0.4);
    assert_eq!(step.same_night, 1, "{text}");
    assert_eq!(step.first_of_night, 1, "{text}");
    assert_eq!(r.other_false_alerts, 0, "{text}");
    // The same step at a recorded wheel change: no alert.
    assert_eq!(r.event_alerts, 0, "{text}");
}

/// The index page leads with the night's news: on a quiet night that no
/// trend alert was raised, on the night a servo's lag doubles that alert,
/// first.
#[test]
fn the_index_page_leads_with_the_nights_news() {
    let d = tempfile::tempdir().unwrap();
    let history = d.path().join("history");
    let index_of = |n: u32, k_s: f64| -> String {
        let root = d.path().join(format!("runs{n}"));
        ok(sparkout(&[
            "generate",
            "servo",
            "--runs",
            "3",
            "--seed",
            &(20 + n).to_string(),
            "--out",
            root.to_str().unwrap(),
            "--effect",
            &format!("servo_lag=k_s={k_s}"),
        ]));
        let out = d.path().join(format!("out{n}"));
        ok(sparkout(&[
            "run",
            "--input",
            root.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--history",
            history.to_str().unwrap(),
            "--night",
            &format!("2026-11-0{n}"),
        ]));
        std::fs::read_to_string(out.join("index.html")).unwrap()
    };
    for n in 1..=2 {
        index_of(n, 0.004);
    }
    let quiet = index_of(3, 0.004);
    let news = quiet.find("id=\"news\"").expect("a news section");
    assert!(news < quiet.find("id=\"failures\"").unwrap(), "news first");
    assert!(
        quiet.contains("Night 2026-11-03: no trend alert"),
        "{quiet}"
    );
    let loud = index_of(4, 0.008);
    assert!(loud.contains("Night 2026-11-04: "), "{loud}");
    let first = &loud[loud.find("<ol><li>").expect("a ranked list of alerts")..];
    let first = &first[..first.find("</li>").unwrap()];
    assert!(first.contains("servo_lag"), "{first}");
}

/// The history's config fingerprint covers the models a night ran, not
/// only its settings: an update of sparkout that renames an effect or
/// changes a stage (what a night computes) is a `config` event — a new
/// baseline — never a night of "appeared"/"disappeared" alerts. Only the
/// night's plugins count: a robot stage's update is no event for a servo
/// fleet.
#[test]
fn the_models_behind_a_night_are_part_of_its_config_fingerprint() {
    use sparkout_pipeline::engine::{models_text, DIAGNOSE_STAGE_VERSION};
    let plugins = sparkout_plugins::all_plugins();
    let servo_night: std::collections::BTreeSet<&str> = ["servo"].into();
    let text = models_text(&plugins, &servo_night);
    assert!(
        text.contains(&format!("diagnose v{DIAGNOSE_STAGE_VERSION}")),
        "{text}"
    );
    let servo = plugins.iter().find(|p| p.name() == "servo").unwrap();
    for s in servo.stages() {
        let stage = format!("{} v{}", s.name(), s.spec().version);
        assert!(text.contains(&stage), "{stage} not in {text}");
    }
    for e in servo.effects() {
        assert!(text.contains(&e.key()), "{} not in {text}", e.key());
    }
    assert!(!text.contains("robot:"), "{text}");
    // The same night's models give the same text (no config event between
    // two nights of one sparkout).
    assert_eq!(text, models_text(&plugins, &servo_night));
}

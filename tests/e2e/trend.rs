//! Issue 13 item 5: nightly diagnoses appended to a fleet history, and the
//! trend report's alerts — a wear rate rising beyond its interval is
//! flagged, a steady one is not; `run --history` dates the night from the
//! runs; a damaged history names its file.

use std::path::Path;

use super::common::sparkout;

fn ok(o: std::process::Output) -> String {
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(o.status.success(), "{text}");
    text
}

/// One night: a generated observations table whose wear rate is `k`,
/// diagnosed and appended to `history`.
fn night(dir: &Path, history: &Path, n: u32, k: f64) -> String {
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
    ok(sparkout(&[
        "diagnose",
        obs.to_str().unwrap(),
        "--out",
        dir.join(format!("d{n}")).to_str().unwrap(),
        "--history",
        history.to_str().unwrap(),
        "--night",
        &format!("2026-11-0{n}"),
    ]))
}

fn trend_json(history: &Path, out: &Path) -> serde_json::Value {
    let o = sparkout(&[
        "trend",
        "--history",
        history.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--json",
    ]);
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
    assert!(text.contains("ALERT 2026-11-04 moved"), "{text}");
    let t = trend_json(&history, &d.path().join("t4"));
    let alerts = t["alerts"].as_array().unwrap();
    assert!(!alerts.is_empty(), "{t:#}");
    for a in alerts {
        assert_eq!(a["kind"], "moved");
        assert_eq!(a["effect"], "wear:removed_mm3");
        assert_eq!(a["param"], "k");
        assert_eq!(a["night"], "2026-11-04");
        assert!(a["value"].as_f64().unwrap() > a["since_value"].as_f64().unwrap());
    }
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
    ]));
    let nights: Vec<String> = std::fs::read_dir(&history)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .collect();
    assert_eq!(nights.len(), 1, "{nights:?}");
    assert!(nights[0].starts_with("night=20"), "{nights:?}");
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

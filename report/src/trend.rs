//! The trend across nights: each night's diagnosis is appended to a fleet
//! history — a Parquet dataset partitioned by night,
//! `<history>/night=YYYY-MM-DD/diagnosis.parquet` (history.rs) — and
//! `sparkout trend` reads it back: each selected effect's parameters over
//! nights with their 95 % intervals, per machine where the diagnosis fitted
//! one, and ranked alerts for a monitoring system (trend.json) when a
//! material effect appears, disappears or moves beyond its night-to-night
//! spread (rule.rs). Deliberate changes (events.rs) start a new baseline.

use std::collections::BTreeMap;
use std::path::Path;

use crate::Context;
use serde::{Deserialize, Serialize};

use crate::contracts::{write_atomic, write_json_atomic};
use crate::error::Result;
use crate::files::json::{parse_json, FileHeader};

/// Where the trend page is, relative to the output root (written by the
/// diagnosis history step when it ran).
pub const TREND_PAGE: &str = "trend/trend.html";

pub mod events;
pub mod history;
pub mod page;
pub mod rule;

pub use events::{append_events, parse_event, read_events, Event, EVENTS_FILE, EVENT_KINDS};
pub use history::{append_night, read_history, rows_of, write_night, HistoryRow, HISTORY_VERSION};
pub use page::{trend_anchor, trend_page};
pub use rule::{holm, trend, TrendConfig};

/// Version of trend.json. 2: ranked alerts with size, fraction of the gap,
/// significance; events, settings, notes, tests per night.
pub const TREND_VERSION: u32 = 2;

/// z of a two-sided 95 % interval.
const Z95: f64 = 1.96;

/// A short fingerprint of the settings a night ran with: nights that differ
/// in it are separated by a `config` event.
pub fn fingerprint(settings: &str) -> String {
    blake3::hash(settings.as_bytes()).to_hex()[..16].to_string()
}

pub use crate::outcome::check_night;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Point {
    pub night: String,
    pub value: f64,
    pub se: Option<f64>,
    pub lo95: Option<f64>,
    pub hi95: Option<f64>,
    /// The effect was material that night (only such nights are tested).
    pub material: bool,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrendSeries {
    pub observable: String,
    pub unit: String,
    pub effect: String,
    /// null: the fleet-wide fit.
    pub machine: Option<String>,
    pub param: String,
    pub points: Vec<Point>,
}

/// One alert, ranked within its night (rule.rs "Rank").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Alert {
    /// 1 = the night's biggest change.
    pub rank: usize,
    /// "appeared", "disappeared" or "moved".
    pub kind: String,
    pub observable: String,
    /// The observable's unit (of `size`, `gap_rms`).
    pub unit: String,
    pub effect: String,
    /// null: the fleet-wide fit.
    pub machine: Option<String>,
    /// The machines the change is on: `machine`, or for a fleet-wide fit
    /// every machine the observable was measured on.
    pub machines: Vec<String>,
    pub param: Option<String>,
    /// The night the alert is raised on.
    pub night: String,
    /// First night of the change: of the tested window (moved) or of the
    /// run of nights that confirmed it (appeared/disappeared).
    pub from_night: String,
    /// Nights in that window or run.
    pub nights: usize,
    /// Moved: first night of the baseline compared with.
    pub since: Option<String>,
    /// Moved: the window's mean, the baseline level, the night-to-night
    /// spread τ (parameter units).
    pub value: Option<f64>,
    pub baseline: Option<f64>,
    pub spread: Option<f64>,
    /// How much of the observable's gap the change moves (its unit).
    pub size: Option<f64>,
    /// The observable's held-out gap RMS that night.
    pub gap_rms: Option<f64>,
    /// size / gap_rms.
    pub fraction_of_gap: Option<f64>,
    pub z: Option<f64>,
    pub p_value: Option<f64>,
    /// Holm-adjusted over the night's tests.
    pub p_holm: Option<f64>,
    /// The night's tests (Holm's family).
    pub tests: usize,
    /// fraction_of_gap · min(1, |z| / z_full): the order within a night.
    pub score: f64,
    pub message: String,
}

/// trend.json.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Trend {
    pub version: u32,
    pub kind: String,
    pub nights: Vec<String>,
    pub rule: String,
    pub settings: TrendConfig,
    /// Deliberate changes: each starts a new baseline.
    pub events: Vec<Event>,
    /// What the reader should know: nights upgraded from an older history.
    pub notes: Vec<String>,
    /// Tests made on each night (the family Holm controls).
    pub tests_per_night: BTreeMap<String, usize>,
    pub series: Vec<TrendSeries>,
    /// Newest night first, each night's alerts by rank.
    pub alerts: Vec<Alert>,
}

impl Trend {
    /// The alerts raised on `night`, by rank.
    pub fn alerts_on<'a>(&'a self, night: &'a str) -> impl Iterator<Item = &'a Alert> + 'a {
        self.alerts.iter().filter(move |a| a.night == night)
    }
}

/// Reads a trend.json written by this version (another is refused) through
/// [`Trend`].
pub fn read_trend(path: &Path) -> Result<Trend> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    // The version first: a file of another version is refused by it, not
    // by the first field this version does not know.
    let header: FileHeader = parse_json(path, &bytes)?;
    if header.version != Some(TREND_VERSION as u64) {
        return Err(crate::InputError::new(
            path,
            format!(
                "trend.json version {}: this sparkout reads version {TREND_VERSION}; rewrite it with `sparkout trend`",
                header.version.map_or("missing".into(), |v| v.to_string())
            ),
        )
        .column("version")
        .into());
    }
    Ok(parse_json(path, &bytes)?)
}

/// Reads a history and its events (plus `extra` events), writes
/// `out/trend.json` and `out/trend.html`.
pub fn write_trend(
    history: &Path,
    out: &Path,
    extra: &[Event],
    cfg: &TrendConfig,
) -> Result<Trend> {
    let (rows, notes) = read_history(history)?;
    let mut events = read_events(history)?;
    events.extend(extra.iter().cloned());
    let t = trend(&rows, &events, notes, cfg);
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    write_atomic(&out.join("trend.html"), trend_page(&t).as_bytes())?;
    write_json_atomic(&out.join("trend.json"), &t)?;
    Ok(t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::Diagnosis;

    /// A diagnosis.json of `per_observable` and `effects` only, the rest
    /// of its fields (and of theirs) filled in, read through its type.
    pub(super) fn diagnosis(v: serde_json::Value) -> Diagnosis {
        let fill = |base: serde_json::Value, over: &serde_json::Value| {
            let mut b = base;
            let b_map = b.as_object_mut().unwrap();
            for (k, x) in over.as_object().unwrap() {
                b_map.insert(k.clone(), x.clone());
            }
            b
        };
        let per: Vec<serde_json::Value> = v["per_observable"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| {
                fill(
                    serde_json::json!({"observable": "", "unit": "mm", "n": 0, "runs": 0,
                        "rms_mm": null, "noise_floor_mm": null, "noise_floor_source": "replicates",
                        "gap_above_noise": true, "p_value": null, "selected": [],
                        "cv_rms_before_mm": null, "cv_rms_after_mm": null, "shrink": null,
                        "stop_reason": ""}),
                    p,
                )
            })
            .collect();
        let effects: Vec<serde_json::Value> = v["effects"]
            .as_array()
            .unwrap()
            .iter()
            .map(|e| {
                let mut e = fill(
                    serde_json::json!({"name": "", "observable": "", "params": {},
                        "param_units": {}, "n_params": 1, "selected": false, "step": 1}),
                    e,
                );
                // An interval's every field.
                if let Some(iv) = e.get_mut("intervals").and_then(|i| i.as_object_mut()) {
                    for i in iv.values_mut() {
                        *i = fill(
                            serde_json::json!({"se": null, "lo": null, "hi": null, "from": "pooled"}),
                            i,
                        );
                    }
                }
                e
            })
            .collect();
        serde_json::from_value(serde_json::json!({
            "version": 1, "observables": [], "where": [], "selected": [],
            "gap": {"rms_mm": null, "max_abs_mm": null, "noise_floor_mm": null, "n": 0},
            "unexplained": {"rms_mm": null, "share": null, "where": []},
            "noise_floor_source": "replicates",
            "cv": {"folds": 5, "by": "run", "test": "", "seed": 0},
            "notes": [], "per_observable": per, "effects": effects}))
        .unwrap()
    }

    /// One night's diagnosis.json: wear (dominant, k) and, when `extra`,
    /// a secondary offset on the same observable.
    fn night(k: f64, se: f64, extra: Option<f64>) -> Diagnosis {
        let mut effects = vec![serde_json::json!({
            "name": "wear", "covariate": "removed_mm3", "observable": "cut_depth",
            "selected": true, "shrink": 0.7, "params": {"k": k}, "p_value": 1e-9,
            "cv_rms_before_mm": 0.01, "cv_rms_after_mm": 0.003,
            "intervals": {"k": {"se": se, "lo": k - 1.96 * se, "hi": k + 1.96 * se}}})];
        if let Some(a) = extra {
            effects.push(serde_json::json!({
                "name": "offset", "observable": "cut_depth", "selected": true, "shrink": 0.3,
                "params": {"a": a}, "p_value": 1e-4,
                "cv_rms_before_mm": 0.003, "cv_rms_after_mm": 0.0022,
                "intervals": {"a": {"se": 1e-5, "lo": a - 2e-5, "hi": a + 2e-5}}}));
        }
        diagnosis(serde_json::json!({
            "per_observable": [{"observable": "cut_depth", "unit": "mm", "rms_mm": 0.01,
                                "noise_floor_mm": 0.002, "runs": 8, "shrink": 0.7,
                                "machines": ["form-1"]}],
            "effects": effects,
        }))
    }

    fn date(i: usize) -> String {
        format!("2026-11-{:02}", i + 1)
    }

    fn history(ks: &[f64], extra: &[Option<f64>]) -> Vec<HistoryRow> {
        ks.iter()
            .enumerate()
            .flat_map(|(i, k)| {
                rows_of(
                    &night(*k, 0.002e-5, extra.get(i).copied().flatten()),
                    &date(i),
                    "c1",
                )
            })
            .collect()
    }

    fn run(rows: &[HistoryRow], events: &[Event]) -> Trend {
        trend(rows, events, Vec::new(), &TrendConfig::default())
    }

    #[test]
    fn nights_are_dates() {
        assert!(check_night("2026-11-25").is_ok());
        for bad in [
            "2026-13-01",
            "26-11-25",
            "2026/11/25",
            "yesterday",
            "2026-11-2x",
        ] {
            assert!(check_night(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_process_wandering_a_few_per_cent_does_not_alert_but_a_40_per_cent_step_does_once() {
        // A 2 % wander at 10 within-night standard errors: the old rule's
        // false alarm; the floor on the night-to-night spread absorbs it.
        let steady = [1.0e-5, 1.02e-5, 0.99e-5, 1.01e-5, 0.98e-5, 1.0e-5];
        let t = run(&history(&steady, &[]), &[]);
        assert!(t.alerts.is_empty(), "{:#?}", t.alerts);
        let mut ks = steady.to_vec();
        ks.extend([1.4e-5, 1.41e-5, 1.39e-5]);
        let t = run(&history(&ks, &[]), &[]);
        assert_eq!(
            t.alerts.len(),
            1,
            "one alert, then the new level: {:#?}",
            t.alerts
        );
        let a = &t.alerts[0];
        assert_eq!(
            (a.kind.as_str(), a.night.as_str(), a.rank),
            ("moved", "2026-11-07", 1)
        );
        // The fleet-wide fit of an observable one machine measures: on it.
        assert_eq!(a.machine, None);
        assert_eq!(a.machines, ["form-1"]);
        assert!(a.message.contains("on machine form-1"), "{}", a.message);
        // Size: 40 % of what wear explains (√(0.01² − 0.003²) mm).
        let explained = (0.01f64.powi(2) - 0.003f64.powi(2)).sqrt();
        assert!(
            (a.size.unwrap() / (0.4 * explained) - 1.0).abs() < 0.02,
            "{a:?}"
        );
        assert!((a.fraction_of_gap.unwrap() - a.size.unwrap() / 0.01).abs() < 1e-12);
        assert!(a.p_holm.unwrap() <= 0.01 && a.tests >= 1);
    }

    #[test]
    fn a_20_per_cent_step_is_raised_within_three_nights() {
        let mut ks = vec![1.0e-5, 1.02e-5, 0.99e-5, 1.01e-5, 0.98e-5];
        ks.extend([1.2e-5, 1.21e-5, 1.19e-5]);
        let t = run(&history(&ks, &[]), &[]);
        assert_eq!(t.alerts.len(), 1, "{:#?}", t.alerts);
        assert!(
            t.alerts[0].night.as_str() <= "2026-11-08",
            "{:?}",
            t.alerts[0]
        );
        assert_eq!(t.alerts[0].from_night, "2026-11-06");
    }

    #[test]
    fn flickering_effects_do_not_alert_and_persistent_ones_do() {
        let ks = [1.0e-5; 8];
        let flicker: Vec<Option<f64>> = (0..8).map(|i| (i % 2 == 0).then_some(0.002)).collect();
        let t = run(&history(&ks, &flicker), &[]);
        assert!(t.alerts.is_empty(), "{:#?}", t.alerts);
        // Absent four nights, then present: appeared on the second night.
        let late: Vec<Option<f64>> = (0..8).map(|i| (i >= 4).then_some(0.002)).collect();
        let t = run(&history(&ks, &late), &[]);
        let kinds: Vec<(&str, &str)> = t
            .alerts
            .iter()
            .map(|a| (a.kind.as_str(), a.night.as_str()))
            .collect();
        assert_eq!(kinds, [("appeared", "2026-11-06")], "{:#?}", t.alerts);
        assert_eq!(t.alerts[0].from_night, "2026-11-05");
        // A minor effect is never present.
        let mut rows = history(&ks, &late);
        for r in rows.iter_mut().filter(|r| r.effect == "offset") {
            r.minor = true;
        }
        assert!(run(&rows, &[]).alerts.is_empty());
    }

    #[test]
    fn an_event_starts_a_new_baseline_and_a_config_change_is_one() {
        let mut ks = vec![1.0e-5, 1.02e-5, 0.99e-5, 1.01e-5];
        ks.extend([2.0e-5, 2.01e-5, 1.99e-5]);
        let rows = history(&ks, &[]);
        assert_eq!(run(&rows, &[]).alerts.len(), 1);
        let dressing =
            parse_event("night=2026-11-05,machine=form-1,kind=wheel_change", None).unwrap();
        let t = run(&rows, std::slice::from_ref(&dressing));
        assert!(t.alerts.is_empty(), "{:#?}", t.alerts);
        assert_eq!(t.events, [dressing]);
        // Another machine's event leaves this one's baseline alone.
        let other = parse_event("night=2026-11-05,machine=gantry-2,kind=repair", None).unwrap();
        assert_eq!(run(&rows, &[other]).alerts.len(), 1);
        // The settings changed on night 5: marked, and no alert.
        let mut rows = rows;
        for r in rows.iter_mut().filter(|r| r.night.as_str() >= "2026-11-05") {
            r.config = "c2".into();
        }
        let t = run(&rows, &[]);
        assert!(t.alerts.is_empty(), "{:#?}", t.alerts);
        assert_eq!(t.events.len(), 1);
        assert_eq!(
            (t.events[0].kind.as_str(), t.events[0].night.as_str()),
            ("config", "2026-11-05")
        );
    }

    #[test]
    fn alerts_of_a_night_are_ranked_by_the_share_of_the_gap_they_move() {
        // Two observables in different units; the small-unit one moves
        // more of its gap.
        let mut rows = Vec::new();
        for (i, (k, g)) in [
            (1.0, 1.0),
            (1.01, 0.99),
            (0.99, 1.0),
            (1.0, 1.01),
            (1.3, 2.0),
        ]
        .iter()
        .enumerate()
        {
            let d = diagnosis(serde_json::json!({
                "per_observable": [
                    {"observable": "a_um", "unit": "um", "rms_mm": 10.0, "runs": 4},
                    {"observable": "b_deg", "unit": "deg", "rms_mm": 0.1, "runs": 4}],
                "effects": [
                    {"name": "wear", "covariate": "removed_mm3", "observable": "a_um",
                     "selected": true, "params": {"k": k}, "p_value": 1e-9,
                     "cv_rms_before_mm": 10.0, "cv_rms_after_mm": 2.0,
                     "intervals": {"k": {"se": 0.001}}},
                    {"name": "drift", "covariate": "t_s", "observable": "b_deg",
                     "selected": true, "params": {"a": g}, "p_value": 1e-9,
                     "cv_rms_before_mm": 0.1, "cv_rms_after_mm": 0.02,
                     "intervals": {"a": {"se": 0.001}}}]}));
            rows.extend(rows_of(&d, &date(i), ""));
        }
        let t = run(&rows, &[]);
        let on: Vec<&Alert> = t.alerts_on("2026-11-05").collect();
        assert_eq!(on.len(), 2, "{:#?}", t.alerts);
        assert_eq!((on[0].observable.as_str(), on[0].rank), ("b_deg", 1));
        assert_eq!((on[1].observable.as_str(), on[1].rank), ("a_um", 2));
        assert!(on[0].fraction_of_gap > on[1].fraction_of_gap);
        assert_eq!(on[0].unit, "deg");
    }

    #[test]
    fn histories_round_trip_old_versions_upgrade_and_newer_ones_are_refused() {
        let d = tempfile::tempdir().unwrap();
        let h = d.path();
        let rows = history(&[1.0e-5, 1.0e-5], &[]);
        write_night(h, "2026-11-02", &rows[rows.len() / 2..]).unwrap();
        // Night 1 as version 1 wrote it: no version column, no new columns.
        let old: Vec<HistoryRow> = rows[..rows.len() / 2].to_vec();
        let b = history::tests_support::v1_batch(&old);
        crate::contracts::write_parquet_atomic(&h.join("night=2026-11-01/diagnosis.parquet"), &b)
            .unwrap();
        let (back, notes) = read_history(h).unwrap();
        assert_eq!(back.len(), rows.len());
        assert_eq!(notes.len(), 1, "{notes:?}");
        assert!(notes[0].contains("version 1") && notes[0].contains("2026-11-01"));
        let wear = back
            .iter()
            .find(|r| r.night == "2026-11-01" && r.effect == "wear:removed_mm3")
            .unwrap();
        assert!(wear.explained_rms > 0.0 && wear.config.is_empty());
        // (NaN ≠ NaN: compared as printed.)
        assert_eq!(
            format!("{:?}", &back[back.len() / 2..]),
            format!("{:?}", &rows[rows.len() / 2..])
        );
        // A night of a newer history version.
        let mut newer = batch_with_version(&rows[..1], HISTORY_VERSION + 1);
        crate::contracts::write_parquet_atomic(
            &h.join("night=2026-11-03/diagnosis.parquet"),
            &newer,
        )
        .unwrap();
        let err = read_history(h).unwrap_err().to_string();
        assert!(
            err.contains("night=2026-11-03")
                && err.contains("history_version")
                && err.contains("update sparkout"),
            "{err}"
        );
        newer = batch_with_version(&rows[..1], HISTORY_VERSION);
        crate::contracts::write_parquet_atomic(
            &h.join("night=2026-11-03/diagnosis.parquet"),
            &newer,
        )
        .unwrap();
        // trend.json is written and read through the same types.
        let t = write_trend(h, &d.path().join("t"), &[], &TrendConfig::default()).unwrap();
        // (serde_json parses floats to within an ulp: the numbers are
        // compared apart.)
        let back = read_trend(&d.path().join("t/trend.json")).unwrap();
        assert_eq!(
            (
                &back.nights,
                &back.events,
                &back.notes,
                &back.alerts,
                &back.settings
            ),
            (&t.nights, &t.events, &t.notes, &t.alerts, &t.settings)
        );
        assert_eq!(back.series.len(), t.series.len());
        for (a, b) in back.series[0].points.iter().zip(&t.series[0].points) {
            assert!((a.lo95.unwrap() / b.lo95.unwrap() - 1.0).abs() < 1e-12);
        }
        std::fs::write(d.path().join("t/trend.json"), b"{\"version\": 1}").unwrap();
        let err = read_trend(&d.path().join("t/trend.json"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("version 1") && err.contains("sparkout trend"),
            "{err}"
        );
    }

    fn batch_with_version(rows: &[HistoryRow], v: u32) -> arrow::array::RecordBatch {
        history::tests_support::with_version(rows, v)
    }
}

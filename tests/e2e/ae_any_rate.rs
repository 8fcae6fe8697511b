//! AE contact detection at any sample rate, from the CLI with the default
//! settings: a generated 250 Hz conditioned RMS run and a generated 1 MHz
//! raw run give exactly one contact per planned touch, each at the true
//! contact time within a stated tolerance; hand-tuned settings that break
//! contacts up raise the fragmentation warning; a flickering signal given to
//! `stage ingest --ae` says so in its JSON.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use arrow::array::{Array, Float64Array, Int32Array, StringArray};
use sparkout_pipeline::contracts::{read_parquet, write_parquet_atomic, BatchBuilder};

use crate::common::{sparkout, text};

/// `sparkout generate robot --runs 1 --seed 5 [extra]`: the run directory.
fn generate(root: &Path, extra: &[&str]) -> PathBuf {
    let out = root.join("runs");
    let mut args = vec![
        "generate",
        "robot",
        "--runs",
        "1",
        "--seed",
        "5",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend(extra);
    let o = sparkout(&args);
    assert!(o.status.success(), "{}", text(&o));
    out.join("kr16-lab").join("r0000")
}

/// `sparkout stage ingest --run DIR --out OUT [flags]`: the summary and the
/// contacts table's (ae_t_s, seq, role).
fn ingest(run: &Path, out: &Path, flags: &[&str]) -> (serde_json::Value, Vec<(f64, i32, String)>) {
    let mut args = vec![
        "stage",
        "ingest",
        "--run",
        run.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend(flags);
    let o = sparkout(&args);
    assert!(o.status.success(), "{}", text(&o));
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("ingest.json")).unwrap()).unwrap();
    let b = read_parquet(&out.join("contacts.parquet")).unwrap();
    let col = |n: &str| b.column_by_name(n).unwrap().clone();
    let t = col("ae_t_s");
    let t = t.as_any().downcast_ref::<Float64Array>().unwrap();
    let s = col("seq");
    let s = s.as_any().downcast_ref::<Int32Array>().unwrap();
    let r = col("role");
    let r = r.as_any().downcast_ref::<StringArray>().unwrap();
    let rows = (0..b.num_rows())
        .map(|i| (t.value(i), s.value(i), r.value(i).to_string()))
        .collect();
    (summary, rows)
}

/// truth.json's contacts: seq → AE recorder time of the true contact.
fn true_contacts(run: &Path) -> BTreeMap<i32, f64> {
    let t: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("truth.json")).unwrap()).unwrap();
    t["contacts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            (
                c["seq"].as_i64().unwrap() as i32,
                c["ae_t_s"].as_f64().unwrap(),
            )
        })
        .collect()
}

/// One contact per planned touch, nothing else, no warning; each contact's
/// onset no earlier than the truth (less a rounding) and at most `tol_s`
/// after it. Returns the largest onset error (s).
fn one_contact_per_touch(run: &Path, out: &Path, signal: &str, tol_s: f64) -> f64 {
    let (s, rows) = ingest(run, out, &[]);
    let ae = &s["ae"];
    let truth = true_contacts(run);
    assert_eq!(ae["params"]["signal"], signal, "{ae}");
    assert_eq!(ae["events"].as_u64(), Some(truth.len() as u64), "{ae}");
    assert_eq!(ae["touches"].as_u64(), Some(truth.len() as u64), "{ae}");
    assert_eq!(ae["extra_events"], 0, "{ae}");
    assert_eq!(ae["unassigned_events"], 0, "{ae}");
    assert_eq!(ae["n_missed"], 0, "{ae}");
    assert_eq!(ae["warnings"].as_array().unwrap().len(), 0, "{ae}");
    let mut worst = 0.0f64;
    for (t, seq, role) in &rows {
        assert_eq!(role, "touch");
        let t0 = truth[seq];
        assert!(
            *t >= t0 - 1e-9 && *t - t0 <= tol_s,
            "seq {seq}: contact at {t} s, truth {t0} s (tolerance {tol_s} s)"
        );
        worst = worst.max(t - t0);
    }
    worst
}

#[test]
fn rms_250_hz_run_one_contact_per_touch_with_the_defaults() {
    let tmp = tempfile::tempdir().unwrap();
    let run = generate(tmp.path(), &["--ae-signal", "rms"]);
    let toml = std::fs::read_to_string(run.join("run.toml")).unwrap();
    assert!(
        toml.contains("sample_rate_hz = 250.0") && toml.contains("kind = \"rms\""),
        "{toml}"
    );
    // Tolerance: two sample periods (8 ms; 40 µm of travel at 5 mm/s). The
    // cut enters over a few ms, so its first sample above the threshold is
    // the first or the second after the contact.
    let worst = one_contact_per_touch(&run, &tmp.path().join("out"), "rms", 2.0 / 250.0);
    assert!(worst > 0.0, "the onset is a sample time after the contact");
    let (s, _) = ingest(&run, &tmp.path().join("out2"), &[]);
    let p = &s["ae"]["params"];
    assert_eq!(p["window_samples"], 1, "{p}");
    assert_eq!(p["min_dwell_samples"], 3, "{p}");
    assert_eq!(s["ae"]["recording_blocks"], 1, "{}", s["ae"]);
    // The log is an RMS: never negative, one continuous recording.
    let mut n = 0usize;
    for c in sparkout_pipeline::contracts::AeStream::open(&run.join("ae.parquet")).unwrap() {
        let c = c.unwrap();
        assert!(c.ae_v.iter().all(|&x| x > 0.0));
        n += c.ae_v.len();
    }
    assert_eq!(s["ae"]["samples"].as_u64(), Some(n as u64));
    // Same seed, same bytes.
    let again = generate(&tmp.path().join("again"), &["--ae-signal", "rms"]);
    for f in ["ae.parquet", "truth.json", "run.toml", "motion.parquet"] {
        assert!(
            std::fs::read(run.join(f)).unwrap() == std::fs::read(again.join(f)).unwrap(),
            "{f} differs between two generations with one seed"
        );
    }
}

#[test]
fn ae_signal_flag_is_checked() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("runs");
    let gen = |what: &str, extra: &[&str]| {
        let mut args = vec![
            "generate",
            what,
            "--runs",
            "1",
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend(extra);
        sparkout(&args)
    };
    // An RMS logger below 100 Hz cannot see a 55 ms touch.
    let o = gen("robot", &["--ae-signal", "rms", "--ae-rate-hz", "20"]);
    assert!(!o.status.success());
    assert!(text(&o).contains("100 Hz"), "{}", text(&o));
    // A raw log needs a carrier: 250 Hz is refused for raw.
    let o = gen("robot", &["--ae-signal", "raw", "--ae-rate-hz", "250"]);
    assert!(!o.status.success());
    assert!(text(&o).contains("20 kHz"), "{}", text(&o));
    let o = gen("robot", &["--ae-signal", "envelope"]);
    assert!(!o.status.success());
    assert!(text(&o).contains("rms"), "{}", text(&o));
    // A machine without an AE log refuses the flag.
    let o = gen("mill", &["--ae-signal", "rms"]);
    assert!(!o.status.success());
    assert!(text(&o).contains("--ae-signal"), "{}", text(&o));
}

#[test]
fn raw_1_mhz_run_one_contact_per_touch_with_the_defaults() {
    let tmp = tempfile::tempdir().unwrap();
    let run = generate(tmp.path(), &[]);
    // Tolerance: 0.1 ms, a tenth of the 1 ms RMS window (the burst rises
    // within 20 µs; the window crosses the threshold a few µs later).
    one_contact_per_touch(&run, &tmp.path().join("out"), "raw", 1e-4);
}

#[test]
fn hand_tuned_settings_that_fragment_contacts_raise_the_warning() {
    let tmp = tempfile::tempdir().unwrap();
    let run = generate(tmp.path(), &["--ae-signal", "rms"]);
    let planned = true_contacts(&run).len();
    // A threshold in the air's scatter, one-sample dwell, no merging.
    let (s, _) = ingest(
        &run,
        &tmp.path().join("out"),
        &[
            "--k-sigma",
            "1",
            "--min-dwell-s",
            "0.004",
            "--merge-gap-s",
            "0",
        ],
    );
    let ae = &s["ae"];
    assert!(ae["events"].as_u64().unwrap() > 2 * planned as u64, "{ae}");
    let w: Vec<&str> = ae["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w.as_str().unwrap())
        .collect();
    assert!(
        w.iter()
            .any(|w| w.contains(&format!("for {planned} planned touches"))),
        "{w:?}"
    );
    assert!(w.iter().all(|w| w.contains("fragmented")), "{w:?}");
}

#[test]
fn a_flickering_signal_file_says_so_in_its_json() {
    // 250 Hz conditioned RMS written here: 4 s of air at 10 mV (±10 %,
    // a fixed pattern), a 2 s cut that is 1 sample at 0.1 V then 2 at
    // 3 mV, 2 s of air. The cut starts at sample 1000 (4.0 s).
    let tmp = tempfile::tempdir().unwrap();
    let f = tmp.path().join("flicker.parquet");
    let v: Vec<f64> = (0..2000usize)
        .map(|i| match i {
            1000..1500 if i % 3 == 1 => 0.1,
            1000..1500 => 0.003,
            _ => 0.01 * (1.0 + 0.1 * ((i * 7 % 13) as f64 - 6.0) / 6.0),
        })
        .collect();
    // Beside it a raw-looking column (a sine: negative from sample 4 on).
    let raw: Vec<f64> = (0..2000).map(|i| 0.01 * (i as f64).sin()).collect();
    write_parquet_atomic(
        &f,
        &BatchBuilder::new()
            .f64("rms_v", v)
            .f64("raw_v", raw)
            .build(),
    )
    .unwrap();
    let run = |flags: &[&str]| -> serde_json::Value {
        let mut args = vec![
            "stage",
            "ingest",
            "--ae",
            f.to_str().unwrap(),
            "--sample-rate-hz",
            "250",
            "--column",
            "rms_v",
            "--json",
        ];
        args.extend(flags);
        let o = sparkout(&args);
        assert!(o.status.success(), "{}", text(&o));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    // The defaults: the signal is guessed an RMS (never negative), the
    // flickers chain into one contact from the cut's first sample; its
    // ripple is no warning.
    let d = run(&[]);
    assert_eq!(d["params"]["signal"], "rms", "{d}");
    let c = d["contacts"].as_array().unwrap();
    assert_eq!(c.len(), 1, "{d}");
    let start = c[0]["start_s"].as_f64().unwrap();
    assert!((start - 1000.0 / 250.0).abs() < 1e-9, "{start}");
    assert_eq!(d["warnings"].as_array().unwrap().len(), 0, "{d}");
    // A one-sample dwell without merging: 167 contacts, and the warning.
    let d = run(&[
        "--signal",
        "rms",
        "--min-dwell-s",
        "0.004",
        "--merge-gap-s",
        "0",
    ]);
    assert_eq!(d["contacts"].as_array().unwrap().len(), 167, "{d}");
    let w = d["warnings"].as_array().unwrap();
    assert!(
        w.len() == 1 && w[0].as_str().unwrap().contains("fragmented"),
        "{d}"
    );
    // A column said to be an RMS that goes negative: the warning names the
    // file, the column and the first negative row.
    let mut args = vec!["stage", "ingest", "--ae", f.to_str().unwrap()];
    args.extend([
        "--sample-rate-hz",
        "250",
        "--column",
        "raw_v",
        "--signal",
        "rms",
        "--json",
    ]);
    let o = sparkout(&args);
    assert!(o.status.success(), "{}", text(&o));
    let d: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let w = d["warnings"][0].as_str().unwrap_or_default();
    assert!(
        w.contains("flicker.parquet") && w.contains("`raw_v`") && w.contains("row 4"),
        "{d}"
    );
    // A bad --signal names the flag and what it may be.
    let o = sparkout(&[
        "stage",
        "ingest",
        "--ae",
        f.to_str().unwrap(),
        "--sample-rate-hz",
        "250",
        "--column",
        "rms_v",
        "--signal",
        "envelope",
    ]);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("signal") && e.contains("rms"), "{e}");
}

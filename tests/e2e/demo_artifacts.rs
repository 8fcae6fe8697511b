//! A non-finite number never reaches an artifact or a fleet
//! summary. `sparkout demo` runs every plugin and the fleet diagnosis; every
//! file it writes is scanned: floating-point Parquet columns must hold only
//! finite values (null is the contract's "no value"), JSON must not carry
//! NaN/Infinity (serde writes them as null, so a token would mean a
//! hand-written writer), and no HTML page may print NaN or inf to a reader.

use std::fs::File;
use std::path::{Path, PathBuf};

use arrow::array::{Array, AsArray};
use arrow::datatypes::{DataType, Float32Type, Float64Type};
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;

use super::common::sparkout;

fn files_under(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).expect("list dir").flatten() {
        let p = e.path();
        if p.is_dir() {
            files_under(&p, out);
        } else {
            out.push(p);
        }
    }
}

/// "row R of column C" of the first non-finite float in a Parquet file.
fn first_non_finite_in_parquet(path: &Path) -> Option<String> {
    let reader = ParquetRecordBatchReaderBuilder::try_new(File::open(path).expect("open"))
        .expect("artifact is Parquet")
        .build()
        .expect("reader");
    let mut row0 = 0usize;
    for batch in reader {
        let batch = batch.expect("artifact decodes");
        for (field, col) in batch.schema().fields().iter().zip(batch.columns()) {
            let bad = match field.data_type() {
                DataType::Float64 => col
                    .as_primitive::<Float64Type>()
                    .iter()
                    .position(|v| v.is_some_and(|x| !x.is_finite())),
                DataType::Float32 => col
                    .as_primitive::<Float32Type>()
                    .iter()
                    .position(|v| v.is_some_and(|x| !x.is_finite())),
                _ => None,
            };
            if let Some(r) = bad {
                return Some(format!("row {} of column `{}`", row0 + r, field.name()));
            }
        }
        row0 += batch.num_rows();
    }
    None
}

/// A word NaN / inf / Infinity as text (not inside an identifier like
/// `infeed_count` or `info`).
fn non_finite_word(text: &str) -> Option<String> {
    let bytes = text.as_bytes();
    for word in ["NaN", "nan", "inf", "Infinity"] {
        let mut from = 0;
        while let Some(i) = text[from..].find(word) {
            let at = from + i;
            let end = at + word.len();
            let before_ok =
                at == 0 || !bytes[at - 1].is_ascii_alphanumeric() && bytes[at - 1] != b'_';
            let after_ok =
                end == bytes.len() || !bytes[end].is_ascii_alphanumeric() && bytes[end] != b'_';
            if before_ok && after_ok {
                let lo = at.saturating_sub(60);
                let hi = (end + 60).min(text.len());
                let lo = (0..=lo)
                    .rev()
                    .find(|&k| text.is_char_boundary(k))
                    .unwrap_or(0);
                let hi = (hi..=text.len())
                    .find(|&k| text.is_char_boundary(k))
                    .unwrap_or(text.len());
                return Some(format!("`{word}` in …{}…", &text[lo..hi]));
            }
            from = end;
        }
    }
    None
}

#[test]
fn demo_artifacts_hold_no_non_finite_number() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let o = sparkout(&["demo", "--out", tmp.path().to_str().expect("utf-8 path")]);
    assert!(
        o.status.success(),
        "demo failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let mut files = Vec::new();
    files_under(&tmp.path().join("out"), &mut files);
    files.sort();
    let (mut parquet, mut json, mut html) = (0, 0, 0);
    let mut problems = Vec::new();
    for f in &files {
        let name = f.display().to_string();
        match f.extension().and_then(|e| e.to_str()) {
            Some("parquet") => {
                parquet += 1;
                if let Some(w) = first_non_finite_in_parquet(f) {
                    problems.push(format!("{name}: non-finite value at {w}"));
                }
            }
            Some("json") => {
                json += 1;
                let text = std::fs::read_to_string(f).expect("json is text");
                serde_json::from_str::<serde_json::Value>(&text)
                    .unwrap_or_else(|e| panic!("{name} is not JSON: {e}"));
                if let Some(w) = non_finite_word(&text) {
                    problems.push(format!("{name}: {w}"));
                }
            }
            Some("html") => {
                html += 1;
                let text = std::fs::read_to_string(f).expect("html is text");
                if let Some(w) = non_finite_word(&text) {
                    problems.push(format!("{name}: {w}"));
                }
            }
            _ => {}
        }
    }
    // The demo runs six plugins: many artifacts of each kind, or the scan
    // looked at the wrong directory.
    assert!(
        parquet >= 30 && json >= 30 && html >= 6,
        "too few artifacts scanned: {parquet} parquet, {json} json, {html} html"
    );
    assert!(
        problems.is_empty(),
        "non-finite numbers in demo artifacts:\n{}",
        problems.join("\n")
    );
    // Every JSON file sparkout's own types write reads back through the
    // type that wrote it into the same JSON: no field the type does not
    // know, none it would drop or rename. (Stage summaries are the
    // plugins' own; truth.json is the generators', checked by their tests.)
    let out = tmp.path().join("out");
    let diagnosis: sparkout_pipeline::diagnose::Diagnosis =
        reads_back(&out.join("fleet/diagnosis.json"));
    assert!(!diagnosis.per_observable.is_empty());
    let model: sparkout_pipeline::diagnose::augment::AugmentedModelFile =
        reads_back(&out.join("fleet/augmented_model.json"));
    assert!(!model.effects.is_empty());
    sparkout_pipeline::diagnose::augment::AugmentedModel::load(
        &out.join("fleet/augmented_model.json"),
    )
    .expect("the demo's model loads for --augment");
    let manifest: sparkout_pipeline::outcome::Manifest = reads_back(&out.join("manifest.json"));
    assert_eq!(manifest.runs.len(), 35, "{:?}", manifest.runs.len());
    let failures: Vec<sparkout_pipeline::outcome::Failure> = reads_back(&out.join("failures.json"));
    assert!(failures.is_empty(), "{failures:?}");
    let (mut caches, mut verdicts) = (0, 0);
    for f in &files {
        match f.file_name().and_then(|n| n.to_str()) {
            Some(sparkout_pipeline::files::RUN_CACHE_FILE) => {
                let r: Vec<sparkout_pipeline::outcome::StageRecord> = reads_back(f);
                assert!(!r.is_empty(), "{}", f.display());
                caches += 1;
            }
            Some(sparkout_pipeline::verdict::RUN_VERDICT_FILE) => {
                let _: sparkout_pipeline::verdict::RunVerdict = reads_back(f);
                verdicts += 1;
            }
            _ => {}
        }
    }
    // A cache file per run and one for the fleet; a verdict per run.
    assert_eq!((caches, verdicts), (36, 35));
}

/// `path` read through `T`, which must write back every field the file
/// holds.
fn reads_back<T: serde::de::DeserializeOwned + serde::Serialize>(path: &Path) -> T {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let typed: T = sparkout_pipeline::files::json::parse_json(path, &bytes)
        .unwrap_or_else(|e| panic!("does not read as its serde type: {e}"));
    if let Some(d) = sparkout_pipeline::files::json::reads_back_whole(&typed, &bytes) {
        panic!(
            "{} does not round-trip through its type: {d}",
            path.display()
        );
    }
    typed
}

#[test]
fn the_scan_finds_what_it_looks_for() {
    // The scanners themselves must be able to fail.
    assert!(non_finite_word("gap NaN µm").is_some());
    assert!(non_finite_word("<td>inf</td>").is_some());
    assert!(non_finite_word("infeed_count info Infinite nano").is_none());
    let tmp = tempfile::tempdir().expect("tempdir");
    let p = tmp.path().join("x.parquet");
    let batch = arrow::record_batch::RecordBatch::try_from_iter([(
        "v",
        std::sync::Arc::new(arrow::array::Float64Array::from(vec![1.0, f64::INFINITY]))
            as std::sync::Arc<dyn Array>,
    )])
    .expect("batch");
    let mut w = parquet::arrow::ArrowWriter::try_new(
        File::create(&p).expect("create"),
        batch.schema(),
        None,
    )
    .expect("writer");
    w.write(&batch).expect("write");
    w.close().expect("close");
    assert_eq!(
        first_non_finite_in_parquet(&p).as_deref(),
        Some("row 1 of column `v`")
    );
}

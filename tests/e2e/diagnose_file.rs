//! The fleet diagnosis reads its observations file one observable at a
//! time (the file's columns, or the covariates the join spills per
//! observable). On a table pyarrow wrote with its defaults — snappy,
//! dictionary-encoded text, 500-row groups, a µm observable, an int
//! covariate, a covariate null on every row, two machines sharing run ids
//! — both give exactly the diagnosis of the file read whole.

use std::path::PathBuf;

use arrow::array::RecordBatchReader;

use sparkout_pipeline::config_check::Checked;
use sparkout_pipeline::diagnose::observations_file::RowValueSpill;
use sparkout_pipeline::diagnose::{
    diagnose_checked, diagnose_observations_file, read_observations, DiagnoseConfig,
    DiagnosisOutput,
};

fn fixture() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/observations/pyarrow_two_machines.parquet")
}

fn json(d: &DiagnosisOutput) -> String {
    serde_json::to_string(&d.diagnosis).unwrap()
}

#[test]
fn a_pyarrow_table_diagnoses_the_same_read_whole_per_observable_or_spilled() {
    let path = fixture();
    let cfg = Checked::check(DiagnoseConfig::default()).unwrap();
    let whole = diagnose_checked(read_observations(&path).unwrap(), &cfg, &[]).unwrap();
    let d = &whole.diagnosis;
    // The fixture exercises what it is meant to.
    assert!(
        d.notes.iter().any(|n| n.contains("temp_c")),
        "{:?}",
        d.notes
    );
    assert_eq!(d.per_observable[0].unit, "mm");
    assert!(
        d.machine_effects.iter().any(|e| e.machine == "m2"),
        "{:#?}",
        d.where_
    );
    let by_observable = diagnose_observations_file(&path, &cfg, &[], None, None, &|_| {}).unwrap();
    assert_eq!(json(&whole), json(&by_observable));
    assert_eq!(
        whole.per_row.to_batch().unwrap(),
        by_observable.per_row.to_batch().unwrap()
    );

    let dir = tempfile::tempdir().unwrap();
    let spill_dir = dir.path().join(".spill");
    let file = std::fs::File::open(&path).unwrap();
    let reader = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(file)
        .unwrap()
        .with_batch_size(700)
        .build()
        .unwrap();
    let mut spill = RowValueSpill::create(&spill_dir, &reader.schema()).unwrap();
    for b in reader {
        spill.push(&b.unwrap(), &path).unwrap();
    }
    let spilled = diagnose_observations_file(
        &path,
        &cfg,
        &[],
        Some(spill.finish().unwrap()),
        None,
        &|_| {},
    )
    .unwrap();
    assert_eq!(json(&whole), json(&spilled));
    assert_eq!(
        whole.per_row.to_batch().unwrap(),
        spilled.per_row.to_batch().unwrap()
    );
    assert!(!spill_dir.exists());
}

/// A table whose selection takes an effect out of the folds' targets and
/// scores the next round against what is left: a scale on x_mm and a
/// drift on t_s, 10 runs × 400 rows, 1 µm noise.
fn two_effect_table(path: &std::path::Path) {
    use sparkout_pipeline::contracts::{write_parquet_atomic, BatchBuilder};
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut noise = || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 2e-3
    };
    let (mut run, mut real, mut x, mut t) = (vec![], vec![], vec![], vec![]);
    for r in 0..10 {
        for i in 0..400 {
            let ti = i as f64 * 0.5;
            let xi = ((i * 37 + r * 11) % 400) as f64 * 0.25;
            run.push(format!("r{r:02}"));
            real.push(0.02 * (1.0 - (-ti / 40.0).exp()) + 4e-4 * xi + noise());
            x.push(xi);
            t.push(ti);
        }
    }
    let n = run.len();
    let batch = BatchBuilder::new()
        .str("run", &run.iter().map(|s| s.as_str()).collect::<Vec<_>>())
        .str("observable", &vec!["e_mm"; n])
        .f64("sim", vec![0.0; n])
        .f64("real", real)
        .f64("x_mm", x)
        .f64("t_s", t)
        .build();
    write_parquet_atomic(path, &batch).unwrap();
}

/// The folds' targets kept as columns (the default for a table this
/// small) or recomputed from the fits on every pass
/// (`SPARKOUT_TARGET_COLUMNS_MAX_BYTES=0`, what a large observable does):
/// `sparkout diagnose` writes the same bytes either way — on the pyarrow
/// table, and on a table whose selection scores a round after an effect
/// was taken out.
#[test]
fn the_targets_kept_or_recomputed_give_the_same_files() {
    let dir = tempfile::tempdir().unwrap();
    let two_effects = dir.path().join("two_effects.parquet");
    two_effect_table(&two_effects);
    const TARGETS: &str = "SPARKOUT_TARGET_COLUMNS_MAX_BYTES";
    const COVARIATES: &str = "SPARKOUT_COVARIATES_MAX_BYTES";
    let run = |table: &std::path::Path, budgets: &[(&str, &str)], out: &str| {
        let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_sparkout"));
        cmd.arg("diagnose")
            .arg(table)
            .arg("--out")
            .arg(dir.path().join(out))
            .env_remove(TARGETS)
            .env_remove(COVARIATES);
        for (var, b) in budgets {
            cmd.env(var, b);
        }
        let o = cmd.output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        dir.path().join(out)
    };
    // The two-effect table: a round scored after an effect was taken
    // out (its candidates' `step` 2 or later) reads recomputed targets.
    for (table, name, min_step) in [(fixture(), "pyarrow", 1), (two_effects, "two", 2)] {
        let kept = run(&table, &[], &format!("{name}-kept"));
        let recomputed = run(&table, &[(TARGETS, "0")], &format!("{name}-recomputed"));
        // The covariates read from a column file a chunk at a time, the
        // targets recomputed: still the same files, and the scratch
        // files gone.
        let streamed = run(
            &table,
            &[(TARGETS, "0"), (COVARIATES, "0")],
            &format!("{name}-streamed"),
        );
        let diagnosis: serde_json::Value =
            serde_json::from_slice(&std::fs::read(kept.join("diagnosis.json")).unwrap()).unwrap();
        assert!(
            !diagnosis["selected"].as_array().unwrap().is_empty(),
            "{name}: nothing selected"
        );
        let last_step = diagnosis["effects"]
            .as_array()
            .unwrap()
            .iter()
            .filter_map(|e| e["step"].as_u64())
            .max();
        assert!(
            last_step >= Some(min_step),
            "{name}: last round {last_step:?}"
        );
        let mut files: Vec<_> = std::fs::read_dir(&kept)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        files.sort();
        assert!(files.len() >= 3, "{files:?}");
        let listing = |d: &std::path::Path| {
            let mut l: Vec<_> = crate::bad_input_matrix::walk(d)
                .into_iter()
                .map(|p| p.strip_prefix(d).unwrap().to_path_buf())
                .collect();
            l.sort();
            l
        };
        assert_eq!(listing(&kept), listing(&streamed), "{name}: leftovers");
        for f in files {
            for other in [&recomputed, &streamed] {
                assert_eq!(
                    std::fs::read(kept.join(&f)).unwrap(),
                    std::fs::read(other.join(&f)).unwrap(),
                    "{name}: {f:?} of {}",
                    other.display()
                );
            }
        }
    }
}

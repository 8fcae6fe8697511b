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
    let by_observable = diagnose_observations_file(&path, &cfg, &[], None, None).unwrap();
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
    let spilled =
        diagnose_observations_file(&path, &cfg, &[], Some(spill.finish().unwrap()), None).unwrap();
    assert_eq!(json(&whole), json(&spilled));
    assert_eq!(
        whole.per_row.to_batch().unwrap(),
        spilled.per_row.to_batch().unwrap()
    );
    assert!(!spill_dir.exists());
}

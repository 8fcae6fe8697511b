//! One test per bad-input rule of docs/formats.md §1: each error names
//! the file, the column and (where it applies) the first offending row.

use std::path::Path;

use sparkout_pipeline::contracts::{
    schema, write_parquet_atomic, AeStream, BatchBuilder, MachineResolver, RunSpec, Table,
};
use sparkout_pipeline::InputError;

fn probe_batch(t: Vec<f64>, z: Vec<f64>) -> BatchBuilder {
    let n = t.len();
    BatchBuilder::new()
        .f64("t_s", t)
        .str("face", &vec!["xy"; n])
        .i32("point", (0..n as i32).collect())
        .i32("trial", vec![0; n])
        .str("method", &vec!["ae"; n])
        .f64("approach_mm_s", vec![5.0; n])
        .f64("nom_x_mm", vec![1.0; n])
        .f64("nom_y_mm", vec![2.0; n])
        .f64("nom_z_mm", vec![3.0; n])
        .f64("x_mm", vec![1.0; n])
        .f64("y_mm", vec![2.0; n])
        .f64("z_mm", z)
}

fn read_probe(dir: &Path, b: BatchBuilder) -> Result<Table, InputError> {
    let p = dir.join("probe.parquet");
    write_parquet_atomic(&p, &b.build()).unwrap();
    Table::read(&p, &sparkout_plugins::robot::tables::PROBE)
}

#[test]
fn good_table_reads_and_keeps_extra_columns() {
    let d = tempfile::tempdir().unwrap();
    let b = probe_batch(vec![0.0, 1.0, 1.0], vec![3.0; 3]).f64("operator_note", vec![7.0; 3]);
    let t = read_probe(d.path(), b).unwrap();
    assert_eq!(t.len(), 3);
    assert_eq!(t.f64("operator_note").unwrap(), &[7.0, 7.0, 7.0]);
    assert_eq!(t.str("face").unwrap(), vec!["xy"; 3]);
}

#[test]
fn missing_column_names_file_and_column() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("probe.parquet");
    let b = BatchBuilder::new().f64("t_s", vec![0.0]).build();
    write_parquet_atomic(&p, &b).unwrap();
    let e = Table::read(&p, &sparkout_plugins::robot::tables::PROBE).unwrap_err();
    assert_eq!(e.file, p);
    assert_eq!(e.column.as_deref(), Some("face"));
    assert!(e.to_string().contains("required column missing"), "{e}");
}

#[test]
fn wrong_type_is_rejected() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("motion.parquet");
    let b = BatchBuilder::new()
        .f64("t_s", vec![0.0])
        .str("cmd_x_mm", &["ten"])
        .f64("cmd_y_mm", vec![0.0])
        .f64("cmd_z_mm", vec![0.0])
        .build();
    write_parquet_atomic(&p, &b).unwrap();
    let e = Table::read(&p, &schema::MOTION).unwrap_err();
    assert_eq!(e.column.as_deref(), Some("cmd_x_mm"));
    assert!(e.to_string().contains("wrong type"), "{e}");
}

#[test]
fn nan_names_the_first_row() {
    let d = tempfile::tempdir().unwrap();
    let e = read_probe(
        d.path(),
        probe_batch(vec![0.0, 1.0, 2.0], vec![3.0, f64::NAN, 3.0]),
    )
    .unwrap_err();
    assert_eq!(e.column.as_deref(), Some("z_mm"));
    assert_eq!(e.row, Some(1));
    assert!(e.to_string().contains("NaN"), "{e}");
}

#[test]
fn infinity_names_the_first_row() {
    let d = tempfile::tempdir().unwrap();
    let e = read_probe(
        d.path(),
        probe_batch(vec![0.0, 1.0, 2.0], vec![3.0, 3.0, f64::NEG_INFINITY]),
    )
    .unwrap_err();
    assert_eq!(e.column.as_deref(), Some("z_mm"));
    assert_eq!(e.row, Some(2));
    assert!(e.to_string().contains("infinite"), "{e}");
}

#[test]
fn non_monotonic_time_is_rejected() {
    let d = tempfile::tempdir().unwrap();
    let e = read_probe(d.path(), probe_batch(vec![0.0, 2.0, 1.0], vec![3.0; 3])).unwrap_err();
    assert_eq!(e.column.as_deref(), Some("t_s"));
    assert_eq!(e.row, Some(2));
}

#[test]
fn empty_table_is_rejected() {
    let d = tempfile::tempdir().unwrap();
    let e = read_probe(d.path(), probe_batch(vec![], vec![])).unwrap_err();
    assert!(e.to_string().contains("empty"), "{e}");
}

#[test]
fn truncated_parquet_is_rejected() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("probe.parquet");
    write_parquet_atomic(&p, &probe_batch(vec![0.0, 1.0], vec![3.0; 2]).build()).unwrap();
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
    let e = Table::read(&p, &sparkout_plugins::robot::tables::PROBE).unwrap_err();
    assert_eq!(e.file, p);
    assert!(e.to_string().contains("Parquet"), "{e}");
}

#[test]
fn ae_stream_validates_across_row_groups() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("ae.parquet");
    let n = 10_000;
    let mut t: Vec<f64> = (0..n).map(|i| i as f64 * 1e-6).collect();
    t[7_500] = 0.0; // goes back in time in a later chunk
    let b = BatchBuilder::new()
        .f64("t_s", t)
        .f32("ae_v", vec![0.01; n])
        .build();
    write_parquet_atomic(&p, &b).unwrap();
    let chunks: Vec<_> = AeStream::open_with_batch(&p, 1000).unwrap().collect();
    let err = chunks.into_iter().find_map(|c| c.err()).expect("an error");
    assert_eq!(err.column.as_deref(), Some("t_s"));
    assert_eq!(err.row, Some(7_500));
}

#[test]
fn missing_run_toml_is_rejected() {
    let d = tempfile::tempdir().unwrap();
    let e = RunSpec::load(d.path()).unwrap_err();
    assert!(e.to_string().contains("run.toml"), "{e}");
}

#[test]
fn run_toml_missing_key_names_it() {
    let d = tempfile::tempdir().unwrap();
    let e = RunSpec::parse(d.path(), "[run]\nid = \"r1\"\nplugin = \"robot\"\n").unwrap_err();
    assert_eq!(e.column.as_deref(), Some("run.machine"));
}

#[test]
fn unknown_machine_says_where_it_looked() {
    let d = tempfile::tempdir().unwrap();
    let spec = RunSpec::parse(
        d.path(),
        "[run]\nid = \"r1\"\nmachine = \"no-such-machine\"\nplugin = \"robot\"\n",
    )
    .unwrap();
    let r = MachineResolver::new(Some(d.path().to_path_buf()), Default::default());
    let e = r.resolve(&spec).unwrap_err();
    assert!(
        e.to_string().contains("unknown machine `no-such-machine`"),
        "{e}"
    );
    // An inline [machine] table (a machine config one level down) resolves it.
    let spec = RunSpec::parse(
        d.path(),
        "[run]\nid = \"r1\"\nmachine = \"m\"\nplugin = \"robot\"\n[machine.wheel]\nradius_mm = 50.0\n",
    )
    .unwrap();
    let m = r.resolve(&spec).unwrap();
    assert_eq!(m.f64("wheel.radius_mm"), Some(50.0));
    // A key of [machine] that is not a section is refused when run.toml is read.
    let e = RunSpec::parse(
        d.path(),
        "[run]\nid = \"r1\"\nmachine = \"m\"\nplugin = \"robot\"\n[machine]\nwheel_radius_mm = 50.0\n",
    )
    .unwrap_err();
    assert_eq!(e.column.as_deref(), Some("machine.wheel_radius_mm"), "{e}");
}

/// Writes an AE log with `groups` row groups of `per_group` rows each.
fn ae_with_row_groups(p: &std::path::Path, t: Vec<f64>, per_group: usize) {
    use parquet::arrow::ArrowWriter;
    use parquet::file::properties::WriterProperties;
    let n = t.len();
    let b = BatchBuilder::new()
        .f64("t_s", t)
        .f32("ae_v", (0..n).map(|i| (i % 17) as f32 * 1e-3).collect())
        .build();
    let props = WriterProperties::builder()
        .set_max_row_group_row_count(Some(per_group))
        .build();
    let mut w =
        ArrowWriter::try_new(std::fs::File::create(p).unwrap(), b.schema(), Some(props)).unwrap();
    w.write(&b).unwrap();
    w.close().unwrap();
}

#[test]
fn ae_stream_parallel_decode_keeps_file_order() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("ae.parquet");
    let n = 23_456;
    ae_with_row_groups(&p, (0..n).map(|i| i as f64 * 1e-6).collect(), 1_000);
    let read = |threads| -> (Vec<usize>, Vec<f64>, Vec<f32>) {
        let mut firsts = vec![];
        let (mut t, mut v) = (vec![], vec![]);
        for c in AeStream::open_with(&p, 700, threads).unwrap() {
            let c = c.unwrap();
            firsts.push(c.first_row);
            t.extend_from_slice(&c.t_s);
            v.extend_from_slice(&c.ae_v);
        }
        (firsts, t, v)
    };
    let one = read(1);
    assert_eq!(one.1.len(), n);
    assert!(one.1.windows(2).all(|w| w[0] < w[1]));
    for threads in [2, 3, 8] {
        assert_eq!(read(threads), one, "{threads} decoder threads");
    }
}

#[test]
fn ae_stream_parallel_decode_reports_the_first_bad_row() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("ae.parquet");
    let n = 12_000;
    let mut t: Vec<f64> = (0..n).map(|i| i as f64 * 1e-6).collect();
    // Back in time exactly at a row-group boundary (group 5 of 1 000 rows),
    // where only the consumer can see it, and later a NaN inside a group.
    t[5_000] = 1e-6;
    t[9_123] = f64::NAN;
    ae_with_row_groups(&p, t, 1_000);
    for threads in [1, 4] {
        let err = AeStream::open_with(&p, 10_000, threads)
            .unwrap()
            .find_map(|c| c.err())
            .expect("an error");
        assert_eq!(err.column.as_deref(), Some("t_s"));
        assert_eq!(err.row, Some(5_000), "{threads} threads: {err}");
    }
}

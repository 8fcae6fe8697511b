//! Parquet that users have (docs/formats.md "Parquet"):
//! every codec × data page v1/v2 × dictionary/plain, written by arrow-rs
//! with the column types other tools use, read through every contract
//! reader; files written by pyarrow, pandas, polars and DuckDB with their
//! defaults (committed fixtures, datasets/fixtures/make_fixtures.py); and
//! damaged files whose errors say what is wrong.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow::array::{
    ArrayRef, DictionaryArray, Float32Array, Float64Array, Int16Array, Int32Array, Int64Array,
    Int8Array, LargeStringArray, StringArray, StringViewArray, TimestampMicrosecondArray,
    TimestampNanosecondArray, UInt16Array, UInt32Array, UInt64Array, UInt8Array,
};
use arrow::datatypes::{Field, Int32Type, Schema};
use arrow::record_batch::RecordBatch;
use parquet::arrow::ArrowWriter;
use parquet::basic::{BrotliLevel, Compression, GzipLevel, ZstdLevel};
use parquet::file::properties::{WriterProperties, WriterVersion};
use sparkout_pipeline::contracts::schema::{ColumnKind, TableSchema};
use sparkout_pipeline::contracts::{read_parquet, AeStream, Table};
use sparkout_pipeline::diagnose::read_observations;
use sparkout_pipeline::InputError;

const N: usize = 40;
/// 2026-11-20T08:00:00Z, seconds since the epoch.
const T0_UNIX_S: i64 = 1_795_161_600;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("datasets/fixtures")
}

fn codecs() -> Vec<Compression> {
    vec![
        Compression::UNCOMPRESSED,
        Compression::SNAPPY,
        Compression::GZIP(GzipLevel::default()),
        Compression::LZ4, // hadoop-framed
        Compression::LZ4_RAW,
        Compression::BROTLI(BrotliLevel::default()),
        Compression::ZSTD(ZstdLevel::default()),
    ]
}

/// The value each row of a contract column holds, as the reader must
/// return it (whatever physical type it was written as).
#[derive(Debug, Clone, PartialEq)]
enum Want {
    F(Vec<f64>),
    I(Vec<i64>),
    S(Vec<String>),
}

fn label(column: &str, i: usize) -> String {
    let opts: &[&str] = match column {
        "face" => &["xy", "yz", "zx"],
        "state" => &["pattern", "before", "final"],
        "stage" => &["rough", "finish", "spark"],
        "method" => &["ae", "electrical"],
        _ => &["s1", "s2", "s3", "s4"],
    };
    opts[i % opts.len()].to_string()
}

/// A column of `kind` written as physical variant `v` (rotating over the
/// types other tools write), and what reading it must give. Values are
/// whole numbers so that every type holds them exactly.
fn column(name: &str, kind: ColumnKind, v: usize) -> (ArrayRef, Want) {
    // Whole numbers inside the column's plausible range (contracts::plausible),
    // so the readers' plausibility check passes: 0..N, wrapped where the
    // range is narrower (a unit direction: 0, 1; an angle: 0..6), shifted to
    // its lower bound where that is above 0. Time columns stay increasing.
    let time = name == "t_s" || (name.starts_with("t_") && name.ends_with("_s"));
    let (lo, hi) = sparkout_pipeline::contracts::plausible::all_ranges(&crate::common::tables())
        .iter()
        .filter(|(_, c, _)| *c == name)
        .fold((f64::NEG_INFINITY, f64::INFINITY), |(lo, hi), (_, _, r)| {
            (lo.max(r.lo), hi.min(r.hi))
        });
    let lo = if lo.is_finite() {
        lo.max(0.0).ceil() as i64
    } else {
        0
    };
    let span = if hi.is_finite() {
        (hi.floor() as i64 - lo + 1).max(1)
    } else {
        i64::MAX
    };
    let idx: Vec<i64> = (0..N as i64)
        .map(|i| if time { i } else { lo + i % span })
        .collect();
    match kind {
        ColumnKind::F64 | ColumnKind::F32 => {
            let vals: Vec<f64> = idx.iter().map(|&i| i as f64).collect();
            let n_variants = if time { 7 } else { 5 };
            let a: ArrayRef = match v % n_variants {
                0 => Arc::new(Float64Array::from(vals.clone())),
                1 => Arc::new(Float32Array::from_iter_values(
                    vals.iter().map(|&x| x as f32),
                )),
                2 => Arc::new(Int64Array::from(idx.clone())),
                3 => arrow::compute::cast(
                    &Float64Array::from(vals.clone()),
                    &arrow::datatypes::DataType::Float16,
                )
                .unwrap(),
                4 => Arc::new(UInt16Array::from_iter_values(idx.iter().map(|&i| i as u16))),
                5 => Arc::new(TimestampMicrosecondArray::from_iter_values(
                    idx.iter().map(|&i| (T0_UNIX_S + i) * 1_000_000),
                )),
                _ => Arc::new(
                    TimestampNanosecondArray::from_iter_values(
                        idx.iter().map(|&i| (T0_UNIX_S + i) * 1_000_000_000),
                    )
                    .with_timezone("UTC"),
                ),
            };
            (a, Want::F(vals))
        }
        ColumnKind::I32 | ColumnKind::I64 | ColumnKind::I8 => {
            // `dir` is ±1 by contract; 1 fits every width, signed or not.
            let vals: Vec<i64> = if name == "dir" {
                vec![1; N]
            } else {
                idx.clone()
            };
            let a: ArrayRef = match v % 9 {
                0 => Arc::new(Int8Array::from_iter_values(vals.iter().map(|&i| i as i8))),
                1 => Arc::new(Int16Array::from_iter_values(vals.iter().map(|&i| i as i16))),
                2 => Arc::new(Int32Array::from_iter_values(vals.iter().map(|&i| i as i32))),
                3 => Arc::new(Int64Array::from(vals.clone())),
                4 => Arc::new(UInt8Array::from_iter_values(vals.iter().map(|&i| i as u8))),
                5 => Arc::new(UInt16Array::from_iter_values(
                    vals.iter().map(|&i| i as u16),
                )),
                6 => Arc::new(UInt32Array::from_iter_values(
                    vals.iter().map(|&i| i as u32),
                )),
                7 => Arc::new(UInt64Array::from_iter_values(
                    vals.iter().map(|&i| i as u64),
                )),
                _ => Arc::new(Float64Array::from_iter_values(
                    vals.iter().map(|&i| i as f64),
                )),
            };
            (a, Want::I(vals))
        }
        ColumnKind::Utf8 => {
            let vals: Vec<String> = (0..N).map(|i| label(name, i)).collect();
            let a: ArrayRef = match v % 4 {
                0 => Arc::new(StringArray::from_iter_values(&vals)),
                1 => Arc::new(LargeStringArray::from_iter_values(&vals)),
                2 => Arc::new(StringViewArray::from_iter_values(&vals)),
                _ => Arc::new(
                    vals.iter()
                        .map(|s| s.as_str())
                        .collect::<DictionaryArray<Int32Type>>(),
                ),
            };
            (a, Want::S(vals))
        }
    }
}

/// A batch of every column of `schema` (required and optional), variant `v`.
fn table_batch(schema: &TableSchema, v: usize) -> (RecordBatch, Vec<(&'static str, Want)>) {
    let mut fields = Vec::new();
    let mut cols = Vec::new();
    let mut want = Vec::new();
    for (k, spec) in schema.columns.iter().enumerate() {
        let (a, w) = column(spec.name, spec.kind, v + k);
        fields.push(Field::new(spec.name, a.data_type().clone(), false));
        cols.push(a);
        want.push((spec.name, w));
    }
    let b = RecordBatch::try_new(Arc::new(Schema::new(fields)), cols).unwrap();
    (b, want)
}

fn write(path: &Path, b: &RecordBatch, codec: Compression, v2: bool, dict: bool) {
    let props = WriterProperties::builder()
        .set_compression(codec)
        .set_writer_version(if v2 {
            WriterVersion::PARQUET_2_0
        } else {
            WriterVersion::PARQUET_1_0
        })
        .set_dictionary_enabled(dict)
        // Several row groups and pages, so streaming crosses boundaries.
        .set_max_row_group_row_count(Some(N / 3))
        .set_data_page_row_count_limit(7)
        .build();
    let f = std::fs::File::create(path).unwrap();
    let mut w = ArrowWriter::try_new(f, b.schema(), Some(props)).unwrap();
    w.write(b).unwrap();
    w.close().unwrap();
}

/// What a contract reader returned for one column.
fn got(t: &Table, name: &str, kind: ColumnKind) -> Want {
    match kind {
        ColumnKind::F64 => Want::F(t.f64(name).unwrap().to_vec()),
        ColumnKind::F32 => Want::F(match t.f32(name) {
            Ok(v) => v.iter().map(|&x| x as f64).collect(),
            Err(_) => t.f64(name).unwrap().to_vec(),
        }),
        ColumnKind::I32 => Want::I(t.i32(name).unwrap().iter().map(|&x| x as i64).collect()),
        ColumnKind::I64 => Want::I(t.i64(name).unwrap().to_vec()),
        ColumnKind::I8 => Want::I(t.i8(name).unwrap().iter().map(|&x| x as i64).collect()),
        ColumnKind::Utf8 => Want::S(t.str(name).unwrap().iter().map(|s| s.to_string()).collect()),
    }
}

#[test]
fn every_codec_page_version_and_encoding_reads_through_every_contract_reader() {
    let d = tempfile::tempdir().unwrap();
    let mut files = 0;
    for (c, codec) in codecs().into_iter().enumerate() {
        for v2 in [false, true] {
            for dict in [true, false] {
                let variant = c * 4 + v2 as usize * 2 + dict as usize;
                let tag = format!("{codec:?} v2={v2} dict={dict}");
                for schema in crate::common::tables().iter() {
                    let (b, want) = table_batch(schema, variant);
                    let p = d.path().join(format!("{}_{variant}.parquet", schema.name));
                    write(&p, &b, codec, v2, dict);
                    // The writer wrote what this test claims to cover.
                    let meta = parquet::file::reader::SerializedFileReader::new(
                        std::fs::File::open(&p).unwrap(),
                    )
                    .map(|r| {
                        use parquet::file::reader::FileReader;
                        r.metadata().row_group(0).column(0).compression()
                    })
                    .unwrap();
                    assert_eq!(
                        std::mem::discriminant(&meta),
                        std::mem::discriminant(&codec),
                        "{tag}"
                    );
                    if schema.name == "ae" {
                        let mut t_s = Vec::new();
                        let mut ae_v = Vec::new();
                        for chunk in AeStream::open_with_batch(&p, 9).unwrap() {
                            let chunk = chunk.unwrap_or_else(|e| panic!("{tag}: {e}"));
                            t_s.extend_from_slice(&chunk.t_s);
                            ae_v.extend(chunk.ae_v.iter().map(|&x| x as f64));
                        }
                        assert_eq!(Want::F(t_s), want[0].1, "{tag} ae t_s");
                        assert_eq!(Want::F(ae_v), want[1].1, "{tag} ae_v");
                    }
                    let t = Table::read(&p, schema).unwrap_or_else(|e| panic!("{tag}: {e}"));
                    for (spec, (name, w)) in schema.columns.iter().zip(&want) {
                        assert_eq!(
                            &got(&t, name, spec.kind),
                            w,
                            "{tag}: {}.{name}",
                            schema.name
                        );
                    }
                    // Artifacts and ad hoc tables go through the same opener.
                    assert_eq!(read_parquet(&p).unwrap().num_rows(), N, "{tag}");
                    files += 1;
                }
                // observations.parquet: run/observable as any text type,
                // sim/real as any number type.
                let mut fields = Vec::new();
                let mut cols = Vec::new();
                for (k, (name, kind)) in [
                    ("run", ColumnKind::Utf8),
                    ("observable", ColumnKind::Utf8),
                    ("sim", ColumnKind::F64),
                    ("real", ColumnKind::F64),
                    ("x_mm", ColumnKind::F64),
                ]
                .into_iter()
                .enumerate()
                {
                    let (a, _) = column(name, kind, variant + k);
                    fields.push(Field::new(name, a.data_type().clone(), false));
                    cols.push(a);
                }
                let b = RecordBatch::try_new(Arc::new(Schema::new(fields)), cols).unwrap();
                let p = d.path().join(format!("observations_{variant}.parquet"));
                write(&p, &b, codec, v2, dict);
                let o = read_observations(&p).unwrap_or_else(|e| panic!("{tag}: {e:#}"));
                assert_eq!(o.num_rows(), N);
                let sim = sparkout_pipeline::contracts::batch_f64(&o, "sim").unwrap();
                assert_eq!(sim, (0..N).map(|i| i as f64).collect::<Vec<_>>().as_slice());
                files += 1;
            }
        }
    }
    assert_eq!(
        files,
        7 * 2 * 2 * (crate::common::tables().iter().count() + 1)
    );
}

/// The contract table a committed fixture holds, by its file name.
fn schema_of(stem: &str) -> &'static TableSchema {
    let name = if stem.starts_with("motion") {
        "motion"
    } else {
        stem.split('_').next().unwrap()
    };
    crate::common::tables().get(name).unwrap()
}

fn normalised(t: &Table, schema: &TableSchema) -> Vec<(String, Want)> {
    schema
        .columns
        .iter()
        .filter(|c| t.has(c.name))
        .map(|c| (c.name.to_string(), got(t, c.name, c.kind)))
        .collect()
}

#[test]
fn files_written_by_pyarrow_pandas_polars_and_duckdb_read_identically() {
    let root = fixtures().join("writers");
    type Columns = Vec<(String, Want)>;
    let mut by_table: std::collections::BTreeMap<String, Vec<(PathBuf, Columns)>> =
        Default::default();
    let mut n = 0;
    for tool in ["pyarrow", "pandas", "polars", "duckdb"] {
        let mut paths: Vec<PathBuf> = std::fs::read_dir(root.join(tool))
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "parquet"))
            .collect();
        paths.sort();
        assert!(paths.len() >= 5, "{tool}: {paths:?}");
        for p in paths {
            let stem = p.file_stem().unwrap().to_str().unwrap().to_string();
            let schema = schema_of(&stem);
            let t = Table::read(&p, schema).unwrap_or_else(|e| panic!("{e}"));
            if schema.name == "ae" {
                let rows: usize = AeStream::open(&p)
                    .unwrap()
                    .map(|c| c.unwrap().t_s.len())
                    .sum();
                assert_eq!(rows, t.len(), "{}", p.display());
            }
            // Same table, whatever tool, codec, encoding or type wrote it.
            let key = if stem.starts_with("motion_timestamps") {
                "motion_timestamps".to_string()
            } else {
                schema.name.to_string()
            };
            by_table
                .entry(key)
                .or_default()
                .push((p.clone(), normalised(&t, schema)));
            n += 1;
        }
    }
    assert!(n >= 25, "{n}");
    for (table, versions) in &by_table {
        let (p0, first) = &versions[0];
        for (p, v) in &versions[1..] {
            for (name, a) in first {
                let Some((_, b)) = v.iter().find(|(n, _)| n == name) else {
                    continue;
                };
                match (a, b) {
                    // DECIMAL(6,3) etc. hold the same decimals; compare to 1e-12.
                    (Want::F(a), Want::F(b)) => {
                        assert_eq!(a.len(), b.len());
                        for (x, y) in a.iter().zip(b) {
                            assert!(
                                (x - y).abs() <= 1e-12 * x.abs().max(1.0),
                                "{table}.{name}: {} vs {}",
                                p0.display(),
                                p.display()
                            );
                        }
                    }
                    _ => assert_eq!(a, b, "{table}.{name}: {} vs {}", p0.display(), p.display()),
                }
            }
        }
    }
    // Wall-clock timestamps became seconds from the first one.
    let m = &by_table["motion_timestamps"][0].1;
    let Want::F(t) = &m[0].1 else { panic!() };
    assert_eq!(t[0], 0.0);
    assert!(
        t.windows(2).all(|w| (w[1] - w[0] - 0.25).abs() < 1e-9),
        "{t:?}"
    );
}

#[test]
fn timestamps_in_a_run_count_from_run_started() {
    use sparkout_pipeline::contracts::{RunSpec, TimeOrigin};
    let p = fixtures().join("writers/pandas/motion_timestamps.parquet");
    let dir = Path::new("/nonexistent-run");
    let at = |started: &str| {
        let spec = RunSpec::parse(
            dir,
            &format!("[run]\nid = \"r1\"\nmachine = \"m\"\nplugin = \"gantry\"\n{started}"),
        )
        .unwrap();
        Table::read_at(&p, schema_of("motion"), &spec.time_origin())
    };
    // The file's first stamp is 08:00:00Z; a run started 2 s earlier.
    let t = at("started = 2026-11-20T07:59:58Z").unwrap();
    assert_eq!(t.f64("t_s").unwrap()[0], 2.0);
    let t = at("started = 2026-11-20T09:59:58+02:00").unwrap();
    assert_eq!(t.f64("t_s").unwrap()[0], 2.0);
    // Without `started` the error says what to add.
    let e = at("").unwrap_err();
    assert_eq!(e.column.as_deref(), Some("t_s"));
    assert!(e.message.contains("started"), "{e}");
    assert_eq!(
        Table::read_at(&p, schema_of("motion"), &TimeOrigin::Missing)
            .unwrap_err()
            .file,
        p
    );
}

#[test]
fn values_that_do_not_fit_are_errors_naming_the_row() {
    let d = tempfile::tempdir().unwrap();
    let (b, _) = table_batch(schema_of("probe"), 0);
    // point as int64 with a value beyond int32 in row 5.
    let mut cols = b.columns().to_vec();
    let i = b.schema().index_of("point").unwrap();
    let mut big: Vec<i64> = (0..N as i64).collect();
    big[5] = 1 << 40;
    cols[i] = Arc::new(Int64Array::from(big));
    let mut fields: Vec<Field> = b
        .schema()
        .fields()
        .iter()
        .map(|f| f.as_ref().clone())
        .collect();
    fields[i] = Field::new("point", arrow::datatypes::DataType::Int64, false);
    let b = RecordBatch::try_new(Arc::new(Schema::new(fields)), cols).unwrap();
    let p = d.path().join("probe.parquet");
    write(&p, &b, Compression::SNAPPY, false, true);
    let e = Table::read(&p, schema_of("probe")).unwrap_err();
    assert_eq!(
        (e.column.as_deref(), e.row),
        (Some("point"), Some(5)),
        "{e}"
    );
    assert!(e.message.contains("does not fit"), "{e}");
}

// ---- damaged files: each error names the file and says what is wrong ----

fn good_file(dir: &Path, codec: Compression) -> PathBuf {
    let (b, _) = table_batch(schema_of("guideway"), 3);
    let p = dir.join(format!("guideway_{}.parquet", format!("{codec:?}").len()));
    write(&p, &b, codec, false, false);
    p
}

fn read_err(p: &Path) -> InputError {
    let e = Table::read(p, schema_of("guideway")).unwrap_err();
    assert_eq!(e.file, p, "{e}");
    // The AE reader and the artifact reader say the same.
    let a = read_parquet(p).unwrap_err();
    assert!(a.to_string().contains(&p.display().to_string()), "{a}");
    e
}

#[test]
fn truncated_file_is_called_truncated() {
    let d = tempfile::tempdir().unwrap();
    let p = good_file(d.path(), Compression::SNAPPY);
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() * 3 / 5]).unwrap();
    let e = read_err(&p);
    assert!(e.message.starts_with("truncated Parquet file"), "{e}");
    // Too short to hold even the footer.
    std::fs::write(&p, &bytes[..6]).unwrap();
    assert!(read_err(&p).message.starts_with("truncated Parquet file"));
    // Not Parquet at all (a CSV under a .parquet name).
    std::fs::write(&p, "t_s,ae_v\n0,1\n").unwrap();
    assert!(read_err(&p).message.starts_with("not a Parquet file"));
}

#[test]
fn corrupt_page_is_called_a_corrupt_page() {
    let d = tempfile::tempdir().unwrap();
    let p = good_file(d.path(), Compression::SNAPPY);
    let mut bytes = std::fs::read(&p).unwrap();
    // Overwrite the first page header of the third column chunk.
    let r =
        parquet::file::reader::SerializedFileReader::new(std::fs::File::open(&p).unwrap()).unwrap();
    let off = {
        use parquet::file::reader::FileReader;
        let c = r.metadata().row_group(0).column(2);
        c.dictionary_page_offset().unwrap_or(c.data_page_offset()) as usize
    };
    for b in &mut bytes[off..off + 12] {
        *b = 0xff;
    }
    std::fs::write(&p, &bytes).unwrap();
    let e = read_err(&p);
    assert!(
        e.message.starts_with("corrupt data page in row group 0"),
        "{e}"
    );
    assert_eq!(e.row, Some(0));
}

#[test]
fn unsupported_codec_is_called_an_unsupported_codec() {
    // No writer here can write LZO; write brotli and patch the footer's
    // codec id (thrift compact: field 4, i32, header 0x15; brotli = 4 →
    // zigzag 8, LZO = 3 → zigzag 6). The candidate that makes the footer
    // say LZO is the codec field.
    use parquet::file::reader::FileReader;
    let d = tempfile::tempdir().unwrap();
    let p = good_file(d.path(), Compression::BROTLI(BrotliLevel::default()));
    let bytes = std::fs::read(&p).unwrap();
    let footer_len =
        u32::from_le_bytes(bytes[bytes.len() - 8..bytes.len() - 4].try_into().unwrap()) as usize;
    let start = bytes.len() - 8 - footer_len;
    let lzo_at = |i: usize| {
        let mut b = bytes.clone();
        b[i + 1] = 0x06;
        b
    };
    let says_lzo = |b: &[u8]| {
        std::fs::write(&p, b).unwrap();
        parquet::file::reader::SerializedFileReader::new(std::fs::File::open(&p).unwrap())
            .map(|r| r.metadata().row_group(0).column(0).compression() == Compression::LZO)
            .unwrap_or(false)
    };
    let at = (start..bytes.len() - 9)
        .filter(|&i| bytes[i] == 0x15 && bytes[i + 1] == 0x08)
        .find(|&i| says_lzo(&lzo_at(i)))
        .expect("the codec field of column 0");
    std::fs::write(&p, lzo_at(at)).unwrap();
    let r = parquet::file::reader::SerializedFileReader::new(std::fs::File::open(&p).unwrap())
        .expect("footer still decodes");
    assert_eq!(
        r.metadata().row_group(0).column(0).compression(),
        Compression::LZO
    );
    let e = read_err(&p);
    assert!(
        e.message.starts_with("unsupported compression codec LZO"),
        "{e}"
    );
    assert!(e.message.contains("the file is intact"), "{e}");
}

/// Found by `cargo fuzz run observations`: a corrupt page
/// on which the parquet crate's decoder panics (division by zero in its
/// plain byte-array dictionary decoder). It must be an error naming the file
/// and the row group, with exit code 1 like any bad input — not a crash.
#[test]
fn a_page_that_panics_the_decoder_is_a_corrupt_page_error() {
    for name in [
        "observations_decoder_div_by_zero.parquet",
        "observations_bitutil_shift_overflow.parquet",
    ] {
        decoder_panic_is_an_error(name);
    }
}

fn decoder_panic_is_an_error(name: &str) {
    let f = fixtures().join("fuzz_found").join(name);
    let d = tempfile::tempdir().unwrap();
    let o = super::common::sparkout(&[
        "diagnose",
        f.to_str().unwrap(),
        "--out",
        d.path().join("o").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_ne!(o.status.code(), Some(101), "crashed: {err}");
    assert!(!o.status.success());
    assert!(
        err.contains(name)
            && err.contains("corrupt data page in row group 0")
            && err.contains("the Parquet decoder failed"),
        "{err}"
    );
    // The decoder's panic is the file's error, not a scary backtrace.
    assert!(!err.contains("panicked"), "{err}");
    assert!(!d.path().join("o").join("diagnosis.json").exists());
}

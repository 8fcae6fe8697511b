//! End-to-end AE ingest: ae.parquet on disk → decode (row
//! groups in parallel, `AeStream`) → RMS envelope → contact events, through
//! the robot plugin's `detect_file`, exactly the path of `sparkout stage
//! ingest`. 50 M float32 samples at 1 MHz in 48 row groups, once zstd and once
//! snappy (pandas' default). Reference on the same files:
//! benches/reference/ae_ingest.py (numpy + pyarrow streaming by row group).
//!
//! The files are written once to `target/bench-data/` (≈ 600 MB each); set
//! `SPARKOUT_AE_BENCH_SAMPLES` to bench a smaller or larger log.

use criterion::{criterion_group, Criterion, Throughput};
use sparkout_pipeline::contracts::{AeKind, TimeOrigin};
use sparkout_plugins::robot::ingest::{detect_file, IngestConfig};
use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::sync::Arc;

mod common;

const FS: f64 = 1e6;
const ROW_GROUPS: usize = 48;

fn samples() -> usize {
    std::env::var("SPARKOUT_AE_BENCH_SAMPLES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(50_000_000)
}

/// The AE log: the ae_kernel bench's signal (5 mV noise, a contact burst every
/// 50 ms), so both benches exercise the detector's in-contact path alike.
fn write_log(path: &Path, n: usize, rows_per_group: usize, codec: parquet::basic::Compression) {
    use arrow::array::{Float32Array, Float64Array};
    use arrow::datatypes::{DataType, Field, Schema};
    use arrow::record_batch::RecordBatch;
    use parquet::arrow::ArrowWriter;
    use parquet::file::properties::WriterProperties;

    let schema = Arc::new(Schema::new(vec![
        Field::new("t_s", DataType::Float64, false),
        Field::new("ae_v", DataType::Float32, false),
    ]));
    let props = WriterProperties::builder()
        .set_compression(codec)
        .set_max_row_group_row_count(Some(rows_per_group))
        .set_dictionary_enabled(false)
        .build();
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    let tmp = path.with_extension("tmp");
    let mut w = ArrowWriter::try_new(
        std::fs::File::create(&tmp).unwrap(),
        schema.clone(),
        Some(props),
    )
    .unwrap();
    let mut s: u64 = 0x2545_F491_4F6C_DD1D;
    let mut uni = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let period = 50_000usize;
    let batch = 1 << 20;
    let mut i0 = 0;
    while i0 < n {
        let m = batch.min(n - i0);
        let t: Vec<f64> = (i0..i0 + m).map(|i| i as f64 / FS).collect();
        let v: Vec<f32> = (i0..i0 + m)
            .map(|i| {
                let g = (uni() + uni() + uni() + uni() - 2.0) * 3f64.sqrt();
                let mut x = 0.005 * g;
                let k = i % period;
                if i >= period && k < 20_000 {
                    let dt = k as f64 / FS;
                    x +=
                        0.15 * (-dt / 2e-3).exp() * (2.0 * std::f64::consts::PI * 250e3 * dt).sin();
                }
                x as f32
            })
            .collect();
        let rb = RecordBatch::try_new(
            schema.clone(),
            vec![
                Arc::new(Float64Array::from(t)),
                Arc::new(Float32Array::from(v)),
            ],
        )
        .unwrap();
        w.write(&rb).unwrap();
        i0 += m;
    }
    w.close().unwrap();
    std::fs::rename(&tmp, path).unwrap();
}

/// Rows per row group of the scaling logs (pyarrow's default group size).
const SCALING_ROWS_PER_GROUP: usize = 1 << 20;

fn log_path(codec_name: &str, n: usize) -> PathBuf {
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("target"));
    target
        .join("bench-data")
        .join(format!("ae_{n}_{codec_name}.parquet"))
}

fn bench(c: &mut Criterion) {
    common::register_references(c, "ae_ingest");
    let n = samples();
    let cfg = ingest_config();
    let mut g = c.benchmark_group("ae_ingest");
    g.throughput(Throughput::Elements(n as u64));
    g.sample_size(10);
    for (name, codec) in [
        (
            "zstd",
            parquet::basic::Compression::ZSTD(Default::default()),
        ),
        ("snappy", parquet::basic::Compression::SNAPPY),
    ] {
        let path = log_path(name, n);
        if !path.exists() {
            eprintln!(
                "writing {} ({n} samples, {ROW_GROUPS} row groups)",
                path.display()
            );
            write_log(&path, n, n.div_ceil(ROW_GROUPS), codec);
        }
        g.bench_function(format!("parquet_{name}_to_contacts"), |b| {
            b.iter(|| {
                let r = detect_file(
                    black_box(&path),
                    FS,
                    Some(AeKind::Raw),
                    &cfg,
                    0.0,
                    &TimeOrigin::TableStart,
                )
                .unwrap();
                assert!(
                    r.events.len() >= n / 50_000 - 2,
                    "{} contacts",
                    r.events.len()
                );
                black_box(r.events.len())
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);

fn main() {
    common::run_or_scale(benches, scaling);
}

/// The detector's defaults (`[robot.ingest]` of nightly.toml).
fn ingest_config() -> IngestConfig {
    IngestConfig::default()
}

/// Peak resident set of this process so far (VmHWM), MiB.
fn peak_rss_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kib| kib / 1024.0)
}

/// `SPARKOUT_BENCH_SCALING=1 cargo bench --bench ae_ingest`:
/// zstd logs of `SPARKOUT_AE_SCALING_SAMPLES` (comma-separated; default
/// 10⁷ and 10⁸; 10⁹ writes ≈ 9 GB) in row groups of 2²⁰ rows (pyarrow's
/// default; a fixed group size, so memory is bounded by the group, not
/// the log), written once to target/bench-data/, ingested from disk best
/// of 3 (1 at ≥ 10⁹); prints samples/s, the cost exponent of each step and the process's peak RSS
/// (monotone: sizes run smallest first, so a flat figure means bounded).
fn scaling() {
    let sizes = common::sizes_from_env("SPARKOUT_AE_SCALING_SAMPLES", "10000000,100000000");
    let cfg = ingest_config();
    let mut prev: Option<(f64, f64)> = None;
    for n in sizes {
        let path = log_path("zstd_rg1Mi", n);
        if !path.exists() {
            eprintln!("writing {} ({n} samples)", path.display());
            write_log(
                &path,
                n,
                SCALING_ROWS_PER_GROUP,
                parquet::basic::Compression::ZSTD(Default::default()),
            );
        }
        let reps = if n >= 1_000_000_000 { 1 } else { 3 };
        let secs = common::best_of(reps, || {
            let r = detect_file(
                &path,
                FS,
                Some(AeKind::Raw),
                &cfg,
                0.0,
                &TimeOrigin::TableStart,
            )
            .unwrap();
            black_box(r.events.len());
        });
        let exponent = common::exponent_text(prev, n as f64, secs);
        println!(
            "ae_ingest scaling {n:>11} samples {secs:>8.3} s {:>7.1} M samples/s  peak RSS {:.0} MiB{exponent}",
            n as f64 / secs / 1e6,
            peak_rss_mib()
        );
        prev = Some((n as f64, secs));
    }
}

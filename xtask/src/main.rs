//! `cargo xtask bench-gate` — the criterion performance gate.
//!
//! Every gated bench is compared as a *ratio* to a reference kernel measured
//! in the same bench process (benches/common/mod.rs): the machine's absolute
//! speed drifts by tens of percent between minutes on a shared 2-core box,
//! the ratio of two kernels measured back to back far less. The committed
//! baseline (benches/gate.toml) holds, per bench, the median ratio over
//! several calibration runs and a threshold justified by their spread.
//!
//!   cargo xtask bench-gate                  run the gated benches, compare, exit 1 on a regression
//!   cargo xtask bench-gate --no-run         compare the results already in target/criterion
//!   cargo xtask bench-gate --calibrate --runs 5
//!                                           run every gated bench 5 times, write ratio + threshold
//!   cargo xtask cycles                      import cycles between the top-level modules of each crate

mod cycles;

use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The smallest threshold the gate uses whatever the calibration spread: a
/// 2-core machine shared with builds never repeats better than this.
const MIN_THRESHOLD: f64 = 0.10;
/// Threshold = this many relative standard deviations of the calibration ratios.
const SIGMAS: f64 = 4.0;

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct GateEntry {
    /// criterion full id of the gated bench, e.g. `ae_kernel/envelope_events_1MHz_chunked`.
    bench: String,
    /// criterion full id of the reference measured in the same process.
    reference: String,
    /// `cargo bench --bench <target>` that runs both.
    target: String,
    /// Baseline median of bench_time / reference_time (0 = not calibrated).
    #[serde(default)]
    ratio: f64,
    /// Allowed relative increase of the ratio before the gate fails.
    #[serde(default)]
    threshold: f64,
    /// Relative standard deviation of the ratio over the calibration runs.
    #[serde(default)]
    calibration_rsd: f64,
    /// Number of calibration runs behind `ratio` and `threshold`.
    #[serde(default)]
    calibration_runs: usize,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct GateFile {
    gate: Vec<GateEntry>,
}

struct Options {
    gate_path: PathBuf,
    run: bool,
    calibrate: bool,
    runs: usize,
    only: Vec<String>,
}

fn main() {
    if let Err(e) = real_main() {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn real_main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.first().map(String::as_str) {
        Some("bench-gate") => bench_gate(parse_options(&args[1..])?),
        Some("cycles") => cycles::check(&workspace_root()),
        _ => {
            eprintln!(
                "usage: cargo xtask bench-gate [--no-run] [--calibrate --runs N] [--gate FILE] [--bench TARGET]...\n       cargo xtask cycles"
            );
            std::process::exit(1)
        }
    }
}

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("xtask lives in the workspace")
        .to_path_buf()
}

fn parse_options(args: &[String]) -> Result<Options> {
    let mut o = Options {
        gate_path: workspace_root().join("benches/gate.toml"),
        run: true,
        calibrate: false,
        runs: 5,
        only: vec![],
    };
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--no-run" => o.run = false,
            "--calibrate" => o.calibrate = true,
            "--runs" => {
                let v = it.next().context("--runs needs a number")?;
                o.runs = v.parse().with_context(|| format!("--runs {v}: not a whole number"))?;
                if o.runs < 2 {
                    bail!("--runs {}: calibration needs at least 2 runs to measure noise (5 recommended)", o.runs);
                }
            }
            "--gate" => o.gate_path = PathBuf::from(it.next().context("--gate needs a file")?),
            "--bench" => o.only.push(it.next().context("--bench needs a bench target name")?.clone()),
            other => bail!("unknown option {other:?} (try: --no-run, --calibrate, --runs N, --gate FILE, --bench TARGET)"),
        }
    }
    if o.calibrate && !o.run {
        bail!("--calibrate runs the benches; it cannot be combined with --no-run");
    }
    Ok(o)
}

fn read_gate(path: &Path) -> Result<GateFile> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let g: GateFile = toml::from_str(&text)
        .with_context(|| format!("{}: not a valid gate file", path.display()))?;
    if g.gate.is_empty() {
        bail!("{}: no [[gate]] entries", path.display());
    }
    Ok(g)
}

fn bench_gate(o: Options) -> Result<()> {
    let mut gate = read_gate(&o.gate_path)?;
    let selected = |e: &GateEntry| o.only.is_empty() || o.only.contains(&e.target);
    let mut targets: Vec<String> = gate
        .gate
        .iter()
        .filter(|e| selected(e))
        .map(|e| e.target.clone())
        .collect();
    targets.sort();
    targets.dedup();
    if targets.is_empty() {
        bail!("no gated bench matches --bench {:?}", o.only);
    }
    let criterion_dir = target_dir().join("criterion");

    if o.calibrate {
        let mut ratios: BTreeMap<String, Vec<f64>> = BTreeMap::new();
        for run in 1..=o.runs {
            eprintln!("calibration run {run}/{}", o.runs);
            run_benches(&targets)?;
            let medians = read_criterion_medians(&criterion_dir)?;
            for e in gate.gate.iter().filter(|e| selected(e)) {
                ratios
                    .entry(e.bench.clone())
                    .or_default()
                    .push(ratio_of(e, &medians)?);
            }
        }
        for e in gate.gate.iter_mut().filter(|e| selected(e)) {
            let r = &ratios[&e.bench];
            let (median, rsd) = median_and_rsd(r);
            e.ratio = round_sig(median, 4);
            e.calibration_rsd = round_sig(rsd, 3);
            e.threshold = round_sig((SIGMAS * rsd).max(MIN_THRESHOLD), 2);
            e.calibration_runs = r.len();
            eprintln!(
                "{:<55} ratio {:.4} (rsd {:.1} % over {} runs) -> threshold +{:.0} %",
                e.bench,
                e.ratio,
                100.0 * rsd,
                r.len(),
                100.0 * e.threshold
            );
        }
        write_gate(&o.gate_path, &gate)?;
        eprintln!("wrote {}", o.gate_path.display());
        return Ok(());
    }

    let selected_entries: Vec<GateEntry> =
        gate.gate.iter().filter(|e| selected(e)).cloned().collect();
    // Refuse an uncalibrated baseline before spending minutes on benches.
    for e in &selected_entries {
        check_calibrated(e).map_err(|err| anyhow::anyhow!("{}: {err}", o.gate_path.display()))?;
    }
    if o.run {
        run_benches(&targets)?;
    }
    let medians = read_criterion_medians(&criterion_dir)?;
    let verdicts = compare(&selected_entries, &medians)
        .map_err(|e| anyhow::anyhow!("{}: {e}", o.gate_path.display()))?;
    println!(
        "{:<55} {:>10} {:>10} {:>8} {:>9}  verdict",
        "bench", "baseline", "now", "change", "allowed"
    );
    let mut failed = 0;
    for v in &verdicts {
        if v.regressed() {
            failed += 1;
        }
        println!(
            "{:<55} {:>10.4} {:>10.4} {:>+7.1}% {:>+8.0}%  {}",
            v.bench,
            v.baseline,
            v.now,
            100.0 * v.change,
            100.0 * v.allowed,
            v.word()
        );
    }
    if failed > 0 {
        bail!("{failed} bench(es) regressed beyond their threshold (ratios to the in-process reference kernel; see benches/gate.toml)");
    }
    println!("gate passed");
    Ok(())
}

/// One gated bench compared with its baseline.
#[derive(Debug)]
struct Verdict {
    bench: String,
    baseline: f64,
    now: f64,
    /// Relative change of the ratio: now / baseline − 1 (positive = slower).
    change: f64,
    allowed: f64,
}

impl Verdict {
    fn regressed(&self) -> bool {
        self.change > self.allowed
    }
    /// `improved` is shown when the ratio fell by more than the threshold:
    /// time to re-calibrate on purpose so the gate keeps the gain.
    fn word(&self) -> &'static str {
        if self.regressed() {
            "REGRESSED"
        } else if self.change < -self.allowed {
            "improved (re-calibrate to keep it)"
        } else {
            "ok"
        }
    }
}

/// An entry without a baseline (ratio/threshold 0) cannot gate anything.
fn check_calibrated(e: &GateEntry) -> Result<()> {
    if e.ratio <= 0.0 || e.threshold <= 0.0 {
        bail!(
            "{} is not calibrated: run `cargo xtask bench-gate --calibrate --runs 5`",
            e.bench
        );
    }
    Ok(())
}

/// The gate's decision, apart from running anything: every entry must be
/// calibrated and have both its bench and its reference in `medians` (a
/// missing result is an error naming the bench, never a silent pass).
fn compare(entries: &[GateEntry], medians: &BTreeMap<String, f64>) -> Result<Vec<Verdict>> {
    let mut out = Vec::new();
    for e in entries {
        check_calibrated(e)?;
        let now = ratio_of(e, medians)?;
        out.push(Verdict {
            bench: e.bench.clone(),
            baseline: e.ratio,
            now,
            change: now / e.ratio - 1.0,
            allowed: e.threshold,
        });
    }
    Ok(out)
}

fn target_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace_root().join("target"))
}

fn run_benches(targets: &[String]) -> Result<()> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    for t in targets {
        eprintln!("cargo bench --bench {t}");
        let mut cmd = Command::new(&cargo);
        // `cargo xtask` runs under `cargo run`, which sets CARGO_PKG_NAME=xtask
        // and friends; build scripts that watch those variables (ring's
        // rerun-if-env-changed) would then rebuild the release dependency
        // tree (≈ 25 min) on every gate run. Give `cargo bench` the
        // developer's environment instead.
        for (k, _) in std::env::vars_os() {
            let k = k.to_string_lossy();
            if k.starts_with("CARGO_PKG_")
                || k.starts_with("CARGO_MANIFEST_")
                || matches!(
                    k.as_ref(),
                    "CARGO_CRATE_NAME" | "CARGO_BIN_NAME" | "CARGO_PRIMARY_PACKAGE"
                )
            {
                cmd.env_remove(k.as_ref());
            }
        }
        let status = cmd
            .current_dir(workspace_root())
            .args(["bench", "--bench", t, "--", "--noplot"])
            .status()
            .with_context(|| format!("cannot start `cargo bench --bench {t}`"))?;
        if !status.success() {
            bail!("`cargo bench --bench {t}` failed ({status})");
        }
    }
    Ok(())
}

/// criterion writes `<dir>/<group>/<function>/new/{benchmark,estimates}.json`;
/// the full id inside benchmark.json is the stable name (directory names are
/// sanitised).
fn read_criterion_medians(dir: &Path) -> Result<BTreeMap<String, f64>> {
    #[derive(Deserialize)]
    struct Benchmark {
        full_id: String,
    }
    #[derive(Deserialize)]
    struct Estimate {
        point_estimate: f64,
    }
    #[derive(Deserialize)]
    struct Estimates {
        median: Estimate,
    }
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for entry in entries.flatten() {
            let p = entry.path();
            if p.is_dir() {
                if p.file_name().is_some_and(|n| n == "new") {
                    let b = p.join("benchmark.json");
                    let s = p.join("estimates.json");
                    if b.exists() && s.exists() {
                        let b: Benchmark = serde_json::from_str(&std::fs::read_to_string(&b)?)
                            .with_context(|| {
                                format!("{}: not criterion's benchmark.json", b.display())
                            })?;
                        let s: Estimates = serde_json::from_str(&std::fs::read_to_string(&s)?)
                            .with_context(|| {
                                format!("{}: not criterion's estimates.json", s.display())
                            })?;
                        out.insert(b.full_id, s.median.point_estimate);
                    }
                } else {
                    stack.push(p);
                }
            }
        }
    }
    Ok(out)
}

fn ratio_of(e: &GateEntry, medians: &BTreeMap<String, f64>) -> Result<f64> {
    let get = |id: &str| {
        medians.get(id).copied().with_context(|| {
            format!(
                "no criterion result for {id:?} under {}: run `cargo bench --bench {}`",
                target_dir().join("criterion").display(),
                e.target
            )
        })
    };
    Ok(get(&e.bench)? / get(&e.reference)?)
}

fn median_and_rsd(v: &[f64]) -> (f64, f64) {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    let median = if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    };
    let mean = s.iter().sum::<f64>() / n as f64;
    let var = s.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n as f64 - 1.0).max(1.0);
    (median, var.sqrt() / mean)
}

fn round_sig(x: f64, digits: i32) -> f64 {
    if x == 0.0 || !x.is_finite() {
        return x;
    }
    let scale = 10f64.powi(digits - 1 - x.abs().log10().floor() as i32);
    (x * scale).round() / scale
}

fn write_gate(path: &Path, gate: &GateFile) -> Result<()> {
    let header = "# The criterion performance gate's baseline. Written by\n\
                  # `cargo xtask bench-gate --calibrate --runs 5`; checked by `cargo xtask bench-gate`.\n\
                  # ratio = median over the calibration runs of bench time / reference time,\n\
                  # both measured in one bench process; threshold = max(10 %, 4 x rsd).\n\n";
    let body = toml::to_string(gate).context("cannot serialise the gate file")?;
    let tmp = path.with_extension("toml.tmp");
    std::fs::write(&tmp, format!("{header}{body}"))
        .with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, path)
        .with_context(|| format!("cannot rename {} to {}", tmp.display(), path.display()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_and_spread() {
        let (m, rsd) = median_and_rsd(&[1.0, 1.1, 0.9, 1.0, 1.0]);
        assert_eq!(m, 1.0);
        assert!((rsd - 0.0707).abs() < 1e-3, "{rsd}");
    }

    fn entry(bench: &str, ratio: f64) -> GateEntry {
        GateEntry {
            bench: bench.into(),
            reference: "g_reference/stream_sum_64MiB".into(),
            target: "g".into(),
            ratio,
            threshold: 0.1,
            calibration_rsd: 0.02,
            calibration_runs: 5,
        }
    }

    /// Writes what criterion writes for one bench:
    /// `<dir>/<sanitised id>/new/{benchmark,estimates}.json`.
    fn write_criterion(dir: &Path, full_id: &str, median_ns: f64) {
        let d = dir.join(full_id.replace(['/', ' '], "_")).join("new");
        std::fs::create_dir_all(&d).unwrap();
        let group = full_id.split('/').next().unwrap();
        std::fs::write(
            d.join("benchmark.json"),
            format!(
                r#"{{"group_id":"{group}","function_id":null,"value_str":null,"throughput":null,"full_id":"{full_id}","directory_name":"x","title":"{full_id}"}}"#
            ),
        )
        .unwrap();
        let est = |v: f64| {
            format!(
                r#"{{"confidence_interval":{{"confidence_level":0.95,"lower_bound":{},"upper_bound":{}}},"point_estimate":{v},"standard_error":1.0}}"#,
                v * 0.99,
                v * 1.01
            )
        };
        std::fs::write(
            d.join("estimates.json"),
            format!(
                r#"{{"mean":{},"median":{},"median_abs_dev":{},"slope":null,"std_dev":{}}}"#,
                est(median_ns * 1.02),
                est(median_ns),
                est(1.0),
                est(2.0)
            ),
        )
        .unwrap();
    }

    #[test]
    fn gate_on_synthetic_criterion_output() {
        let dir = std::env::temp_dir().join(format!("xtask-gate-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        // Reference 100 ms; baselines of ratio 2.0 for every bench.
        write_criterion(&dir, "g_reference/stream_sum_64MiB", 100e6);
        write_criterion(&dir, "g/regressed", 250e6); // +25 %
        write_criterion(&dir, "g/unchanged", 205e6); // +2.5 %
        write_criterion(&dir, "g/improved", 150e6); // -25 %
        let medians = read_criterion_medians(&dir).unwrap();
        assert_eq!(medians.len(), 4, "{medians:?}");
        let v = compare(
            &[
                entry("g/regressed", 2.0),
                entry("g/unchanged", 2.0),
                entry("g/improved", 2.0),
            ],
            &medians,
        )
        .unwrap();
        let words: Vec<&str> = v.iter().map(|v| v.word()).collect();
        assert_eq!(
            words,
            ["REGRESSED", "ok", "improved (re-calibrate to keep it)"]
        );
        assert!((v[0].change - 0.25).abs() < 1e-12);
        assert!(v[0].regressed() && !v[1].regressed() && !v[2].regressed());
        // A bench without a result fails the gate with its name.
        let err = compare(&[entry("g/missing", 2.0)], &medians).unwrap_err();
        assert!(err.to_string().contains("g/missing"), "{err}");
        // A missing reference too.
        std::fs::remove_dir_all(dir.join("g_reference_stream_sum_64MiB")).unwrap();
        let medians = read_criterion_medians(&dir).unwrap();
        let err = compare(&[entry("g/unchanged", 2.0)], &medians).unwrap_err();
        assert!(err.to_string().contains("stream_sum_64MiB"), "{err}");
        // An uncalibrated entry refuses with the command to calibrate.
        let err = compare(&[entry("g/unchanged", 0.0)], &medians).unwrap_err();
        assert!(err.to_string().contains("--calibrate"), "{err}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn committed_gate_file_parses() {
        let g = read_gate(&workspace_root().join("benches/gate.toml")).unwrap();
        for e in &g.gate {
            // Uncalibrated entries (0, 0) make `bench-gate` refuse with a
            // message; calibrated ones must respect the noise floor.
            let calibrated =
                e.ratio > 0.0 && e.threshold >= MIN_THRESHOLD && e.calibration_runs >= 2;
            let uncalibrated = e.ratio == 0.0 && e.threshold == 0.0;
            assert!(
                calibrated || uncalibrated,
                "{}: half-calibrated entry",
                e.bench
            );
            assert!(
                workspace_root()
                    .join(format!("benches/{}.rs", e.target))
                    .exists(),
                "{}: no bench file",
                e.target
            );
        }
    }
}

//! `sparkout run`: the nightly batch.

use std::path::{Path, PathBuf};

use sparkout_pipeline::engine::FleetOutcome;
use sparkout_pipeline::storage::{self, Location, Output};

use crate::cli::ConfigArgs;
use crate::progress::BatchProgress;
use crate::registry;

/// `--input` and `--out` as local directories: a bucket input staged into
/// the work directory (large Parquet files read in place by ranged GETs), a
/// bucket output written locally and published when the batch is done.
pub struct Places {
    input: PathBuf,
    /// The bucket URL a staged input came from.
    input_url: Option<String>,
    out: Output,
    /// `--work`: where bucket locations are staged.
    work: Option<PathBuf>,
}

impl Places {
    /// Both places; a bucket output is checked for write access first, so
    /// bad credentials are found before the batch computes. `select` picks
    /// the runs a staged input fetches (a shard's own).
    pub fn resolve(
        input: &Path,
        out: &Path,
        work: Option<&Path>,
        select: Option<storage::RunSelector>,
    ) -> anyhow::Result<Places> {
        storage::check_remote_apart(input, out)?;
        let mut out = Output::resolve(out, work)?;
        let local = storage::resolve_input_selected(input, work, "input", true, select)?;
        out.staged(&local, input);
        Ok(Places {
            input: local,
            input_url: storage::is_url(input).then(|| input.display().to_string()),
            out,
            work: work.map(Path::to_path_buf),
        })
    }
}

pub fn run(
    config: &ConfigArgs,
    places: &Places,
    jobs: Option<usize>,
    history: Option<(std::path::PathBuf, Option<String>, Vec<String>)>,
    (augment, snapshot): (Option<&Path>, Option<&Path>),
) -> anyhow::Result<u8> {
    if jobs == Some(0) {
        anyhow::bail!("--jobs must be at least 1");
    }
    let mut engine = registry::engine(config)?;
    if let Some(file) = snapshot {
        engine.set_snapshot(file)?;
    }
    let mut history_out = None;
    if let Some((dir, night, events)) = history {
        let (local, publish) = storage::resolve_history(&dir, places.work.as_deref())?;
        history_out = publish;
        engine.set_history(local, night, events)?;
    }
    if let Some(model) = augment {
        engine.set_augment(model)?;
    }
    let progress = BatchProgress::new();
    let outcome = engine.run_fleet(&places.input, &places.out.local, jobs, &progress)?;
    progress.finish();
    print_outcome(&outcome);
    places.out.publish()?;
    // The history after the night's outputs: a history that names a night
    // whose outputs were not published would mislead the next night's trend.
    if let Some(h) = history_out {
        h.publish()?;
    }
    Ok(outcome.exit_code() as u8)
}

/// `sparkout run --shard i/n`: this shard's runs, then shard.json. From a
/// bucket, only this shard's runs are downloaded (every run.toml is, to
/// partition the night the same way on every node).
pub fn run_shard(
    config: &ConfigArgs,
    (input, out, work): (&Path, &Path, Option<&Path>),
    jobs: Option<usize>,
    (shard, balance): (&str, &str),
    snapshot: Option<&Path>,
) -> anyhow::Result<u8> {
    use sparkout_pipeline::engine::shard::{Balance, ShardSpec};
    if jobs == Some(0) {
        anyhow::bail!("--jobs must be at least 1");
    }
    let balance = match balance {
        "hash" => Balance::Hash,
        "size" => Balance::Size,
        other => anyhow::bail!("--balance `{other}`: expected `hash` or `size`"),
    };
    let spec = ShardSpec::parse(shard, balance).map_err(anyhow::Error::msg)?;
    let mut engine = registry::engine(config)?;
    if let Some(file) = snapshot {
        engine.set_snapshot(file)?;
    }
    let select = |root: &Path| engine.shard_runs(root, &spec);
    let places = Places::resolve(input, out, work, Some(&select))?;
    if let Some(url) = &places.input_url {
        engine.set_input_label(url.clone());
    }
    let progress = BatchProgress::new();
    let outcome = engine.run_shard(&places.input, &places.out.local, jobs, &spec, &progress)?;
    progress.finish();
    print_outcome(&outcome);
    println!(
        "shard {}/{}: {}; join every shard with `sparkout aggregate --shards DIR... --out DIR`",
        spec.index,
        spec.count,
        places
            .out
            .local
            .join(sparkout_pipeline::engine::shard::SHARD_FILE)
            .display()
    );
    places.out.publish()?;
    Ok(outcome.exit_code() as u8)
}

/// `sparkout snapshot --input DIR|URL --out FILE`: the night's run set. A
/// bucket input is listed by staging its run.toml files only.
pub fn snapshot(input: &Path, out: &Path, work: Option<&Path>) -> anyhow::Result<u8> {
    use sparkout_pipeline::engine::snapshot::NightSnapshot;
    if storage::is_url(out) {
        anyhow::bail!(
            "--out {}: the snapshot is a local file (copy it next to the shards' inputs with `sparkout sync`)",
            out.display()
        );
    }
    let none = |_: &Path| Ok(Vec::new());
    let select: Option<storage::RunSelector> = storage::is_url(input).then_some(&none);
    let root = storage::resolve_input_selected(input, work, "input", true, select)?;
    let found = sparkout_pipeline::contracts::discover(&root)
        .map_err(|e| anyhow::anyhow!("cannot list runs under {}: {e}", root.display()))?;
    let snap = NightSnapshot::of(&input.display().to_string(), &root, &found);
    snap.write(out)?;
    println!(
        "snapshot: {} run(s) and {} listed director(ies) under {} → {}",
        snap.runs.len(),
        snap.listed.len(),
        input.display(),
        out.display()
    );
    Ok(0)
}

/// `sparkout aggregate --shards DIR... --out DIR`.
pub fn aggregate(
    config: &ConfigArgs,
    shards: &[PathBuf],
    out: &Path,
    work: Option<&Path>,
) -> anyhow::Result<u8> {
    let engine = registry::engine(config)?;
    let mut out = Output::resolve(out, work)?;
    // A shard's artifacts are copied into the fleet output, so a remote
    // shard is downloaded whole (no ranged-read stubs).
    let shards = shards
        .iter()
        .map(|s| {
            let local = storage::resolve_input(s, work, "shard", false)?;
            out.staged(&local, s);
            Ok(local)
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let progress = BatchProgress::new();
    // A refused set of shards leaves no empty output folder behind (only
    // an empty one is removed: anything written there stays).
    let created = !out.local.exists();
    let aggregated = engine.aggregate(&shards, &out.local, &progress);
    progress.finish();
    let outcome = match aggregated {
        Ok(o) => o,
        Err(e) => {
            if created {
                let _ = std::fs::remove_dir(&out.local);
            }
            return Err(e.into());
        }
    };
    print_outcome(&outcome);
    out.publish()?;
    Ok(outcome.exit_code() as u8)
}

/// `sparkout sync FROM TO`: one side local, the other a bucket URL.
pub fn sync(from: &Path, to: &Path) -> anyhow::Result<u8> {
    match (Location::parse(from)?, Location::parse(to)?) {
        (Location::Local(dir), Location::Remote(remote)) => {
            if !dir.is_dir() {
                anyhow::bail!("{}: no such directory", dir.display());
            }
            storage::check_writable(&remote)?;
            Output {
                stands_for: Vec::new(),
                local: dir,
                remote: Some(remote),
            }
            .publish()?;
        }
        (Location::Remote(remote), Location::Local(dir)) => {
            let r = storage::stage_down(&remote, &dir, None)?;
            eprintln!(
                "downloaded {} to {}: {} files ({:.1} MB), {} unchanged, {} removed",
                remote.url,
                dir.display(),
                r.downloaded,
                r.downloaded_bytes as f64 / 1e6,
                r.unchanged,
                r.removed
            );
        }
        _ => anyhow::bail!(
            "`sparkout sync` copies between a local directory and a bucket URL (s3://, gs://, az://); use cp for two local paths"
        ),
    }
    Ok(0)
}

/// The end-of-batch summary an engineer reads first.
pub fn print_outcome(o: &FleetOutcome) {
    use sparkout_pipeline::units::format::{param_unit, show_group, show_param};
    let computed = o.stages_computed();
    let cached = o.stages_cached();
    println!(
        "{} runs ok, {} rejected; stages: {computed} computed, {cached} cached{}",
        o.runs.len(),
        o.failures.len(),
        if computed == 0 {
            " (everything cached)"
        } else {
            ""
        }
    );
    for f in &o.failures {
        println!("  rejected {}: {}", f.run_dir, f.error);
    }
    if let Some(d) = &o.diagnosis {
        println!("diagnosis: {}", d.display());
        if let Some(diag) = read_diagnosis(d) {
            let named = if diag.selected.is_empty() {
                "no effect selected".to_string()
            } else {
                diag.selected.join(", ")
            };
            if diag.observables.len() > 1 {
                // Pooled RMS over observables of different scales says
                // nothing; the per-observable lines below do.
                println!("  effects named (most signal explained first): {named}");
            } else {
                let unit = diag
                    .per_observable
                    .first()
                    .map_or("mm", |o| o.unit.as_str());
                let figures = [
                    diag.gap.rms_mm,
                    diag.gap.noise_floor_mm,
                    diag.unexplained.rms_mm,
                ];
                let [b, n, a] =
                    <[String; 3]>::try_from(show_group(&figures, unit)).expect("three figures");
                println!("  gap RMS {b} (noise floor {n}) → held-out {a} after: {named}");
            }
            // Per observable: each has its own noise floor and effects,
            // and a small observable's shrink is invisible in the total.
            for o in sparkout_pipeline::report::observable_summaries(&diag) {
                let [b, n, a] = <[String; 3]>::try_from(show_group(
                    &[o.rms_mm, o.noise_floor_mm, o.after_mm],
                    &o.unit,
                ))
                .expect("three figures");
                println!(
                    "  {}: gap RMS {b} (noise {n}) → held-out {a}, {:.0} % shrink; {}",
                    o.observable,
                    100.0 * o.shrink,
                    o.explained_by
                );
            }
            // Effects only one machine has (diagnosis.json machine_effects).
            for e in &diag.machine_effects {
                let cov = e.effect.split_once(':').map(|k| k.1);
                let gap_unit = diag
                    .per_observable
                    .iter()
                    .find(|o| o.observable == e.observable)
                    .map_or("mm", |o| o.unit.as_str());
                let params: Vec<String> = e
                    .params
                    .iter()
                    .map(|(k, v)| show_param(k, *v, None, &param_unit(k, cov, gap_unit)))
                    .collect();
                println!(
                    "  {} on machine {} only: {} ({}), held-out shrink {:.0} % over its {} runs",
                    e.observable,
                    e.machine,
                    e.effect,
                    params.join(", "),
                    100.0 * e.shrink.unwrap_or(f64::NAN),
                    e.runs
                );
            }
        }
    }
    if let Some(r) = &o.report {
        println!("fleet report: {}", r.display());
    }
    // A shard writes shard.json instead (its caller says so).
    if o.report.is_some() {
        println!("failures: {}", o.out_dir.join("failures.json").display());
        println!("manifest: {}", o.out_dir.join("manifest.json").display());
    }
}

/// diagnosis.json as its serde type; a file that does not read is said
/// so, not skipped silently.
fn read_diagnosis(path: &Path) -> Option<sparkout_pipeline::diagnose::Diagnosis> {
    let read = || -> anyhow::Result<_> { Ok(serde_json::from_slice(&std::fs::read(path)?)?) };
    match read() {
        Ok(r) => Some(r),
        Err(e) => {
            eprintln!("  (cannot summarise {}: {e})", path.display());
            None
        }
    }
}

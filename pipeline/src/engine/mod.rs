//! The DAG engine: runs every plugin stage of every run (rayon across runs,
//! per-run isolation, content-hash cache), then the fleet diagnosis and the
//! reports, then failures.json and — last — manifest.json.

pub mod cache;
mod checks;
pub mod config;
pub mod dag;
mod fleet;
pub mod lock;
mod run;
pub mod shard;
pub mod snapshot;
pub use crate::outcome::*;
pub use checks::check_finite;
use checks::check_plugin;
use fleet::json_bytes;
pub use fleet::{models_text, parquet_bytes, with_machine_column};

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::{bail, err, Context};
use arrow::record_batch::RecordBatch;
use serde::Serialize;

use crate::config_check::Checked;
use crate::contracts::{
    config_keys, discover, names, remove_orphaned_temps, write_atomic, write_json_atomic, AeStream,
    MachineResolver, RunSpec, Table, TableRegistry,
};
use crate::diagnose::{self, DiagnoseConfig, Effect};
use crate::error::{InputError, Result};
use crate::files::OBSERVATIONS_FILE;
use crate::report;
use crate::traits::{ArtifactStore, MachinePlugin, Run, Stage, StageContext, StageOutput};
use cache::{hash_bytes, hash_file, hash_input, read_run_cache, record_valid, KeyBuilder};
pub use config::{CheckedConfig, PipelineConfig, PipelineSection, ReportSection};

/// Version of the fleet `diagnose` step (bump when its output changes).
pub const DIAGNOSE_STAGE_VERSION: u32 = 10;

/// Run directories with their run.toml, read and checked once.
type RunSpecs = BTreeMap<PathBuf, RunSpec>;

/// A plugin's name and the composite effects it adds to the diagnosis.
pub type PluginEffects = (&'static str, Vec<Box<dyn Effect>>);

/// Version of the manifest/failures layout.
pub use crate::outcome::MANIFEST_VERSION;

/// Where `run --history` appends the night, and the events it records.
pub struct History {
    pub dir: PathBuf,
    pub night: Option<String>,
    /// `--event` specs, parsed once the night is known.
    pub events: Vec<String>,
}

pub struct Engine {
    plugins: Vec<Arc<dyn MachinePlugin>>,
    /// The shared tables and every plugin's (`MachinePlugin::tables`).
    tables: TableRegistry,
    resolver: MachineResolver,
    config: PipelineConfig,
    /// `config`, every section read and checked once in [`Engine::new`].
    checked: CheckedConfig,
    /// `run --history DIR [--night D] [--event ...]`.
    history: Option<History>,
    /// `run --augment augmented_model.json`.
    augment: Option<crate::diagnose::augment::AugmentedModel>,
    /// What the input is called in shard.json when it is not the local
    /// directory the engine reads: the bucket URL a staged input came
    /// from, so shards staged into different work directories are still
    /// of one input.
    input_label: Option<String>,
    /// `run --snapshot FILE`: the night's run set, fixed when it started.
    snapshot: Option<(PathBuf, snapshot::NightSnapshot)>,
}

fn config_text(t: &toml::Table) -> String {
    toml::to_string(t).unwrap_or_default()
}

impl Engine {
    /// The engine over these plugins; checks each plugin's declared stages
    /// and the config against them before anything runs (unknown plugin,
    /// unknown stage, bad values).
    /// The tables this engine knows: the shared ones and its plugins'.
    pub fn tables(&self) -> &TableRegistry {
        &self.tables
    }

    pub fn new(
        plugins: Vec<Arc<dyn MachinePlugin>>,
        resolver: MachineResolver,
        config: PipelineConfig,
    ) -> Result<Self> {
        let tables = TableRegistry::of(plugins.iter().map(|p| (p.name(), p.tables())))?;
        for p in &plugins {
            check_plugin(p.as_ref(), &tables)?;
        }
        let checked = checks::check_config(&plugins, &config)?;
        Ok(Engine {
            plugins,
            tables,
            resolver,
            config,
            checked,
            history: None,
            augment: None,
            input_label: None,
            snapshot: None,
        })
    }

    /// Append each batch's diagnosis to a fleet history and write the trend
    /// report to `<out>/trend/` (before the index, which links it). `night`
    /// defaults to the latest `[run].started` of the batch's runs; `events`
    /// (`--event` specs: a wheel change, dressing, repair or config change)
    /// are added to the history's events.toml, dated that night unless they
    /// say otherwise. Everything is checked here, before any run.
    pub fn set_history(
        &mut self,
        dir: PathBuf,
        night: Option<String>,
        events: Vec<String>,
    ) -> Result<()> {
        if let Some(n) = &night {
            report::trend::check_night(n)?;
        }
        if night.is_none() {
            // Dated later, from the runs; checked now with a stand-in night.
            for e in &events {
                report::trend::parse_event(e, Some("2000-01-01"))?;
            }
        } else {
            for e in &events {
                report::trend::parse_event(e, night.as_deref())?;
            }
        }
        report::trend::read_events(&dir)?;
        self.history = Some(History { dir, night, events });
        Ok(())
    }

    /// Add a previous diagnosis's effects to the sim side of the fleet's
    /// observations and report the plain vs augmented gap
    /// (`fleet/augment.json`). The model is read and checked here, before
    /// any run is processed.
    /// Name the input by the URL it was staged from (see `input_label`).
    pub fn set_input_label(&mut self, label: impl Into<String>) {
        self.input_label = Some(label.into());
    }

    /// The run directories under `input_root` that `shard` owns, as
    /// `run --shard` partitions them (discovery, duplicate ids, then the
    /// balance rule) — for staging only those runs from object storage.
    pub fn shard_runs(&self, input_root: &Path, shard: &shard::ShardSpec) -> Result<Vec<PathBuf>> {
        let (found, _) = self.discover_night(input_root)?;
        let (run_dirs, _, _) = self.account_for_runs(&found);
        Ok(shard::select_runs(&run_dirs, shard))
    }

    /// Process the run set of `file` (written by `sparkout snapshot` when
    /// the night started) instead of whatever is under the input now.
    pub fn set_snapshot(&mut self, file: &Path) -> Result<()> {
        self.snapshot = Some((file.to_path_buf(), snapshot::NightSnapshot::read(file)?));
        Ok(())
    }

    /// What the night processes under `input_root`: discovery, restricted
    /// to the snapshot when there is one; and the runs that arrived after
    /// it (for the next night).
    pub fn discover_night(
        &self,
        input_root: &Path,
    ) -> Result<(crate::contracts::Discovery, Vec<PathBuf>)> {
        let found = discover(input_root)
            .with_context(|| format!("cannot list runs under {}", input_root.display()))?;
        Ok(match &self.snapshot {
            Some((file, snap)) => snap.restrict(input_root, found, file),
            None => (found, Vec::new()),
        })
    }

    pub fn set_augment(&mut self, model: &Path) -> Result<()> {
        self.augment = Some(crate::diagnose::augment::AugmentedModel::load(model)?);
        Ok(())
    }

    pub fn config(&self) -> &PipelineConfig {
        &self.config
    }

    pub fn plugins(&self) -> &[Arc<dyn MachinePlugin>] {
        &self.plugins
    }

    pub fn plugin(&self, name: &str) -> Option<&Arc<dyn MachinePlugin>> {
        self.plugins.iter().find(|p| p.name() == name)
    }

    fn plugin_names(&self) -> Vec<&'static str> {
        self.plugins.iter().map(|p| p.name()).collect()
    }

    /// Each plugin's composites (plugin name, effects), in registry order;
    /// the diagnosis scopes them to the plugin's observables.
    pub fn plugin_effects(&self) -> Vec<PluginEffects> {
        self.plugins
            .iter()
            .map(|p| (p.name(), p.effects()))
            .collect()
    }

    /// Load and resolve one run: run.toml, plugin, machine, required tables.
    pub fn open_run(&self, dir: &Path) -> Result<(Run, Arc<dyn MachinePlugin>)> {
        self.open_spec(RunSpec::load(dir)?)
    }

    /// [`Engine::open_run`] from its run.toml, already read and checked.
    pub(super) fn open_spec(&self, spec: RunSpec) -> Result<(Run, Arc<dyn MachinePlugin>)> {
        let dir = spec.dir.clone();
        let dir = dir.as_path();
        let plugin = self.plugin(&spec.plugin).cloned().ok_or_else(|| {
            InputError::new(
                spec.run_toml_path(),
                format!(
                    "unknown plugin `{}` (known: {})",
                    spec.plugin,
                    self.plugin_names().join(", ")
                ),
            )
            .column("run.plugin")
        })?;
        // A contract table's name that is not a regular file (a directory,
        // e.g. a Hive-partitioned export) would otherwise read as "absent".
        for schema in self.tables.iter() {
            let p = dir.join(schema.file_name());
            if p.exists() && !p.is_file() {
                return Err(InputError::new(
                    &p,
                    format!(
                        "`{}` is a directory (or not a regular file), not a Parquet file; write the table as one file (e.g. pandas `df.to_parquet(\"{}\")`)",
                        schema.file_name(),
                        schema.file_name()
                    ),
                )
                .into());
            }
        }
        let mut machine = self.resolver.resolve(&spec)?;
        let builtins: Vec<&str> = plugin.builtin_machines().iter().map(|(_, t)| *t).collect();
        config_keys::load_machine(
            &mut machine,
            plugin.name(),
            &builtins,
            plugin.machine_sections(),
        )?;
        // An inline [machine] that a machine config file shadows is checked
        // all the same: a typo in it is never silent.
        if let Some(mut inline) = MachineResolver::inline(&spec) {
            if inline.source != machine.source {
                config_keys::load_machine(
                    &mut inline,
                    plugin.name(),
                    &builtins,
                    plugin.machine_sections(),
                )?;
            }
        }
        config_keys::check_process(&spec, plugin.name(), plugin.process_keys())?;
        let run = Run::new(spec, machine);
        // Every present table is checked against the contract up front, the
        // ones no stage reads too: a broken table is bad input whether or
        // not this DAG needs it. (Tables are cached in the Run, so stages do
        // not read them twice; the AE log streams and is checked as it is
        // read.)
        for schema in self.tables.iter() {
            if schema.name != "ae" && run.has_table(schema) {
                run.table(schema)?;
            }
        }
        let alternatives = plugin.required_tables();
        let satisfied = alternatives.is_empty()
            || alternatives.iter().any(|set| {
                set.iter().all(|t| {
                    self.tables
                        .get(t)
                        .map(|s| run.has_table(s))
                        .unwrap_or(false)
                })
            });
        if !satisfied {
            let alts: Vec<String> = alternatives
                .iter()
                .map(|s| {
                    s.iter()
                        .map(|t| format!("{t}.parquet"))
                        .collect::<Vec<_>>()
                        .join(" + ")
                })
                .collect();
            return Err(InputError::new(
                run.dir(),
                format!(
                    "plugin `{}` needs {} (docs/formats.md); none of these sets is complete",
                    plugin.name(),
                    alts.join(", or ")
                ),
            )
            .into());
        }
        for &(name, min) in plugin.min_rows() {
            let Some(schema) = self.tables.get(name) else {
                continue;
            };
            if let Some(t) = run.table(schema)? {
                if t.len() < min {
                    return Err(InputError::new(
                        t.path(),
                        format!(
                            "`{}` has {} row(s); plugin `{}` needs at least {min} (docs/formats.md, section 5)",
                            schema.file_name(),
                            t.len(),
                            plugin.name()
                        ),
                    )
                    .into());
                }
            }
        }
        Ok((run, plugin))
    }

    /// The stages to run for a plugin, per `[pipeline].stages`, with their
    /// upstream stages, in topological order.
    fn plan(&self, plugin: &dyn MachinePlugin) -> Result<Vec<Arc<dyn Stage>>> {
        let ordered = dag::topological_order(&plugin.stages())?;
        match &self.checked.pipeline.stages {
            None => Ok(ordered),
            Some(list) => {
                let targets: BTreeSet<String> = list.iter().cloned().collect();
                Ok(dag::with_upstream(&ordered, &targets))
            }
        }
    }

    fn plugins_enabled(&self) -> Result<Option<BTreeSet<String>>> {
        Ok(self
            .checked
            .pipeline
            .plugins
            .as_ref()
            .map(|l| l.iter().cloned().collect()))
    }

    /// The whole batch.
    pub fn run_fleet(
        &self,
        input_root: &Path,
        out: &Path,
        jobs: Option<usize>,
        progress: &dyn Progress,
    ) -> Result<FleetOutcome> {
        self.run_batch(input_root, out, jobs, None, progress)
    }

    /// One shard of the batch (`sparkout run --shard i/n`): its runs exactly
    /// as `run_fleet` processes them, then shard.json instead of the fleet
    /// steps (`aggregate` runs those once over every shard).
    pub fn run_shard(
        &self,
        input_root: &Path,
        out: &Path,
        jobs: Option<usize>,
        shard: &shard::ShardSpec,
        progress: &dyn Progress,
    ) -> Result<FleetOutcome> {
        self.run_batch(input_root, out, jobs, Some(shard), progress)
    }

    fn run_batch(
        &self,
        input_root: &Path,
        out: &Path,
        jobs: Option<usize>,
        shard: Option<&shard::ShardSpec>,
        progress: &dyn Progress,
    ) -> Result<FleetOutcome> {
        names::check_out_apart(input_root, out, "--input").map_err(|e| err!(e))?;
        let (found, late) = self.discover_night(input_root)?;
        if !late.is_empty() {
            tracing::warn!(
                "{} run(s) arrived after the night's snapshot and are left for the next night (first: {})",
                late.len(),
                late[0].display()
            );
        }
        if found.runs.is_empty() && found.skipped.is_empty() {
            bail!(
                "no runs under {} (expected <root>/<machine>/<run>/run.toml); generate some with `sparkout generate robot --runs 4 --seed 1 --out {}`",
                input_root.display(),
                input_root.display()
            );
        }
        let jobs = clamp_jobs(jobs);
        // One batch per output directory, held until the manifest is written.
        let _lock = lock::BatchLock::acquire(out)?;
        let orphans = remove_orphaned_temps(out, 3);
        if !orphans.is_empty() {
            tracing::warn!(
                "removed {} temporary file(s) a killed batch left under {}",
                orphans.len(),
                out.display()
            );
        }
        let (mut run_dirs, mut early_failures, specs) = self.account_for_runs(&found);
        let night_items = run_dirs.len() + early_failures.len();
        let items_of = |runs: &[PathBuf], fails: &[Failure]| -> Vec<String> {
            let mut v: Vec<String> = runs
                .iter()
                .map(|r| snapshot::relative(input_root, r))
                .chain(
                    fails
                        .iter()
                        .map(|f| snapshot::relative(input_root, Path::new(&f.run_dir))),
                )
                .collect();
            v.sort();
            v
        };
        let night_list = shard.map(|_| items_of(&run_dirs, &early_failures));
        if let Some(sh) = shard {
            // A shard.json left by an earlier batch must not outlive this
            // one: if this run is killed, aggregate finds no finished shard.
            match std::fs::remove_file(out.join(shard::SHARD_FILE)) {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                    return Err(e).with_context(|| {
                        format!(
                            "cannot remove the earlier {}",
                            out.join(shard::SHARD_FILE).display()
                        )
                    })
                }
                _ => {}
            }
            run_dirs = shard::select_runs(&run_dirs, sh);
            early_failures.retain(|f| shard::owns_failure(f, sh));
        }
        let assigned_items = run_dirs.len() + early_failures.len();
        let assigned_list = shard.map(|_| items_of(&run_dirs, &early_failures));
        for f in &early_failures {
            if let (Some(m), Some(r)) = (&f.machine, &f.run) {
                // Nothing of a rejected run stays in the output (only what
                // sparkout's own cache file lists is removed).
                if let Ok(run_out) = run_out_dir(out, m, r) {
                    cache::remove_run_outputs(&run_out);
                }
            }
            tracing::warn!("{}: {}", f.run_dir, f.error);
        }
        progress.start(run_dirs.len());
        let enabled = self.plugins_enabled()?;
        let work = |dir: &PathBuf| -> Option<std::result::Result<RunResult, Failure>> {
            let r = self.process_run(dir, specs.get(dir), out, enabled.as_ref());
            match &r {
                Some(Ok(rr)) => progress.run_done(
                    &format!("{}/{}", rr.machine, rr.run),
                    true,
                    rr.computed(),
                    rr.cached(),
                ),
                Some(Err(f)) => progress.run_done(&f.run_dir, false, 0, 0),
                None => {}
            }
            r
        };
        let results: Vec<Option<std::result::Result<RunResult, Failure>>> = {
            use rayon::prelude::*;
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(jobs)
                .build()
                .context("cannot start worker threads")?;
            pool.install(|| run_dirs.par_iter().map(work).collect())
        };
        let mut runs = Vec::new();
        let mut failures = Vec::new();
        for r in results.into_iter().flatten() {
            match r {
                Ok(rr) => runs.push(rr),
                Err(f) => failures.push(f),
            }
        }
        failures.append(&mut early_failures);
        let mut outcome = FleetOutcome::new(out, runs, failures);
        if let Some(sh) = shard {
            shard::ShardManifest::write(
                out,
                &shard::ShardManifest {
                    version: shard::SHARD_VERSION,
                    kind: "sparkout.shard".into(),
                    shard: sh.index,
                    shards: sh.count,
                    balance: sh.balance,
                    sparkout_version: env!("CARGO_PKG_VERSION").into(),
                    input_root: self
                        .input_label
                        .clone()
                        .unwrap_or_else(|| input_root.display().to_string()),
                    input_dir: input_root.display().to_string(),
                    config: serde_json::to_value(&self.config.table)
                        .unwrap_or(serde_json::Value::Null),
                    config_source: self.config.source.clone(),
                    input_fingerprint: shard::input_fingerprint(input_root, &found),
                    night_items,
                    assigned_items,
                    night_runs: night_list.unwrap_or_default(),
                    assigned_runs: assigned_list.unwrap_or_default(),
                    machines_fingerprint: self.resolver.fingerprint(),
                    runs: outcome.runs.clone(),
                    failures: outcome.failures.clone(),
                },
            )?;
            return Ok(outcome);
        }
        self.run_fleet_stages(out, &mut outcome, progress)?;
        write_json_atomic(&out.join("failures.json"), &outcome.failures)?;
        self.write_manifest(input_root, out, &outcome)?;
        Ok(outcome)
    }

    /// `sparkout aggregate`: every shard's runs gathered under `out` (the
    /// same layout a single-node `run` writes), then the fleet steps, once.
    /// The fleet outputs equal those of a single-node run of the same input
    /// and config (tests/e2e/shards.rs holds them byte-identical).
    pub fn aggregate(
        &self,
        shard_dirs: &[PathBuf],
        out: &Path,
        progress: &dyn Progress,
    ) -> Result<FleetOutcome> {
        // The fleet steps alone: every thread shares one malloc arena,
        // which keeps less freed memory at the diagnosis' peak
        // (`alloc::share_one_arena`).
        crate::alloc::share_one_arena();
        let manifests: Vec<shard::ShardManifest> = shard_dirs
            .iter()
            .map(|d| shard::ShardManifest::read(d))
            .collect::<Result<_>>()?;
        shard::check_shards(shard_dirs, &manifests)?;
        let config = serde_json::to_value(&self.config.table).unwrap_or(serde_json::Value::Null);
        if manifests[0].config != config {
            bail!(
                "the shards under {} were run with a different config than this aggregate was given: pass the same --config/--set to `aggregate` as to every `run --shard`",
                shard_dirs[0].display()
            );
        }
        let input_root = PathBuf::from(&manifests[0].input_root);
        if input_root.is_dir() {
            names::check_out_apart(&input_root, out, "the shards' input").map_err(|e| err!(e))?;
        }
        // The output gathers from the shards and cleans up after itself:
        // inside a shard, or holding one, it would mix with (and tidy) the
        // shard's own files. A shard's own directory is allowed (`--out`
        // may be one of the shards': its runs are then already in place).
        let out_resolved = names::resolve(out);
        for d in shard_dirs {
            if out_resolved.is_some() && names::resolve(d) == out_resolved {
                continue;
            }
            names::check_out_apart(d, out, "--shards").map_err(|e| err!(e))?;
        }
        let _lock = lock::BatchLock::acquire(out)?;
        let mut runs = Vec::new();
        let mut failures = Vec::new();
        progress.message(&format!("gathering {} shard(s)", manifests.len()));
        for (dir, m) in shard_dirs.iter().zip(manifests) {
            let input_dir = PathBuf::from(&m.input_dir);
            for mut r in m.runs {
                // Names in a shard manifest are input like any other.
                let shard_file = dir.join(shard::SHARD_FILE);
                let from = run_out_dir(dir, &r.machine, &r.run)
                    .map_err(|e| err!("{}: {e}", shard_file.display()))?;
                let to = run_out_dir(out, &r.machine, &r.run)
                    .map_err(|e| err!("{}: {e}", shard_file.display()))?;
                if !from.is_dir() {
                    bail!(
                        "{}: run {}/{} is listed, but its folder {} is missing (moved or deleted since the shard ran): re-run shard {}/{}",
                        shard_file.display(),
                        r.machine,
                        r.run,
                        from.display(),
                        m.shard,
                        m.shards
                    );
                }
                shard::copy_run_dir(&from, &to)
                    .map_err(|e| err!("{}: {e:#}", shard_file.display()))?;
                r.out_dir = to.display().to_string();
                r.observations = Some(to.join(OBSERVATIONS_FILE)).filter(|o| o.is_file());
                let rel = PathBuf::from(&r.run_dir)
                    .strip_prefix(&input_dir)
                    .map(Path::to_path_buf)
                    .unwrap_or_else(|_| PathBuf::from(&r.run_dir));
                runs.push((rel, r));
            }
            failures.extend(m.failures);
        }
        // The order a single-node batch has: run directories sorted (by
        // their path below the input, which is the same on every node).
        runs.sort_by(|a, b| a.0.cmp(&b.0));
        let runs: Vec<RunResult> = runs.into_iter().map(|(_, r)| r).collect();
        let mut outcome = FleetOutcome::new(out, runs, failures);
        self.run_fleet_stages(out, &mut outcome, progress)?;
        write_json_atomic(&out.join("failures.json"), &outcome.failures)?;
        self.write_manifest(&input_root, out, &outcome)?;
        Ok(outcome)
    }

    /// Every directory found is either processed or listed: directories
    /// with tables but no run.toml, and runs whose (machine, run) id another
    /// directory also claims (one would silently overwrite the other's
    /// outputs), become failures naming every directory involved.
    /// The run.toml of every run directory that has a readable one comes
    /// back with it, read once: processing the run takes it from there.
    fn account_for_runs(
        &self,
        found: &crate::contracts::Discovery,
    ) -> (Vec<PathBuf>, Vec<Failure>, RunSpecs) {
        let mut failures: Vec<Failure> = found
            .skipped
            .iter()
            .map(|s| Failure {
                run_dir: s.dir.display().to_string(),
                machine: None,
                run: None,
                stage: Some("discover".into()),
                file: Some(s.file.display().to_string()),
                column: None,
                row: None,
                error: s.why.clone(),
            })
            .collect();
        let mut by_id: BTreeMap<(String, String), Vec<(&PathBuf, RunSpec)>> = BTreeMap::new();
        let mut runs = Vec::new();
        for dir in &found.runs {
            match RunSpec::load(dir) {
                Ok(spec) => by_id
                    .entry((spec.machine.clone(), spec.id.clone()))
                    .or_default()
                    .push((dir, spec)),
                // process_run reports it with the same error.
                Err(_) => runs.push(dir.clone()),
            }
        }
        let mut specs = RunSpecs::new();
        for ((machine, id), mut dirs) in by_id {
            if dirs.len() == 1 {
                let (dir, spec) = dirs.remove(0);
                runs.push(dir.clone());
                specs.insert(dir.clone(), spec);
                continue;
            }
            let all: Vec<String> = dirs.iter().map(|(d, _)| d.display().to_string()).collect();
            for (dir, spec) in &dirs {
                failures.push(Failure {
                    run_dir: dir.display().to_string(),
                    machine: Some(machine.clone()),
                    run: Some(id.clone()),
                    stage: Some("discover".into()),
                    file: Some(spec.run_toml_path().display().to_string()),
                    column: Some("run.id".into()),
                    row: None,
                    error: format!(
                        "duplicate run id: machine `{machine}` run `{id}` is claimed by {} directories ({}); run ids must be unique within a machine (docs/formats.md), so none of them is processed — rename [run].id in all but one",
                        all.len(),
                        all.join(" and ")
                    ),
                });
            }
        }
        runs.sort();
        (runs, failures, specs)
    }

    /// A stage by name across all plugins (for run-less `sparkout stage`).
    pub fn find_stage(&self, name: &str) -> Option<Arc<dyn Stage>> {
        self.plugins
            .iter()
            .flat_map(|p| p.stages().into_iter().chain(p.standalone_stages()))
            .find(|s| s.name() == name)
    }
}

/// `<out>/<machine>/<id>`, checked: both are plain names and the path
/// stays inside `out` (symbolic links resolved).
pub fn run_out_dir(out: &Path, machine: &str, id: &str) -> std::result::Result<PathBuf, String> {
    names::inside(out, &[("[run].machine", machine), ("[run].id", id)])
}

/// A stage's files, then the run's cache file listing every stage done so
/// far (written last, so it never lists a file that is not complete).
fn write_stage_files(
    run_out: &Path,
    files: &[(String, Vec<u8>)],
    records: &[StageRecord],
) -> Result<()> {
    for (name, bytes) in files {
        write_atomic(&run_out.join(name), bytes)?;
    }
    write_json_atomic(&run_out.join(cache::RUN_CACHE_FILE), &records)
}

/// Fault injection for the resume tests: `SPARKOUT_FAULT_ABORT_AFTER_STAGE=
/// <stage>` aborts the process (like a kill -9) right after that stage was
/// recorded. Unset in normal use.
fn abort_if_fault_injected(stage: &str) {
    if std::env::var("SPARKOUT_FAULT_ABORT_AFTER_STAGE").is_ok_and(|s| s == stage) {
        std::process::abort();
    }
}

/// `--jobs`: absent or 0 means every core. More threads than cores gains
/// nothing for this CPU-bound work and, at --jobs 100000, exhausts the
/// kernel's threads, so it is clamped with a warning.
pub fn clamp_jobs(jobs: Option<usize>) -> usize {
    let cores = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1);
    match jobs {
        None | Some(0) => cores,
        Some(j) if j > cores => {
            tracing::warn!("--jobs {j} is more than the {cores} cores available; using {cores}");
            cores
        }
        Some(j) => j,
    }
}

//! The per-run steps of the engine: one run through its plugin's stages
//! (cache key, cached or computed, held to each stage's spec), its report,
//! and `sparkout stage` (one stage with its upstream in memory).

use super::*;

/// The run's report step, as the cache records it beside the stages.
const REPORT_STEP: &str = "report";

impl Engine {
    /// One run through its plugin's stages. `None` when its plugin is not
    /// enabled by `[pipeline].plugins`.
    pub(super) fn process_run(
        &self,
        dir: &Path,
        spec: Option<&RunSpec>,
        out: &Path,
        enabled: Option<&BTreeSet<String>>,
    ) -> Option<std::result::Result<RunResult, Failure>> {
        self.process_run_at(dir, spec, Some(out), enabled)
    }

    /// [`Self::process_run`] writing under `out`, or in memory only. `spec`
    /// is the run's run.toml when discovery read it already (else it is
    /// read here).
    pub(super) fn process_run_at(
        &self,
        dir: &Path,
        spec: Option<&RunSpec>,
        out: Option<&Path>,
        enabled: Option<&BTreeSet<String>>,
    ) -> Option<std::result::Result<RunResult, Failure>> {
        let spec = match spec.cloned().map_or_else(|| RunSpec::load(dir), Ok) {
            Ok(s) => s,
            Err(e) => return Some(Err(Failure::from_error(dir, None, None, &e.into()))),
        };
        if let Some(en) = enabled {
            if !en.contains(&spec.plugin) {
                return None;
            }
        }
        let run_out = match out.map(|o| run_out_dir(o, &spec.machine, &spec.id)) {
            None => None,
            Some(Ok(d)) => Some(d),
            Some(Err(e)) => {
                let e = InputError::new(spec.run_toml_path(), e).column("run.machine");
                return Some(Err(Failure::from_error(dir, Some(&spec), None, &e.into())));
            }
        };
        let mut failed_stage: Option<String> = None;
        // A panic in a stage is a bug, but it must not take the batch down:
        // the run is rejected like any other failure.
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            self.process_run_inner(dir, spec.clone(), run_out.as_deref(), &mut failed_stage)
        }))
        .unwrap_or_else(|panic| {
            let msg = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "unknown panic".into());
            Err(err!(
                "internal error (a bug in sparkout, please report it): {msg}"
            ))
        });
        Some(result.map_err(|e| {
            // Nothing of a rejected run stays in the output: drop the
            // artifacts an earlier batch (or its earlier stages) wrote —
            // only the files its own cache file lists.
            if let Some(run_out) = &run_out {
                cache::remove_run_outputs(run_out);
                tracing::warn!("run {} rejected: {e:#}", dir.display());
            }
            Failure::from_error(dir, Some(&spec), failed_stage.as_deref(), &e)
        }))
    }

    /// A stage's cache key: its name, version, plugin and effective config
    /// (its checked section serialised canonically, defaults applied),
    /// run.toml and the machine config, the hash of every table it reads
    /// (hashed once per run, in `table_hashes`), the keys of the stages
    /// whose artifacts it reads, and the augmented model's hash when it
    /// reads one.
    fn stage_key(
        &self,
        stage: &Arc<dyn Stage>,
        plugin: &str,
        cfg: &crate::config_check::CheckedSection,
        run: &Run,
        table_hashes: &mut BTreeMap<String, String>,
        producer_key: &BTreeMap<String, String>,
    ) -> Result<String> {
        let mut key = KeyBuilder::new("stage");
        key.part("stage", stage.name())
            .part("version", &stage.version().to_string())
            .part("plugin", plugin)
            .part("config", cfg.effective())
            .part("run.toml", &run.spec.text)
            .part("machine", &run.machine.text);
        for schema in stage.spec().reads {
            let t = schema.name;
            if !run.has_table(schema) {
                key.part(t, "absent");
                continue;
            }
            if !table_hashes.contains_key(t) {
                let h = hash_input(&run.table_path(schema))
                    .with_context(|| format!("cannot hash {}", run.table_path(schema).display()))?;
                table_hashes.insert(t.to_string(), h);
            }
            key.part(t, &table_hashes[t]);
        }
        for a in stage.reads_artifacts() {
            key.part(
                a,
                producer_key.get(*a).map(|s| s.as_str()).unwrap_or("absent"),
            );
        }
        if stage.spec().reads_augmented_model {
            key.part(
                "augmented_model",
                self.augment
                    .as_ref()
                    .map_or("none", |m| m.content_hash.as_str()),
            );
        }
        Ok(key.finish())
    }

    /// Every stage of one run. With `run_out` the artifacts are written and
    /// the cache consulted; without, everything is computed in memory and
    /// nothing written (`validate-input` runs exactly the checks `run` runs).
    pub(super) fn process_run_inner(
        &self,
        dir: &Path,
        spec: RunSpec,
        run_out: Option<&Path>,
        failed_stage: &mut Option<String>,
    ) -> Result<RunResult> {
        // run.toml was read and checked once by the caller.
        let (run, plugin) = self.open_spec(spec)?;
        let stages = self.plan(plugin.as_ref())?;
        let previous = run_out.map(read_run_cache).unwrap_or_default();
        let store = ArtifactStore::default();
        let mut table_hashes: BTreeMap<String, String> = BTreeMap::new();
        let mut producer_key: BTreeMap<String, String> = BTreeMap::new();
        let mut records: Vec<StageRecord> = Vec::new();

        for stage in &stages {
            *failed_stage = Some(stage.name().to_string());
            let cfg = self.checked.stage(plugin.name(), stage.name())?;
            let augment = self
                .augment
                .as_ref()
                .filter(|_| stage.spec().reads_augmented_model);
            let key = self.stage_key(
                stage,
                plugin.name(),
                cfg,
                &run,
                &mut table_hashes,
                &producer_key,
            )?;
            for w in stage.writes() {
                producer_key.insert(w.to_string(), key.clone());
            }
            let summary_file = format!("{}.json", stage.name());
            if let (Some(run_out), Some(prev)) = (run_out, previous.get(stage.name())) {
                if record_valid(run_out, prev, &key) {
                    for w in stage.writes() {
                        let f = format!("{w}.parquet");
                        if prev.files.contains_key(&f) {
                            store.insert_on_disk(w, run_out.join(&f));
                        }
                    }
                    if let Ok(b) = std::fs::read(run_out.join(&summary_file)) {
                        if let Ok(v) = serde_json::from_slice(&b) {
                            store.set_summary(stage.name(), v);
                        }
                    }
                    let mut rec = prev.clone();
                    rec.cached = true;
                    records.push(rec);
                    continue;
                }
            }
            let ctx = StageContext {
                run: &run,
                config: cfg,
                artifacts: &store,
                augment,
            };
            let output = run_checked(stage.as_ref(), &ctx)?;
            let mut files = BTreeMap::new();
            let mut pending: Vec<(String, Vec<u8>)> = Vec::new();
            for (name, batch) in &output.artifacts {
                check_finite(stage.name(), name, batch)?;
                // A run's observations name their machine too, so a
                // per-run file read alone cannot be mistaken for another
                // machine's run with the same id.
                let batch = if name == "observations" {
                    with_machine_column(batch.clone(), &run.spec.machine)?
                } else {
                    batch.clone()
                };
                let bytes = parquet_bytes(&batch)?;
                files.insert(format!("{name}.parquet"), hash_bytes(&bytes));
                pending.push((format!("{name}.parquet"), bytes));
                store.insert(name, batch);
            }
            let summary_bytes = json_bytes(&output.summary)?;
            files.insert(summary_file.clone(), hash_bytes(&summary_bytes));
            pending.push((summary_file, summary_bytes));
            store.set_summary(stage.name(), output.summary);
            records.push(StageRecord {
                stage: stage.name().to_string(),
                version: stage.version(),
                key,
                files,
                cached: false,
            });
            if let Some(run_out) = run_out {
                // Recorded as soon as it completes: a batch killed in a later
                // stage resumes here instead of recomputing this one. If a
                // later stage rejects the run, process_run removes it all.
                write_stage_files(run_out, &pending, &records)?;
                abort_if_fault_injected(stage.name());
            }
        }
        *failed_stage = Some(REPORT_STEP.into());
        // The run's report: a step of its own, cached on every stage's key.
        let mut rkey = KeyBuilder::new("run-report");
        rkey.part("version", &report::REPORT_VERSION.to_string())
            .part("config", self.checked.report.effective())
            // The verdict's `[tolerance]` limits live in these two.
            .part("run.toml", &run.spec.text)
            .part("machine", &run.machine.text);
        for r in &records {
            rkey.part(&r.stage, &r.key);
        }
        let rkey = rkey.finish();
        let cached_report = match (run_out, previous.get(REPORT_STEP)) {
            (Some(run_out), Some(p)) if record_valid(run_out, p, &rkey) => Some(p),
            _ => None,
        };
        if let Some(p) = cached_report {
            let mut rec = p.clone();
            rec.cached = true;
            records.push(rec);
        } else {
            let sections = plugin.report_sections(&run, &store);
            let verdicts = plugin.verdicts(&run, &store);
            let html = report::run_page(
                &self.checked.report,
                &run,
                &store.summary_names(),
                &verdicts,
                &sections,
            );
            let bytes = html.into_bytes();
            let verdict = report::verdict::RunVerdict::of(&verdicts).to_bytes()?;
            let mut files = BTreeMap::new();
            files.insert("report.html".to_string(), hash_bytes(&bytes));
            files.insert(
                report::verdict::RUN_VERDICT_FILE.to_string(),
                hash_bytes(&verdict),
            );
            records.push(StageRecord {
                stage: REPORT_STEP.into(),
                version: report::REPORT_VERSION,
                key: rkey,
                files,
                cached: false,
            });
            if let Some(run_out) = run_out {
                write_stage_files(
                    run_out,
                    &[
                        ("report.html".into(), bytes),
                        (report::verdict::RUN_VERDICT_FILE.into(), verdict),
                    ],
                    &records,
                )?;
            }
        }
        *failed_stage = None;
        let observations = run_out.map(|d| d.join(OBSERVATIONS_FILE));
        Ok(RunResult {
            machine: run.spec.machine.clone(),
            run: run.spec.id.clone(),
            plugin: plugin.name().to_string(),
            run_dir: dir.display().to_string(),
            out_dir: run_out.map(|d| d.display().to_string()).unwrap_or_default(),
            inputs: table_hashes,
            stages: records,
            observations: observations.filter(|o| o.is_file()),
        })
    }

    /// `sparkout stage <name> --run <dir>`: that stage of that run, with its
    /// upstream stages computed in memory.
    pub fn run_single_stage(
        &self,
        run_dir: &Path,
        stage_name: &str,
    ) -> Result<(Arc<dyn Stage>, StageOutput)> {
        let (run, plugin) = self.open_run(run_dir)?;
        let ordered = dag::topological_order(&plugin.stages())?;
        let target = ordered
            .iter()
            .find(|s| s.name() == stage_name)
            .cloned()
            .ok_or_else(|| {
                err!(
                    "plugin `{}` has no stage `{stage_name}` (its stages: {})",
                    plugin.name(),
                    ordered
                        .iter()
                        .map(|s| s.name())
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            })?;
        let chain = dag::with_upstream(&ordered, &[stage_name.to_string()].into());
        let store = ArtifactStore::default();
        let mut last = None;
        for stage in &chain {
            let cfg = self.checked.stage(plugin.name(), stage.name())?;
            let ctx = StageContext {
                run: &run,
                config: cfg,
                artifacts: &store,
                augment: None,
            };
            let output = run_checked(stage.as_ref(), &ctx)?;
            for (name, batch) in &output.artifacts {
                store.insert(name, batch.clone());
            }
            store.set_summary(stage.name(), output.summary.clone());
            last = Some(output);
        }
        Ok((target, last.expect("chain includes the target")))
    }
}

/// Run one stage and hold it to its [`StageSpec`]: it may read only the
/// tables and artifacts it declares and write only the artifacts it declares
/// (what the cache key and the DAG are built from).
pub(super) fn run_checked(stage: &dyn Stage, ctx: &StageContext) -> Result<StageOutput> {
    let spec = stage.spec();
    ctx.run.take_reads();
    ctx.artifacts.take_reads();
    let output = stage
        .run(ctx)
        .with_context(|| format!("stage `{}` of run `{}`", spec.name, ctx.run.spec.id))?;
    spec.check_reads(&ctx.run.take_reads(), &ctx.artifacts.take_reads())?;
    if let Some((name, _)) = output
        .artifacts
        .iter()
        .find(|(name, _)| !spec.writes.contains(&name.as_str()))
    {
        bail!(
            "stage `{}` produced undeclared artifact `{name}`",
            spec.name
        );
    }
    Ok(output)
}

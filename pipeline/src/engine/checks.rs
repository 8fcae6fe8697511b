//! Checks made before and around a batch: the config against the
//! registered plugins and stages, each plugin's declared stages and DAG,
//! `validate-input` (run's checks, writing nothing), and no non-finite
//! number in an artifact.

use super::*;

impl Engine {
    /// Every config section names a registered plugin and stage, and each
    /// stage accepts its section (unknown keys, bad values), before anything
    /// runs.
    pub(super) fn validate_config(&self) -> Result<()> {
        let src = &self.config.source;
        // A typo'd plugin (`--set guidewy.separate.method=...`, `[robotx.ingest]`)
        // would otherwise configure nothing, silently.
        let mut sections: Vec<&str> = vec!["pipeline", "diagnose", "report", "trend"];
        sections.extend(self.plugin_names());
        for (key, value) in &self.config.table {
            if !sections.contains(&key.as_str()) {
                bail!(
                    "config {src} (with any --set): unknown {} `{key}`; the known sections are {} (a plugin's stages go under [PLUGIN.STAGE])",
                    if value.is_table() { "section" } else { "top-level key" },
                    sections.iter().map(|s| format!("[{s}]")).collect::<Vec<_>>().join(", ")
                );
            }
        }
        for (section, known) in [
            ("pipeline", &["plugins", "stages"][..]),
            ("report", &["title"][..]),
        ] {
            for key in self.config.section(section).keys() {
                if !known.contains(&key.as_str()) {
                    bail!(
                        "config {src} (with any --set): unknown key [{section}].{key} (known: {})",
                        known.join(", ")
                    );
                }
            }
        }
        if let Some(list) = self.config.pipeline_list("plugins")? {
            for p in &list {
                if self.plugin(p).is_none() {
                    bail!(
                        "config {src}: [pipeline].plugins names unknown plugin `{p}` (known: {})",
                        self.plugin_names().join(", ")
                    );
                }
            }
        }
        let all_stages: BTreeSet<&str> = self
            .plugins
            .iter()
            .flat_map(|p| p.stages().into_iter().map(|s| s.name()).collect::<Vec<_>>())
            .chain(["diagnose", "report"])
            .collect();
        if let Some(list) = self.config.pipeline_list("stages")? {
            for s in &list {
                if !all_stages.contains(s.as_str()) {
                    bail!(
                        "config {src}: [pipeline].stages names unknown stage `{s}` (known: {})",
                        all_stages.iter().copied().collect::<Vec<_>>().join(", ")
                    );
                }
            }
        }
        for plugin in &self.plugins {
            let section = self.config.section(plugin.name());
            let stages = plugin.stages();
            for (key, value) in &section {
                let stage =
                    stages.iter().find(|s| s.name() == key).ok_or_else(|| {
                        anyhow!(
                        "config {src}: [{}.{key}] is not a stage of plugin `{}` (its stages: {})",
                        plugin.name(),
                        plugin.name(),
                        stages.iter().map(|s| s.name()).collect::<Vec<_>>().join(", ")
                    )
                    })?;
                let t = value.as_table().ok_or_else(|| {
                    anyhow!("config {src}: [{}.{key}] must be a table", plugin.name())
                })?;
                stage
                    .validate_config(t)
                    .with_context(|| format!("config {src}: [{}.{key}]", plugin.name()))?;
            }
        }
        self.diagnose_config()?;
        self.trend_config()?;
        Ok(())
    }

    /// `sparkout validate-input`: the checks `sparkout run` makes, with the
    /// same code — discovery (directories without run.toml, duplicate ids),
    /// run.toml, machine, every stage computed in memory — writing nothing.
    /// For a rejected run, every other present table that breaks the
    /// contract is listed too, so one pass shows all there is to fix.
    pub fn validate_input(&self, root: &Path) -> Result<(usize, Vec<Problem>)> {
        let found = discover(root)?;
        let (dirs, early) = self.account_for_runs(&found);
        let mut problems: Vec<Problem> = early
            .into_iter()
            .map(|f| Problem {
                run_dir: f.run_dir,
                message: f.error,
            })
            .collect();
        let enabled = self.plugins_enabled()?;
        for dir in &dirs {
            let d = dir.display().to_string();
            let Some(Err(f)) = self.check_run(dir, enabled.as_ref()) else {
                continue;
            };
            let first = f.error.clone();
            problems.push(Problem {
                run_dir: d.clone(),
                message: first.clone(),
            });
            // Validate every table that is present, whatever else is wrong.
            let origin = RunSpec::load(dir)
                .map(|s| s.time_origin())
                .unwrap_or(crate::contracts::TimeOrigin::TableStart);
            for schema in crate::contracts::ALL_TABLES {
                let path = dir.join(schema.file_name());
                if !crate::contracts::input_file::InputFile::exists(&path) {
                    continue;
                }
                let r: std::result::Result<(), InputError> = if schema.name == "ae" {
                    AeStream::open_at(&path, &origin, AeStream::DEFAULT_BATCH_ROWS)
                        .and_then(|mut s| s.try_for_each(|c| c.map(|_| ())))
                } else {
                    Table::read_at(&path, schema, &origin).map(|_| ())
                };
                if let Err(e) = r {
                    let m = e.to_string();
                    if !first.contains(&m) {
                        problems.push(Problem {
                            run_dir: d.clone(),
                            message: m,
                        });
                    }
                }
            }
        }
        problems.sort_by(|a, b| a.run_dir.cmp(&b.run_dir));
        // Directories checked: the runs, the duplicates and the skipped.
        let checked: BTreeSet<String> = dirs
            .iter()
            .map(|d| d.display().to_string())
            .chain(problems.iter().map(|p| p.run_dir.clone()))
            .collect();
        Ok((checked.len(), problems))
    }

    /// One run through `run`'s per-run path, in memory: `None` when its
    /// plugin is not enabled, else accepted or the failure `run` would list.
    pub fn check_run(
        &self,
        dir: &Path,
        enabled: Option<&BTreeSet<String>>,
    ) -> Option<std::result::Result<RunResult, Failure>> {
        self.process_run_at(dir, None, enabled)
    }
}

/// A non-finite number never reaches an artifact: NaN or inf out
/// of a stage means an input the checks let through or a bug, and either way
/// the run is rejected rather than written (null is how an artifact says
/// "not applicable").
pub fn check_finite(stage: &str, artifact: &str, batch: &RecordBatch) -> Result<()> {
    use arrow::array::{Array, Float32Array, Float64Array};
    for (f, col) in batch.schema().fields().iter().zip(batch.columns()) {
        let bad = if let Some(a) = col.as_any().downcast_ref::<Float64Array>() {
            (0..a.len())
                .find(|&i| !a.is_null(i) && !a.value(i).is_finite())
                .map(|i| (i, a.value(i)))
        } else if let Some(a) = col.as_any().downcast_ref::<Float32Array>() {
            (0..a.len())
                .find(|&i| !a.is_null(i) && !a.value(i).is_finite())
                .map(|i| (i, a.value(i) as f64))
        } else {
            None
        };
        if let Some((row, v)) = bad {
            bail!(
                "stage `{stage}` computed {v} in artifact `{artifact}`, column `{}`, row {row}: a non-finite number is never written (an input outside the checks, or a bug to report)",
                f.name()
            );
        }
    }
    Ok(())
}

/// What a plugin declares, checked when the engine is built: every stage's
/// spec on its own, stage names unique within the plugin, and the DAG its
/// stages form (each artifact read is written by exactly one stage, no
/// cycle).
pub(super) fn check_plugin(plugin: &dyn MachinePlugin) -> Result<()> {
    let stages = plugin.stages();
    let mut names = BTreeSet::new();
    for s in &stages {
        s.spec()
            .check()
            .with_context(|| format!("plugin `{}`", plugin.name()))?;
        if !names.insert(s.name()) {
            bail!(
                "plugin `{}` has two stages named `{}`",
                plugin.name(),
                s.name()
            );
        }
    }
    dag::topological_order(&stages).with_context(|| format!("plugin `{}`", plugin.name()))?;
    for set in plugin.required_tables() {
        if let Some(t) = set.iter().find(|t| table_schema(t).is_none()) {
            bail!("plugin `{}` requires unknown table `{t}`", plugin.name());
        }
    }
    Ok(())
}

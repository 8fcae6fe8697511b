//! Checks made before and around a batch: the config against the
//! registered plugins and stages, each plugin's declared stages and DAG,
//! `validate-input` (run's checks, writing nothing), and no non-finite
//! number in an artifact.

use super::*;

/// The pipeline config read and checked once, before any run: every
/// section names a registered plugin and stage, and every section —
/// `[pipeline]`, `[report]`, `[diagnose]`, `[trend]` and each stage's
/// `[<plugin>.<stage>]`, an absent one as its defaults — is read into its
/// typed struct here. Runs take the typed values from the result; nothing
/// parses a section again.
pub(super) fn check_config(
    plugins: &[Arc<dyn MachinePlugin>],
    config: &PipelineConfig,
) -> Result<CheckedConfig> {
    let src = &config.source;
    let plugin_names: Vec<&'static str> = plugins.iter().map(|p| p.name()).collect();
    // A typo'd plugin (`--set guidewy.separate.method=...`, `[robotx.ingest]`)
    // would otherwise configure nothing, silently.
    let mut sections: Vec<&str> = vec!["pipeline", "diagnose", "report", "trend"];
    sections.extend(plugin_names.iter().copied());
    for (key, value) in &config.table {
        if !sections.contains(&key.as_str()) {
            bail!(
                "config {src} (with any --set): unknown {} `{key}`; the known sections are {} (a plugin's stages go under [PLUGIN.STAGE])",
                if value.is_table() { "section" } else { "top-level key" },
                sections.iter().map(|s| format!("[{s}]")).collect::<Vec<_>>().join(", ")
            );
        }
    }
    let table_of = |name: &str| -> Result<toml::Table> {
        match config.table.get(name) {
            None => Ok(toml::Table::new()),
            Some(toml::Value::Table(t)) => Ok(t.clone()),
            Some(_) => bail!("config {src}: [{name}] must be a table"),
        }
    };
    let pipeline: Checked<PipelineSection> = Checked::read(&table_of("pipeline")?)
        .with_context(|| format!("config {src} (with any --set): [pipeline]"))?;
    let report: Checked<ReportSection> = Checked::read(&table_of("report")?)
        .with_context(|| format!("config {src} (with any --set): [report]"))?;
    let diagnose: Checked<DiagnoseConfig> = Checked::read(&table_of("diagnose")?)
        .with_context(|| format!("config {src}: [diagnose]"))?;
    let trend: Checked<report::trend::TrendConfig> =
        Checked::read(&table_of("trend")?).with_context(|| format!("config {src}: [trend]"))?;
    if let Some(list) = &pipeline.plugins {
        for p in list {
            if !plugin_names.contains(&p.as_str()) {
                bail!(
                    "config {src}: [pipeline].plugins names unknown plugin `{p}` (known: {})",
                    plugin_names.join(", ")
                );
            }
        }
    }
    let all_stages: BTreeSet<&str> = plugins
        .iter()
        .flat_map(|p| p.stages().into_iter().map(|s| s.name()).collect::<Vec<_>>())
        .chain(["diagnose", "report"])
        .collect();
    if let Some(list) = &pipeline.stages {
        for s in list {
            if !all_stages.contains(s.as_str()) {
                bail!(
                    "config {src}: [pipeline].stages names unknown stage `{s}` (known: {})",
                    all_stages.iter().copied().collect::<Vec<_>>().join(", ")
                );
            }
        }
    }
    let mut stage_sections = BTreeMap::new();
    for plugin in plugins {
        let section = table_of(plugin.name())?;
        let stages = plugin.stages();
        for (key, value) in &section {
            if !stages.iter().any(|s| s.name() == key) {
                bail!(
                    "config {src}: [{}.{key}] is not a stage of plugin `{}` (its stages: {})",
                    plugin.name(),
                    plugin.name(),
                    stages
                        .iter()
                        .map(|s| s.name())
                        .collect::<Vec<_>>()
                        .join(", ")
                );
            }
            if !value.is_table() {
                bail!("config {src}: [{}.{key}] must be a table", plugin.name());
            }
        }
        for stage in &stages {
            let own = match section.get(stage.name()) {
                Some(toml::Value::Table(t)) => t.clone(),
                _ => toml::Table::new(),
            };
            let checked = stage
                .read_config(&own)
                .with_context(|| format!("config {src}: [{}.{}]", plugin.name(), stage.name()))?;
            stage_sections.insert((plugin.name(), stage.name()), checked);
        }
    }
    Ok(CheckedConfig {
        pipeline,
        report,
        diagnose,
        trend,
        stages: stage_sections,
    })
}

impl Engine {
    /// `sparkout validate-input`: the checks `sparkout run` makes, with the
    /// same code — discovery (directories without run.toml, duplicate ids),
    /// run.toml, machine, every stage computed in memory — writing nothing.
    /// For a rejected run, every other present table that breaks the
    /// contract is listed too, so one pass shows all there is to fix.
    pub fn validate_input(&self, root: &Path) -> Result<(usize, Vec<Problem>)> {
        let found = discover(root)?;
        let (dirs, early, specs) = self.account_for_runs(&found);
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
            // `run`'s per-run path, in memory.
            let Some(Err(f)) = self.process_run_at(dir, specs.get(dir), None, enabled.as_ref())
            else {
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
            for schema in self.tables.iter() {
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
/// spec on its own, stage names unique within the plugin, the DAG its
/// stages form (each artifact read is written by exactly one stage, no
/// cycle), and its built-in machines loaded through its declared machine
/// sections (a section struct that refuses a built-in value is a plugin
/// bug).
pub(super) fn check_plugin(
    plugin: &dyn MachinePlugin,
    tables: &crate::contracts::TableRegistry,
) -> Result<()> {
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
        if let Some(t) = set.iter().find(|t| tables.get(t).is_none()) {
            bail!("plugin `{}` requires unknown table `{t}`", plugin.name());
        }
    }
    let builtins = plugin.builtin_machines();
    let texts: Vec<&str> = builtins.iter().map(|(_, t)| *t).collect();
    for (id, text) in &builtins {
        let mut m = crate::contracts::MachineConfig {
            id: id.to_string(),
            source: format!("built-in machine `{id}`"),
            table: text
                .parse()
                .with_context(|| format!("plugin `{}`: built-in machine `{id}`", plugin.name()))?,
            text: text.to_string(),
            ..Default::default()
        };
        crate::contracts::config_keys::load_machine(
            &mut m,
            plugin.name(),
            &texts,
            plugin.machine_sections(),
        )
        .with_context(|| format!("plugin `{}`: its built-in machine `{id}`", plugin.name()))?;
    }
    Ok(())
}

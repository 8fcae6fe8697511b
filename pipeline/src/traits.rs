//! The traits everything plugs in by (DESIGN.md "Traits"). The engine knows
//! no concrete machine; a plugin knows no other plugin.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use arrow::record_batch::RecordBatch;

use crate::contracts::{read_parquet, MachineConfig, RunSpec, Table, TableSchema};
use crate::diagnose::Effect;
use crate::error::{InputError, Result};

/// One recorded run, resolved: its run.toml, its machine config and its
/// tables, each read and validated at most once, on first use.
pub struct Run {
    pub spec: RunSpec,
    pub machine: MachineConfig,
    tables: Mutex<BTreeMap<&'static str, Arc<Table>>>,
}

impl Run {
    pub fn new(spec: RunSpec, machine: MachineConfig) -> Self {
        Run {
            spec,
            machine,
            tables: Mutex::new(BTreeMap::new()),
        }
    }
    pub fn dir(&self) -> &Path {
        &self.spec.dir
    }
    pub fn table_path(&self, schema: &TableSchema) -> PathBuf {
        self.spec.dir.join(schema.file_name())
    }
    /// Whether the run has this table's file.
    pub fn has_table(&self, schema: &TableSchema) -> bool {
        self.table_path(schema).is_file()
    }
    /// The table, validated; `Ok(None)` when the run has no such file.
    pub fn table(&self, schema: &'static TableSchema) -> Result<Option<Arc<Table>>, InputError> {
        if !self.has_table(schema) {
            return Ok(None);
        }
        if let Some(t) = self.tables.lock().expect("table cache").get(schema.name) {
            return Ok(Some(t.clone()));
        }
        let t = Arc::new(Table::read(&self.table_path(schema), schema)?);
        self.tables
            .lock()
            .expect("table cache")
            .insert(schema.name, t.clone());
        Ok(Some(t))
    }
    /// The table, which the stage cannot do without.
    pub fn require(&self, schema: &'static TableSchema) -> Result<Arc<Table>, InputError> {
        self.table(schema)?.ok_or_else(|| {
            InputError::new(
                self.table_path(schema),
                format!(
                    "required table `{}` is missing from run `{}`",
                    schema.name, self.spec.id
                ),
            )
        })
    }
}

/// Upstream artifacts of one run: in memory when computed in this process,
/// read from disk on first use when a cached stage produced them earlier.
#[derive(Default)]
pub struct ArtifactStore {
    tables: Mutex<BTreeMap<String, ArtifactSlot>>,
    summaries: Mutex<BTreeMap<String, serde_json::Value>>,
}

enum ArtifactSlot {
    Memory(Arc<RecordBatch>),
    Disk(PathBuf),
}

impl ArtifactStore {
    pub fn insert(&self, name: &str, batch: RecordBatch) {
        self.tables
            .lock()
            .expect("store")
            .insert(name.to_string(), ArtifactSlot::Memory(Arc::new(batch)));
    }
    pub fn insert_on_disk(&self, name: &str, path: PathBuf) {
        self.tables
            .lock()
            .expect("store")
            .insert(name.to_string(), ArtifactSlot::Disk(path));
    }
    pub fn set_summary(&self, stage: &str, summary: serde_json::Value) {
        self.summaries
            .lock()
            .expect("store")
            .insert(stage.to_string(), summary);
    }
    pub fn summary(&self, stage: &str) -> Option<serde_json::Value> {
        self.summaries.lock().expect("store").get(stage).cloned()
    }
    pub fn summaries(&self) -> BTreeMap<String, serde_json::Value> {
        self.summaries.lock().expect("store").clone()
    }
    pub fn has(&self, name: &str) -> bool {
        self.tables.lock().expect("store").contains_key(name)
    }
    pub fn names(&self) -> Vec<String> {
        self.tables.lock().expect("store").keys().cloned().collect()
    }
    /// An artifact by name; `None` if no stage produced it.
    pub fn get(&self, name: &str) -> Result<Option<Arc<RecordBatch>>> {
        let path = {
            let guard = self.tables.lock().expect("store");
            match guard.get(name) {
                None => return Ok(None),
                Some(ArtifactSlot::Memory(b)) => return Ok(Some(b.clone())),
                Some(ArtifactSlot::Disk(p)) => p.clone(),
            }
        };
        let batch = Arc::new(read_parquet(&path)?);
        self.tables
            .lock()
            .expect("store")
            .insert(name.to_string(), ArtifactSlot::Memory(batch.clone()));
        Ok(Some(batch))
    }
    /// An artifact a stage cannot do without.
    pub fn require(&self, name: &str) -> Result<Arc<RecordBatch>> {
        self.get(name)?
            .ok_or_else(|| anyhow::anyhow!("upstream artifact `{name}` was not produced"))
    }
}

/// What a stage sees when it runs on one run.
pub struct StageContext<'a> {
    pub run: &'a Run,
    /// The stage's config section (`[<plugin>.<stage>]` of the pipeline
    /// config), already checked by [`Stage::validate_config`].
    pub config: &'a toml::Table,
    pub artifacts: &'a ArtifactStore,
}

impl StageContext<'_> {
    /// A number from the stage config, with a default.
    pub fn cfg_f64(&self, key: &str, default: f64) -> f64 {
        cfg_f64(self.config, key).unwrap_or(default)
    }
    pub fn cfg_str<'b>(&'b self, key: &str, default: &'b str) -> &'b str {
        self.config
            .get(key)
            .and_then(|v| v.as_str())
            .unwrap_or(default)
    }
    pub fn cfg_bool(&self, key: &str, default: bool) -> bool {
        self.config
            .get(key)
            .and_then(|v| v.as_bool())
            .unwrap_or(default)
    }
}

/// A number in a TOML table (integers accepted).
pub fn cfg_f64(t: &toml::Table, key: &str) -> Option<f64> {
    match t.get(key)? {
        toml::Value::Float(f) => Some(*f),
        toml::Value::Integer(i) => Some(*i as f64),
        _ => None,
    }
}

/// What a stage produced for one run.
#[derive(Debug, Clone, Default)]
pub struct StageOutput {
    /// Artifacts, written as `<name>.parquet`; names must be the stage's
    /// declared [`Stage::writes`].
    pub artifacts: Vec<(String, RecordBatch)>,
    /// A JSON summary (written as `<stage>.json`, printed by `stage --json`,
    /// read by reports).
    pub summary: serde_json::Value,
}

impl StageOutput {
    pub fn new(summary: serde_json::Value) -> Self {
        StageOutput {
            artifacts: Vec::new(),
            summary,
        }
    }
    pub fn with(mut self, name: &str, batch: RecordBatch) -> Self {
        self.artifacts.push((name.to_string(), batch));
        self
    }
}

/// Options of `sparkout stage <name> --flag value ...` without a run.
pub type StageArgs = BTreeMap<String, String>;

/// A step of the DAG. Edges come from what stages declare they read and
/// write, not from a hard-coded order.
pub trait Stage: Send + Sync {
    fn name(&self) -> &'static str;
    /// Bump when the stage's output changes for the same input (cache key).
    fn version(&self) -> u32;
    /// Raw tables of the run this stage reads (their file hashes enter its
    /// cache key).
    fn reads_tables(&self) -> &'static [&'static str];
    /// Artifacts of upstream stages this stage reads (edges of the DAG).
    fn reads_artifacts(&self) -> &'static [&'static str];
    /// Artifacts this stage writes.
    fn writes(&self) -> &'static [&'static str];
    /// One-line description for `--help` listings.
    fn about(&self) -> &'static str {
        ""
    }
    /// Check the config section before anything runs.
    fn validate_config(&self, _config: &toml::Table) -> Result<()> {
        Ok(())
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput>;
    /// Run from command-line options alone (no run directory), when the stage
    /// supports it, e.g. `sparkout stage datum --planes ...`.
    fn run_standalone(&self, _args: &StageArgs) -> Option<Result<serde_json::Value>> {
        None
    }
}

/// A section of a report: a title and a self-contained HTML fragment.
#[derive(Debug, Clone)]
pub struct ReportSection {
    pub title: String,
    pub html: String,
}

/// One machine type.
pub trait MachinePlugin: Send + Sync {
    fn name(&self) -> &'static str;
    /// Alternative sets of tables, one of which a run must have
    /// (CONTRACTS.md §3), e.g. robot: `[["probe"], ["ae", "motion", "plan"]]`.
    fn required_tables(&self) -> Vec<Vec<&'static str>>;
    /// The plugin's stages, in any order (the engine sorts them by edges).
    fn stages(&self) -> Vec<Arc<dyn Stage>>;
    /// Machine configs built into the binary: (machine id, TOML text).
    /// The keys this plugin reads from run.toml `[process]`; any other key
    /// there is a typo and rejects the run. `None` leaves them unchecked.
    fn process_keys(&self) -> Option<&'static [&'static str]> {
        None
    }
    fn builtin_machines(&self) -> Vec<(&'static str, &'static str)> {
        Vec::new()
    }
    /// Physically named composite effects for the diagnosis.
    fn effects(&self) -> Vec<Box<dyn Effect>> {
        Vec::new()
    }
    /// Report sections for one run from its stage summaries and artifacts.
    fn report_sections(&self, _run: &Run, _artifacts: &ArtifactStore) -> Vec<ReportSection> {
        Vec::new()
    }
}

//! The traits everything plugs in by (docs/design.md §3). The engine knows
//! no concrete machine; a plugin knows no other plugin.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use arrow::record_batch::RecordBatch;

use crate::contracts::{read_parquet, MachineConfig, RunSpec, Table, TableSchema};
use crate::effect::Effect;
use crate::error::{InputError, Result};

/// One recorded run, resolved: its run.toml, its machine config and its
/// tables, each read and validated at most once, on first use.
pub struct Run {
    pub spec: RunSpec,
    pub machine: MachineConfig,
    tables: Mutex<BTreeMap<&'static str, Arc<Table>>>,
    /// Tables looked at since the last [`Run::take_reads`]: the engine
    /// checks them against the running stage's [`StageSpec::reads`].
    reads: Mutex<BTreeSet<&'static str>>,
}

impl Run {
    /// A verdict limit (run.toml `[tolerance]`, else the machine config's,
    /// else its documented default).
    pub fn tolerance(&self, key: &str) -> f64 {
        self.spec.tolerance(&self.machine, key)
    }
    pub fn new(spec: RunSpec, machine: MachineConfig) -> Self {
        Run {
            spec,
            machine,
            tables: Mutex::new(BTreeMap::new()),
            reads: Mutex::new(BTreeSet::new()),
        }
    }
    /// The tables looked at since the last call.
    pub fn take_reads(&self) -> BTreeSet<&'static str> {
        std::mem::take(&mut *self.reads.lock().expect("read log"))
    }
    pub fn dir(&self) -> &Path {
        &self.spec.dir
    }
    pub fn table_path(&self, schema: &TableSchema) -> PathBuf {
        self.spec.dir.join(schema.file_name())
    }
    /// Whether the run has this table's file.
    pub fn has_table(&self, schema: &TableSchema) -> bool {
        self.reads.lock().expect("read log").insert(schema.name);
        crate::contracts::input_file::InputFile::exists(&self.table_path(schema))
    }
    /// The table, validated; `Ok(None)` when the run has no such file.
    pub fn table(&self, schema: &'static TableSchema) -> Result<Option<Arc<Table>>, InputError> {
        if !self.has_table(schema) {
            return Ok(None);
        }
        if let Some(t) = self.tables.lock().expect("table cache").get(schema.name) {
            return Ok(Some(t.clone()));
        }
        let t = Arc::new(Table::read_at(
            &self.table_path(schema),
            schema,
            &self.spec.time_origin(),
        )?);
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
    /// Artifacts looked up since the last [`ArtifactStore::take_reads`].
    reads: Mutex<BTreeSet<String>>,
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
    /// The stages that left a summary, by name.
    pub fn summary_names(&self) -> Vec<String> {
        self.summaries
            .lock()
            .expect("store")
            .keys()
            .cloned()
            .collect()
    }
    pub fn summaries(&self) -> BTreeMap<String, serde_json::Value> {
        self.summaries.lock().expect("store").clone()
    }
    /// A stage's summary read through the serde type that wrote it
    /// (`StageOutput::typed`): `None` when the stage has not run, an error
    /// naming the stage when the summary does not have the type's shape.
    pub fn summary_as<T: serde::de::DeserializeOwned>(&self, stage: &str) -> Option<Result<T>> {
        let v = self.summary(stage)?;
        Some(
            serde_json::from_value(v)
                .map_err(|e| crate::err!("summary of stage `{stage}` ({stage}.json): {e}")),
        )
    }
    /// The artifacts looked up since the last call.
    pub fn take_reads(&self) -> BTreeSet<String> {
        std::mem::take(&mut *self.reads.lock().expect("read log"))
    }
    pub fn has(&self, name: &str) -> bool {
        self.reads
            .lock()
            .expect("read log")
            .insert(name.to_string());
        self.tables.lock().expect("store").contains_key(name)
    }
    pub fn names(&self) -> Vec<String> {
        self.tables.lock().expect("store").keys().cloned().collect()
    }
    /// An artifact by name; `None` if no stage produced it.
    pub fn get(&self, name: &str) -> Result<Option<Arc<RecordBatch>>> {
        self.reads
            .lock()
            .expect("read log")
            .insert(name.to_string());
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
            .ok_or_else(|| crate::err!("upstream artifact `{name}` was not produced"))
    }
}

/// What a stage sees when it runs on one run.
pub struct StageContext<'a> {
    pub run: &'a Run,
    /// The stage's config section (`[<plugin>.<stage>]` of the pipeline
    /// config), read and checked once per batch by the engine
    /// ([`Stage::read_config`]); the stage takes its typed value with
    /// [`StageContext::section`].
    pub config: &'a crate::config_check::CheckedSection,
    pub artifacts: &'a ArtifactStore,
    /// `run --augment MODEL`, for a stage whose spec sets
    /// `reads_augmented_model` (None otherwise, and on a night without it).
    pub augment: Option<&'a crate::augment::AugmentedModel>,
}

impl StageContext<'_> {
    /// The stage's config section as its [`Section`] struct, as the engine
    /// read and checked it before any run (absent keys hold the defaults):
    /// nothing is parsed here. Asking for another struct than the one the
    /// stage's spec declares is a bug in the plugin, and an error.
    ///
    /// [`Section`]: crate::config_check::Section
    pub fn section<T: crate::config_check::Section>(&self) -> Result<&T> {
        self.config.get::<T>().ok_or_else(|| {
            crate::err!(
                "stage config is not a `{}` (a bug in the plugin: StageSpec.config declares another struct)",
                std::any::type_name::<T>()
            )
        })
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
    /// A summary written through its serde type (the same type a reader
    /// gets back with [`ArtifactStore::summary_as`]).
    pub fn typed<T: serde::Serialize>(summary: &T) -> Result<Self> {
        Ok(StageOutput::new(serde_json::to_value(summary)?))
    }
    pub fn with(mut self, name: &str, batch: RecordBatch) -> Self {
        self.artifacts.push((name.to_string(), batch));
        self
    }
}

/// Options of `sparkout stage <name> --flag value ...` without a run.
pub type StageArgs = BTreeMap<String, String>;

/// What a stage is, as data: the engine takes the DAG's
/// edges, the cache key and `--help` listings from it and checks it when a
/// plugin is registered ([`StageSpec::check`]) and while the stage runs (a
/// table or artifact read that the spec does not declare is an error, so the
/// cache key cannot miss an input).
#[derive(Debug, Clone, Copy)]
pub struct StageSpec {
    pub name: &'static str,
    /// Bump when the stage's output changes for the same input (cache key).
    pub version: u32,
    /// Raw tables of the run this stage reads (their file hashes enter its
    /// cache key).
    pub reads: &'static [&'static TableSchema],
    /// Artifacts of upstream stages this stage reads (edges of the DAG).
    pub reads_artifacts: &'static [&'static str],
    /// Artifacts this stage writes.
    pub writes: &'static [&'static str],
    /// The stage puts an augmented model's effects into its physics
    /// (`sparkout run --augment`): it gets the model in
    /// [`StageContext::augment`], and the model's hash enters its cache key.
    pub reads_augmented_model: bool,
    /// One-line description for `--help` listings.
    pub about: &'static str,
    /// The stage's config section (`[<plugin>.<stage>]`) as its
    /// [`Section`](crate::config_check::Section) struct: read and checked
    /// once before anything runs (the default [`Stage::read_config`]
    /// applies it),
    /// its defaults tested against configs/nightly.toml; its effective
    /// config (the checked value, serialised canonically) enters the cache
    /// key.
    pub config: crate::config_check::SectionCheck,
}

impl StageSpec {
    /// The spec on its own: a name, no input declared twice, artifact names
    /// that are file stems, a stage that does not read what it writes.
    pub fn check(&self) -> Result<()> {
        let name = self.name;
        let stem = |s: &str| {
            !s.is_empty()
                && s.chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
        };
        if !stem(name) {
            crate::bail!("stage name `{name}` must be letters, digits, `_` or `-`");
        }
        let mut seen = std::collections::BTreeSet::new();
        for t in self.reads {
            if !seen.insert(t.name) {
                crate::bail!("stage `{name}` declares table `{}` twice", t.name);
            }
        }
        if let Some(k) = (self.config.undeclared_checks)().first() {
            crate::bail!(
                "stage `{name}` checks config key `{k}`, which its section struct does not have"
            );
        }
        for list in [self.reads_artifacts, self.writes] {
            let mut seen = std::collections::BTreeSet::new();
            for a in list {
                if !stem(a) || !seen.insert(*a) {
                    crate::bail!(
                        "stage `{name}`: artifact `{a}` is declared twice or is not a file stem"
                    );
                }
            }
        }
        if let Some(a) = self
            .reads_artifacts
            .iter()
            .find(|a| self.writes.contains(a))
        {
            crate::bail!("stage `{name}` reads its own output `{a}`");
        }
        Ok(())
    }
    pub fn reads_table(&self, table: &str) -> bool {
        self.reads.iter().any(|t| t.name == table)
    }
    /// What the stage looked at while it ran ([`Run::take_reads`],
    /// [`ArtifactStore::take_reads`]) against what it declares: an
    /// undeclared input would be missing from its cache key.
    pub fn check_reads(&self, tables: &BTreeSet<&str>, artifacts: &BTreeSet<String>) -> Result<()> {
        if let Some(t) = tables.iter().find(|t| !self.reads_table(t)) {
            crate::bail!(
                "stage `{}` read table `{t}`, which its StageSpec.reads does not declare (a bug in the plugin: the cache key would miss it)",
                self.name
            );
        }
        if let Some(a) = artifacts
            .iter()
            .find(|a| !self.reads_artifacts.contains(&a.as_str()))
        {
            crate::bail!(
                "stage `{}` read artifact `{a}`, which its StageSpec.reads_artifacts does not declare (a bug in the plugin: the DAG edge and cache key would miss it)",
                self.name
            );
        }
        Ok(())
    }
}

/// A step of the DAG. Edges come from what stages declare ([`StageSpec`]),
/// not from a hard-coded order.
pub trait Stage: Send + Sync {
    /// What the stage reads and writes; a `const` in the stage's file.
    fn spec(&self) -> &'static StageSpec;
    /// Read and check the config section before anything runs, as the
    /// spec's `config` says (an unknown key or a bad value is an error
    /// naming the key); the engine does it once per batch and hands the
    /// typed value to every run ([`StageContext::section`]).
    fn read_config(&self, config: &toml::Table) -> Result<crate::config_check::CheckedSection> {
        self.spec().config.read(config)
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput>;
    /// Run from command-line options alone (no run directory), when the stage
    /// supports it, e.g. `sparkout stage datum --planes ...`.
    fn run_standalone(&self, _args: &StageArgs) -> Option<Result<serde_json::Value>> {
        None
    }
    /// Human-readable text of a run-less result, printed instead of the
    /// JSON when `--json` is not given; `None`: the JSON is the output.
    fn console(&self, _result: &serde_json::Value) -> Option<String> {
        None
    }
}

/// Shorthands for the spec's fields (callers hold `Arc<dyn Stage>`).
impl dyn Stage {
    pub fn name(&self) -> &'static str {
        self.spec().name
    }
    pub fn version(&self) -> u32 {
        self.spec().version
    }
    pub fn reads_artifacts(&self) -> &'static [&'static str] {
        self.spec().reads_artifacts
    }
    pub fn writes(&self) -> &'static [&'static str] {
        self.spec().writes
    }
    pub fn about(&self) -> &'static str {
        self.spec().about
    }
}

/// A section of a report: a title and a self-contained HTML fragment.
#[derive(Debug, Clone)]
pub struct ReportSection {
    pub title: String,
    pub html: String,
}

/// run.toml `[process]` keys with what each value must be
/// ([`MachinePlugin::process_keys`]).
pub type ProcessKeys = &'static [(&'static str, crate::config_check::Check)];

/// One machine type.
pub trait MachinePlugin: Send + Sync {
    fn name(&self) -> &'static str;
    /// The tables this machine type records beyond the shared ones (the AE,
    /// motion and thermal logs, `contracts::SHARED_TABLES`): their columns,
    /// types and plausible ranges. The engine registers them
    /// (`contracts::TableRegistry`); a name may be declared once.
    fn tables(&self) -> &'static [TableSchema] {
        &[]
    }
    /// Alternative sets of tables, one of which a run must have
    /// (docs/formats.md §5), e.g. robot: `[["probe"], ["ae", "motion", "plan"]]`.
    fn required_tables(&self) -> Vec<Vec<&'static str>>;
    /// The fewest rows a present table must have for the plugin's methods,
    /// as (table, rows); fewer rejects the run naming the file before any
    /// stage runs (`validate-input` says so too).
    fn min_rows(&self) -> &'static [(&'static str, usize)] {
        &[]
    }
    /// The plugin's stages, in any order (the engine sorts them by edges).
    fn stages(&self) -> Vec<Arc<dyn Stage>>;
    /// Stages with only a run-less form (`sparkout stage NAME --flags`):
    /// found by name like the others but never part of a run's DAG.
    fn standalone_stages(&self) -> Vec<Arc<dyn Stage>> {
        Vec::new()
    }
    /// The keys this plugin reads (or the generator records) in run.toml
    /// `[process]`, each with its valid range: any other key is a typo and
    /// a value of the wrong type or outside its range is impossible; either
    /// rejects the run naming run.toml and the key. docs/formats.md's table
    /// of ranges is tested against these. A plugin that reads no key
    /// declares none, and any key in its runs' `[process]` is refused.
    fn process_keys(&self) -> ProcessKeys {
        &[]
    }
    /// Machine configs built into the binary: (machine id, TOML text).
    fn builtin_machines(&self) -> Vec<(&'static str, &'static str)> {
        Vec::new()
    }
    /// The sections of this plugin's machine config that its stages read,
    /// each as its serde struct (`("wheel", SectionCheck::of::<Wheel>())`):
    /// read and checked once when a run's machine is loaded, an error
    /// naming the machine config and `<section>.<key>`; a stage takes the
    /// value with [`MachineConfig::section`]. Every key of a machine config
    /// is also checked against the built-in machines (names, types,
    /// ranges), declared or not.
    fn machine_sections(&self) -> &'static [(&'static str, crate::config_check::SectionCheck)] {
        &[]
    }
    /// Physically named composite effects for the diagnosis. They apply
    /// only to the observables this plugin produces.
    fn effects(&self) -> Vec<Box<dyn Effect>> {
        Vec::new()
    }
    /// Names of the observables this plugin's `observe` stage writes; a
    /// trailing `*` matches by prefix (`touch_normal*`). `sparkout diagnose
    /// --plugin NAME` scopes the plugin's composites with it; the fleet
    /// batch scopes them by the runs each plugin actually processed.
    fn observables(&self) -> Vec<&'static str> {
        Vec::new()
    }
    /// Report sections for one run from its stage summaries and artifacts.
    fn report_sections(&self, _run: &Run, _artifacts: &ArtifactStore) -> Vec<ReportSection> {
        Vec::new()
    }
    /// The run's key figures for the verdict at the top of its page
    /// (`crate::verdict` judges them; none leaves the page at CHECK).
    fn verdicts(&self, _run: &Run, _artifacts: &ArtifactStore) -> Vec<crate::verdict::Verdict> {
        Vec::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::contracts::schema::{MOTION, THERMAL};

    const SPEC: StageSpec = StageSpec {
        name: "removal",
        version: 1,
        reads: &[&THERMAL, &MOTION],
        reads_artifacts: &["plan"],
        writes: &["removal"],
        reads_augmented_model: false,
        about: "",
        config: crate::config_check::SectionCheck::of::<crate::config_check::NoKeys>(),
    };

    #[test]
    fn a_spec_is_checked_on_its_own() {
        SPEC.check().unwrap();
        let twice = StageSpec {
            reads: &[&THERMAL, &THERMAL],
            ..SPEC
        };
        assert!(twice.check().unwrap_err().to_string().contains("twice"));
        let own = StageSpec {
            reads_artifacts: &["removal"],
            ..SPEC
        };
        assert!(own.check().unwrap_err().to_string().contains("own output"));
        let bad_name = StageSpec {
            writes: &["a/b"],
            ..SPEC
        };
        assert!(bad_name.check().is_err());
    }

    #[test]
    fn reads_outside_the_spec_are_refused() {
        let tables: BTreeSet<&str> = ["thermal"].into();
        let artifacts: BTreeSet<String> = ["plan".to_string()].into();
        SPEC.check_reads(&tables, &artifacts).unwrap();
        let e = SPEC
            .check_reads(&["probe"].into(), &artifacts)
            .unwrap_err()
            .to_string();
        assert!(e.contains("read table `probe`"), "{e}");
        let e = SPEC
            .check_reads(&tables, &["touches".to_string()].into())
            .unwrap_err()
            .to_string();
        assert!(e.contains("read artifact `touches`"), "{e}");
    }

    #[test]
    fn the_artifact_store_logs_what_was_looked_up() {
        let store = ArtifactStore::default();
        assert!(store.get("plan").unwrap().is_none());
        assert!(!store.has("removal"));
        let seen = store.take_reads();
        assert_eq!(seen.into_iter().collect::<Vec<_>>(), ["plan", "removal"]);
        assert!(store.take_reads().is_empty());
    }
}

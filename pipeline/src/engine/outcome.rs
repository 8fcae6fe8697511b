//! What a batch reports: progress callbacks, each run's result, the
//! failures (file, column, row and what to do) and the fleet's outcome.

use super::*;

/// Receives progress from a long batch (the CLI draws a bar or logs lines).
pub trait Progress: Sync {
    fn start(&self, _runs: usize) {}
    fn run_done(&self, _label: &str, _ok: bool, _computed: usize, _cached: usize) {}
    fn message(&self, _msg: &str) {}
}

/// Progress that says nothing (tests, library use).
pub struct Quiet;
impl Progress for Quiet {}

/// A rejected run, as failures.json lists it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Failure {
    pub run_dir: String,
    pub machine: Option<String>,
    pub run: Option<String>,
    pub stage: Option<String>,
    pub file: Option<String>,
    pub column: Option<String>,
    pub row: Option<usize>,
    pub error: String,
}

impl Failure {
    pub(super) fn from_error(
        run_dir: &Path,
        spec: Option<&RunSpec>,
        stage: Option<&str>,
        e: &anyhow::Error,
    ) -> Self {
        let input = e.chain().find_map(|c| c.downcast_ref::<InputError>());
        Failure {
            run_dir: run_dir.display().to_string(),
            machine: spec.map(|s| s.machine.clone()),
            run: spec.map(|s| s.id.clone()),
            stage: stage.map(|s| s.to_string()),
            file: input.map(|i| i.file.display().to_string()),
            column: input.and_then(|i| i.column.clone()),
            row: input.and_then(|i| i.row),
            error: format!("{e:#}"),
        }
    }
}

/// One run that went through.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RunResult {
    pub machine: String,
    pub run: String,
    pub plugin: String,
    pub run_dir: String,
    pub out_dir: String,
    pub inputs: BTreeMap<String, String>,
    pub stages: Vec<StageRecord>,
    #[serde(skip)]
    pub observations: Option<PathBuf>,
}

impl RunResult {
    pub fn computed(&self) -> usize {
        self.stages.iter().filter(|s| !s.cached).count()
    }
    pub fn cached(&self) -> usize {
        self.stages.iter().filter(|s| s.cached).count()
    }
}

/// What a whole batch did.
#[derive(Debug, Clone, Serialize)]
pub struct FleetOutcome {
    pub out_dir: PathBuf,
    pub runs: Vec<RunResult>,
    pub failures: Vec<Failure>,
    /// Fleet-level steps (observations, diagnose, report) with their keys.
    pub fleet: Vec<StageRecord>,
    pub report: Option<PathBuf>,
    pub diagnosis: Option<PathBuf>,
}

impl FleetOutcome {
    /// Before the fleet steps; failures in run-directory order.
    pub(super) fn new(
        out: &Path,
        runs: Vec<RunResult>,
        mut failures: Vec<Failure>,
    ) -> FleetOutcome {
        failures.sort_by(|a, b| a.run_dir.cmp(&b.run_dir));
        FleetOutcome {
            out_dir: out.to_path_buf(),
            runs,
            failures,
            fleet: Vec::new(),
            report: None,
            diagnosis: None,
        }
    }
    pub fn stages_computed(&self) -> usize {
        self.runs.iter().map(|r| r.computed()).sum::<usize>()
            + self.fleet.iter().filter(|s| !s.cached).count()
    }
    pub fn stages_cached(&self) -> usize {
        self.runs.iter().map(|r| r.cached()).sum::<usize>()
            + self.fleet.iter().filter(|s| s.cached).count()
    }
    /// 0 all good, 2 some runs failed (1 is for usage/config errors, which
    /// never get this far).
    pub fn exit_code(&self) -> i32 {
        if self.failures.is_empty() {
            0
        } else {
            2
        }
    }
}

/// A problem `validate-input` found.
#[derive(Debug, Clone, Serialize)]
pub struct Problem {
    pub run_dir: String,
    pub message: String,
}

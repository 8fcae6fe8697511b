//! What a batch reports: progress callbacks, each run's result, the
//! failures (file, column, row and what to do) and the fleet's outcome.
//! Data only, below the engine that fills it and the reports that show it.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::contracts::RunSpec;

/// What one stage left on disk for one run (the per-run cache file records
/// these; manifest.json repeats them).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageRecord {
    pub stage: String,
    pub version: u32,
    pub key: String,
    /// Output file name → blake3 of its bytes.
    pub files: BTreeMap<String, String>,
    #[serde(default)]
    pub cached: bool,
}

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
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
    pub fn from_error(
        run_dir: &Path,
        spec: Option<&RunSpec>,
        stage: Option<&str>,
        e: &crate::Error,
    ) -> Self {
        let input = e.input();
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
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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

/// Layout version of manifest.json.
pub const MANIFEST_VERSION: u32 = 1;

/// manifest.json (docs/formats.md): written last, so its presence means the
/// batch completed; the provenance of everything under the output. Read
/// back through this type ([`Manifest::read`]).
///
/// Its keys are in alphabetical order at every level, the run and stage
/// records included (which the per-run cache files and shard.json write in
/// their own field order): [`Manifest::write`] serialises it through
/// serde_json's sorted map, as it always has been.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// The whole resolved pipeline config (the TOML tables as JSON),
    /// passed through as it is.
    pub config: serde_json::Value,
    pub config_source: String,
    /// Number of rejected runs (failures.json lists them).
    pub failures: usize,
    /// The fleet steps (observations, diagnosis, reports, index).
    pub fleet: Vec<StageRecord>,
    pub input_root: String,
    pub runs: Vec<RunResult>,
    pub sparkout_version: String,
    pub stages_cached: usize,
    pub stages_computed: usize,
    pub version: u32,
}

impl Manifest {
    /// Writes `path` atomically, keys sorted at every level.
    pub fn write(&self, path: &Path) -> crate::Result<()> {
        let sorted = serde_json::to_value(self)?;
        crate::files::write::write_json_atomic(path, &sorted)
    }

    /// A manifest.json as [`Manifest::write`] wrote it.
    pub fn read(path: &Path) -> crate::Result<Manifest> {
        crate::files::json::read_json(path)
    }
}

/// The failures.json of an output directory (`[]` when none).
pub fn read_failures(path: &Path) -> crate::Result<Vec<Failure>> {
    crate::files::json::read_json(path)
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
    /// The night the batch is, as the pages head it (set by the fleet
    /// steps).
    #[serde(skip)]
    pub night: Night,
}

/// The date of a night's batch: given with `run --history DIR --night D`,
/// else the latest date of the runs' `[run].started`; never the wall clock
/// (the pages are byte-identical across reruns).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Night {
    /// YYYY-MM-DD; None when nothing dates the runs.
    pub date: Option<String>,
    /// The earliest date of the runs' `[run].started` (when the night was
    /// dated from the runs and they span several dates).
    pub first: Option<String>,
    /// Given with `--night` rather than read from the runs.
    pub given: bool,
}

impl Night {
    /// The night given with `--night`, else dated from the runs' starts
    /// (the latest; malformed dates are ignored).
    pub fn of(given: Option<&str>, runs: &[RunResult]) -> Night {
        if let Some(d) = given {
            return Night {
                date: Some(d.to_string()),
                first: None,
                given: true,
            };
        }
        let days: BTreeSet<String> = runs
            .iter()
            .filter_map(|r| RunSpec::load(Path::new(&r.run_dir)).ok()?.started)
            .filter_map(|s| s.get(..10).map(str::to_string))
            .filter(|d| check_night(d).is_ok())
            .collect();
        let (first, last) = (days.first().cloned(), days.last().cloned());
        Night {
            first: first.filter(|f| Some(f) != last.as_ref()),
            date: last,
            given: false,
        }
    }
}

/// `YYYY-MM-DD`, checked.
pub fn check_night(night: &str) -> crate::error::Result<()> {
    let b = night.as_bytes();
    let ok = b.len() == 10
        && b[4] == b'-'
        && b[7] == b'-'
        && b.iter()
            .enumerate()
            .all(|(i, c)| i == 4 || i == 7 || c.is_ascii_digit())
        && (1..=12).contains(&night[5..7].parse::<u32>().unwrap_or(0))
        && (1..=31).contains(&night[8..10].parse::<u32>().unwrap_or(0));
    if !ok {
        crate::bail!("night `{night}`: expected a date YYYY-MM-DD, e.g. 2026-11-25");
    }
    Ok(())
}

impl FleetOutcome {
    /// Before the fleet steps; failures in run-directory order.
    pub fn new(out: &Path, runs: Vec<RunResult>, mut failures: Vec<Failure>) -> FleetOutcome {
        failures.sort_by(|a, b| a.run_dir.cmp(&b.run_dir));
        FleetOutcome {
            out_dir: out.to_path_buf(),
            runs,
            failures,
            fleet: Vec::new(),
            report: None,
            diagnosis: None,
            night: Night::default(),
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

#[cfg(test)]
mod tests {
    use super::*;

    fn record(stage: &str, cached: bool) -> StageRecord {
        StageRecord {
            stage: stage.into(),
            version: 3,
            key: "ab12".into(),
            files: [(format!("{stage}.json"), "cd34".to_string())].into(),
            cached,
        }
    }

    fn run() -> RunResult {
        RunResult {
            machine: "kr16-lab".into(),
            run: "r0001".into(),
            plugin: "robot".into(),
            run_dir: "runs/kr16-lab/r0001".into(),
            out_dir: "out/kr16-lab/r0001".into(),
            inputs: [("probe".to_string(), "ef56".to_string())].into(),
            stages: vec![record("ingest", false), record("datum", true)],
            observations: None,
        }
    }

    /// manifest.json, failures.json and the cache's stage records: written,
    /// read back through the same types, equal.
    #[test]
    fn the_batch_files_round_trip_through_their_types() {
        let d = tempfile::tempdir().unwrap();
        let m = Manifest {
            config: serde_json::json!({"diagnose": {"folds": 5, "alpha": 0.01}}),
            config_source: "built-in configs/nightly.toml".into(),
            failures: 1,
            fleet: vec![record("diagnose", false)],
            input_root: "runs".into(),
            runs: vec![run()],
            sparkout_version: "0.1.0".into(),
            stages_cached: 1,
            stages_computed: 2,
            version: MANIFEST_VERSION,
        };
        let path = d.path().join("manifest.json");
        m.write(&path).unwrap();
        assert_eq!(Manifest::read(&path).unwrap(), m);
        // Sorted at every level: a run record's `inputs` before `machine`,
        // a stage record's `cached` before `stage`, as manifest.json has
        // always been.
        let text = std::fs::read_to_string(&path).unwrap();
        let at = |k: &str| text.find(&format!("\"{k}\":")).unwrap();
        assert!(at("config") < at("config_source") && at("sparkout_version") < at("stages_cached"));
        assert!(text.rfind("\"version\":") > Some(at("stages_computed")));
        assert!(
            at("inputs") < at("machine") && at("cached") < at("stage"),
            "{text}"
        );

        let failures = vec![Failure {
            run_dir: "runs/kr16-lab/r0003".into(),
            machine: Some("kr16-lab".into()),
            run: Some("r0003".into()),
            stage: None,
            file: Some("runs/kr16-lab/r0003/probe.parquet".into()),
            column: Some("z_mm".into()),
            row: Some(17),
            error: "NaN in a required column".into(),
        }];
        let path = d.path().join("failures.json");
        crate::files::write::write_json_atomic(&path, &failures).unwrap();
        assert_eq!(read_failures(&path).unwrap(), failures);
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.contains("\"stage\": null"), "{text}");

        let records = vec![record("ingest", false), record("datum", true)];
        let path = d.path().join(crate::files::RUN_CACHE_FILE);
        crate::files::write::write_json_atomic(&path, &records).unwrap();
        let back: Vec<StageRecord> = crate::files::json::read_json(&path).unwrap();
        assert_eq!(back, records);
    }
}

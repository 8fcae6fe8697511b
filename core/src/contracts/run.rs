//! run.toml (docs/formats.md §3) and machine configs.

use crate::values::toml_f64;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::config_check::{read_section, Check, Section};
use crate::error::{ConfigError, InputError};

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AeKind {
    Raw,
    Rms,
}

/// `[ae]` of run.toml.
#[derive(Debug, Clone, serde::Serialize)]
pub struct AeSpec {
    pub sample_rate_hz: f64,
    /// `[ae].kind`, `raw` when the file does not say.
    pub kind: AeKind,
    /// Whether run.toml wrote `kind` (a reader may then guess it from the
    /// signal instead of taking the default).
    #[serde(skip)]
    pub kind_given: bool,
    pub clock_offset_s: f64,
}

/// A parsed, checked run.toml.
#[derive(Debug, Clone)]
pub struct RunSpec {
    /// The run directory.
    pub dir: PathBuf,
    pub id: String,
    pub machine: String,
    pub plugin: String,
    pub started: Option<String>,
    /// `[process]`: plugin-specific parameters.
    pub process: toml::Table,
    pub ae: Option<AeSpec>,
    /// An inline `[machine]` table, if the run carries its own machine
    /// config: a table of sections (`[machine.<section>]`), checked like a
    /// machine config file when the run is opened ([`MachineResolver::inline`]).
    pub inline_machine: Option<toml::Table>,
    /// `[replay]`: where a run recorded by `sparkout replay --record` came
    /// from (provenance; no stage reads it).
    pub replay: Option<ReplayProvenance>,
    /// `[tolerance]`: the run's own verdict limits (checked keys).
    pub tolerance: BTreeMap<String, f64>,
    /// The file's text (hashed into cache keys).
    pub text: String,
}

/// `[run]` as a [`Section`]: unknown keys and wrong types are refused by
/// the shared reader; the three names are then required non-empty and
/// checked as path components, `started` as a date-time.
#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RunSection {
    id: Option<String>,
    machine: Option<String>,
    plugin: Option<String>,
    /// A TOML date-time or a string holding one ([`parse_started`]).
    started: Option<toml::Value>,
}

impl Section for RunSection {}

/// `[ae]` as a [`Section`] (only with ae.parquet).
#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
struct AeSection {
    sample_rate_hz: Option<f64>,
    kind: Option<AeKind>,
    clock_offset_s: f64,
}

impl Section for AeSection {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("sample_rate_hz", Check::Positive),
        ("kind", Check::OneOf(&["raw", "rms"])),
        ("clock_offset_s", Check::Number),
    ];
    fn validate(&self) -> crate::Result<()> {
        if self.sample_rate_hz.is_none() {
            return Err(ConfigError::Missing {
                key: "sample_rate_hz".into(),
            }
            .into());
        }
        Ok(())
    }
}

/// `[replay]` of run.toml: the provenance `sparkout replay --record`
/// writes into the run it records (replay/record.rs), read and checked like
/// the other sections.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReplayProvenance {
    /// The replayed run's directory.
    pub source_run: Option<String>,
    /// The compensation table applied, if any.
    pub compensation: Option<String>,
    /// The CAN bus (an interface, or a log file for a dry run).
    pub bus: Option<String>,
    pub cycle_s: Option<f64>,
    pub counts_per_mm: Option<f64>,
    pub cycles_streamed: Option<u64>,
    pub rows_recorded: Option<u64>,
    /// How the replay ended.
    pub outcome: Option<String>,
    /// The source's tables copied beside the recorded motion.
    pub copied_tables: Option<Vec<String>>,
}

impl Section for ReplayProvenance {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("cycle_s", Check::Positive),
        ("counts_per_mm", Check::Positive),
        ("cycles_streamed", Check::WholeIn(0, i64::MAX)),
        ("rows_recorded", Check::WholeIn(0, i64::MAX)),
    ];
}

/// A section of a config file read as its [`Section`] struct, an error
/// naming the file, the section and the key (as the column
/// `<section>.<key>`).
pub fn read_file_section<T: Section>(
    path: &Path,
    name: &str,
    value: &toml::Value,
) -> Result<T, InputError> {
    let table = value
        .as_table()
        .ok_or_else(|| InputError::new(path, format!("[{name}] must be a table")).column(name))?;
    read_section::<T>(table).map_err(|e| {
        let column = e
            .config()
            .and_then(|c| c.key())
            .map_or_else(|| name.to_string(), |k| format!("{name}.{k}"));
        InputError::new(path, format!("[{name}]: {e:#}")).column(column)
    })
}

/// A required name of `[run]`: present and not blank.
fn required_name(path: &Path, key: &str, value: Option<String>) -> Result<String, InputError> {
    match value {
        Some(s) if !s.trim().is_empty() => Ok(s),
        Some(_) => Err(
            InputError::new(path, format!("[run].{key} must be a non-empty string"))
                .column(format!("run.{key}")),
        ),
        None => Err(
            InputError::new(path, format!("required key [run].{key} is missing"))
                .column(format!("run.{key}")),
        ),
    }
}

/// `[run].started`: a TOML date-time (`2026-11-20T08:00:00Z`) or a string
/// holding one (RFC 3339). A date alone is accepted; "yesterday" is not —
/// the report and the provenance would carry it as if it were a time.
fn parse_started(path: &Path, v: &toml::Value) -> Result<String, InputError> {
    let bad = |found: String| {
        InputError::new(
            path,
            format!(
                "[run].started must be a date-time like 2026-11-20T08:00:00Z (RFC 3339), found {found}"
            ),
        )
        .column("run.started")
    };
    let dt = match v {
        toml::Value::Datetime(d) => *d,
        toml::Value::String(s) => s
            .trim()
            .parse::<toml::value::Datetime>()
            .map_err(|_| bad(format!("\"{s}\"")))?,
        other => return Err(bad(format!("a {}", other.type_str()))),
    };
    if dt.date.is_none() {
        return Err(bad(format!("\"{dt}\" (no date)")));
    }
    Ok(dt.to_string())
}

/// The sections of run.toml (docs/formats.md §3).
/// `[replay]` is the provenance `sparkout replay --record` writes;
/// `[tolerance]` the limits of the run page's verdict (tolerance.rs).
pub const RUN_TOML_SECTIONS: [&str; 6] = ["run", "process", "ae", "machine", "replay", "tolerance"];

impl RunSpec {
    pub const FILE: &'static str = "run.toml";

    /// Load `<dir>/run.toml`.
    pub fn load(dir: &Path) -> Result<RunSpec, InputError> {
        let path = dir.join(Self::FILE);
        let text = std::fs::read_to_string(&path).map_err(|e| {
            InputError::new(
                &path,
                format!(
                    "cannot read run.toml ({e}); every run directory needs one (docs/formats.md)"
                ),
            )
        })?;
        Self::parse(dir, &text)
    }

    pub fn parse(dir: &Path, text: &str) -> Result<RunSpec, InputError> {
        let path = dir.join(Self::FILE);
        let doc: toml::Table = text
            .parse()
            .map_err(|e| InputError::new(&path, format!("not valid TOML: {e}")))?;
        // A typo'd section (`[proces]`) would silently drop its keys.
        for (k, v) in &doc {
            if !RUN_TOML_SECTIONS.contains(&k.as_str()) {
                return Err(InputError::new(
                    &path,
                    format!(
                        "unknown {} `{k}` (run.toml has the sections {})",
                        if v.is_table() {
                            "section"
                        } else {
                            "top-level key"
                        },
                        RUN_TOML_SECTIONS.map(|s| format!("[{s}]")).join(", ")
                    ),
                )
                .column(k.clone()));
            }
        }
        let run: RunSection = match doc.get("run") {
            Some(v) => read_file_section(&path, "run", v)?,
            None => return Err(InputError::new(&path, "missing the [run] table").column("run")),
        };
        let id = required_name(&path, "id", run.id)?;
        let machine = required_name(&path, "machine", run.machine)?;
        let plugin = required_name(&path, "plugin", run.plugin)?;
        // Names become output path components (`<out>/<machine>/<id>`) and
        // machine config file names: checked here, at the edge.
        for (key, value) in [("id", &id), ("machine", &machine), ("plugin", &plugin)] {
            super::names::check_name(&format!("[run].{key}"), value)
                .map_err(|m| InputError::new(&path, m).column(format!("run.{key}")))?;
        }
        let started = match &run.started {
            None => None,
            Some(v) => Some(parse_started(&path, v)?),
        };
        let process = match doc.get("process") {
            None => toml::Table::new(),
            Some(toml::Value::Table(t)) => t.clone(),
            Some(_) => {
                return Err(InputError::new(&path, "[process] must be a table").column("process"))
            }
        };
        let ae = match doc.get("ae") {
            None => None,
            Some(v) => {
                let t: AeSection = read_file_section(&path, "ae", v)?;
                Some(AeSpec {
                    sample_rate_hz: t.sample_rate_hz.unwrap_or_default(),
                    kind: t.kind.unwrap_or(AeKind::Raw),
                    kind_given: t.kind.is_some(),
                    clock_offset_s: t.clock_offset_s,
                })
            }
        };
        let inline_machine = match doc.get("machine") {
            None => None,
            Some(toml::Value::Table(t)) => {
                // Each key is a section of a machine config; its keys are
                // checked against the plugin's machines when the run opens.
                if let Some((k, _)) = t.iter().find(|(_, v)| !v.is_table()) {
                    return Err(InputError::new(
                        &path,
                        format!(
                            "[machine].{k}: the inline [machine] table holds the sections of a machine config, each a table ([machine.{k}] …), e.g. [machine.machine] id = \"{machine}\""
                        ),
                    )
                    .column(format!("machine.{k}")));
                }
                Some(t.clone())
            }
            Some(_) => {
                return Err(InputError::new(
                    &path,
                    "[machine] must be a table (an inline machine config: [machine.machine], [machine.<section>] …)",
                )
                .column("machine"))
            }
        };
        let replay = match doc.get("replay") {
            None => None,
            Some(v) => Some(read_file_section::<ReplayProvenance>(&path, "replay", v)?),
        };
        let tolerance = match doc.get("tolerance") {
            None => BTreeMap::new(),
            Some(t) => super::tolerance::check_tolerance(t)
                .map_err(|(key, msg)| InputError::new(&path, msg).column(key))?,
        };
        Ok(RunSpec {
            dir: dir.to_path_buf(),
            id,
            machine,
            plugin,
            started,
            process,
            ae,
            inline_machine,
            replay,
            tolerance,
            text: text.to_string(),
        })
    }

    pub fn run_toml_path(&self) -> PathBuf {
        self.dir.join(Self::FILE)
    }

    /// What timestamps in this run's tables count from: `[run].started`
    /// (docs/formats.md: `t_s` is seconds since the run's start).
    pub fn time_origin(&self) -> super::TimeOrigin {
        match self
            .started
            .as_deref()
            .and_then(super::convert::parse_datetime_unix_s)
        {
            Some(t0) => super::TimeOrigin::UnixS(t0),
            None => super::TimeOrigin::Missing,
        }
    }

    /// A verdict limit: the run's `[tolerance]`, else the machine config's,
    /// else the documented default (tolerance.rs).
    pub fn tolerance(&self, machine: &MachineConfig, key: &str) -> f64 {
        self.tolerance
            .get(key)
            .copied()
            .or_else(|| machine.tolerance.get(key).copied())
            .or_else(|| super::tolerance::tolerance_default(key))
            .unwrap_or(f64::NAN)
    }

    /// A number from `[process]`, with a default.
    pub fn process_f64(&self, key: &str, default: f64) -> f64 {
        self.process.get(key).and_then(toml_f64).unwrap_or(default)
    }
}

/// A resolved machine config: where it came from, its TOML and, once it
/// is loaded for a run ([`super::config_keys::load_machine`]), its checked
/// typed values: `[tolerance]` and each section the plugin declares
/// ([`crate::MachinePlugin::machine_sections`]).
#[derive(Debug, Clone, Default)]
pub struct MachineConfig {
    pub id: String,
    pub source: String,
    pub table: toml::Table,
    pub text: String,
    /// `[tolerance]`, checked (empty until loaded, or when absent).
    pub tolerance: BTreeMap<String, f64>,
    /// The plugin's declared sections by name, read into their serde
    /// structs once when the machine is loaded.
    pub sections: BTreeMap<String, crate::config_check::CheckedSection>,
}

impl MachineConfig {
    /// A declared section as its serde struct, as it was read and checked
    /// when the machine was loaded (absent keys at their defaults); None
    /// when no section of that type was loaded (a config not loaded
    /// through [`super::config_keys::load_machine`]).
    pub fn section<T: crate::config_check::Section>(&self) -> Option<&T> {
        self.sections.values().find_map(|s| s.get::<T>())
    }

    /// Section `name` as its serde struct: the value read when the machine
    /// was loaded, or — for a config not loaded for a run (a generator's,
    /// a run-less stage's) — read now through the same reader. An absent
    /// section holds the struct's defaults; an error names the file and
    /// `name.key`.
    pub fn typed_section<T: Section + Clone>(&self, name: &str) -> Result<T, InputError> {
        // By name: two sections may share a type (a gantry's bodies).
        if let Some(v) = self.sections.get(name).and_then(|s| s.get::<T>()) {
            return Ok(v.clone());
        }
        let empty = toml::Value::Table(toml::Table::new());
        read_file_section::<T>(
            Path::new(&self.source),
            name,
            self.table.get(name).unwrap_or(&empty),
        )
    }

    /// Where the config came from, without any directory (a per-run output
    /// must not depend on the working directory or where a shard ran): the
    /// file name or "built-in" or "inline", and a hash of the text.
    pub fn provenance(&self) -> String {
        let hash = blake3::hash(self.text.as_bytes()).to_hex();
        let short = &hash.as_str()[..12];
        let from = if self.source.starts_with("built-in") {
            format!("built-in machine `{}`", self.id)
        } else if self.source.ends_with("[machine]") {
            "the run's inline [machine] table".to_string()
        } else {
            let name = Path::new(&self.source)
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_else(|| format!("{}.toml", self.id));
            format!("`{name}`")
        };
        format!("{from}, blake3 {short}")
    }

    /// The value at a dotted path, e.g. `wheel.radius_mm`.
    pub fn get(&self, dotted: &str) -> Option<&toml::Value> {
        let mut parts = dotted.split('.');
        let mut cur = self.table.get(parts.next()?)?;
        for p in parts {
            cur = cur.get(p)?;
        }
        Some(cur)
    }
    /// A number at a dotted path.
    pub fn f64(&self, dotted: &str) -> Option<f64> {
        self.get(dotted).and_then(toml_f64)
    }
}

/// Resolves machine ids in the order docs/formats.md §3 gives: `--machines DIR`
/// (or SPARKOUT_MACHINES), ./configs/machines/, the run's inline [machine],
/// then the configs built into the binary.
#[derive(Debug, Clone, Default)]
pub struct MachineResolver {
    pub dirs: Vec<PathBuf>,
    pub builtins: BTreeMap<String, String>,
}

impl MachineResolver {
    pub fn new(explicit: Option<PathBuf>, builtins: BTreeMap<String, String>) -> Self {
        let mut dirs = Vec::new();
        if let Some(d) = explicit {
            dirs.push(d);
        } else if let Ok(d) = std::env::var("SPARKOUT_MACHINES") {
            if !d.is_empty() {
                dirs.push(PathBuf::from(d));
            }
        }
        dirs.push(PathBuf::from("configs/machines"));
        MachineResolver { dirs, builtins }
    }

    /// blake3 over every machine config this resolver can find: each
    /// directory's `*.toml` files (name and bytes; the directory's own path
    /// left out, so the same configs from another working directory agree)
    /// and the built-in machines. Shards of one night must agree on it.
    pub fn fingerprint(&self) -> String {
        let mut h = blake3::Hasher::new();
        let mut part = |label: &str, bytes: &[u8]| {
            h.update(&(label.len() as u64).to_le_bytes());
            h.update(label.as_bytes());
            h.update(&(bytes.len() as u64).to_le_bytes());
            h.update(bytes);
        };
        for (i, dir) in self.dirs.iter().enumerate() {
            part("dir", i.to_string().as_bytes());
            let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
                .map(|rd| {
                    rd.filter_map(|e| e.ok().map(|e| e.path()))
                        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
                        .collect()
                })
                .unwrap_or_default();
            files.sort();
            for f in files {
                let name = f.file_name().map(|n| n.to_string_lossy().into_owned());
                part(
                    &name.unwrap_or_default(),
                    &std::fs::read(&f).unwrap_or_default(),
                );
            }
        }
        for (id, text) in &self.builtins {
            part(&format!("builtin {id}"), text.as_bytes());
        }
        h.finalize().to_hex().to_string()
    }

    /// The run's inline `[machine]` table as a machine config (not yet
    /// loaded), its errors naming `run.toml [machine]`.
    pub fn inline(spec: &RunSpec) -> Option<MachineConfig> {
        spec.inline_machine.as_ref().map(|t| MachineConfig {
            id: spec.machine.clone(),
            source: format!("{} [machine]", spec.run_toml_path().display()),
            text: toml::to_string(t).unwrap_or_default(),
            table: t.clone(),
            ..MachineConfig::default()
        })
    }

    pub fn resolve(&self, spec: &RunSpec) -> Result<MachineConfig, InputError> {
        let id = &spec.machine;
        let parse = |text: &str, source: String| -> Result<MachineConfig, InputError> {
            let table: toml::Table = text.parse().map_err(|e| {
                InputError::new(&source, format!("machine config is not valid TOML: {e}"))
            })?;
            Ok(MachineConfig {
                id: id.clone(),
                source,
                table,
                text: text.to_string(),
                ..MachineConfig::default()
            })
        };
        for dir in &self.dirs {
            let p = dir.join(format!("{id}.toml"));
            if let Ok(text) = std::fs::read_to_string(&p) {
                return parse(&text, p.display().to_string());
            }
        }
        if let Some(m) = Self::inline(spec) {
            return Ok(m);
        }
        if let Some(text) = self.builtins.get(id) {
            return parse(text, format!("built-in machine `{id}`"));
        }
        let searched: Vec<String> = self.dirs.iter().map(|d| d.display().to_string()).collect();
        let known: Vec<&str> = self.builtins.keys().map(|s| s.as_str()).collect();
        Err(InputError::new(
            spec.run_toml_path(),
            format!(
                "unknown machine `{id}`: no {id}.toml in {}, no inline [machine] table, and no built-in machine of that name (built in: {}). Add configs/machines/{id}.toml or pass --machines DIR",
                searched.join(", "),
                known.join(", ")
            ),
        )
        .column("run.machine"))
    }
}

/// What a walk of an input root found: run directories, and directories
/// that look like runs (they hold Parquet tables) but cannot be read as one
/// — listed, never dropped silently (every run accounted for).
#[derive(Debug, Clone, Default)]
pub struct Discovery {
    pub runs: Vec<PathBuf>,
    pub skipped: Vec<Skipped>,
}

/// A directory (or link) found under the input and not processed.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct Skipped {
    pub dir: PathBuf,
    /// The file the message is about (a missing run.toml, a link, the
    /// directory itself).
    pub file: PathBuf,
    pub why: String,
}

/// Whether `dir` is something sparkout wrote (a run's output or an output
/// root): an `--out` inside `--input` is not a run that lacks its run.toml.
fn is_sparkout_output(dir: &Path) -> bool {
    dir.join(crate::files::RUN_CACHE_FILE).is_file()
        || dir.join("manifest.json").is_file()
        || dir.join(crate::files::LOCK_FILE).is_file()
}

/// How deep a walk goes below the input root: far deeper than any real
/// layout (`<root>/<site>/<line>/<machine>/<run>`), and a bound on a
/// hostile tree.
pub const MAX_DISCOVER_DEPTH: usize = 32;

/// Every run directory under `root`, at any depth (a root that is itself a
/// run works too), sorted; and, listed by name so the batch can go on
/// without them: directories with tables but no run.toml, a run directory
/// inside another run's directory, directories that cannot be read, and
/// symbolic links that lead outside `root` (not followed).
pub fn discover(root: &Path) -> std::io::Result<Discovery> {
    struct Walk {
        root: PathBuf,
        /// Canonical directories entered (a link loop is entered once).
        seen: std::collections::BTreeSet<PathBuf>,
        out: Discovery,
    }
    impl Walk {
        fn skip(&mut self, dir: &Path, file: &Path, why: String) {
            self.out.skipped.push(Skipped {
                dir: dir.to_path_buf(),
                file: file.to_path_buf(),
                why,
            });
        }
        /// A link (or anything) under `dir` that resolves outside the root.
        fn escapes(&self, p: &Path) -> Option<PathBuf> {
            let c = p.canonicalize().ok()?;
            (!c.starts_with(&self.root)).then_some(c)
        }
        fn entries(&mut self, dir: &Path) -> Option<Vec<PathBuf>> {
            match std::fs::read_dir(dir) {
                Ok(rd) => {
                    let mut v: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).collect();
                    v.sort();
                    Some(v)
                }
                Err(e) => {
                    self.skip(
                        dir,
                        dir,
                        format!(
                            "cannot list directory {} ({e}); its runs, if any, are not processed — fix its permissions",
                            dir.display()
                        ),
                    );
                    None
                }
            }
        }
        /// Run directories below the run `outer` (they are errors).
        fn nested(&mut self, outer: &Path, dir: &Path, depth: usize) {
            if depth == 0 {
                return;
            }
            let Some(entries) = self.entries(dir) else {
                return;
            };
            for e in entries
                .into_iter()
                .filter(|p| p.is_dir() && !p.is_symlink())
            {
                if e.join(RunSpec::FILE).is_file() {
                    self.skip(
                        &e,
                        &e.join(RunSpec::FILE),
                        format!(
                            "run directory {} is inside run directory {}; a run's directory may not hold another run — move it out (the outer run is processed without it)",
                            e.display(),
                            outer.display()
                        ),
                    );
                }
                self.nested(outer, &e, depth - 1);
            }
        }
        fn walk(&mut self, dir: &Path, depth: usize) {
            if let Ok(c) = dir.canonicalize() {
                if !self.seen.insert(c) {
                    return;
                }
            }
            if dir.join(RunSpec::FILE).is_file() {
                // A run's own files must not lead outside the input either
                // (a run.toml or table linked to /etc or another fleet).
                if let Some(entries) = self.entries(dir) {
                    if let Some((link, to)) = entries
                        .iter()
                        .filter(|p| p.is_symlink())
                        .find_map(|p| self.escapes(p).map(|c| (p.clone(), c)))
                    {
                        self.skip(
                            dir,
                            &link,
                            format!(
                                "{} is a symbolic link to {}, outside the input {}; links out of the input are not followed — copy the file into the run",
                                link.display(),
                                to.display(),
                                self.root.display()
                            ),
                        );
                        return;
                    }
                }
                self.out.runs.push(dir.to_path_buf());
                self.nested(dir, dir, MAX_DISCOVER_DEPTH);
                return;
            }
            if is_sparkout_output(dir) {
                return;
            }
            let Some(entries) = self.entries(dir) else {
                return;
            };
            let tables: Vec<String> = entries
                .iter()
                .filter(|p| p.extension().is_some_and(|e| e == "parquet"))
                .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
                .collect();
            if !tables.is_empty() {
                self.skip(
                    dir,
                    &dir.join(RunSpec::FILE),
                    format!(
                        "skipped: holds {} but no run.toml, so it cannot be processed (docs/formats.md: every run directory needs a run.toml with [run] id, machine, plugin)",
                        tables.join(", ")
                    ),
                );
                return;
            }
            if depth == 0 {
                self.skip(
                    dir,
                    dir,
                    format!(
                        "not searched: deeper than {MAX_DISCOVER_DEPTH} directories below the input"
                    ),
                );
                return;
            }
            for e in entries {
                if e.is_symlink() {
                    if let Some(to) = self.escapes(&e) {
                        self.skip(
                            &e,
                            &e,
                            format!(
                                "{} is a symbolic link to {}, outside the input {}; not followed",
                                e.display(),
                                to.display(),
                                self.root.display()
                            ),
                        );
                        continue;
                    }
                }
                if e.is_dir() {
                    self.walk(&e, depth - 1);
                }
            }
        }
    }
    if !root.is_dir() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::NotFound,
            format!("input root {} is not a directory", root.display()),
        ));
    }
    // The root itself must be readable: otherwise nothing can be said.
    std::fs::read_dir(root).map_err(|e| {
        std::io::Error::new(
            e.kind(),
            format!("cannot list the input {} ({e})", root.display()),
        )
    })?;
    let mut w = Walk {
        root: root.canonicalize()?,
        seen: Default::default(),
        out: Discovery::default(),
    };
    w.walk(root, MAX_DISCOVER_DEPTH);
    w.out.runs.sort();
    w.out.skipped.sort();
    Ok(w.out)
}

/// The run directories of [`discover`] only.
pub fn discover_runs(root: &Path) -> std::io::Result<Vec<PathBuf>> {
    discover(root).map(|d| d.runs)
}

#[cfg(test)]
mod tests {
    use super::*;

    const RUN: &str = "[run]\nid = \"r1\"\nmachine = \"kr16-lab\"\nplugin = \"robot\"\nstarted = 2026-11-20T08:00:00Z\n";

    /// run.toml with `extra` after `[run]`, or before it when it is a
    /// top-level key.
    fn parse(extra: &str) -> Result<RunSpec, InputError> {
        let text = if extra.starts_with('[') {
            format!("{RUN}{extra}")
        } else {
            format!("{extra}{RUN}")
        };
        RunSpec::parse(Path::new("runs/r1"), &text)
    }

    #[test]
    fn run_toml_sections_are_checked_by_key_and_type() {
        let ok = parse("[ae]\nsample_rate_hz = 100000\nkind = \"rms\"\n").unwrap();
        assert_eq!(ok.started.as_deref(), Some("2026-11-20T08:00:00Z"));
        let ae = ok.ae.unwrap();
        assert_eq!(
            (ae.sample_rate_hz, ae.kind, ae.kind_given),
            (1e5, AeKind::Rms, true)
        );
        assert_eq!(ae.clock_offset_s, 0.0);
        let ae = parse("[ae]\nsample_rate_hz = 5.0\n").unwrap().ae.unwrap();
        assert_eq!((ae.kind, ae.kind_given), (AeKind::Raw, false));
        for (extra, column, needle) in [
            // A wrong type is an error, never the default (`raw`).
            (
                "[ae]\nsample_rate_hz = 5.0\nkind = 5\n",
                "ae.kind",
                "must be one of raw, rms",
            ),
            (
                "[ae]\nsample_rate_hz = \"fast\"\n",
                "ae.sample_rate_hz",
                "a number > 0",
            ),
            (
                "[ae]\nsample_rate_hz = 0\n",
                "ae.sample_rate_hz",
                "a number > 0",
            ),
            (
                "[ae]\nkind = \"raw\"\n",
                "ae.sample_rate_hz",
                "required key",
            ),
            (
                "[ae]\nsample_rate_hz = 5.0\nclock_offset = 1\n",
                "ae.clock_offset",
                "unknown key",
            ),
            (
                "[ae]\nsample_rate_hz = 5.0\nclock_offset_s = \"1 s\"\n",
                "ae.clock_offset_s",
                "a finite number",
            ),
            ("ae = 5\n", "ae", "must be a table"),
            ("process = 5\n", "process", "must be a table"),
        ] {
            let e = parse(extra).unwrap_err();
            assert_eq!(e.column.as_deref(), Some(column), "{extra}: {e}");
            let text = e.to_string();
            assert!(
                text.contains("runs/r1/run.toml") && text.contains(needle),
                "{extra}: {text}"
            );
        }
        let typo = RUN.replace("started", "strated");
        let e = RunSpec::parse(Path::new("runs/r1"), &typo).unwrap_err();
        assert_eq!(e.column.as_deref(), Some("run.strated"), "{e}");
        let wrong = RUN.replace("plugin = \"robot\"", "plugin = 3");
        let e = RunSpec::parse(Path::new("runs/r1"), &wrong).unwrap_err();
        assert_eq!(e.column.as_deref(), Some("run.plugin"), "{e}");
        let blank = RUN.replace("id = \"r1\"", "id = \" \"");
        let e = RunSpec::parse(Path::new("runs/r1"), &blank).unwrap_err();
        assert_eq!(e.column.as_deref(), Some("run.id"), "{e}");
    }

    #[test]
    fn run_toml_machine_and_replay_are_checked_by_key_and_type() {
        let ok = parse(
            "[replay]\nsource_run = \"runs/r0\"\nbus = \"vcan0\"\ncycle_s = 0.004\ncounts_per_mm = 1000.0\ncycles_streamed = 10\nrows_recorded = 10\noutcome = \"completed\"\ncopied_tables = [\"plan\"]\n[machine.machine]\nid = \"kr16-lab\"\n[machine.wheel]\nradius_mm = 40.0\n",
        )
        .unwrap();
        let replay = ok.replay.unwrap();
        assert_eq!(
            (replay.cycle_s, replay.rows_recorded, replay.copied_tables),
            (Some(0.004), Some(10), Some(vec!["plan".to_string()]))
        );
        assert!(ok.inline_machine.unwrap().contains_key("wheel"));
        assert!(parse("").unwrap().replay.is_none());
        for (extra, column, needle) in [
            // An unknown key, a wrong type, a value out of range.
            (
                "[replay]\nsorce_run = \"runs/r0\"\n",
                "replay.sorce_run",
                "unknown key",
            ),
            (
                "[replay]\ncycle_s = \"4 ms\"\n",
                "replay.cycle_s",
                "a number > 0",
            ),
            ("[replay]\ncycle_s = 0\n", "replay.cycle_s", "a number > 0"),
            (
                "[replay]\nrows_recorded = -1\n",
                "replay.rows_recorded",
                "a whole number",
            ),
            (
                "[replay]\ncopied_tables = \"plan\"\n",
                "replay.copied_tables",
                "copied_tables",
            ),
            ("replay = 5\n", "replay", "must be a table"),
            ("machine = \"kr16-lab\"\n", "machine", "must be a table"),
            (
                "[machine]\nradius_mm = 40.0\n",
                "machine.radius_mm",
                "each a table",
            ),
        ] {
            let e = parse(extra).unwrap_err();
            assert_eq!(e.column.as_deref(), Some(column), "{extra}: {e}");
            let text = e.to_string();
            assert!(
                text.contains("runs/r1/run.toml") && text.contains(needle),
                "{extra}: {text}"
            );
        }
    }
}

//! The pipeline config (configs/nightly.toml and `--set key=value`).

use std::path::Path;

use crate::{bail, err, Context};
use serde::{Deserialize, Serialize};

use std::collections::BTreeMap;

use crate::config_check::{Checked, CheckedSection, Section};
use crate::diagnose::DiagnoseConfig;
use crate::error::Result;
use crate::report::trend::TrendConfig;

/// The default DAG, built into the binary so `sparkout run` works from any
/// directory without `--config`.
pub const NIGHTLY_TOML: &str = include_str!("../../configs/nightly.toml");

#[derive(Debug, Clone)]
pub struct PipelineConfig {
    pub table: toml::Table,
    /// Where it came from (a path, or "built-in nightly.toml").
    pub source: String,
}

impl PipelineConfig {
    pub fn builtin() -> Self {
        Self::parse(NIGHTLY_TOML, "built-in configs/nightly.toml").expect("nightly.toml parses")
    }

    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read config {}", path.display()))?;
        Self::parse(&text, &path.display().to_string())
    }

    pub fn parse(text: &str, source: &str) -> Result<Self> {
        let table: toml::Table = text
            .parse()
            .map_err(|e| err!("config {source} is not valid TOML: {e}"))?;
        Ok(PipelineConfig {
            table,
            source: source.to_string(),
        })
    }

    /// Apply `key.path=value` (value read as TOML: numbers, booleans,
    /// arrays; anything else is a string).
    pub fn set(&mut self, assignment: &str) -> Result<()> {
        let (key, raw) = assignment.split_once('=').ok_or_else(|| {
            err!("--set `{assignment}`: expected KEY=VALUE, e.g. --set robot.ingest.k_sigma=8")
        })?;
        let key = key.trim();
        if key.is_empty() || key.split('.').any(|p| p.is_empty()) {
            bail!("--set `{assignment}`: the key must be a dotted path like robot.ingest.k_sigma");
        }
        let value = parse_value(raw.trim());
        let parts: Vec<&str> = key.split('.').collect();
        let mut cur = &mut self.table;
        for p in &parts[..parts.len() - 1] {
            let entry = cur
                .entry(p.to_string())
                .or_insert_with(|| toml::Value::Table(toml::Table::new()));
            cur = entry
                .as_table_mut()
                .ok_or_else(|| err!("--set `{assignment}`: `{p}` is not a table in the config"))?;
        }
        cur.insert(parts[parts.len() - 1].to_string(), value);
        Ok(())
    }

    /// A top-level or dotted section, empty when absent.
    pub fn section(&self, dotted: &str) -> toml::Table {
        let mut cur = &self.table;
        for p in dotted.split('.') {
            match cur.get(p).and_then(|v| v.as_table()) {
                Some(t) => cur = t,
                None => return toml::Table::new(),
            }
        }
        cur.clone()
    }
}

/// `[pipeline]`: which plugins and stages a batch runs (all when absent).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PipelineSection {
    /// Only these plugins' runs are processed.
    pub plugins: Option<Vec<String>>,
    /// Only these stages (and the stages they read from) run.
    pub stages: Option<Vec<String>>,
}

impl Section for PipelineSection {}

/// `[report]`: what the report pages take from the config (defined with
/// the pages, which receive it typed).
pub use crate::report::ReportConfig as ReportSection;

/// The pipeline config read and checked once, when the engine is built
/// (before any run): each section as its typed, checked value. Runs and
/// the fleet steps take their settings from here; nothing parses a
/// section again, and each cache key hashes the effective config
/// ([`Checked::effective`], [`CheckedSection::effective`]).
#[derive(Debug, Clone)]
pub struct CheckedConfig {
    pub pipeline: Checked<PipelineSection>,
    pub report: Checked<ReportSection>,
    pub diagnose: Checked<DiagnoseConfig>,
    pub trend: Checked<TrendConfig>,
    /// Every stage of every plugin, by (plugin, stage): its section, or
    /// its defaults when the config has none.
    pub(super) stages: BTreeMap<(&'static str, &'static str), CheckedSection>,
}

impl CheckedConfig {
    /// A stage's checked section.
    pub fn stage(&self, plugin: &str, stage: &str) -> Result<&CheckedSection> {
        self.stages
            .iter()
            .find(|((p, s), _)| *p == plugin && *s == stage)
            .map(|(_, c)| c)
            .ok_or_else(|| err!("stage `{plugin}.{stage}` has no checked config section"))
    }
}

fn parse_value(raw: &str) -> toml::Value {
    let doc = format!("v = {raw}");
    match doc.parse::<toml::Table>() {
        Ok(mut t) => t
            .remove("v")
            .unwrap_or(toml::Value::String(raw.to_string())),
        Err(_) => toml::Value::String(raw.to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn set_overrides_nested_keys() {
        let mut c = PipelineConfig::parse("[robot.ingest]\nk_sigma = 6\n", "t").unwrap();
        c.set("robot.ingest.k_sigma=8.5").unwrap();
        c.set("diagnose.effects=[\"drift\"]").unwrap();
        c.set("report.title=night shift").unwrap();
        assert_eq!(c.section("robot.ingest")["k_sigma"].as_float(), Some(8.5));
        assert!(c.section("diagnose")["effects"].is_array());
        assert_eq!(c.section("report")["title"].as_str(), Some("night shift"));
        assert!(c.set("nokey").is_err());
        assert!(c.set("robot..x=1").is_err());
    }

    #[test]
    fn report_and_pipeline_sections_are_checked_naming_file_and_key() {
        let check = |text: &str| {
            let c = PipelineConfig::parse(text, "night.toml").unwrap();
            super::super::checks::check_config(&[], &c)
        };
        let ok = check("[report]\ntitle = \"night shift\"\n[pipeline]\nstages = [\"report\"]\n")
            .unwrap();
        assert_eq!(ok.report.title.as_deref(), Some("night shift"));
        assert_eq!(ok.pipeline.stages, Some(vec!["report".to_string()]));
        // An unknown key, a wrong type, a value outside what the key takes.
        for (text, needle) in [
            ("[report]\ntitel = \"x\"\n", "unknown key `titel`"),
            ("[report]\ntitle = 5\n", "key `title`"),
            ("[pipeline]\nstages = \"report\"\n", "key `stages`"),
            ("[pipeline]\nplugin = [\"robot\"]\n", "unknown key `plugin`"),
            (
                "[pipeline]\nplugins = [\"robotx\"]\n",
                "[pipeline].plugins names unknown plugin `robotx`",
            ),
            (
                "[pipeline]\nstages = [\"injest\"]\n",
                "[pipeline].stages names unknown stage `injest`",
            ),
            ("report = 5\n", "[report] must be a table"),
        ] {
            let e = format!("{:#}", check(text).unwrap_err());
            assert!(
                e.contains("night.toml") && e.contains(needle),
                "{text}: {e}"
            );
        }
    }

    #[test]
    fn builtin_nightly_parses() {
        let c = PipelineConfig::builtin();
        assert!(c.table.contains_key("diagnose"));
    }
}

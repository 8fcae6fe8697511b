//! sparkout-pipeline: the DAG engine (discovery, the per-stage cache,
//! shards, the fleet steps), import of foreign tables and the fuzz entry
//! points. It knows no concrete machine: plugins plug in by trait.
//!
//! The crates below it are re-exported under their old module names, so a
//! plugin or the binary names one crate: `sparkout-core` (the plugin
//! interface, contracts, units, errors, files, storage),
//! `sparkout-diagnose` (the gap diagnosis), `sparkout-report` (the HTML
//! pages and the trend) and `sparkout-can` (CANopen replay).

pub mod engine;
pub mod fuzz_entry;
pub mod import;

pub use sparkout_can as replay;
pub use sparkout_core::{
    alloc, augment, config_check, contracts, effect, effect_spec, error, files, html, outcome,
    storage, traits, units, values, verdict,
};
pub use sparkout_diagnose as diagnose;
pub use sparkout_report as report;

pub use sparkout_core::{bail, err, Context, Error, Kind};
pub use sparkout_core::{
    json_f64, json_opt_f64, toml_f64, ArtifactStore, ConfigError, EffectSpec, InputError,
    MachinePlugin, ProcessKeys, ReportSection, Result, Run, Stage, StageArgs, StageContext,
    StageOutput, StageSpec,
};

//! sparkout-pipeline: the DAG engine, the Stage/MachinePlugin/Effect traits,
//! data contracts (validated readers and atomic writers), the gap diagnosis
//! and reports. It knows no concrete machine: plugins plug in by trait.

pub mod alloc;
pub mod config_check;
pub mod contracts;
pub mod diagnose;
pub mod effect_spec;
pub mod engine;
pub mod error;
pub mod files;
pub mod fuzz_entry;
pub mod html;
pub mod import;
pub mod outcome;
pub mod replay;
pub mod report;
pub mod storage;
pub mod traits;
pub mod units;
pub mod values;
pub mod verdict;

pub use effect_spec::EffectSpec;
pub use error::{ConfigError, InputError, Result};
pub use traits::{
    ArtifactStore, MachinePlugin, ProcessKeys, ReportSection, Run, Stage, StageArgs, StageContext,
    StageOutput, StageSpec,
};
pub use values::{json_f64, json_opt_f64, toml_f64};

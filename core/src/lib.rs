//! sparkout-core: the ground floor every other crate stands on — the plugin
//! interface (`MachinePlugin`, `Stage`, `Effect`), the data contracts
//! (schemas, validated readers, atomic writers), units, errors, safe file
//! names and object storage. It knows no machine and no concrete stage.
//!
//! Layers inside, from the ground up (docs/design.md §1 "Layers"): `error`,
//! `values`, `files`, `html`, `storage`, `units`, `config_check`,
//! `contracts`, `effect` (the effect model and its least squares),
//! `augment`, `verdict`, `outcome`, then `traits`, the plugin interface.

pub mod ahead;
pub mod alloc;
pub mod augment;
pub mod config_check;
pub mod contracts;
pub mod effect;
pub mod effect_spec;
pub mod error;
pub mod files;
pub mod html;
pub mod outcome;
pub mod storage;
pub mod traits;
pub mod units;
pub mod values;
pub mod verdict;

pub use effect_spec::EffectSpec;
pub use error::{ConfigError, Context, Error, InputError, Kind, Result};
pub use traits::{
    ArtifactStore, MachinePlugin, ProcessKeys, ReportSection, Run, Stage, StageArgs, StageContext,
    StageOutput, StageSpec,
};
pub use values::{json_f64, json_opt_f64, toml_f64};

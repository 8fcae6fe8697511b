//! `[robot.<stage>]` config sections are checked by the pipeline's shared
//! checker.

pub use sparkout_pipeline::config_check::{check_config, Check};

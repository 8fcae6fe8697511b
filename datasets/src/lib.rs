//! sparkout-datasets: synthetic recorded runs (a plugin's forward model +
//! injected effects from the DESIGN.md catalogue + noise), seeded and
//! deterministic, and the `sparkout validate` harness.

pub mod form;
pub mod gantry;
pub mod guideway;
pub mod mill;
pub mod observations;
pub mod robot;
pub mod servo;
pub mod validate;

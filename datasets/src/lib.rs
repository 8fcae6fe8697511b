//! sparkout-datasets: synthetic recorded runs (a plugin's forward model +
//! injected effects from the catalogue of docs/models.md §8.4 + noise), seeded and
//! deterministic, and the `sparkout validate` harness.

pub mod form;
pub mod gantry;
pub mod generator;
pub mod guideway;
pub mod mill;
pub mod observations;
pub mod rng;
pub mod robot;
pub mod servo;
pub mod validate;

pub use generator::{
    all_generators, generator, DemoFleet, FleetGenerator, GenerateOptions, Generated, Generator,
    Predicted, RunSize,
};

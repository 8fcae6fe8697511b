//! sparkout-datasets: synthetic recorded runs (a plugin's forward model +
//! injected effects from the catalogue of docs/models.md §8.4 + noise), seeded and
//! deterministic, and the `sparkout validate` harness.

// Typed errors (sparkout-core `error`) by the names every generator uses.
#[allow(unused_imports)]
pub(crate) use sparkout_pipeline::{bail, err, Context, Error, Result};

pub mod form;
pub mod gantry;
pub mod generator;
pub mod guideway;
pub mod mill;
pub mod observations;
pub mod rng;
pub mod robot;
pub mod servo;
pub mod started;
pub mod validate;

pub use generator::{
    DemoFleet, FleetGenerator, GenerateOptions, Generated, Generator, Predicted, RunSize,
};

use std::sync::Arc;

// The registry sits at the crate root, above every generator: a generator
// module needs only the `Generator` trait below it, never the list.
/// Every generator this build knows, in the demo's order.
pub fn all_generators() -> Vec<Arc<dyn Generator>> {
    vec![
        Arc::new(crate::robot::RobotGenerator),
        Arc::new(crate::gantry::GENERATOR),
        Arc::new(crate::guideway::GENERATOR),
        Arc::new(crate::mill::GENERATOR),
        Arc::new(crate::form::GENERATOR),
        Arc::new(crate::servo::GENERATOR),
        Arc::new(crate::observations::ObservationsGenerator),
        Arc::new(crate::observations::RasterGenerator { varied: false }),
        Arc::new(crate::observations::RasterGenerator { varied: true }),
    ]
}

/// The generator named `name`.
pub fn generator(name: &str) -> Option<Arc<dyn Generator>> {
    all_generators().into_iter().find(|g| g.name() == name)
}

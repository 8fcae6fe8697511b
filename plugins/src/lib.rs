//! sparkout-plugins: one module per machine type, each implementing the
//! pipeline's traits. A plugin knows no other plugin.

use std::sync::Arc;

use sparkout_pipeline::MachinePlugin;

pub mod form;
pub mod gantry;
pub mod guideway;
pub mod metrology;
pub mod mill;
pub mod robot;
pub mod servo;
#[cfg(test)]
mod toy;
mod typed_summary;

/// Every plugin this build knows, in a fixed order.
pub fn all_plugins() -> Vec<Arc<dyn MachinePlugin>> {
    vec![
        Arc::new(robot::RobotPlugin),
        Arc::new(guideway::GuidewayPlugin),
        Arc::new(mill::MillPlugin),
        Arc::new(form::FormPlugin),
        Arc::new(gantry::GantryPlugin),
        Arc::new(servo::ServoPlugin),
    ]
}

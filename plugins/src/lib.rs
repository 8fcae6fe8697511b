//! sparkout-plugins: one module per machine type, each implementing the
//! pipeline's traits. A plugin knows no other plugin.

// Typed errors (sparkout-core `error`) by the names every stage uses.
#[allow(unused_imports)]
pub(crate) use sparkout_pipeline::{bail, err, Context, Error, Result};

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

#[cfg(test)]
mod tables_tests {
    use sparkout_pipeline::contracts::plausible::{all_ranges, range_for};
    use sparkout_pipeline::contracts::TableRegistry;

    fn registry() -> TableRegistry {
        let plugins = super::all_plugins();
        TableRegistry::of(plugins.iter().map(|p| (p.name(), p.tables()))).unwrap()
    }

    /// Each plugin declares its own tables, none twice, and every numeric
    /// column of every table has a plausible range (its own or its unit
    /// suffix's).
    #[test]
    fn every_plugin_table_is_registered_once_with_ranges() {
        let r = registry();
        for name in ["ae", "motion", "thermal", "probe", "plan", "passes"] {
            assert!(r.get(name).is_some(), "{name} not registered");
        }
        for name in ["topography", "guideway", "profile", "tracker"] {
            assert!(r.get(name).is_some(), "{name} not registered");
        }
        for t in r.iter() {
            for c in t.columns {
                let text = matches!(c.name, "face" | "method" | "state" | "stage" | "sensor");
                assert!(
                    text || range_for(t, c.name).is_some(),
                    "{}.{} has no plausible range",
                    t.name,
                    c.name
                );
            }
        }
        let mut twice = TableRegistry::shared();
        let robot = super::robot::RobotPlugin;
        use sparkout_pipeline::MachinePlugin;
        twice.register("robot", robot.tables()).unwrap();
        let e = twice.register("robot again", robot.tables()).unwrap_err();
        assert!(e.to_string().contains("`probe`"), "{e}");
    }

    /// docs/validation.md lists every registered table's ranges.
    #[test]
    fn every_registered_range_is_documented() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/validation.md");
        let doc = std::fs::read_to_string(path).unwrap();
        for (t, c, r) in all_ranges(&registry()) {
            let row = format!("| {t} | {c} | {} | {} |", r.lo, r.hi);
            assert!(
                doc.contains(&row),
                "docs/validation.md lacks the row `{row}`"
            );
        }
    }
}

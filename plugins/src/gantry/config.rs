//! The gantry's `[gantry.<stage>]` config sections as serde structs
//! (defaults here only, each key's range as data, read by the pipeline's
//! shared `config_check::read_section`); `[gantry.polish_plan]` is
//! [`PlanConfig`](super::polish_plan::PlanConfig).

use serde::{Deserialize, Serialize};
pub use sparkout_pipeline::config_check::{Check, Section};

/// Topography states in the order a workpiece goes through them
/// (docs/formats.md §4, topography.parquet).
pub const STATES: [&str; 5] = ["pattern", "before", "after_grind", "after_polish", "final"];

/// Where the polishing path comes from: the run's motion log (a planned
/// raster when it has none), or always the planned raster.
pub const PATH_SOURCES: [&str; 2] = ["motion", "raster"];

/// `[gantry.flatness]`.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FlatnessConfig {
    /// None: the last state in the order of [`STATES`].
    pub state: Option<String>,
}

impl Section for FlatnessConfig {
    const CHECKS: &'static [(&'static str, Check)] = &[("state", Check::OneOf(&STATES))];
}

/// `[gantry.removal]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RemovalConfig {
    /// The measured surface polishing starts from.
    pub from_state: String,
    /// One of [`PATH_SOURCES`].
    pub path: String,
}

impl Default for RemovalConfig {
    fn default() -> Self {
        RemovalConfig {
            from_state: "after_grind".to_string(),
            path: "motion".to_string(),
        }
    }
}

impl Section for RemovalConfig {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("from_state", Check::OneOf(&STATES)),
        ("path", Check::OneOf(&PATH_SOURCES)),
    ];
}

/// `[gantry.observe]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ObserveConfig {
    /// The measured state compared with the removal stage's prediction.
    pub state: String,
    /// One of [`PATH_SOURCES`].
    pub path: String,
}

impl Default for ObserveConfig {
    fn default() -> Self {
        ObserveConfig {
            state: "after_polish".to_string(),
            path: "motion".to_string(),
        }
    }
}

impl Section for ObserveConfig {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("state", Check::OneOf(&STATES)),
        ("path", Check::OneOf(&PATH_SOURCES)),
    ];
}

#[cfg(test)]
mod tests {
    use super::*;
    use sparkout_pipeline::config_check::read_section;

    #[test]
    fn rejects_unknown_keys_and_bad_values() {
        let ok: toml::Table = "from_state = \"before\"\npath = \"raster\""
            .parse()
            .unwrap();
        assert_eq!(read_section::<RemovalConfig>(&ok).unwrap().path, "raster");
        let bad: toml::Table = "from = \"before\"".parse().unwrap();
        assert!(read_section::<RemovalConfig>(&bad)
            .unwrap_err()
            .to_string()
            .contains("unknown key `from`"));
        let st: toml::Table = "state = \"polished\"".parse().unwrap();
        assert!(read_section::<FlatnessConfig>(&st)
            .unwrap_err()
            .to_string()
            .contains("one of"));
    }
}

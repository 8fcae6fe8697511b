//! Checking `[form.<stage>]` config sections. The checker itself is the
//! pipeline's shared one (`config_check`, not copied); this file holds
//! the form plugin's keys.

pub use sparkout_pipeline::config_check::{check_config, Check};

use sparkout_pipeline::{cfg_f64, Result};

use super::curvature::CurvatureConfig;

/// `window_points` shared by every stage that differentiates the profile:
/// an odd number of points ≥ 5 per local cubic fit.
pub const WINDOW_KEY: (&str, Check) = ("window_points", Check::OddAtLeast(5));

/// The curvature settings of a stage section (checked: odd, ≥ 5).
pub fn curvature(cfg: &toml::Table) -> CurvatureConfig {
    CurvatureConfig {
        window_points: cfg_f64(cfg, "window_points")
            .map(|w| w as usize)
            .unwrap_or(CurvatureConfig::default().window_points),
    }
}

/// A whole number ≥ 1 (segment counts).
pub fn check_count(cfg: &toml::Table, key: &str, max: usize) -> Result<()> {
    sparkout_pipeline::config_check::check_whole(cfg, key, 1, max as i64)
}

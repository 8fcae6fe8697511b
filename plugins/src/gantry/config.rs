//! Checking `[gantry.<stage>]` config sections: every key known, every value
//! of the right type and range, with an error that names the key and says
//! what to write instead.

pub use sparkout_pipeline::config_check::{check_config, Check};

/// Topography states in the order a workpiece goes through them
/// (CONTRACTS.md §1, topography.parquet).
pub const STATES: [&str; 5] = ["pattern", "before", "after_grind", "after_polish", "final"];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_unknown_keys_and_bad_values() {
        let keys = [
            ("tol_mm", Check::Positive),
            ("state", Check::OneOf(&STATES)),
        ];
        let ok: toml::Table = "tol_mm = 0.01\nstate = \"before\"".parse().unwrap();
        assert!(check_config(&ok, &keys).is_ok());
        let bad: toml::Table = "tol = 0.01".parse().unwrap();
        assert!(check_config(&bad, &keys)
            .unwrap_err()
            .to_string()
            .contains("unknown key `tol`"));
        let neg: toml::Table = "tol_mm = -1".parse().unwrap();
        assert!(check_config(&neg, &keys).is_err());
        let st: toml::Table = "state = \"polished\"".parse().unwrap();
        assert!(check_config(&st, &keys)
            .unwrap_err()
            .to_string()
            .contains("one of"));
    }
}

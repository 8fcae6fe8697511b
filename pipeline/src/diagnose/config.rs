//! `[diagnose]`: the one settings struct of the diagnosis (issue 13 item 1),
//! parsed in one place for `sparkout run`, `sparkout diagnose` and
//! `sparkout validate` — serde with `deny_unknown_fields`, defaults here
//! only, then [`DiagnoseConfig::validate`] before anything runs.

use anyhow::{anyhow, bail};
use serde::{Deserialize, Serialize};

use crate::Result;

/// Settings of the diagnosis (`[diagnose]` config section / CLI flags).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DiagnoseConfig {
    /// k of the k-fold cross-validation by (machine, run).
    pub folds: usize,
    /// Restrict candidates to these effect names (catalogue or plugin).
    pub effects: Option<Vec<String>>,
    /// Seed of the fold assignment.
    pub seed: u64,
    /// Significance level of every test (cells, paired CV test).
    pub alpha: f64,
    /// Selection stops when the held-out RMS is ≤ noise_margin·σ, and a gap
    /// at or below it is "no gap above noise".
    pub noise_margin: f64,
    /// At most this many effects are selected per observable.
    pub max_effects: usize,
    /// Smallest held-out gain that counts (mean ln of RMS before/after over
    /// held-out units): selection needs it, and a more complex candidate
    /// must beat a simpler one by it (parsimony).
    pub min_gain: f64,
}

impl Default for DiagnoseConfig {
    fn default() -> Self {
        DiagnoseConfig {
            folds: 5,
            effects: None,
            seed: 0,
            alpha: 0.01,
            noise_margin: 1.1,
            max_effects: 4,
            min_gain: 0.01,
        }
    }
}

/// The keys `[diagnose]` accepts (for error messages and docs).
pub const KEYS: [&str; 7] = [
    "folds",
    "effects",
    "seed",
    "alpha",
    "noise_margin",
    "max_effects",
    "min_gain",
];

impl DiagnoseConfig {
    /// `[diagnose]` → settings, checked. Unknown keys and wrong types are
    /// errors naming the key.
    pub fn from_toml(section: &toml::Table) -> Result<DiagnoseConfig> {
        let c: DiagnoseConfig =
            toml::Value::Table(section.clone())
                .try_into()
                .map_err(|e: toml::de::Error| {
                    let msg = e.message().to_string();
                    if msg.contains("unknown field") {
                        anyhow!("{msg} (known keys: {})", KEYS.join(", "))
                    } else {
                        anyhow!("{msg}")
                    }
                })?;
        c.validate()?;
        Ok(c)
    }

    pub fn validate(&self) -> Result<()> {
        if self.folds < 2 {
            bail!("diagnose.folds must be at least 2 (got {})", self.folds);
        }
        if !(self.alpha > 0.0 && self.alpha < 1.0) {
            bail!("diagnose.alpha must be in (0, 1) (got {})", self.alpha);
        }
        if !(self.noise_margin >= 1.0 && self.noise_margin.is_finite()) {
            bail!(
                "diagnose.noise_margin must be ≥ 1 (got {})",
                self.noise_margin
            );
        }
        if !(self.min_gain >= 0.0 && self.min_gain.is_finite()) {
            bail!("diagnose.min_gain must be ≥ 0 (got {})", self.min_gain);
        }
        if self.max_effects == 0 {
            bail!("diagnose.max_effects must be at least 1");
        }
        if let Some(e) = &self.effects {
            if e.is_empty() {
                bail!("diagnose.effects is empty: name at least one effect or omit it");
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_defaults_overrides_and_rejects_unknowns() {
        let c = DiagnoseConfig::from_toml(&toml::Table::new()).unwrap();
        assert_eq!(c, DiagnoseConfig::default());
        let t: toml::Table = "folds = 3\nalpha = 0.05\neffects = [\"drift\"]\nmin_gain = 0"
            .parse()
            .unwrap();
        let c = DiagnoseConfig::from_toml(&t).unwrap();
        assert_eq!((c.folds, c.alpha, c.min_gain), (3, 0.05, 0.0));
        assert_eq!(c.effects, Some(vec!["drift".to_string()]));
        let bad: toml::Table = "fold = 3".parse().unwrap();
        let e = DiagnoseConfig::from_toml(&bad).unwrap_err().to_string();
        assert!(e.contains("fold") && e.contains("known keys"), "{e}");
        let bad: toml::Table = "folds = 1".parse().unwrap();
        assert!(DiagnoseConfig::from_toml(&bad).is_err());
        let bad: toml::Table = "alpha = \"x\"".parse().unwrap();
        assert!(DiagnoseConfig::from_toml(&bad).is_err());
    }

    /// configs/nightly.toml's `[diagnose]` parses into these settings (the
    /// shipped config and the struct cannot disagree unnoticed).
    #[test]
    fn shipped_nightly_config_parses() {
        let text = include_str!("../../../configs/nightly.toml");
        let t: toml::Table = text.parse().unwrap();
        let sec = t
            .get("diagnose")
            .and_then(|v| v.as_table())
            .cloned()
            .unwrap_or_default();
        let c = DiagnoseConfig::from_toml(&sec).unwrap();
        assert_eq!(c.folds, DiagnoseConfig::default().folds);
        assert_eq!(c.alpha, DiagnoseConfig::default().alpha);
    }
}

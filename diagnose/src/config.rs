//! `[diagnose]`: the one settings struct of the diagnosis,
//! parsed in one place for `sparkout run`, `sparkout diagnose` and
//! `sparkout validate` — a [`Section`] like every stage's: defaults here
//! only, ranges as data, checked before anything runs.

use crate::bail;
use serde::{Deserialize, Serialize};

use crate::config_check::{check_settings, read_section, Check, Checked, Section};

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
    /// Stability: an effect is selected only when its held-out gain holds
    /// (mean log RMS ratio ≥ `min_gain`) on at least this share of
    /// half-subsamples of the runs (its `selection_frequency`); below it
    /// the effect is "minor".
    pub min_selection_frequency: f64,
    /// Materiality: an effect is selected only when its held-out
    /// improvement removes at least this share of the observable's
    /// explainable gap (held-out mean square of the gap above the noise
    /// floor σ²; its `gap_share`); below it the effect is "minor".
    pub min_gap_share: f64,
    /// Covariates whose within-run correlation reaches |r| ≥ this move
    /// together on these runs: reported with the selected effect.
    pub collinear_r: f64,
    /// A selected effect's covariate with a variance inflation factor
    /// (within runs, against the other covariates) ≥ this is reported as
    /// collinear.
    pub collinear_vif: f64,
    /// A rival that also passed the held-out test in the selected effect's
    /// round, on a covariate that moves with the selected one's within
    /// runs, is named beside it when it removes at least this share of the
    /// held-out gap the selected effect removes (Σ before − Σ after over
    /// the held-out units): the same gap, nearly as well explained by
    /// another cause the runs cannot rule out.
    pub confound_share: f64,
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
            min_selection_frequency: 0.8,
            min_gap_share: 0.03,
            collinear_r: 0.95,
            collinear_vif: 10.0,
            confound_share: 0.95,
        }
    }
}

impl Section for DiagnoseConfig {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("folds", Check::WholeIn(2, 1000)),
        ("seed", Check::WholeIn(0, i64::MAX)),
        ("alpha", Check::Probability),
        ("noise_margin", Check::AtLeastOne),
        ("max_effects", Check::WholeIn(1, 100)),
        ("min_gain", Check::NonNegative),
        ("min_selection_frequency", Check::Fraction),
        ("min_gap_share", Check::NonNegative),
        ("collinear_r", Check::Fraction),
        ("collinear_vif", Check::AtLeastOne),
        ("confound_share", Check::Fraction),
    ];
    fn validate(&self) -> Result<()> {
        if let Some(e) = &self.effects {
            if e.is_empty() {
                bail!("diagnose.effects is empty: name at least one effect or omit it");
            }
        }
        Ok(())
    }
}

impl DiagnoseConfig {
    /// `[diagnose]` → settings, checked. Unknown keys and bad values are
    /// errors naming the key ([`crate::ConfigError`]).
    pub fn from_toml(section: &toml::Table) -> Result<DiagnoseConfig> {
        read_section(section)
    }
    /// Settings built in code, held to the section's checks. Any u64 seed
    /// is valid in code (TOML holds seeds up to i64::MAX only, the check's
    /// bound for a config file).
    pub fn check(&self) -> Result<()> {
        check_settings(&DiagnoseConfig {
            seed: 0,
            ..self.clone()
        })
    }
    /// Settings built in code, checked once ([`DiagnoseConfig::check`]),
    /// for [`crate::diagnose_checked`].
    pub fn checked(self) -> Result<Checked<DiagnoseConfig>> {
        self.check()?;
        Checked::checked_by_caller(self)
    }
    /// The same checked settings with another seed: any u64 seed is valid,
    /// so nothing is checked again (a validation diagnoses many fleets,
    /// each with its own seed).
    pub fn reseeded(
        checked: &Checked<DiagnoseConfig>,
        seed: u64,
    ) -> Result<Checked<DiagnoseConfig>> {
        Checked::checked_by_caller(DiagnoseConfig {
            seed,
            ..(**checked).clone()
        })
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
        assert!(e.contains("fold") && e.contains("known: folds"), "{e}");
        let bad: toml::Table = "folds = 1".parse().unwrap();
        assert!(DiagnoseConfig::from_toml(&bad).is_err());
        let bad: toml::Table = "alpha = \"x\"".parse().unwrap();
        assert!(DiagnoseConfig::from_toml(&bad).is_err());
        let bad: toml::Table = "effects = []".parse().unwrap();
        assert!(DiagnoseConfig::from_toml(&bad).is_err());
        let bad: toml::Table = "noise_margin = 0.5".parse().unwrap();
        assert!(DiagnoseConfig::from_toml(&bad).is_err());
    }
}

//! Step 4, candidates: the catalogue on the observable's varying covariates,
//! plus the composites of the plugins *in scope* for it:
//! a plugin's physically named effects apply only to the observables that
//! plugin produces; the catalogue applies everywhere.

use crate::bail;

use super::effect::{Effect, Kind};
use super::{DiagnoseConfig, Notes};
use crate::Result;

/// A plugin's composites and the observables they apply to.
#[derive(Clone, Copy)]
pub struct EffectScope<'a> {
    /// Plugin name (for notes); "" for effects given without a plugin.
    pub plugin: &'a str,
    /// `None`: every observable of the table.
    pub observables: Option<&'a [String]>,
    pub effects: &'a [Box<dyn Effect>],
}

impl EffectScope<'_> {
    pub fn applies_to(&self, observable: &str) -> bool {
        self.observables
            .is_none_or(|o| o.iter().any(|x| x == observable))
    }
}

/// Every name in `diagnose.effects` is a catalogue kind or an in-scope
/// composite of some plugin.
pub fn check_wanted(cfg: &DiagnoseConfig, scopes: &[EffectScope]) -> Result<()> {
    if let Some(wanted) = &cfg.effects {
        for w in wanted {
            let known = Kind::from_name(w).is_some()
                || scopes
                    .iter()
                    .flat_map(|s| s.effects.iter())
                    .any(|e| e.name() == w);
            if !known {
                bail!("unknown effect `{w}` in diagnose.effects (catalogue: offset, scale, drift, lag, inertia, backlash, wear, compliance, bow, periodic, edge, squareness, thermal, or a plugin composite)");
            }
        }
    }
    Ok(())
}

/// The candidates of one observable: `builtin` (the catalogue on `names`)
/// then each in-scope composite whose covariates are all present, which
/// replaces the catalogue candidate it names physically.
pub fn candidates<'a>(
    cfg: &DiagnoseConfig,
    observable: &str,
    names: &[String],
    builtin: &'a [Box<dyn Effect>],
    scopes: &[EffectScope<'a>],
    notes: &mut Notes,
) -> Vec<&'a dyn Effect> {
    let wanted = |e: &dyn Effect| {
        cfg.effects
            .as_ref()
            .is_none_or(|w| w.iter().any(|n| n == e.name()))
    };
    let mut cands: Vec<&'a dyn Effect> = builtin
        .iter()
        .map(|b| b.as_ref())
        .filter(|e| wanted(*e))
        .collect();
    for scope in scopes.iter().filter(|s| s.applies_to(observable)) {
        for e in scope.effects {
            // A composite of another family of the plugin's observables
            // (e.g. the servo's lag on positions, k·v, on a velocity
            // error, where it is k·a) is no candidate here, nor a note.
            if !wanted(e.as_ref()) || !e.applies_to(observable) {
                continue;
            }
            let missing: Vec<String> = e
                .covariates()
                .into_iter()
                .filter(|c| !names.contains(c))
                .collect();
            if missing.is_empty() {
                if let Some(generic) = e.replaces() {
                    cands.retain(|c| c.key() != generic);
                }
                cands.push(e.as_ref());
            } else {
                notes.add(format!(
                    "{} not applicable: covariate {} absent or constant",
                    e.key(),
                    missing.join(",")
                ));
            }
        }
    }
    cands
}

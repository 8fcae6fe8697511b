//! An augmented model's spindle growth in the mill's physics
//! (`sparkout run --augment MODEL`). The diagnosis names the warm-up
//! growth on `tracker_dz` either in time — `thermal_growth:t_s` (this
//! plugin's composite) or `drift:t_s` — or, where thermal.parquet logs the
//! spindle, as `thermal:temp_c` (growth ∝ the spindle's warming, the
//! physically direct form). Its physical home is the spindle: the tool
//! point moves by g along machine z while the static geometric model holds
//! still (docs/models.md §5), g the effect's change since the first tracker
//! point (the rest is its constant offset). Then
//!
//! - `observe` re-simulates tracker_dz as the model's deviation plus g and
//!   the offset into `sim_augmented` (tracker_dx/dy keep the plain sim:
//!   the growth is along z);
//! - `kinematics` takes g out of the compensation path replay sends (dz − g
//!   along the measured sequence; temperatures as observe reads them by
//!   default, the mean of thermal.parquet's sensors).
//!
//! As a machine-frame displacement the growth re-simulates exactly as the
//! added term would; what the physics adds is the compensation.

use sparkout_pipeline::diagnose::augment::{join_keys, AugmentEffect};
use sparkout_pipeline::StageContext;

/// The observable the growth is read from.
pub const OBSERVABLE: &str = "tracker_dz";

/// The model's spindle growth effects on `t_s` for `tracker_dz`.
pub struct SpindleGrowth<'a> {
    effects: Vec<&'a AugmentEffect>,
}

impl<'a> SpindleGrowth<'a> {
    /// None when the stage has no model or the model has no such effect.
    pub fn of(ctx: &StageContext<'a>) -> Option<SpindleGrowth<'a>> {
        let effects: Vec<&AugmentEffect> = ctx
            .augment?
            .effects_for(OBSERVABLE)
            .filter(|e| {
                (matches!(e.name(), "thermal_growth" | "drift") && e.covariates == ["t_s"])
                    || (e.name() == "thermal" && e.covariates == ["temp_c"])
            })
            .collect();
        (!effects.is_empty()).then_some(SpindleGrowth { effects })
    }

    /// The effects' keys (`sim_augmented_effects`).
    pub fn keys(&self) -> String {
        join_keys(self.effects.iter().map(|e| e.key.as_str()))
    }

    /// Whether an effect reads the spindle temperature.
    pub fn needs_temperature(&self) -> bool {
        self.effects.iter().any(|e| e.covariates == ["temp_c"])
    }

    /// (g, the constant offset) per tracker point, from its time and (when
    /// an effect reads it) temperature; g is each effect's change since the
    /// first point. None when an effect cannot be evaluated (or needs a
    /// temperature that is not there).
    pub fn growth_and_offset(
        &self,
        t_s: &[f64],
        temp_c: Option<&[f64]>,
    ) -> Option<(Vec<f64>, f64)> {
        let (mut g, mut offset) = (vec![0.0; t_s.len()], 0.0);
        for e in &self.effects {
            let cov = if e.covariates == ["temp_c"] {
                temp_c?
            } else {
                t_s
            };
            let at = e.predict(&[cov.to_vec()])?;
            let base = at.first().copied().unwrap_or(0.0);
            offset += base;
            for (a, v) in g.iter_mut().zip(at) {
                *a += v - base;
            }
        }
        Some((g, offset))
    }
}

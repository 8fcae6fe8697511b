//! An augmented model's thermal bow in the gantry's physics
//! (`sparkout run --augment MODEL`). The diagnosis names the bridge's
//! thermal bow — `thermal_bow:y_mm,t_s` = bow(y)·drift(t), this plugin's
//! composite — on `surface_z`, as the material left on the polished
//! surface. Its physical home is the bridge: as it warms it lifts the tool
//! by b(y, t), the spring-loaded disc loses pressure b/compression, and
//! Preston removal falls by that share (docs/models.md §2.5). On a surface
//! polished to a mean depth R̄ the material left is R̄·b/compression, so
//! the fitted growth G(y, t) = effect(y, t) − effect(y, 0) (the part that
//! grows while polishing; the rest is the effect's constant offset) reads
//! as a lift b = G·compression/R̄. Then
//!
//! - `removal` re-simulates the removal with each path sample's pressure
//!   scaled by 1 − b/compression = 1 − G/R̄ (dwell ⊛ tool influence, as
//!   the plain prediction), plus the constant offset, into
//!   `final_augmented_mm`, which `observe` passes on as `sim_augmented`;
//! - `matrices` lowers the compensation path that replay sends by b — the
//!   thermal bow entering the bridge deflection Γ corrects.

use sparkout_pipeline::diagnose::augment::{join_keys, AugmentEffect};
use sparkout_pipeline::StageContext;

use super::observe::OBSERVABLE;

/// The model's thermal bow effects on (y_mm, t_s) for `surface_z`.
pub struct ThermalBow<'a> {
    effects: Vec<&'a AugmentEffect>,
}

impl<'a> ThermalBow<'a> {
    /// None when the stage has no model or the model has no thermal bow.
    pub fn of(ctx: &StageContext<'a>) -> Option<ThermalBow<'a>> {
        let effects: Vec<&AugmentEffect> = ctx
            .augment?
            .effects_for(OBSERVABLE)
            .filter(|e| e.name() == "thermal_bow" && e.covariates == ["y_mm", "t_s"])
            .collect();
        (!effects.is_empty()).then_some(ThermalBow { effects })
    }

    /// The effects' keys, joined by `;` (`sim_augmented_effects`; a key itself may hold a comma).
    pub fn keys(&self) -> String {
        join_keys(self.effects.iter().map(|e| e.key.as_str()))
    }

    fn value(&self, y_mm: &[f64], t_s: &[f64]) -> Option<Vec<f64>> {
        let mut v = vec![0.0; y_mm.len()];
        for e in &self.effects {
            for (a, x) in v.iter_mut().zip(e.predict(&[y_mm.to_vec(), t_s.to_vec()])?) {
                *a += x;
            }
        }
        Some(v)
    }

    /// The constant part effect(y, 0) per point (before polishing warms
    /// the bridge). None when an effect cannot be evaluated.
    pub fn offset(&self, y_mm: &[f64]) -> Option<Vec<f64>> {
        self.value(y_mm, &vec![0.0; y_mm.len()])
    }

    /// G(y, t) = effect(y, t) − effect(y, 0): the growth while polishing,
    /// per point. None when an effect cannot be evaluated.
    pub fn growth(&self, y_mm: &[f64], t_s: &[f64]) -> Option<Vec<f64>> {
        let at = self.value(y_mm, t_s)?;
        let at0 = self.offset(y_mm)?;
        Some(at.iter().zip(&at0).map(|(a, b)| a - b).collect())
    }
}

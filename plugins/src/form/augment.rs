//! An augmented model's wheel wear in the form grinder's physics
//! (`sparkout run --augment MODEL`). The diagnosis names a wheel
//! that wears with the volume it removes — `wheel_wear:removed_mm3` (this
//! plugin's composite) or the catalogue's `wear:removed_mm3` — on
//! `profile_error`, the gap along the profile normal. Its physical home is
//! the wheel radius: since its last dressing the wheel has lost w mm that
//! the controller does not know about, so
//!
//! - `observe` re-simulates each point for a wheel the controller places
//!   as radius r_k whose surface is w smaller (model::delta_at: δ + w,
//!   exact in the osculating-circle geometry of docs/models.md §4) into
//!   `sim_augmented`, listing the effect in `sim_augmented_effects` so the
//!   fleet step does not add it again;
//! - `profile_error` computes the compensation that replay sends for the
//!   worn wheel: the exact centre P + (r_k − w)·n instead of P + r_k·n, so
//!   the diagnosis reaches the machine.
//!
//! The fitted value (the gap the wear leaves along the normal, intercept
//! included) is read as w. Under this model the re-simulated gap equals
//! the additive one; what the physics adds is the compensation.

use sparkout_pipeline::diagnose::augment::{join_keys, AugmentEffect};
use sparkout_pipeline::StageContext;

/// The observable whose effects this reads.
pub const OBSERVABLE: &str = "profile_error";

/// The wear effects of an augmented model, evaluated as radius lost.
pub struct WheelWear<'a> {
    effects: Vec<&'a AugmentEffect>,
}

impl<'a> WheelWear<'a> {
    /// The model's wear effects on `removed_mm3` for `profile_error`; None
    /// when the stage has no model or the model has none.
    pub fn of(ctx: &StageContext<'a>) -> Option<WheelWear<'a>> {
        let model = ctx.augment?;
        let effects: Vec<&AugmentEffect> = model
            .effects_for(OBSERVABLE)
            .filter(|e| {
                matches!(e.name(), "wheel_wear" | "wear") && e.covariates == ["removed_mm3"]
            })
            .collect();
        (!effects.is_empty()).then_some(WheelWear { effects })
    }

    /// The effects' keys, joined by `;` (`sim_augmented_effects`; a key itself may hold a comma).
    pub fn keys(&self) -> String {
        join_keys(self.effects.iter().map(|e| e.key.as_str()))
    }

    /// Radius lost (mm) at each removed volume; None when an effect cannot
    /// be evaluated.
    pub fn radius_loss_mm(&self, removed_mm3: &[f64]) -> Option<Vec<f64>> {
        let mut w = vec![0.0; removed_mm3.len()];
        for e in &self.effects {
            for (a, v) in w.iter_mut().zip(e.predict(&[removed_mm3.to_vec()])?) {
                *a += v;
            }
        }
        Some(w)
    }
}

#[cfg(test)]
mod tests {
    use crate::form::curvature::{CurvatureConfig, Profile};
    use crate::form::model::{centre_path, delta_at, profile_error};
    use crate::form::profile_error::compensation;
    use crate::form::shapes::{ellipse_r, sample};
    use sparkout_pipeline::contracts::batch_f64;

    /// A worn wheel's compensation moves the centre in by the wear along
    /// the normal at every point, and its δ is the known wheel's plus the
    /// wear.
    #[test]
    fn wear_moves_the_compensated_centre_in_along_the_normal() {
        let (phi, r) = sample(720, |f| ellipse_r(f, 60.0, 40.0));
        let p = Profile::new(&phi, &r, &CurvatureConfig::default()).unwrap();
        let wear: Vec<f64> = (0..p.len()).map(|i| 1e-3 + 1e-5 * i as f64).collect();
        let plain = compensation(&p, 170.0, 160.0, None, 5.0);
        let worn = compensation(&p, 170.0, 160.0, Some(&wear), 5.0);
        let col = |b, c| batch_f64(b, c).unwrap().to_vec();
        let (dx0, dy0, dx1, dy1) = (
            col(&plain, "dx_mm"),
            col(&plain, "dy_mm"),
            col(&worn, "dx_mm"),
            col(&worn, "dy_mm"),
        );
        for i in 0..p.len() {
            let n = p.normal[i];
            let along = (dx1[i] - dx0[i]) * n[0] + (dy1[i] - dy0[i]) * n[1];
            let across = (dx1[i] - dx0[i]) * n[1] - (dy1[i] - dy0[i]) * n[0];
            assert!((along + wear[i]).abs() < 1e-12, "point {i}: {along}");
            assert!(across.abs() < 1e-12, "point {i}: {across}");
        }
        let path = centre_path(&p, 170.0);
        let d = profile_error(&p, &path, 160.0).unwrap();
        let f = p.phi_rad[100];
        assert!((delta_at(&p, &path, f, 160.0, 0.004).unwrap() - d[100] - 0.004).abs() < 1e-12);
    }
}

//! An augmented model's thermal growth in the guide-way grinder's physics
//! (`sparkout run --augment MODEL`). The diagnosis names
//! the workpiece's thermal growth with the number of infeeds —
//! `thermal_infeed:infeed_count` (this plugin's composite) or the
//! catalogue's `wear:infeed_count` — on `motion_error`. Its physical home
//! is g, the thermal term of the compensation F = f + g + δ̂z (docs/models.md
//! §3.4): g = κ·(infeed_count − 1). The fitted effect is linear in the
//! count, so κ is its value at count 2 less its value at count 1. Then
//!
//! - `observe` re-simulates motion_error with κ in the model
//!   (leave-pass-out straightness of δz − g, plus g of this pass) into
//!   `sim_augmented`, listing the effect in `sim_augmented_effects`;
//! - `compensation` builds F with that κ in g — the fleet's rate, fitted
//!   over every run the model saw, in place of the run's own fit (which is
//!   reported beside it) — so the command replay sends carries the
//!   diagnosis.

use sparkout_pipeline::diagnose::augment::{join_keys, AugmentEffect};
use sparkout_pipeline::StageContext;

use super::observe::OBSERVABLE;

/// The model's thermal growth per infeed, and the effects it came from.
pub struct ThermalGrowth {
    /// κ, mm per infeed.
    pub k_mm_per_infeed: f64,
    /// The effects' keys, joined by `;` (`sim_augmented_effects`; a key itself may hold a comma).
    pub keys: String,
}

impl ThermalGrowth {
    /// κ from the model's effects on `infeed_count` for `motion_error`;
    /// None when the stage has no model, the model has none, or they cannot
    /// be evaluated.
    pub fn of(ctx: &StageContext) -> Option<ThermalGrowth> {
        let effects: Vec<&AugmentEffect> = ctx
            .augment?
            .effects_for(OBSERVABLE)
            .filter(|e| {
                matches!(e.name(), "thermal_infeed" | "wear") && e.covariates == ["infeed_count"]
            })
            .collect();
        if effects.is_empty() {
            return None;
        }
        let mut k = 0.0;
        for e in &effects {
            let v = e.predict(&[vec![1.0, 2.0]])?;
            k += v[1] - v[0];
        }
        k.is_finite().then(|| ThermalGrowth {
            k_mm_per_infeed: k,
            keys: join_keys(effects.iter().map(|e| e.key.as_str())),
        })
    }
}

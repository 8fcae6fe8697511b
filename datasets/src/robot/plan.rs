//! Cell geometry and the probing plan. (Part of the robot generator; see mod.rs.)

use super::*;

// Geometry and plan

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Face {
    Xy,
    Yz,
    Zx,
}

impl Face {
    pub(super) const ALL: [Face; 3] = [Face::Xy, Face::Yz, Face::Zx];
    pub(super) fn label(self) -> &'static str {
        match self {
            Face::Xy => "xy",
            Face::Yz => "yz",
            Face::Zx => "zx",
        }
    }
    /// Index of the face's normal axis (the observable's normal coordinate).
    pub(super) fn axis(self) -> usize {
        match self {
            Face::Xy => 2,
            Face::Yz => 0,
            Face::Zx => 1,
        }
    }
    /// Outward unit normal of the nominal face (the block is on the other side).
    pub(super) fn normal(self) -> V3 {
        match self {
            Face::Xy => V3::new(0.0, 0.0, 1.0),
            Face::Yz => V3::new(-1.0, 0.0, 0.0),
            Face::Zx => V3::new(0.0, -1.0, 0.0),
        }
    }
    /// Nominal point `id` (0–3 outer, 4–7 middle, 8–11 inner square; corners
    /// counter-clockwise from (−,−)) relative to the datum.
    pub(super) fn point(self, id: usize) -> V3 {
        let h = SQUARE_HALF_MM[id / 4];
        let (su, sv) = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)][id % 4];
        match self {
            Face::Xy => V3::new(BLOCK_X_MM / 2.0 + su * h, BLOCK_Y_MM / 2.0 + sv * h, 0.0),
            Face::Yz => V3::new(0.0, BLOCK_Y_MM / 2.0 + su * h, -BLOCK_H_MM / 2.0 + sv * h),
            Face::Zx => V3::new(BLOCK_X_MM / 2.0 + su * h, 0.0, -BLOCK_H_MM / 2.0 + sv * h),
        }
    }
}

#[derive(Debug, Clone)]
pub(super) struct PlanRow {
    /// Plan order = motion segment; −1 for the comparison methods' program
    /// (not in plan.parquet).
    pub(super) seq: i32,
    pub(super) method: &'static str,
    pub(super) face: Face,
    pub(super) point: i32,
    pub(super) trial: i32,
    pub(super) speed_mm_s: f64,
    pub(super) nom: V3,
    /// Unit approach direction (= −outward normal).
    pub(super) dir: V3,
}

/// Program order: repeated sweeps (trial, then speed) over all three faces
/// and 12 points. Sweeping the whole pattern per repeat spreads each face's
/// touches over the whole probing time, so a slow drift is not absorbed
/// into a face's plane fit, and repeats of a point are not back to back.
pub(super) fn build_plan(cfg: &RobotFleetConfig) -> Vec<PlanRow> {
    let datum = V3::from(DATUM_NOM_MM);
    let mut plan = Vec::new();
    for trial in 0..cfg.trials {
        for &v in &cfg.speeds_mm_s {
            for face in Face::ALL {
                for p in 0..12 {
                    plan.push(PlanRow {
                        seq: plan.len() as i32,
                        method: "ae",
                        face,
                        point: p as i32,
                        trial: trial as i32,
                        speed_mm_s: v,
                        nom: datum + face.point(p),
                        dir: -face.normal(),
                    });
                }
            }
        }
    }
    plan
}

/// The comparison methods' program: every nominal point `trials` times per
/// method, sweeping the pattern like the AE plan; segment −1 (not a plan row).
pub(super) fn build_other_program(cfg: &RobotFleetConfig) -> Vec<PlanRow> {
    let datum = V3::from(DATUM_NOM_MM);
    let mut rows = Vec::new();
    for m in &cfg.other_methods {
        let method = m.label();
        for trial in 0..cfg.trials {
            for face in Face::ALL {
                for p in 0..12 {
                    rows.push(PlanRow {
                        seq: -1,
                        method,
                        face,
                        point: p as i32,
                        trial: trial as i32,
                        speed_mm_s: m.speed_mm_s,
                        nom: datum + face.point(p),
                        dir: -face.normal(),
                    });
                }
            }
        }
    }
    rows
}

/// σ of a method's registered touches at an approach speed.
pub(super) fn touch_sigma_mm(method: &str, v_mm_s: f64) -> f64 {
    match method {
        "mechanical" => MECHANICAL_RANGE_MM.0 / D2_N12 * v_mm_s / MECHANICAL_RANGE_MM.1,
        "electrical" => ELECTRICAL_RANGE_MM.0 / D2_N12 * v_mm_s / ELECTRICAL_RANGE_MM.1,
        _ => ae_touch_sigma_mm(v_mm_s),
    }
}

/// σ of the AE method's registered touches at an approach speed: the
/// thesis's ranges (docs/models.md §1.1) as σ = range/d2(12), interpolated
/// log-log in speed (25 µm @ 5 → 85 µm @ 10 mm/s: σ ∝ v^1.77).
pub(super) fn ae_touch_sigma_mm(v_mm_s: f64) -> f64 {
    let s5 = AE_RANGE_5_MM / D2_N12;
    let p = (AE_RANGE_10_MM / AE_RANGE_5_MM).ln() / 2f64.ln();
    s5 * (v_mm_s / 5.0).powf(p)
}

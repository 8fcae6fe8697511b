//! `profile_error`: δ(φ) of the design profile for the wheel radius the
//! run was actually ground with, against the nominal the program was made
//! for (docs/models.md §4), with the profile's curvature κ(φ) (κ, not ρ, so a
//! straight part stays finite).

use std::collections::BTreeSet;

use super::summary::{fin, ProfileErrorSummary, RadiusError, WearApplied};
use crate::bail;
use crate::form::tables::PROFILE;
use arrow::record_batch::RecordBatch;
use sparkout_pipeline::config_check::SectionCheck;
use sparkout_pipeline::contracts::BatchBuilder;
use sparkout_pipeline::{InputError, Result, Stage, StageContext, StageOutput, StageSpec};

use super::augment::WheelWear;
use super::config::ProfileErrorConfig;
use super::curvature::Profile;
use super::model::{
    centre_path, check_wheel_radius, feed_mm_s, process_f64, profile_error, profile_setup,
    wheel_usage, DeltaModel, ProfileRows, WheelRange,
};

/// The actual wheel radii of a run: the stage config's `wheel_radius_mm`,
/// else every distinct `wheel_radius_mm` of the measured rows, else
/// run.toml `[process] wheel_radius_mm`. Each must be in the usable range.
pub fn actual_radii(
    ctx: &StageContext,
    wheel_radius_mm: Option<f64>,
    rows: &ProfileRows,
    file: &std::path::Path,
    range: &WheelRange,
) -> Result<Vec<f64>> {
    if let Some(r) = wheel_radius_mm {
        if !range.contains(r) {
            bail!(
                "[form.profile_error].wheel_radius_mm = {r} is outside the machine's usable range [{}, {}] mm",
                range.r_min_mm(),
                range.r_max_mm
            );
        }
        return Ok(vec![r]);
    }
    let mut set = BTreeSet::new();
    for &i in &rows.measured_rows {
        if let Some(r) = rows.wheel[i] {
            check_wheel_radius(file, i, r, range)?;
            set.insert(r.to_bits());
        }
    }
    if set.is_empty() {
        if let Some(r) = process_f64(ctx.run, "wheel_radius_mm") {
            if !range.contains(r) {
                return Err(InputError::new(
                    ctx.run.spec.run_toml_path(),
                    format!(
                        "wheel radius {r} mm is outside the machine's usable range [{}, {}] mm",
                        range.r_min_mm(),
                        range.r_max_mm
                    ),
                )
                .column("process.wheel_radius_mm")
                .into());
            }
            return Ok(vec![r]);
        }
        return Err(InputError::new(
            file,
            "no actual wheel radius: the measured rows have no wheel_radius_mm, run.toml has no [process] wheel_radius_mm, and [form.profile_error] sets none",
        )
        .column("wheel_radius_mm")
        .into());
    }
    let mut v: Vec<f64> = set.into_iter().map(f64::from_bits).collect();
    v.sort_by(|a, b| b.total_cmp(a));
    Ok(v)
}

/// The `profile_error` artifact and summary for a profile, nominal and radii.
pub fn compute(
    p: &Profile,
    r_kn: f64,
    radii: &[f64],
    file: &std::path::Path,
    design_rows: &[usize],
    model: DeltaModel,
) -> Result<(RecordBatch, ProfileErrorSummary)> {
    let path = centre_path(p, r_kn).with_model(model);
    let n = p.len();
    let mut b_rk = Vec::new();
    let mut delta = Vec::new();
    let mut per = Vec::new();
    for &rk in radii {
        let d = profile_error(p, &path, rk).map_err(|i| {
            InputError::new(
                file,
                format!("a wheel of radius {rk} mm cannot follow the design profile here: its concave radius of curvature is smaller than the wheel"),
            )
            .column("r_mm")
            .row(design_rows[i])
        })?;
        let (mut mx, mut at) = (0.0_f64, p.phi_rad[0]);
        for (i, v) in d.iter().enumerate() {
            if v.abs() > mx.abs() {
                mx = *v;
                at = p.phi_rad[i];
            }
        }
        let rms = (d.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
        per.push(RadiusError {
            wheel_radius_mm: rk,
            max_error_mm: mx.abs(),
            signed_max_error_mm: mx,
            phi_at_max_rad: at,
            rms_error_mm: rms,
        });
        b_rk.extend(std::iter::repeat_n(rk, n));
        delta.extend(d);
    }
    let rep = |v: &[f64]| -> Vec<f64> { radii.iter().flat_map(|_| v.iter().copied()).collect() };
    let batch = BatchBuilder::new()
        .f64("wheel_radius_mm", b_rk)
        .f64("phi_rad", rep(&p.phi_rad))
        .f64("r_mm", rep(&p.r_mm))
        .f64("curvature_per_mm", rep(&p.kappa_per_mm))
        .f64("gamma0_rad", rep(&p.gamma0_rad))
        .f64("gamma_rad", rep(&path.gamma_rad))
        .f64("x_mm", rep(&path.x_mm))
        .f64("delta_mm", delta)
        .build();
    // A point counts as straight when its radius of curvature exceeds 100
    // times the profile's mean radius.
    let mean_r = p.r_mm.iter().sum::<f64>() / n as f64;
    let flat = p
        .kappa_per_mm
        .iter()
        .filter(|k| k.abs() * mean_r < 1e-2)
        .count();
    // The largest of the radii's errors that are defined (a NaN one was
    // written as null and never counted).
    let max_error_mm = per
        .iter()
        .map(|v| v.max_error_mm)
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    let summary = ProfileErrorSummary {
        nominal_mm: r_kn,
        delta_model: format!("{model:?}").to_lowercase(),
        points: n,
        closed: p.closed,
        straight_points: flat,
        curvature_max_per_mm: p
            .kappa_per_mm
            .iter()
            .cloned()
            .fold(f64::NEG_INFINITY, f64::max),
        curvature_min_per_mm: p.kappa_per_mm.iter().cloned().fold(f64::INFINITY, f64::min),
        radii: per,
        max_error_mm,
        augmented: None,
    };
    Ok((batch, summary))
}

pub struct ProfileErrorStage;

const SPEC: StageSpec = StageSpec {
    name: "profile_error",
    // 2: compensation for the worn wheel under `run --augment`; summary `augmented`.
    version: 2,
    reads: &[&PROFILE],
    reads_artifacts: &[],
    writes: &["profile_error", "compensation"],
    reads_augmented_model: true,
    about: "profile error δ(φ) of the design profile for the actual wheel radius vs the programmed nominal, with curvature κ(φ) (docs/models.md §4)",
    config: SectionCheck::of::<ProfileErrorConfig>(),
};

impl Stage for ProfileErrorStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let cfg: &ProfileErrorConfig = ctx.section()?;
        let (range, t, rows, p, r_kn) = profile_setup(ctx, cfg.window_points, cfg.nominal_mm)?;
        let radii = actual_radii(ctx, cfg.wheel_radius_mm, &rows, t.path(), &range)?;
        let (batch, summary) = compute(
            &p,
            r_kn,
            &radii,
            t.path(),
            &rows.design_rows,
            cfg.delta_model,
        )?;
        let feed = feed_mm_s(ctx.run)?;
        // `run --augment`: a fitted wheel wear makes the compensation that
        // replay sends the one for the worn wheel (form/augment.rs), along
        // the volume the wheel removes over the profile.
        let (wear_mm, augmented) = match (WheelWear::of(ctx), wheel_usage(ctx.run)) {
            (Some(w), Some((v0, area))) => {
                let removed: Vec<f64> = p.arc_length_mm().iter().map(|s| v0 + area * s).collect();
                let loss = w.radius_loss_mm(&removed);
                let info = WearApplied::Applied {
                    in_physics: w.keys(),
                    wear_max_mm: loss
                        .as_ref()
                        .and_then(|l| fin(l.iter().fold(0.0f64, |m, v| m.max(v.abs())))),
                };
                (loss, Some(info))
            }
            (Some(w), None) => (
                None,
                Some(WearApplied::NotApplied {
                    in_physics: None,
                    not_applied: w.keys(),
                    why: "run.toml gives no removed_before_mm3 and stock_mm: the wheel's usage is unknown".into(),
                }),
            ),
            _ => (None, None),
        };
        // The largest actual radius (the first) gets the compensation.
        let comp = compensation(&p, r_kn, radii[0], wear_mm.as_deref(), feed);
        let summary = ProfileErrorSummary {
            augmented,
            ..summary
        };
        Ok(StageOutput::typed(&summary)?
            .with("profile_error", batch)
            .with("compensation", comp))
    }
}

/// The wheel-centre correction that removes δ for the actual radius
/// `r_k`: the exact centre P + R_k·n minus the one the controller uses
/// (the programmed P + R_kn·n moved radially in by R_kn − R_k), in the
/// work's plane, per profile point at t_s = arc length / feed (strictly
/// increasing). With `wear_mm` (per profile point, `run --augment`) the
/// wheel is smaller than the controller knows by that much: the exact
/// centre is P + (R_k − w)·n. The shape CAN replay reads: t_s, dx_mm, dy_mm.
pub fn compensation(
    p: &Profile,
    r_kn: f64,
    r_k: f64,
    wear_mm: Option<&[f64]>,
    feed_mm_s: f64,
) -> RecordBatch {
    let arc = p.arc_length_mm();
    let d = r_kn - r_k;
    let (mut dx, mut dy) = (Vec::with_capacity(p.len()), Vec::with_capacity(p.len()));
    for i in 0..p.len() {
        let pt = p.point(i);
        let n = p.normal[i];
        let cn = [pt[0] + r_kn * n[0], pt[1] + r_kn * n[1]];
        let re = cn[0].hypot(cn[1]);
        let ctrl = [cn[0] - d * cn[0] / re, cn[1] - d * cn[1] / re];
        let r_actual = r_k - wear_mm.map_or(0.0, |w| w[i]);
        dx.push(pt[0] + r_actual * n[0] - ctrl[0]);
        dy.push(pt[1] + r_actual * n[1] - ctrl[1]);
    }
    BatchBuilder::new()
        .f64("t_s", arc.iter().map(|s| s / feed_mm_s).collect())
        .f64("phi_rad", p.phi_rad.clone())
        .f64("dx_mm", dx)
        .f64("dy_mm", dy)
        .build()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::form::curvature::CurvatureConfig;
    use crate::form::shapes::{ellipse_r, sample};
    use sparkout_pipeline::contracts::batch_f64;

    /// The correction's component along the normal is δ to first order
    /// (moving the centre by it removes the error); t_s increases strictly.
    #[test]
    fn compensation_removes_the_error_along_the_normal() {
        let (phi, r) = sample(720, |f| ellipse_r(f, 60.0, 40.0));
        let p = Profile::new(&phi, &r, &CurvatureConfig::default()).unwrap();
        let b = compensation(&p, 170.0, 160.0, None, 5.0);
        let (t, dx, dy) = (
            batch_f64(&b, "t_s").unwrap(),
            batch_f64(&b, "dx_mm").unwrap(),
            batch_f64(&b, "dy_mm").unwrap(),
        );
        assert!(t.windows(2).all(|w| w[1] > w[0]));
        let path = centre_path(&p, 170.0);
        let delta = profile_error(&p, &path, 160.0).unwrap();
        for i in 0..p.len() {
            let along = -(dx[i] * p.normal[i][0] + dy[i] * p.normal[i][1]);
            assert!(
                (along - delta[i]).abs() < 0.05 * delta[i].abs() + 1e-6,
                "{i}: {along} vs {}",
                delta[i]
            );
        }
    }
}

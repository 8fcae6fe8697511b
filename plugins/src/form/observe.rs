//! `observe`: paired observations (docs/formats.md §7) for the gap diagnosis.
//!
//! `profile_error`, one row per measured profile point: real = the measured
//! deviation from the design profile along the profile normal,
//! (r_measured − R_design(φ))·cos γ0(φ); sim = the model's δ(φ) for the
//! wheel radius that point was ground with (its `wheel_radius_mm`) against
//! the programmed nominal (docs/models.md §4). What is left is what the model
//! lacks: wheel wear since the last dressing, run-out, thermal growth …
//!
//! Covariates: phi_rad, wheel_radius_mm, t_s (the profile's own `t_s`
//! column when it has one, else the arc length from the first design point
//! over the run's `[process] feed_mm_s`), and removed_mm3 — the volume the
//! wheel has removed since its last dressing when the point was ground:
//! `[process] removed_before_mm3` + stock_mm × wheel width × arc length
//! (only when run.toml gives removed_before_mm3 and stock_mm). Wear of the
//! wheel grows with removed volume (grinding ratio), so a wheel that wears
//! between dressings shows up as `wear:removed_mm3`.

use std::collections::BTreeMap;

use super::summary::{ObserveAugmented, ObserveSummary};
use crate::bail;
use crate::form::tables::PROFILE;
use sparkout_pipeline::config_check::SectionCheck;
use sparkout_pipeline::contracts::BatchBuilder;
use sparkout_pipeline::{InputError, Result, Stage, StageContext, StageOutput, StageSpec};

use super::augment::WheelWear;
use super::config::ObserveConfig;
use super::model::{
    centre_path, check_wheel_radius, delta_at, feed_mm_s, process_f64, profile_error,
    profile_setup, wheel_usage,
};

pub struct ObserveStage;

const SPEC: StageSpec = StageSpec {
    name: "observe",
    // 2: `sim_augmented` (+ effects) under `run --augment`; summary `augmented`.
    version: 2,
    reads: &[&PROFILE],
    reads_artifacts: &[],
    writes: &["observations"],
    reads_augmented_model: true,
    about: "paired observations profile_error (measured vs δ(φ) of the model; covariates phi_rad, wheel_radius_mm, t_s, removed_mm3)",
    config: SectionCheck::of::<ObserveConfig>(),
};

impl Stage for ObserveStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let cfg: &ObserveConfig = ctx.section()?;
        let (range, t, rows, p, r_kn) = profile_setup(ctx, cfg.window_points, cfg.nominal_mm)?;
        let file = t.path();
        let path = centre_path(&p, r_kn).with_model(cfg.delta_model);
        let arc = p.arc_length_mm();
        let feed = feed_mm_s(ctx.run)?;
        let usage = wheel_usage(ctx.run);
        // `run --augment`: a fitted wheel wear re-simulated as the radius
        // the wheel lost (form/augment.rs), where the run says how much
        // the wheel has removed.
        let wear = WheelWear::of(ctx).filter(|_| usage.is_some());
        let process_radius = process_f64(ctx.run, "wheel_radius_mm");
        if rows.measured_rows.is_empty() {
            bail!(
                "{}: no `measured` rows: nothing to compare the model with",
                file.display()
            );
        }
        // δ on the design grid per distinct radius (a run usually has one).
        let mut deltas: BTreeMap<u64, Vec<f64>> = BTreeMap::new();
        let (mut sim, mut real, mut phi, mut wr, mut ts, mut rem) = (
            Vec::new(),
            Vec::new(),
            Vec::new(),
            Vec::new(),
            Vec::new(),
            Vec::new(),
        );
        for &i in &rows.measured_rows {
            let f = rows.phi[i];
            let rk = match rows.wheel[i].or(process_radius) {
                Some(r) => r,
                None => {
                    return Err(InputError::new(
                        file,
                        "measured row without wheel_radius_mm (and no [process] wheel_radius_mm in run.toml): the model needs the radius the point was ground with",
                    )
                    .column("wheel_radius_mm")
                    .row(i)
                    .into())
                }
            };
            check_wheel_radius(file, i, rk, &range)?;
            let d = match deltas.get(&rk.to_bits()) {
                Some(d) => d,
                None => {
                    let d = profile_error(&p, &path, rk).map_err(|k| {
                        InputError::new(file, format!("a wheel of radius {rk} mm cannot follow the design profile here (concave radius smaller than the wheel)"))
                            .column("r_mm")
                            .row(rows.design_rows[k])
                    })?;
                    deltas.entry(rk.to_bits()).or_insert(d)
                }
            };
            let (Some(r_design), Some(g0), Some(s), Some(dl)) = (
                p.r_at(f),
                p.value_at(f, &p.gamma0_rad),
                p.value_at(f, &arc),
                p.value_at(f, d),
            ) else {
                return Err(InputError::new(
                    file,
                    format!(
                        "measured φ = {f} rad lies outside the design profile's φ range [{}, {}]",
                        p.phi_rad[0],
                        p.phi_rad[p.len() - 1]
                    ),
                )
                .column("phi_rad")
                .row(i)
                .into());
            };
            sim.push(dl);
            real.push((rows.r[i] - r_design) * g0.cos());
            phi.push(f);
            wr.push(rk);
            ts.push(rows.t_s.as_ref().and_then(|t| t[i]).unwrap_or(s / feed));
            if let Some((v0, area)) = usage {
                rem.push(v0 + area * s);
            }
        }
        let n = sim.len();
        // The worn wheel per row (None where it cannot follow the profile:
        // that row keeps the plain sim and the fleet step adds the effect).
        let sim_aug: Option<Vec<Option<f64>>> = wear.as_ref().map(|w| {
            let loss = w.radius_loss_mm(&rem).unwrap_or_else(|| vec![f64::NAN; n]);
            (0..n)
                .map(|k| delta_at(&p, &path, phi[k], wr[k], loss[k]).filter(|v| v.is_finite()))
                .collect()
        });
        let gap: Vec<f64> = real.iter().zip(&sim).map(|(r, s)| r - s).collect();
        let rms = (gap.iter().map(|g| g * g).sum::<f64>() / n as f64).sqrt();
        let mut b = BatchBuilder::new()
            .str("run", &vec![ctx.run.spec.id.as_str(); n])
            .str("observable", &vec!["profile_error"; n])
            .f64("sim", sim)
            .f64("real", real)
            .f64("phi_rad", phi)
            .f64("wheel_radius_mm", wr)
            .f64("t_s", ts);
        if usage.is_some() {
            b = b.f64("removed_mm3", rem);
        }
        let augmented = match (&wear, sim_aug) {
            (Some(w), Some(aug)) => {
                let keys = w.keys();
                let listed: Vec<Option<&str>> =
                    aug.iter().map(|v| v.map(|_| keys.as_str())).collect();
                let applied = listed.iter().flatten().count();
                b = b
                    .opt_f64("sim_augmented", aug)
                    .opt_str("sim_augmented_effects", listed);
                Some(ObserveAugmented {
                    in_physics: keys,
                    rows: applied,
                })
            }
            _ => None,
        };
        let mut covariates = vec!["phi_rad", "wheel_radius_mm", "t_s"];
        if usage.is_some() {
            covariates.push("removed_mm3");
        }
        let summary = ObserveSummary {
            observable: "profile_error".into(),
            rows: n,
            nominal_mm: r_kn,
            wheel_radii_mm: deltas.keys().map(|k| f64::from_bits(*k)).collect(),
            gap_rms_mm: rms,
            gap_mean_mm: gap.iter().sum::<f64>() / n as f64,
            covariates: covariates.into_iter().map(String::from).collect(),
            nominal_source: if cfg.nominal_mm.is_some() {
                "config"
            } else {
                "run"
            }
            .into(),
            augmented,
        };
        Ok(StageOutput::typed(&summary)?.with("observations", b.build()))
    }
}

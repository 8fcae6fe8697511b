//! `compensation`: the headstock command for the next sample (docs/models.md
//! §3.4)
//!
//! ```text
//! F(n+1) = f(n+1) + g(n+1) + δ̂z(n+1) (+ the reversal constant C)
//! ```
//!
//! - f: the nominal headstock path, down one infeed per pass:
//!   f = −infeed_mm·(infeed_count − 1).
//! - g: workpiece thermal deformation, which the source says depends mainly
//!   on the infeed value and the number of infeeds. Fitted on the run's
//!   measured δz together with the table's repeatable straightness s(x) and
//!   its reversal error: δz(n) = s(j) + κ·(count − 1) + κ_T·(T − T₀) +
//!   (C_t/2)·dir + e, by least squares with s free per grid point (the
//!   per-point means are projected out). κ needs ≥ 2 infeed counts
//!   ("repeated passes"), κ_T a varying temp_c, C_t both directions.
//!   g = κ·(count − 1) + κ_T·(T(n) − T₀), with the last measured T.
//! - δ̂z(n+1): the predictor's AR model (order and coefficients of the
//!   `predictor` stage) one step ahead on the *table part* δz − g − C_t/2·dir,
//!   so the thermal and reversal terms are not counted twice.
//! - table reversal: (C_t/2)·dir(n+1), known from the program;
//!   headstock reversal: + (C/2)·sign(ΔF) with C = `backlash_mm` (machine
//!   `[headstock] backlash_mm`), so the command jumps by C whenever F
//!   changes direction relative to F(n), as docs/models.md §3.4 says.
//!
//! Artifact `compensation` (one row per predicted sample): n, t_s, x_mm,
//! dir, f_mm, g_mm, dz_pred_mm, reversal_mm, backlash_mm, F_mm, and dz_mm =
//! F − f, the offset to add to the nominal path — with t_s strictly
//! increasing this is the shape CAN replay reads (t_s + dz_mm).

use crate::err;
use crate::guideway::tables::GUIDEWAY;
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use sparkout_pipeline::config_check::SectionCheck;
use sparkout_pipeline::contracts::BatchBuilder;
use sparkout_pipeline::{InputError, Result, Stage, StageContext, StageOutput, StageSpec};

use super::ar_fpe;
use super::augment::ThermalGrowth;
use super::config::{
    machine_f64, machine_section, AutoOff, CompensationConfig, MachineHeadstock, MachineProcess,
};
use super::predictor::PredictorSummary;
use super::separate::SepData;

/// The fitted thermal and reversal terms.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ThermalReversal {
    /// mm per infeed (None: not fitted).
    pub k_mm_per_infeed: Option<f64>,
    pub k_sigma: Option<f64>,
    /// mm per °C.
    pub k_mm_per_c: Option<f64>,
    pub k_c_sigma: Option<f64>,
    pub t0_c: f64,
    /// Table reversal error C_t (mm): δz jumps by C_t when dir goes − → +.
    pub c_mm: Option<f64>,
    pub c_sigma: Option<f64>,
    pub residual_rms_mm: f64,
    pub notes: Vec<String>,
}

impl ThermalReversal {
    /// g(n) for a sample given its count and (last measured) temperature.
    pub fn g(&self, count: i32, temp: Option<f64>) -> f64 {
        let mut g = self.k_mm_per_infeed.unwrap_or(0.0) * (count - 1) as f64;
        if let (Some(k), Some(t)) = (self.k_mm_per_c, temp) {
            g += k * (t - self.t0_c);
        }
        g
    }
    pub fn reversal(&self, dir: f64) -> f64 {
        self.c_mm.unwrap_or(0.0) / 2.0 * dir
    }
    /// As `compensation.json` `fit` holds it.
    pub fn to_summary(&self) -> ThermalReversalFit {
        ThermalReversalFit {
            thermal_k_mm_per_infeed: self.k_mm_per_infeed,
            thermal_k_sigma_mm_per_infeed: self.k_sigma,
            thermal_k_mm_per_c: self.k_mm_per_c,
            thermal_k_sigma_mm_per_c: self.k_c_sigma,
            t0_c: self.t0_c,
            reversal_c_mm: self.c_mm,
            reversal_c_sigma_mm: self.c_sigma,
            residual_rms_mm: self.residual_rms_mm,
            notes: self.notes.clone(),
        }
    }
    /// The terms back from `compensation.json` `fit` (without its notes).
    pub fn from_summary(f: &ThermalReversalFit) -> ThermalReversal {
        ThermalReversal {
            k_mm_per_infeed: f.thermal_k_mm_per_infeed,
            k_sigma: f.thermal_k_sigma_mm_per_infeed,
            k_mm_per_c: f.thermal_k_mm_per_c,
            k_c_sigma: f.thermal_k_sigma_mm_per_c,
            t0_c: f.t0_c,
            c_mm: f.reversal_c_mm,
            c_sigma: f.reversal_c_sigma_mm,
            residual_rms_mm: f.residual_rms_mm,
            notes: Vec::new(),
        }
    }
}

/// `compensation.json` `fit`: the fitted thermal and reversal terms
/// (`null`: not fitted).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ThermalReversalFit {
    pub thermal_k_mm_per_infeed: Option<f64>,
    pub thermal_k_sigma_mm_per_infeed: Option<f64>,
    pub thermal_k_mm_per_c: Option<f64>,
    pub thermal_k_sigma_mm_per_c: Option<f64>,
    /// Reference temperature (`null` reads as 0 °C).
    #[serde(deserialize_with = "zero_if_null")]
    pub t0_c: f64,
    pub reversal_c_mm: Option<f64>,
    pub reversal_c_sigma_mm: Option<f64>,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub residual_rms_mm: f64,
    pub notes: Vec<String>,
}

fn zero_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(0.0))
}

/// `compensation.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CompensationSummary {
    /// Predicted samples (rows of `compensation`).
    pub rows: usize,
    /// Differencing and AR order of the predictor used.
    pub d: usize,
    pub order: usize,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub infeed_mm: f64,
    /// Headstock reversal constant C.
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub backlash_mm: f64,
    pub fit: ThermalReversalFit,
    /// g per mm of cumulative infeed (value × count), when the infeed is known.
    pub thermal_k_per_mm_infeed: Option<f64>,
    /// RMS of the offsets F − f.
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub dz_rms_mm: f64,
    /// RMS of the predictor's one-step residual: the offset error left.
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub prediction_residual_rms_mm: f64,
    /// The columns CAN replay reads.
    pub replay_columns: Vec<String>,
    /// `null` without a thermal growth from `run --augment`.
    pub augmented: Option<CompensationAugmented>,
}

/// `compensation.json` `augmented`: the fleet's thermal growth per infeed
/// g uses, and the run's own fit beside it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CompensationAugmented {
    pub in_physics: String,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub k_mm_per_infeed: f64,
    pub k_mm_per_infeed_run_fit: Option<f64>,
}

/// Fit κ, κ_T, C_t with s(j) free (see the module doc).
pub fn fit_thermal_reversal(s: &SepData, thermal: bool, reversal: bool) -> ThermalReversal {
    let n = s.len();
    let mut out = ThermalReversal {
        t0_c: s.temp_c.as_ref().map(|t| t[0]).unwrap_or(0.0),
        ..Default::default()
    };
    let mut cols: Vec<(&str, Vec<f64>)> = Vec::new();
    let distinct = |v: &[f64]| v.iter().any(|x| (x - v[0]).abs() > 1e-12);
    if thermal {
        let c: Vec<f64> = s.infeed_count.iter().map(|c| (*c - 1) as f64).collect();
        if distinct(&c) {
            cols.push(("count", c));
        } else {
            out.notes
                .push("one infeed count only: thermal growth per infeed not fitted".into());
        }
        match &s.temp_c {
            Some(t) if distinct(t) => cols.push(("temp", t.iter().map(|x| x - out.t0_c).collect())),
            Some(_) => out
                .notes
                .push("temp_c does not vary: thermal expansion per °C not fitted".into()),
            None => {}
        }
    }
    if reversal {
        let d: Vec<f64> = s.dir.iter().map(|d| d / 2.0).collect();
        if distinct(&d) {
            cols.push(("dir", d));
        } else {
            out.notes
                .push("one travel direction only: reversal error not fitted".into());
        }
    }
    // Project out the per-point means (s(j) free).
    let m = s.j.iter().max().map(|m| m + 1).unwrap_or(0);
    let demean = |v: &[f64]| -> Vec<f64> {
        let mut sum = vec![0.0; m];
        let mut cnt = vec![0usize; m];
        for (i, &j) in s.j.iter().enumerate() {
            sum[j] += v[i];
            cnt[j] += 1;
        }
        (0..n)
            .map(|i| v[i] - sum[s.j[i]] / cnt[s.j[i]] as f64)
            .collect()
    };
    let y = demean(&s.dz_mm);
    let points = {
        let mut seen = vec![false; m];
        s.j.iter().for_each(|&j| seen[j] = true);
        seen.iter().filter(|b| **b).count()
    };
    let xs: Vec<Vec<f64>> = cols.iter().map(|(_, c)| demean(c)).collect();
    let q = xs.len();
    let dof = n.saturating_sub(points + q);
    if q == 0 || dof < 2 {
        out.residual_rms_mm = (y.iter().map(|v| v * v).sum::<f64>() / n.max(1) as f64).sqrt();
        return out;
    }
    let x = DMatrix::from_fn(n, q, |i, c| xs[c][i]);
    let yv = DVector::from_column_slice(&y);
    let xtx = x.transpose() * &x;
    let Some(inv) = xtx.clone().try_inverse() else {
        out.notes
            .push("thermal and reversal regressors are collinear: not fitted".into());
        return out;
    };
    let beta = &inv * (x.transpose() * &yv);
    let res = &yv - &x * &beta;
    let rss = res.dot(&res);
    let s2 = rss / dof as f64;
    out.residual_rms_mm = (rss / n as f64).sqrt();
    for (c, (name, _)) in cols.iter().enumerate() {
        let (b, se) = (beta[c], (s2 * inv[(c, c)]).sqrt());
        match *name {
            "count" => (out.k_mm_per_infeed, out.k_sigma) = (Some(b), Some(se)),
            "temp" => (out.k_mm_per_c, out.k_c_sigma) = (Some(b), Some(se)),
            _ => (out.c_mm, out.c_sigma) = (Some(b), Some(se)),
        }
    }
    out
}

/// The compensation curve.
#[derive(Debug, Clone)]
pub struct Curve {
    pub rows: Vec<usize>,
    pub f: Vec<f64>,
    pub g: Vec<f64>,
    pub dz_pred: Vec<f64>,
    pub reversal: Vec<f64>,
    pub backlash: Vec<f64>,
    pub big_f: Vec<f64>,
    /// Table part measured − predicted at the same rows.
    pub residual: Vec<f64>,
}

/// F(n+1) for every sample the AR model can predict.
pub fn curve(
    s: &SepData,
    fit: &ThermalReversal,
    d: usize,
    coef: &[f64],
    infeed_mm: f64,
    backlash_mm: f64,
) -> Curve {
    let n = s.len();
    let temp_at = |i: usize| s.temp_c.as_ref().map(|t| t[i]);
    let table: Vec<f64> = (0..n)
        .map(|i| s.dz_mm[i] - fit.g(s.infeed_count[i], temp_at(i)) - fit.reversal(s.dir[i]))
        .collect();
    let y = ar_fpe::difference(&table, d);
    let c = ar_fpe::difference_poly(d);
    let p = coef.len();
    let mut out = Curve {
        rows: Vec::new(),
        f: Vec::new(),
        g: Vec::new(),
        dz_pred: Vec::new(),
        reversal: Vec::new(),
        backlash: Vec::new(),
        big_f: Vec::new(),
        residual: Vec::new(),
    };
    let (mut last_f0, mut sign) = (None::<f64>, 1.0);
    for m in (d + p).max(1)..n {
        let t = m - d;
        let y_hat: f64 = (0..p).map(|i| coef[i] * y[t - 1 - i]).sum();
        let prev: Vec<f64> = (1..=d).map(|i| table[m - i]).collect();
        let pred = ar_fpe::undifference(y_hat, &prev, &c);
        let f = -infeed_mm * (s.infeed_count[m] - 1) as f64;
        // Temperature of sample m is not known before it: the last reading.
        let g = fit.g(s.infeed_count[m], temp_at(m - 1));
        let rev = fit.reversal(s.dir[m]);
        let f0 = f + g + pred + rev;
        if let Some(l) = last_f0 {
            let df: f64 = f0 - l;
            if df != 0.0 {
                sign = df.signum();
            }
        }
        last_f0 = Some(f0);
        let bl = backlash_mm / 2.0 * sign;
        out.rows.push(m);
        out.f.push(f);
        out.g.push(g);
        out.dz_pred.push(pred);
        out.reversal.push(rev);
        out.backlash.push(bl);
        out.big_f.push(f0 + bl);
        out.residual.push(table[m] - pred);
    }
    out
}

pub struct CompensationStage;

const SPEC: StageSpec = StageSpec {
    name: "compensation",
    // 3: g from the augmented model's thermal growth under `run --augment`.
    version: 3,
    reads: &[],
    reads_artifacts: &["separation", "predictor"],
    writes: &["compensation"],
    reads_augmented_model: true,
    about: "headstock path F(n+1) = f + g + δ̂z + reversal, thermal g fitted from infeed count/temperature (docs/models.md §3.4); dz_mm offsets with t_s for CAN replay",
    config: SectionCheck::of::<CompensationConfig>(),
};

impl Stage for CompensationStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let s = SepData::from_batch(ctx.artifacts.require("separation")?.as_ref())?;
        let ps: PredictorSummary = ctx
            .artifacts
            .summary_as("predictor")
            .ok_or_else(|| err!("the predictor stage's summary is missing"))??;
        let d = ps.d;
        // A coefficient that could not be computed (`null`) is left out.
        let coef: Vec<f64> = ps
            .coefficients
            .iter()
            .copied()
            .filter(|c| c.is_finite())
            .collect();
        let cfg: &CompensationConfig = ctx.section()?;
        let mut fit = fit_thermal_reversal(
            &s,
            cfg.thermal == AutoOff::Auto,
            cfg.reversal == AutoOff::Auto,
        );
        // `run --augment`: g carries the fleet's thermal growth per infeed
        // (guideway/augment.rs); the run's own fit is reported beside it.
        let augmented = match ThermalGrowth::of(ctx) {
            Some(tg) => {
                let own = fit.k_mm_per_infeed;
                fit.k_mm_per_infeed = Some(tg.k_mm_per_infeed);
                fit.notes.push(format!(
                    "g uses the augmented model's {} per infeed ({})",
                    sparkout_pipeline::units::format::show_length(tg.k_mm_per_infeed),
                    tg.keys
                ));
                Some(CompensationAugmented {
                    in_physics: tg.keys,
                    k_mm_per_infeed: tg.k_mm_per_infeed,
                    k_mm_per_infeed_run_fit: own,
                })
            }
            None => None,
        };
        let infeed = cfg.infeed_mm.unwrap_or_else(|| {
            ctx.run.spec.process_f64(
                "infeed_mm",
                machine_f64(machine_section::<MachineProcess>(ctx.run).infeed_mm, 0.0),
            )
        });
        let backlash = cfg.backlash_mm.unwrap_or_else(|| {
            machine_f64(
                machine_section::<MachineHeadstock>(ctx.run).backlash_mm,
                0.0,
            )
        });
        let c = curve(&s, &fit, d, &coef, infeed, backlash);
        let t: Vec<f64> = c.rows.iter().map(|&i| s.t_s[i]).collect();
        if let Some(w) = t.windows(2).position(|w| w[1] <= w[0]) {
            return Err(InputError::new(
                ctx.run.table_path(&GUIDEWAY),
                format!(
                    "t_s does not increase ({} then {}): the compensation curve needs strictly increasing times",
                    t[w],
                    t[w + 1]
                ),
            )
            .column("t_s")
            .row(c.rows[w + 1])
            .into());
        }
        let offset: Vec<f64> = c.big_f.iter().zip(&c.f).map(|(a, b)| a - b).collect();
        let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
        let summary = CompensationSummary {
            rows: c.rows.len(),
            d,
            order: coef.len(),
            infeed_mm: infeed,
            backlash_mm: backlash,
            fit: fit.to_summary(),
            thermal_k_per_mm_infeed: fit
                .k_mm_per_infeed
                .filter(|_| infeed > 0.0)
                .map(|k| k / infeed),
            dz_rms_mm: rms(&offset),
            prediction_residual_rms_mm: rms(&c.residual),
            replay_columns: vec!["t_s".into(), "dz_mm".into()],
            augmented,
        };
        let pick = |v: &[f64]| c.rows.iter().map(|&i| v[i]).collect::<Vec<f64>>();
        let batch = BatchBuilder::new()
            .i64("n", c.rows.iter().map(|&i| s.n[i]).collect())
            .f64("t_s", t)
            .f64("x_mm", pick(&s.x_mm))
            .i8("dir", c.rows.iter().map(|&i| s.dir[i] as i8).collect())
            .f64("f_mm", c.f.clone())
            .f64("g_mm", c.g.clone())
            .f64("dz_pred_mm", c.dz_pred.clone())
            .f64("reversal_mm", c.reversal.clone())
            .f64("backlash_mm", c.backlash.clone())
            .f64("F_mm", c.big_f.clone())
            .f64("dz_mm", offset)
            .build();
        Ok(StageOutput::typed(&summary)?.with("compensation", batch))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// δz = s(j) + k·(count − 1) + C/2·dir + small wiggle, 8 passes.
    fn sep(k: f64, c: f64) -> SepData {
        let (m, passes) = (20usize, 8);
        let mut s = SepData {
            n: Vec::new(),
            x_mm: Vec::new(),
            h_mm: Vec::new(),
            dz_mm: Vec::new(),
            t_s: Vec::new(),
            dir: Vec::new(),
            pass: Vec::new(),
            infeed_count: Vec::new(),
            j: Vec::new(),
            temp_c: None,
        };
        for p in 0..passes {
            for j in crate::guideway::input::tests::pass_points(m, p as usize) {
                let i = s.n.len();
                let dir = if p % 2 == 0 { 1.0 } else { -1.0 };
                let wiggle = 1e-5 * ((i * 7919) % 13) as f64 / 13.0;
                s.n.push(i as i64);
                s.x_mm.push(j as f64 * 30.0);
                s.h_mm.push(0.0);
                s.dz_mm
                    .push(2e-3 * (j as f64 * 0.3).sin() + k * p as f64 + c / 2.0 * dir + wiggle);
                s.t_s.push(i as f64 * 0.1);
                s.dir.push(dir);
                s.pass.push(p);
                s.infeed_count.push(p + 1);
                s.j.push(j);
            }
        }
        s
    }

    #[test]
    fn thermal_growth_and_reversal_are_recovered() {
        let s = sep(4e-4, 2e-3);
        let f = fit_thermal_reversal(&s, true, true);
        let (k, c) = (f.k_mm_per_infeed.unwrap(), f.c_mm.unwrap());
        assert!((k - 4e-4).abs() < 3e-6, "{k}");
        assert!((c - 2e-3).abs() < 1e-5, "{c}");
        assert!(f.k_sigma.unwrap() > 0.0 && f.k_sigma.unwrap() < 1e-5);
        // Switched off: nothing fitted, the curve has no thermal part.
        let off = fit_thermal_reversal(&s, false, false);
        assert!(off.k_mm_per_infeed.is_none() && off.c_mm.is_none());
        // One pass only: not fitted, and said so.
        let mut one = sep(4e-4, 0.0);
        one.infeed_count.iter_mut().for_each(|c| *c = 1);
        let f1 = fit_thermal_reversal(&one, true, false);
        assert!(f1.k_mm_per_infeed.is_none() && !f1.notes.is_empty());
    }

    #[test]
    fn curve_adds_the_parts_and_takes_up_headstock_backlash() {
        let s = sep(4e-4, 2e-3);
        let f = fit_thermal_reversal(&s, true, true);
        let c = curve(&s, &f, 2, &[0.3], 0.005, 0.001);
        assert_eq!(c.rows[0], 3);
        for i in 0..c.rows.len() {
            let sum = c.f[i] + c.g[i] + c.dz_pred[i] + c.reversal[i] + c.backlash[i];
            assert!((c.big_f[i] - sum).abs() < 1e-15);
            assert_eq!(c.backlash[i].abs(), 0.0005);
        }
        // The table part left after g and C is the smooth straightness:
        // predicted one step ahead it beats "same as the last sample".
        let median = |mut r: Vec<f64>| {
            r.sort_by(f64::total_cmp);
            r[r.len() / 2]
        };
        let table = |i: usize| s.dz_mm[i] - f.g(s.infeed_count[i], None) - f.reversal(s.dir[i]);
        let ar = median(c.residual.iter().map(|v| v.abs()).collect());
        let persistence = median(
            c.rows
                .iter()
                .map(|&m| (table(m) - table(m - 1)).abs())
                .collect(),
        );
        assert!(ar < 0.5 * persistence, "{ar} vs {persistence}");
    }
}

//! `matrices`: the static and dynamic compensation matrices on the
//! machining grid (the pattern state's grid), docs/models.md §2.1–2.3.
//!
//! Per grid node (x, y) — bridge at x, spindle at y:
//! - stringer k: its straightness P_k(x) (piecewise quadratic Lagrange)
//!   minus its deflection under its own weight (uniform) and the bridge end
//!   load it carries at x: half the bridge weight plus its lever-rule share
//!   of spindle weight + cutting force (Qin), and of the travelling moment;
//! - bridge: its straightness at y minus its deflection under its own
//!   weight and the spindle + cutting force at y;
//! - τ(x, y) = (1 − s)·z₁(x) + s·z₂(x) + z_b(y), s = (y − y₁)/(y₂ − y₁):
//!   the bridge rests on both stringers, so each stringer's Z error reaches
//!   the tool by the lever rule. Each term is that body's share.
//!
//! τ_static uses the static influence lines; τ_dynamic replaces the moving
//! load's deflection on the body it travels along (stringers when passes
//! run along x, the bridge along y) by the moving-load series at the path
//! velocity. Γ = τ − τ_pattern for both.

use crate::err;
use crate::gantry::tables::TOPOGRAPHY;
use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use sparkout_pipeline::config_check::{NoKeys, SectionCheck};
use sparkout_pipeline::contracts::schema::MOTION;
use sparkout_pipeline::contracts::BatchBuilder;
use sparkout_pipeline::{InputError, Result, Stage, StageContext, StageOutput, StageSpec};

use super::augment::ThermalBow;
use super::grid::{self, Grid, Surface};
use super::machine::{Body, Gantry, PassAxis, BODIES};
use super::moving_load;
use super::removal::RemovalSummary;

/// τ on the grid and each body's share (row-major, y rows).
#[derive(Debug, Clone)]
pub struct Topography {
    pub tau: Vec<f64>,
    /// stringer1, stringer2, bridge.
    pub shares: [Vec<f64>; 3],
    pub max_terms: usize,
}

/// Both matrices.
#[derive(Debug, Clone)]
pub struct Matrices {
    pub grid: Grid,
    pub pattern: Vec<f64>,
    pub stat: Topography,
    pub dynamic: Topography,
    pub cut_force_n: f64,
    pub moment_n_mm: f64,
}

/// Deflection response of one body at its own load point g (load under the
/// tool), per unit force and per unit moment, static or moving at v.
fn unit_response(body: &Body, g: f64, v: f64, tol_rel: f64) -> Result<(f64, f64, usize)> {
    let b = &body.beam;
    let scale = b.span_mm.powi(3) / (48.0 * b.ei_n_mm2);
    let unit = |force_n, moment_n_mm| moving_load::MovingLoad {
        x_mm: g,
        at_mm: g,
        v_mm_s: v,
        force_n,
        moment_n_mm,
    };
    let f = moving_load::series(b, unit(1.0, 0.0), tol_rel * scale)
        .map_err(|e| err!("{}: {e}", body.name))?;
    let m = moving_load::series(b, unit(0.0, 1.0), tol_rel * scale / b.span_mm)
        .map_err(|e| err!("{}: {e}", body.name))?;
    Ok((f.w_mm, m.w_mm, f.terms.max(m.terms)))
}

/// τ over the grid; `dynamic` selects the moving-load series for the body
/// the load travels along.
pub fn topography(g: &Gantry, grid: &Grid, dynamic: bool) -> Result<Topography> {
    let f_cut = g.cut_force_n();
    let m = f_cut * g.cut_moment_arm_mm;
    let v = g.path_velocity_mm_s;
    let (v_str, v_br) = match (dynamic, g.pass_axis) {
        (false, _) => (0.0, 0.0),
        (true, PassAxis::X) => (v, 0.0),
        (true, PassAxis::Y) => (0.0, v),
    };
    // The travelling moment acts on the body the tool travels along.
    let (m_str, m_br) = match g.pass_axis {
        PassAxis::X => (m, 0.0),
        PassAxis::Y => (0.0, m),
    };
    let tol = g.series_tol_rel;
    let mut max_terms = 0;
    // Stringer responses per column x.
    let mut col = Vec::with_capacity(grid.nx());
    for i in 0..grid.nx() {
        let x = grid.x(i);
        let mut r = [(0.0, 0.0, 0.0); 2];
        for (k, body) in [&g.stringer1, &g.stringer2].into_iter().enumerate() {
            let (uf, um, n) = unit_response(body, x, v_str, tol)?;
            max_terms = max_terms.max(n);
            let base = body.straightness.eval(x) - body.w_n_mm() * body.beam.uniform(1.0, x);
            r[k] = (base, uf, um);
        }
        col.push(r);
    }
    // Bridge responses per row y (beam coordinate from stringer 1).
    let mut row = Vec::with_capacity(grid.ny());
    for j in 0..grid.ny() {
        let y = grid.y(j);
        let u = y - g.y_stringer1_mm;
        let b = &g.bridge;
        let (uf, um, n) = unit_response(b, u, v_br, tol)?;
        max_terms = max_terms.max(n);
        let base = b.straightness.eval(y) - b.w_n_mm() * b.beam.uniform(1.0, u);
        row.push(base + (g.spindle_weight_n + f_cut) * uf + m_br * um);
    }
    let n = grid.len();
    let mut tau = vec![0.0; n];
    let mut shares = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
    let half_bridge = 0.5 * g.bridge.weight_n;
    let carried = g.spindle_weight_n + f_cut;
    for (j, &zb) in row.iter().enumerate() {
        let s = g.share2(grid.y(j));
        for (i, c) in col.iter().enumerate() {
            let k = j * grid.nx() + i;
            let [(b1, f1, m1), (b2, f2, m2)] = *c;
            let z1 = b1 + (half_bridge + (1.0 - s) * carried) * f1 + (1.0 - s) * m_str * m1;
            let z2 = b2 + (half_bridge + s * carried) * f2 + s * m_str * m2;
            shares[0][k] = (1.0 - s) * z1;
            shares[1][k] = s * z2;
            shares[2][k] = zb;
            tau[k] = shares[0][k] + shares[1][k] + shares[2][k];
        }
    }
    Ok(Topography {
        tau,
        shares,
        max_terms,
    })
}

/// Check the grid lies within the machine's travel.
pub fn check_travel(g: &Gantry, grid: &Grid, topo: &std::path::Path) -> Result<(), InputError> {
    let l = g.stringer1.beam.span_mm.min(g.stringer2.beam.span_mm);
    if grid.x0 < 0.0 || grid.x_max() > l {
        return Err(InputError::new(
            topo,
            format!(
                "pattern grid x from {} to {} mm lies outside the stringers' span 0–{l} mm ({})",
                grid.x0,
                grid.x_max(),
                g.source
            ),
        )
        .column("x_mm"));
    }
    if grid.y0 < g.y_stringer1_mm || grid.y_max() > g.y_stringer2_mm {
        return Err(InputError::new(
            topo,
            format!(
                "pattern grid y from {} to {} mm lies outside the bridge between the stringers ({}–{} mm, {})",
                grid.y0,
                grid.y_max(),
                g.y_stringer1_mm,
                g.y_stringer2_mm,
                g.source
            ),
        )
        .column("y_mm"));
    }
    Ok(())
}

pub fn compute(g: &Gantry, pattern: &Surface) -> Result<Matrices> {
    Ok(Matrices {
        grid: pattern.grid,
        pattern: pattern.z.clone(),
        stat: topography(g, &pattern.grid, false)?,
        dynamic: topography(g, &pattern.grid, true)?,
        cut_force_n: g.cut_force_n(),
        moment_n_mm: g.cut_force_n() * g.cut_moment_arm_mm,
    })
}

impl Matrices {
    pub fn gamma(&self, t: &Topography) -> Vec<f64> {
        t.tau
            .iter()
            .zip(&self.pattern)
            .map(|(a, b)| a - b)
            .collect()
    }
    fn matrix_batch(&self, t: &Topography) -> arrow::record_batch::RecordBatch {
        let n = self.grid.len();
        let (xs, ys): (Vec<f64>, Vec<f64>) = (0..n).map(|k| self.grid.xy(k)).unzip();
        let mut b = BatchBuilder::new()
            .f64("x_mm", xs)
            .f64("y_mm", ys)
            .f64("value_mm", self.gamma(t))
            .f64("tau_mm", t.tau.clone())
            .f64("pattern_mm", self.pattern.clone());
        for (name, s) in BODIES.iter().zip(&t.shares) {
            b = b.f64(&format!("{name}_mm"), s.clone());
        }
        b.build()
    }
    /// The controller's table: nodes in row order (y outer, x inner) with
    /// grid indices, both Γ and the Z correction to apply (−Γ_dynamic).
    fn controller_batch(&self) -> arrow::record_batch::RecordBatch {
        let n = self.grid.len();
        let nx = self.grid.nx();
        let (xs, ys): (Vec<f64>, Vec<f64>) = (0..n).map(|k| self.grid.xy(k)).unzip();
        let gd = self.gamma(&self.dynamic);
        BatchBuilder::new()
            .i32("i", (0..n).map(|k| (k % nx) as i32).collect())
            .i32("j", (0..n).map(|k| (k / nx) as i32).collect())
            .f64("x_mm", xs)
            .f64("y_mm", ys)
            .f64("gamma_static_mm", self.gamma(&self.stat))
            .f64("gamma_dynamic_mm", gd.clone())
            .f64("correction_mm", gd.iter().map(|v| -v).collect())
            .build()
    }
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().map(|x| x.abs()).fold(0.0, f64::max)
}

/// `matrices.json` (and `stage matrices --topography FILE --json`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MatricesSummary {
    pub grid: GridSummary,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub cut_force_n: f64,
    /// Travelling moment, N·mm.
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub moment_n_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub path_velocity_mm_s: f64,
    pub critical_speed_mm_s: CriticalSpeeds,
    /// Most series terms the moving-load solution needed.
    pub series_terms_max: usize,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub gamma_static_max_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub gamma_dynamic_max_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub dynamic_minus_static_max_mm: f64,
    /// Largest |share| of τ per body (`stringer1`, `stringer2`, `bridge`).
    #[serde(deserialize_with = "crate::typed_summary::map_f64_or_nan")]
    pub static_share_max_mm: BTreeMap<String, f64>,
    #[serde(deserialize_with = "crate::typed_summary::map_f64_or_nan")]
    pub dynamic_share_max_mm: BTreeMap<String, f64>,
    pub compensation_path_rows: usize,
    /// Written by a run (`null` without a thermal bow from `run --augment`);
    /// absent from the run-less JSON.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "crate::typed_summary::present"
    )]
    pub augmented: Option<Option<MatricesAugmented>>,
}

/// `matrices.json` `grid`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct GridSummary {
    pub nx: usize,
    pub ny: usize,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub dx_mm: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub dy_mm: f64,
}

/// `matrices.json` `critical_speed_mm_s`, per beam.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CriticalSpeeds {
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub stringer1: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub stringer2: f64,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub bridge: f64,
}

/// `matrices.json` `augmented`: the bridge lift taken out of the path.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MatricesAugmented {
    pub in_physics: String,
    #[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]
    pub bridge_lift_max_mm: f64,
}

/// The stage summary (also the run-less JSON, without `augmented`).
pub fn summary(g: &Gantry, m: &Matrices, path_rows: usize) -> MatricesSummary {
    let gs = m.gamma(&m.stat);
    let gd = m.gamma(&m.dynamic);
    let shares = |t: &Topography| {
        BODIES
            .iter()
            .zip(&t.shares)
            .map(|(name, s)| (name.to_string(), max_abs(s)))
            .collect()
    };
    MatricesSummary {
        grid: GridSummary {
            nx: m.grid.nx(),
            ny: m.grid.ny(),
            dx_mm: m.grid.dx,
            dy_mm: m.grid.dy,
        },
        cut_force_n: m.cut_force_n,
        moment_n_mm: m.moment_n_mm,
        path_velocity_mm_s: g.path_velocity_mm_s,
        critical_speed_mm_s: CriticalSpeeds {
            stringer1: g.stringer1.beam.critical_speed_mm_s(),
            stringer2: g.stringer2.beam.critical_speed_mm_s(),
            bridge: g.bridge.beam.critical_speed_mm_s(),
        },
        series_terms_max: m.dynamic.max_terms,
        gamma_static_max_mm: max_abs(&gs),
        gamma_dynamic_max_mm: max_abs(&gd),
        dynamic_minus_static_max_mm: max_abs(
            &gd.iter().zip(&gs).map(|(a, b)| a - b).collect::<Vec<_>>(),
        ),
        static_share_max_mm: shares(&m.stat),
        dynamic_share_max_mm: shares(&m.dynamic),
        compensation_path_rows: path_rows,
        augmented: None,
    }
}

pub struct MatricesStage;

const SPEC: StageSpec = StageSpec {
    name: "matrices",
    // 2: under `run --augment` the compensation path lowers the tool by the
    // thermal bow's bridge lift (reads the removal summary's mean depth).
    version: 2,
    reads: &[&TOPOGRAPHY, &MOTION],
    reads_artifacts: &["removal"],
    writes: &[
            "static_matrix",
            "dynamic_matrix",
            "compensation_table",
            "compensation_path",
        ],
    reads_augmented_model: true,
    about: "static and dynamic compensation matrices Γ = τ − τ_pattern with each body's share (docs/models.md §2.1–2.3)",
    config: SectionCheck::of::<NoKeys>(),
};

impl Stage for MatricesStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    /// `sparkout stage matrices --topography FILE --json`, with the built-in
    /// aplm-gantry machine.
    fn run_standalone(
        &self,
        args: &sparkout_pipeline::StageArgs,
    ) -> Option<Result<serde_json::Value>> {
        let file = args.get("topography")?;
        Some((|| {
            if let Some(k) = args.keys().find(|k| *k != "topography") {
                crate::bail!("unknown flag --{k} for `matrices` (known: --topography FILE)");
            }
            let mc = super::builtin_machine()?;
            let g = Gantry::read(&mc, &toml::Table::new(), std::path::PathBuf::from(file))?;
            let t =
                sparkout_pipeline::contracts::Table::read(std::path::Path::new(file), &TOPOGRAPHY)?;
            let pattern = grid::pattern(&t)?;
            check_travel(&g, &pattern.grid, t.path())?;
            let m = compute(&g, &pattern)?;
            Ok(serde_json::to_value(summary(&g, &m, 0))?)
        })())
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let g = Gantry::from_run(&ctx.run.machine, &ctx.run.spec)?;
        let t = ctx.run.require(&TOPOGRAPHY)?;
        let pattern = grid::pattern(&t)?;
        check_travel(&g, &pattern.grid, t.path())?;
        let m = compute(&g, &pattern)?;
        let mut path = None;
        let mut path_rows = 0;
        let mut augmented = None;
        if let Some(mo) = ctx.run.table(&MOTION)? {
            let (ts, xs, ys) = (mo.f64("t_s")?, mo.f64("cmd_x_mm")?, mo.f64("cmd_y_mm")?);
            let gd = m.gamma(&m.dynamic);
            let (mut t_out, mut dz) = (Vec::new(), Vec::new());
            for k in 0..ts.len() {
                // Replay needs strictly increasing t_s: keep the first of equal stamps.
                if t_out.last().is_some_and(|&l| ts[k] <= l) {
                    continue;
                }
                t_out.push(ts[k]);
                dz.push(m.grid.bilinear(&gd, xs[k], ys[k]));
            }
            path_rows = t_out.len();
            // `run --augment` (gantry/augment.rs): the bridge lifts by
            // b(y, t) as it warms; lower the tool by it.
            let mean_removal = ctx
                .artifacts
                .summary_as::<RemovalSummary>("removal")
                .transpose()?
                .map(|s| s.removal_mean_mm)
                .filter(|r| *r > 0.0);
            if let (Some(bow), Some(r)) = (ThermalBow::of(ctx), mean_removal) {
                let mut ys_out = Vec::with_capacity(t_out.len());
                let mut last = f64::NEG_INFINITY;
                for k in 0..ts.len() {
                    if ts[k] > last {
                        ys_out.push(ys[k]);
                        last = ts[k];
                    }
                }
                let growth = bow
                    .growth(&ys_out, &t_out)
                    .ok_or_else(|| err!("the augmented model's thermal bow cannot be evaluated"))?;
                let lift_per_growth = g.polish.spring_compression_mm / r;
                for (d, gr) in dz.iter_mut().zip(&growth) {
                    *d -= gr * lift_per_growth;
                }
                augmented = Some(MatricesAugmented {
                    in_physics: bow.keys(),
                    bridge_lift_max_mm: growth.iter().fold(0.0f64, |m, v| m.max(v.abs()))
                        * lift_per_growth,
                });
            }
            path = Some(
                BatchBuilder::new()
                    .f64("t_s", t_out)
                    .f64("dz_mm", dz)
                    .build(),
            );
        }
        let mut summary = summary(&g, &m, path_rows);
        summary.augmented = Some(augmented);
        let mut out = StageOutput::typed(&summary)?
            .with("static_matrix", m.matrix_batch(&m.stat))
            .with("dynamic_matrix", m.matrix_batch(&m.dynamic))
            .with("compensation_table", m.controller_batch());
        if let Some(path) = path {
            out = out.with("compensation_path", path);
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sparkout_pipeline::contracts::RunSpec;

    fn gantry() -> Gantry {
        let m = crate::gantry::builtin_machine().unwrap();
        let spec = RunSpec::parse(
            std::path::Path::new("."),
            "[run]\nid = \"t\"\nmachine = \"aplm-gantry\"\nplugin = \"gantry\"\n",
        )
        .unwrap();
        Gantry::from_run(&m, &spec).unwrap()
    }

    #[test]
    fn tau_on_stringer1_at_mid_span_is_its_straightness_minus_textbook_sag() {
        let g = gantry();
        // Spindle over stringer 1 (y = y₁): s = 0, the bridge adds nothing
        // (its ends do not deflect, its straightness is 0 there).
        let grid = Grid::new(1200.0, 10.0, 2, 0.0, 10.0, 2);
        let t = topography(&g, &grid, false).unwrap();
        let b = &g.stringer1.beam;
        let (l, ei) = (b.span_mm, b.ei_n_mm2);
        let p = 0.5 * g.bridge.weight_n + g.spindle_weight_n + g.cut_force_n();
        let sag =
            5.0 * g.stringer1.w_n_mm() * l.powi(4) / (384.0 * ei) + p * l.powi(3) / (48.0 * ei);
        let want = 0.021 - sag;
        assert!((t.tau[0] - want).abs() < 1e-9, "{} vs {want}", t.tau[0]);
        assert!((t.shares[0][0] - want).abs() < 1e-9 && t.shares[1][0] == 0.0);
        // The source's magnitude: ~0.15 mm of static sag on a stringer.
        assert!(sag > 0.1 && sag < 0.2, "{sag}");
        // Dynamic differs from static only through the moving load, and
        // at 9 m/min (far below the critical speed) by well under 1 µm.
        let d = topography(&g, &grid, true).unwrap();
        assert!((d.tau[0] - t.tau[0]).abs() < 1e-3);
    }

    #[test]
    fn qin_cutting_force() {
        let g = gantry();
        // F = K_r·a_d·v_a/v_r·b with v_r = π·177·350/60.
        let vr = std::f64::consts::PI * 177.0 * 350.0 / 60.0;
        let f = 2255.53 * 0.1 * 150.0 / vr * 20.0;
        assert!((g.cut_force_n() - f).abs() < 1e-9);
    }
}

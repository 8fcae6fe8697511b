//! `polish_plan`: selective polishing (MODELS.md §2.6). Zones above the
//! tolerance band (height above the least-squares plane > tolerance), tool
//! placements covering every such point, the dwell per placement that brings
//! its zone into tolerance (the tool centre runs an Archimedean spiral at
//! each placement), the total time against raster polishing of the whole
//! piece, and the zone area fraction beyond which selective polishing stops
//! paying off — found by sweeping the fraction, not assumed.
//!
//! Placement: the highest uncovered point seeds a placement; its centre is
//! the mean of the uncovered points within the cover radius of the seed (so
//! the seed stays covered); every uncovered point within the cover radius of
//! the centre is "in". Repeat until no point is out. The cover radius is the
//! tool radius less the spiral radius: those points are under the disc for
//! the whole spiral.

use serde_json::{json, Value};
use sparkout_pipeline::contracts::schema::TOPOGRAPHY;
use sparkout_pipeline::contracts::{BatchBuilder, Table};
use sparkout_pipeline::{
    InputError, Result, Stage, StageArgs, StageContext, StageOutput, StageSpec,
};

use super::config::{check_config, Check, STATES};
use super::flatness::least_squares;
use super::grid::{self, Grid, Surface};
use super::machine::{Gantry, PassAxis};
use super::removal::{check_tool_fits, plan_raster};
use super::tool_influence::{dwell_map, removal_of_dwell, spiral_path, PathSample, PolishTool};

/// Settings (`[gantry.polish_plan]`).
#[derive(Debug, Clone, Copy)]
pub struct PlanConfig {
    pub tolerance_mm: f64,
    /// Spiral radius as a fraction of the tool radius.
    pub spiral_fraction: f64,
    pub spiral_pitch_mm: Option<f64>,
    pub rapid_mm_s: f64,
    pub sweep_steps: usize,
}

impl Default for PlanConfig {
    fn default() -> Self {
        PlanConfig {
            tolerance_mm: 0.01,
            spiral_fraction: 0.5,
            spiral_pitch_mm: None,
            rapid_mm_s: 500.0,
            sweep_steps: 20,
        }
    }
}

const KEYS: &[(&str, Check)] = &[
    ("state", Check::OneOf(&STATES)),
    ("tolerance_mm", Check::NonNegative),
    ("spiral_fraction", Check::Probability),
    ("spiral_pitch_mm", Check::Positive),
    ("rapid_mm_s", Check::Positive),
    ("sweep_steps", Check::AtLeastOne),
];

impl PlanConfig {
    fn from_table(t: &toml::Table) -> PlanConfig {
        let d = PlanConfig::default();
        let f = |k: &str| sparkout_pipeline::cfg_f64(t, k);
        PlanConfig {
            tolerance_mm: f("tolerance_mm").unwrap_or(d.tolerance_mm),
            spiral_fraction: f("spiral_fraction").unwrap_or(d.spiral_fraction),
            spiral_pitch_mm: f("spiral_pitch_mm"),
            rapid_mm_s: f("rapid_mm_s").unwrap_or(d.rapid_mm_s),
            sweep_steps: f("sweep_steps")
                .map(|v| v as usize)
                .unwrap_or(d.sweep_steps),
        }
    }
}

/// One tool placement.
#[derive(Debug, Clone, PartialEq)]
pub struct Placement {
    pub x_mm: f64,
    pub y_mm: f64,
    pub dwell_s: f64,
    /// Grid nodes this placement is responsible for.
    pub members: Vec<usize>,
    pub need_max_mm: f64,
}

/// A selective plan and its raster comparison.
#[derive(Debug, Clone)]
pub struct Plan {
    pub placements: Vec<Placement>,
    pub dwell_total_s: f64,
    pub travel_s: f64,
    pub selective_s: f64,
    pub raster_s: f64,
    pub zone_points: usize,
}

/// What stays the same while the zone changes (the sweep reuses it).
pub struct Planner<'a> {
    pub grid: &'a Grid,
    pub tool: &'a PolishTool,
    pub cfg: PlanConfig,
    pub cover_mm: f64,
    spiral: Vec<PathSample>,
    spiral_s: f64,
    /// Removal of one raster sweep of the whole piece, per node, and its time.
    raster_removal: Vec<f64>,
    raster_sweep_s: f64,
}

impl<'a> Planner<'a> {
    pub fn new(grid: &'a Grid, tool: &'a PolishTool, cfg: PlanConfig, axis_x: bool) -> Planner<'a> {
        let r_sp = cfg.spiral_fraction * tool.radius_mm;
        let pitch = cfg.spiral_pitch_mm.unwrap_or(r_sp / 2.0);
        let ds = (grid.dx.min(grid.dy) / 4.0).min(pitch / 2.0);
        let spiral = spiral_path(0.0, 0.0, r_sp, pitch, tool.feed_mm_s, ds);
        let spiral_s = spiral.iter().map(|s| s.dt_s).sum();
        let raster = plan_raster(grid, tool, axis_x);
        let raster_sweep_s = raster.last().map(|p| p.t_s).unwrap_or(0.0);
        let raster_removal = removal_of_dwell(grid, tool, &dwell_map(grid, &raster, |_| 1.0));
        Planner {
            grid,
            tool,
            cfg,
            cover_mm: tool.radius_mm - r_sp,
            spiral,
            spiral_s,
            raster_removal,
            raster_sweep_s,
        }
    }

    /// Removal depth per second of spiralling at (cx, cy), at node k.
    fn response(&self, cx: f64, cy: f64, k: usize) -> f64 {
        let (x, y) = self.grid.xy(k);
        let r: f64 = self
            .spiral
            .iter()
            .map(|s| {
                s.dt_s
                    * self
                        .tool
                        .rate_mm_s((x - cx - s.x_mm).hypot(y - cy - s.y_mm))
            })
            .sum();
        r / self.spiral_s
    }

    /// Cover every node with need > 0 and set each placement's dwell.
    pub fn plan(&self, need: &[f64]) -> Plan {
        let mut out: Vec<usize> = (0..need.len()).filter(|&k| need[k] > 0.0).collect();
        let zone_points = out.len();
        let r2 = self.cover_mm * self.cover_mm;
        let d2 = |a: (f64, f64), b: (f64, f64)| (a.0 - b.0).powi(2) + (a.1 - b.1).powi(2);
        let mut placements = Vec::new();
        while !out.is_empty() {
            let seed = *out
                .iter()
                .max_by(|&&a, &&b| need[a].total_cmp(&need[b]).then(b.cmp(&a)))
                .expect("non-empty");
            let ps = self.grid.xy(seed);
            let near: Vec<usize> = out
                .iter()
                .copied()
                .filter(|&k| d2(self.grid.xy(k), ps) <= r2)
                .collect();
            let c = near.iter().fold((0.0, 0.0), |a, &k| {
                let p = self.grid.xy(k);
                (a.0 + p.0, a.1 + p.1)
            });
            let c = (c.0 / near.len() as f64, c.1 / near.len() as f64);
            let members: Vec<usize> = out
                .iter()
                .copied()
                .filter(|&k| d2(self.grid.xy(k), c) <= r2 * (1.0 + 1e-12))
                .collect();
            debug_assert!(members.contains(&seed));
            out.retain(|k| !members.contains(k));
            let dwell_s = members
                .iter()
                .map(|&k| need[k] / self.response(c.0, c.1, k))
                .fold(0.0, f64::max);
            let need_max_mm = members.iter().map(|&k| need[k]).fold(0.0, f64::max);
            placements.push(Placement {
                x_mm: c.0,
                y_mm: c.1,
                dwell_s,
                members,
                need_max_mm,
            });
        }
        // Travel between placements: nearest-neighbour tour from the first.
        let mut travel_mm = 0.0;
        let mut left: Vec<usize> = (1..placements.len()).collect();
        let mut cur = 0;
        while !left.is_empty() {
            let (pos, &next) = left
                .iter()
                .enumerate()
                .min_by(|a, b| {
                    let da = d2(
                        (placements[cur].x_mm, placements[cur].y_mm),
                        (placements[*a.1].x_mm, placements[*a.1].y_mm),
                    );
                    let db = d2(
                        (placements[cur].x_mm, placements[cur].y_mm),
                        (placements[*b.1].x_mm, placements[*b.1].y_mm),
                    );
                    da.total_cmp(&db)
                })
                .expect("non-empty");
            travel_mm += d2(
                (placements[cur].x_mm, placements[cur].y_mm),
                (placements[next].x_mm, placements[next].y_mm),
            )
            .sqrt();
            cur = next;
            left.remove(pos);
        }
        let travel_s = travel_mm / self.cfg.rapid_mm_s;
        let dwell_total_s: f64 = placements.iter().map(|p| p.dwell_s).sum();
        // Raster: sweeps of the whole piece until the deepest need (relative
        // to what one sweep removes there) is met.
        let sweeps = (0..need.len())
            .filter(|&k| need[k] > 0.0 && self.raster_removal[k] > 0.0)
            .map(|k| need[k] / self.raster_removal[k])
            .fold(0.0, f64::max);
        Plan {
            dwell_total_s,
            travel_s,
            selective_s: dwell_total_s + travel_s,
            raster_s: sweeps * self.raster_sweep_s,
            zone_points,
            placements,
        }
    }

    /// Predicted surface after the selective plan (spiral dwell ⊛ influence).
    pub fn after(&self, z: &[f64], plan: &Plan) -> Vec<f64> {
        let mut path = Vec::new();
        for p in &plan.placements {
            let scale = p.dwell_s / self.spiral_s;
            path.extend(self.spiral.iter().map(|s| PathSample {
                x_mm: s.x_mm + p.x_mm,
                y_mm: s.y_mm + p.y_mm,
                dt_s: s.dt_s * scale,
                ..*s
            }));
        }
        let removal = removal_of_dwell(self.grid, self.tool, &dwell_map(self.grid, &path, |_| 1.0));
        z.iter().zip(&removal).map(|(a, b)| a - b).collect()
    }

    /// Ratio selective/raster against the zone's area fraction: the zone is
    /// the highest fraction f of the points (by `dz`), each needing the same
    /// removal `depth_mm`, so only the area changes; the breakeven is where
    /// the ratio first reaches 1 (linear interpolation between steps).
    pub fn sweep(&self, dz: &[f64], depth_mm: f64) -> (Vec<(f64, f64)>, Option<f64>) {
        let mut sorted = dz.to_vec();
        sorted.sort_by(|a, b| b.total_cmp(a));
        let n = sorted.len();
        let mut pts = Vec::new();
        for s in 1..=self.cfg.sweep_steps {
            let f = s as f64 / self.cfg.sweep_steps as f64;
            let m = ((f * n as f64).round() as usize).clamp(1, n);
            let thr = if m < n { sorted[m] } else { f64::NEG_INFINITY };
            let need: Vec<f64> = dz
                .iter()
                .map(|v| if *v > thr { depth_mm } else { 0.0 })
                .collect();
            let p = self.plan(&need);
            if p.raster_s > 0.0 {
                pts.push((m as f64 / n as f64, p.selective_s / p.raster_s));
            }
        }
        let mut breakeven = None;
        for w in 0..pts.len() {
            if pts[w].1 >= 1.0 {
                breakeven = Some(if w == 0 {
                    pts[0].0
                } else {
                    let (a, b) = (pts[w - 1], pts[w]);
                    a.0 + (1.0 - a.1) * (b.0 - a.0) / (b.1 - a.1)
                });
                break;
            }
        }
        (pts, breakeven)
    }
}

/// Heights above the least-squares plane.
pub fn above_plane(s: &Surface) -> Result<Vec<f64>> {
    let n = s.grid.len();
    let (x, y): (Vec<f64>, Vec<f64>) = (0..n).map(|k| s.grid.xy(k)).unzip();
    let f = least_squares(&x, &y, &s.z)?;
    Ok((0..n)
        .map(|k| s.z[k] - f.plane[0] * x[k] - f.plane[1] * y[k] - f.plane[2])
        .collect())
}

/// The whole analysis: plan, verification, sweep, JSON and the artifact.
pub fn analyse(
    g: &Gantry,
    s: &Surface,
    cfg: PlanConfig,
) -> Result<(
    Value,
    arrow::record_batch::RecordBatch,
    arrow::record_batch::RecordBatch,
)> {
    let planner = Planner::new(&s.grid, &g.polish, cfg, g.pass_axis == PassAxis::X);
    let dz = above_plane(s)?;
    let need: Vec<f64> = dz.iter().map(|v| (v - cfg.tolerance_mm).max(0.0)).collect();
    let plan = planner.plan(&need);
    let after = planner.after(&dz, &plan);
    let still_out = after
        .iter()
        .filter(|v| **v > cfg.tolerance_mm + 1e-9)
        .count();
    // Sweep at the depth this surface needs (at least 1 µm when in tolerance).
    let depth = need.iter().cloned().fold(0.0, f64::max).max(0.001);
    let (sweep, breakeven) = planner.sweep(&dz, depth);
    let ratio = if plan.raster_s > 0.0 {
        plan.selective_s / plan.raster_s
    } else {
        f64::NAN
    };
    let num = |v: f64| if v.is_finite() { json!(v) } else { Value::Null };
    let summary = json!({
        "state": s.state,
        "placements": plan.placements.len(),
        "selective_s": plan.selective_s,
        "raster_s": plan.raster_s,
        "ratio": num(ratio),
        "breakeven_area_fraction": breakeven,
        "tolerance_mm": cfg.tolerance_mm,
        "zone_points": plan.zone_points,
        "zone_area_fraction": plan.zone_points as f64 / s.grid.len() as f64,
        "dwell_s": plan.dwell_total_s,
        "travel_s": plan.travel_s,
        "cover_radius_mm": planner.cover_mm,
        "uncovered_points": 0,
        "points_above_tolerance_after": still_out,
        "max_above_plane_mm": dz.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
        "max_above_plane_after_mm": after.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
        "sweep": sweep.iter().map(|(f, r)| json!({"area_fraction": f, "ratio": r})).collect::<Vec<_>>(),
    });
    let p = &plan.placements;
    let batch = BatchBuilder::new()
        .i32("placement", (0..p.len() as i32).collect())
        .f64("x_mm", p.iter().map(|q| q.x_mm).collect())
        .f64("y_mm", p.iter().map(|q| q.y_mm).collect())
        .f64("dwell_s", p.iter().map(|q| q.dwell_s).collect())
        .i32("points", p.iter().map(|q| q.members.len() as i32).collect())
        .f64("need_max_mm", p.iter().map(|q| q.need_max_mm).collect())
        .f64("radius_mm", vec![g.polish.radius_mm; p.len()])
        .build();
    let n = s.grid.len();
    let (xs, ys): (Vec<f64>, Vec<f64>) = (0..n).map(|k| s.grid.xy(k)).unzip();
    let surface = BatchBuilder::new()
        .f64("x_mm", xs)
        .f64("y_mm", ys)
        .f64("above_plane_mm", dz)
        .f64("need_mm", need)
        .f64("after_mm", after)
        .build();
    Ok((summary, batch, surface))
}

pub struct PolishPlanStage;

fn load(t: &Table, state: &str, g: &Gantry) -> Result<Surface, InputError> {
    let s = grid::surface(t, state)?;
    check_tool_fits(g, &s.grid, t.path())?;
    Ok(s)
}

const SPEC: StageSpec = StageSpec {
    name: "polish_plan",
    version: 1,
    reads: &[&TOPOGRAPHY],
    reads_artifacts: &[],
    writes: &["polish_plan", "polish_surface"],
    about: "selective polishing: placements covering every point above tolerance, dwell, time vs raster, breakeven area (MODELS.md §2.6)",
};

impl Stage for PolishPlanStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn validate_config(&self, config: &toml::Table) -> Result<()> {
        check_config(config, KEYS)
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let g = Gantry::from_run(&ctx.run.machine, &ctx.run.spec)?;
        let t = ctx.run.require(&TOPOGRAPHY)?;
        grid::pattern(&t)?;
        let s = load(&t, ctx.cfg_str("state", "after_grind"), &g)?;
        let (summary, batch, surface) = analyse(&g, &s, PlanConfig::from_table(ctx.config))?;
        Ok(StageOutput::new(summary)
            .with("polish_plan", batch)
            .with("polish_surface", surface))
    }
    /// `sparkout stage polish_plan --topography FILE [--state S]
    /// [--tolerance-mm T] --json`, with the built-in aplm-gantry machine.
    fn run_standalone(&self, args: &StageArgs) -> Option<Result<Value>> {
        let file = args.get("topography")?;
        Some((|| {
            let mut cfg = toml::Table::new();
            for (k, v) in args {
                match k.as_str() {
                    "topography" | "state" => {}
                    "tolerance-mm" | "tolerance_mm" => {
                        let x: f64 = v.parse().map_err(|_| anyhow::anyhow!("--tolerance-mm must be a number, got `{v}`"))?;
                        cfg.insert("tolerance_mm".into(), toml::Value::Float(x));
                    }
                    other => anyhow::bail!("unknown flag --{other} for `polish_plan` (known: --topography FILE, --state NAME, --tolerance-mm MM)"),
                }
            }
            check_config(&cfg, KEYS)?;
            let m = super::builtin_machine()?;
            let g = Gantry::read(&m, &toml::Table::new(), std::path::PathBuf::from(file))?;
            let t = Table::read(std::path::Path::new(file), &TOPOGRAPHY)?;
            let s = load(
                &t,
                args.get("state")
                    .map(|s| s.as_str())
                    .unwrap_or("after_grind"),
                &g,
            )?;
            Ok(analyse(&g, &s, PlanConfig::from_table(&cfg))?.0)
        })())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tool() -> PolishTool {
        PolishTool {
            k_p_per_pa: 1.7097e-8,
            pressure_pa: 389.93,
            radius_mm: 60.0,
            rev_per_s: 2.5,
            linear_speed_mm_s: 1000.0,
            spring_compression_mm: 0.5,
            feed_mm_s: 100.0,
            step_over_mm: 30.0,
            accel_mm_s2: 500.0,
        }
    }

    #[test]
    fn every_zone_point_is_covered_and_brought_into_tolerance() {
        let grid = Grid::new(0.0, 20.0, 31, 0.0, 20.0, 21);
        let t = tool();
        let p = Planner::new(&grid, &t, PlanConfig::default(), true);
        // Two bumps above tolerance.
        let dz: Vec<f64> = (0..grid.len())
            .map(|k| {
                let (x, y) = grid.xy(k);
                0.03 * (-((x - 150.0).powi(2) + (y - 200.0).powi(2)) / 3000.0).exp()
                    + 0.02 * (-((x - 480.0).powi(2) + (y - 120.0).powi(2)) / 2000.0).exp()
            })
            .collect();
        let tol = 0.005;
        let need: Vec<f64> = dz.iter().map(|v| (v - tol).max(0.0)).collect();
        let plan = p.plan(&need);
        let mut covered = vec![false; grid.len()];
        for pl in &plan.placements {
            for &k in &pl.members {
                let (x, y) = grid.xy(k);
                assert!((x - pl.x_mm).hypot(y - pl.y_mm) <= p.cover_mm + 1e-9);
                covered[k] = true;
            }
        }
        for k in 0..grid.len() {
            assert_eq!(covered[k], need[k] > 0.0, "node {k}");
        }
        let after = p.after(&dz, &plan);
        for (k, v) in after.iter().enumerate() {
            assert!(*v <= tol + 1e-9, "node {k} still {v}");
        }
        assert!(
            plan.selective_s < plan.raster_s,
            "{} vs {}",
            plan.selective_s,
            plan.raster_s
        );
        // The sweep: selective pays for small zones, not for the whole piece.
        let (pts, be) = p.sweep(&dz, 0.02);
        assert!(pts.first().unwrap().1 < 1.0);
        assert!(pts.last().unwrap().1 > 1.0, "{pts:?}");
        let be = be.expect("a breakeven");
        assert!(be > 0.0 && be < 1.0);
    }
}

//! `kinematics`: the 21 error functions and the tracker frame identified
//! from tracker.parquet (docs/models.md §5), validated on held-out points, the
//! volumetric error before and after compensation, and the compensation
//! table a controller would load.
//!
//! Definitions (all lengths mm, machine frame = the tracker measurement
//! rotated back by the identified tracker frame):
//! - measured deviation d = Qᵀ(m − T) − nominal tool point;
//! - `fit_rms_mm` / `holdout_rms_mm`: RMS over points of the 3-D residual
//!   |d − model deviation| on the identification / held-out points;
//! - `before_rms_mm`: RMS of |d| over all points (the uncompensated
//!   volumetric error);
//! - `after_rms_mm`: RMS of |d − c| over all points, c the volumetric error
//!   the controller computes from the compensation table (per-axis tables of
//!   the six error functions at `table_step_mm`, linearly interpolated, and
//!   the squareness terms, pushed through the same chain). To first order a
//!   controller commanding q − c(q) leaves d − c.
//!
//! Length (over 700 lines with its tests; ~650 of code): the stage, its
//! artifacts and the tracker reader share the identified model's layout;
//! the numerics live in identify.rs and chain.rs.

use std::collections::BTreeMap;

use crate::mill::tables::TRACKER;
use arrow::array::{Array, Int64Array};
use arrow::compute::cast;
use arrow::datatypes::DataType;
use arrow::record_batch::RecordBatch;
use sparkout_pipeline::config_check::SectionCheck;
use sparkout_pipeline::contracts::schema::THERMAL;
use sparkout_pipeline::contracts::{batch_f64, batch_i32, batch_str, BatchBuilder, Table};
use sparkout_pipeline::{InputError, Result, Run, Stage, StageContext, StageOutput, StageSpec};

use super::augment::SpindleGrowth;
use super::chain::{
    chain_point, function_axis, function_index, function_name, ErrorValues, Layout, Model, Point,
    AXES, FRAME, N_FUNCTIONS, SQUARENESS, V3,
};
use super::config::{KinematicsConfig, MillMachine};
use super::identify::{function_sigma, identify, split, IdentOptions, Identified, Obs};
use super::summary::{
    AugmentedGrowth, Coefficient, ErrorFunction, KinematicsSummary, Squareness, TrackerFrame,
};

/// The tracker points of a run, checked.
#[derive(Debug, Clone)]
pub struct TrackerData {
    pub path: std::path::PathBuf,
    pub point: Vec<i32>,
    pub trial: Vec<i32>,
    pub tool: Vec<usize>,
    pub obs: Vec<Obs>,
    pub t_s: Option<Vec<f64>>,
}

/// Read tracker.parquet (docs/formats.md §4; NaN in required columns is
/// rejected by the contract reader) and check what the contract does not:
/// unique (point, trial), finite optional t_s, and the optional `tool`
/// (index into the machine's [tool] offsets_mm) and `trial` columns (0 when
/// absent).
pub fn tracker_points(run: &Run, machine: &MillMachine) -> Result<TrackerData, InputError> {
    let table = run.require(&TRACKER)?;
    tracker_from_table(&table, machine)
}

pub fn tracker_from_table(table: &Table, machine: &MillMachine) -> Result<TrackerData, InputError> {
    let path = table.path().to_path_buf();
    let n = table.len();
    let point = table.i32("point")?.to_vec();
    // Optional integer columns beyond the contract (kept by the reader):
    // `tool` (index into [tool] offsets_mm) and `trial` (repeat index of a
    // re-measured point, as in probe.parquet), both 0 when absent.
    let int_col = |name: &str, lo: i64, hi: i64, what: &str| -> Result<Vec<i64>, InputError> {
        let Some(col) = table.batch().column_by_name(name) else {
            return Ok(vec![0; n]);
        };
        let c = cast(col, &DataType::Int64).map_err(|e| {
            InputError::new(&path, format!("`{name}` must be an integer column: {e}")).column(name)
        })?;
        let c = c
            .as_any()
            .downcast_ref::<Int64Array>()
            .expect("cast to Int64");
        (0..n)
            .map(|i| {
                let v = if c.is_null(i) { -1 } else { c.value(i) };
                if v < lo || v > hi {
                    Err(InputError::new(&path, format!("{name} {v}: {what}"))
                        .column(name)
                        .row(i))
                } else {
                    Ok(v)
                }
            })
            .collect()
    };
    let tool: Vec<usize> = int_col(
        "tool",
        0,
        machine.tools.len() as i64 - 1,
        &format!(
            "not one of the machine's {} tool offsets (0..{}); add it to [tool] offsets_mm",
            machine.tools.len(),
            machine.tools.len() - 1
        ),
    )?
    .into_iter()
    .map(|v| v as usize)
    .collect();
    let trial: Vec<i32> = int_col(
        "trial",
        0,
        i32::MAX as i64,
        "trial must be a non-negative integer",
    )?
    .into_iter()
    .map(|v| v as i32)
    .collect();
    let mut first: BTreeMap<(i32, i32), usize> = BTreeMap::new();
    for i in 0..n {
        if let Some(f) = first.insert((point[i], trial[i]), i) {
            return Err(InputError::new(
                &path,
                format!(
                    "duplicated point id {} (trial {}; first at row {f}); every tracker measurement needs its own (point, trial)",
                    point[i], trial[i]
                ),
            )
            .column("point")
            .row(i));
        }
    }
    let t_s = table.opt_f64("t_s").map(|t| t.to_vec());
    if let Some(t) = &t_s {
        if let Some(i) = t.iter().position(|v| !v.is_finite()) {
            return Err(
                InputError::new(&path, format!("t_s must be finite, found {}", t[i]))
                    .column("t_s")
                    .row(i),
            );
        }
    }
    let (x, y, z) = (table.f64("x_mm")?, table.f64("y_mm")?, table.f64("z_mm")?);
    let (mx, my, mz) = (
        table.f64("mx_mm")?,
        table.f64("my_mm")?,
        table.f64("mz_mm")?,
    );
    let obs = (0..n)
        .map(|i| Obs {
            pt: Point {
                q: [x[i], y[i], z[i]],
                tool: machine.tools[tool[i]],
            },
            m: V3::new(mx[i], my[i], mz[i]),
        })
        .collect();
    Ok(TrackerData {
        path,
        point,
        trial,
        tool,
        obs,
        t_s,
    })
}

/// The compensation table: per axis, positions every `step` over the
/// travel (both ends included) and the six error functions there.
#[derive(Debug, Clone)]
pub struct CompTable {
    /// [axis] → positions (ascending).
    pub pos: [Vec<f64>; 3],
    /// [axis][kind] → values at `pos`.
    pub values: [[Vec<f64>; 6]; 3],
    pub squareness: [f64; 3],
}

impl CompTable {
    pub fn from_model(model: &Model, step: f64) -> CompTable {
        let mut pos: [Vec<f64>; 3] = Default::default();
        let mut values: [[Vec<f64>; 6]; 3] = Default::default();
        for a in 0..3 {
            let (lo, hi) = model.layout.travels[a];
            let n = ((hi - lo) / step).ceil().max(1.0) as usize;
            pos[a] = (0..=n)
                .map(|i| lo + (hi - lo) * i as f64 / n as f64)
                .collect();
            for (k, v) in values[a].iter_mut().enumerate() {
                *v = pos[a]
                    .iter()
                    .map(|q| model.function_value(a * 6 + k, *q))
                    .collect();
            }
        }
        CompTable {
            pos,
            values,
            squareness: model.squareness(),
        }
    }
    /// Linear interpolation of the tables (clamped at the travel ends).
    pub fn errors(&self, q: [f64; 3]) -> ErrorValues {
        let mut e = ErrorValues::default();
        for (a, qa) in q.iter().enumerate() {
            let p = &self.pos[a];
            let j = p.partition_point(|v| v <= qa).clamp(1, p.len() - 1);
            let (q0, q1) = (p[j - 1], p[j]);
            let w = ((qa - q0) / (q1 - q0)).clamp(0.0, 1.0);
            for (k, v) in self.values[a].iter().enumerate() {
                e.set(a * 6 + k, v[j - 1] + w * (v[j] - v[j - 1]));
            }
        }
        e
    }
    /// The volumetric error the controller computes from the table.
    pub fn deviation(&self, pt: &Point) -> V3 {
        chain_point(&self.errors(pt.q), self.squareness, pt, None) - pt.nominal()
    }
}

fn rms3(v: impl Iterator<Item = V3>) -> Option<f64> {
    let (mut s, mut n) = (0.0, 0usize);
    for d in v {
        s += d.norm_squared();
        n += 1;
    }
    (n > 0).then(|| (s / n as f64).sqrt())
}

/// Everything the stage computes for one run.
pub struct KinematicsResult {
    pub id: Identified,
    pub data: TrackerData,
    pub holdout: Vec<bool>,
    pub table: CompTable,
    pub summary: KinematicsSummary,
    pub artifacts: Vec<(String, RecordBatch)>,
}

/// Identify, validate, compensate.
pub fn analyse(
    data: TrackerData,
    machine: &MillMachine,
    cfg: &KinematicsConfig,
) -> Result<KinematicsResult> {
    let n = data.obs.len();
    let (ident, hold) = split(n, machine.holdout_fraction, machine.seed);
    let obs_ident: Vec<Obs> = ident.iter().map(|&i| data.obs[i]).collect();
    let opts = IdentOptions {
        rcond: cfg.rcond,
        max_evaluations: cfg.max_evaluations,
    };
    let layout = machine.layout();
    let id = identify(layout, &obs_ident, &opts).map_err(|e| {
        InputError::new(
            &data.path,
            format!("{e} ({} points, {} held out)", n, hold.len()),
        )
    })?;
    let model = &id.model;
    let mut holdout = vec![false; n];
    for &i in &hold {
        holdout[i] = true;
    }
    let measured: Vec<V3> = data
        .obs
        .iter()
        .map(|o| model.to_machine(&o.m) - o.pt.nominal())
        .collect();
    let predicted: Vec<V3> = data.obs.iter().map(|o| model.deviation(&o.pt)).collect();
    let table = CompTable::from_model(model, cfg.table_step_mm);
    let from_table: Vec<V3> = data.obs.iter().map(|o| table.deviation(&o.pt)).collect();
    let resid = |i: usize| measured[i] - predicted[i];
    let fit_rms = rms3(ident.iter().map(|&i| resid(i)));
    let holdout_rms = rms3(hold.iter().map(|&i| resid(i)));
    let before_rms = rms3(measured.iter().copied());
    let after_rms = rms3((0..n).map(|i| measured[i] - from_table[i]));

    let params_batch = params_batch(&id);
    let cov_batch = covariance_batch(&id);
    let table_batch = table_batch(&table, &id);
    let map_batch = map_batch(model, &table, machine, cfg.map_grid);
    let resid_batch = BatchBuilder::new()
        .i32("point", data.point.clone())
        .i32("trial", data.trial.clone())
        .i32("tool", data.tool.iter().map(|t| *t as i32).collect())
        .i32("holdout", holdout.iter().map(|h| *h as i32).collect())
        .f64("x_mm", data.obs.iter().map(|o| o.pt.q[0]).collect())
        .f64("y_mm", data.obs.iter().map(|o| o.pt.q[1]).collect())
        .f64("z_mm", data.obs.iter().map(|o| o.pt.q[2]).collect())
        .opt_f64(
            "t_s",
            (0..n).map(|i| data.t_s.as_ref().map(|t| t[i])).collect(),
        )
        .f64("measured_dx_mm", measured.iter().map(|d| d.x).collect())
        .f64("measured_dy_mm", measured.iter().map(|d| d.y).collect())
        .f64("measured_dz_mm", measured.iter().map(|d| d.z).collect())
        .f64("model_dx_mm", predicted.iter().map(|d| d.x).collect())
        .f64("model_dy_mm", predicted.iter().map(|d| d.y).collect())
        .f64("model_dz_mm", predicted.iter().map(|d| d.z).collect())
        .f64("residual_mm", (0..n).map(|i| resid(i).norm()).collect())
        .f64(
            "after_mm",
            (0..n)
                .map(|i| (measured[i] - from_table[i]).norm())
                .collect(),
        )
        .build();
    let mut artifacts = vec![
        ("kinematic_params".to_string(), params_batch),
        ("kinematic_covariance".to_string(), cov_batch),
        ("compensation_table".to_string(), table_batch),
        ("volumetric_map".to_string(), map_batch),
        ("tracker_residuals".to_string(), resid_batch),
    ];
    // For CAN replay (docs/design.md §9): the correction along the
    // measured sequence, when its time stamps are strictly increasing.
    let path_written = match &data.t_s {
        Some(t) if t.windows(2).all(|w| w[1] > w[0]) => {
            let corr: Vec<V3> = data.obs.iter().map(|o| -table.deviation(&o.pt)).collect();
            artifacts.push((
                "compensation_path".to_string(),
                BatchBuilder::new()
                    .f64("t_s", t.clone())
                    .f64("x_mm", data.obs.iter().map(|o| o.pt.q[0]).collect())
                    .f64("y_mm", data.obs.iter().map(|o| o.pt.q[1]).collect())
                    .f64("z_mm", data.obs.iter().map(|o| o.pt.q[2]).collect())
                    .f64("dx_mm", corr.iter().map(|c| c.x).collect())
                    .f64("dy_mm", corr.iter().map(|c| c.y).collect())
                    .f64("dz_mm", corr.iter().map(|c| c.z).collect())
                    .build(),
            ));
            true
        }
        _ => false,
    };
    let summary = summary(
        &id,
        machine,
        cfg,
        [fit_rms, holdout_rms, before_rms, after_rms],
        (ident.len(), hold.len()),
        path_written,
    );
    Ok(KinematicsResult {
        id,
        data,
        holdout,
        table,
        summary,
        artifacts,
    })
}

fn summary(
    id: &Identified,
    machine: &MillMachine,
    cfg: &KinematicsConfig,
    [fit, hold, before, after]: [Option<f64>; 4],
    (n_ident, n_hold): (usize, usize),
    path_written: bool,
) -> KinematicsSummary {
    let model = &id.model;
    let layout = &model.layout;
    let mut functions = BTreeMap::new();
    for f in 0..N_FUNCTIONS {
        let a = function_axis(f);
        let (lo, hi) = layout.travels[a];
        let grid: Vec<f64> = (0..=20).map(|i| lo + (hi - lo) * i as f64 / 20.0).collect();
        let coefs: BTreeMap<String, Coefficient> = layout
            .coef
            .iter()
            .enumerate()
            .filter(|(_, (g, _))| *g == f)
            .map(|(i, (_, m))| {
                (
                    format!("P{m}"),
                    Coefficient {
                        value: model.params[i],
                        sigma: id.std(i),
                    },
                )
            })
            .collect();
        let max_abs = grid
            .iter()
            .map(|q| model.function_value(f, *q).abs())
            .fold(0.0, f64::max);
        let max_sigma = grid
            .iter()
            .map(|q| function_sigma(id, f, *q))
            .fold(0.0, f64::max);
        functions.insert(
            function_name(f),
            ErrorFunction {
                unit: super::identify::unit_of(f).to_string(),
                fixed: coefs.is_empty(),
                max_abs,
                max_sigma,
                coefficients: coefs,
            },
        );
    }
    let si = layout.sq_index();
    let sq: BTreeMap<String, Squareness> = (0..3)
        .map(|k| {
            (
                SQUARENESS[k].to_string(),
                Squareness {
                    value_rad: model.params[si + k],
                    sigma_rad: id.std(si + k),
                },
            )
        })
        .collect();
    let w = model.omega();
    let t = model.translation();
    // A fit far above the tracker's noise is still a fit, but a suspicious
    // one: wrong tool offsets, mixed-up point ids, a moved tracker.
    let mut warnings = Vec::new();
    if id.sigma_mm > 10.0 * machine.tracker_sigma_mm {
        warnings.push(format!(
            "residual σ {:.4} mm is {:.0}× the tracker noise of the machine config ({} mm): check the tool offsets ([tool] offsets_mm, tracker.parquet `tool`), the point ids and whether the tracker moved during the measurement",
            id.sigma_mm,
            id.sigma_mm / machine.tracker_sigma_mm,
            machine.tracker_sigma_mm
        ));
    }
    KinematicsSummary {
        warnings,
        params: layout.n_params(),
        fit_rms_mm: fit,
        holdout_rms_mm: hold,
        before_rms_mm: before,
        after_rms_mm: after,
        sigma_mm: id.sigma_mm,
        points: n_ident + n_hold,
        points_identification: n_ident,
        points_holdout: n_hold,
        holdout_fraction: machine.holdout_fraction,
        seed: machine.seed,
        degree: layout.degree,
        tools: machine.tools.len(),
        fixed: machine.fixed.iter().map(|f| function_name(*f)).collect(),
        gauge: [
            "P0 of the nine translations → tracker translation",
            "P0 of the rotations of X → tracker rotation",
            "P0 of the rotations of Y → squareness sq_xz, sq_yz and the constant rotation of Z",
            "P1 of the six straightness functions → squareness and tracker rotation (ISO 230-1 reference line)",
        ]
        .map(String::from)
        .to_vec(),
        dof: id.dof,
        rcond: id.rcond,
        evaluations: id.evaluations,
        termination: id.termination.clone(),
        squareness: sq,
        tracker: TrackerFrame {
            rotation_vector_rad: [w.x, w.y, w.z],
            angle_rad: w.norm(),
            translation_mm: [t.x, t.y, t.z],
        },
        functions,
        table_step_mm: cfg.table_step_mm,
        map_grid: cfg.map_grid,
        compensation_path: path_written,
        augmented: None,
    }
}

/// One row per identified parameter (the model observe re-reads).
fn params_batch(id: &Identified) -> RecordBatch {
    let layout = &id.model.layout;
    let p = layout.n_params();
    let function: Vec<String> = (0..p)
        .map(|i| {
            if i < layout.coef.len() {
                function_name(layout.coef[i].0)
            } else if i < layout.frame_index() {
                SQUARENESS[i - layout.sq_index()].to_string()
            } else {
                FRAME[i - layout.frame_index()].to_string()
            }
        })
        .collect();
    BatchBuilder::new()
        .str(
            "name",
            &(0..p).map(|i| layout.param_name(i)).collect::<Vec<_>>(),
        )
        .str("function", &function)
        .i32(
            "order",
            (0..p)
                .map(|i| layout.coef.get(i).map(|c| c.1 as i32).unwrap_or(-1))
                .collect(),
        )
        .f64("value", id.model.params.iter().copied().collect())
        .f64("sigma", (0..p).map(|i| id.std(i)).collect())
        .i32("degree", vec![layout.degree as i32; p])
        .build()
}

/// Rebuild the identified model from `kinematic_params`.
pub fn model_from_params(b: &RecordBatch, travels: [(f64, f64); 3]) -> Result<Model> {
    let function = batch_str(b, "function")?;
    let order = batch_i32(b, "order")?;
    let value = batch_f64(b, "value")?;
    let degree = batch_i32(b, "degree")?
        .first()
        .copied()
        .ok_or_else(|| crate::err!("kinematic_params is empty"))? as usize;
    let mut coef = Vec::new();
    let mut rest = Vec::new();
    for i in 0..b.num_rows() {
        match function_index(&function[i]) {
            Some(f) if order[i] >= 0 => coef.push(((f, order[i] as usize), value[i])),
            _ => rest.push((function[i].clone(), value[i])),
        }
    }
    let layout = Layout {
        degree,
        travels,
        coef: coef.iter().map(|c| c.0).collect(),
    };
    let mut model = Model::zeros(layout);
    for (i, (_, v)) in coef.iter().enumerate() {
        model.params[i] = *v;
    }
    let names: Vec<&str> = SQUARENESS.iter().chain(FRAME.iter()).copied().collect();
    for (k, name) in names.iter().enumerate() {
        let v = rest
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| *v)
            .ok_or_else(|| crate::err!("kinematic_params lacks `{name}`"))?;
        model.params[model.layout.sq_index() + k] = v;
    }
    Ok(model)
}

fn covariance_batch(id: &Identified) -> RecordBatch {
    let p = id.model.layout.n_params();
    let names: Vec<String> = (0..p).map(|i| id.model.layout.param_name(i)).collect();
    let (mut a, mut b, mut c) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..p {
        for j in 0..p {
            a.push(names[i].as_str());
            b.push(names[j].as_str());
            c.push(id.cov[(i, j)]);
        }
    }
    BatchBuilder::new()
        .str("param_i", &a)
        .str("param_j", &b)
        .f64("cov", c)
        .build()
}

/// The compensation table a controller loads: per axis and position the
/// six error functions with their standard deviations.
fn table_batch(t: &CompTable, id: &Identified) -> RecordBatch {
    let mut axis = Vec::new();
    let mut pos = Vec::new();
    let mut cols: [Vec<f64>; 6] = Default::default();
    let mut sig: [Vec<f64>; 6] = Default::default();
    for (a, name) in AXES.iter().enumerate() {
        for (i, q) in t.pos[a].iter().enumerate() {
            axis.push(*name);
            pos.push(*q);
            for (k, (c, sg)) in cols.iter_mut().zip(sig.iter_mut()).enumerate() {
                c.push(t.values[a][k][i]);
                sg.push(function_sigma(id, a * 6 + k, *q));
            }
        }
    }
    let mut b = BatchBuilder::new().str("axis", &axis).f64("pos_mm", pos);
    let names = ["dx_mm", "dy_mm", "dz_mm", "ex_rad", "ey_rad", "ez_rad"];
    for (name, c) in names.iter().zip(cols) {
        b = b.f64(name, c);
    }
    for (name, sg) in names.iter().zip(sig) {
        b = b.f64(&format!("sigma_{name}"), sg);
    }
    b.build()
}

/// Volumetric error over a grid of the workspace (tool 0), before
/// compensation (the model) and after (model − table correction).
fn map_batch(model: &Model, t: &CompTable, machine: &MillMachine, n: usize) -> RecordBatch {
    let g = |a: usize, i: usize| {
        let (lo, hi) = model.layout.travels[a];
        lo + (hi - lo) * i as f64 / (n - 1) as f64
    };
    // (position, error before, error after)
    type MapRow = ([f64; 3], V3, V3);
    let mut rows: Vec<MapRow> = Vec::new();
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                let pt = Point {
                    q: [g(0, i), g(1, j), g(2, k)],
                    tool: machine.tools[0],
                };
                let before = model.deviation(&pt);
                rows.push((pt.q, before, before - t.deviation(&pt)));
            }
        }
    }
    let col = |f: &dyn Fn(&MapRow) -> f64| rows.iter().map(f).collect::<Vec<_>>();
    BatchBuilder::new()
        .f64("x_mm", col(&|r| r.0[0]))
        .f64("y_mm", col(&|r| r.0[1]))
        .f64("z_mm", col(&|r| r.0[2]))
        .f64("before_dx_mm", col(&|r| r.1.x))
        .f64("before_dy_mm", col(&|r| r.1.y))
        .f64("before_dz_mm", col(&|r| r.1.z))
        .f64("before_mm", col(&|r| r.1.norm()))
        .f64("after_dx_mm", col(&|r| r.2.x))
        .f64("after_dy_mm", col(&|r| r.2.y))
        .f64("after_dz_mm", col(&|r| r.2.z))
        .f64("after_mm", col(&|r| r.2.norm()))
        .build()
}

pub struct KinematicsStage;

const SPEC: StageSpec = StageSpec {
    name: "kinematics",
    // 2: the compensation path less the spindle growth under `run --augment`.
    version: 2,
    reads: &[&TRACKER, &THERMAL],
    reads_artifacts: &[],
    writes: &[
            "kinematic_params",
            "kinematic_covariance",
            "compensation_table",
            "volumetric_map",
            "tracker_residuals",
            "compensation_path",
        ],
    reads_augmented_model: true,
    about: "XFYZ 21-error identification from laser-tracker points (Levenberg–Marquardt, covariance), held-out validation, volumetric error before/after, compensation table (docs/models.md §5)",
    config: SectionCheck::of::<KinematicsConfig>(),
};

impl Stage for KinematicsStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let machine = MillMachine::from_config(&ctx.run.machine)?;
        let cfg: &KinematicsConfig = ctx.section()?;
        let machine = cfg.apply(&machine)?;
        let data = tracker_points(ctx.run, &machine)?;
        let r = analyse(data, &machine, cfg)?;
        let mut summary = r.summary;
        let mut artifacts = Vec::new();
        let growth = SpindleGrowth::of(ctx);
        for (name, batch) in r.artifacts {
            let batch = match (&growth, name.as_str()) {
                // `run --augment` (mill/augment.rs): the growth taken out of
                // the correction replay sends.
                (Some(sg), "compensation_path") => {
                    let temp = match ctx.run.table(&THERMAL)? {
                        Some(th) if sg.needs_temperature() => {
                            let t = sparkout_pipeline::contracts::batch_f64(&batch, "t_s")?;
                            Some(super::observe::temperature_at(&th, None, t)?)
                        }
                        _ => None,
                    };
                    let (b, g_max) = without_growth(&batch, sg, temp.as_deref())?;
                    summary.augmented = Some(AugmentedGrowth {
                        in_physics: sg.keys(),
                        growth_max_mm: g_max,
                    });
                    b
                }
                _ => batch,
            };
            artifacts.push((name, batch));
        }
        let mut out = StageOutput::typed(&summary)?;
        out.artifacts = artifacts;
        Ok(out)
    }
}

/// The compensation path with the spindle's growth g(t) taken out of dz;
/// and the largest |g|.
fn without_growth(
    path: &RecordBatch,
    sg: &SpindleGrowth,
    temp_c: Option<&[f64]>,
) -> Result<(RecordBatch, f64)> {
    use sparkout_pipeline::contracts::batch_f64;
    let t = batch_f64(path, "t_s")?;
    let (g, _) = sg
        .growth_and_offset(t, temp_c)
        .ok_or_else(|| crate::err!("the augmented model's spindle growth cannot be evaluated"))?;
    let mut b = BatchBuilder::new();
    for (f, c) in path.schema().fields().iter().zip(path.columns()) {
        if f.name() == "dz_mm" {
            let dz = batch_f64(path, "dz_mm")?;
            b = b.f64("dz_mm", dz.iter().zip(&g).map(|(d, g)| d - g).collect());
        } else {
            b = b.column(f.as_ref().clone(), c.clone());
        }
    }
    Ok((b.build(), g.iter().fold(0.0f64, |m, v| m.max(v.abs()))))
}

#[cfg(test)]
mod tests;

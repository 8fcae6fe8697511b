//! `observe`: paired observations (docs/formats.md §7) for the gap diagnosis.
//!
//! - `touch_normal` (touches the controller registered, probe.parquet) and
//!   `touch_normal_ae` (touches derived from the AE signal by `ingest`),
//!   one row per touch: real = the registered normal
//!   coordinate; sim = the normal coordinate the run's fitted face plane
//!   (TLS over all touches of the face) predicts at the touch's in-plane
//!   position — the block pose is the modelled part, what is left is what
//!   the model lacks (trigger latency, drift, backlash, …). Covariates:
//!   x_mm, y_mm, z_mm (nominal point), approach_mm_s, approach_normal_mm_s
//!   (approach speed × the direction's component along the +axis of the
//!   normal coordinate, so a latency L gives gap = L·approach_normal_mm_s),
//!   t_s, trial, point, dir (sign of the last move along the normal before
//!   the approach, for backlash; null when the motion log does not say),
//!   normal_axis_z (1 when the normal coordinate is z, i.e. face `xy`, else
//!   0: a vertical TCP displacement such as the column's thermal growth
//!   moves only those touches' normal coordinate).
//! - `cut_depth`, one row per pass: real = measured cut, sim = the
//!   compliance model's cut with α from the first pass (docs/models.md §1.4).
//!   Covariates: pass, t_s, feed_mm_s, nominal_doc_mm, removed_mm3
//!   (cumulative removal before the pass), compliance_response_mm2 (the
//!   gap per unit k of a cut loss k·δ′² seen through the first-pass
//!   calibration of α, `cycle::depth_compliance_response_mm2`: such a loss
//!   shortens the first cut too, so its gap is not its own form).
//!
//! Covariates that do not apply to an observable are null in its rows.

use std::collections::BTreeMap;

/// Touches the controller registered (probe.parquet): the position was
/// latched when the trigger fired, so trigger latency is in them.
const TOUCH_REGISTERED: &str = "touch_normal";
/// Touches derived offline from the AE signal (ingest): the contact time is
/// the burst onset, so no trigger latency. Kept as their own observable —
/// pooled with registered touches, an effect present in one source and not
/// the other fails the run-by-run cross-validation of either.
const TOUCH_AE: &str = "touch_normal_ae";

/// The observable of a touch: AE-derived touches are `touch_normal_ae`;
/// registered touches of the AE method are `touch_normal`; the comparison
/// methods (docs/models.md §1.1: mechanical 700 µm, electrical 163 µm range) get
/// their own `touch_normal_<method>` — pooled with AE touches, their scatter
/// would bury a trigger latency of the AE method.
fn touch_observable(source: &str, method: &str) -> String {
    if source == "ae" {
        TOUCH_AE.to_string()
    } else if method == "ae" {
        TOUCH_REGISTERED.to_string()
    } else {
        format!("{TOUCH_REGISTERED}_{method}")
    }
}
use std::sync::Arc;

use crate::err;
use arrow::array::Int32Array;
use arrow::datatypes::{DataType, Field};
use nalgebra::Vector3;
use sparkout_pipeline::config_check::{Check, Section, SectionCheck};
use sparkout_pipeline::contracts::{batch_f64, batch_i32, batch_str, BatchBuilder};
use sparkout_pipeline::{Result, Stage, StageContext, StageOutput, StageSpec};

use super::datum::PlaneFit;
use super::planes::{Face, Plane};
use super::summary::{fin, ObservableGap, ObserveSummary};
use super::touches::{self, opt_col};

pub struct ObserveStage;

/// `[robot.observe]`.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ObserveConfig {
    /// The face planes that predict touch_normal's sim.
    pub fit: PlaneFit,
}

impl Default for ObserveConfig {
    fn default() -> Self {
        ObserveConfig { fit: PlaneFit::Tls }
    }
}

impl Section for ObserveConfig {
    const CHECKS: &'static [(&'static str, Check)] = &[("fit", Check::OneOf(&["tls", "ols"]))];
}

/// One observation row.
#[derive(Debug, Clone, Default)]
struct Row {
    observable: String,
    sim: f64,
    real: f64,
    x: Option<f64>,
    y: Option<f64>,
    z: Option<f64>,
    approach: Option<f64>,
    approach_normal: Option<f64>,
    t: Option<f64>,
    trial: Option<i32>,
    point: Option<i32>,
    dir: Option<f64>,
    normal_axis_z: Option<f64>,
    pass: Option<i32>,
    feed: Option<f64>,
    doc: Option<f64>,
    removed: Option<f64>,
    compliance_response: Option<f64>,
}

/// The face planes (scope `all`) of the `planes` artifact for one fit.
fn face_planes(b: &arrow::record_batch::RecordBatch, fit: &str) -> Result<BTreeMap<Face, Plane>> {
    let face = batch_str(b, "face")?;
    let fits = batch_str(b, "fit")?;
    let scope = batch_str(b, "scope")?;
    let (nx, ny, nz, d) = (
        batch_f64(b, "nx")?,
        batch_f64(b, "ny")?,
        batch_f64(b, "nz")?,
        batch_f64(b, "d_mm")?,
    );
    let mut out = BTreeMap::new();
    for i in 0..b.num_rows() {
        if fits[i] == fit && scope[i] == "all" {
            let f =
                Face::parse(&face[i]).ok_or_else(|| err!("planes: unknown face `{}`", face[i]))?;
            out.insert(
                f,
                Plane {
                    n: Vector3::new(nx[i], ny[i], nz[i]),
                    d: d[i],
                    cov: nalgebra::Matrix4::zeros(),
                },
            );
        }
    }
    Ok(out)
}

fn opt_i32(name: &str, v: Vec<Option<i32>>) -> (Field, Arc<Int32Array>) {
    (
        Field::new(name, DataType::Int32, true),
        Arc::new(Int32Array::from(v)),
    )
}

fn build(run: &str, rows: &[Row]) -> arrow::record_batch::RecordBatch {
    let f = |g: &dyn Fn(&Row) -> Option<f64>| rows.iter().map(g).collect::<Vec<_>>();
    let i = |g: &dyn Fn(&Row) -> Option<i32>| rows.iter().map(g).collect::<Vec<_>>();
    let (tf, tc) = opt_i32("trial", i(&|r| r.trial));
    let (pf, pc) = opt_i32("point", i(&|r| r.point));
    let (sf, sc) = opt_i32("pass", i(&|r| r.pass));
    BatchBuilder::new()
        .str("run", &vec![run; rows.len()])
        .str(
            "observable",
            &rows
                .iter()
                .map(|r| r.observable.as_str())
                .collect::<Vec<_>>(),
        )
        .f64("sim", rows.iter().map(|r| r.sim).collect())
        .f64("real", rows.iter().map(|r| r.real).collect())
        .opt_f64("x_mm", f(&|r| r.x))
        .opt_f64("y_mm", f(&|r| r.y))
        .opt_f64("z_mm", f(&|r| r.z))
        .opt_f64("approach_mm_s", f(&|r| r.approach))
        .opt_f64("approach_normal_mm_s", f(&|r| r.approach_normal))
        .opt_f64("t_s", f(&|r| r.t))
        .column(tf, tc)
        .column(pf, pc)
        .opt_f64("dir", f(&|r| r.dir))
        .opt_f64("normal_axis_z", f(&|r| r.normal_axis_z))
        .column(sf, sc)
        .opt_f64("feed_mm_s", f(&|r| r.feed))
        .opt_f64("nominal_doc_mm", f(&|r| r.doc))
        .opt_f64("removed_mm3", f(&|r| r.removed))
        .opt_f64("compliance_response_mm2", f(&|r| r.compliance_response))
        .build()
}

const SPEC: StageSpec = StageSpec {
    name: "observe",
    version: 3,
    reads: &[],
    reads_artifacts: &["touches", "planes", "cycle"],
    writes: &["observations"],
    reads_augmented_model: false,
    about: "paired observations touch_normal and cut_depth for the gap diagnosis (docs/formats.md)",
    config: SectionCheck::of::<ObserveConfig>(),
};

impl Stage for ObserveStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let fit = ctx.section::<ObserveConfig>()?.fit.as_str();
        let all = touches::require(ctx)?;
        let planes_batch = ctx.artifacts.require("planes")?;
        let planes = face_planes(&planes_batch, fit)?;
        let mut rows = Vec::with_capacity(all.len() + 16);
        for t in &all {
            let plane = planes
                .get(&t.face)
                .ok_or_else(|| err!("no fitted plane for face {}", t.face.label()))?;
            rows.push(Row {
                observable: touch_observable(&t.source, &t.method),
                sim: plane.normal_coordinate_at(t.face, &t.p),
                real: t.normal(),
                x: Some(t.nom.x),
                y: Some(t.nom.y),
                z: Some(t.nom.z),
                approach: Some(t.approach_mm_s),
                approach_normal: Some(t.approach_normal_mm_s()),
                t: Some(t.t_s),
                trial: Some(t.trial),
                point: Some(t.point),
                dir: t.prev_move_dir,
                normal_axis_z: Some(if t.face.normal_axis() == 2 { 1.0 } else { 0.0 }),
                ..Row::default()
            });
        }
        if let Some(c) = ctx.artifacts.get("cycle")? {
            if c.num_rows() > 0 {
                let pass = batch_i32(&c, "pass")?;
                let pred = batch_f64(&c, "predicted_cut_mm")?;
                let meas = opt_col(&c, "measured_cut_mm")?;
                let feed = batch_f64(&c, "feed_mm_s")?;
                let doc = batch_f64(&c, "nominal_doc_mm")?;
                let removed = batch_f64(&c, "removed_mm3")?;
                let ts = opt_col(&c, "t_start_s")?;
                let te = opt_col(&c, "t_end_s")?;
                let alpha = batch_f64(&c, "alpha_first_pass")?;
                // The cycle's passes in order; α was calibrated on the first
                // one's measured cut (cycle::model).
                let response = match meas.first() {
                    Some(&Some(first_cut)) if alpha[0].is_finite() => {
                        super::cycle::depth_compliance_response_mm2(alpha[0], doc, first_cut)
                    }
                    _ => vec![f64::NAN; c.num_rows()],
                };
                for i in 0..c.num_rows() {
                    let Some(m) = meas[i] else { continue };
                    let t = match (ts[i], te[i]) {
                        (Some(a), Some(b)) => Some(0.5 * (a + b)),
                        (a, _) => a,
                    };
                    rows.push(Row {
                        observable: "cut_depth".to_string(),
                        sim: pred[i],
                        real: m,
                        t,
                        pass: Some(pass[i]),
                        feed: Some(feed[i]),
                        doc: Some(doc[i]),
                        removed: Some(removed[i]),
                        compliance_response: fin(response[i]),
                        ..Row::default()
                    });
                }
            }
        }
        let rms = |obs: &str| {
            let g: Vec<f64> = rows
                .iter()
                .filter(|r| r.observable == obs)
                .map(|r| r.real - r.sim)
                .collect();
            if g.is_empty() {
                None
            } else {
                fin((g.iter().map(|x| x * x).sum::<f64>() / g.len() as f64).sqrt())
            }
        };
        let count = |obs: &str| rows.iter().filter(|r| r.observable == obs).count();
        // The three observables every robot run can have, always present
        // (n = 0 when absent), then any comparison method's.
        let names: std::collections::BTreeSet<&str> = [TOUCH_REGISTERED, TOUCH_AE, "cut_depth"]
            .into_iter()
            .chain(rows.iter().map(|r| r.observable.as_str()))
            .collect();
        let summary = ObserveSummary {
            rows: rows.len(),
            plane_fit: fit.into(),
            observables: names
                .into_iter()
                .map(|obs| {
                    (
                        obs.to_string(),
                        ObservableGap {
                            n: count(obs),
                            rms_gap_mm: rms(obs),
                        },
                    )
                })
                .collect(),
        };
        Ok(StageOutput::typed(&summary)?.with("observations", build(&ctx.run.spec.id, &rows)))
    }
}

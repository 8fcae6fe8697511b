//! The `touches` artifact: probe.parquet's columns (docs/formats.md §4) plus
//! what later stages need — the plan `seq`, the unit approach direction and
//! the sign of the move that preceded the approach along the face normal.

use crate::err;
use arrow::array::{Array, Float64Array};
use arrow::record_batch::RecordBatch;
use nalgebra::Vector3;
use sparkout_pipeline::contracts::{batch_f64, batch_i32, batch_str, BatchBuilder};
use sparkout_pipeline::Result;

use super::planes::Face;

/// One registered (or AE-derived) touch.
#[derive(Debug, Clone, PartialEq)]
pub struct Touch {
    /// Controller time of the registration / contact.
    pub t_s: f64,
    pub face: Face,
    pub point: i32,
    pub trial: i32,
    pub method: String,
    pub approach_mm_s: f64,
    pub nom: Vector3<f64>,
    pub p: Vector3<f64>,
    /// Plan row, −1 when unknown.
    pub seq: i32,
    /// Unit approach direction.
    pub dir: Vector3<f64>,
    /// Sign (±1) of the last move along the face's normal axis before the
    /// approach began (backlash), when the motion log says.
    pub prev_move_dir: Option<f64>,
    /// `probe` (registered by the controller) or `ae` (from the AE signal).
    pub source: String,
}

impl Touch {
    /// The registered normal coordinate (z on `xy`, x on `yz`, y on `zx`).
    pub fn normal(&self) -> f64 {
        self.p[self.face.normal_axis()]
    }
    pub fn nominal_normal(&self) -> f64 {
        self.nom[self.face.normal_axis()]
    }
    /// The approach velocity's component along the +axis of the normal
    /// coordinate (mm/s, signed): a trigger latency L moves the registered
    /// normal coordinate by L times this.
    pub fn approach_normal_mm_s(&self) -> f64 {
        self.approach_mm_s * self.dir[self.face.normal_axis()]
    }
}

pub fn to_batch(t: &[Touch]) -> RecordBatch {
    let col = |f: &dyn Fn(&Touch) -> f64| t.iter().map(f).collect::<Vec<f64>>();
    BatchBuilder::new()
        .f64("t_s", col(&|x| x.t_s))
        .str(
            "face",
            &t.iter().map(|x| x.face.label()).collect::<Vec<_>>(),
        )
        .i32("point", t.iter().map(|x| x.point).collect())
        .i32("trial", t.iter().map(|x| x.trial).collect())
        .str(
            "method",
            &t.iter().map(|x| x.method.as_str()).collect::<Vec<_>>(),
        )
        .f64("approach_mm_s", col(&|x| x.approach_mm_s))
        .f64("nom_x_mm", col(&|x| x.nom.x))
        .f64("nom_y_mm", col(&|x| x.nom.y))
        .f64("nom_z_mm", col(&|x| x.nom.z))
        .f64("x_mm", col(&|x| x.p.x))
        .f64("y_mm", col(&|x| x.p.y))
        .f64("z_mm", col(&|x| x.p.z))
        .i32("seq", t.iter().map(|x| x.seq).collect())
        .f64("dir_x", col(&|x| x.dir.x))
        .f64("dir_y", col(&|x| x.dir.y))
        .f64("dir_z", col(&|x| x.dir.z))
        .opt_f64("prev_move_dir", t.iter().map(|x| x.prev_move_dir).collect())
        .str(
            "source",
            &t.iter().map(|x| x.source.as_str()).collect::<Vec<_>>(),
        )
        .build()
}

/// A nullable float column as options.
pub fn opt_col(b: &RecordBatch, name: &str) -> Result<Vec<Option<f64>>> {
    let a = b
        .column_by_name(name)
        .and_then(|c| c.as_any().downcast_ref::<Float64Array>())
        .ok_or_else(|| err!("artifact has no float64 column `{name}`"))?;
    Ok((0..a.len())
        .map(|i| (!a.is_null(i)).then(|| a.value(i)))
        .collect())
}

pub fn from_batch(b: &RecordBatch) -> Result<Vec<Touch>> {
    let f = |n: &str| batch_f64(b, n);
    let (t, v, nx, ny, nz, x, y, z) = (
        f("t_s")?,
        f("approach_mm_s")?,
        f("nom_x_mm")?,
        f("nom_y_mm")?,
        f("nom_z_mm")?,
        f("x_mm")?,
        f("y_mm")?,
        f("z_mm")?,
    );
    let (dx, dy, dz) = (f("dir_x")?, f("dir_y")?, f("dir_z")?);
    let face = batch_str(b, "face")?;
    let method = batch_str(b, "method")?;
    let source = batch_str(b, "source")?;
    let point = batch_i32(b, "point")?;
    let trial = batch_i32(b, "trial")?;
    let seq = batch_i32(b, "seq")?;
    let prev = opt_col(b, "prev_move_dir")?;
    (0..b.num_rows())
        .map(|i| {
            Ok(Touch {
                t_s: t[i],
                face: Face::parse(&face[i])
                    .ok_or_else(|| err!("touches: unknown face `{}` in row {i}", face[i]))?,
                point: point[i],
                trial: trial[i],
                method: method[i].clone(),
                approach_mm_s: v[i],
                nom: Vector3::new(nx[i], ny[i], nz[i]),
                p: Vector3::new(x[i], y[i], z[i]),
                seq: seq[i],
                dir: Vector3::new(dx[i], dy[i], dz[i]),
                prev_move_dir: prev[i],
                source: source[i].clone(),
            })
        })
        .collect()
}

/// The upstream `touches` artifact of a run.
pub fn require(ctx: &sparkout_pipeline::StageContext) -> Result<Vec<Touch>> {
    let b = ctx.artifacts.require("touches")?;
    from_batch(&b)
}

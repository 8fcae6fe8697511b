//! The AE chain's inputs: plan.parquet rows (which face/point/trial a
//! motion segment probes) and motion.parquet interpolated at a contact's time.

use super::*;

/// One plan row.
#[derive(Debug, Clone)]
pub struct PlanRow {
    pub seq: i32,
    pub face: Face,
    pub point: i32,
    pub trial: i32,
    pub method: String,
    pub approach_mm_s: f64,
    pub nom: Vector3<f64>,
    pub dir: Vector3<f64>,
}

pub(super) fn unknown_face(path: &Path, label: &str, row: usize) -> InputError {
    InputError::new(
        path,
        format!(
            "unknown face label `{label}` (expected xy, yz or zx: the faces with normal Z, X, Y)"
        ),
    )
    .column("face")
    .row(row)
}

/// The columns that name a probing point — face, point, trial, method,
/// approach speed, nominal position — shared by probe.parquet and
/// plan.parquet (contracts::schema `probing_point_columns!`).
pub struct PointColumns<'a> {
    pub face: Vec<Face>,
    pub point: &'a [i32],
    pub trial: &'a [i32],
    pub method: Vec<&'a str>,
    pub approach_mm_s: &'a [f64],
    nom_mm: [&'a [f64]; 3],
}

impl<'a> PointColumns<'a> {
    /// Reads and checks them (an unknown face label names its row).
    pub fn read(t: &'a Table) -> Result<PointColumns<'a>> {
        let face = t
            .str("face")?
            .iter()
            .enumerate()
            .map(|(i, l)| Face::parse(l).ok_or_else(|| unknown_face(t.path(), l, i)))
            .collect::<Result<Vec<Face>, InputError>>()?;
        Ok(PointColumns {
            face,
            point: t.i32("point")?,
            trial: t.i32("trial")?,
            method: t.str("method")?,
            approach_mm_s: t.f64("approach_mm_s")?,
            nom_mm: [t.f64("nom_x_mm")?, t.f64("nom_y_mm")?, t.f64("nom_z_mm")?],
        })
    }

    /// Row i's nominal position.
    pub fn nom(&self, i: usize) -> Vector3<f64> {
        Vector3::new(self.nom_mm[0][i], self.nom_mm[1][i], self.nom_mm[2][i])
    }
}

pub fn read_plan(t: &Table) -> Result<Vec<PlanRow>> {
    let path = t.path();
    let seq = t.i32("seq")?;
    let c = PointColumns::read(t)?;
    let (dx, dy, dz) = (t.f64("dir_x")?, t.f64("dir_y")?, t.f64("dir_z")?);
    let mut out = Vec::with_capacity(t.len());
    let mut seen = BTreeMap::new();
    for i in 0..t.len() {
        let d = Vector3::new(dx[i], dy[i], dz[i]);
        let n = d.norm();
        if !(n > 1e-9) {
            return Err(InputError::new(path, "approach direction is zero")
                .column("dir_x")
                .row(i)
                .into());
        }
        if let Some(prev) = seen.insert(seq[i], i) {
            return Err(InputError::new(
                path,
                format!("seq {} appears twice (rows {prev} and {i})", seq[i]),
            )
            .column("seq")
            .row(i)
            .into());
        }
        out.push(PlanRow {
            seq: seq[i],
            face: c.face[i],
            point: c.point[i],
            trial: c.trial[i],
            method: c.method[i].to_string(),
            approach_mm_s: c.approach_mm_s[i],
            nom: c.nom(i),
            dir: d / n,
        });
    }
    Ok(out)
}

/// The machine's default approach direction of a face (when no plan says):
/// `[probing].approach_dir_<face>` in the machine config, else −normal axis
/// (the block below/behind the face).
pub fn default_dir(
    machine: &sparkout_pipeline::contracts::MachineConfig,
    face: Face,
) -> Vector3<f64> {
    let probing = machine.section::<crate::robot::machine::MachineProbing>();
    let dir = probing.and_then(|p| match face {
        Face::Xy => p.approach_dir_xy,
        Face::Yz => p.approach_dir_yz,
        Face::Zx => p.approach_dir_zx,
    });
    if let Some(v) = dir {
        let d = Vector3::new(v[0], v[1], v[2]);
        if d.norm() > 0.0 {
            return d.normalize();
        }
    }
    let mut d = Vector3::zeros();
    d[face.normal_axis()] = -1.0;
    d
}

/// The motion log as the AE mapping needs it.
pub struct Motion {
    pub(super) path: std::path::PathBuf,
    t: Vec<f64>,
    pos: [Vec<f64>; 3],
    cmd: [Vec<f64>; 3],
    segment: Option<Vec<i32>>,
    /// First sample index of each segment value ≥ 0.
    seg_first: BTreeMap<i32, usize>,
    /// Index range of each segment value ≥ 0 (first, last).
    seg_span: BTreeMap<i32, (usize, usize)>,
    /// Whether positions are measured (`act_*`) rather than commanded.
    pub measured: bool,
}

impl Motion {
    pub fn from_table(t: &Table) -> Result<Motion> {
        let ts = t.f64("t_s")?.to_vec();
        let cmd = [
            t.f64("cmd_x_mm")?.to_vec(),
            t.f64("cmd_y_mm")?.to_vec(),
            t.f64("cmd_z_mm")?.to_vec(),
        ];
        let has_act = ["act_x_mm", "act_y_mm", "act_z_mm"].iter().all(|c| {
            t.has(c)
                && t.batch()
                    .column_by_name(c)
                    .is_some_and(|a| a.null_count() == 0)
        });
        let pos = if has_act {
            let v = [t.f64("act_x_mm")?, t.f64("act_y_mm")?, t.f64("act_z_mm")?];
            for (k, c) in v.iter().enumerate() {
                if let Some(i) = c.iter().position(|x| !x.is_finite()) {
                    return Err(InputError::new(t.path(), "NaN or infinite position")
                        .column(["act_x_mm", "act_y_mm", "act_z_mm"][k])
                        .row(i)
                        .into());
                }
            }
            [v[0].to_vec(), v[1].to_vec(), v[2].to_vec()]
        } else {
            cmd.clone()
        };
        let segment = t.opt_i32("segment").map(|s| s.to_vec());
        let mut seg_first = BTreeMap::new();
        let mut seg_span = BTreeMap::new();
        if let Some(s) = &segment {
            for (i, &v) in s.iter().enumerate() {
                if v >= 0 {
                    seg_first.entry(v).or_insert(i);
                    seg_span
                        .entry(v)
                        .and_modify(|e: &mut (usize, usize)| e.1 = i)
                        .or_insert((i, i));
                }
            }
        }
        Ok(Motion {
            path: t.path().to_path_buf(),
            t: ts,
            pos,
            cmd,
            segment,
            seg_first,
            seg_span,
            measured: has_act,
        })
    }

    pub fn has_segments(&self) -> bool {
        self.segment.is_some()
    }

    pub fn span_s(&self) -> (f64, f64) {
        (self.t[0], self.t[self.t.len() - 1])
    }

    /// Linear interpolation of the TCP position at controller time `t`;
    /// `None` outside the log.
    pub fn position_at(&self, t: f64) -> Option<Vector3<f64>> {
        let n = self.t.len();
        if !(t >= self.t[0] && t <= self.t[n - 1]) {
            return None;
        }
        let j = self.t.partition_point(|&x| x <= t).clamp(1, n - 1);
        let (t0, t1) = (self.t[j - 1], self.t[j]);
        let w = if t1 > t0 { (t - t0) / (t1 - t0) } else { 0.0 };
        let at = |k: usize| self.pos[k][j - 1] + w * (self.pos[k][j] - self.pos[k][j - 1]);
        Some(Vector3::new(at(0), at(1), at(2)))
    }

    /// The plan `seq` being approached at time `t`: the segment of the last
    /// sample at or before `t`; when that is −1 (the robot already stopping
    /// or retracting), the segment whose samples lie within `tol` of `t`.
    pub fn segment_at(&self, t: f64, tol: f64) -> Option<i32> {
        let seg = self.segment.as_ref()?;
        let j = self.t.partition_point(|&x| x <= t);
        if j > 0 && seg[j - 1] >= 0 {
            return Some(seg[j - 1]);
        }
        let mut best: Option<(f64, i32)> = None;
        let lo = self.t.partition_point(|&x| x < t - tol);
        let hi = self.t.partition_point(|&x| x <= t + tol);
        for (ti, &s) in self.t[lo..hi].iter().zip(&seg[lo..hi]) {
            if s >= 0 {
                let d = (ti - t).abs();
                if best.is_none_or(|b| d < b.0) {
                    best = Some((d, s));
                }
            }
        }
        best.map(|b| b.1)
    }

    /// Sign (±1) of the last commanded move along `axis` before segment
    /// `seq` began (for backlash: the direction the axis was last driven).
    pub fn prev_move_sign(&self, seq: i32, axis: usize) -> Option<f64> {
        let first = *self.seg_first.get(&seq)?;
        let c = &self.cmd[axis];
        let mut i = first;
        while i > 0 {
            let d = c[i] - c[i - 1];
            if d.abs() > 1e-9 {
                return Some(d.signum());
            }
            i -= 1;
        }
        None
    }

    /// Time span of a segment.
    pub fn segment_span_s(&self, seq: i32) -> Option<(f64, f64)> {
        self.seg_span
            .get(&seq)
            .map(|&(a, b)| (self.t[a], self.t[b]))
    }
}

//! `repeatability`: the thesis's "accuracy error" (docs/models.md §1.1) — per
//! (method, approach speed, face), over the trials of each nominal point, the
//! range (max − min) and the standard deviation of the coordinate normal to
//! the face; per (method, speed) the mean range over the faces.
//!
//! Beyond the source: each touch's deviation from its nominal is split into
//! a bias (mean deviation) and a scatter (within-point spread), and with ≥ 2
//! approach speeds the trigger latency L is estimated from bias ≈ v·L along
//! the approach direction — a regression of the deviation on the signed
//! normal approach speed, within each nominal point (so the block's unknown
//! pose, the same at every speed, cancels).

use std::collections::BTreeMap;

use sparkout_pipeline::config_check::{Check, Section, SectionCheck};
use sparkout_pipeline::contracts::BatchBuilder;
use sparkout_pipeline::{Result, Stage, StageContext, StageOutput, StageSpec};

use super::planes::Face;
use super::summary::{
    fin, fin_opt, FaceRepeatability, MethodLatency, RepeatabilityGroup, RepeatabilitySummary,
};
use super::touches::{self, Touch};

/// Statistics of one face within one (method, speed) group.
#[derive(Debug, Clone, PartialEq)]
pub struct FaceStats {
    /// Mean over nominal points (with ≥ 2 trials) of max − min of the
    /// normal coordinate.
    pub range_mm: Option<f64>,
    /// Pooled within-point standard deviation of the normal coordinate (the
    /// scatter).
    pub std_mm: Option<f64>,
    /// Mean deviation of the normal coordinate from its nominal (the bias).
    pub bias_mm: f64,
    /// Mean signed normal approach speed of the touches (mm/s).
    pub mean_approach_normal_mm_s: f64,
    pub n: usize,
    pub n_points: usize,
}

/// Range and pooled std over the trials of each nominal point.
pub fn face_stats(ts: &[&Touch]) -> FaceStats {
    let mut by_point: BTreeMap<i32, Vec<f64>> = BTreeMap::new();
    for t in ts {
        by_point.entry(t.point).or_default().push(t.normal());
    }
    let (mut ranges, mut ss, mut dof) = (Vec::new(), 0.0, 0usize);
    for v in by_point.values() {
        if v.len() < 2 {
            continue;
        }
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        ranges.push(hi - lo);
        let m = v.iter().sum::<f64>() / v.len() as f64;
        ss += v.iter().map(|x| (x - m).powi(2)).sum::<f64>();
        dof += v.len() - 1;
    }
    let n = ts.len();
    FaceStats {
        range_mm: (!ranges.is_empty()).then(|| ranges.iter().sum::<f64>() / ranges.len() as f64),
        std_mm: (dof > 0).then(|| (ss / dof as f64).sqrt()),
        bias_mm: ts
            .iter()
            .map(|t| t.normal() - t.nominal_normal())
            .sum::<f64>()
            / n.max(1) as f64,
        mean_approach_normal_mm_s: ts.iter().map(|t| t.approach_normal_mm_s()).sum::<f64>()
            / n.max(1) as f64,
        n,
        n_points: by_point.len(),
    }
}

/// Trigger latency estimate of one method.
#[derive(Debug, Clone, PartialEq)]
pub struct Latency {
    pub latency_s: f64,
    pub stderr_s: f64,
    pub n: usize,
    pub speeds_mm_s: Vec<f64>,
}

/// L from deviation = a_point + L·u, u = approach speed × dir along the +axis
/// of the normal coordinate; within-point least squares. `None` unless some
/// point was touched at ≥ 2 speeds.
pub fn latency(ts: &[&Touch]) -> Option<Latency> {
    let mut groups: BTreeMap<(Face, i32), Vec<(f64, f64)>> = BTreeMap::new();
    for t in ts {
        groups
            .entry((t.face, t.point))
            .or_default()
            .push((t.approach_normal_mm_s(), t.normal() - t.nominal_normal()));
    }
    let (mut sxx, mut sxy, mut n, mut k) = (0.0, 0.0, 0usize, 0usize);
    let mut demeaned = Vec::new();
    for g in groups.values() {
        let m = g.len() as f64;
        let (mu, me) = (
            g.iter().map(|p| p.0).sum::<f64>() / m,
            g.iter().map(|p| p.1).sum::<f64>() / m,
        );
        for &(u, e) in g {
            sxx += (u - mu).powi(2);
            sxy += (u - mu) * (e - me);
            demeaned.push((u - mu, e - me));
        }
        n += g.len();
        k += 1;
    }
    let mut speeds: Vec<f64> = ts.iter().map(|t| t.approach_mm_s).collect();
    speeds.sort_by(f64::total_cmp);
    speeds.dedup();
    // Different speeds must actually vary u within points.
    let scale = demeaned.iter().map(|p| p.0.abs()).fold(0.0, f64::max);
    if speeds.len() < 2 || !(sxx > 1e-18 * (1.0 + scale * scale)) {
        return None;
    }
    let l = sxy / sxx;
    let dof = n as f64 - k as f64 - 1.0;
    let rss: f64 = demeaned.iter().map(|(u, e)| (e - l * u).powi(2)).sum();
    let se = if dof > 0.0 {
        (rss / dof / sxx).sqrt()
    } else {
        f64::NAN
    };
    Some(Latency {
        latency_s: l,
        stderr_s: se,
        n,
        speeds_mm_s: speeds,
    })
}

/// Everything the stage computes, for the summary and the report.
pub fn analyse(
    all: &[Touch],
    latency_method: &str,
) -> (RepeatabilitySummary, arrow::record_batch::RecordBatch) {
    // (method, speed bits) → touches, groups in (method, speed) order.
    let mut groups: BTreeMap<(String, u64), Vec<&Touch>> = BTreeMap::new();
    for t in all {
        groups
            .entry((t.method.clone(), t.approach_mm_s.to_bits()))
            .or_default()
            .push(t);
    }
    let mut by_method: BTreeMap<String, Vec<&Touch>> = BTreeMap::new();
    for t in all {
        by_method.entry(t.method.clone()).or_default().push(t);
    }
    let lat: BTreeMap<String, Latency> = by_method
        .iter()
        .filter_map(|(m, ts)| latency(ts).map(|l| (m.clone(), l)))
        .collect();
    // The headline latency: the requested method, else `ae` when it has
    // one, else the method with the most touches.
    let headline = match latency_method {
        "auto" => lat
            .get("ae")
            .or_else(|| {
                lat.iter()
                    .max_by_key(|(m, l)| (l.n, std::cmp::Reverse((*m).clone())))
                    .map(|(_, l)| l)
            })
            .map(|l| l.latency_s),
        m => lat.get(m).map(|l| l.latency_s),
    };
    let mut out_groups = Vec::new();
    let mut rows: Vec<(String, f64, Face, FaceStats, Option<f64>)> = Vec::new();
    for ((method, _), ts) in &groups {
        let v = ts[0].approach_mm_s;
        let mut faces = BTreeMap::new();
        let mut ranges = Vec::new();
        let mut stds = Vec::new();
        for face in Face::ALL {
            let ft: Vec<&Touch> = ts.iter().copied().filter(|t| t.face == face).collect();
            if ft.is_empty() {
                continue;
            }
            let s = face_stats(&ft);
            let corrected = lat
                .get(method)
                .map(|l| s.bias_mm - l.latency_s * s.mean_approach_normal_mm_s);
            faces.insert(
                face.label().into(),
                FaceRepeatability {
                    range_mm: fin_opt(s.range_mm),
                    std_mm: fin_opt(s.std_mm),
                    n: s.n,
                    n_points: s.n_points,
                    bias_mm: s.bias_mm,
                    scatter_mm: fin_opt(s.std_mm),
                    bias_latency_corrected_mm: fin_opt(corrected),
                },
            );
            ranges.extend(s.range_mm);
            stds.extend(s.std_mm);
            rows.push((method.clone(), v, face, s, corrected));
        }
        let mean = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
        out_groups.push(RepeatabilityGroup {
            method: method.clone(),
            approach_mm_s: v,
            faces,
            mean_range_mm: fin_opt(mean(&ranges)),
            mean_std_mm: fin_opt(mean(&stds)),
        });
    }
    let latency_by_method: BTreeMap<String, MethodLatency> = lat
        .iter()
        .map(|(m, l)| {
            (
                m.clone(),
                MethodLatency {
                    latency_s: l.latency_s,
                    stderr_s: fin(l.stderr_s),
                    n: l.n,
                    speeds_mm_s: l.speeds_mm_s.clone(),
                },
            )
        })
        .collect();
    let summary = RepeatabilitySummary {
        groups: out_groups,
        latency_s: fin_opt(headline),
        latency_by_method,
    };
    let batch = BatchBuilder::new()
        .str(
            "method",
            &rows.iter().map(|r| r.0.as_str()).collect::<Vec<_>>(),
        )
        .f64("approach_mm_s", rows.iter().map(|r| r.1).collect())
        .str(
            "face",
            &rows.iter().map(|r| r.2.label()).collect::<Vec<_>>(),
        )
        .i32("n", rows.iter().map(|r| r.3.n as i32).collect())
        .i32(
            "n_points",
            rows.iter().map(|r| r.3.n_points as i32).collect(),
        )
        .opt_f64("range_mm", rows.iter().map(|r| r.3.range_mm).collect())
        .opt_f64("std_mm", rows.iter().map(|r| r.3.std_mm).collect())
        .f64("bias_mm", rows.iter().map(|r| r.3.bias_mm).collect())
        .opt_f64(
            "bias_latency_corrected_mm",
            rows.iter().map(|r| r.4).collect(),
        )
        .build();
    (summary, batch)
}

/// Pooled within-point standard deviation of each face over every touch
/// (the thesis's α vector of the error vector E = A·α, docs/models.md §1.3),
/// pooled over (method, speed, point) groups.
pub fn pooled_std_by_face(all: &[Touch]) -> [Option<f64>; 3] {
    let mut out = [None; 3];
    for face in Face::ALL {
        let mut by: BTreeMap<(String, u64, i32), Vec<f64>> = BTreeMap::new();
        for t in all.iter().filter(|t| t.face == face) {
            by.entry((t.method.clone(), t.approach_mm_s.to_bits(), t.point))
                .or_default()
                .push(t.normal());
        }
        let (mut ss, mut dof) = (0.0, 0usize);
        for v in by.values().filter(|v| v.len() >= 2) {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            ss += v.iter().map(|x| (x - m).powi(2)).sum::<f64>();
            dof += v.len() - 1;
        }
        out[face.index()] = (dof > 0).then(|| (ss / dof as f64).sqrt());
    }
    out
}

pub struct RepeatabilityStage;

/// `[robot.repeatability]`.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RepeatabilityConfig {
    /// Which method's latency is the headline (`auto`: AE first).
    pub latency_method: String,
}

impl Default for RepeatabilityConfig {
    fn default() -> Self {
        RepeatabilityConfig {
            latency_method: "auto".to_string(),
        }
    }
}

impl Section for RepeatabilityConfig {
    const CHECKS: &'static [(&'static str, Check)] = &[(
        "latency_method",
        Check::OneOf(&["auto", "ae", "electrical", "mechanical"]),
    )];
}

const SPEC: StageSpec = StageSpec {
    name: "repeatability",
    version: 1,
    reads: &[],
    reads_artifacts: &["touches"],
    writes: &["repeatability"],
    reads_augmented_model: false,
    about: "range and std of the normal coordinate per method × speed × face; bias vs scatter; trigger latency (docs/models.md §1.1)",
    config: SectionCheck::of::<RepeatabilityConfig>(),
};

impl Stage for RepeatabilityStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let t = touches::require(ctx)?;
        let cfg: &RepeatabilityConfig = ctx.section()?;
        let (summary, batch) = analyse(&t, &cfg.latency_method);
        Ok(StageOutput::typed(&summary)?.with("repeatability", batch))
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::robot::planes::tests::Rng;
    use nalgebra::Vector3;

    /// Touches on three axis-aligned faces of a block at `origin` (outward
    /// normals +x, +y, +z; approached along −normal), 12 points per face,
    /// `trials` per point at each speed, registered with latency `lat_s`
    /// and normal noise σ.
    pub fn synth_touches(
        origin: Vector3<f64>,
        speeds: &[f64],
        trials: i32,
        lat_s: f64,
        sigma: f64,
        seed: u64,
    ) -> Vec<Touch> {
        let mut rng = Rng::new(seed);
        let mut out = Vec::new();
        let mut t = 0.0;
        let mut seq = 0;
        for &v in speeds {
            for face in Face::ALL {
                let a = face.normal_axis();
                let (u, w) = face.in_plane_axes();
                for point in 0..12 {
                    let sq = point / 4;
                    let half = [20.0, 13.0, 6.0][sq as usize];
                    let corner =
                        [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)][(point % 4) as usize];
                    let mut nom = origin;
                    nom[u] += 25.0 + corner.0 * half;
                    nom[w] += 25.0 + corner.1 * half;
                    for trial in 0..trials {
                        let mut dir = Vector3::zeros();
                        dir[a] = -1.0;
                        let p = nom + dir * (v * lat_s) + dir * (sigma * rng.normal());
                        out.push(Touch {
                            t_s: t,
                            face,
                            point,
                            trial,
                            method: "ae".into(),
                            approach_mm_s: v,
                            nom,
                            p,
                            seq,
                            dir,
                            prev_move_dir: Some(1.0),
                            source: "probe".into(),
                        });
                        t += 1.0;
                        seq += 1;
                    }
                }
            }
        }
        out
    }

    #[test]
    fn range_std_and_latency_from_two_speeds() {
        let lat = 0.004;
        let ts = synth_touches(Vector3::new(0.0, 0.0, 0.0), &[5.0, 10.0], 10, lat, 0.005, 9);
        let (s, b) = analyse(&ts, "auto");
        let l = s.latency_s.unwrap();
        let se = s.latency_by_method["ae"].stderr_s.unwrap();
        assert!((l - lat).abs() < 4.0 * se && se < 2e-4, "L {l} ± {se}");
        let g = &s.groups[0];
        assert_eq!(g.method, "ae");
        assert_eq!(g.approach_mm_s, 5.0);
        let xy = &g.faces["xy"];
        let std = xy.std_mm.unwrap();
        assert!((std - 0.005).abs() < 0.001, "{std}");
        // Range of 10 normal draws ≈ 3.1 σ.
        let range = xy.range_mm.unwrap();
        assert!(range > 2.0 * 0.005 && range < 4.5 * 0.005, "{range}");
        // Bias along the normal = −v·L (overshoot into the face).
        assert!((xy.bias_mm + 5.0 * lat).abs() < 0.002);
        let corrected = xy.bias_latency_corrected_mm.unwrap();
        assert!(corrected.abs() < 0.002, "{corrected}");
        assert_eq!(b.num_rows(), 6);
        // One speed: no latency.
        let one: Vec<Touch> = ts
            .iter()
            .filter(|t| t.approach_mm_s == 5.0)
            .cloned()
            .collect();
        let (s1, _) = analyse(&one, "auto");
        assert!(s1.latency_s.is_none());
    }
}

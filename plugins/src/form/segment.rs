//! `segment`: split the wheel's usable radius range into N segments, one
//! tool-path program per segment made for the segment's mean radius, and
//! the largest profile error a wheel anywhere in the segment leaves
//! (docs/models.md §4: the error is close to linear in R_kn − R_k, so N segments
//! cut it about N-fold). Also a sweep over N and the tool paths (X, Z, A, C
//! per profile point) of each segment's nominal.

use crate::form::summary::{SegmentRow, SegmentSummary, SweepPoint};
use crate::form::tables::PROFILE;
use crate::{bail, err};
use arrow::record_batch::RecordBatch;
use sparkout_pipeline::config_check::SectionCheck;
use sparkout_pipeline::contracts::BatchBuilder;
use sparkout_pipeline::{InputError, Result, Stage, StageContext, StageOutput, StageSpec};

use super::config::{curvature, SegmentSection, MAX_SEGMENTS};
use super::curvature::Profile;
use super::model::{centre_path, profile_rows, CentrePath, DeltaModel, WheelRange};

/// Segmentation settings (`[form.segment]`; the range defaults to the
/// machine's `[wheel]`).
#[derive(Debug, Clone, Copy)]
pub struct SegmentConfig {
    pub range: WheelRange,
    pub segments: usize,
    /// Radii sampled per segment (ends included) when searching its largest
    /// error.
    pub radius_samples: usize,
    /// The sweep runs N = 1..=sweep_max.
    pub sweep_max: usize,
    /// Axial position of the section (Z of the tool path).
    pub z_mm: f64,
    pub model: DeltaModel,
}

/// One segment's result.
#[derive(Debug, Clone)]
pub struct Segment {
    pub index: usize,
    pub nominal_mm: f64,
    pub r_min_mm: f64,
    pub r_max_mm: f64,
    /// max over the segment's radii and the profile of |δ|.
    pub max_error_mm: f64,
    /// Where (φ) and at which radius it occurs.
    pub phi_at_max_rad: f64,
    pub radius_at_max_mm: f64,
    /// δ(φ) at the segment's two ends (the error envelope: δ is close to
    /// linear in R_kn − R_k).
    pub error_at_r_min_mm: Vec<f64>,
    pub error_at_r_max_mm: Vec<f64>,
    pub path: CentrePath,
}

/// The segments of the range, each with its error and tool path. Errors
/// with the profile point where the wheel cannot follow the profile.
pub fn segment(
    p: &Profile,
    range: &WheelRange,
    n: usize,
    samples: usize,
    model: DeltaModel,
) -> Result<Vec<Segment>, (usize, f64)> {
    let width = range.range_mm / n as f64;
    let samples = samples.max(2);
    (0..n)
        .map(|k| {
            // Segment 1 is the new wheel (largest radii); dressing walks down.
            let hi = range.r_max_mm - k as f64 * width;
            let lo = hi - width;
            let nominal = 0.5 * (lo + hi);
            let path = centre_path(p, nominal).with_model(model);
            let mut best = (0.0_f64, p.phi_rad[0], nominal);
            let mut ends = (Vec::new(), Vec::new());
            for s in 0..samples {
                let rk = lo + (hi - lo) * s as f64 / (samples - 1) as f64;
                let mut col = Vec::with_capacity(p.len());
                for i in 0..p.len() {
                    let d = path.delta(p, i, rk).ok_or((i, rk))?;
                    if d.abs() > best.0 {
                        best = (d.abs(), p.phi_rad[i], rk);
                    }
                    col.push(d);
                }
                if s == 0 {
                    ends.0 = col;
                } else if s == samples - 1 {
                    ends.1 = col;
                }
            }
            Ok(Segment {
                index: k + 1,
                nominal_mm: nominal,
                r_min_mm: lo,
                r_max_mm: hi,
                max_error_mm: best.0,
                phi_at_max_rad: best.1,
                radius_at_max_mm: best.2,
                error_at_r_min_mm: ends.0,
                error_at_r_max_mm: ends.1,
                path,
            })
        })
        .collect()
}

/// max over segments of max_error_mm.
pub fn overall(segs: &[Segment]) -> f64 {
    segs.iter().map(|s| s.max_error_mm).fold(0.0, f64::max)
}

/// The largest error for N = 1..=max segments.
pub fn sweep(
    p: &Profile,
    range: &WheelRange,
    max: usize,
    samples: usize,
    model: DeltaModel,
) -> Result<Vec<(usize, f64)>, (usize, f64)> {
    (1..=max)
        .map(|n| Ok((n, overall(&segment(p, range, n, samples, model)?))))
        .collect()
}

pub fn segment_rows(segs: &[Segment]) -> Vec<SegmentRow> {
    segs.iter()
        .map(|s| SegmentRow {
            segment: s.index,
            nominal_mm: s.nominal_mm,
            r_min_mm: s.r_min_mm,
            r_max_mm: s.r_max_mm,
            max_error_mm: s.max_error_mm,
            phi_at_max_rad: s.phi_at_max_rad,
            radius_at_max_mm: s.radius_at_max_mm,
        })
        .collect()
}

pub fn summary(
    segs: &[Segment],
    sweep: &[(usize, f64)],
    range: &WheelRange,
    points: usize,
) -> SegmentSummary {
    SegmentSummary {
        r_max_mm: range.r_max_mm,
        range_mm: range.range_mm,
        profile_points: points,
        segments: segment_rows(segs),
        max_error_mm: overall(segs),
        sweep: sweep
            .iter()
            .map(|&(segments, max_error_mm)| SweepPoint {
                segments,
                max_error_mm,
            })
            .collect(),
    }
}

/// `segments`: one row per segment.
pub fn segments_batch(segs: &[Segment]) -> RecordBatch {
    BatchBuilder::new()
        .i32("segment", segs.iter().map(|s| s.index as i32).collect())
        .f64("nominal_mm", segs.iter().map(|s| s.nominal_mm).collect())
        .f64("r_min_mm", segs.iter().map(|s| s.r_min_mm).collect())
        .f64("r_max_mm", segs.iter().map(|s| s.r_max_mm).collect())
        .f64(
            "max_error_mm",
            segs.iter().map(|s| s.max_error_mm).collect(),
        )
        .f64(
            "phi_at_max_rad",
            segs.iter().map(|s| s.phi_at_max_rad).collect(),
        )
        .f64(
            "radius_at_max_mm",
            segs.iter().map(|s| s.radius_at_max_mm).collect(),
        )
        .build()
}

/// `segment_error`: δ(φ) at both ends of every segment (for the report's
/// profile error against φ per segment).
pub fn segment_error_batch(p: &Profile, segs: &[Segment]) -> RecordBatch {
    let mut seg = Vec::new();
    let mut phi = Vec::new();
    let (mut lo, mut hi) = (Vec::new(), Vec::new());
    for s in segs {
        for i in 0..p.len() {
            seg.push(s.index as i32);
            phi.push(p.phi_rad[i]);
            lo.push(s.error_at_r_min_mm[i]);
            hi.push(s.error_at_r_max_mm[i]);
        }
    }
    BatchBuilder::new()
        .i32("segment", seg)
        .f64("phi_rad", phi)
        .f64("error_at_r_min_mm", lo)
        .f64("error_at_r_max_mm", hi)
        .build()
}

/// `toolpath`: X, Z, A, C per profile point for each segment's nominal.
pub fn toolpath_batch(p: &Profile, segs: &[Segment], z_mm: f64) -> RecordBatch {
    let n = p.len() * segs.len();
    let (mut seg, mut nom, mut point, mut phi) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    let (mut x, mut a, mut c) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    for s in segs {
        for i in 0..p.len() {
            seg.push(s.index as i32);
            nom.push(s.nominal_mm);
            point.push(i as i32);
            phi.push(p.phi_rad[i]);
            x.push(s.path.x_mm[i]);
            a.push(s.path.gamma_rad[i]);
            c.push(s.path.c_rad[i]);
        }
    }
    BatchBuilder::new()
        .i32("segment", seg)
        .f64("nominal_mm", nom)
        .i32("point", point)
        .f64("phi_rad", phi)
        .f64("x_mm", x)
        .f64("z_mm", vec![z_mm; n])
        .f64("a_rad", a)
        .f64("c_rad", c)
        .build()
}

/// The settings for a run: stage config first, then the machine.
pub fn config_for(cfg: &SegmentSection, machine: Option<WheelRange>) -> Result<SegmentConfig> {
    let r_max = cfg.r_max_mm.or(machine.map(|m| m.r_max_mm));
    let width = cfg.range_mm.or(machine.map(|m| m.range_mm));
    let (Some(r_max_mm), Some(range_mm)) = (r_max, width) else {
        bail!("the wheel's usable range is unknown: give r_max_mm and range_mm (--r-max-mm, --range-mm) or a machine with [wheel] radius_max_mm and usable_range_mm");
    };
    let range = WheelRange { r_max_mm, range_mm };
    range.check().map_err(|m| err!(m))?;
    Ok(SegmentConfig {
        range,
        segments: cfg.segments.unwrap_or(5),
        radius_samples: cfg.radius_samples,
        sweep_max: cfg.sweep_max,
        z_mm: cfg.z_mm.unwrap_or(0.0),
        model: cfg.delta_model,
    })
}

/// Everything `segment` computes for a profile.
pub struct SegmentResult {
    pub segments: Vec<Segment>,
    pub sweep: Vec<(usize, f64)>,
    /// What the output's summary holds.
    pub summary: SegmentSummary,
    pub output: StageOutput,
}

/// Run the segmentation on a differentiated profile; `file` names the
/// profile in errors.
pub fn compute(
    p: &Profile,
    sc: &SegmentConfig,
    file: &std::path::Path,
    rows: &[usize],
) -> Result<SegmentResult> {
    let fail = |(i, rk): (usize, f64)| -> crate::Error {
        InputError::new(
            file,
            format!(
                "a wheel of radius {rk:.3} mm cannot follow the design profile here: its concave radius of curvature is smaller than the wheel"
            ),
        )
        .column("r_mm")
        .row(rows.get(i).copied().unwrap_or(i))
        .into()
    };
    let segs = segment(p, &sc.range, sc.segments, sc.radius_samples, sc.model).map_err(fail)?;
    let sw = sweep(p, &sc.range, sc.sweep_max, sc.radius_samples, sc.model).map_err(fail)?;
    let sweep_batch = BatchBuilder::new()
        .i32("segments", sw.iter().map(|s| s.0 as i32).collect())
        .f64("max_error_mm", sw.iter().map(|s| s.1).collect())
        .build();
    let summary = summary(&segs, &sw, &sc.range, p.len());
    let output = StageOutput::typed(&summary)?
        .with("segments", segments_batch(&segs))
        .with("segment_error", segment_error_batch(p, &segs))
        .with("segment_sweep", sweep_batch)
        .with("toolpath", toolpath_batch(p, &segs, sc.z_mm));
    Ok(SegmentResult {
        segments: segs,
        sweep: sw,
        summary,
        output,
    })
}

pub struct SegmentStage;

const SPEC: StageSpec = StageSpec {
    name: "segment",
    version: 1,
    reads: &[&PROFILE],
    reads_artifacts: &[],
    writes: &["segments", "segment_error", "segment_sweep", "toolpath"],
    reads_augmented_model: false,
    about: "split the usable wheel-radius range into N segments: nominal, range and max profile error per segment, tool paths (X, Z, A, C), sweep over N (docs/models.md §4)",
    config: SectionCheck::of::<SegmentSection>(),
};

impl Stage for SegmentStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let machine = WheelRange::from_machine(&ctx.run.machine).ok();
        let cfg: &SegmentSection = ctx.section()?;
        let sc = config_for(cfg, machine)?;
        let (t, rows) = profile_rows(ctx.run)?;
        let p = rows.design(t.path(), &curvature(cfg.window_points))?;
        let z = match cfg.z_mm {
            Some(z) => z,
            None => ctx.run.spec.process_f64("z_mm", 0.0),
        };
        // Segment count: stage config, else the machine's `[wheel] segments`.
        let machine_segments = ctx
            .run
            .machine
            .section::<super::config::MachineWheel>()
            .and_then(|w| w.segments);
        let segments = match (cfg.segments, machine_segments) {
            (None, Some(m)) if (1..=MAX_SEGMENTS).contains(&m) => m,
            _ => sc.segments,
        };
        let sc = SegmentConfig {
            z_mm: z,
            segments,
            ..sc
        };
        Ok(compute(&p, &sc, t.path(), &rows.design_rows)?.output)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::form::model::tests::ellipse;
    use crate::form::model::DeltaModel;

    #[test]
    fn segments_tile_the_range_and_errors_shrink_with_n() {
        let p = ellipse(720, 60.0, 40.0);
        let range = WheelRange {
            r_max_mm: 175.0,
            range_mm: 50.0,
        };
        let s5 = segment(&p, &range, 5, 11, DeltaModel::Published).unwrap();
        let noms: Vec<f64> = s5.iter().map(|s| s.nominal_mm).collect();
        assert_eq!(noms, vec![170.0, 160.0, 150.0, 140.0, 130.0]);
        assert_eq!(s5[0].r_max_mm, 175.0);
        assert!((s5[4].r_min_mm - 125.0).abs() < 1e-12);
        let sw = sweep(&p, &range, 10, 11, DeltaModel::Published).unwrap();
        for w in sw.windows(2) {
            assert!(w[1].1 < w[0].1, "max error must fall with N: {sw:?}");
        }
        // Close to linear in the radius deviation: N segments cut the error
        // roughly N-fold (not exactly: γ, hence the slope, grows with the
        // nominal radius, and the first segment has the largest nominal).
        let one = sw[0].1;
        assert!(sw[4].1 < 0.3 * one && sw[4].1 > 0.15 * one, "{sw:?}");
        assert!(sw[9].1 < 0.15 * one && sw[9].1 > 0.075 * one, "{sw:?}");
        // Each segment's max is at one of its ends (δ ≈ linear).
        for s in &s5 {
            let end = s
                .error_at_r_min_mm
                .iter()
                .chain(&s.error_at_r_max_mm)
                .fold(0.0_f64, |a, b| a.max(b.abs()));
            assert!((end - s.max_error_mm).abs() < 1e-3 * s.max_error_mm);
        }
    }

    #[test]
    fn toolpath_has_every_point_of_every_segment() {
        let p = ellipse(360, 60.0, 40.0);
        let range = WheelRange {
            r_max_mm: 175.0,
            range_mm: 50.0,
        };
        let segs = segment(&p, &range, 3, 5, DeltaModel::Published).unwrap();
        let b = toolpath_batch(&p, &segs, 12.5);
        assert_eq!(b.num_rows(), 3 * 360);
        let x = sparkout_pipeline::contracts::batch_f64(&b, "x_mm").unwrap();
        // X at φ = 0 (the major axis, γ = 0) is a + nominal.
        assert!((x[0] - (60.0 + segs[0].nominal_mm)).abs() < 1e-9);
    }

    #[test]
    fn config_is_checked() {
        let validate = sparkout_pipeline::config_check::read_section::<SegmentSection>;
        let t: toml::Table = "segments = 0".parse().unwrap();
        assert!(validate(&t).is_err());
        let t: toml::Table = "segments = 2.5".parse().unwrap();
        assert!(validate(&t).is_err());
        let t: toml::Table = "r_max_mm = 50\nrange_mm = 60".parse().unwrap();
        assert!(validate(&t).is_err());
        let t: toml::Table = "bogus = 1".parse().unwrap();
        assert!(validate(&t).is_err());
        let t: toml::Table = "segments = 4\nr_max_mm = 175\nrange_mm = 50\nwindow_points = 7"
            .parse()
            .unwrap();
        assert!(validate(&t).is_ok());
        let t: toml::Table = "radius_samples = 1".parse().unwrap();
        assert!(validate(&t).is_err());
    }
}

//! Report sections of a form-grinding run: profile error against φ per
//! segment (the segmentation of docs/models.md §4), the run's own δ(φ) for the
//! radius it was ground with, and measured against predicted error.

use sparkout_pipeline::contracts::{batch_f64, batch_i32};
use sparkout_pipeline::report::svg::{bar_chart, xy_chart, Mark, Series};
use sparkout_pipeline::report::{esc, fmt_um, table, Verdict};
use sparkout_pipeline::{ArtifactStore, ReportSection, Run};

use super::summary::{fin, ProfileErrorSummary, SegmentSummary};

fn um(x: Option<f64>) -> String {
    fmt_um(x, 2)
}

/// Every k-th point so a chart has at most `max` points per series.
fn thin(points: Vec<(f64, f64)>, max: usize) -> Vec<(f64, f64)> {
    let step = points.len().div_ceil(max.max(1)).max(1);
    points.into_iter().step_by(step).collect()
}

fn segments(s: &SegmentSummary, a: &ArtifactStore) -> ReportSection {
    let segs = &s.segments;
    let rows: Vec<Vec<String>> = segs
        .iter()
        .map(|g| {
            vec![
                g.segment.to_string(),
                format!("{:.3}", g.nominal_mm),
                format!("{:.3} – {:.3}", g.r_min_mm, g.r_max_mm),
                um(fin(g.max_error_mm)),
                format!("{:.1}", g.phi_at_max_rad.to_degrees()),
            ]
        })
        .collect();
    let mut html = format!(
        "<p>Usable wheel radius {:.1} – {:.1} mm in {} segments, one program per segment for its mean radius; largest profile error left: <b>{} µm</b>.</p>",
        s.r_max_mm - s.range_mm,
        s.r_max_mm,
        segs.len(),
        um(fin(s.max_error_mm))
    );
    html.push_str(&table(
        &[
            "segment",
            "nominal (mm)",
            "radius range (mm)",
            "max |δ| (µm)",
            "at φ (°)",
        ],
        &rows,
    ));
    if let Ok(Some(b)) = a.get("segment_error") {
        if let (Ok(seg), Ok(phi), Ok(lo), Ok(hi)) = (
            batch_i32(&b, "segment"),
            batch_f64(&b, "phi_rad"),
            batch_f64(&b, "error_at_r_min_mm"),
            batch_f64(&b, "error_at_r_max_mm"),
        ) {
            let mut ids: Vec<i32> = seg.to_vec();
            ids.dedup();
            let mut data: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
            for id in &ids {
                for (end, v) in [("smallest", lo), ("largest", hi)] {
                    let pts: Vec<(f64, f64)> = (0..seg.len())
                        .filter(|&i| seg[i] == *id)
                        .map(|i| (phi[i].to_degrees(), v[i] * 1e3))
                        .collect();
                    data.push((format!("segment {id}, {end} radius"), thin(pts, 360)));
                }
            }
            html.push_str(&delta_phi_chart(
                "Profile error against φ per segment (wheel at each end of its segment)",
                &data,
            ));
        }
    }
    let bars: Vec<(String, f64)> = s
        .sweep
        .iter()
        .map(|e| (format!("N={}", e.segments), e.max_error_mm * 1e3))
        .collect();
    html.push_str(&bar_chart(
        "Largest profile error against the number of segments",
        "max |δ| (µm)",
        &bars,
    ));
    ReportSection {
        title: "Wheel-radius segmentation".into(),
        html,
    }
}

fn run_error(s: &ProfileErrorSummary, a: &ArtifactStore) -> ReportSection {
    let rows: Vec<Vec<String>> = s
        .radii
        .iter()
        .map(|r| {
            vec![
                format!("{:.3}", r.wheel_radius_mm),
                um(fin(r.max_error_mm)),
                um(fin(r.rms_error_mm)),
            ]
        })
        .collect();
    let mut html = format!(
        "<p>Program nominal {:.3} mm; {} design points, {} of them straight (curvature ≈ 0).</p>",
        s.nominal_mm, s.points, s.straight_points
    );
    html.push_str(&table(
        &["wheel radius (mm)", "max |δ| (µm)", "RMS δ (µm)"],
        &rows,
    ));
    if let Ok(Some(b)) = a.get("profile_error") {
        if let (Ok(rk), Ok(phi), Ok(d)) = (
            batch_f64(&b, "wheel_radius_mm"),
            batch_f64(&b, "phi_rad"),
            batch_f64(&b, "delta_mm"),
        ) {
            let mut radii: Vec<f64> = rk.to_vec();
            radii.dedup();
            let data: Vec<(String, Vec<(f64, f64)>)> = radii
                .iter()
                .map(|r| {
                    let pts = (0..rk.len())
                        .filter(|&i| rk[i] == *r)
                        .map(|i| (phi[i].to_degrees(), d[i] * 1e3))
                        .collect();
                    (format!("R_k = {r:.3} mm"), thin(pts, 360))
                })
                .collect();
            html.push_str(&delta_phi_chart(
                "Model profile error δ(φ) of this run",
                &data,
            ));
        }
    }
    ReportSection {
        title: "Profile error of this run (model)".into(),
        html,
    }
}

fn measured(a: &ArtifactStore) -> Option<ReportSection> {
    let b = a.get("observations").ok()??;
    let (phi, sim, real) = (
        batch_f64(&b, "phi_rad").ok()?,
        batch_f64(&b, "sim").ok()?,
        batch_f64(&b, "real").ok()?,
    );
    let m: Vec<(f64, f64)> = thin(
        phi.iter()
            .zip(real)
            .map(|(p, r)| (p.to_degrees(), r * 1e3))
            .collect(),
        720,
    );
    let s: Vec<(f64, f64)> = thin(
        phi.iter()
            .zip(sim)
            .map(|(p, v)| (p.to_degrees(), v * 1e3))
            .collect(),
        720,
    );
    let html = xy_chart(
        "Profile error: measured vs model",
        "φ (°)",
        "error along the normal (µm)",
        &[
            Series {
                name: "measured",
                points: &m,
                mark: Mark::Points,
            },
            Series {
                name: "model δ(φ)",
                points: &s,
                mark: Mark::Line,
            },
        ],
    );
    Some(ReportSection {
        title: esc("Measured vs predicted profile error"),
        html,
    })
}

use crate::typed_summary::read;

pub fn sections(_run: &Run, a: &ArtifactStore) -> Vec<ReportSection> {
    let mut out = Vec::new();
    if let Some(s) = read::<SegmentSummary>(a, "segment") {
        out.push(segments(&s, a));
    }
    if let Some(s) = read::<ProfileErrorSummary>(a, "profile_error") {
        out.push(run_error(&s, a));
    }
    out.extend(measured(a));
    out
}

/// δ(φ) curves, one line each, in µm over φ in degrees.
fn delta_phi_chart(title: &str, curves: &[(String, Vec<(f64, f64)>)]) -> String {
    let series: Vec<Series> = curves
        .iter()
        .map(|(n, p)| Series {
            name: n,
            points: p,
            mark: Mark::Line,
        })
        .collect();
    xy_chart(title, "φ (°)", "δ (µm)", &series)
}

/// The verdict: RMS of the measured profile error along the normal against
/// the tolerance and against the model's δ(φ) at the same points. They
/// agree when their point-by-point difference is within three times the
/// reading noise, estimated from successive differences of that
/// difference (a smooth model misfit cancels there, noise does not).
pub fn verdicts(run: &Run, a: &ArtifactStore) -> Vec<Verdict> {
    let Some(b) = a.get("observations").ok().flatten() else {
        return Vec::new();
    };
    let (Ok(sim), Ok(real)) = (batch_f64(&b, "sim"), batch_f64(&b, "real")) else {
        return Vec::new();
    };
    let rms = |v: &mut dyn Iterator<Item = f64>| {
        let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
        if n == 0 {
            f64::NAN
        } else {
            (s / n as f64).sqrt() * 1e3
        }
    };
    let gap: Vec<f64> = real.iter().zip(sim).map(|(r, s)| r - s).collect();
    let noise = rms(&mut gap.windows(2).map(|w| w[1] - w[0])) / std::f64::consts::SQRT_2;
    vec![Verdict::new(
        "profile error (RMS along the normal)",
        "µm",
        "measured",
        rms(&mut real.iter().copied()),
    )
    .limit("profile_error_um", run.tolerance("profile_error_um"))
    .model(rms(&mut sim.iter().copied()), 3.0 * noise)
    .model_gap(rms(&mut gap.iter().copied()))]
}

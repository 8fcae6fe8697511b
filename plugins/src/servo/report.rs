//! Report of a servo run: per axis the effective lag against the model's
//! (1 − ff)/Kv, the following error real vs simulated (RMS and peak), the
//! commanded-vs-actual and following-error traces over the run, and for
//! every circular move a ballbar-style polar plot of the radial error
//! (reversal spikes, backlash). The verdict judges each axis' peak
//! following error against `[tolerance].following_error_um` and against
//! what the model predicts.

use sparkout_pipeline::contracts::batch_f64;
use sparkout_pipeline::report::svg::{polar_chart, xy_chart, Mark, Series};
use sparkout_pipeline::report::{fmt_fixed, table, Verdict};
use sparkout_pipeline::{ArtifactStore, ReportSection, Run};

use super::follow::FollowSummary;
use super::trace::Trace;

/// At most this many points per trace line (a night's trace has 10⁵).
const MAX_POINTS: usize = 1500;

fn thin(p: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
    let step = p.len().div_ceil(MAX_POINTS).max(1);
    p.into_iter().step_by(step).collect()
}

fn peak(v: &[f64]) -> f64 {
    v.iter()
        .filter(|x| x.is_finite())
        .fold(0.0, |m: f64, x| m.max(x.abs()))
}

fn rms(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

/// One axis' errors from the `following_error` artifact (mm).
struct AxisErr {
    axis: String,
    real: Vec<f64>,
    sim: Vec<f64>,
}

fn axis_errors(a: &ArtifactStore, s: &FollowSummary) -> Option<(Vec<f64>, Vec<AxisErr>)> {
    let b = a.get("following_error").ok()??;
    let t = batch_f64(&b, "t_s").ok()?.to_vec();
    let out = s
        .axes
        .keys()
        .filter_map(|ax| {
            Some(AxisErr {
                axis: ax.clone(),
                real: batch_f64(&b, &format!("real_e_{ax}_mm")).ok()?.to_vec(),
                sim: batch_f64(&b, &format!("sim_e_{ax}_mm")).ok()?.to_vec(),
            })
        })
        .collect();
    Some((t, out))
}

/// A drive whose effective lag is within this share of the model's
/// (1 − ff)/Kv agrees with it: the configured Kv and ff are nominal.
const LAG_AGREEMENT: f64 = 0.1;

/// The verdict, per axis: the following error the model does not predict
/// (RMS of measured − simulated) against `[tolerance].following_error_um`
/// — the following error itself grows with feed and is what the model is
/// for; and the effective lag against the model's.
pub fn verdicts(run: &Run, a: &ArtifactStore) -> Vec<Verdict> {
    let Some(s) = crate::typed_summary::read::<FollowSummary>(a, "follow") else {
        return Vec::new();
    };
    let Some((_, axes)) = axis_errors(a, &s) else {
        return Vec::new();
    };
    let limit = run.tolerance("following_error_um");
    let mut out = Vec::new();
    for e in &axes {
        let gap: Vec<f64> = e.real.iter().zip(&e.sim).map(|(r, s)| r - s).collect();
        out.push(
            Verdict::new(
                &format!(
                    "following error unexplained by the model, axis {} (RMS)",
                    e.axis
                ),
                "µm",
                "measured − model",
                rms(&gap) * 1e3,
            )
            .limit("following_error_um", limit),
        );
        let p = s.axes.get(&e.axis);
        if let (Some(eff), Some(model)) = (
            p.and_then(|p| p.effective_lag_s),
            p.map(|p| p.model_lag_s).filter(|m| m.is_finite()),
        ) {
            out.push(
                Verdict::new(
                    &format!("effective lag, axis {}", e.axis),
                    "ms",
                    "measured",
                    eff * 1e3,
                )
                .model(model * 1e3, LAG_AGREEMENT * model.abs() * 1e3),
            );
        }
    }
    out
}

fn ms(v: Option<f64>) -> String {
    fmt_fixed(v.map(|x| x * 1e3), 2)
}

fn lag_and_error(s: &FollowSummary, axes: &[AxisErr]) -> String {
    let rows: Vec<Vec<String>> = axes
        .iter()
        .map(|e| {
            let p = s.axes.get(&e.axis);
            vec![
                e.axis.clone(),
                ms(p.and_then(|p| p.effective_lag_s)),
                ms(p.map(|p| p.model_lag_s).filter(|m| m.is_finite())),
                fmt_fixed(Some(rms(&e.real) * 1e3), 2),
                fmt_fixed(Some(rms(&e.sim) * 1e3), 2),
                fmt_fixed(Some(peak(&e.real) * 1e3), 2),
                fmt_fixed(Some(peak(&e.sim) * 1e3), 2),
            ]
        })
        .collect();
    let mut html = String::from(
        "<p>Effective lag: the least-squares lag of the measured following error on the commanded velocity (e = c − lag·v), against the model's (1 − ff)/Kv. A real axis lagging more than its model has a lower gain than configured (or a load it fights).</p>",
    );
    html.push_str(&table(
        &[
            "axis",
            "effective lag (ms)",
            "model lag (ms)",
            "RMS error real (µm)",
            "RMS error simulated (µm)",
            "peak error real (µm)",
            "peak error simulated (µm)",
        ],
        &rows,
    ));
    html
}

fn traces(run: &Run, t: &[f64], axes: &[AxisErr]) -> String {
    let mut html = String::from("<div class=\"figs\">");
    if let Ok(tr) = Trace::read(run) {
        for a in &tr.axes {
            let cmd = thin(
                tr.t_s
                    .iter()
                    .copied()
                    .zip(a.cmd_mm.iter().copied())
                    .collect(),
            );
            let act = thin(
                tr.t_s
                    .iter()
                    .copied()
                    .zip(a.act_mm.iter().copied())
                    .collect(),
            );
            html.push_str(&xy_chart(
                &format!("Axis {}: commanded vs actual position", a.axis),
                "t (s)",
                "position (mm)",
                &[
                    Series {
                        name: "commanded",
                        points: &cmd,
                        mark: Mark::Line,
                    },
                    Series {
                        name: "actual",
                        points: &act,
                        mark: Mark::Line,
                    },
                ],
            ));
        }
    }
    for e in axes {
        let real = thin(
            t.iter()
                .copied()
                .zip(e.real.iter().map(|x| x * 1e3))
                .collect(),
        );
        let sim = thin(
            t.iter()
                .copied()
                .zip(e.sim.iter().map(|x| x * 1e3))
                .collect(),
        );
        html.push_str(&xy_chart(
            &format!("Axis {}: following error (actual − commanded)", e.axis),
            "t (s)",
            "following error (µm)",
            &[
                Series {
                    name: "measured",
                    points: &real,
                    mark: Mark::Line,
                },
                Series {
                    name: "model",
                    points: &sim,
                    mark: Mark::Line,
                },
            ],
        ));
    }
    html.push_str("</div>");
    html
}

/// Least-squares circle through points (Kåsa): centre and radius.
fn fit_circle(x: &[f64], y: &[f64]) -> Option<(f64, f64, f64)> {
    let n = x.len() as f64;
    if x.len() < 8 {
        return None;
    }
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let (mut suu, mut svv, mut suv, mut suuu, mut svvv, mut suvv, mut svuu) =
        (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for (xi, yi) in x.iter().zip(y) {
        let (u, v) = (xi - mx, yi - my);
        suu += u * u;
        svv += v * v;
        suv += u * v;
        suuu += u * u * u;
        svvv += v * v * v;
        suvv += u * v * v;
        svuu += v * u * u;
    }
    let det = suu * svv - suv * suv;
    if det.abs() < 1e-18 {
        return None;
    }
    let (b1, b2) = ((suuu + suvv) / 2.0, (svvv + svuu) / 2.0);
    let uc = (b1 * svv - b2 * suv) / det;
    let vc = (b2 * suu - b1 * suv) / det;
    let r = (uc * uc + vc * vc + (suu + svv) / n).sqrt();
    Some((mx + uc, my + vc, r))
}

/// The circular moves of an XY path: stretches of one segment (or, without
/// a `segment` column, of the whole trace) whose commanded points lie on
/// one circle within 1 µm + 0.1 % of its radius and cover at least a half
/// turn. Each gives (radius, [(angle, radial error µm)]).
fn circles(tr: &Trace) -> Vec<(f64, Vec<(f64, f64)>)> {
    let find = |axis: &str| tr.axes.iter().find(|a| a.axis == axis);
    let (Some(ax), Some(ay)) = (find("x"), find("y")) else {
        return Vec::new();
    };
    let n = tr.t_s.len();
    let seg: Vec<i32> = tr.segment.clone().unwrap_or_else(|| vec![0; n]);
    let mut out = Vec::new();
    let mut start = 0;
    while start < n {
        let mut end = start;
        while end < n && seg[end] == seg[start] {
            end += 1;
        }
        // Only the moving samples: the ends of a move sit still.
        let idx: Vec<usize> = (start..end)
            .filter(|&i| ax.cmd_v_mm_s[i].hypot(ay.cmd_v_mm_s[i]) > 1e-3)
            .collect();
        start = end;
        let (x, y): (Vec<f64>, Vec<f64>) =
            idx.iter().map(|&i| (ax.cmd_mm[i], ay.cmd_mm[i])).unzip();
        let Some((cx, cy, r)) = fit_circle(&x, &y) else {
            continue;
        };
        let on_circle = x
            .iter()
            .zip(&y)
            .all(|(x, y)| ((x - cx).hypot(y - cy) - r).abs() <= 1e-3 + 1e-3 * r);
        // Angle swept, unwrapped along the path.
        let mut swept = 0.0;
        for w in idx.windows(2) {
            let a0 = (ay.cmd_mm[w[0]] - cy).atan2(ax.cmd_mm[w[0]] - cx);
            let a1 = (ay.cmd_mm[w[1]] - cy).atan2(ax.cmd_mm[w[1]] - cx);
            let mut d = a1 - a0;
            while d > std::f64::consts::PI {
                d -= 2.0 * std::f64::consts::PI;
            }
            while d < -std::f64::consts::PI {
                d += 2.0 * std::f64::consts::PI;
            }
            swept += d;
        }
        if !on_circle || swept.abs() < std::f64::consts::PI {
            continue;
        }
        let pts = idx
            .iter()
            .map(|&i| {
                let (xa, ya) = (ax.act_mm[i] - cx, ay.act_mm[i] - cy);
                let (xc, yc) = (ax.cmd_mm[i] - cx, ay.cmd_mm[i] - cy);
                (yc.atan2(xc), (xa.hypot(ya) - xc.hypot(yc)) * 1e3)
            })
            .collect();
        out.push((r, thin(pts)));
    }
    out
}

fn ballbar(run: &Run) -> Option<ReportSection> {
    let tr = Trace::read(run).ok()?;
    let cs = circles(&tr);
    if cs.is_empty() {
        return None;
    }
    let mut html = String::from(
        "<p>Radial error of each circular move (actual radius − commanded radius about the commanded circle's centre), plotted around the circle like a ballbar test: a spike where an axis reverses (0°, 90°, 180°, 270°) is friction at the reversal; the two halves of the circle offset from each other is backlash; an ellipse is a gain mismatch between X and Y.</p><div class=\"figs\">",
    );
    let names: Vec<String> = cs
        .iter()
        .enumerate()
        .map(|(k, (r, _))| format!("circle {} (R = {r:.1} mm)", k + 1))
        .collect();
    for ((_, pts), name) in cs.iter().zip(&names) {
        html.push_str(&polar_chart(
            &format!("Radial error, {name}"),
            "µm",
            &[(name.as_str(), pts.as_slice())],
        ));
    }
    html.push_str("</div>");
    Some(ReportSection {
        title: "Circular moves (ballbar view)".into(),
        html,
    })
}

pub fn sections(run: &Run, a: &ArtifactStore) -> Vec<ReportSection> {
    let mut out = Vec::new();
    if let Some(s) = crate::typed_summary::read::<FollowSummary>(a, "follow") {
        if let Some((t, axes)) = axis_errors(a, &s) {
            out.push(ReportSection {
                title: "Lag and following error per axis".into(),
                html: lag_and_error(&s, &axes),
            });
            out.push(ReportSection {
                title: "Traces over the run".into(),
                html: traces(run, &t, &axes),
            });
        }
    }
    out.extend(ballbar(run));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn circle_fit_recovers_centre_and_radius() {
        let (x, y): (Vec<f64>, Vec<f64>) = (0..40)
            .map(|k| {
                let a = k as f64 * 0.1;
                (3.0 + 25.0 * a.cos(), -2.0 + 25.0 * a.sin())
            })
            .unzip();
        let (cx, cy, r) = fit_circle(&x, &y).unwrap();
        assert!((cx - 3.0).abs() < 1e-9 && (cy + 2.0).abs() < 1e-9 && (r - 25.0).abs() < 1e-9);
    }
}

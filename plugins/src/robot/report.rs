//! Report sections of a robot run: repeatability by
//! method × speed, the fitted planes' residuals, the datum with its
//! uncertainty, predicted vs measured cuts per pass, and how far recorded
//! and AE-derived touches disagree.

use sparkout_pipeline::report::svg::{bar_chart, xy_chart, Mark, Series};
use sparkout_pipeline::report::{esc, fmt_fixed, fmt_um, table, warning, Verdict};

/// Condition number of the datum's 3×3 plane-normal system above which
/// the report warns (orthogonal faces give 1).
const DATUM_CONDITION_WARN: f64 = 100.0;
use sparkout_pipeline::units::format::{show_as_written, show_group_in, Dims, ParamUnit};
use sparkout_pipeline::{ArtifactStore, ReportSection, Run};

use super::planes::Face;
use super::summary::{
    fin, json_number, CompareSummary, CycleSummary, DatumSummary, IngestSummary, Remaining,
    RepeatabilitySummary,
};
use super::touches;

fn um(v: Option<f64>) -> String {
    fmt_um(v, 1)
}

/// An AE voltage in mV with three significant digits (`6.46 mV`: the
/// threshold and noise are millivolts).
fn volts(v: f64) -> String {
    fin(v).map_or_else(|| "—".into(), |x| show_as_written(x * 1e3, "mV"))
}

fn num(v: Option<f64>, digits: usize) -> String {
    fmt_fixed(v, digits)
}

/// A time in ms with three decimals, "—" when undefined.
fn millis(v: f64) -> String {
    fin(v)
        .map(|x| format!("{:.3}", x * 1e3))
        .unwrap_or_else(|| "—".into())
}

fn repeatability(s: &RepeatabilitySummary) -> Option<ReportSection> {
    let mut rows = Vec::new();
    let mut bars = Vec::new();
    for g in &s.groups {
        let label = format!("{} @ {} mm/s", g.method, num(Some(g.approach_mm_s), 3));
        for f in Face::ALL {
            let Some(x) = g.faces.get(f.label()) else {
                continue;
            };
            rows.push(vec![
                g.method.clone(),
                num(Some(g.approach_mm_s), 3),
                f.label().to_string(),
                x.n.to_string(),
                um(x.range_mm),
                um(x.std_mm),
                um(Some(x.bias_mm)),
                um(x.bias_latency_corrected_mm),
            ]);
        }
        if let Some(v) = g.mean_range_mm {
            bars.push((label, v * 1e3));
        }
    }
    let mut html = table(
        &[
            "method",
            "approach (mm/s)",
            "face",
            "n",
            "range (µm)",
            "std (µm)",
            "bias (µm)",
            "bias, latency-corrected (µm)",
        ],
        &rows,
    );
    html.push_str(&bar_chart(
        "Mean range over faces (the thesis's accuracy error)",
        "µm",
        &bars,
    ));
    let lat = match s.latency_s {
        Some(l) => format!(
            "<p>Trigger latency from the bias at ≥ 2 approach speeds: <b>{:.3} ms</b> (bias ≈ v·L along the approach direction).</p>",
            l * 1e3
        ),
        None => "<p class=\"note\">Trigger latency: not estimable (fewer than two approach speeds per point).</p>".into(),
    };
    html.push_str(&lat);
    Some(ReportSection {
        title: "Repeatability by method and approach speed".into(),
        html,
    })
}

fn planes(s: &DatumSummary, run_artifacts: &ArtifactStore) -> Option<ReportSection> {
    let p = &s.planes;
    let mut rows = Vec::new();
    for f in Face::ALL {
        let Some(x) = p.get(f.label()) else {
            continue;
        };
        // The plane's offset b0 at micrometre resolution (a datum plane's
        // position), its slopes b1, b2 as lengths per length (µm/m).
        let slope = ParamUnit {
            num: Dims::length(),
            den: Dims::length(),
        };
        let b: Vec<f64> = x.ols.iter().map(|v| v.unwrap_or(f64::NAN)).collect();
        let mut ols: Vec<String> = b
            .first()
            .map(|b0| format!("{} mm", fmt_fixed(Some(*b0), 3)))
            .into_iter()
            .collect();
        // Both slopes in one unit.
        ols.extend(show_group_in(b.get(1..).unwrap_or_default(), &slope));
        rows.push(vec![
            f.label().to_string(),
            x.n.to_string(),
            x.n_rejected.to_string(),
            ols.join(", "),
            um(x.ols_residual_rms_mm),
            um(x.tls_residual_rms_mm),
            um(x.residual_max_mm),
        ]);
    }
    let mut html = table(
        &[
            "face",
            "touches",
            "rejected",
            "OLS plane: b0, slopes b1, b2",
            "OLS RMS (µm)",
            "TLS RMS (µm)",
            "max |res| (µm)",
        ],
        &rows,
    );
    // Residual of each touch from its face's TLS plane, in touch order.
    if let Ok(Some(t)) = run_artifacts.get("touches") {
        if let Ok(t) = touches::from_batch(&t) {
            let mut series: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
            for f in Face::ALL {
                let x = p.get(f.label());
                let (Some(n), Some(d)) = (
                    x.map(|x| {
                        let a = x.tls_normal.map(|v| v.unwrap_or(0.0));
                        nalgebra::Vector3::new(a[0], a[1], a[2])
                    }),
                    x.and_then(|x| fin(x.tls_d)),
                ) else {
                    continue;
                };
                let pts: Vec<(f64, f64)> = t
                    .iter()
                    .filter(|q| q.face == f)
                    .enumerate()
                    .map(|(i, q)| (i as f64, (n.dot(&q.p) - d) * 1e3))
                    .collect();
                series.push((f.label().to_string(), pts));
            }
            let s: Vec<Series> = series
                .iter()
                .map(|(name, pts)| Series {
                    name,
                    points: pts,
                    mark: Mark::Points,
                })
                .collect();
            html.push_str(&xy_chart(
                "Orthogonal residuals from each face's TLS plane",
                "touch (in time order within its face)",
                "residual (µm)",
                &s,
            ));
        }
    }
    Some(ReportSection {
        title: "Fitted face planes".into(),
        html,
    })
}

fn datum(s: &DatumSummary) -> Option<ReportSection> {
    let p = s.datum_mm?;
    let sig = &s.datum_sigma_mm;
    let ell = &s.datum_ellipsoid_mm.semi_axes_mm;
    let conf = fin(s.datum_ellipsoid_mm.confidence).unwrap_or(0.95);
    let rows: Vec<Vec<String>> = ["x", "y", "z"]
        .iter()
        .enumerate()
        .map(|(i, a)| vec![a.to_string(), num(Some(p[i]), 4), um(sig[i]), um(ell[i])])
        .collect();
    let mut html = format!(
        "<p>Datum = intersection of the three face planes ({} fit); condition number {}.</p>",
        esc(&s.fit),
        num(Some(s.condition), 3)
    );
    // A datum from nearly parallel planes moves a lot with little noise.
    if let Some(c) = fin(s.condition).filter(|c| *c > DATUM_CONDITION_WARN) {
        html.push_str(&warning(&format!(
            "the datum is badly conditioned (condition number {c:.0} > {DATUM_CONDITION_WARN:.0}): the three faces are close to parallel, so probing noise moves the datum far more than its σ suggests. Probe faces that are closer to orthogonal."
        )));
    }
    html.push_str(&table(
        &[
            "axis",
            "datum (mm)",
            "1σ (µm)",
            &format!("{:.0} % ellipsoid semi-axis (µm)", conf * 100.0),
        ],
        &rows,
    ));
    html.push_str(&table(
        &["faces", "deviation from 90° (µrad)"],
        &s.squareness_rad
            .pairs()
            .iter()
            .map(|(k, v)| {
                vec![
                    k.replace('_', "–"),
                    v.map(|x| format!("{:.1}", x * 1e6))
                        .unwrap_or_else(|| "—".into()),
                ]
            })
            .collect::<Vec<_>>(),
    ));
    if !s.by_square.is_empty() {
        let rows: Vec<Vec<String>> = s
            .by_square
            .iter()
            .map(|q| {
                let d = |i: usize| num(q.datum_mm.map(|d| d[i]), 4);
                vec![q.square.clone(), d(0), d(1), d(2)]
            })
            .collect();
        html.push_str("<p>Datum per square of the thesis's pattern:</p>");
        html.push_str(&table(&["square", "x (mm)", "y (mm)", "z (mm)"], &rows));
    }
    if let Some(e) = s.error_vector_mm {
        html.push_str(&format!(
            "<p class=\"note\">Thesis error vector E = A·α: ({}, {}, {}) µm.</p>",
            um(Some(e[0])),
            um(Some(e[1])),
            um(Some(e[2]))
        ));
    }
    Some(ReportSection {
        title: "Datum and its uncertainty".into(),
        html,
    })
}

fn cycle(s: &CycleSummary) -> Option<ReportSection> {
    let s = match s {
        CycleSummary::Passes(s) if !s.passes.is_empty() => s,
        other => {
            let note = match other {
                CycleSummary::NoPasses(n) => n.note.as_str(),
                CycleSummary::Passes(_) => "no passes",
            };
            return Some(ReportSection {
                title: "Grinding cycle".into(),
                html: format!("<p class=\"note\">{}</p>", esc(note)),
            });
        }
    };
    let passes = &s.passes;
    let pt = |cut: &dyn Fn(&super::summary::CyclePass) -> Option<f64>| -> Vec<(f64, f64)> {
        passes
            .iter()
            .filter_map(|p| Some((p.pass as f64, cut(p)? * 1e3)))
            .collect()
    };
    let (pred, meas, fit) = (
        pt(&|p| fin(p.predicted_cut_mm)),
        pt(&|p| p.measured_cut_mm),
        pt(&|p| p.predicted_cut_fit_mm),
    );
    let mut series = vec![
        Series {
            name: "predicted (α from pass 1)",
            points: &pred,
            mark: Mark::Line,
        },
        Series {
            name: "measured",
            points: &meas,
            mark: Mark::Points,
        },
    ];
    if !fit.is_empty() {
        series.push(Series {
            name: "predicted (α refit)",
            points: &fit,
            mark: Mark::Line,
        });
    }
    let mut html = format!(
        "<p>α from the first pass {} (ratio α/(1+α) {}); α refit over all passes {}.</p>",
        num(Some(s.alpha_first_pass), 4),
        num(Some(s.ratio_first_pass), 4),
        num(s.alpha_fit, 4)
    );
    html.push_str(&xy_chart("Real cut per pass", "pass", "cut (µm)", &series));
    let rows: Vec<Vec<String>> = passes
        .iter()
        .map(|p| {
            vec![
                p.pass.to_string(),
                p.stage.clone(),
                um(Some(p.nominal_doc_mm)),
                um(Some(p.predicted_cut_mm)),
                um(p.measured_cut_mm),
                um(p.predicted_cut_fit_mm),
            ]
        })
        .collect();
    html.push_str(&table(
        &[
            "pass",
            "stage",
            "δ′ (µm)",
            "predicted (µm)",
            "measured (µm)",
            "refit (µm)",
        ],
        &rows,
    ));
    let (r, rm) = (&s.remaining_after_mm, &s.remaining_after_measured_mm);
    html.push_str(&table(
        &[
            "after",
            "remaining predicted (µm)",
            "remaining measured (µm)",
        ],
        &r.stages()
            .iter()
            .zip(rm.stages())
            .map(|((k, r), (_, rm))| vec![k.to_string(), um(*r), um(rm)])
            .collect::<Vec<_>>(),
    ));
    if !s.tau_s.is_empty() {
        let rows: Vec<Vec<String>> = s
            .tau_s
            .iter()
            .map(|(k, v)| vec![k.clone(), num(*v, 3)])
            .collect();
        html.push_str(&table(&["feed (mm/s)", "spark-out τ (s)"], &rows));
    }
    Some(ReportSection {
        title: "Grinding cycle: predicted vs measured cuts".into(),
        html,
    })
}

fn compare(c: &CompareSummary) -> ReportSection {
    let mut html = format!(
        "<p>{} touches both registered by the controller and detected from AE: RMS distance {} µm (max {} µm); mean normal difference {} µm; the controller registers on average {} ms after the AE contact.</p>",
        c.n,
        um(Some(c.rms_dist_mm)),
        um(Some(c.max_dist_mm)),
        um(Some(c.mean_dnormal_mm)),
        millis(c.mean_dt_s)
    );
    let rows: Vec<Vec<String>> = c
        .by_speed
        .iter()
        .map(|g| {
            vec![
                g.method.clone(),
                num(Some(g.approach_mm_s), 3),
                g.n.to_string(),
                um(Some(g.mean_dnormal_mm)),
                millis(g.mean_dt_s),
            ]
        })
        .collect();
    html.push_str(&table(
        &[
            "method",
            "approach (mm/s)",
            "n",
            "mean Δnormal (µm)",
            "mean Δt (ms)",
        ],
        &rows,
    ));
    ReportSection {
        title: "Recorded vs AE-derived touches".into(),
        html,
    }
}

/// How the AE contacts were found: the signal kind and the parameters in
/// force (derived or set), what they found, and any fragmentation warning.
fn ae_detection(s: &IngestSummary) -> Option<ReportSection> {
    let ae = s.ae.as_ref()?;
    let p = &ae.params;
    let ms = |x: f64| {
        fin(x)
            .map(|x| format!("{:.3} ms", x * 1e3))
            .unwrap_or_else(|| "—".into())
    };
    let mut html = format!(
        "<p>{} AE signal ({}) at {} Hz: {} contacts, {} of them touches of the plan, {} extra, {} outside any approach; {} planned touches without one.</p>",
        esc(&p.signal),
        esc(&p.signal_from),
        json_number(p.sample_rate_hz),
        ae.events,
        ae.touches,
        ae.extra_events,
        ae.unassigned_events,
        ae.n_missed,
    );
    let rows: Vec<Vec<String>> = [
        ("envelope window", p.window_samples, ms(p.window_s)),
        ("minimum dwell", p.min_dwell_samples, ms(p.min_dwell_s)),
        ("merge gap", p.merge_gap_samples, ms(p.merge_gap_s)),
        ("noise window", p.noise_window_samples, ms(p.noise_window_s)),
    ]
    .into_iter()
    .map(|(name, n, secs)| vec![name.to_string(), n.to_string(), secs])
    .collect();
    html.push_str(&table(&["parameter", "samples", "time"], &rows));
    html.push_str(&format!(
        "<p>Threshold {} = noise median {} + {}·σ (σ = 1.4826·MAD {}); {} threshold crossings shorter than the dwell were dropped.</p>",
        volts(ae.threshold_v),
        volts(ae.noise_floor_v),
        json_number(p.k_sigma),
        volts(ae.noise_sigma_v),
        ae.short_crossings,
    ));
    for w in &ae.warnings {
        html.push_str(&warning(w));
    }
    Some(ReportSection {
        title: "AE contact detection".into(),
        html,
    })
}

use crate::typed_summary::read;

pub fn sections(_run: &Run, a: &ArtifactStore) -> Vec<ReportSection> {
    let mut out = Vec::new();
    if let Some(s) = read::<RepeatabilitySummary>(a, "repeatability") {
        out.extend(repeatability(&s));
    }
    if let Some(s) = read::<DatumSummary>(a, "datum") {
        out.extend(planes(&s, a));
        out.extend(datum(&s));
    }
    if let Some(s) = read::<CycleSummary>(a, "cycle") {
        out.extend(cycle(&s));
    }
    if let Some(s) = read::<IngestSummary>(a, "ingest") {
        out.extend(ae_detection(&s));
        out.extend(s.compare.as_ref().map(compare));
    }
    out
}

/// The verdict: stock left on the part after spark-out (measured) against
/// the stock left after finishing (before), the tolerance, and the cycle
/// model's prediction. Two probings of the part differ by √2 × the probe's
/// standard deviation — of its most repeatable group (method and speed):
/// slow or latency-biased groups measure the probing method, not the
/// part; the model agrees with the measurement within three of those.
pub fn verdicts(run: &Run, a: &ArtifactStore) -> Vec<Verdict> {
    let Some(s) = read::<CycleSummary>(a, "cycle") else {
        return Vec::new();
    };
    let um_of = |v: Option<f64>| v.map(|x| x * 1e3).unwrap_or(f64::NAN);
    let none = Remaining::default();
    let (pred, meas) = match &s {
        CycleSummary::Passes(c) => (&c.remaining_after_mm, &c.remaining_after_measured_mm),
        CycleSummary::NoPasses(n) => (&n.remaining_after_mm, &none),
    };
    if meas.spark.is_none() && pred.spark.is_none() {
        return Vec::new();
    }
    let probe_std_um = read::<RepeatabilitySummary>(a, "repeatability")
        .map(|r| {
            r.groups
                .iter()
                .flat_map(|g| Face::ALL.map(|f| g.faces.get(f.label()).and_then(|x| x.std_mm)))
                .flatten()
                .fold(f64::NAN, f64::min)
        })
        .filter(|v| v.is_finite())
        .map(|v| v * 1e3);
    let mut v = Verdict::new(
        "stock left after spark-out",
        "µm",
        "after spark-out",
        um_of(meas.spark),
    )
    .before("after finishing", um_of(meas.finish))
    .limit("stock_um", run.tolerance("stock_um"));
    if let Some(sd) = probe_std_um {
        v = v.model(um_of(pred.spark), 3.0 * std::f64::consts::SQRT_2 * sd);
    }
    vec![v]
}

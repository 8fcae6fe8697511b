//! Report sections of a robot run: repeatability by
//! method × speed, the fitted planes' residuals, the datum with its
//! uncertainty, predicted vs measured cuts per pass, and how far recorded
//! and AE-derived touches disagree.

use serde_json::Value;
use sparkout_pipeline::report::svg::{bar_chart, xy_chart, Mark, Series};
use sparkout_pipeline::report::{esc, fmt_fixed, fmt_um, table, warning, Verdict};

/// Condition number of the datum's 3×3 plane-normal system above which
/// the report warns (orthogonal faces give 1).
const DATUM_CONDITION_WARN: f64 = 100.0;
use sparkout_pipeline::units::format::{show_as_written, show_group_in, Dims, ParamUnit};
use sparkout_pipeline::{ArtifactStore, ReportSection, Run};

use super::planes::Face;
use super::touches;

fn um(v: &Value) -> String {
    fmt_um(v.as_f64(), 1)
}

/// An AE voltage in mV with three significant digits (`6.46 mV`: the
/// threshold and noise are millivolts).
fn volts(v: &Value) -> String {
    v.as_f64()
        .map_or_else(|| "—".into(), |x| show_as_written(x * 1e3, "mV"))
}

fn num(v: &Value, digits: usize) -> String {
    fmt_fixed(v.as_f64(), digits)
}

fn repeatability(s: &Value) -> Option<ReportSection> {
    let groups = s.get("groups")?.as_array()?;
    let mut rows = Vec::new();
    let mut bars = Vec::new();
    for g in groups {
        let label = format!(
            "{} @ {} mm/s",
            g["method"].as_str().unwrap_or("?"),
            num(&g["approach_mm_s"], 3)
        );
        for f in Face::ALL {
            let x = &g["faces"][f.label()];
            if x.is_null() {
                continue;
            }
            rows.push(vec![
                g["method"].as_str().unwrap_or("?").to_string(),
                num(&g["approach_mm_s"], 3),
                f.label().to_string(),
                x["n"].to_string(),
                um(&x["range_mm"]),
                um(&x["std_mm"]),
                um(&x["bias_mm"]),
                um(&x["bias_latency_corrected_mm"]),
            ]);
        }
        if let Some(v) = g["mean_range_mm"].as_f64() {
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
    let lat = match s["latency_s"].as_f64() {
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

fn planes(s: &Value, run_artifacts: &ArtifactStore) -> Option<ReportSection> {
    let p = s.get("planes")?;
    let mut rows = Vec::new();
    for f in Face::ALL {
        let x = &p[f.label()];
        if x.is_null() {
            continue;
        }
        // The plane's offset b0 at micrometre resolution (a datum plane's
        // position), its slopes b1, b2 as lengths per length (µm/m).
        let slope = ParamUnit {
            num: Dims::length(),
            den: Dims::length(),
        };
        let b: Vec<f64> = x["ols"]
            .as_array()
            .map(|a| a.iter().map(|v| v.as_f64().unwrap_or(f64::NAN)).collect())
            .unwrap_or_default();
        let mut ols: Vec<String> = b
            .first()
            .map(|b0| format!("{} mm", fmt_fixed(Some(*b0), 3)))
            .into_iter()
            .collect();
        // Both slopes in one unit.
        ols.extend(show_group_in(b.get(1..).unwrap_or_default(), &slope));
        rows.push(vec![
            f.label().to_string(),
            x["n"].to_string(),
            x["n_rejected"].to_string(),
            ols.join(", "),
            um(&x["ols_residual_rms_mm"]),
            um(&x["tls_residual_rms_mm"]),
            um(&x["residual_max_mm"]),
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
    if let (Ok(Some(t)), Some(pl)) = (run_artifacts.get("touches"), p.as_object()) {
        if let Ok(t) = touches::from_batch(&t) {
            let mut series: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
            for f in Face::ALL {
                let x = &pl.get(f.label());
                let (Some(n), Some(d)) = (
                    x.and_then(|x| x["tls_normal"].as_array()).map(|a| {
                        nalgebra::Vector3::new(
                            a[0].as_f64().unwrap_or(0.0),
                            a[1].as_f64().unwrap_or(0.0),
                            a[2].as_f64().unwrap_or(0.0),
                        )
                    }),
                    x.and_then(|x| x["tls_d"].as_f64()),
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

fn datum(s: &Value) -> Option<ReportSection> {
    let p = s.get("datum_mm")?.as_array()?;
    let sig = &s["datum_sigma_mm"];
    let ell = &s["datum_ellipsoid_mm"]["semi_axes_mm"];
    let conf = s["datum_ellipsoid_mm"]["confidence"]
        .as_f64()
        .unwrap_or(0.95);
    let rows: Vec<Vec<String>> = ["x", "y", "z"]
        .iter()
        .enumerate()
        .map(|(i, a)| vec![a.to_string(), num(&p[i], 4), um(&sig[i]), um(&ell[i])])
        .collect();
    let mut html = format!(
        "<p>Datum = intersection of the three face planes ({} fit); condition number {}.</p>",
        esc(s["fit"].as_str().unwrap_or("tls")),
        num(&s["condition"], 3)
    );
    // A datum from nearly parallel planes moves a lot with little noise.
    if let Some(c) = s["condition"]
        .as_f64()
        .filter(|c| *c > DATUM_CONDITION_WARN)
    {
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
    let sq = &s["squareness_rad"];
    html.push_str(&table(
        &["faces", "deviation from 90° (µrad)"],
        &["xy_yz", "yz_zx", "zx_xy"]
            .iter()
            .map(|k| {
                vec![
                    k.replace('_', "–"),
                    sq[*k]
                        .as_f64()
                        .map(|x| format!("{:.1}", x * 1e6))
                        .unwrap_or_else(|| "—".into()),
                ]
            })
            .collect::<Vec<_>>(),
    ));
    if let Some(sq) = s["by_square"].as_array().filter(|a| !a.is_empty()) {
        let rows: Vec<Vec<String>> = sq
            .iter()
            .map(|q| {
                let d = &q["datum_mm"];
                vec![
                    q["square"].as_str().unwrap_or("?").to_string(),
                    num(&d[0], 4),
                    num(&d[1], 4),
                    num(&d[2], 4),
                ]
            })
            .collect();
        html.push_str("<p>Datum per square of the thesis's pattern:</p>");
        html.push_str(&table(&["square", "x (mm)", "y (mm)", "z (mm)"], &rows));
    }
    if let Some(e) = s["error_vector_mm"].as_array() {
        html.push_str(&format!(
            "<p class=\"note\">Thesis error vector E = A·α: ({}, {}, {}) µm.</p>",
            um(&e[0]),
            um(&e[1]),
            um(&e[2])
        ));
    }
    Some(ReportSection {
        title: "Datum and its uncertainty".into(),
        html,
    })
}

fn cycle(s: &Value) -> Option<ReportSection> {
    let passes = s.get("passes")?.as_array()?;
    if passes.is_empty() {
        return Some(ReportSection {
            title: "Grinding cycle".into(),
            html: format!(
                "<p class=\"note\">{}</p>",
                esc(s["note"].as_str().unwrap_or("no passes"))
            ),
        });
    }
    let pt = |k: &str| -> Vec<(f64, f64)> {
        passes
            .iter()
            .filter_map(|p| Some((p["pass"].as_f64()?, p[k].as_f64()? * 1e3)))
            .collect()
    };
    let (pred, meas, fit) = (
        pt("predicted_cut_mm"),
        pt("measured_cut_mm"),
        pt("predicted_cut_fit_mm"),
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
        num(&s["alpha_first_pass"], 4),
        num(&s["ratio_first_pass"], 4),
        num(&s["alpha_fit"], 4)
    );
    html.push_str(&xy_chart("Real cut per pass", "pass", "cut (µm)", &series));
    let rows: Vec<Vec<String>> = passes
        .iter()
        .map(|p| {
            vec![
                p["pass"].to_string(),
                p["stage"].as_str().unwrap_or("?").to_string(),
                um(&p["nominal_doc_mm"]),
                um(&p["predicted_cut_mm"]),
                um(&p["measured_cut_mm"]),
                um(&p["predicted_cut_fit_mm"]),
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
    let r = &s["remaining_after_mm"];
    let rm = &s["remaining_after_measured_mm"];
    html.push_str(&table(
        &[
            "after",
            "remaining predicted (µm)",
            "remaining measured (µm)",
        ],
        &["rough", "finish", "spark"]
            .iter()
            .map(|k| vec![k.to_string(), um(&r[*k]), um(&rm[*k])])
            .collect::<Vec<_>>(),
    ));
    if let Some(t) = s["tau_s"].as_object().filter(|t| !t.is_empty()) {
        let rows: Vec<Vec<String>> = t.iter().map(|(k, v)| vec![k.clone(), num(v, 3)]).collect();
        html.push_str(&table(&["feed (mm/s)", "spark-out τ (s)"], &rows));
    }
    Some(ReportSection {
        title: "Grinding cycle: predicted vs measured cuts".into(),
        html,
    })
}

fn compare(s: &Value) -> Option<ReportSection> {
    let c = s.get("compare").filter(|c| !c.is_null())?;
    let mut html = format!(
        "<p>{} touches both registered by the controller and detected from AE: RMS distance {} µm (max {} µm); mean normal difference {} µm; the controller registers on average {} ms after the AE contact.</p>",
        c["n"],
        um(&c["rms_dist_mm"]),
        um(&c["max_dist_mm"]),
        um(&c["mean_dnormal_mm"]),
        c["mean_dt_s"].as_f64().map(|x| format!("{:.3}", x * 1e3)).unwrap_or_else(|| "—".into())
    );
    if let Some(b) = c["by_speed"].as_array() {
        let rows: Vec<Vec<String>> = b
            .iter()
            .map(|g| {
                vec![
                    g["method"].as_str().unwrap_or("?").to_string(),
                    num(&g["approach_mm_s"], 3),
                    g["n"].to_string(),
                    um(&g["mean_dnormal_mm"]),
                    g["mean_dt_s"]
                        .as_f64()
                        .map(|x| format!("{:.3}", x * 1e3))
                        .unwrap_or_else(|| "—".into()),
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
    }
    Some(ReportSection {
        title: "Recorded vs AE-derived touches".into(),
        html,
    })
}

/// How the AE contacts were found: the signal kind and the parameters in
/// force (derived or set), what they found, and any fragmentation warning.
fn ae_detection(s: &Value) -> Option<ReportSection> {
    let ae = s.get("ae").filter(|a| !a.is_null())?;
    let p = &ae["params"];
    let ms = |k: &str| {
        p[k].as_f64()
            .map(|x| format!("{:.3} ms", x * 1e3))
            .unwrap_or_else(|| "—".into())
    };
    let mut html = format!(
        "<p>{} AE signal ({}) at {} Hz: {} contacts, {} of them touches of the plan, {} extra, {} outside any approach; {} planned touches without one.</p>",
        esc(p["signal"].as_str().unwrap_or("?")),
        esc(p["signal_from"].as_str().unwrap_or("?")),
        p["sample_rate_hz"],
        ae["events"],
        ae["touches"],
        ae["extra_events"],
        ae["unassigned_events"],
        ae["n_missed"],
    );
    let rows: Vec<Vec<String>> = [
        ("envelope window", "window_samples", ms("window_s")),
        ("minimum dwell", "min_dwell_samples", ms("min_dwell_s")),
        ("merge gap", "merge_gap_samples", ms("merge_gap_s")),
        ("noise window", "noise_window_samples", ms("noise_window_s")),
    ]
    .into_iter()
    .map(|(name, k, secs)| vec![name.to_string(), p[k].to_string(), secs])
    .collect();
    html.push_str(&table(&["parameter", "samples", "time"], &rows));
    html.push_str(&format!(
        "<p>Threshold {} = noise median {} + {}·σ (σ = 1.4826·MAD {}); {} threshold crossings shorter than the dwell were dropped.</p>",
        volts(&ae["threshold_v"]),
        volts(&ae["noise_floor_v"]),
        p["k_sigma"],
        volts(&ae["noise_sigma_v"]),
        ae["short_crossings"],
    ));
    for w in ae["warnings"].as_array().into_iter().flatten() {
        if let Some(w) = w.as_str() {
            html.push_str(&warning(w));
        }
    }
    Some(ReportSection {
        title: "AE contact detection".into(),
        html,
    })
}

pub fn sections(_run: &Run, a: &ArtifactStore) -> Vec<ReportSection> {
    let mut out = Vec::new();
    if let Some(s) = a.summary("repeatability") {
        out.extend(repeatability(&s));
    }
    if let Some(s) = a.summary("datum") {
        out.extend(planes(&s, a));
        out.extend(datum(&s));
    }
    if let Some(s) = a.summary("cycle") {
        out.extend(cycle(&s));
    }
    if let Some(s) = a.summary("ingest") {
        out.extend(ae_detection(&s));
        out.extend(compare(&s));
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
    let Some(s) = a.summary("cycle") else {
        return Vec::new();
    };
    let um_of = |v: &Value| v.as_f64().map(|x| x * 1e3).unwrap_or(f64::NAN);
    let (pred, meas) = (&s["remaining_after_mm"], &s["remaining_after_measured_mm"]);
    if meas["spark"].is_null() && pred["spark"].is_null() {
        return Vec::new();
    }
    let probe_std_um = a
        .summary("repeatability")
        .and_then(|r| {
            r["groups"].as_array().map(|g| {
                g.iter()
                    .flat_map(|g| Face::ALL.map(|f| g["faces"][f.label()]["std_mm"].as_f64()))
                    .flatten()
                    .fold(f64::NAN, f64::min)
            })
        })
        .filter(|v| v.is_finite())
        .map(|v| v * 1e3);
    let mut v = Verdict::new(
        "stock left after spark-out",
        "µm",
        "after spark-out",
        um_of(&meas["spark"]),
    )
    .before("after finishing", um_of(&meas["finish"]))
    .limit("stock_um", run.tolerance("stock_um"));
    if let Some(sd) = probe_std_um {
        v = v.model(um_of(&pred["spark"]), 3.0 * std::f64::consts::SQRT_2 * sd);
    }
    vec![v]
}

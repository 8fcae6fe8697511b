//! Report sections of a guide-way run: h, δz and β with
//! their uncertainty bands, FPE against the AR order, one-step prediction
//! and Kalman estimate against the measurement, the compensation curve.

use arrow::array::{Array, Float64Array};
use arrow::record_batch::RecordBatch;
use sparkout_pipeline::contracts::{batch_f64, batch_i32};
use sparkout_pipeline::report::svg::{bar_chart, xy_chart, Mark, Series};
use sparkout_pipeline::report::{esc, fmt_um, table, warn_fit_above_floor, Verdict};

/// A fit whose residual RMS exceeds this many reading-noise σ is flagged.
const FIT_FLOOR_FACTOR: f64 = 5.0;
use sparkout_pipeline::{ArtifactStore, ReportSection, Run};

use super::compensation::CompensationSummary;
use super::predictor::PredictorSummary;
use super::separate::SeparateSummary;
use crate::typed_summary::{finite, read};

/// At most this many points per drawn series (inline SVG stays small).
const MAX_POINTS: usize = 1500;

fn stride(n: usize) -> usize {
    n.div_ceil(MAX_POINTS).max(1)
}

fn um(v: Option<f64>) -> String {
    fmt_um(v.and_then(finite), 3)
}

use crate::typed_summary::json_number;

fn col(b: &RecordBatch, name: &str) -> Option<Vec<f64>> {
    batch_f64(b, name).ok().map(|v| v.to_vec())
}

/// A nullable float column: nulls as NaN (not drawn).
fn opt_col(b: &RecordBatch, name: &str) -> Option<Vec<f64>> {
    let a = b
        .column_by_name(name)?
        .as_any()
        .downcast_ref::<Float64Array>()?;
    Some(
        (0..a.len())
            .map(|i| if a.is_null(i) { f64::NAN } else { a.value(i) })
            .collect(),
    )
}

fn n_col(b: &RecordBatch) -> Vec<f64> {
    b.column_by_name("n")
        .and_then(|c| c.as_any().downcast_ref::<arrow::array::Int64Array>())
        .map(|a| a.values().iter().map(|v| *v as f64).collect())
        .unwrap_or_default()
}

/// (x, y·scale) points, every `stride`-th.
fn pts(x: &[f64], y: &[f64], scale: f64) -> Vec<(f64, f64)> {
    let s = stride(x.len());
    x.iter()
        .zip(y)
        .step_by(s)
        .map(|(a, b)| (*a, b * scale))
        .collect()
}

/// Value ± 2σ as three series.
fn band(x: &[f64], y: &[f64], sig: Option<&Vec<f64>>, scale: f64) -> Vec<Vec<(f64, f64)>> {
    let mut out = vec![pts(x, y, scale)];
    if let Some(s) = sig {
        let hi: Vec<f64> = y.iter().zip(s).map(|(a, b)| a + 2.0 * b).collect();
        let lo: Vec<f64> = y.iter().zip(s).map(|(a, b)| a - 2.0 * b).collect();
        out.push(pts(x, &hi, scale));
        out.push(pts(x, &lo, scale));
    }
    out
}

fn chart(title: &str, xl: &str, yl: &str, names: &[&str], data: &[Vec<(f64, f64)>]) -> String {
    let series: Vec<Series> = data
        .iter()
        .zip(names)
        .map(|(p, n)| Series {
            name: n,
            points: p,
            mark: Mark::Line,
        })
        .collect();
    xy_chart(title, xl, yl, &series)
}

fn separation(s: &SeparateSummary, b: &RecordBatch) -> Option<ReportSection> {
    let x = col(b, "x_mm")?;
    let n = n_col(b);
    let j: Vec<i32> = batch_i32(b, "j").ok()?.to_vec();
    let (h, dz, beta) = (col(b, "h_mm")?, col(b, "dz_mm")?, col(b, "beta_rad")?);
    let (hs, ds, bs) = (
        col(b, "h_sigma_mm"),
        col(b, "dz_sigma_mm"),
        col(b, "beta_sigma_rad"),
    );
    // h per workpiece point (first sample that saw it), along the workpiece.
    let step = finite(s.sample_step_mm).unwrap_or(1.0);
    let mut seen = std::collections::BTreeMap::new();
    for (i, jj) in j.iter().enumerate() {
        seen.entry(*jj).or_insert(i);
    }
    let u: Vec<f64> = seen.keys().map(|jj| *jj as f64 * step).collect();
    let hp: Vec<f64> = seen.values().map(|&i| h[i]).collect();
    let hsp: Option<Vec<f64>> = hs.as_ref().map(|v| seen.values().map(|&i| v[i]).collect());
    let names = ["estimate", "+2σ", "−2σ"];
    let mut html = format!(
        "<p>Method <b>{}</b> (reference: {}), {} samples over {} passes, {} workpiece points, probe spacing {} mm = {} × ΔL{}. Reading noise σ = {} µm ({}). h RMS about its line {} µm, δz RMS {} µm.</p>",
        esc(&s.method),
        esc(&s.reference),
        s.n,
        s.passes,
        s.positions,
        json_number(s.probe_spacing_mm),
        s.k,
        if s.resampled { " (resampled)" } else { "" },
        um(s.sigma_mm),
        esc(s.sigma_source.as_deref().unwrap_or("—")),
        um(Some(s.h_rms_mm)),
        um(Some(s.dz_rms_mm)),
    );
    if let Some(o) = &s.other {
        html.push_str(&format!(
            "<p class=\"note\">The {} solution: h RMS {} µm, δz RMS {} µm; the two h differ by {} µm RMS beyond a line.</p>",
            esc(&o.method),
            um(Some(o.h_rms_mm)),
            um(Some(o.dz_rms_mm)),
            um(Some(o.h_difference_rms_mm)),
        ));
    }
    html.push_str(&chart(
        "Workpiece shape h with ±2σ",
        "workpiece position (mm)",
        "h (µm)",
        &names,
        &band(&u, &hp, hsp.as_ref(), 1e3),
    ));
    html.push_str(&chart(
        "Table motion error δz with ±2σ",
        "sample n",
        "δz (µm)",
        &names,
        &band(&n, &dz, ds.as_ref(), 1e3),
    ));
    html.push_str(&chart(
        "Pitch β with ±2σ",
        "sample n",
        "β (µrad)",
        &names,
        &band(&n, &beta, bs.as_ref(), 1e6),
    ));
    let _ = x;
    Some(ReportSection {
        title: "Three-probe error separation".into(),
        html,
    })
}

fn fpe(s: &PredictorSummary) -> Option<ReportSection> {
    let bars: Vec<(String, f64)> = s
        .fpe
        .iter()
        .enumerate()
        .map(|(i, v)| (format!("p = {}", i + 1), v * 1e6))
        .collect();
    // Coefficients as text, 4 decimals each.
    let coefficients = |c: &[f64]| -> Vec<String> { c.iter().map(|v| format!("{v:.4}")).collect() };
    let coef = coefficients(&s.coefficients);
    let rls = coefficients(&s.rls_coefficients);
    let mut html = format!(
        "<p>δz differenced d = {} times; AR order by {}: <b>p = {}</b> (FPE would choose {}, BIC {}, HQ {}). Batch coefficients ({}), online RLS after the last sample ({}). One-step prediction-error variance {} µm² (source: below 1 µm).</p>",
        s.d,
        s.criterion.as_str().to_uppercase(),
        s.order,
        s.orders.fpe,
        s.orders.bic,
        s.orders.hq,
        esc(&coef.join(", ")),
        esc(&rls.join(", ")),
        finite(s.prediction_error_var_mm2)
            .map(|v| format!("{:.4}", v * 1e6))
            .unwrap_or_else(|| "—".into()),
    );
    html.push_str(&bar_chart("FPE against AR order p", "FPE (µm²)", &bars));
    Some(ReportSection {
        title: "AR model order (FPE)".into(),
        html,
    })
}

fn prediction(b: &RecordBatch, fc: Option<&RecordBatch>) -> Option<ReportSection> {
    let n = n_col(b);
    let dz = col(b, "dz_mm")?;
    let pred = opt_col(b, "dz_pred_mm")?;
    let kal = opt_col(b, "dz_kalman_mm")?;
    let mut data = vec![pts(&n, &dz, 1e3), pts(&n, &pred, 1e3), pts(&n, &kal, 1e3)];
    let mut names = vec!["measured", "one-step prediction", "Kalman estimate"];
    if let Some(f) = fc {
        let fnn = n_col(f);
        if let Some(fd) = col(f, "dz_mm") {
            data.push(pts(&fnn, &fd, 1e3));
            names.push("forecast");
        }
    }
    let mut html = chart(
        "δz: measured, predicted one step ahead, fused",
        "sample n",
        "δz (µm)",
        &names,
        &data,
    );
    let inn = opt_col(b, "innovation_mm")?;
    html.push_str(&chart(
        "One-step prediction error",
        "sample n",
        "innovation (µm)",
        &["measured − predicted"],
        &[pts(&n, &inn, 1e3)],
    ));
    Some(ReportSection {
        title: "Prediction vs measurement".into(),
        html,
    })
}

fn compensation(s: &CompensationSummary, b: &RecordBatch) -> Option<ReportSection> {
    let n = n_col(b);
    let total = col(b, "dz_mm")?;
    let g = col(b, "g_mm")?;
    let p = col(b, "dz_pred_mm")?;
    let r = col(b, "reversal_mm")?;
    let fit = &s.fit;
    let mut html = chart(
        "Compensation curve F − f and its parts",
        "sample n",
        "offset (µm)",
        &[
            "F − f (dz_mm)",
            "thermal g",
            "predicted δz",
            "table reversal",
        ],
        &[
            pts(&n, &total, 1e3),
            pts(&n, &g, 1e3),
            pts(&n, &p, 1e3),
            pts(&n, &r, 1e3),
        ],
    );
    let cell = |v: Option<f64>, e: Option<f64>, scale: f64| -> Vec<String> {
        vec![
            v.and_then(finite)
                .map(|x| format!("{:.4}", x * scale))
                .unwrap_or_else(|| "not fitted".into()),
            e.and_then(finite)
                .map(|x| format!("{:.4}", x * scale))
                .unwrap_or_else(|| "—".into()),
        ]
    };
    let mut rows = Vec::new();
    for (label, k, ks) in [
        (
            "thermal growth per infeed (µm)",
            fit.thermal_k_mm_per_infeed,
            fit.thermal_k_sigma_mm_per_infeed,
        ),
        (
            "thermal expansion per °C (µm)",
            fit.thermal_k_mm_per_c,
            fit.thermal_k_sigma_mm_per_c,
        ),
        (
            "table reversal C (µm)",
            fit.reversal_c_mm,
            fit.reversal_c_sigma_mm,
        ),
    ] {
        let mut r = vec![label.to_string()];
        r.extend(cell(k, ks, 1e3));
        rows.push(r);
    }
    html.push_str(&table(&["term", "estimate", "1σ"], &rows));
    html.push_str(&format!(
        "<p class=\"note\">Headstock reversal constant C = {} µm; infeed {} µm per pass. dz_mm (with t_s) is the offset CAN replay reads.</p>",
        um(Some(s.backlash_mm)),
        um(Some(s.infeed_mm)),
    ));
    for nt in &fit.notes {
        html.push_str(&format!("<p class=\"note\">{}</p>", esc(nt)));
    }
    Some(ReportSection {
        title: "Compensation curve".into(),
        html,
    })
}

/// The verdict: the offset error the compensation leaves (its predictor's
/// residual RMS) against the uncompensated offsets F − f (RMS about their
/// mean), the tolerance, and the separation's reading noise — the model
/// reaches its floor within [`FIT_FLOOR_FACTOR`] × the noise (the same
/// rule as the fit warning of the compensation section).
pub fn verdicts(run: &Run, a: &ArtifactStore) -> Vec<Verdict> {
    let (Some(s), Ok(Some(b))) = (
        read::<CompensationSummary>(a, "compensation"),
        a.get("compensation"),
    ) else {
        return Vec::new();
    };
    let after = s.prediction_residual_rms_mm * 1e3;
    let before = col(&b, "dz_mm").map(|v| {
        let v: Vec<f64> = v.into_iter().filter(|x| x.is_finite()).collect();
        let m = v.iter().sum::<f64>() / v.len().max(1) as f64;
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len().max(1) as f64).sqrt() * 1e3
    });
    let mut v = Verdict::new(
        "offset error left after compensation (RMS)",
        "µm",
        "compensated (prediction residual)",
        after,
    )
    .limit(
        "guideway_residual_um",
        run.tolerance("guideway_residual_um"),
    );
    if let Some(bf) = before {
        v = v.before("uncompensated F − f", bf);
    }
    if let Some(floor) = read::<SeparateSummary>(a, "separate")
        .and_then(|p| p.sigma_mm)
        .filter(|f| f.is_finite() && *f > 0.0)
    {
        let floor = floor * 1e3;
        v = v.model(floor, (FIT_FLOOR_FACTOR - 1.0) * floor);
    }
    vec![v]
}

pub fn sections(_run: &Run, a: &ArtifactStore) -> Vec<ReportSection> {
    let mut out = Vec::new();
    if let (Some(s), Ok(Some(b))) = (read::<SeparateSummary>(a, "separate"), a.get("separation")) {
        out.extend(separation(&s, &b));
    }
    if let Some(s) = read::<PredictorSummary>(a, "predictor") {
        out.extend(fpe(&s));
    }
    if let Ok(Some(b)) = a.get("predictor") {
        let fc = a.get("forecast").ok().flatten();
        out.extend(prediction(&b, fc.as_deref()));
    }
    if let (Some(s), Ok(Some(b))) = (
        read::<CompensationSummary>(a, "compensation"),
        a.get("compensation"),
    ) {
        let mut sec = compensation(&s, &b);
        // The compensation's predictor should reach the reading noise of
        // the separation (docs/models.md §3); far above it, the offsets it
        // writes carry a systematic error.
        let floor = read::<SeparateSummary>(a, "separate")
            .and_then(|p| p.sigma_mm)
            .unwrap_or(f64::NAN);
        let rms = s.prediction_residual_rms_mm;
        if let (Some(sec), Some(w)) = (
            sec.as_mut(),
            warn_fit_above_floor("compensation predictor", rms, floor, FIT_FLOOR_FACTOR),
        ) {
            sec.html.insert_str(0, &w);
        }
        out.extend(sec);
    }
    out
}

//! `cycle`: the grinding-cycle compliance model of docs/models.md §1.4.
//!
//! The loop robot–wheel–workpiece deflects by ε = α·δ (δ the real cut). The
//! wheel's programmed position advances δ′ per pass, so the real cut of pass
//! i is δ_i = δ′_i + ε_{i−1} − ε_i, i.e.
//!
//! ```text
//! δ_i = (δ′_i + α·δ_{i−1}) / (1 + α),   δ_0 = 0.
//! ```
//!
//! With constant δ′ this is the closed form of docs/models.md §1.4, δ_i = [1 − r^i]·δ′,
//! r = α/(1+α) (δ_1 = δ′/(1+α)); a spark-out pass (δ′ = 0) removes
//! δ = r·δ_{i−1}, so spark-out cuts decay geometrically. The recurrence is
//! used for every pass, so a change of δ′ between roughing and finishing
//! carries the deflection over, as the physics requires.
//!
//! α comes from the first infeed pass (the thesis: α = δ′/δ_1 − 1) and is
//! refitted by least squares over all measured passes (output error: the
//! predicted cut sequence against the measured one). τ per feed speed comes
//! from the decay of spark-out cuts, A = A0·exp(−t/τ).
//!
//! Length (over 700 lines with its tests; ~660 of code): the model, its
//! run-less `stage cycle --weld-mm …` form and the stage share the pass
//! schedule and its checks.

use sparkout_pipeline::toml_f64;
use std::collections::BTreeMap;

use super::summary::{fin, fin_opt, CyclePass, CyclePasses, CycleSummary, NoPasses, Remaining};
use crate::robot::tables::PASSES;
use crate::{bail, err};
use serde_json::Value;
use sparkout_pipeline::config_check::{read_flags, whole_number, Check, Section, SectionCheck};
use sparkout_pipeline::contracts::BatchBuilder;
use sparkout_pipeline::{
    InputError, Result, Stage, StageArgs, StageContext, StageOutput, StageSpec,
};

/// A pass's kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum PassStage {
    Rough,
    Finish,
    Spark,
}

impl PassStage {
    pub fn parse(s: &str) -> Option<PassStage> {
        match s {
            "rough" => Some(PassStage::Rough),
            "finish" => Some(PassStage::Finish),
            "spark" => Some(PassStage::Spark),
            _ => None,
        }
    }
    pub fn label(self) -> &'static str {
        match self {
            PassStage::Rough => "rough",
            PassStage::Finish => "finish",
            PassStage::Spark => "spark",
        }
    }
}

/// One pass as the model sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct Pass {
    pub pass: i32,
    pub stage: PassStage,
    pub nominal_doc_mm: f64,
    pub feed_mm_s: f64,
    pub measured_cut_mm: Option<f64>,
    pub t_start_s: Option<f64>,
    pub t_end_s: Option<f64>,
}

/// The stock left after each pass: the weld height less the cuts so far.
fn stock_left(weld_mm: f64, cuts_mm: &[f64]) -> Vec<f64> {
    cuts_mm
        .iter()
        .scan(weld_mm, |left, c| {
            *left -= c;
            Some(*left)
        })
        .collect()
}

/// Real cuts predicted by the compliance recurrence for nominal depths `docs`.
pub fn predict_cuts(alpha: f64, docs: &[f64]) -> Vec<f64> {
    let mut prev = 0.0;
    docs.iter()
        .map(|&dp| {
            let c = (dp + alpha * prev) / (1.0 + alpha);
            prev = c;
            c
        })
        .collect()
}

/// ∂δ_i/∂α of the recurrence at `alpha`, per pass: differentiating
/// δ_i = (δ′_i + α·δ_{i−1})/(1+α) gives
/// S_i = (δ_{i−1} + α·S_{i−1} − δ_i)/(1+α), S_0 = δ_0 = 0 (docs/models.md §1.4,
/// "Depth-dependent compliance through the calibration").
pub fn cut_sensitivity_to_alpha(alpha: f64, docs: &[f64]) -> Vec<f64> {
    let (mut prev_cut, mut prev_s) = (0.0, 0.0);
    docs.iter()
        .map(|&dp| {
            let cut = (dp + alpha * prev_cut) / (1.0 + alpha);
            let s = (prev_cut + alpha * prev_s - cut) / (1.0 + alpha);
            (prev_cut, prev_s) = (cut, s);
            s
        })
        .collect()
}

/// The cut_depth gap per unit k (mm², gap = k·x, k in 1/mm) of a
/// depth-dependent compliance that removes k·δ′_i² less than the recurrence
/// on every pass, as the model calibrated on the first pass sees it
/// (docs/models.md §1.4): the first cut is short by k·δ′_1² too, so α̂
/// exceeds the true α by ≈ k·δ′_1³/δ_1², and the model's cuts move by
/// S_i·(α̂ − α). To first order in k,
/// x_i = −(δ′_i² + S_i·δ′_1³/δ_1²), which is 0 on the first pass and on
/// spark-out carries the over-estimated deflection. `first_cut_mm`: the
/// measured δ_1 that calibrated `alpha_first_pass`.
pub fn depth_compliance_response_mm2(
    alpha_first_pass: f64,
    docs: &[f64],
    first_cut_mm: f64,
) -> Vec<f64> {
    let Some(&d1) = docs.first() else {
        return Vec::new();
    };
    let shift_per_k = d1.powi(3) / (first_cut_mm * first_cut_mm);
    cut_sensitivity_to_alpha(alpha_first_pass, docs)
        .iter()
        .zip(docs)
        .map(|(s, d)| -(d * d + s * shift_per_k))
        .collect()
}

/// α from the first infeed pass: δ_1 = δ′/(1+α) ⇒ α = δ′/δ_1 − 1. A first
/// cut larger than δ′ would mean negative compliance: clamped to 0.
pub fn alpha_from_first_cut(doc_mm: f64, first_cut_mm: f64) -> Result<f64> {
    if !(doc_mm > 0.0) {
        bail!("the first pass has nominal depth {doc_mm} mm; α needs an infeed pass (δ′ > 0)");
    }
    if !(first_cut_mm > 0.0) {
        bail!(
            "the first pass removed {first_cut_mm} mm (δ′ = {doc_mm} mm): α = δ′/δ₁ − 1 is undefined without a positive first cut"
        );
    }
    Ok((doc_mm / first_cut_mm - 1.0).max(0.0))
}

fn sse(alpha: f64, docs: &[f64], measured: &[Option<f64>]) -> f64 {
    predict_cuts(alpha, docs)
        .iter()
        .zip(measured)
        .filter_map(|(p, m)| m.map(|m| (p - m) * (p - m)))
        .sum()
}

/// α by least squares over every measured pass (output error), searched on
/// [0, alpha_max]: a log-spaced grid, then golden-section refinement around
/// the best grid point. `None` without at least two measured passes.
pub fn fit_alpha(docs: &[f64], measured: &[Option<f64>], alpha_max: f64) -> Option<f64> {
    if measured.iter().filter(|m| m.is_some()).count() < 2 {
        return None;
    }
    let mut grid = vec![0.0];
    let n = 400;
    let lo: f64 = 1e-4;
    for i in 0..=n {
        grid.push(lo * (alpha_max / lo).powf(i as f64 / n as f64));
    }
    let (bi, _) = grid
        .iter()
        .map(|&a| sse(a, docs, measured))
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(&b.1))?;
    let (mut a, mut b) = (
        grid[bi.saturating_sub(1)],
        grid[(bi + 1).min(grid.len() - 1)],
    );
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let mut c = b - g * (b - a);
    let mut d = a + g * (b - a);
    for _ in 0..100 {
        if sse(c, docs, measured) < sse(d, docs, measured) {
            b = d;
        } else {
            a = c;
        }
        c = b - g * (b - a);
        d = a + g * (b - a);
        if (b - a).abs() < 1e-12 * (1.0 + a.abs()) {
            break;
        }
    }
    Some(0.5 * (a + b))
}

/// τ per feed speed from the spark-out decay (docs/models.md §1.4): for each feed,
/// the spark-out passes at that feed — with the pass right before the first
/// of them when it ran at the same feed — give ln(cut) = a − t/τ; τ from the
/// least-squares slope. `None` for a feed without ≥ 2 timed, positive cuts
/// or without decay.
pub fn tau_per_feed(passes: &[Pass]) -> BTreeMap<String, Option<f64>> {
    let mut by_feed: BTreeMap<String, Vec<(f64, f64)>> = BTreeMap::new();
    let mut feeds: BTreeMap<String, f64> = BTreeMap::new();
    for (i, p) in passes.iter().enumerate() {
        if p.stage != PassStage::Spark {
            continue;
        }
        let key = feed_key(p.feed_mm_s);
        feeds.insert(key.clone(), p.feed_mm_s);
        let pts = by_feed.entry(key).or_default();
        if pts.is_empty() && i > 0 {
            let q = &passes[i - 1];
            if q.stage != PassStage::Spark && q.feed_mm_s == p.feed_mm_s {
                if let (Some(t), Some(c)) = (mid_time(q), q.measured_cut_mm) {
                    pts.push((t, c));
                }
            }
        }
        if let (Some(t), Some(c)) = (mid_time(p), p.measured_cut_mm) {
            pts.push((t, c));
        }
    }
    by_feed
        .into_iter()
        .map(|(k, pts)| {
            let pts: Vec<(f64, f64)> = pts.into_iter().filter(|(_, c)| *c > 0.0).collect();
            if pts.len() < 2 {
                return (k, None);
            }
            let n = pts.len() as f64;
            let mt = pts.iter().map(|p| p.0).sum::<f64>() / n;
            let my = pts.iter().map(|p| p.1.ln()).sum::<f64>() / n;
            let sxx: f64 = pts.iter().map(|p| (p.0 - mt).powi(2)).sum();
            let sxy: f64 = pts.iter().map(|p| (p.0 - mt) * (p.1.ln() - my)).sum();
            if !(sxx > 0.0) {
                return (k, None);
            }
            let slope = sxy / sxx;
            (k, (slope < 0.0).then(|| -1.0 / slope))
        })
        .collect()
}

fn feed_key(f: f64) -> String {
    // Shortest exact decimal form (e.g. "20" for 20.0, "12.5").
    let s = format!("{f}");
    s
}

fn mid_time(p: &Pass) -> Option<f64> {
    match (p.t_start_s, p.t_end_s) {
        (Some(a), Some(b)) => Some(0.5 * (a + b)),
        (Some(a), None) => Some(a),
        _ => None,
    }
}

/// The model's output for a cycle.
#[derive(Debug, Clone)]
pub struct CycleResult {
    pub alpha_first_pass: f64,
    pub alpha_fit: Option<f64>,
    pub predicted: Vec<f64>,
    pub predicted_fit: Option<Vec<f64>>,
    pub remaining_pred: Option<Vec<f64>>,
    pub remaining_meas: Vec<Option<f64>>,
    pub tau_s: BTreeMap<String, Option<f64>>,
}

/// Run the model over passes (sorted by pass number). `weld_mm`: initial
/// stock above the finished surface, when known.
pub fn model(passes: &[Pass], weld_mm: Option<f64>, alpha_max: f64) -> Result<CycleResult> {
    let first = passes.first().ok_or_else(|| err!("no passes"))?;
    let first_cut = first
        .measured_cut_mm
        .ok_or_else(|| err!("the first pass has no measured cut; α cannot be estimated"))?;
    let alpha_first_pass = alpha_from_first_cut(first.nominal_doc_mm, first_cut)?;
    let docs: Vec<f64> = passes.iter().map(|p| p.nominal_doc_mm).collect();
    let measured: Vec<Option<f64>> = passes.iter().map(|p| p.measured_cut_mm).collect();
    let predicted = predict_cuts(alpha_first_pass, &docs);
    let alpha_fit = fit_alpha(&docs, &measured, alpha_max);
    let predicted_fit = alpha_fit.map(|a| predict_cuts(a, &docs));
    let remaining_pred = weld_mm.map(|w| stock_left(w, &predicted));
    let mut acc = weld_mm;
    let remaining_meas = measured
        .iter()
        .map(|m| {
            acc = match (acc, m) {
                (Some(a), Some(m)) => Some(a - m),
                _ => None,
            };
            acc
        })
        .collect();
    Ok(CycleResult {
        alpha_first_pass,
        alpha_fit,
        predicted,
        predicted_fit,
        remaining_pred,
        remaining_meas,
        tau_s: tau_per_feed(passes),
    })
}

/// The remaining stock after the last pass of each stage (`None` for a
/// stage with no pass or when the weld height is unknown).
fn remaining_after(passes: &[Pass], remaining: Option<&[f64]>) -> Remaining {
    let after = |st: PassStage| {
        let last = passes.iter().rposition(|p| p.stage == st);
        match (last, remaining) {
            (Some(i), Some(r)) => fin(r[i]),
            _ => None,
        }
    };
    Remaining {
        rough: after(PassStage::Rough),
        finish: after(PassStage::Finish),
        spark: after(PassStage::Spark),
    }
}

/// The `--json` summary of the stage.
pub fn summary(passes: &[Pass], r: &CycleResult, weld_mm: Option<f64>) -> CycleSummary {
    let rows: Vec<CyclePass> = passes
        .iter()
        .enumerate()
        .map(|(i, p)| CyclePass {
            pass: p.pass,
            stage: p.stage.label().into(),
            nominal_doc_mm: p.nominal_doc_mm,
            predicted_cut_mm: r.predicted[i],
            measured_cut_mm: fin_opt(p.measured_cut_mm),
            predicted_cut_fit_mm: fin_opt(r.predicted_fit.as_ref().map(|v| v[i])),
        })
        .collect();
    let remaining_meas: Option<Vec<f64>> = r.remaining_meas.iter().copied().collect();
    let tau_s: BTreeMap<String, Option<f64>> = r
        .tau_s
        .iter()
        .map(|(k, v)| (k.clone(), fin_opt(*v)))
        .collect();
    let rms = |pred: &[f64]| -> Option<f64> {
        let d: Vec<f64> = pred
            .iter()
            .zip(passes)
            .filter_map(|(p, q)| q.measured_cut_mm.map(|m| m - p))
            .collect();
        if d.is_empty() {
            None
        } else {
            fin((d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt())
        }
    };
    CycleSummary::Passes(CyclePasses {
        alpha_first_pass: r.alpha_first_pass,
        alpha_fit: fin_opt(r.alpha_fit),
        ratio_first_pass: r.alpha_first_pass / (1.0 + r.alpha_first_pass),
        passes: rows,
        remaining_after_mm: remaining_after(passes, r.remaining_pred.as_deref()),
        remaining_after_measured_mm: remaining_after(passes, remaining_meas.as_deref()),
        tau_s,
        weld_mm: fin_opt(weld_mm),
        rms_gap_first_pass_mm: rms(&r.predicted),
        rms_gap_fit_mm: r.predicted_fit.as_deref().and_then(rms),
    })
}

/// Read and check passes.parquet.
pub fn read_passes(ctx: &StageContext) -> Result<Option<Vec<Pass>>> {
    let Some(t) = ctx.run.table(&PASSES)? else {
        return Ok(None);
    };
    let path = t.path().to_path_buf();
    let pass = t.i32("pass")?;
    let stage = t.str("stage")?;
    let doc = t.f64("nominal_doc_mm")?;
    let feed = t.f64("feed_mm_s")?;
    let hb = t.f64("height_before_mm")?;
    let ha = t.f64("height_after_mm")?;
    let ts = t.opt_f64("t_start_s");
    let te = t.opt_f64("t_end_s");
    let nulls = |c: &str| {
        t.batch()
            .column_by_name(c)
            .map(|a| a.null_count() > 0)
            .unwrap_or(false)
    };
    let (ts, te) = (
        if nulls("t_start_s") { None } else { ts },
        if nulls("t_end_s") { None } else { te },
    );
    let mut out = Vec::with_capacity(t.len());
    for i in 0..t.len() {
        let st = PassStage::parse(stage[i]).ok_or_else(|| {
            InputError::new(
                &path,
                format!(
                    "unknown pass stage `{}` (expected rough, finish or spark)",
                    stage[i]
                ),
            )
            .column("stage")
            .row(i)
        })?;
        if doc[i] < 0.0 {
            return Err(InputError::new(
                &path,
                format!("negative nominal depth of cut {}", doc[i]),
            )
            .column("nominal_doc_mm")
            .row(i)
            .into());
        }
        out.push(Pass {
            pass: pass[i],
            stage: st,
            nominal_doc_mm: doc[i],
            feed_mm_s: feed[i],
            measured_cut_mm: Some(hb[i] - ha[i]),
            t_start_s: ts.map(|v| v[i]).filter(|v| v.is_finite()),
            t_end_s: te.map(|v| v[i]).filter(|v| v.is_finite()),
        });
    }
    out.sort_by_key(|p| p.pass);
    for w in out.windows(2) {
        if w[0].pass == w[1].pass {
            let row = pass.iter().position(|&p| p == w[1].pass).unwrap_or(0);
            return Err(
                InputError::new(&path, format!("pass {} appears twice", w[1].pass))
                    .column("pass")
                    .row(row)
                    .into(),
            );
        }
    }
    if out[0].nominal_doc_mm <= 0.0 {
        return Err(InputError::new(
            &path,
            format!(
                "the first pass (pass {}) has nominal depth {} mm: α is estimated from the first infeed pass (docs/models.md §1.4)",
                out[0].pass, out[0].nominal_doc_mm
            ),
        )
        .column("nominal_doc_mm")
        .into());
    }
    if !(out[0].measured_cut_mm.unwrap_or(0.0) > 0.0) {
        let row = pass.iter().position(|&p| p == out[0].pass).unwrap_or(0);
        return Err(InputError::new(
            &path,
            format!(
                "the first pass removed {:.6} mm (height_before − height_after): α = δ′/δ₁ − 1 needs a positive first cut",
                out[0].measured_cut_mm.unwrap_or(0.0)
            ),
        )
        .column("height_after_mm")
        .row(row)
        .into());
    }
    Ok(Some(out))
}

/// Contact area (mm²) for cumulative removal: stage config, then the run's
/// `[process]`, then the machine's `process.contact_area_mm2`, else 100.
pub fn contact_area_mm2(ctx: &StageContext, cfg: &CycleConfig) -> f64 {
    if let Some(v) = cfg.contact_area_mm2 {
        return v;
    }
    if let Some(v) = ctx
        .run
        .spec
        .process
        .get("contact_area_mm2")
        .and_then(toml_f64)
    {
        return v;
    }
    ctx.run
        .machine
        .section::<super::machine::MachineProcess>()
        .and_then(|p| p.contact_area_mm2)
        .unwrap_or(100.0)
}

pub struct CycleStage;

/// `[robot.cycle]`.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CycleConfig {
    /// Upper bound of the least-squares α search (docs/models.md §1.4).
    pub alpha_max: f64,
    /// None: the run's `[process]`, then the machine's ([`contact_area_mm2`]).
    pub contact_area_mm2: Option<f64>,
}

impl Default for CycleConfig {
    fn default() -> Self {
        CycleConfig {
            alpha_max: 20.0,
            contact_area_mm2: None,
        }
    }
}

impl Section for CycleConfig {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("alpha_max", Check::Positive),
        ("contact_area_mm2", Check::Positive),
    ];
}

const SPEC: StageSpec = StageSpec {
    name: "cycle",
    version: 1,
    reads: &[&PASSES],
    reads_artifacts: &[],
    writes: &["cycle"],
    reads_augmented_model: false,
    about: "compliance model of the grinding cycle: α, predicted vs measured cut per pass, remaining stock, τ (docs/models.md §1.4)",
    config: SectionCheck::of::<CycleConfig>(),
};

impl Stage for CycleStage {
    fn spec(&self) -> &'static StageSpec {
        &SPEC
    }
    fn run(&self, ctx: &StageContext) -> Result<StageOutput> {
        let cfg: &CycleConfig = ctx.section()?;
        let alpha_max = cfg.alpha_max;
        let area = contact_area_mm2(ctx, cfg);
        let weld = ctx.run.spec.process.get("weld_mm").and_then(toml_f64);
        let Some(passes) = read_passes(ctx)? else {
            // A probing-only run is legal: an empty, valid artifact.
            let empty = CycleSummary::NoPasses(NoPasses {
                alpha_first_pass: None,
                alpha_fit: None,
                passes: Vec::new(),
                remaining_after_mm: Remaining::default(),
                tau_s: BTreeMap::new(),
                note: "no passes: the run has no passes.parquet (probing only)".into(),
            });
            return Ok(StageOutput::typed(&empty)?.with("cycle", cycle_batch(&[], None, area)));
        };
        let r = model(&passes, weld, alpha_max)?;
        let s = summary(&passes, &r, weld);
        Ok(StageOutput::typed(&s)?.with("cycle", cycle_batch(&passes, Some(&r), area)))
    }
    fn run_standalone(&self, args: &StageArgs) -> Option<Result<Value>> {
        Some(standalone(args))
    }
}

/// The `cycle` artifact: one row per pass.
pub fn cycle_batch(
    passes: &[Pass],
    r: Option<&CycleResult>,
    area_mm2: f64,
) -> arrow::record_batch::RecordBatch {
    let mut removed = Vec::with_capacity(passes.len());
    let mut acc = 0.0;
    for p in passes {
        removed.push(acc * area_mm2);
        acc += p.measured_cut_mm.unwrap_or(0.0);
    }
    let pick = |f: &dyn Fn(usize) -> Option<f64>| (0..passes.len()).map(f).collect::<Vec<_>>();
    BatchBuilder::new()
        .i32("pass", passes.iter().map(|p| p.pass).collect())
        .str(
            "stage",
            &passes.iter().map(|p| p.stage.label()).collect::<Vec<_>>(),
        )
        .f64(
            "nominal_doc_mm",
            passes.iter().map(|p| p.nominal_doc_mm).collect(),
        )
        .f64("feed_mm_s", passes.iter().map(|p| p.feed_mm_s).collect())
        .opt_f64(
            "measured_cut_mm",
            passes.iter().map(|p| p.measured_cut_mm).collect(),
        )
        .f64(
            "predicted_cut_mm",
            r.map(|r| r.predicted.clone()).unwrap_or_default(),
        )
        .opt_f64(
            "predicted_cut_fit_mm",
            pick(&|i| r.and_then(|r| r.predicted_fit.as_ref().map(|v| v[i]))),
        )
        .opt_f64(
            "remaining_predicted_mm",
            pick(&|i| r.and_then(|r| r.remaining_pred.as_ref().map(|v| v[i]))),
        )
        .opt_f64(
            "remaining_measured_mm",
            pick(&|i| r.and_then(|r| r.remaining_meas[i])),
        )
        .f64("removed_mm3", removed)
        .opt_f64("t_start_s", passes.iter().map(|p| p.t_start_s).collect())
        .opt_f64("t_end_s", passes.iter().map(|p| p.t_end_s).collect())
        .f64(
            "alpha_first_pass",
            vec![r.map(|r| r.alpha_first_pass).unwrap_or(f64::NAN); passes.len()],
        )
        .build()
}

/// Largest pass count of a cycle (run.toml `[process]` and `stage cycle`
/// flags): far beyond any real cycle, small enough that the schedule's
/// memory stays in megabytes.
pub const MAX_PASSES: i64 = 100_000;

/// The run-less form's flags and what each must be.
const FLAGS: &[(&str, Check)] = &[
    ("weld-mm", Check::Positive),
    ("rough", Check::WholeIn(0, MAX_PASSES)),
    ("finish", Check::WholeIn(0, MAX_PASSES)),
    ("spark", Check::WholeIn(0, MAX_PASSES)),
    ("doc-rough", Check::Positive),
    ("doc-finish", Check::Positive),
    ("first-cut", Check::Positive),
    ("alpha", Check::NonNegative),
];

/// `sparkout stage cycle --weld-mm 2.27 --rough 7 --finish 2 --spark 2
/// --doc-rough 0.3 --doc-finish 0.1 --first-cut 0.2` (or `--alpha`).
fn standalone(args: &StageArgs) -> Result<Value> {
    let flags = read_flags("cycle", args, FLAGS)?;
    let num = |k: &str| flags.get(k).and_then(toml_f64);
    let count = |k: &str| flags.get(k).and_then(whole_number).unwrap_or(0) as usize;
    let (nr, nf, ns) = (count("rough"), count("finish"), count("spark"));
    if nr + nf == 0 {
        bail!("stage cycle: give at least one infeed pass (--rough N and/or --finish N)");
    }
    let doc_r = num("doc-rough");
    let doc_f = num("doc-finish");
    let need = |v: Option<f64>, k: &str, n: usize| -> Result<f64> {
        match v {
            Some(x) => Ok(x),
            None if n == 0 => Ok(0.0),
            None => bail!("stage cycle: --{k} is required with {n} pass(es)"),
        }
    };
    let doc_r = need(doc_r, "doc-rough", nr)?;
    let doc_f = need(doc_f, "doc-finish", nf)?;
    let mut passes = Vec::new();
    let mut push = |stage, doc| {
        passes.push(Pass {
            pass: passes.len() as i32 + 1,
            stage,
            nominal_doc_mm: doc,
            feed_mm_s: f64::NAN,
            measured_cut_mm: None,
            t_start_s: None,
            t_end_s: None,
        })
    };
    (0..nr).for_each(|_| push(PassStage::Rough, doc_r));
    (0..nf).for_each(|_| push(PassStage::Finish, doc_f));
    (0..ns).for_each(|_| push(PassStage::Spark, 0.0));
    let first_doc = passes[0].nominal_doc_mm;
    let alpha = match (num("first-cut"), num("alpha")) {
        (Some(c), None) => {
            passes[0].measured_cut_mm = Some(c);
            alpha_from_first_cut(first_doc, c)?
        }
        (None, Some(a)) => a,
        (Some(_), Some(_)) => bail!("stage cycle: give --first-cut or --alpha, not both"),
        (None, None) => {
            bail!("stage cycle: give --first-cut (the measured first cut, mm) or --alpha")
        }
    };
    let weld = num("weld-mm");
    let docs: Vec<f64> = passes.iter().map(|p| p.nominal_doc_mm).collect();
    let predicted = predict_cuts(alpha, &docs);
    let remaining_pred = weld.map(|w| stock_left(w, &predicted));
    let r = CycleResult {
        alpha_first_pass: alpha,
        alpha_fit: None,
        predicted,
        predicted_fit: None,
        remaining_pred,
        remaining_meas: vec![None; passes.len()],
        tau_s: BTreeMap::new(),
    };
    Ok(serde_json::to_value(summary(&passes, &r, weld))?)
}

#[cfg(test)]
mod tests;

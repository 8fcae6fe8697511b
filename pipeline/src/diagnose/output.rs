//! What the diagnosis returns: diagnosis.json v1 (docs/formats.md
//! "diagnosis.json (v1)") plus the fields later versions added — every v1
//! field unchanged — and the per-row diagnosis.parquet.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use arrow::array::{ArrayRef, Float64Array, RecordBatch};
use arrow::datatypes::{DataType, Field, Schema};
use serde::{Deserialize, Serialize};

use super::augment::{AugmentedModelFile, ModelEffect, ModelFactor, ModelFrame, ModelLinear};
use super::collinear::Collinearity;
use super::effect::Effect;
use super::gather::ObsRows;
use super::intervals::{ChosenIntervals, ParamInterval};
use super::machines::{self, MachineTest};
use super::observations::{self, Table};
use super::outliers::OutlierReport;
use super::select::{Problem, Record, Selection};
use super::{cells, report, Accum, DiagnoseConfig, Notes};
use crate::Result;

const PAIRED_TEST: &str = "one-sided paired t-test on ln(rms_before/rms_after) over held-out units (runs; blocks of runs when fewer than 6 runs)";

fn fin(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// A number as diagnosis.json holds it: serde_json writes a non-finite f64
/// as `null`, which reads back as NaN (not an error).
pub(crate) use crate::files::json::f64_or_nan;

/// A bound (`lo` or `hi`) of a `where` cell: a number for a 1-D cell, an
/// `[x, y]` pair for an x/y tile, the label of a discrete cell (a
/// `machine`). Written as the bare number, array or string
/// (docs/formats.md); a number that is not finite is `null`, read back as
/// NaN.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum CellBound {
    Number(#[serde(deserialize_with = "crate::files::json::f64_or_nan")] f64),
    Point(#[serde(deserialize_with = "crate::files::json::vec_f64_or_nan")] Vec<f64>),
    Label(String),
}

impl CellBound {
    /// A discrete cell's label (`machine`'s id).
    pub fn as_label(&self) -> Option<&str> {
        match self {
            CellBound::Label(l) => Some(l),
            _ => None,
        }
    }
    /// An x/y tile's corner.
    pub fn as_point(&self) -> Option<&[f64]> {
        match self {
            CellBound::Point(p) => Some(p),
            _ => None,
        }
    }
    /// The bound as diagnosis.json writes it (compact JSON text): the
    /// `where` lists' last tie-break.
    pub fn json_text(&self) -> String {
        serde_json::to_string(self).unwrap_or_default()
    }
}

/// diagnosis.json `gap`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct GapSummary {
    #[serde(deserialize_with = "crate::diagnose::output::f64_or_nan")]
    pub rms_mm: f64,
    #[serde(deserialize_with = "crate::diagnose::output::f64_or_nan")]
    pub max_abs_mm: f64,
    #[serde(deserialize_with = "crate::diagnose::output::f64_or_nan")]
    pub noise_floor_mm: f64,
    pub n: usize,
}

/// A cell of `where` / `unexplained.where`. `lo`/`hi` are numbers for a
/// 1-D cell and `[x, y]` arrays for an x/y tile (docs/formats.md).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct WhereCell {
    pub covariate: String,
    pub lo: CellBound,
    pub hi: CellBound,
    pub observable: String,
    #[serde(deserialize_with = "crate::diagnose::output::f64_or_nan")]
    pub share: f64,
    #[serde(deserialize_with = "crate::diagnose::output::f64_or_nan")]
    pub rms_mm: f64,
    /// Bonferroni-adjusted over all cells of all observables.
    #[serde(deserialize_with = "crate::diagnose::output::f64_or_nan")]
    pub p_value: f64,
    pub n: usize,
    /// Only in `unexplained.where`: the cell's gap RMS before the selection
    /// and 1 − after/before.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rms_before_mm: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shrink: Option<f64>,
}

/// An entry of `effects`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EffectEntry {
    pub name: String,
    pub covariate: Option<String>,
    pub observable: String,
    pub params: BTreeMap<String, f64>,
    /// The canonical unit of every parameter of `params` and of
    /// `offset_mm` (`{"k": "s", "offset_mm": "mm"}`; docs/formats.md
    /// "Units"), so no reader has to guess it from the names.
    pub param_units: BTreeMap<String, String>,
    pub offset_mm: Option<f64>,
    pub n_params: usize,
    pub cv_rms_before_mm: Option<f64>,
    pub cv_rms_after_mm: Option<f64>,
    pub shrink: Option<f64>,
    pub p_value: Option<f64>,
    /// Mean over held-out units of ln(rms_before/rms_after): the ranking score.
    pub mean_log_ratio: Option<f64>,
    pub selected: bool,
    /// Share of half-subsamples of the runs on whose held-out units its
    /// gain holds (stability; `diagnose.min_selection_frequency`).
    pub selection_frequency: Option<f64>,
    /// Held-out SSE it removes over the observable's explainable SSE (gap
    /// SSE above the noise floor; materiality; `diagnose.min_gap_share`).
    pub gap_share: Option<f64>,
    /// Passed the held-out test but is not stable or material enough to
    /// be selected: listed with its figures as "minor".
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub minor: bool,
    /// Selected effects: candidates of the same round whose held-out error
    /// is statistically indistinguishable from this one's (95 % paired
    /// interval over held-out units containing zero) — on these runs, the
    /// gap is explained as well by any of them.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub indistinguishable_from: Vec<String>,
    /// Selection round the score belongs to (1 = against the raw gap).
    pub step: usize,
    pub skipped_reason: Option<String>,
    /// The effect fitted on each machine's runs alone, present when the
    /// machines of this observable disagree significantly
    /// (`machines.rs`): the pooled `params` are then a compromise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub per_machine: Option<Vec<MachineFit>>,
    /// p-value of "one effect for all machines" against "one per machine".
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub machines_differ_p: Option<f64>,
    /// Selected effects: standard error and 95 % interval of every
    /// parameter and of `offset_mm` (intervals.rs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub intervals: Option<BTreeMap<String, ParamInterval>>,
    /// Selected effects: 95 % bootstrap interval of `shrink` over held-out
    /// runs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shrink_interval: Option<[f64; 2]>,
    /// The unit of the observable's gap (`mm`, `mm/s`): the unit of the
    /// amplitudes and offset, the numerator of a coefficient.
    #[serde(skip)]
    pub gap_unit: String,
}

/// The canonical unit of each parameter and of `offset_mm`.
pub fn param_units(
    params: &BTreeMap<String, f64>,
    covariate: Option<&str>,
    gap_unit: &str,
) -> BTreeMap<String, String> {
    params
        .keys()
        .map(String::as_str)
        .chain(["offset_mm"])
        .map(|k| {
            (
                k.to_string(),
                crate::units::format::param_unit(k, covariate, gap_unit).canonical(),
            )
        })
        .collect()
}

impl EffectEntry {
    /// `name:covariate` (or `name`), as `selected` spells it.
    pub fn key(&self) -> String {
        match &self.covariate {
            Some(c) => format!("{}:{c}", self.name),
            None => self.name.clone(),
        }
    }
    /// "explained by K" plus, when rivals fit these runs as well, "— on
    /// these runs indistinguishable from R1, R2".
    pub fn explained_text(&self) -> String {
        explained_text(&self.key(), &self.indistinguishable_from)
    }
    /// Each parameter as an engineer reads it, in its unit chosen by
    /// magnitude: `k = 4.92 ± 0.08 ms (95 % 4.76 … 5.07 ms)` when it has
    /// an interval, else `k = 4.92 ms`; the offset last; frame constants
    /// left out.
    pub fn params_text(&self) -> Vec<String> {
        let mut all: Vec<(&str, f64)> = self.params.iter().map(|(k, v)| (k.as_str(), *v)).collect();
        if let Some(o) = self.offset_mm {
            all.push(("offset_mm", o));
        }
        all.into_iter()
            .filter_map(|(k, v)| {
                let iv = self.intervals.as_ref().and_then(|i| i.get(k));
                // Frame constants of a form (centre, span) come with a
                // zero-width interval: they were not fitted, so they are
                // not a finding.
                if iv.is_some_and(|i| i.se == 0.0 && i.lo == i.hi) {
                    return None;
                }
                Some(param_text(
                    k,
                    v,
                    iv,
                    self.covariate.as_deref(),
                    &self.gap_unit,
                ))
            })
            .collect()
    }
}

/// Parameter `k` of an effect on `covariate` over a gap in `gap_unit`, as
/// every page and console line writes it (units::format::show_param).
pub fn param_text(
    k: &str,
    v: f64,
    iv: Option<&ParamInterval>,
    covariate: Option<&str>,
    gap_unit: &str,
) -> String {
    use crate::units::format::{param_unit, show_param};
    show_param(
        k,
        v,
        iv.map(|i| (i.se, i.lo, i.hi)),
        &param_unit(k, covariate, gap_unit),
    )
}

/// "explained by K — on these runs indistinguishable from R…" (the rivals
/// part only when there are rivals).
pub fn explained_text(key: &str, rivals: &[String]) -> String {
    format!("explained by {}", with_rivals(key, rivals))
}

/// "K — on these runs indistinguishable from R1, R2", or "K" alone.
pub fn with_rivals(key: &str, rivals: &[String]) -> String {
    if rivals.is_empty() {
        key.to_string()
    } else {
        format!(
            "{key} — on these runs indistinguishable from {}",
            rivals.join(" and ")
        )
    }
}

/// One machine's fit of a selected effect (`EffectEntry::per_machine`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MachineFit {
    pub machine: String,
    pub n: usize,
    pub runs: usize,
    pub params: BTreeMap<String, f64>,
    pub offset_mm: Option<f64>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Unexplained {
    #[serde(deserialize_with = "crate::diagnose::output::f64_or_nan")]
    pub rms_mm: f64,
    #[serde(deserialize_with = "crate::diagnose::output::f64_or_nan")]
    pub share: f64,
    #[serde(rename = "where")]
    pub where_: Vec<WhereCell>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CvInfo {
    pub folds: usize,
    /// "run" (a run = one (machine, run) pair) or "blocked_within_run".
    pub by: String,
    pub test: String,
    pub seed: u64,
}

/// Per-observable summary (extra to v1).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ObservableSummary {
    pub observable: String,
    /// Unit of this observable's gap, RMS and noise-floor numbers (the
    /// `_mm` field names are v1's; the values are in this unit — "mm"
    /// unless the observations' `unit` column says otherwise).
    pub unit: String,
    pub n: usize,
    /// Run units: (machine, run) pairs.
    pub runs: usize,
    /// Machines whose rows carry this observable (empty without a
    /// `machine` column).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub machines: Vec<String>,
    #[serde(deserialize_with = "crate::diagnose::output::f64_or_nan")]
    pub rms_mm: f64,
    #[serde(deserialize_with = "crate::diagnose::output::f64_or_nan")]
    pub noise_floor_mm: f64,
    pub noise_floor_source: String,
    pub gap_above_noise: bool,
    #[serde(deserialize_with = "crate::diagnose::output::f64_or_nan")]
    pub p_value: f64,
    pub selected: Vec<String>,
    /// Effects that passed the held-out test but not the stability or
    /// materiality threshold (their figures are in `effects`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub minor: Vec<String>,
    /// Covariates of selected effects that move with others within runs,
    /// with advice (collinear.rs).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub collinear: Vec<Collinearity>,
    #[serde(deserialize_with = "crate::diagnose::output::f64_or_nan")]
    pub cv_rms_before_mm: f64,
    #[serde(deserialize_with = "crate::diagnose::output::f64_or_nan")]
    pub cv_rms_after_mm: f64,
    #[serde(deserialize_with = "crate::diagnose::output::f64_or_nan")]
    pub shrink: f64,
    /// 95 % bootstrap interval of `shrink` over held-out runs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shrink_interval: Option<[f64; 2]>,
    /// With outliers trimmed: `shrink` and the CV RMS
    /// are over the kept rows (robust); this is over every row.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shrink_plain: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub outliers: Option<OutlierReport>,
    pub stop_reason: String,
}

/// diagnosis.json v1 (every contract field) plus extras.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Diagnosis {
    pub version: u32,
    pub observables: Vec<String>,
    /// Machine ids of the table (empty without a `machine`
    /// column — a v1 table).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub machines: Vec<String>,
    pub gap: GapSummary,
    #[serde(rename = "where")]
    pub where_: Vec<WhereCell>,
    pub effects: Vec<EffectEntry>,
    pub selected: Vec<String>,
    pub unexplained: Unexplained,
    /// "replicates", "point_to_point" or "mixed" (per observable below).
    pub noise_floor_source: String,
    pub cv: CvInfo,
    pub per_observable: Vec<ObservableSummary>,
    pub notes: Vec<String>,
    /// Effects named on one machine's rows alone, where a `where` cell over
    /// `machine` localised the gap to that machine (13
    /// item 6): the fleet-wide fit dilutes an effect only one machine has.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub machine_effects: Vec<MachineEffect>,
}

/// An effect selected by diagnosing one machine's rows of one observable.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MachineEffect {
    pub machine: String,
    pub observable: String,
    /// `name:covariate`, as `selected` spells it.
    pub effect: String,
    pub params: BTreeMap<String, f64>,
    /// As `EffectEntry::param_units`: the canonical unit of each parameter
    /// and of the offset.
    pub param_units: BTreeMap<String, String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub intervals: Option<BTreeMap<String, ParamInterval>>,
    pub shrink: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shrink_interval: Option<[f64; 2]>,
    /// Runs of that machine the effect was fitted and held out on.
    pub runs: usize,
}

pub struct DiagnosisOutput {
    pub diagnosis: Diagnosis,
    /// diagnosis.parquet: [machine,] run, observable, gap,
    /// contrib_<name:cov>…, residual_after — one row per observation, in
    /// input order.
    pub per_row: RecordBatch,
    /// The selected effects fitted on all runs, for a simulator to add
    /// (augmented_model.json).
    pub augmented_model: AugmentedModelFile,
    /// Self-contained `<section>` for the fleet report.
    pub report_html: String,
}

pub fn per_row_batch(
    batch: &RecordBatch,
    table: &observations::Table,
    contrib: &BTreeMap<String, Vec<f64>>,
    keys: &[String],
    residual: &[f64],
) -> Result<RecordBatch> {
    let to_utf8 = |name: &str| -> Result<ArrayRef> {
        let a = batch.column_by_name(name).expect("validated");
        Ok(arrow::compute::cast(a, &DataType::Utf8)?)
    };
    let mut fields = Vec::new();
    let mut cols: Vec<ArrayRef> = Vec::new();
    if table.has_machine {
        fields.push(Field::new("machine", DataType::Utf8, false));
        cols.push(to_utf8("machine")?);
    }
    fields.extend([
        Field::new("run", DataType::Utf8, false),
        Field::new("observable", DataType::Utf8, false),
        Field::new("gap", DataType::Float64, false),
    ]);
    cols.extend([
        to_utf8("run")?,
        to_utf8("observable")?,
        Arc::new(Float64Array::from(table.gap.clone())) as ArrayRef,
    ]);
    for k in keys {
        fields.push(Field::new(format!("contrib_{k}"), DataType::Float64, false));
        cols.push(Arc::new(Float64Array::from(contrib[k].clone())));
    }
    fields.push(Field::new("residual_after", DataType::Float64, false));
    cols.push(Arc::new(Float64Array::from(residual.to_vec())));
    Ok(RecordBatch::try_new(Arc::new(Schema::new(fields)), cols)?)
}

/// Per selected effect (in selection order): does it hold for every machine?
/// Empty entries without a `machine` column or with one machine.
pub fn machine_tests(
    table: &Table,
    o: &ObsRows,
    prob: &Problem,
    cands: &[&dyn Effect],
    sel: &Selection,
) -> Result<Vec<Option<MachineTest>>> {
    if !table.has_machine || o.machines().len() < 2 {
        return Ok(sel.chosen.iter().map(|_| None).collect());
    }
    sel.chosen
        .iter()
        .zip(&sel.final_targets)
        .map(|(&ci, target)| {
            machines::per_machine(
                cands[ci],
                &prob.x,
                target,
                &o.machine,
                &o.run_ranges,
                &table.machine_names,
            )
        })
        .collect()
}

/// The `effects` entries of one observable: selected (in order), then by
/// score, skipped last.
#[allow(clippy::too_many_arguments)]
pub fn effect_entries(
    observable: &str,
    gap_unit: &str,
    n: usize,
    cands: &[&dyn Effect],
    sel: &Selection,
    tests: &[Option<MachineTest>],
    intervals: &ChosenIntervals,
    cfg: &DiagnoseConfig,
) -> Vec<EffectEntry> {
    let mut recs: Vec<&Record> = sel.records.iter().collect();
    let rank = |r: &Record| {
        if r.selected {
            (
                0usize,
                sel.chosen.iter().position(|&c| c == r.idx).unwrap_or(0) as f64,
            )
        } else if r.skipped.is_some() {
            (2, 0.0)
        } else {
            (1, -r.mean_log_ratio)
        }
    };
    recs.sort_by(|a, b| {
        let (ra, rb) = (rank(a), rank(b));
        ra.0.cmp(&rb.0)
            .then(ra.1.total_cmp(&rb.1))
            .then(a.idx.cmp(&b.idx))
    });
    recs.into_iter()
        .map(|r| {
            let e = cands[r.idx];
            let covs = e.covariates();
            let before = (r.sse_before / n as f64).sqrt();
            let after = (r.sse_after / n as f64).sqrt();
            let j = sel.chosen.iter().position(|&c| c == r.idx && r.selected);
            let test = j.and_then(|j| tests.get(j)).and_then(|t| t.as_ref());
            let iv = j.and_then(|j| intervals.get(j));
            let covariate = (!covs.is_empty()).then(|| covs.join(","));
            let params: BTreeMap<String, f64> = r
                .params
                .iter()
                .filter(|(_, v)| v.is_finite())
                .map(|(k, v)| (k.clone(), *v))
                .collect();
            EffectEntry {
                name: e.name().to_string(),
                param_units: param_units(&params, covariate.as_deref(), gap_unit),
                covariate,
                observable: observable.to_string(),
                params,
                offset_mm: fin(r.offset_mm),
                n_params: e.n_params(),
                cv_rms_before_mm: fin(before),
                cv_rms_after_mm: fin(after),
                shrink: fin(1.0 - after / before),
                p_value: fin(r.p_value),
                mean_log_ratio: fin(r.mean_log_ratio),
                selected: r.selected,
                selection_frequency: fin(r.selection_frequency),
                gap_share: fin(r.gap_share),
                minor: r.minor,
                indistinguishable_from: r
                    .indistinguishable
                    .iter()
                    .map(|&i| cands[i].key())
                    .collect(),
                step: r.step,
                skipped_reason: r.skipped.clone(),
                per_machine: test
                    .filter(|t| t.disagree(cfg.alpha, cfg.min_gain))
                    .map(|t| t.fits.clone()),
                machines_differ_p: test.and_then(|t| fin(t.p_value)),
                intervals: iv.map(|i| i.0.clone()),
                shrink_interval: iv.and_then(|i| i.1),
                gap_unit: gap_unit.to_string(),
            }
        })
        .collect()
}

/// Selected effects of one observable into the fleet accumulators: keys,
/// explained variance, per-row contributions, augmented model, residual.
/// `extra_rows` (trimmed outliers) get the all-runs fits' predictions.
/// Returns the observable's selected keys.
#[allow(clippy::too_many_arguments)]
pub fn record_selected(
    table: &Table,
    o: &ObsRows,
    prob: &Problem,
    cands: &[&dyn Effect],
    sel: &Selection,
    sigma_mm: f64,
    extra_rows: &[usize],
    acc: &mut Accum,
) -> Result<Vec<String>> {
    let mut extra_resid: Vec<f64> = extra_rows.iter().map(|&i| table.gap[i]).collect();
    let mut obs_selected = Vec::new();
    for (j, &ci) in sel.chosen.iter().enumerate() {
        let e = cands[ci];
        let key = e.key();
        if !acc.selected_keys.contains(&key) {
            acc.selected_keys.push(key.clone());
        }
        if let Some(r) = sel.records.iter().find(|r| r.idx == ci && r.selected) {
            let var = sigma_mm.powi(2).max(f64::MIN_POSITIVE);
            *acc.explained_var.entry(key.clone()).or_insert(0.0) +=
                ((r.sse_before - r.sse_after) / var).max(0.0);
        }
        obs_selected.push(key.clone());
        let col = acc
            .contrib_cols
            .entry(key.clone())
            .or_insert_with(|| vec![0.0; table.n]);
        for (pos, &i) in o.rows.iter().enumerate() {
            col[i] = sel.contrib[j][pos];
        }
        if !extra_rows.is_empty() {
            let pred = predict_rows(e, &prob.x, &sel.final_targets[j], table, extra_rows)?;
            for ((&i, p), r) in extra_rows.iter().zip(pred).zip(extra_resid.iter_mut()) {
                col[i] = p;
                *r -= p;
            }
        }
        let (params, off) = &sel.final_params[j];
        let covs = e.covariates();
        // The catalogue form it evaluates as outside the diagnosis (`run
        // --augment`): its own name, or that of the catalogue effect a
        // plugin composite renames; none for products of forms.
        let form = super::effect::Kind::from_name(e.name())
            .or_else(|| {
                e.replaces()
                    .and_then(|r| super::effect::Kind::from_name(r.split(':').next().unwrap_or("")))
            })
            .map(|k| k.name());
        // The all-runs fit exactly as the diagnosis predicts with it (θ,
        // feature-space intercept and coefficients of its linear form, and
        // the catalogue forms it is built from), so `run --augment` replays
        // any linear-form effect — products of forms included.
        let linear = match (&sel.chosen_evals[j].fit, e.linear_form()) {
            (super::select::CandFit::Fast { theta, beta }, Some(form))
                if !form.factors().is_empty() =>
            {
                Some(ModelLinear {
                    coef: beta[prob.k][1..].iter().map(|b| fin(*b)).collect(),
                    factors: form
                        .factors()
                        .iter()
                        .map(|(k, c)| ModelFactor {
                            covariates: c.clone(),
                            form: k.name().to_string(),
                        })
                        .collect(),
                    intercept: fin(beta[prob.k][0]),
                    theta: fin(theta[prob.k]),
                })
            }
            _ => None,
        };
        acc.augmented.push(ModelEffect {
            covariate: (!covs.is_empty()).then(|| covs.join(",")),
            form: form.map(str::to_string),
            frame: covs
                .iter()
                .map(|c| (c.clone(), prob.frames.get(c).copied().map(ModelFrame::from)))
                .collect(),
            key,
            linear,
            name: e.name().to_string(),
            observable: o.name.to_string(),
            offset_mm: fin(*off),
            params: params
                .iter()
                .filter(|(_, v)| v.is_finite())
                .map(|(k, v)| (k.clone(), *v))
                .collect(),
        });
    }
    for (pos, &i) in o.rows.iter().enumerate() {
        acc.residual_all[i] = sel.residual[pos];
    }
    for (&i, r) in extra_rows.iter().zip(extra_resid) {
        acc.residual_all[i] = r;
    }
    Ok(obs_selected)
}

/// The all-runs fit of `e` to `target` (over the rows of `x`), predicted on
/// table rows `rows` (offset included).
fn predict_rows(
    e: &dyn Effect,
    x: &super::effect::EffectData,
    target: &[f64],
    table: &Table,
    rows: &[usize],
) -> Result<Vec<f64>> {
    let fe = e.fit(x, target)?;
    let covs = e.covariates();
    let store: Vec<Vec<f64>> = covs
        .iter()
        .map(|c| {
            table
                .cov(c)
                .map(|v| rows.iter().map(|&i| v[i]).collect())
                .ok_or_else(|| anyhow::anyhow!("covariate `{c}` not in the table"))
        })
        .collect::<Result<_>>()?;
    let mut xd = super::effect::EffectData::new(rows.len());
    for (c, v) in covs.iter().zip(&store) {
        xd.push(c, v);
    }
    let off = fe.offset_mm();
    Ok(fe.predict(&xd).into_iter().map(|p| p + off).collect())
}

/// The fleet-level diagnosis from the per-observable results.
pub fn assemble(
    batch: &RecordBatch,
    table: &Table,
    cfg: &DiagnoseConfig,
    mut acc: Accum,
    mut notes: Notes,
) -> Result<DiagnosisOutput> {
    let n_all = table.n;
    if acc.blocked {
        notes.add("single run: blocked folds within the run".into());
    }
    if acc.summaries.iter().all(|s| !s.gap_above_noise) {
        notes.add("no gap above noise".into());
    }
    let sum_g2: f64 = table.gap.iter().map(|g| g * g).sum();
    let sum_r2: f64 = acc.residual_all.iter().map(|r| r * r).sum();
    let noise_floor = (acc
        .summaries
        .iter()
        .map(|s| s.n as f64 * s.noise_floor_mm.powi(2))
        .sum::<f64>()
        / n_all as f64)
        .sqrt();
    let sources: BTreeSet<&str> = acc
        .summaries
        .iter()
        .map(|s| s.noise_floor_source.as_str())
        .collect();
    let noise_src = if sources.len() == 1 {
        sources
            .into_iter()
            .next()
            .unwrap_or("point_to_point")
            .to_string()
    } else {
        "mixed".into()
    };
    let (where_, where_after) = cells::where_lists(&acc.cells, sum_g2, sum_r2, cfg.alpha);
    // Stable: ties keep the order of first selection.
    let explained = std::mem::take(&mut acc.explained_var);
    acc.selected_keys.sort_by(|a, b| {
        let w = |k: &String| explained.get(k).copied().unwrap_or(0.0);
        w(b).total_cmp(&w(a))
    });
    let diagnosis = Diagnosis {
        version: 1,
        observables: table.obs_names.clone(),
        machines: if table.has_machine {
            table.machine_names.clone()
        } else {
            Vec::new()
        },
        gap: GapSummary {
            rms_mm: (sum_g2 / n_all as f64).sqrt(),
            max_abs_mm: table.gap.iter().fold(0.0, |m, g| m.max(g.abs())),
            noise_floor_mm: noise_floor,
            n: n_all,
        },
        where_,
        effects: acc.effects,
        selected: acc.selected_keys.clone(),
        unexplained: Unexplained {
            rms_mm: (sum_r2 / n_all as f64).sqrt(),
            share: if sum_g2 > 0.0 { sum_r2 / sum_g2 } else { 0.0 },
            where_: where_after,
        },
        noise_floor_source: noise_src,
        cv: CvInfo {
            folds: acc.folds_used,
            by: if acc.blocked {
                "blocked_within_run".into()
            } else {
                "run".into()
            },
            test: PAIRED_TEST.into(),
            seed: cfg.seed,
        },
        per_observable: acc.summaries,
        notes: notes.into_vec(),
        machine_effects: Vec::new(),
    };
    let per_row = per_row_batch(
        batch,
        table,
        &acc.contrib_cols,
        &acc.selected_keys,
        &acc.residual_all,
    )?;
    let augmented_model = AugmentedModelFile {
        applies_as: "real ≈ sim + Σ over effects of (offset_mm + form(covariates; params)), per observable; forms as in the effect catalogue of docs/formats.md".into(),
        effects: acc.augmented,
        // `run --augment` reports the augmented gap on the runs not listed
        // here (held out by construction).
        fitted_on_runs: table.run_names.clone(),
        kind: super::augment::MODEL_KIND.into(),
        version: 1,
    };
    let report_html = report::section(&diagnosis);
    Ok(DiagnosisOutput {
        diagnosis,
        per_row,
        augmented_model,
        report_html,
    })
}

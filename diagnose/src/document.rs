//! diagnosis.json's serde types (docs/formats.md "diagnosis.json (v1)"):
//! what the diagnosis writes and what every reader — the fleet page, the
//! trend, `sparkout run`'s summary — reads back, through the same types.
//! They sit below the steps that fill them (`output` assembles them) so a
//! reader needs no diagnosis logic.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::augment::AugmentedModelFile;
use crate::collinear::Collinearity;
use crate::intervals::ParamInterval;
use crate::outliers::OutlierReport;

pub(crate) fn fin(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// A bound (`lo` or `hi`) of a `where` cell: a number for a 1-D cell, an
/// `[x, y]` pair for an x/y tile, the label of a discrete cell (a
/// `machine`). Written as the bare number, array or string
/// (docs/formats.md); a number that is not finite is `null`, read back as
/// NaN.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum CellBound {
    Number(#[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")] f64),
    Point(#[serde(deserialize_with = "sparkout_core::files::json::vec_f64_or_nan")] Vec<f64>),
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
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
    pub rms_mm: f64,
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
    pub max_abs_mm: f64,
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
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
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
    pub share: f64,
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
    pub rms_mm: f64,
    /// Bonferroni-adjusted over all cells of all observables.
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
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
    /// "explained by K" plus, when rivals fit these runs as well, " (on
    /// these runs indistinguishable from R1 and R2)".
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

/// "explained by K (on these runs indistinguishable from R…)" (the rivals
/// part only when there are rivals).
pub fn explained_text(key: &str, rivals: &[String]) -> String {
    format!("explained by {}", with_rivals(key, rivals))
}

/// "K (on these runs indistinguishable from R1 and R2)", or "K" alone:
/// in parentheses, so a list of selected effects stays readable when a
/// rival is also selected later ("drift:t_s (… from periodic:t_s),
/// periodic:t_s").
pub fn with_rivals(key: &str, rivals: &[String]) -> String {
    match rivals_text(rivals) {
        Some(r) => format!("{key} ({r})"),
        None => key.to_string(),
    }
}

/// "on these runs indistinguishable from R1 and R2"; None without rivals.
pub fn rivals_text(rivals: &[String]) -> Option<String> {
    (!rivals.is_empty()).then(|| {
        format!(
            "on these runs indistinguishable from {}",
            rivals.join(" and ")
        )
    })
}

/// What the runs cannot rule out for `o`'s selected effects, as
/// sentences for a report: the rivals that also passed on covariates
/// moving with the selected ones' ([`confounded_text`]) and each
/// collinearity's advice — empty when no rival is confounded.
pub fn caution_sentences(o: &ObservableSummary, effects: &[EffectEntry]) -> Vec<String> {
    let mut out = Vec::new();
    if let Some(also) = confounded_text(o, effects) {
        out.push(format!("{also}."));
    }
    for c in o.collinear.iter().filter(|c| !c.confounds.is_empty()) {
        out.push(format!("Note: {}.", c.advice));
    }
    out
}

/// What explains one observable's gap, as `sparkout run` prints it and
/// the fleet report shows it: the selected effects, each with the rivals
/// it cannot be told from on these runs; the minor effects; the rivals
/// that passed on covariates moving with the selected ones', and the
/// covariates that move together with what to change.
pub fn explained_by(o: &ObservableSummary, effects: &[EffectEntry]) -> String {
    let mut text = if o.selected.is_empty() {
        o.stop_reason.clone()
    } else {
        let keys = o
            .selected
            .iter()
            .map(|k| {
                let rivals = effects
                    .iter()
                    .find(|e| e.observable == o.observable && e.selected && e.key() == *k)
                    .map(|e| e.indistinguishable_from.as_slice())
                    .unwrap_or_default();
                with_rivals(k, rivals)
            })
            .collect::<Vec<_>>()
            .join(", ");
        format!("explained by {keys}")
    };
    if !o.minor.is_empty() {
        text.push_str(&format!("; minor (not selected): {}", o.minor.join(", ")));
    }
    // News only where a rival that passed cannot be ruled out.
    let cautions = caution_sentences(o, effects);
    if !cautions.is_empty() {
        text.push_str(". ");
        text.push_str(cautions.join(" ").trim_end_matches('.'));
    }
    text
}

/// The rivals of `o`'s selected effects that the collinearity notes are
/// about and that are not already named as indistinguishable, best
/// held-out RMS first: "Also passing on covariates that move with t_s
/// within every run: wear:removed_mm3 (held-out 3.64 µm), wear:pass
/// (held-out 4.23 µm)" (each rival's held-out RMS in the selected
/// effect's round). None when there are none. Read from
/// diagnosis.json's fields alone, so the CLI and the report say the same.
fn confounded_text(o: &ObservableSummary, effects: &[EffectEntry]) -> Option<String> {
    let of_o = |key: &str| {
        effects
            .iter()
            .find(|e| e.observable == o.observable && e.key() == key)
    };
    let named: Vec<&String> = o
        .selected
        .iter()
        .filter_map(|k| of_o(k))
        .flat_map(|e| &e.indistinguishable_from)
        .collect();
    let parts: Vec<String> = o
        .collinear
        .iter()
        .filter_map(|c| {
            let mut rivals: Vec<(f64, String)> = c
                .confounds
                .iter()
                .filter(|k| !named.contains(k))
                .map(|k| match c.confound_rms.get(k) {
                    Some(&rms) => (
                        rms,
                        format!(
                            "{k} (held-out {})",
                            crate::units::format::show_in(rms, &o.unit)
                        ),
                    ),
                    None => (f64::INFINITY, k.clone()),
                })
                .collect();
            rivals.sort_by(|a, b| a.0.total_cmp(&b.0));
            (!rivals.is_empty()).then(|| {
                let listed: Vec<String> = rivals.into_iter().map(|(_, t)| t).collect();
                format!(
                    "Also passing on covariates that move with {} within every run: {}",
                    c.covariate,
                    listed.join(", ")
                )
            })
        })
        .collect();
    (!parts.is_empty()).then(|| parts.join("; "))
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
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
    pub rms_mm: f64,
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
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
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
    pub rms_mm: f64,
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
    pub noise_floor_mm: f64,
    pub noise_floor_source: String,
    pub gap_above_noise: bool,
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
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
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
    pub cv_rms_before_mm: f64,
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
    pub cv_rms_after_mm: f64,
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
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
    /// diagnosis.parquet, built a slice at a time as it is written.
    pub per_row: crate::per_row::PerRow,
    /// The selected effects fitted on all runs, for a simulator to add
    /// (augmented_model.json).
    pub augmented_model: AugmentedModelFile,
    /// Self-contained `<section>` for the fleet report.
    pub report_html: String,
}

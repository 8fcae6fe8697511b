//! `sparkout run --augment augmented_model.json` (issue 13 item 4, the
//! generic part): the effects a previous diagnosis selected are added to
//! the sim side of tonight's observations, and per observable and machine
//! the gap of the plain and of the augmented simulator is reported on the
//! runs the model was **not** fitted on (held out by construction: last
//! night's model on tonight's runs). Written to `fleet/augment.json`, shown
//! in the fleet page's verdicts.
//!
//! What this is not (yet): the effects enter as the catalogue's additive
//! forms (docs/formats.md, "Candidate effects"), evaluated on each row's
//! covariates — not inside the plugins' physics (wheel radius in the form
//! grinder's profile model, bridge deflection in Γ, g in the guide-way
//! compensation F), and the compensation artifacts are not recomputed from
//! it. Effects that are not one catalogue form are listed as not applied.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use arrow::array::RecordBatch;
use serde_json::{json, Value};

use super::effect::{shape_value, Kind};
use crate::contracts::batch::{batch_f64, batch_str};

/// One selected effect of an augmented model.
#[derive(Debug, Clone)]
pub struct AugmentEffect {
    pub observable: String,
    /// `name:covariates` as diagnosis.json spells it.
    pub key: String,
    /// The catalogue form it evaluates as; None: not one catalogue form.
    pub kind: Option<Kind>,
    pub covariates: Vec<String>,
    pub params: BTreeMap<String, f64>,
    pub offset_mm: f64,
}

/// An augmented_model.json, checked.
#[derive(Debug, Clone)]
pub struct AugmentedModel {
    pub path: PathBuf,
    pub effects: Vec<AugmentEffect>,
    /// `machine/run` of every run the model was fitted on (empty when the
    /// model predates the field: then nothing counts as held out by id).
    pub fitted_on: BTreeSet<String>,
}

impl AugmentedModel {
    /// Read and check a model written by `sparkout run`/`diagnose`
    /// (`fleet/augmented_model.json`); errors name the file and the field.
    pub fn load(path: &Path) -> Result<AugmentedModel> {
        let bytes = std::fs::read(path)
            .with_context(|| format!("{}: cannot read the augmented model", path.display()))?;
        let v: Value = serde_json::from_slice(&bytes).with_context(|| {
            format!(
                "{}: not JSON; --augment takes the fleet/augmented_model.json of an earlier `sparkout run`",
                path.display()
            )
        })?;
        let here = |field: &str, what: &str| -> anyhow::Error {
            anyhow::anyhow!(
                "{}: field `{field}`: {what} (--augment takes the fleet/augmented_model.json of an earlier `sparkout run`)",
                path.display()
            )
        };
        if v.get("kind").and_then(|k| k.as_str()) != Some("sparkout.augmented_model") {
            return Err(here("kind", "expected \"sparkout.augmented_model\""));
        }
        if v.get("version").and_then(|k| k.as_u64()) != Some(1) {
            return Err(here("version", "expected 1"));
        }
        let Some(list) = v.get("effects").and_then(|e| e.as_array()) else {
            return Err(here("effects", "expected an array"));
        };
        let mut effects = Vec::new();
        for (i, e) in list.iter().enumerate() {
            let field = |k: &str| format!("effects[{i}].{k}");
            let text = |k: &str| -> Result<String> {
                e.get(k)
                    .and_then(|x| x.as_str())
                    .map(str::to_string)
                    .ok_or_else(|| here(&field(k), "expected text"))
            };
            let observable = text("observable")?;
            let key = text("key")?;
            let form = e.get("form").and_then(|f| f.as_str());
            let kind = match form {
                Some(f) => Some(
                    Kind::from_name(f)
                        .ok_or_else(|| here(&field("form"), &format!("unknown form `{f}`")))?,
                ),
                None => None,
            };
            let covariates: Vec<String> = e
                .get("covariate")
                .and_then(|c| c.as_str())
                .map(|c| c.split(',').map(str::to_string).collect())
                .unwrap_or_default();
            let mut params = BTreeMap::new();
            if let Some(p) = e.get("params").and_then(|p| p.as_object()) {
                for (k, x) in p {
                    let x = x.as_f64().filter(|x| x.is_finite()).ok_or_else(|| {
                        here(&field(&format!("params.{k}")), "expected a finite number")
                    })?;
                    params.insert(k.clone(), x);
                }
            }
            // Frame constants (bow's c0/c1) the parameters leave out.
            if let Some(fr) = e.get("frame").and_then(|f| f.as_object()) {
                for (_, f) in fr {
                    for (k, x) in f.as_object().into_iter().flatten() {
                        if let Some(x) = x.as_f64() {
                            params.entry(k.clone()).or_insert(x);
                        }
                    }
                }
            }
            let offset_mm = match e.get("offset_mm") {
                None | Some(Value::Null) => 0.0,
                Some(x) => x
                    .as_f64()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| here(&field("offset_mm"), "expected a finite number"))?,
            };
            effects.push(AugmentEffect {
                observable,
                key,
                kind,
                covariates,
                params,
                offset_mm,
            });
        }
        let fitted_on = v
            .get("fitted_on_runs")
            .and_then(|r| r.as_array())
            .into_iter()
            .flatten()
            .filter_map(|r| r.as_str().map(str::to_string))
            .collect();
        Ok(AugmentedModel {
            path: path.to_path_buf(),
            effects,
            fitted_on,
        })
    }
}

/// A numeric column as float64 (integer covariates such as `infeed_count`
/// widened); None when absent.
fn float_column(obs: &RecordBatch, name: &str) -> Option<Vec<f64>> {
    use arrow::array::{Array, AsArray};
    let c = obs.column_by_name(name)?;
    let c = arrow::compute::cast(c, &arrow::datatypes::DataType::Float64).ok()?;
    let a = c.as_primitive::<arrow::datatypes::Float64Type>();
    Some(
        (0..a.len())
            .map(|i| if a.is_null(i) { f64::NAN } else { a.value(i) })
            .collect(),
    )
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for x in v.filter(|x| x.is_finite()) {
        s += x * x;
        n += 1;
    }
    if n == 0 {
        f64::NAN
    } else {
        (s / n as f64).sqrt()
    }
}

/// The augmented simulator on the joined observations: one entry per
/// (observable, machine) the model has applicable effects for, in the shape
/// the fleet page reads (`fleet/augment.json`).
pub fn evaluate(model: &AugmentedModel, obs: &RecordBatch) -> Result<Value> {
    let observable = batch_str(obs, "observable")?;
    let run = batch_str(obs, "run")?;
    let machine = if obs.schema().index_of("machine").is_ok() {
        batch_str(obs, "machine")?
    } else {
        vec![String::new(); obs.num_rows()]
    };
    let sim = batch_f64(obs, "sim")?;
    let real = batch_f64(obs, "real")?;
    let unit = if obs.schema().index_of("unit").is_ok() {
        Some(batch_str(obs, "unit")?)
    } else {
        None
    };
    let mut not_applied = Vec::new();
    let mut by_obs: BTreeMap<&str, Vec<&AugmentEffect>> = BTreeMap::new();
    for e in &model.effects {
        if e.kind.is_none() {
            not_applied.push(json!({
                "observable": e.observable,
                "effect": e.key,
                "why": "not one catalogue form: cannot be evaluated outside its plugin",
            }));
            continue;
        }
        by_obs.entry(e.observable.as_str()).or_default().push(e);
    }
    let mut entries = Vec::new();
    for (o, effects) in &by_obs {
        let rows: Vec<usize> = (0..obs.num_rows())
            .filter(|&i| observable[i] == *o)
            .collect();
        if rows.is_empty() {
            continue;
        }
        // sim_aug = sim + Σ (offset + form(covariates; params)).
        let mut added = vec![0.0; rows.len()];
        let mut applied = Vec::new();
        for e in effects {
            let cols: Option<Vec<Vec<f64>>> =
                e.covariates.iter().map(|c| float_column(obs, c)).collect();
            let Some(cols) = cols else {
                not_applied.push(json!({
                    "observable": o,
                    "effect": e.key,
                    "why": format!("tonight's observations lack its covariate ({})", e.covariates.join(", ")),
                }));
                continue;
            };
            let pick = |c: &Vec<f64>| rows.iter().map(|&i| c[i]).collect::<Vec<f64>>();
            let c1 = cols
                .first()
                .map(&pick)
                .unwrap_or_else(|| vec![0.0; rows.len()]);
            let c2 = cols.get(1).map(pick);
            let kind = e.kind.expect("filtered");
            let shape = shape_value(kind, &e.params, &c1, c2.as_deref());
            for (a, s) in added.iter_mut().zip(shape) {
                *a += if kind == Kind::Offset {
                    s
                } else {
                    s + e.offset_mm
                };
            }
            applied.push(e.key.clone());
        }
        if applied.is_empty() {
            continue;
        }
        let machines: BTreeSet<&str> = rows.iter().map(|&i| machine[i].as_str()).collect();
        for m in machines {
            let mine: Vec<usize> = (0..rows.len()).filter(|&k| machine[rows[k]] == m).collect();
            let id = |k: usize| {
                if m.is_empty() {
                    run[rows[k]].clone()
                } else {
                    format!("{m}/{}", run[rows[k]])
                }
            };
            let held: Vec<usize> = mine
                .iter()
                .copied()
                .filter(|&k| !model.fitted_on.contains(&id(k)))
                .collect();
            let (use_rows, held_out) = if held.is_empty() {
                (mine.clone(), false)
            } else {
                (held, true)
            };
            let runs: BTreeSet<String> = use_rows.iter().map(|&k| id(k)).collect();
            let plain = rms(use_rows.iter().map(|&k| real[rows[k]] - sim[rows[k]]));
            let aug = rms(use_rows
                .iter()
                .map(|&k| real[rows[k]] - sim[rows[k]] - added[k]));
            let mut entry = json!({
                "observable": o,
                "machine": m,
                "effects": applied,
                "runs": runs.len(),
                "rows": use_rows.len(),
                "held_out": held_out,
                "heldout_rms_plain": plain,
                "heldout_rms_augmented": aug,
                "shrink": if plain > 0.0 { 1.0 - aug / plain } else { f64::NAN },
            });
            if let Some(u) = unit.as_ref().and_then(|u| {
                use_rows
                    .first()
                    .map(|&k| u[rows[k]].clone())
                    .filter(|s| !s.is_empty())
            }) {
                entry["unit"] = json!(u);
            }
            entries.push(entry);
        }
    }
    if model.effects.is_empty() {
        bail!(
            "{}: the model has no effects (its diagnosis selected none); nothing to augment",
            model.path.display()
        );
    }
    Ok(json!({
        "version": 1,
        "kind": "sparkout.augment",
        "model": model.path.display().to_string(),
        "applies_as": "sim_augmented = sim + Σ (offset_mm + form(covariates; params)) per observable; figures on the runs the model was not fitted on (held_out = true), else on all runs (held_out = false: in-sample)",
        "entries": entries,
        "not_applied": not_applied,
    }))
}

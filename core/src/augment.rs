//! `sparkout run --augment augmented_model.json` (the
//! generic part): the effects a previous diagnosis selected are added to
//! the sim side of tonight's observations, and per observable and machine
//! the gap of the plain and of the augmented simulator is reported on the
//! runs the model was **not** fitted on (held out by construction: last
//! night's model on tonight's runs). Written to `fleet/augment.json`, shown
//! in the fleet page's verdicts.
//!
//! Each effect is replayed exactly as the diagnosis fitted it (its linear
//! form's θ, intercept and coefficients, products of forms included) on
//! each row's covariates, and added to the sim side. What this is not
//! (yet): the effects do not enter the plugins' physics (wheel radius in
//! the form grinder's profile model, bridge deflection in Γ, g in the
//! guide-way compensation F), and the compensation artifacts are not
//! recomputed from them.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use arrow::array::RecordBatch;
use serde_json::{json, Value};

use super::effect::{rebuild_linear_form, shape_value, CovStats, EffectData, Kind};
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
    /// The fit as the diagnosis made it, when the model carries it (diagnose
    /// step version 6): replayed exactly, products of forms included.
    pub linear: Option<LinearFit>,
}

/// A linear-form fit: `intercept + Σ coef_j · feature_j(frame, covariates; θ)`.
#[derive(Debug, Clone)]
pub struct LinearFit {
    pub factors: Vec<(Kind, Vec<String>)>,
    /// Covariate statistics in `covariates` order (the features' scaling).
    pub frame: Vec<CovStats>,
    pub theta: f64,
    pub intercept: f64,
    pub coef: Vec<f64>,
}

impl LinearFit {
    /// The effect's prediction (offset included) on rows whose covariates
    /// are `cols` (in `covariates` order); None when the form cannot be
    /// rebuilt or its features fail.
    fn predict(&self, covariates: &[String], cols: &[Vec<f64>]) -> Option<Vec<f64>> {
        let form = rebuild_linear_form(&self.factors)?;
        if form.n_linear() != self.coef.len() || form.covariates() != covariates {
            return None;
        }
        let n = cols.first().map_or(0, Vec::len);
        let mut x = EffectData::new(n);
        for (c, v) in covariates.iter().zip(cols) {
            x.push(c, v);
        }
        let mut feats = vec![Vec::new(); form.n_linear()];
        form.features(&self.frame, &x, self.theta, &mut feats)
            .ok()?;
        let mut out = vec![self.intercept; n];
        for (f, b) in feats.iter().zip(&self.coef) {
            for (o, v) in out.iter_mut().zip(f) {
                *o += b * v;
            }
        }
        Some(out)
    }
}

/// The `linear` block of an augmented-model effect, if present and whole
/// (a model from before it, or one with a non-finite number, has none).
fn linear_fit(e: &Value, covariates: &[String]) -> Option<LinearFit> {
    let l = e.get("linear").filter(|l| !l.is_null())?;
    let factors = l
        .get("factors")?
        .as_array()?
        .iter()
        .map(|f| {
            let kind = Kind::from_name(f.get("form")?.as_str()?)?;
            let covs = f
                .get("covariates")?
                .as_array()?
                .iter()
                .map(|c| c.as_str().map(str::to_string))
                .collect::<Option<Vec<String>>>()?;
            Some((kind, covs))
        })
        .collect::<Option<Vec<_>>>()?;
    let frames = e.get("frame")?.as_object()?;
    let frame = covariates
        .iter()
        .map(|c| serde_json::from_value::<CovStats>(frames.get(c)?.clone()).ok())
        .collect::<Option<Vec<_>>>()?;
    let num = |v: &Value| v.as_f64().filter(|x| x.is_finite());
    Some(LinearFit {
        factors,
        frame,
        // No θ (a purely linear form) is null.
        theta: l.get("theta").and_then(num).unwrap_or(f64::NAN),
        intercept: num(l.get("intercept")?)?,
        coef: l
            .get("coef")?
            .as_array()?
            .iter()
            .map(num)
            .collect::<Option<Vec<f64>>>()?,
    })
}

impl AugmentEffect {
    /// The effect's value (offset included) on rows whose covariates are
    /// `cols`, in `covariates` order: the diagnosis's fit replayed when the
    /// model carries it, else the catalogue form from the contract
    /// parameters. None when neither can be evaluated.
    pub fn predict(&self, cols: &[Vec<f64>]) -> Option<Vec<f64>> {
        match (&self.linear, self.kind) {
            (Some(l), _) => l.predict(&self.covariates, cols),
            (None, Some(kind)) => {
                let n = cols.first().map_or(0, Vec::len);
                let c1 = cols.first().cloned().unwrap_or_else(|| vec![0.0; n]);
                let shape = shape_value(kind, &self.params, &c1, cols.get(1).map(Vec::as_slice));
                let off = if kind == Kind::Offset {
                    0.0
                } else {
                    self.offset_mm
                };
                Some(shape.into_iter().map(|v| v + off).collect())
            }
            (None, None) => None,
        }
    }

    /// The composite or catalogue name (`wheel_wear` of
    /// `wheel_wear:removed_mm3`).
    pub fn name(&self) -> &str {
        self.key.split(':').next().unwrap_or("")
    }
}

/// What separates the effect keys in `sim_augmented_effects`: a key such
/// as `thermal_bow:y_mm,t_s` holds a comma.
pub const KEY_SEPARATOR: char = ';';

/// Effect keys as `sim_augmented_effects` lists them.
pub fn join_keys<'a>(keys: impl IntoIterator<Item = &'a str>) -> String {
    keys.into_iter()
        .collect::<Vec<_>>()
        .join(&KEY_SEPARATOR.to_string())
}

/// An augmented_model.json, checked.
#[derive(Debug, Clone)]
pub struct AugmentedModel {
    pub path: PathBuf,
    /// blake3 of the file: the cache key of every stage that reads it.
    pub content_hash: String,
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
            let linear = linear_fit(e, &covariates);
            effects.push(AugmentEffect {
                observable,
                key,
                kind,
                covariates,
                params,
                offset_mm,
                linear,
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
            content_hash: blake3::hash(&bytes).to_hex().to_string(),
            effects,
            fitted_on,
        })
    }

    /// The effects selected for one observable.
    pub fn effects_for<'a>(
        &'a self,
        observable: &'a str,
    ) -> impl Iterator<Item = &'a AugmentEffect> + 'a {
        self.effects
            .iter()
            .filter(move |e| e.observable == observable)
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

/// The sim side a plugin re-simulated with effects in its physics
/// (`sim_augmented`, else `sim`), and which effects it put there, per row
/// (none where the column is absent or null).
fn resimulated(obs: &RecordBatch, sim: &[f64]) -> Result<(Vec<f64>, Vec<Vec<String>>)> {
    let sim_base: Vec<f64> = match float_column(obs, "sim_augmented") {
        Some(a) => a
            .iter()
            .zip(sim)
            .map(|(a, s)| if a.is_finite() { *a } else { *s })
            .collect(),
        None => sim.to_vec(),
    };
    let in_physics: Vec<Vec<String>> = if obs.schema().index_of("sim_augmented_effects").is_ok() {
        batch_str(obs, "sim_augmented_effects")?
            .into_iter()
            .map(|s| {
                s.split(KEY_SEPARATOR)
                    .filter(|k| !k.is_empty())
                    .map(str::to_string)
                    .collect()
            })
            .collect()
    } else {
        vec![Vec::new(); obs.num_rows()]
    };
    Ok((sim_base, in_physics))
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
    let (sim_base, in_physics) = resimulated(obs, sim)?;
    let mut not_applied = Vec::new();
    let mut by_obs: BTreeMap<&str, Vec<&AugmentEffect>> = BTreeMap::new();
    for e in &model.effects {
        if e.kind.is_none() && e.linear.is_none() {
            not_applied.push(json!({
                "observable": e.observable,
                "effect": e.key,
                "why": "neither one catalogue form nor a replayable linear fit (a model written before diagnose step version 6): re-run the diagnosis",
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
        // sim_aug = (sim_augmented where the plugin re-simulated, else sim)
        // + Σ the effects not already in its physics.
        let mut added = vec![0.0; rows.len()];
        let mut applied = Vec::new();
        let mut applied_in_physics = Vec::new();
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
            let picked: Vec<Vec<f64>> = cols.iter().map(pick).collect();
            let Some(effect) = e.predict(&picked) else {
                not_applied.push(json!({
                    "observable": o,
                    "effect": e.key,
                    "why": "its fitted form could not be rebuilt from the model",
                }));
                continue;
            };
            // Rows whose plugin put the effect into its physics
            // (`sim_augmented`) do not get it again as an added term.
            let mut physics = false;
            for ((a, v), &i) in added.iter_mut().zip(effect).zip(&rows) {
                if in_physics[i].contains(&e.key) {
                    physics = true;
                } else {
                    *a += v;
                }
            }
            if physics {
                applied_in_physics.push(e.key.clone());
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
                .map(|&k| real[rows[k]] - sim_base[rows[k]] - added[k]));
            let mut entry = json!({
                "observable": o,
                "machine": m,
                "effects": applied,
                "in_physics": applied_in_physics,
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
        "applies_as": "sim_augmented = the plugin's re-simulation with the effects listed in `in_physics` inside its physics (else sim) + Σ the other effects, each as the diagnosis fitted it (its linear form replayed; else offset_mm + form(covariates; params)); figures on the runs the model was not fitted on (held_out = true), else on all runs (held_out = false: in-sample)",
        "entries": entries,
        "not_applied": not_applied,
    }))
}

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

use crate::{bail, Context, Result};
use arrow::array::RecordBatch;
use serde::{Deserialize, Serialize};

use super::effect::{rebuild_linear_form, shape_value, CovStats, EffectData, Kind};
use crate::contracts::batch::{batch_f64, batch_str};
use crate::files::json::{f64_or_nan, parse_json, FileHeader};

/// `kind` of augmented_model.json.
pub const MODEL_KIND: &str = "sparkout.augmented_model";
/// `kind` of augment.json.
pub const AUGMENT_KIND: &str = "sparkout.augment";

/// fleet/augmented_model.json (docs/formats.md): the selected effects as a
/// model to add to the simulator, written by the diagnosis and read back by
/// `run --augment` through this type. The fields are in the order the
/// file has always had them (alphabetical, at every level).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AugmentedModelFile {
    #[serde(default)]
    pub applies_as: String,
    pub effects: Vec<ModelEffect>,
    /// `machine/run` of every run the model was fitted on (since diagnose
    /// step version 5; absent before: nothing counts as held out by id).
    #[serde(default)]
    pub fitted_on_runs: Vec<String>,
    pub kind: String,
    pub version: u32,
}

/// One selected effect of augmented_model.json.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelEffect {
    /// `covariate[,covariate2]`; null for an effect without one.
    #[serde(default)]
    pub covariate: Option<String>,
    /// The catalogue form it evaluates as; null for a product of forms
    /// (since diagnose step version 5).
    #[serde(default)]
    pub form: Option<String>,
    /// The covariates' statistics over the rows it was fitted on (null
    /// where the diagnosis had none).
    #[serde(default)]
    pub frame: BTreeMap<String, Option<ModelFrame>>,
    /// `name:covariates`, as diagnosis.json spells it.
    pub key: String,
    /// The fit exactly as the diagnosis predicts with it; null for an
    /// effect without a linear form (since diagnose step version 6).
    #[serde(default)]
    pub linear: Option<ModelLinear>,
    #[serde(default)]
    pub name: String,
    pub observable: String,
    #[serde(default)]
    pub offset_mm: Option<f64>,
    #[serde(default)]
    pub params: BTreeMap<String, f64>,
}

/// A covariate's frame in augmented_model.json (a [`CovStats`] in the
/// file's field order).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ModelFrame {
    #[serde(deserialize_with = "f64_or_nan")]
    pub max: f64,
    #[serde(deserialize_with = "f64_or_nan")]
    pub max_abs: f64,
    #[serde(deserialize_with = "f64_or_nan")]
    pub min: f64,
    #[serde(deserialize_with = "f64_or_nan")]
    pub step: f64,
}

impl From<CovStats> for ModelFrame {
    fn from(c: CovStats) -> Self {
        ModelFrame {
            max: c.max,
            max_abs: c.max_abs,
            min: c.min,
            step: c.step,
        }
    }
}

impl ModelFrame {
    /// The statistics, when every one is a number.
    fn stats(&self) -> Option<CovStats> {
        [self.min, self.max, self.step, self.max_abs]
            .iter()
            .all(|x| x.is_finite())
            .then_some(CovStats {
                min: self.min,
                max: self.max,
                step: self.step,
                max_abs: self.max_abs,
                run_span: None,
            })
    }
}

/// The `linear` block of an effect: `intercept + Σ coef_j · feature_j`,
/// the features built from `factors` and scaled by the effect's `frame`.
/// A number that was not finite is null.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelLinear {
    pub coef: Vec<Option<f64>>,
    pub factors: Vec<ModelFactor>,
    pub intercept: Option<f64>,
    /// The nonlinear parameter; null when the form has none.
    pub theta: Option<f64>,
}

/// One catalogue form of a linear block.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelFactor {
    pub covariates: Vec<String>,
    pub form: String,
}

/// fleet/augment.json (docs/formats.md, `run --augment`): the plain and
/// the augmented simulator's gap per observable and machine, written by
/// [`evaluate`] and read by the fleet page through this type. Fields in
/// the file's (alphabetical) order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AugmentReport {
    pub applies_as: String,
    pub entries: Vec<AugmentEntry>,
    pub kind: String,
    /// The model file given to `--augment`.
    pub model: String,
    pub not_applied: Vec<NotApplied>,
    pub version: u32,
}

/// One observable and machine of augment.json.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AugmentEntry {
    /// Keys of the effects applied.
    pub effects: Vec<String>,
    /// True: the figures are over runs the model was not fitted on; false:
    /// every run was in `fitted_on_runs` (in-sample).
    pub held_out: bool,
    /// RMS of real − sim_augmented (null when there is no row to measure).
    #[serde(deserialize_with = "f64_or_nan")]
    pub heldout_rms_augmented: f64,
    /// RMS of real − sim.
    #[serde(deserialize_with = "f64_or_nan")]
    pub heldout_rms_plain: f64,
    /// The effects a plugin put into its physics rather than added.
    pub in_physics: Vec<String>,
    /// "" without a machine column.
    pub machine: String,
    pub observable: String,
    pub rows: usize,
    pub runs: usize,
    /// 1 − augmented/plain.
    #[serde(deserialize_with = "f64_or_nan")]
    pub shrink: f64,
    /// The observable's unit, when the observations name one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unit: Option<String>,
}

/// An effect of the model that was not applied, and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NotApplied {
    pub effect: String,
    pub observable: String,
    pub why: String,
}

impl AugmentReport {
    /// `<out>/fleet/augment.json` as written by `run --augment`.
    pub fn read(path: &Path) -> Result<AugmentReport> {
        let r: AugmentReport = crate::files::json::read_json(path)?;
        if r.kind != AUGMENT_KIND || r.version != 1 {
            bail!(
                "{}: kind {:?} version {}, expected {AUGMENT_KIND:?} version 1",
                path.display(),
                r.kind,
                r.version
            );
        }
        Ok(r)
    }
}

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
fn linear_fit(e: &ModelEffect, covariates: &[String]) -> Option<LinearFit> {
    let l = e.linear.as_ref()?;
    let factors = l
        .factors
        .iter()
        .map(|f| Some((Kind::from_name(&f.form)?, f.covariates.clone())))
        .collect::<Option<Vec<_>>>()?;
    let frame = covariates
        .iter()
        .map(|c| e.frame.get(c)?.as_ref()?.stats())
        .collect::<Option<Vec<_>>>()?;
    let num = |v: Option<f64>| v.filter(|x| x.is_finite());
    Some(LinearFit {
        factors,
        frame,
        // No θ (a purely linear form) is null.
        theta: num(l.theta).unwrap_or(f64::NAN),
        intercept: num(l.intercept)?,
        coef: l
            .coef
            .iter()
            .map(|c| num(*c))
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
    /// (`fleet/augmented_model.json`) through [`AugmentedModelFile`];
    /// errors name the file and the field.
    pub fn load(path: &Path) -> Result<AugmentedModel> {
        const HINT: &str =
            "--augment takes the fleet/augmented_model.json of an earlier `sparkout run`";
        let bytes = std::fs::read(path)
            .with_context(|| format!("{}: cannot read the augmented model", path.display()))?;
        let here = |field: &str, what: &str| -> crate::Error {
            crate::err!("{}: field `{field}`: {what} ({HINT})", path.display())
        };
        // Kind and version first: another file is refused by name.
        let header: FileHeader = parse_json(path, &bytes).map_err(|e| {
            crate::err!(
                "{}: not an augmented model ({}); {HINT}",
                path.display(),
                e.message
            )
        })?;
        if header.kind.as_deref() != Some(MODEL_KIND) {
            return Err(here("kind", &format!("expected \"{MODEL_KIND}\"")));
        }
        if header.version != Some(1) {
            return Err(here("version", "expected 1"));
        }
        let file: AugmentedModelFile =
            parse_json(path, &bytes).map_err(|e| crate::err!("{e} ({HINT})"))?;
        let mut effects = Vec::new();
        for (i, e) in file.effects.iter().enumerate() {
            let field = |k: &str| format!("effects[{i}].{k}");
            let kind = match &e.form {
                Some(f) => Some(
                    Kind::from_name(f)
                        .ok_or_else(|| here(&field("form"), &format!("unknown form `{f}`")))?,
                ),
                None => None,
            };
            let covariates: Vec<String> = e
                .covariate
                .as_deref()
                .map(|c| c.split(',').map(str::to_string).collect())
                .unwrap_or_default();
            let offset_mm = match e.offset_mm {
                None => 0.0,
                Some(x) if x.is_finite() => x,
                Some(_) => return Err(here(&field("offset_mm"), "expected a finite number")),
            };
            let linear = linear_fit(e, &covariates);
            effects.push(AugmentEffect {
                observable: e.observable.clone(),
                key: e.key.clone(),
                kind,
                covariates,
                params: e.params.clone(),
                offset_mm,
                linear,
            });
        }
        Ok(AugmentedModel {
            path: path.to_path_buf(),
            content_hash: blake3::hash(&bytes).to_hex().to_string(),
            effects,
            fitted_on: file.fitted_on_runs.into_iter().collect(),
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
pub fn evaluate(model: &AugmentedModel, obs: &RecordBatch) -> Result<AugmentReport> {
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
            not_applied.push(NotApplied {
                observable: e.observable.clone(),
                effect: e.key.clone(),
                why: "neither one catalogue form nor a replayable linear fit (a model written before diagnose step version 6): re-run the diagnosis".into(),
            });
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
                not_applied.push(NotApplied {
                    observable: o.to_string(),
                    effect: e.key.clone(),
                    why: format!(
                        "tonight's observations lack its covariate ({})",
                        e.covariates.join(", ")
                    ),
                });
                continue;
            };
            let pick = |c: &Vec<f64>| rows.iter().map(|&i| c[i]).collect::<Vec<f64>>();
            let picked: Vec<Vec<f64>> = cols.iter().map(pick).collect();
            let Some(effect) = e.predict(&picked) else {
                not_applied.push(NotApplied {
                    observable: o.to_string(),
                    effect: e.key.clone(),
                    why: "its fitted form could not be rebuilt from the model".into(),
                });
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
            let unit = unit.as_ref().and_then(|u| {
                use_rows
                    .first()
                    .map(|&k| u[rows[k]].clone())
                    .filter(|s| !s.is_empty())
            });
            let entry = AugmentEntry {
                effects: applied.clone(),
                held_out,
                heldout_rms_augmented: aug,
                heldout_rms_plain: plain,
                in_physics: applied_in_physics.clone(),
                machine: m.to_string(),
                observable: o.to_string(),
                rows: use_rows.len(),
                runs: runs.len(),
                shrink: if plain > 0.0 {
                    1.0 - aug / plain
                } else {
                    f64::NAN
                },
                unit,
            };
            entries.push(entry);
        }
    }
    if model.effects.is_empty() {
        bail!(
            "{}: the model has no effects (its diagnosis selected none); nothing to augment",
            model.path.display()
        );
    }
    Ok(AugmentReport {
        applies_as: "sim_augmented = the plugin's re-simulation with the effects listed in `in_physics` inside its physics (else sim) + Σ the other effects, each as the diagnosis fitted it (its linear form replayed; else offset_mm + form(covariates; params)); figures on the runs the model was not fitted on (held_out = true), else on all runs (held_out = false: in-sample)".into(),
        entries,
        kind: AUGMENT_KIND.into(),
        model: model.path.display().to_string(),
        not_applied,
        version: 1,
    })
}

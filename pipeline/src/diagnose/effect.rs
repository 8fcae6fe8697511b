//! Candidate effects: the `Effect` trait (fit → fitted → predict, linfa
//! style), the v1 catalogue of CONTRACTS.md ("Candidate effect names") and
//! the composites plugins register (DESIGN.md "Sim-to-real gap diagnosis",
//! point 2).
//!
//! Every catalogue effect is *linear in its amplitudes once its (at most one)
//! nonlinear parameter θ is fixed*: drift's τ, periodic's λ (the phase is
//! linear through a sin/cos pair), edge's λ. Such an effect exposes a
//! [`LinearForm`]; the diagnosis engine then cross-validates it from additive
//! per-run sufficient statistics (X'X, X'y) instead of refitting on rows, and
//! scans θ on a grid. An effect that is not of that shape (a plugin's own
//! nonlinear model) implements only [`Effect::fit`] and is cross-validated
//! the slow way (fit on the training rows, predict the held-out rows).

use std::collections::BTreeMap;
use std::f64::consts::PI;
use std::sync::Arc;

use anyhow::{anyhow, bail};

use super::fit;
use crate::Result;

/// Column views over the rows an effect is fitted on or predicts: one `f64`
/// slice per covariate, all of the same length. Cheap to build (borrows).
#[derive(Debug, Clone, Default)]
pub struct EffectData<'a> {
    n: usize,
    cols: Vec<(String, &'a [f64])>,
}

impl<'a> EffectData<'a> {
    pub fn new(n_rows: usize) -> Self {
        EffectData {
            n: n_rows,
            cols: Vec::new(),
        }
    }
    /// Adds a covariate column; panics when its length is not the row count
    /// (an engine bug, never user input).
    pub fn with(mut self, name: &str, values: &'a [f64]) -> Self {
        self.push(name, values);
        self
    }
    pub fn push(&mut self, name: &str, values: &'a [f64]) {
        assert_eq!(values.len(), self.n, "column {name}: length mismatch");
        self.cols.retain(|(n, _)| n != name);
        self.cols.push((name.to_string(), values));
    }
    pub fn col(&self, name: &str) -> Option<&'a [f64]> {
        self.cols.iter().find(|(n, _)| n == name).map(|(_, v)| *v)
    }
    /// The column or an error naming it (an effect asked for a covariate the
    /// table lacks).
    pub fn require(&self, name: &str) -> Result<&'a [f64]> {
        self.col(name)
            .ok_or_else(|| anyhow!("effect needs covariate `{name}`, which the data lack"))
    }
    pub fn len(&self) -> usize {
        self.n
    }
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.cols.iter().map(|(n, _)| n.as_str())
    }
}

/// A candidate unmodelled effect. `fit` must fit the shape *together with a
/// free offset* (DESIGN.md: "every shape is fitted together with an offset,
/// so it is judged on its shape").
pub trait Effect: Send + Sync {
    /// Catalogue or composite name, e.g. `drift`, `thermal_bow`.
    fn name(&self) -> &str;
    /// Covariates it reads, in order (`squareness`: two).
    fn covariates(&self) -> Vec<String>;
    /// Shape parameters, the offset excluded (`drift`: amplitude and τ = 2).
    fn n_params(&self) -> usize;
    /// Fits shape + offset to `gap` over the rows of `x`.
    fn fit(&self, x: &EffectData, gap: &[f64]) -> Result<Box<dyn FittedEffect>>;
    /// The fast path: `Some` when the effect is linear in its amplitudes for
    /// a fixed θ (all catalogue effects are).
    fn linear_form(&self) -> Option<Arc<dyn LinearForm>> {
        None
    }
    /// `name:covariate` as diagnosis.json's `selected` spells it
    /// (`offset` alone; two covariates joined by a comma).
    /// The key of the catalogue candidate this effect is a physically named
    /// version of (a plugin composite made by [`composite`]): the diagnosis
    /// then tries only the named one, so the two never tie for first place.
    fn replaces(&self) -> Option<String> {
        None
    }
    fn key(&self) -> String {
        let c = self.covariates();
        if c.is_empty() {
            self.name().to_string()
        } else {
            format!("{}:{}", self.name(), c.join(","))
        }
    }
}

/// A fitted effect: its parameters and a predictor of its *shape* (the
/// offset it was fitted with is reported apart, [`FittedEffect::offset_mm`]).
pub trait FittedEffect: Send + Sync {
    fn params(&self) -> BTreeMap<String, f64>;
    fn offset_mm(&self) -> f64;
    fn predict(&self, x: &EffectData) -> Vec<f64>;
}

/// Data-dependent constants of one covariate, computed from covariate values
/// only (never from the gap), over all rows of an observable: the range that
/// bounds `bow` and `periodic`, and the typical sample step (the smallest
/// admissible wavelength is 3 sample steps, CONTRACTS.md catalogue table).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CovStats {
    pub min: f64,
    pub max: f64,
    /// Median positive spacing of the sorted distinct values.
    pub step: f64,
    pub max_abs: f64,
}

impl CovStats {
    pub fn from_values(v: &[f64]) -> CovStats {
        let mut s: Vec<f64> = v.to_vec();
        s.sort_unstable_by(f64::total_cmp);
        Self::from_sorted(&s)
    }
    /// From ascending values (the engine sorts each covariate once).
    pub fn from_sorted(s: &[f64]) -> CovStats {
        if s.is_empty() {
            return CovStats {
                min: 0.0,
                max: 0.0,
                step: 0.0,
                max_abs: 0.0,
            };
        }
        let (min, max) = (s[0], s[s.len() - 1]);
        let tol = 1e-12 * (max - min).abs().max(1e-300);
        let mut steps: Vec<f64> = s
            .windows(2)
            .map(|w| w[1] - w[0])
            .filter(|d| *d > tol)
            .collect();
        let step = if steps.is_empty() {
            0.0
        } else {
            let m = steps.len() / 2;
            *steps.select_nth_unstable_by(m, f64::total_cmp).1
        };
        CovStats {
            min,
            max,
            step,
            max_abs: min.abs().max(max.abs()),
        }
    }
    pub fn range(&self) -> f64 {
        self.max - self.min
    }
    /// Centre and half range, used to standardise linear features so the
    /// normal equations stay well conditioned (removed_mm3 reaches 1e5).
    fn mid_half(&self) -> (f64, f64) {
        let half = 0.5 * self.range();
        (
            0.5 * (self.min + self.max),
            if half > 0.0 { half } else { 1.0 },
        )
    }
    /// A covariate that does not vary cannot carry a shape (skipped, said).
    pub fn is_constant(&self) -> bool {
        let r = self.range();
        r.is_nan() || r <= 1e-12 * self.max_abs.max(1e-300)
    }
}

/// The constants of each covariate of a form, in `covariates()` order.
pub type Frame = Vec<CovStats>;

/// Search range of the one nonlinear parameter θ of a form.
#[derive(Debug, Clone, PartialEq)]
pub struct ThetaRange {
    /// Parameter name as reported (`tau_s`, `lambda`).
    pub name: String,
    pub lo: f64,
    pub hi: f64,
    /// Coarse grid, ascending in θ, dense enough that the refinement between
    /// two neighbours finds the optimum (periodic: a quarter cycle over the
    /// covariate's range between neighbours).
    pub grid: Vec<f64>,
    /// Covariate resolution at which values may be pooled for the coarse
    /// scan without changing a feature by more than ~1 %.
    pub resolution: f64,
    /// Refine in log θ (τ, edge λ) or in 1/θ (periodic λ: frequency).
    pub refine_in_frequency: bool,
}

/// An effect that is linear in its amplitudes given θ.
pub trait LinearForm: Send + Sync {
    fn covariates(&self) -> Vec<String>;
    /// Number of linear shape features (the offset is implicit).
    fn n_linear(&self) -> usize;
    /// `None` for purely linear forms.
    fn theta(&self, frame: &Frame) -> Option<ThetaRange>;
    /// Writes the shape features of every row of `x` into `out[j][i]`
    /// (`out.len() == n_linear()`, each `x.len()` long).
    fn features(
        &self,
        frame: &Frame,
        x: &EffectData,
        theta: f64,
        out: &mut [Vec<f64>],
    ) -> Result<()>;
    /// Reported parameters (contract units) from θ, the feature
    /// coefficients and the fitted offset; returns the parameters and the
    /// offset in the convention `offset_mm + form(c; params)`.
    fn params(
        &self,
        frame: &Frame,
        theta: f64,
        coef: &[f64],
        offset: f64,
    ) -> (BTreeMap<String, f64>, f64);
}

/// The v1 catalogue kinds (CONTRACTS.md table).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    Offset,
    Scale,
    Drift,
    Lag,
    Inertia,
    Backlash,
    Wear,
    Compliance,
    Bow,
    Periodic,
    Edge,
    Squareness,
    Thermal,
}

impl Kind {
    pub fn name(self) -> &'static str {
        match self {
            Kind::Offset => "offset",
            Kind::Scale => "scale",
            Kind::Drift => "drift",
            Kind::Lag => "lag",
            Kind::Inertia => "inertia",
            Kind::Backlash => "backlash",
            Kind::Wear => "wear",
            Kind::Compliance => "compliance",
            Kind::Bow => "bow",
            Kind::Periodic => "periodic",
            Kind::Edge => "edge",
            Kind::Squareness => "squareness",
            Kind::Thermal => "thermal",
        }
    }
    pub fn all() -> [Kind; 13] {
        [
            Kind::Offset,
            Kind::Scale,
            Kind::Drift,
            Kind::Lag,
            Kind::Inertia,
            Kind::Backlash,
            Kind::Wear,
            Kind::Compliance,
            Kind::Bow,
            Kind::Periodic,
            Kind::Edge,
            Kind::Squareness,
            Kind::Thermal,
        ]
    }
    pub fn from_name(s: &str) -> Option<Kind> {
        Kind::all().into_iter().find(|k| k.name() == s)
    }
    /// Shape parameters (offset excluded).
    pub fn n_params(self) -> usize {
        match self {
            Kind::Offset => 0,
            Kind::Drift | Kind::Edge => 2,
            Kind::Periodic => 3,
            _ => 1,
        }
    }
    fn n_linear(self) -> usize {
        match self {
            Kind::Offset => 0,
            Kind::Periodic => 2,
            _ => 1,
        }
    }
}

/// Reference temperature of `thermal` (k·(T − T0)): T0 is confounded with
/// the offset, so it is fixed at the metrology reference 20 °C (ISO 1).
pub const THERMAL_T0_C: f64 = 20.0;
/// τ of `drift` is searched in [span/200, span] of the time covariate: a
/// longer τ makes drift a straight line (which `wear`/`scale` already are).
pub const DRIFT_TAU_MIN_FRAC: f64 = 1.0 / 200.0;
/// Upper bound of periodic's cycle count over the covariate range beyond the
/// contract's 3-sample-step bound: keeps the frequency scan bounded on
/// densely sampled time covariates (see [`periodic_lambda_bounds`]).
pub const PERIODIC_MAX_CYCLES: f64 = 64.0;

/// Periodic λ bounds: from max(3 sample steps, range/64) to the covariate
/// range (CONTRACTS.md: at least one whole cycle inside the data, so
/// periodic cannot impersonate scale or bow).
pub fn periodic_lambda_bounds(s: &CovStats) -> (f64, f64) {
    let range = s.range();
    let lo = (3.0 * s.step).max(range / PERIODIC_MAX_CYCLES);
    (lo.min(range), range)
}

/// A catalogue shape on concrete covariates.
#[derive(Debug, Clone)]
pub struct Shape {
    pub kind: Kind,
    pub covs: Vec<String>,
}

fn log_grid(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if hi.is_nan() || lo.is_nan() || hi <= lo || n < 2 {
        return vec![lo];
    }
    let (a, b) = (lo.ln(), hi.ln());
    (0..n)
        .map(|i| (a + (b - a) * i as f64 / (n - 1) as f64).exp())
        .collect()
}

impl LinearForm for Shape {
    fn covariates(&self) -> Vec<String> {
        self.covs.clone()
    }
    fn n_linear(&self) -> usize {
        self.kind.n_linear()
    }
    fn theta(&self, frame: &Frame) -> Option<ThetaRange> {
        match self.kind {
            Kind::Drift => {
                let s = frame[0];
                // t_s counts from the run's start; the span is the latest time.
                let span = s.max.max(s.range()).max(1e-9);
                let (lo, hi) = (span * DRIFT_TAU_MIN_FRAC, span);
                Some(ThetaRange {
                    name: "tau_s".into(),
                    lo,
                    hi,
                    grid: log_grid(lo, hi, 40),
                    // Pooled at the bin mean, the error is second order:
                    // (τ/20)²/24τ² ≈ 1e-4 relative.
                    resolution: lo / 20.0,
                    refine_in_frequency: false,
                })
            }
            Kind::Edge => {
                let s = frame[0];
                let range = s.max.max(s.range()).max(1e-9);
                // Down to a third of the sample step: a pressure rise that
                // only the outermost sample sees is still an edge effect.
                let lo = (s.step / 3.0).max(range / 500.0).min(range);
                let hi = range;
                Some(ThetaRange {
                    name: "lambda_mm".into(),
                    lo,
                    hi,
                    grid: log_grid(lo, hi, 32),
                    resolution: lo / 20.0,
                    refine_in_frequency: false,
                })
            }
            Kind::Periodic => {
                let s = frame[0];
                let (lo, hi) = periodic_lambda_bounds(&s);
                let range = s.range().max(1e-300);
                // Uniform in frequency, a quarter cycle over the range apart.
                let (f_lo, f_hi) = (1.0 / hi, 1.0 / lo);
                let df = 0.25 / range;
                let n = (((f_hi - f_lo) / df).ceil() as usize).max(1);
                let mut grid: Vec<f64> = (0..=n)
                    .map(|i| 1.0 / (f_lo + (f_hi - f_lo) * i as f64 / n as f64))
                    .collect();
                grid.reverse();
                Some(ThetaRange {
                    name: "lambda".into(),
                    lo,
                    hi,
                    grid,
                    // phase error 2π·res/λ ≤ 0.1 rad
                    resolution: lo / 64.0,
                    refine_in_frequency: true,
                })
            }
            _ => None,
        }
    }

    fn features(
        &self,
        frame: &Frame,
        x: &EffectData,
        theta: f64,
        out: &mut [Vec<f64>],
    ) -> Result<()> {
        let n = x.len();
        for o in out.iter_mut() {
            o.resize(n, 0.0);
        }
        let k = self.kind;
        if k == Kind::Offset {
            return Ok(());
        }
        let c = x.require(&self.covs[0])?;
        let s = frame[0];
        match k {
            Kind::Offset => {}
            Kind::Scale
            | Kind::Lag
            | Kind::Inertia
            | Kind::Wear
            | Kind::Compliance
            | Kind::Thermal => {
                let (m, h) = s.mid_half();
                let inv = 1.0 / h;
                for (o, v) in out[0].iter_mut().zip(c) {
                    *o = (v - m) * inv;
                }
            }
            Kind::Backlash => {
                for (o, v) in out[0].iter_mut().zip(c) {
                    *o = 0.5 * v;
                }
            }
            Kind::Bow => {
                let (c0, c1) = (s.min, s.max);
                let d2 = (c1 - c0).powi(2).max(1e-300);
                for (o, v) in out[0].iter_mut().zip(c) {
                    *o = 4.0 * (v - c0) * (c1 - v) / d2;
                }
            }
            Kind::Drift => {
                let inv = 1.0 / theta;
                for (o, v) in out[0].iter_mut().zip(c) {
                    *o = 1.0 - (-v * inv).exp();
                }
            }
            Kind::Edge => {
                let inv = 1.0 / theta;
                for (o, v) in out[0].iter_mut().zip(c) {
                    *o = (-v * inv).exp();
                }
            }
            Kind::Periodic => {
                let w = 2.0 * PI / theta;
                let (a, b) = out.split_at_mut(1);
                for ((sn, cs), v) in a[0].iter_mut().zip(b[0].iter_mut()).zip(c) {
                    let (si, co) = (w * v).sin_cos();
                    *sn = si;
                    *cs = co;
                }
            }
            Kind::Squareness => {
                // k·c1·c2 exactly (no centring: centring would add linear
                // terms that are not part of the contract's form).
                let c2 = x.require(&self.covs[1])?;
                let s2 = frame[1];
                let inv = 1.0 / (s.max_abs.max(1e-300) * s2.max_abs.max(1e-300));
                for ((o, a), b) in out[0].iter_mut().zip(c).zip(c2) {
                    *o = a * b * inv;
                }
            }
        }
        Ok(())
    }

    fn params(
        &self,
        frame: &Frame,
        theta: f64,
        coef: &[f64],
        offset: f64,
    ) -> (BTreeMap<String, f64>, f64) {
        let mut p = BTreeMap::new();
        let mut off = offset;
        match self.kind {
            Kind::Offset => {
                p.insert("offset_mm".into(), offset);
            }
            Kind::Scale | Kind::Lag | Kind::Inertia | Kind::Wear | Kind::Compliance => {
                let (m, h) = frame[0].mid_half();
                let k = coef[0] / h;
                off -= k * m;
                p.insert("k".into(), k);
            }
            Kind::Thermal => {
                let (m, h) = frame[0].mid_half();
                let k = coef[0] / h;
                off -= k * m;
                off += k * THERMAL_T0_C;
                p.insert("k".into(), k);
                p.insert("t0_c".into(), THERMAL_T0_C);
            }
            Kind::Backlash => {
                p.insert("b_mm".into(), coef[0]);
            }
            Kind::Bow => {
                p.insert("amplitude_mm".into(), coef[0]);
                p.insert("c0".into(), frame[0].min);
                p.insert("c1".into(), frame[0].max);
            }
            Kind::Drift => {
                p.insert("amplitude_mm".into(), coef[0]);
                p.insert("tau_s".into(), theta);
            }
            Kind::Edge => {
                p.insert("k_mm".into(), coef[0]);
                p.insert("lambda_mm".into(), theta);
            }
            Kind::Periodic => {
                // a·sin + b·cos = A·sin(· + φ) with A cos φ = a, A sin φ = b.
                let (a, b) = (coef[0], coef[1]);
                p.insert("amplitude_mm".into(), a.hypot(b));
                p.insert("phase_rad".into(), b.atan2(a));
                p.insert("lambda".into(), theta);
            }
            Kind::Squareness => {
                let inv = frame[0].max_abs.max(1e-300) * frame[1].max_abs.max(1e-300);
                p.insert("k".into(), coef[0] / inv);
            }
        }
        (p, off)
    }
}

/// Evaluates a catalogue shape from contract parameters (the generator and
/// the augmented model use this; `frame` supplies bow's c0/c1 when the
/// parameters do not). Returns the value of `form(c; params)` per row.
pub fn shape_value(
    kind: Kind,
    params: &BTreeMap<String, f64>,
    c: &[f64],
    c2: Option<&[f64]>,
) -> Vec<f64> {
    let g = |k: &str, d: f64| params.get(k).copied().unwrap_or(d);
    let mut out = vec![0.0; c.len()];
    for (i, o) in out.iter_mut().enumerate() {
        let v = c.get(i).copied().unwrap_or(0.0);
        *o = match kind {
            Kind::Offset => g("offset_mm", 0.0),
            Kind::Scale | Kind::Lag | Kind::Inertia | Kind::Wear | Kind::Compliance => {
                g("k", 0.0) * v
            }
            Kind::Thermal => g("k", 0.0) * (v - g("t0_c", THERMAL_T0_C)),
            Kind::Backlash => g("b_mm", 0.0) * v / 2.0,
            Kind::Bow => {
                let (c0, c1) = (g("c0", 0.0), g("c1", 1.0));
                4.0 * g("amplitude_mm", 0.0) * (v - c0) * (c1 - v) / (c1 - c0).powi(2).max(1e-300)
            }
            Kind::Drift => g("amplitude_mm", 0.0) * (1.0 - (-v / g("tau_s", 1.0)).exp()),
            Kind::Edge => g("k_mm", 0.0) * (-v / g("lambda_mm", 1.0)).exp(),
            Kind::Periodic => {
                g("amplitude_mm", 0.0)
                    * (2.0 * PI * v / g("lambda", 1.0) + g("phase_rad", 0.0)).sin()
            }
            Kind::Squareness => g("k", 0.0) * v * c2.map(|c2| c2[i]).unwrap_or(0.0),
        };
    }
    out
}

/// A form wrapped as an [`Effect`] under a name.
pub struct FormEffect {
    name: String,
    n_params: usize,
    form: Arc<dyn LinearForm>,
}

impl FormEffect {
    pub fn new(name: &str, n_params: usize, form: Arc<dyn LinearForm>) -> Self {
        FormEffect {
            name: name.to_string(),
            n_params,
            form,
        }
    }
}

impl Effect for FormEffect {
    fn name(&self) -> &str {
        &self.name
    }
    fn covariates(&self) -> Vec<String> {
        self.form.covariates()
    }
    fn n_params(&self) -> usize {
        self.n_params
    }
    fn fit(&self, x: &EffectData, gap: &[f64]) -> Result<Box<dyn FittedEffect>> {
        let frame: Frame = self
            .form
            .covariates()
            .iter()
            .map(|c| x.require(c).map(CovStats::from_values))
            .collect::<Result<_>>()?;
        let f = fit::fit_form(self.form.as_ref(), &frame, x, gap)?;
        Ok(Box::new(FittedForm {
            form: self.form.clone(),
            frame,
            theta: f.theta,
            coef: f.coef,
            offset: f.offset,
        }))
    }
    fn linear_form(&self) -> Option<Arc<dyn LinearForm>> {
        Some(self.form.clone())
    }
}

/// A fitted [`LinearForm`]: θ, coefficients, offset and the frame they refer to.
pub struct FittedForm {
    pub form: Arc<dyn LinearForm>,
    pub frame: Frame,
    pub theta: f64,
    pub coef: Vec<f64>,
    pub offset: f64,
}

impl FittedEffect for FittedForm {
    fn params(&self) -> BTreeMap<String, f64> {
        self.form
            .params(&self.frame, self.theta, &self.coef, self.offset)
            .0
    }
    fn offset_mm(&self) -> f64 {
        self.form
            .params(&self.frame, self.theta, &self.coef, self.offset)
            .1
    }
    /// `form(c; params)` in the contract convention: the feature-space
    /// prediction minus the contract offset (features are standardised, so
    /// part of the feature-space offset belongs to the shape).
    fn predict(&self, x: &EffectData) -> Vec<f64> {
        let mut feats = vec![Vec::new(); self.form.n_linear()];
        let mut out = vec![self.offset - self.offset_mm(); x.len()];
        if self
            .form
            .features(&self.frame, x, self.theta, &mut feats)
            .is_ok()
        {
            for (f, b) in feats.iter().zip(&self.coef) {
                for (o, v) in out.iter_mut().zip(f) {
                    *o += b * v;
                }
            }
        }
        out
    }
}

/// The catalogue effect `kind` on `covs`.
pub fn catalogue_effect(kind: Kind, covs: &[&str]) -> Box<dyn Effect> {
    Box::new(FormEffect::new(
        kind.name(),
        kind.n_params(),
        Arc::new(Shape {
            kind,
            covs: covs.iter().map(|s| s.to_string()).collect(),
        }),
    ))
}

/// Covariate kinds as CONTRACTS.md reads them from names.
fn is_position(c: &str) -> bool {
    matches!(c, "x_mm" | "y_mm" | "z_mm" | "phi_rad")
}
fn is_time(c: &str) -> bool {
    c == "t_s"
}
fn is_speed(c: &str) -> bool {
    c.ends_with("_mm_s")
}
fn is_accel(c: &str) -> bool {
    c.ends_with("_mm_s2")
}
fn is_usage(c: &str) -> bool {
    c.ends_with("_mm3") || c == "pass" || c == "infeed_count"
}
fn is_load(c: &str) -> bool {
    c.ends_with("_n") || c == "nominal_doc_mm"
}

/// Which catalogue kinds apply to a covariate (single-covariate kinds).
pub fn kinds_for(c: &str) -> Vec<Kind> {
    let mut k = Vec::new();
    if is_position(c) {
        k.extend([Kind::Scale, Kind::Bow, Kind::Periodic]);
    }
    if is_time(c) {
        k.extend([Kind::Drift, Kind::Periodic]);
    }
    if is_speed(c) {
        k.push(Kind::Lag);
    }
    if is_accel(c) {
        k.push(Kind::Inertia);
    }
    if c == "dir" {
        k.push(Kind::Backlash);
    }
    if is_usage(c) {
        k.push(Kind::Wear);
    }
    if is_load(c) {
        k.push(Kind::Compliance);
    }
    if c == "path_end_mm" {
        k.push(Kind::Edge);
    }
    if c == "temp_c" {
        k.push(Kind::Thermal);
    }
    k
}

/// Every applicable catalogue candidate for the given covariate names
/// (CONTRACTS.md "Candidate effect names"): `offset`, then each covariate's
/// kinds in the order given, then `squareness` on every pair of positions.
pub fn catalogue(covariates: &[String]) -> Vec<Box<dyn Effect>> {
    let mut out = vec![catalogue_effect(Kind::Offset, &[])];
    for c in covariates {
        for k in kinds_for(c) {
            out.push(catalogue_effect(k, &[c.as_str()]));
        }
    }
    let pos: Vec<&String> = covariates.iter().filter(|c| is_position(c)).collect();
    for i in 0..pos.len() {
        for j in i + 1..pos.len() {
            out.push(catalogue_effect(
                Kind::Squareness,
                &[pos[i].as_str(), pos[j].as_str()],
            ));
        }
    }
    out
}

/// A catalogue (or any) effect under a physical name, e.g. the robot's
/// `trigger_latency` = `lag` on `approach_mm_s` (DESIGN.md point 2).
pub fn composite(name: &str, base: Box<dyn Effect>) -> Box<dyn Effect> {
    Box::new(Renamed {
        name: name.to_string(),
        base,
    })
}

struct Renamed {
    name: String,
    base: Box<dyn Effect>,
}

impl Effect for Renamed {
    fn name(&self) -> &str {
        &self.name
    }
    fn covariates(&self) -> Vec<String> {
        self.base.covariates()
    }
    fn n_params(&self) -> usize {
        self.base.n_params()
    }
    fn fit(&self, x: &EffectData, gap: &[f64]) -> Result<Box<dyn FittedEffect>> {
        self.base.fit(x, gap)
    }
    fn linear_form(&self) -> Option<Arc<dyn LinearForm>> {
        self.base.linear_form()
    }
    fn replaces(&self) -> Option<String> {
        Some(self.base.key())
    }
}

/// The product of two effects' shapes with one joint amplitude per pair of
/// features, e.g. the gantry's `thermal_bow` = bow(y_mm)·drift(t_s). Both
/// must be linear forms and at most one may have a nonlinear θ.
pub fn product(name: &str, a: Box<dyn Effect>, b: Box<dyn Effect>) -> Result<Box<dyn Effect>> {
    let (fa, fb) = match (a.linear_form(), b.linear_form()) {
        (Some(fa), Some(fb)) => (fa, fb),
        _ => bail!("product `{name}`: both factors must be linear forms"),
    };
    if fa.n_linear() == 0 || fb.n_linear() == 0 {
        bail!("product `{name}`: a factor has no shape (offset)");
    }
    let n_params = a.n_params() + b.n_params() - 1;
    Ok(Box::new(FormEffect::new(
        name,
        n_params,
        Arc::new(ProductForm { a: fa, b: fb }),
    )))
}

struct ProductForm {
    a: Arc<dyn LinearForm>,
    b: Arc<dyn LinearForm>,
}

impl ProductForm {
    fn split(&self, frame: &Frame) -> (Frame, Frame) {
        let na = self.a.covariates().len();
        (frame[..na].to_vec(), frame[na..].to_vec())
    }
    /// (θ of a, θ of b): θ belongs to whichever factor has one.
    fn thetas(&self, fa: &Frame, theta: f64) -> (f64, f64) {
        if self.a.theta(fa).is_some() {
            (theta, f64::NAN)
        } else {
            (f64::NAN, theta)
        }
    }
}

impl LinearForm for ProductForm {
    fn covariates(&self) -> Vec<String> {
        let mut c = self.a.covariates();
        c.extend(self.b.covariates());
        c
    }
    fn n_linear(&self) -> usize {
        self.a.n_linear() * self.b.n_linear()
    }
    fn theta(&self, frame: &Frame) -> Option<ThetaRange> {
        let (fa, fb) = self.split(frame);
        self.a
            .theta(&fa)
            .or_else(|| self.b.theta(&fb))
            .map(|mut t| {
                // Rows are not pooled for products: features depend on two covariates.
                t.resolution = 0.0;
                t
            })
    }
    fn features(
        &self,
        frame: &Frame,
        x: &EffectData,
        theta: f64,
        out: &mut [Vec<f64>],
    ) -> Result<()> {
        let (fa, fb) = self.split(frame);
        let (ta, tb) = self.thetas(&fa, theta);
        let mut va = vec![Vec::new(); self.a.n_linear()];
        let mut vb = vec![Vec::new(); self.b.n_linear()];
        self.a.features(&fa, x, ta, &mut va)?;
        self.b.features(&fb, x, tb, &mut vb)?;
        let mut j = 0;
        for ca in &va {
            for cb in &vb {
                out[j].clear();
                out[j].extend(ca.iter().zip(cb).map(|(p, q)| p * q));
                j += 1;
            }
        }
        Ok(())
    }
    fn params(
        &self,
        frame: &Frame,
        theta: f64,
        coef: &[f64],
        offset: f64,
    ) -> (BTreeMap<String, f64>, f64) {
        // Report the product's joint amplitudes and each factor's shape
        // parameters with a unit amplitude on the other factor.
        let (fa, fb) = self.split(frame);
        let (ta, tb) = self.thetas(&fa, theta);
        let ones_a = vec![1.0; self.a.n_linear()];
        let ones_b = vec![1.0; self.b.n_linear()];
        let (pa, _) = self.a.params(&fa, ta, &ones_a, 0.0);
        let (pb, _) = self.b.params(&fb, tb, &ones_b, 0.0);
        let mut p = BTreeMap::new();
        for (k, v) in pa {
            if v.is_finite() && !k.starts_with("amplitude") && k != "k" {
                p.insert(format!("a.{k}"), v);
            }
        }
        for (k, v) in pb {
            if v.is_finite() && !k.starts_with("amplitude") && k != "k" {
                p.insert(format!("b.{k}"), v);
            }
        }
        for (j, c) in coef.iter().enumerate() {
            p.insert(format!("coef{j}"), *c);
        }
        (p, offset)
    }
}

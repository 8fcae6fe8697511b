//! Candidate effects: the `Effect` trait (fit → fitted → predict, linfa
//! style), the v1 catalogue of docs/formats.md §7, "Candidate effects" and
//! the composites plugins register (docs/design.md §7,
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

use crate::{bail, err};

use crate::Result;

pub mod fit;
mod shape;
pub use shape::*;
mod catalogue;
pub use catalogue::*;
mod composite;
pub use composite::*;

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
            .ok_or_else(|| err!("effect needs covariate `{name}`, which the data lack"))
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
    /// Rows `r` of the columns `names` (views, nothing copied); an error
    /// names a covariate the data lack.
    pub fn rows_of(&self, names: &[String], r: std::ops::Range<usize>) -> Result<EffectData<'a>> {
        let mut d = EffectData::new(r.len());
        for c in names {
            d.push(c, &self.require(c)?[r.clone()]);
        }
        Ok(d)
    }
}

/// A candidate unmodelled effect. `fit` must fit the shape *together with a
/// free offset* (docs/design.md §7: "every shape is fitted together with an offset,
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
    /// Whether the effect is a candidate for `observable`: a plugin
    /// composite meant for one family of its plugin's observables says
    /// which ([`only_on`]); every other effect applies wherever its
    /// covariates are.
    fn applies_to(&self, _observable: &str) -> bool {
        true
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

/// The values ascending in the total order of `f64::total_cmp` (−0 before
/// +0, NaN last). Sorted as integers: the total order is the order of the
/// bit patterns with the sign bit flipped (and the rest too, for
/// negatives), which sorts about a third faster than comparing floats —
/// the diagnosis sorts every covariate of an observable (10⁷ rows each at
/// 10⁸ fleet rows). The same values, bit for bit, as `sort_by(total_cmp)`.
pub fn sorted_values(v: &[f64]) -> Vec<f64> {
    let mut k: Vec<u64> = v.iter().map(|&x| total_order_key(x)).collect();
    k.sort_unstable();
    k.into_iter().map(from_total_order_key).collect()
}

/// `x` as an integer whose unsigned order is `f64::total_cmp`'s: the bit
/// pattern with the sign bit flipped (and the rest too, for negatives).
pub fn total_order_key(x: f64) -> u64 {
    const SIGN: u64 = 1 << 63;
    let b = x.to_bits();
    if b & SIGN != 0 {
        !b
    } else {
        b | SIGN
    }
}

/// The inverse of [`total_order_key`].
pub fn from_total_order_key(k: u64) -> f64 {
    const SIGN: u64 = 1 << 63;
    f64::from_bits(if k & SIGN != 0 { k & !SIGN } else { !k })
}

/// Up to this many distinct values a covariate's constants are found from
/// a hash set of its values instead of sorting its column: a time base,
/// a commanded velocity, a direction or a few z levels repeat across the
/// runs of a fleet, and hashing 4.8·10⁶ rows into a set that stays in
/// cache costs a fraction of sorting them (docs/design.md §8).
const DISTINCT_HASHED_MAX: usize = 1 << 16;

/// The total-order keys of `v`'s distinct values (no order), or None as
/// soon as there are more than `max` of them (the caller sorts instead).
fn distinct_keys(v: &[f64], max: usize) -> Option<Vec<u64>> {
    let mut seen: std::collections::HashSet<u64, std::hash::BuildHasherDefault<KeyHasher>> =
        std::collections::HashSet::with_capacity_and_hasher(
            max.saturating_add(1).min(1024),
            Default::default(),
        );
    // A stretch of one value (a run's rows at one level) is looked up once.
    let mut last = None;
    for &x in v {
        let k = total_order_key(x);
        if last == Some(k) {
            continue;
        }
        last = Some(k);
        if seen.insert(k) && seen.len() > max {
            return None;
        }
    }
    Some(seen.into_iter().collect())
}

/// A 64-bit key's hash: the splitmix64 finaliser (every bit of the key
/// moves the bucket and the control byte; `std`'s default SipHash costs
/// several times more and guards against adversarial keys, which a
/// column of numbers cannot exploit beyond slowing itself down).
#[derive(Default)]
struct KeyHasher(u64);

impl std::hash::Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = self.0.rotate_left(8) ^ u64::from(b);
        }
    }
    fn write_u64(&mut self, k: u64) {
        self.0 = k;
    }
}

/// Data-dependent constants of one covariate, computed from covariate values
/// only (never from the gap), over all rows of an observable: the range that
/// bounds `bow` and `periodic`, and the typical sample step (the smallest
/// admissible wavelength is 3 sample steps, docs/formats.md §7 catalogue table).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CovStats {
    pub min: f64,
    pub max: f64,
    /// Median positive spacing of the sorted distinct values.
    pub step: f64,
    pub max_abs: f64,
    /// A covariate counted from each run's start (time, docs/formats.md):
    /// the largest range one run spans — a cycle longer than any run is
    /// never seen whole, however the runs' ranges lie against each other
    /// ([`periodic_lambda_bounds`]). None for covariates on a scale the
    /// runs share (positions), and where the runs are not known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub run_span: Option<f64>,
}

impl CovStats {
    pub fn from_values(v: &[f64]) -> CovStats {
        match distinct_keys(v, DISTINCT_HASHED_MAX) {
            Some(keys) => Self::from_distinct_keys(keys),
            None => Self::from_sorted(&sorted_values(v)),
        }
    }

    /// From the distinct values' total-order keys (any order). A column's
    /// constants depend only on its distinct values: its extremes, and the
    /// spacings between consecutive distinct values — the zero spacings
    /// between repeated values are never above the tolerance — so the same
    /// bits as sorting every row.
    fn from_distinct_keys(mut keys: Vec<u64>) -> CovStats {
        keys.sort_unstable();
        let values: Vec<f64> = keys.into_iter().map(from_total_order_key).collect();
        Self::from_sorted(&values)
    }
    /// From values the caller no longer needs in their order: sorted in
    /// place, and the spacings written over the sorted values as they are
    /// read — no copy of the column (an observable's covariates read from
    /// a file one at a time, docs/design.md §8). The same bits as
    /// [`CovStats::from_values`].
    pub fn from_values_in_place(v: &mut [f64]) -> CovStats {
        if let Some(keys) = distinct_keys(v, DISTINCT_HASHED_MAX) {
            return Self::from_distinct_keys(keys);
        }
        for x in v.iter_mut() {
            *x = f64::from_bits(total_order_key(*x));
        }
        // Sorted as the integers `sorted_values` sorts.
        v.sort_unstable_by_key(|x| x.to_bits());
        for x in v.iter_mut() {
            *x = from_total_order_key(x.to_bits());
        }
        if v.is_empty() {
            return Self::from_sorted(v);
        }
        let (min, max) = (v[0], v[v.len() - 1]);
        let tol = 1e-12 * (max - min).abs().max(1e-300);
        // Spacing i is written at m ≤ i after values i and i + 1 are read.
        let mut m = 0;
        for i in 0..v.len() - 1 {
            let d = v[i + 1] - v[i];
            if d > tol {
                v[m] = d;
                m += 1;
            }
        }
        Self::with_steps(min, max, &mut v[..m])
    }

    /// The constants of values from `min` to `max` whose positive
    /// spacings are `steps` (reordered).
    fn with_steps(min: f64, max: f64, steps: &mut [f64]) -> CovStats {
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
            run_span: None,
        }
    }

    /// From ascending values (the engine sorts each covariate once).
    pub fn from_sorted(s: &[f64]) -> CovStats {
        if s.is_empty() {
            return CovStats {
                min: 0.0,
                max: 0.0,
                step: 0.0,
                max_abs: 0.0,
                run_span: None,
            };
        }
        let (min, max) = (s[0], s[s.len() - 1]);
        let tol = 1e-12 * (max - min).abs().max(1e-300);
        let mut steps: Vec<f64> = s
            .windows(2)
            .map(|w| w[1] - w[0])
            .filter(|d| *d > tol)
            .collect();
        Self::with_steps(min, max, &mut steps)
    }
    pub fn range(&self) -> f64 {
        self.max - self.min
    }
    /// These constants with `run_span` (see [`run_span_of`]).
    pub fn with_run_span(self, run_span: Option<f64>) -> CovStats {
        CovStats { run_span, ..self }
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

/// Reported parameters (contract units) and the offset in the convention
/// `offset_mm + form(c; params)`.
pub type ParamsAndOffset = (BTreeMap<String, f64>, f64);

/// Feature columns, `out[j][i]` = feature j at row i.
pub type Columns = [Vec<f64>];

thread_local! {
    /// Feature columns kept for reuse by this thread (see [`with_columns`]).
    static SPARE_COLUMNS: std::cell::RefCell<Vec<Vec<f64>>> =
        const { std::cell::RefCell::new(Vec::new()) };
}

/// Columns longer than this (values) are not kept for reuse.
pub const SPARE_COLUMN_MAX: usize = 1 << 18;

/// Runs `f` on `n` empty feature columns that keep the capacity of this
/// thread's earlier calls: features are computed once per candidate, unit
/// and θ value tried, and a fresh vector each time was allocator work (and
/// above 32 MiB fresh pages from the kernel, `alloc.rs`). Columns longer
/// than [`SPARE_COLUMN_MAX`] values (2 MiB) go back to the allocator
/// instead: the diagnosis computes features one unit or one set of pooled
/// cells at a time, and a thread's spare columns of a large set of cells,
/// kept for the rest of the night, were ≈ 10 % of a fleet diagnosis' heap
/// peak while other steps allocated their own. Re-entrant: a nested call
/// takes its own columns.
pub fn with_columns<T>(n: usize, f: impl FnOnce(&mut Columns) -> T) -> T {
    let mut cols: Vec<Vec<f64>> = SPARE_COLUMNS.with(|s| {
        let mut spare = s.borrow_mut();
        let keep = spare.len().saturating_sub(n);
        spare.split_off(keep)
    });
    cols.resize_with(n, Vec::new);
    for c in cols.iter_mut() {
        c.clear();
    }
    let out = f(&mut cols);
    SPARE_COLUMNS.with(|s| {
        s.borrow_mut().extend(
            cols.into_iter()
                .filter(|c| c.capacity() <= SPARE_COLUMN_MAX),
        )
    });
    out
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
    fn features(&self, frame: &Frame, x: &EffectData, theta: f64, out: &mut Columns) -> Result<()>;
    /// The features at every θ of `grid`, in order, each handed to `each`
    /// (the coarse θ scan). The default computes each θ from scratch
    /// ([`features_each`]); a form whose features advance cheaply from one
    /// grid value to the next overrides it (periodic: one rotation per row).
    fn features_grid(
        &self,
        frame: &Frame,
        x: &EffectData,
        grid: &[f64],
        out: &mut Columns,
        each: &mut dyn FnMut(usize, &Columns) -> Result<()>,
    ) -> Result<()> {
        features_each(self, frame, x, grid, out, each)
    }
    /// Covariate widths (one per covariate, in `covariates()` order) within
    /// which rows may be pooled at their mean without changing a feature
    /// by more than ~1 % (the θ scan and the CV folds' fits,
    /// `fit::scan_rows`); `None`: never pool (the default — a form must
    /// know its features are smooth at that width).
    fn pool_resolutions(&self, _frame: &Frame) -> Option<Vec<f64>> {
        None
    }
    /// Reported parameters (contract units) from θ, the feature
    /// coefficients and the fitted offset; returns the parameters and the
    /// offset in the convention `offset_mm + form(c; params)`.
    fn params(&self, frame: &Frame, theta: f64, coef: &[f64], offset: f64) -> ParamsAndOffset;
    /// The catalogue forms it is built from, each on its covariates (one
    /// for a catalogue shape, two for a product), so a fit can be replayed
    /// outside the diagnosis ([`rebuild_linear_form`]); empty for a form
    /// that is not built from the catalogue.
    fn factors(&self) -> Vec<(Kind, Vec<String>)> {
        Vec::new()
    }
}

/// [`LinearForm::features_grid`] by [`LinearForm::features`] at each θ.
pub fn features_each<F: LinearForm + ?Sized>(
    form: &F,
    frame: &Frame,
    x: &EffectData,
    grid: &[f64],
    out: &mut Columns,
    each: &mut dyn FnMut(usize, &Columns) -> Result<()>,
) -> Result<()> {
    for (gi, &theta) in grid.iter().enumerate() {
        form.features(frame, x, theta, out)?;
        each(gi, out)?;
    }
    Ok(())
}

/// The linear form of `factors` (as [`LinearForm::factors`] lists them):
/// a catalogue shape, or the product of two. None for any other list.
pub fn rebuild_linear_form(factors: &[(Kind, Vec<String>)]) -> Option<Arc<dyn LinearForm>> {
    let effect = |(k, c): &(Kind, Vec<String>)| {
        let covs: Vec<&str> = c.iter().map(String::as_str).collect();
        catalogue_effect(*k, &covs)
    };
    match factors {
        [one] => effect(one).linear_form(),
        [a, b] => product("replay", effect(a), effect(b)).ok()?.linear_form(),
        _ => None,
    }
}

/// The v1 catalogue kinds (docs/formats.md §7 table).
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

/// The largest range one run spans of the covariate `name` whose column
/// `v` is in run order with runs `runs`, when it counts from each run's
/// start (its unit is a time, docs/formats.md "Time"); None for a
/// covariate on a scale the runs share (positions, speeds, volumes).
pub fn run_span_of(name: &str, v: &[f64], runs: &[std::ops::Range<usize>]) -> Option<f64> {
    use crate::units::format::{covariate_unit, Dims, ParamUnit};
    if covariate_unit(name) != ParamUnit::of(Dims::time()) {
        return None;
    }
    let span = |r: &std::ops::Range<usize>| min_max(&v[r.clone()]).map_or(0.0, |(lo, hi)| hi - lo);
    Some(runs.iter().map(span).fold(0.0, f64::max))
}

/// The smallest and largest non-NaN value of `v`; None when it has none.
pub fn min_max(v: &[f64]) -> Option<(f64, f64)> {
    let (lo, hi) = v
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
            (lo.min(*x), hi.max(*x))
        });
    (hi >= lo).then_some((lo, hi))
}

/// Periodic λ bounds: from max(3 sample steps, range/64) to the covariate
/// range (docs/formats.md: at least one whole cycle inside the data, so
/// periodic cannot impersonate scale or bow) — for a covariate counted
/// from each run's start, to the largest span of one run (docs/models.md
/// §8.4): runs that start their passes at two offsets a λ apart would
/// otherwise let a part of one cycle, the same in every run, follow any
/// smooth trend of the pass order.
pub fn periodic_lambda_bounds(s: &CovStats) -> (f64, f64) {
    let range = s.range();
    let hi = s.run_span.map_or(range, |r| r.min(range));
    let lo = (3.0 * s.step).max(range / PERIODIC_MAX_CYCLES);
    (lo.min(hi), hi)
}

#[cfg(test)]
mod with_columns_tests {
    use super::with_columns;

    #[test]
    fn columns_come_back_empty_with_their_capacity_and_nest() {
        let first = with_columns(2, |c| {
            c[0].extend([1.0; 1000]);
            c[0].as_ptr() as usize
        });
        with_columns(2, |c| {
            assert!(c.iter().all(|v| v.is_empty()), "handed out dirty");
            assert!(c.iter().any(|v| v.capacity() >= 1000), "capacity not kept");
            let outer: Vec<usize> = c.iter().map(|v| v.as_ptr() as usize).collect();
            assert!(outer.contains(&first));
            // A nested call (a product of forms) gets columns of its own.
            with_columns(3, |d| {
                assert_eq!(d.len(), 3);
                assert!(d
                    .iter()
                    .all(|v| !outer.contains(&(v.as_ptr() as usize)) || v.capacity() == 0));
            });
        });
    }

    /// A column longer than `SPARE_COLUMN_MAX` goes back to the allocator,
    /// not to this thread's spares (run on a thread of its own: the
    /// spares are per thread).
    #[test]
    fn a_long_column_is_not_kept() {
        std::thread::spawn(|| {
            with_columns(2, |c| {
                c[0].resize(super::SPARE_COLUMN_MAX + 1, 0.0);
                c[1].resize(100, 0.0);
            });
            with_columns(2, |c| {
                let caps: Vec<usize> = c.iter().map(|v| v.capacity()).collect();
                assert!(
                    caps.iter().all(|&n| n <= super::SPARE_COLUMN_MAX),
                    "{caps:?}"
                );
                assert!(
                    caps.iter().any(|&n| n >= 100),
                    "the short one is kept: {caps:?}"
                );
            });
        })
        .join()
        .unwrap();
    }
}

#[cfg(test)]
mod sorted_tests {
    /// Sorting as integers gives `total_cmp`'s order bit for bit: signed
    /// zeros, subnormals, infinities, NaN of both signs, ties.
    #[test]
    fn sorted_values_are_total_cmp_sorted() {
        let mut v = vec![
            3.5,
            -0.0,
            0.0,
            f64::MIN_POSITIVE / 4.0,
            -f64::MIN_POSITIVE / 4.0,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            -f64::NAN,
            -2.0,
            -2.0,
            1e300,
            -1e-300,
        ];
        v.extend((0..1000).map(|i| ((i * 7919) % 1009) as f64 * 0.37 - 150.0));
        let mut want = v.clone();
        want.sort_by(f64::total_cmp);
        let bits = |s: &[f64]| s.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&super::sorted_values(&v)), bits(&want));
    }

    #[test]
    fn stats_in_place_are_the_stats_of_a_sorted_copy() {
        let wavy: Vec<f64> = (0..5000)
            .map(|i| ((i * 7919) % 1013) as f64 * 0.013 - 4.0 + (i as f64 * 0.7).sin())
            .collect();
        let steps: Vec<f64> = (0..3000).map(|i| (i % 37) as f64 * 0.25).collect();
        // More distinct values than the hash set takes: sorted.
        let many: Vec<f64> = (0..super::DISTINCT_HASHED_MAX + 7)
            .map(|i| ((i * 7919) % 70_001) as f64 * 1e-3 - 20.0)
            .collect();
        let nan = vec![1.0, f64::NAN, -2.0, 1.0, -f64::NAN, 0.25];
        let bits = |s: super::CovStats| [s.min, s.max, s.step, s.max_abs].map(|x| x.to_bits());
        for v in [
            Vec::new(),
            vec![2.5],
            vec![1.0; 9],
            vec![3.0, -1.0, 3.0, 0.5, -0.0, 0.0],
            wavy,
            steps,
            many,
            nan,
        ] {
            // The definition: every value sorted.
            let want = bits(super::CovStats::from_sorted(&super::sorted_values(&v)));
            assert_eq!(bits(super::CovStats::from_values(&v)), want, "{v:?}");
            let got = super::CovStats::from_values_in_place(&mut v.clone());
            assert_eq!(bits(got), want, "{v:?}");
            // The hash set's stats whatever its bound: the distinct
            // values alone, or none past the bound.
            for max in [0, 1, 3, 1000, usize::MAX] {
                match super::distinct_keys(&v, max) {
                    Some(keys) => {
                        assert!(keys.len() <= max);
                        assert_eq!(bits(super::CovStats::from_distinct_keys(keys)), want);
                    }
                    None => {
                        let mut all: Vec<u64> =
                            v.iter().map(|&x| super::total_order_key(x)).collect();
                        all.sort_unstable();
                        all.dedup();
                        assert!(all.len() > max, "{max}: {} distinct", all.len());
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod run_span_tests {
    use super::{periodic_lambda_bounds, run_span_of, CovStats};

    #[test]
    fn time_spans_runs_and_bounds_the_periodic_wavelength() {
        // Two runs: 0..100 s and 500..580 s of their own clocks.
        let t = [0.0, 50.0, 100.0, 500.0, 540.0, 580.0];
        let runs = [0..3, 3..6];
        assert_eq!(run_span_of("t_s", &t, &runs), Some(100.0));
        // A position is on the machine's scale, shared by the runs.
        assert_eq!(run_span_of("x_mm", &t, &runs), None);
        let st = CovStats::from_values(&t);
        assert_eq!(periodic_lambda_bounds(&st).1, 580.0);
        let spanned = st.with_run_span(run_span_of("t_s", &t, &runs));
        assert_eq!(periodic_lambda_bounds(&spanned).1, 100.0);
        // Never above the range, never below the lower bound.
        let short = st.with_run_span(Some(1e-9));
        let (lo, hi) = periodic_lambda_bounds(&short);
        assert!(lo <= hi && hi == 1e-9, "{lo} {hi}");
    }
}

//! Cross-validating one candidate: per-fold targets, the fast path for
//! linear forms (sufficient statistics, θ scanned per fold), the slow path
//! (refit per fold) for plugin effects, and each fold's prediction and
//! parameters.

use super::*;
use crate::effect::{LinearForm, ThetaRange};

/// The folds' current targets (fold k = all runs): the gap less, fold by
/// fold, each chosen effect's fit of that fold — recomputed for the rows a
/// pass reads (`chunk`) from the fits, not kept as a column per fold
/// (docs/design.md §8: a few numbers per fold, not 8 B a row each), unless
/// the columns fit in [`TARGET_COLUMNS_MAX_BYTES`]. The
/// same subtractions in the same order as taking each effect out of a
/// target column, so the same bits.
pub struct Targets<'a> {
    gap: &'a [f64],
    taken: Vec<TakenFit>,
    /// The distinct target each fold fits (all the gap before any effect
    /// is chosen; each fold its own after).
    of_fold: Vec<usize>,
    /// A fold whose target each distinct target is.
    fold_of: Vec<usize>,
    /// Every fold's target as a column, when they fit in
    /// [`TARGET_COLUMNS_MAX_BYTES`] (after an effect is taken out).
    columns: Option<Vec<Vec<f64>>>,
}

/// Up to this many bytes (rows × (k + 1) folds × 8 B) the folds' targets
/// are also kept as columns, each chosen effect's prediction subtracted
/// once when it is taken out; a larger observable's are recomputed from
/// the fits for each pass (twice a round), so its
/// memory is bounded by the fits, not by its rows. The same bits either
/// way: the same subtractions in the same order. A budget like any
/// batch engine's: a small observable keeps the speed, a large one the
/// memory (a chosen effect with an exponential or a sine costs its
/// features again on every pass — docs/design.md §8).
pub const TARGET_COLUMNS_MAX_BYTES: usize = 64 << 20;

/// The budget in force: [`TARGET_COLUMNS_MAX_BYTES`], or
/// `SPARKOUT_TARGET_COLUMNS_MAX_BYTES` (bytes; 0 recomputes always) — for
/// a night short of memory, and to run both ways in a test. It moves time
/// and memory, never a result.
fn target_columns_budget() -> usize {
    static BUDGET: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    *BUDGET.get_or_init(|| {
        crate::covariates::byte_budget(
            "SPARKOUT_TARGET_COLUMNS_MAX_BYTES",
            TARGET_COLUMNS_MAX_BYTES,
        )
    })
}

/// A chosen effect's fits, one per fold, as the targets take them out.
enum TakenFit {
    /// A linear form's θ and coefficients per fold: predicted row by row
    /// from the rows' own covariates.
    Linear {
        form: Arc<dyn LinearForm>,
        frame: Frame,
        theta: Vec<f64>,
        beta: Vec<Vec<f64>>,
    },
    /// A plugin's fitted effect, which predicts the rows it is given with
    /// no promise that a row's value is its own alone: each fold's
    /// prediction of every row, computed once over all rows.
    Predicted(Vec<Vec<f64>>),
}

impl TakenFit {
    fn of(e: &dyn Effect, prob: &Problem, ev: &CandEval) -> Result<TakenFit> {
        Ok(match &ev.fit {
            CandFit::Fast { theta, beta } => TakenFit::Linear {
                form: e.linear_form().expect("fast fit has a form"),
                frame: prob.frame(e)?,
                theta: theta.clone(),
                beta: beta.clone(),
            },
            CandFit::Slow { .. } => TakenFit::Predicted(
                (0..=prob.k)
                    .map(|f| {
                        let mut pred = Vec::new();
                        let x = prob.x.columns(&e.covariates())?;
                        fold_prediction(e, prob, ev, f, &x.data(), &mut pred)?;
                        Ok(pred)
                    })
                    .collect::<Result<_>>()?,
            ),
        })
    }

    /// The covariates its predictions read.
    fn covariates(&self) -> Vec<String> {
        match self {
            TakenFit::Linear { form, .. } => form.covariates(),
            TakenFit::Predicted(_) => Vec::new(),
        }
    }

    /// Fold `f`'s prediction (offset included) of the observable's rows
    /// `rows`, whose covariates are `x`, into `pred`.
    fn predict(
        &self,
        x: &EffectData,
        f: usize,
        rows: Range<usize>,
        pred: &mut Vec<f64>,
    ) -> Result<()> {
        match self {
            TakenFit::Linear {
                form,
                frame,
                theta,
                beta,
            } => {
                let fit = FoldFit::Linear {
                    form: form.clone(),
                    frame: frame.clone(),
                    theta: theta[f],
                    beta: &beta[f],
                };
                debug_assert_eq!(x.len(), rows.len(), "the rows' covariates");
                fit.predict(x, pred)
            }
            TakenFit::Predicted(p) => {
                pred.clear();
                pred.extend_from_slice(&p[f][rows]);
                Ok(())
            }
        }
    }
}

impl<'a> Targets<'a> {
    /// Every fold's target before any effect is chosen: the gap.
    pub fn gap(prob: &Problem<'a>) -> Targets<'a> {
        Targets::with(prob, Vec::new(), None)
    }

    fn with(
        prob: &Problem<'a>,
        taken: Vec<TakenFit>,
        columns: Option<Vec<Vec<f64>>>,
    ) -> Targets<'a> {
        let nf = prob.k + 1;
        let (of_fold, fold_of) = if taken.is_empty() {
            (vec![0; nf], vec![0])
        } else {
            ((0..nf).collect(), (0..nf).collect())
        };
        Targets {
            gap: prob.gap,
            taken,
            of_fold,
            fold_of,
            columns,
        }
    }

    /// These targets with `e`'s fits (`ev`) taken out of every fold's.
    pub fn taking_out(
        self,
        prob: &Problem<'a>,
        e: &dyn Effect,
        ev: &CandEval,
    ) -> Result<Targets<'a>> {
        self.taking_out_within(prob, e, ev, target_columns_budget())
    }

    /// [`Targets::taking_out`] with the folds' target columns kept up to
    /// `max_column_bytes`.
    fn taking_out_within(
        mut self,
        prob: &Problem<'a>,
        e: &dyn Effect,
        ev: &CandEval,
        max_column_bytes: usize,
    ) -> Result<Targets<'a>> {
        let fit = TakenFit::of(e, prob, ev)?;
        let nf = prob.k + 1;
        let columns = if self.gap.len() * nf * 8 <= max_column_bytes {
            // Each fold's column less this fold's prediction, unit by unit.
            let mut columns = match self.columns.take() {
                Some(columns) => columns,
                None => vec![self.gap.to_vec(); nf],
            };
            // A chunk of units' covariates read once for every fold.
            let names = fit.covariates();
            for units in consecutive_units(prob, CHUNK_ROWS) {
                let (span, local) = rows_of_units(prob, units.clone());
                let xs = prob.x.rows_of(&names, span)?;
                let xd = xs.data();
                columns
                    .par_iter_mut()
                    .enumerate()
                    .try_for_each(|(f, col)| -> Result<()> {
                        let mut pred = Vec::new();
                        for (r, l) in prob.units[units.clone()].iter().zip(&local) {
                            fit.predict(&xd.rows_of(&names, l.clone())?, f, r.clone(), &mut pred)?;
                            col[r.clone()]
                                .iter_mut()
                                .zip(&pred)
                                .for_each(|(y, p)| *y -= p);
                        }
                        Ok(())
                    })?;
            }
            Some(columns)
        } else {
            None
        };
        self.taken.push(fit);
        Ok(Targets::with(prob, self.taken, columns))
    }

    /// How many distinct targets the folds fit.
    pub fn n_distinct(&self) -> usize {
        self.fold_of.len()
    }

    /// The distinct targets over the rows of `units` (their rows one after
    /// another): each the gap less its fold's fit of every chosen effect,
    /// in the order they were chosen.
    /// `names`: the covariates the chunk carries besides the chosen
    /// effects' (those its readers need).
    pub fn chunk<'x>(
        &self,
        prob: &Problem<'x>,
        units: Vec<usize>,
        names: &[String],
    ) -> Result<Chunk<'x>> {
        let mut names = names.to_vec();
        names.extend(self.taken_covariates());
        names.sort();
        names.dedup();
        self.chunk_of_folds(prob, units, &self.fold_of, &names)
    }

    /// The covariates the chosen effects' predictions read.
    fn taken_covariates(&self) -> Vec<String> {
        let mut names: Vec<String> = self.taken.iter().flat_map(|t| t.covariates()).collect();
        names.sort();
        names.dedup();
        names
    }

    /// The targets of `folds` over the rows of `units`, with the
    /// covariates `names` of those rows (a superset of the chosen
    /// effects').
    fn chunk_of_folds<'x>(
        &self,
        prob: &Problem<'x>,
        units: Vec<usize>,
        folds: &[usize],
        names: &[String],
    ) -> Result<Chunk<'x>> {
        let mut local = Vec::with_capacity(units.len());
        let mut n = 0;
        for &u in &units {
            local.push(n..n + prob.units[u].len());
            n += prob.units[u].len();
        }
        let ranges: Vec<Range<usize>> = units.iter().map(|&u| prob.units[u].clone()).collect();
        let (x, x_local) = prob.x.rows_in_place(names, &ranges)?;
        let taken_names = self.taken_covariates();
        let xd = x.data();
        let targets = folds
            .par_iter()
            .map(|&f| -> Result<Vec<f64>> {
                let mut t = Vec::with_capacity(n);
                if let Some(columns) = &self.columns {
                    for &u in &units {
                        t.extend_from_slice(&columns[f][prob.units[u].clone()]);
                    }
                    return Ok(t);
                }
                let mut pred = Vec::new();
                for (&u, xl) in units.iter().zip(&x_local) {
                    let (rows, at) = (prob.units[u].clone(), t.len());
                    t.extend_from_slice(&self.gap[rows.clone()]);
                    if self.taken.is_empty() {
                        continue;
                    }
                    let xu = xd.rows_of(&taken_names, xl.clone())?;
                    for fit in &self.taken {
                        fit.predict(&xu, f, rows.clone(), &mut pred)?;
                        t[at..].iter_mut().zip(&pred).for_each(|(y, p)| *y -= p);
                    }
                }
                Ok(t)
            })
            .collect::<Result<_>>()?;
        drop(xd);
        Ok(Chunk {
            units,
            local,
            targets,
            x,
            x_local,
        })
    }

    /// Fold `f`'s target over every row (a plugin effect's refit and a
    /// form not pooled on cells read the whole column).
    fn column(&self, prob: &Problem, f: usize) -> Result<Vec<f64>> {
        let names = self.taken_covariates();
        let mut c = self.chunk_of_folds(prob, (0..prob.units.len()).collect(), &[f], &names)?;
        Ok(c.targets.pop().expect("one target"))
    }
}

/// The units, in order, cut into runs of consecutive units of at most
/// `max_rows` rows (a unit longer than that on its own).
fn consecutive_units(prob: &Problem, max_rows: usize) -> Vec<Range<usize>> {
    cut_units(prob, &(0..prob.units.len()).collect::<Vec<_>>(), max_rows)
        .into_iter()
        .map(|us| us[0]..us[us.len() - 1] + 1)
        .collect()
}

/// The rows of the consecutive units `units`, and each unit's rows within
/// them.
fn rows_of_units(prob: &Problem, units: Range<usize>) -> (Range<usize>, Vec<Range<usize>>) {
    let span = prob.units[units.start].start..prob.units[units.end - 1].end;
    let local = prob.units[units]
        .iter()
        .map(|r| r.start - span.start..r.end - span.start)
        .collect();
    (span, local)
}

/// `e`'s held-out contribution per row: each unit predicted by the fold
/// that holds it out (`ev`'s fits).
pub fn held_out_contribution(prob: &Problem, e: &dyn Effect, ev: &CandEval) -> Result<Vec<f64>> {
    let fit = TakenFit::of(e, prob, ev)?;
    let names = fit.covariates();
    let mut contrib = Vec::with_capacity(prob.x.len());
    for units in consecutive_units(prob, CHUNK_ROWS) {
        let (span, local) = rows_of_units(prob, units.clone());
        let xs = prob.x.rows_of(&names, span)?;
        let xd = xs.data();
        let preds: Vec<Vec<f64>> = units
            .zip(local)
            .collect::<Vec<_>>()
            .into_par_iter()
            .map(|(u, l)| -> Result<Vec<f64>> {
                let mut pred = Vec::new();
                let x = xd.rows_of(&names, l)?;
                fit.predict(&x, prob.unit_fold[u], prob.units[u].clone(), &mut pred)?;
                Ok(pred)
            })
            .collect::<Result<_>>()?;
        preds.iter().for_each(|p| contrib.extend_from_slice(p));
    }
    Ok(contrib)
}

/// `units` (ascending) cut into lists of at most `max_rows` rows (a unit
/// longer than that in a list of its own).
fn cut_units(prob: &Problem, units: &[usize], max_rows: usize) -> Vec<Vec<usize>> {
    let mut out: Vec<Vec<usize>> = Vec::new();
    let mut rows = 0;
    for &u in units {
        let n = prob.units[u].len();
        match out.last_mut() {
            Some(last) if rows + n <= max_rows => {
                last.push(u);
                rows += n;
            }
            _ => {
                out.push(vec![u]);
                rows = n;
            }
        }
    }
    out
}

/// A candidate's cross-validated fit.
pub enum CandFit {
    /// θ and [offset, coefs…] per fold (k + 1 entries).
    Fast {
        theta: Vec<f64>,
        beta: Vec<Vec<f64>>,
    },
    /// A plugin effect without a linear form: one fitted effect per fold.
    Slow { fitted: Vec<Box<dyn FittedEffect>> },
}

pub struct CandEval {
    pub fit: CandFit,
    /// Held-out SSE per unit.
    pub unit_sse: Vec<f64>,
}

/// How much finer than a form's θ-scan resolution the CV folds' training
/// rows are pooled: a feature changes by well under 1 % inside a bin.
const TRAIN_POOL_FINER: f64 = 8.0;

/// Rows a pass over the observable takes at a time: the unit of what a
/// node reads of a run's rows (several runs fit in one chunk).
const CHUNK_ROWS: usize = 1 << 18;

/// Scoring units as a pass over the observable reads them
/// (docs/design.md §8): their targets, computed for their rows. A unit's
/// covariates are its rows of the observable's columns.
pub struct Chunk<'x> {
    /// The units, ascending.
    pub units: Vec<usize>,
    /// Each unit's rows within `targets`, one after another.
    pub local: Vec<Range<usize>>,
    /// Each distinct target of [`Targets`] over the units' rows.
    pub targets: Vec<Vec<f64>>,
    /// The covariates of the units' rows, read once for every candidate:
    /// views of the columns in memory, the rows one after another (as
    /// `targets`) from a file ([`crate::covariates::Covariates::rows_in_place`]).
    pub x: CovRows<'x>,
    /// Each unit's rows within `x`.
    pub x_local: Vec<Range<usize>>,
}

impl Chunk<'_> {
    /// Each of its units' Σy² of every distinct target, into `yy_u`
    /// (per target, per unit).
    fn sum_squares(&self, yy_u: &mut [Vec<f64>]) {
        for (yy, t) in yy_u.iter_mut().zip(&self.targets) {
            for (&u, l) in self.units.iter().zip(&self.local) {
                yy[u] = dot(&t[l.clone()], &t[l.clone()]);
            }
        }
    }

    /// Each of its units' Σy of every target (per unit, per target; the
    /// bits of `iter().sum()`): what every candidate's X'y of the unit
    /// starts with, summed once for all of them.
    fn unit_sums(&self) -> Vec<Vec<f64>> {
        let mut cols = Vec::with_capacity(self.targets.len());
        self.local
            .iter()
            .map(|l| {
                cols.clear();
                cols.extend(self.targets.iter().map(|t| &t[l.clone()]));
                fit::sums_in_order(&cols)
            })
            .collect()
    }
}

/// Cross-validates candidates against the current targets (in parallel):
/// the cell pass reading a chunk of units once for every candidate (fold
/// group after fold group), each candidate's θ fit, then the score pass
/// reading a chunk once for every candidate. Each candidate's result (a
/// failed fit is an error of its own) and its time in seconds.
pub fn evaluate_all(
    cands: &[&dyn Effect],
    prob: &Problem,
    tg: &Targets,
) -> Vec<(Result<CandEval>, f64)> {
    evaluate_all_in_chunks(cands, prob, tg, CHUNK_ROWS, CHUNK_ROWS)
}

/// [`evaluate_all`] with its cell pass over the rows in chunks of
/// `cell_rows` and its score pass in chunks of `score_rows`: the same bits
/// for any chunk sizes.
pub(super) fn evaluate_all_in_chunks(
    cands: &[&dyn Effect],
    prob: &Problem,
    tg: &Targets,
    cell_rows: usize,
    score_rows: usize,
) -> Vec<(Result<CandEval>, f64)> {
    /// A candidate's state between passes and its time so far.
    enum Cv {
        Form(Box<FormCv>),
        /// Fitted on rows when the passes are done (no linear form).
        Slow,
        Failed(crate::Error),
    }
    let timed = |secs: &mut f64, f: &mut dyn FnMut()| {
        let t = std::time::Instant::now();
        f();
        *secs += t.elapsed().as_secs_f64();
    };
    let masks = prob.train_masks();
    let groups = fit::fold_groups(&masks, prob.units.len());
    let mut wall = crate::clock::StepClock::new("round passes".into());
    // The covariates a chunk carries: the candidates' (read from a file,
    // a chunk of every covariate would be read for nothing).
    let mut read: Vec<String> = cands.iter().flat_map(|e| e.covariates()).collect();
    read.sort();
    read.dedup();
    // Each unit's Σy² of every distinct target, taken in the first pass
    // that reads every unit (the targets are computed once a pass).
    let mut yy_u = vec![vec![f64::NAN; prob.units.len()]; tg.n_distinct()];
    let mut yy_done = false;
    let mut cvs: Vec<(Cv, f64)> = cands
        .par_iter()
        .map(|e| {
            let mut secs = 0.0;
            let mut cv = Cv::Slow;
            timed(&mut secs, &mut || {
                cv = match FormCv::new(*e, prob, tg, &groups) {
                    Ok(Some(f)) => Cv::Form(Box::new(f)),
                    Ok(None) => Cv::Slow,
                    Err(e) => Cv::Failed(e),
                }
            });
            (cv, secs)
        })
        .collect();
    wall.lap("new");
    // A pass that cannot compute a chunk's targets fails every candidate
    // it feeds.
    let fail_forms = |cvs: &mut Vec<(Cv, f64)>, e: crate::Error| {
        let why = e.to_string();
        for (cv, _) in cvs.iter_mut() {
            if matches!(cv, Cv::Form(_)) {
                *cv = Cv::Failed(err!("{why}"));
            }
        }
    };
    // The cell pass: the fold groups one after another (a candidate's
    // cells then hold one open group besides the sealed ones), each
    // group's units a chunk at a time, the chunk's targets computed once
    // for every candidate.
    let pooled = |cvs: &Vec<(Cv, f64)>| {
        cvs.iter()
            .any(|(cv, _)| matches!(cv, Cv::Form(f) if f.cells.is_some()))
    };
    if pooled(&cvs) {
        // The count pass first, from the pooled covariates alone: the
        // cells a one-covariate pool's groups occupy, so each group's cells
        // are laid out before its rows arrive; the bins each covariate of a
        // several-covariate pool occupies, so its cells are slots of a
        // compact grid rather than sorted (`CellPool::count_range`).
        let mut names: Vec<String> = cvs
            .iter()
            .filter_map(|(cv, _)| match cv {
                Cv::Form(f) if f.cells.is_some() => Some(f.form.covariates()),
                _ => None,
            })
            .flatten()
            .collect();
        names.sort();
        names.dedup();
        if !names.is_empty() {
            for units in consecutive_units(prob, cell_rows) {
                let (span, local) = rows_of_units(prob, units.clone());
                let x = match prob.x.rows_of(&names, span) {
                    Ok(x) => x,
                    Err(e) => {
                        fail_forms(&mut cvs, e);
                        break;
                    }
                };
                let us: Vec<usize> = units.collect();
                wall.lap("read");
                costliest_first(&mut cvs, |cv, secs| {
                    if let Cv::Form(f) = cv {
                        let mut failed = None;
                        timed(secs, &mut || failed = f.count_pass(&x, &us, &local).err());
                        if let Some(e) = failed {
                            *cv = Cv::Failed(e);
                        }
                    }
                });
                wall.lap("count");
            }
        }
        cvs.par_iter_mut().for_each(|(cv, _)| {
            if let Cv::Form(f) = cv {
                if let Some(cells) = f.cells.as_mut() {
                    cells.counted();
                }
            }
        });
        'groups: for (g, members) in groups.iter().enumerate() {
            for units in cut_units(prob, members, cell_rows) {
                let c = match tg.chunk(prob, units, &read) {
                    Ok(c) => c,
                    Err(e) => {
                        fail_forms(&mut cvs, e);
                        break 'groups;
                    }
                };
                c.sum_squares(&mut yy_u);
                wall.lap("chunk");
                costliest_first(&mut cvs, |cv, secs| {
                    if let Cv::Form(f) = cv {
                        let mut failed = None;
                        timed(secs, &mut || failed = f.cell_pass(&c, g).err());
                        if let Some(e) = failed {
                            *cv = Cv::Failed(e);
                        }
                    }
                });
                wall.lap("cells");
            }
        }
        yy_done = true;
    }
    costliest_first(&mut cvs, |cv, secs| {
        if let Cv::Form(f) = cv {
            let mut failed = None;
            timed(secs, &mut || failed = f.fit_theta(prob, tg, &yy_u).err());
            if let Some(e) = failed {
                *cv = Cv::Failed(e);
            }
        }
    });
    wall.lap("theta");
    // The score pass: each chunk once for every candidate.
    for units in consecutive_units(prob, score_rows) {
        if !cvs.iter().any(|(cv, _)| matches!(cv, Cv::Form(_))) {
            break;
        }
        let c = match tg.chunk(prob, units.collect(), &read) {
            Ok(c) => c,
            Err(e) => {
                fail_forms(&mut cvs, e);
                break;
            }
        };
        if !yy_done {
            c.sum_squares(&mut yy_u);
        }
        let sy_c = c.unit_sums();
        wall.lap("chunk");
        costliest_first(&mut cvs, |cv, secs| {
            if let Cv::Form(f) = cv {
                let mut failed = None;
                timed(secs, &mut || {
                    failed = f.score_pass(prob, tg, &yy_u, &c, &sy_c).err()
                });
                if let Some(e) = failed {
                    *cv = Cv::Failed(e);
                }
            }
        });
        wall.lap("score");
    }
    let out = cvs
        .into_par_iter()
        .zip(cands.par_iter())
        .map(|((cv, secs), e)| {
            let t = std::time::Instant::now();
            let out = match cv {
                Cv::Form(f) => f.finish(prob, tg, &yy_u),
                Cv::Slow => evaluate_slow(*e, prob, tg, &masks),
                Cv::Failed(e) => Err(e),
            };
            (out, secs + t.elapsed().as_secs_f64())
        })
        .collect();
    wall.lap("finish");
    wall.done();
    out
}

/// `f` on every candidate (its state, its time so far), in parallel, the
/// candidates that took longest so far first. Each pass is a barrier (the
/// next chunk waits for every candidate), so a costly candidate started
/// last leaves the other core idle while it finishes; started first, the
/// cheap ones fill in around it. Each candidate's work is its own, so the
/// order changes no result.
fn costliest_first<T: Send>(cvs: &mut [(T, f64)], f: impl Fn(&mut T, &mut f64) + Sync) {
    let mut order: Vec<&mut (T, f64)> = cvs.iter_mut().collect();
    order.sort_by(|a, b| b.1.total_cmp(&a.1));
    order
        .into_par_iter()
        .with_max_len(1)
        .for_each(|(cv, secs)| f(cv, secs));
}

/// A linear form's cross-validation as passes over the rows
/// (docs/design.md §8): the cell pass pools each unit's rows into its
/// fold group's cells; θ is chosen per fold on those cells; the score
/// pass computes each unit's blocks at its folds' θ, from which each
/// fold's coefficients and held-out scores follow. Each pass reads a
/// unit's rows once, in unit order, a chunk of units at a time.
struct FormCv {
    form: Arc<dyn LinearForm>,
    frame: Frame,
    masks: Vec<Vec<bool>>,
    theta_range: Option<ThetaRange>,
    /// The fold group of each unit (`fit::fold_groups`): units every fold
    /// treats alike, pooled together for the θ scan.
    groups: Vec<Vec<usize>>,
    group_of_unit: Vec<usize>,
    /// The CV folds' training cells (`TRAIN_POOL_FINER`), filled by the
    /// cell pass; `None` when the form is not scanned on cells.
    cells: Option<fit::CellPool>,
    thetas: Vec<f64>,
    /// Coefficients of folds 0..k fitted on pooled cells; `None` for a fold
    /// fitted on its units' blocks.
    pooled_beta: Vec<Option<Vec<f64>>>,
    /// Folds fitted on blocks, by θ: each unit's blocks at that θ.
    block_sets: Vec<BlockSet>,
    unit_sse: Vec<f64>,
}

/// Folds sharing a θ whose fits come from the units' blocks (X'X, and
/// X'y of each of the folds' targets) at that θ.
struct BlockSet {
    theta: f64,
    folds: Vec<usize>,
    /// The distinct targets of `folds`, ascending.
    targets: Vec<usize>,
    g_u: Vec<Vec<f64>>,
    /// `h_of[j][u]`: X'y of target `targets[j]` in unit u.
    h_of: Vec<Vec<Vec<f64>>>,
}

impl FormCv {
    /// `None`: the effect has no linear form (fitted on rows instead).
    /// `groups`: the fold groups of the units (`fit::fold_groups`): units
    /// every fold treats alike, pooled together for the θ scan.
    fn new(
        e: &dyn Effect,
        prob: &Problem,
        tg: &Targets,
        groups: &[Vec<usize>],
    ) -> Result<Option<FormCv>> {
        let Some(form) = e.linear_form() else {
            return Ok(None);
        };
        let frame = prob.frame(e)?;
        let masks = prob.train_masks();
        let nf = masks.len();
        let theta_range = form.theta(&frame);
        // θ is scanned over groups of units that every fold trains on
        // alike: the scan costs folds × bins, not runs × bins.
        let groups = groups.to_vec();
        let mut group_of_unit = vec![0; prob.units.len()];
        for (g, members) in groups.iter().enumerate() {
            for &u in members {
                group_of_unit[u] = g;
            }
        }
        let covs = form.covariates();
        let res = form
            .pool_resolutions(&frame)
            .filter(|r| r.len() == covs.len() && r.iter().all(|v| *v > 0.0 && v.is_finite()));
        let cells = match (&theta_range, res) {
            (Some(_), Some(res)) => {
                // The grid spans the columns' values, as the rows pooled at
                // once would (`fit::pool_rows`): max − min of each, the
                // frame's (rounding is monotonic, so the largest v − min
                // is max − min, bit for bit). Its cells are counted by
                // the count pass.
                let axes = frame
                    .iter()
                    .zip(&res)
                    .map(|(s, &r)| {
                        let span = 0.0f64.max(s.max - s.min);
                        fit::pool::Axis::new(s.min, span, r / TRAIN_POOL_FINER)
                    })
                    .collect();
                Some(fit::CellPool::new(axes, tg.n_distinct(), groups.len()))
            }
            _ => None,
        };
        Ok(Some(FormCv {
            form,
            frame,
            theta_range,
            groups,
            group_of_unit,
            cells,
            thetas: vec![f64::NAN; nf],
            pooled_beta: vec![None; nf],
            block_sets: Vec::new(),
            unit_sse: vec![f64::NAN; prob.units.len()],
            masks,
        }))
    }

    /// The count pass over one chunk: the cells its units' rows occupy in
    /// their groups (one covariate: laid out before any is filled; several:
    /// the bins each covariate occupies, for the compact grid).
    fn count_pass(&mut self, c: &CovRows, units: &[usize], local: &[Range<usize>]) -> Result<()> {
        let Some(cells) = self.cells.as_mut() else {
            return Ok(());
        };
        let cols: Vec<&[f64]> = self
            .form
            .covariates()
            .iter()
            .map(|n| {
                c.col(n)
                    .ok_or_else(|| err!("covariate `{n}` not available"))
            })
            .collect::<Result<_>>()?;
        let mut part = Vec::with_capacity(cols.len());
        for (&u, l) in units.iter().zip(local) {
            part.clear();
            part.extend(cols.iter().map(|col| &col[l.clone()]));
            cells.count_range(self.group_of_unit[u], &part);
        }
        Ok(())
    }

    /// The cell pass over one chunk of group `g`'s units: each unit's rows
    /// into the group's cells, in unit order (the order of the additions,
    /// so the same bits however the units come); the group sealed after
    /// its last unit.
    fn cell_pass(&mut self, c: &Chunk, g: usize) -> Result<()> {
        let Some(cells) = self.cells.as_mut() else {
            return Ok(());
        };
        let cols: Vec<&[f64]> = self
            .form
            .covariates()
            .iter()
            .map(|n| {
                c.x.col(n)
                    .ok_or_else(|| err!("covariate `{n}` not available"))
            })
            .collect::<Result<_>>()?;
        let (mut unit_cols, mut unit_targets) = (Vec::new(), Vec::new());
        for ((&u, l), xl) in c.units.iter().zip(&c.local).zip(&c.x_local) {
            debug_assert_eq!(self.group_of_unit[u], g, "a chunk of one group");
            unit_cols.clear();
            unit_cols.extend(cols.iter().map(|col| &col[xl.clone()]));
            unit_targets.clear();
            unit_targets.extend(c.targets.iter().map(|t| &t[l.clone()]));
            cells.add_range(g, 0..l.len(), &unit_cols, None, &unit_targets);
        }
        if c.units.last() == self.groups[g].last() {
            cells.seal(g);
        }
        Ok(())
    }

    /// θ per fold — scanned on the groups' cells, or on the rows when the
    /// form is not pooled — then the coefficients of the CV folds fitted
    /// on their training cells, and the folds left to fit on blocks.
    /// `yy_u`: each unit's Σy² of every distinct target.
    fn fit_theta(&mut self, prob: &Problem, tg: &Targets, yy_u: &[Vec<f64>]) -> Result<()> {
        let form = self.form.as_ref();
        let frame = &self.frame;
        let nf = self.masks.len();
        if let Some(tr) = &self.theta_range {
            let group_train: Vec<Vec<bool>> = self
                .masks
                .iter()
                .map(|m| self.groups.iter().map(|g| m[g[0]]).collect())
                .collect();
            let group_yy: Vec<Vec<f64>> = yy_u
                .iter()
                .map(|yy| {
                    self.groups
                        .iter()
                        .map(|g| g.iter().map(|&u| yy[u]).sum())
                        .collect()
                })
                .collect();
            let spec = FoldSpec {
                train: &group_train,
                target_of_fold: &tg.of_fold,
            };
            match self.cells.take() {
                Some(cells) => {
                    // The θ scan's coarser cells from the CV folds' finer
                    // ones: no other pass over the rows.
                    let mut fine_store = Vec::new();
                    let pooled = cells.finish();
                    tracing::debug!("fine cells of {:?}: {}", form.covariates(), pooled.1.len());
                    let fine = fit::scan_rows_of_cells(&form.covariates(), pooled, &mut fine_store);
                    let mut store = Vec::new();
                    let coarse = fit::coarser(form, frame, &fine, &mut store)?;
                    self.thetas = choose_theta(form, frame, tr, &coarse, &group_yy, &spec)?;
                    // Each CV fold fits at its own θ on its training
                    // groups' fine cells, so a row is evaluated once for
                    // every fold's held-out score instead of once per
                    // fold; fold k (all runs: the reported fit) stays
                    // exact on rows.
                    let k = prob.k;
                    let betas =
                        fit::pooled_fold_betas(form, frame, &fine, &self.thetas[..k], &spec)?;
                    for (slot, b) in self.pooled_beta.iter_mut().zip(betas) {
                        *slot = Some(b);
                    }
                }
                None => {
                    // Not pooled: the scan runs over the groups' rows.
                    let group_rows: Vec<Vec<Range<usize>>> = self
                        .groups
                        .iter()
                        .map(|g| g.iter().map(|&u| prob.units[u].clone()).collect())
                        .collect();
                    let tcols: Vec<Vec<f64>> = tg
                        .fold_of
                        .iter()
                        .map(|&f| tg.column(prob, f))
                        .collect::<Result<_>>()?;
                    let tslices: Vec<&[f64]> = tcols.iter().map(|t| t.as_slice()).collect();
                    let mut store = Vec::new();
                    let x = prob.x.columns(&form.covariates())?;
                    let rows = scan_rows(
                        form,
                        frame,
                        &x.data(),
                        &group_rows,
                        &tslices,
                        TRAIN_POOL_FINER,
                        &mut store,
                    )?;
                    self.thetas = choose_theta(form, frame, tr, &rows, &group_yy, &spec)?;
                }
            }
        }
        // The folds fitted on blocks, those at one θ together.
        let mut listed = vec![false; nf];
        for f0 in 0..nf {
            if listed[f0] || self.pooled_beta[f0].is_some() {
                continue;
            }
            let th = self.thetas[f0];
            let folds: Vec<usize> = (f0..nf)
                .filter(|&f| {
                    !listed[f]
                        && self.pooled_beta[f].is_none()
                        && self.thetas[f].to_bits() == th.to_bits()
                })
                .collect();
            let mut targets: Vec<usize> = folds.iter().map(|&f| tg.of_fold[f]).collect();
            targets.sort_unstable();
            targets.dedup();
            for &f in &folds {
                listed[f] = true;
            }
            let n_units = prob.units.len();
            self.block_sets.push(BlockSet {
                theta: th,
                folds,
                h_of: (0..targets.len())
                    .map(|_| Vec::with_capacity(n_units))
                    .collect(),
                targets,
                g_u: Vec::with_capacity(n_units),
            });
        }
        Ok(())
    }

    /// The score pass over one chunk. Each unit's statistics come from its
    /// own rows' features (a unit-sized buffer): features are row by row
    /// and a unit's sums run over its rows in order, so they are what a
    /// node holding only that run computes. A unit held out by a fold
    /// fitted on cells is scored at once; the block sets keep its blocks.
    /// `sy_c`: each of the chunk's units' Σy per target
    /// ([`Chunk::unit_sums`]).
    fn score_pass(
        &mut self,
        prob: &Problem,
        tg: &Targets,
        yy_u: &[Vec<f64>],
        c: &Chunk,
        sy_c: &[Vec<f64>],
    ) -> Result<()> {
        let form = self.form.clone();
        let covs = form.covariates();
        let xc = c.x.data();
        with_columns(form.n_linear(), |buf| -> Result<()> {
            for (((&u, l), xl), sy) in c.units.iter().zip(&c.local).zip(&c.x_local).zip(sy_c) {
                let r = prob.units[u].clone();
                let x = xc.rows_of(&covs, xl.clone())?;
                let f = prob.unit_fold[u];
                if let Some(b) = self.pooled_beta.get(f).and_then(|b| b.as_ref()) {
                    // Held out by CV fold f, fitted on cells at its θ.
                    let t = tg.of_fold[f];
                    form.features(&self.frame, &x, self.thetas[f], buf)?;
                    let g = fit::design_gram(buf, None, 0..r.len());
                    let h = fit::design_xy_summed(buf, &c.targets[t][l.clone()], 0..r.len(), sy[t]);
                    self.unit_sse[u] = fit::sse(&g, &h, yy_u[t][u], b);
                }
                for set in &mut self.block_sets {
                    form.features(&self.frame, &x, set.theta, buf)?;
                    set.g_u.push(fit::design_gram(buf, None, 0..r.len()));
                    for (h_u, &t) in set.h_of.iter_mut().zip(&set.targets) {
                        let y = &c.targets[t][l.clone()];
                        h_u.push(fit::design_xy_summed(buf, y, 0..r.len(), sy[t]));
                    }
                }
            }
            Ok(())
        })
    }

    /// Each block-fitted fold's coefficients from its training units'
    /// blocks (summed in unit order) and its held-out units' scores.
    fn finish(mut self, prob: &Problem, tg: &Targets, yy_u: &[Vec<f64>]) -> Result<CandEval> {
        let nf = self.masks.len();
        let p = self.form.n_linear() + 1;
        let mut beta = vec![Vec::new(); nf];
        for (f, b) in self.pooled_beta.iter_mut().enumerate() {
            if let Some(b) = b.take() {
                beta[f] = b;
            }
        }
        for set in &self.block_sets {
            debug_assert_eq!(set.g_u.len(), prob.units.len(), "every unit's blocks");
            for &f in &set.folds {
                let t = tg.of_fold[f];
                let h_u = &set.h_of[set.targets.binary_search(&t).expect("target listed")];
                let (g, h) = fit::train_sums(&set.g_u, h_u, &self.masks[f], p);
                let b = fit::solve(&g, &h).ok_or_else(|| err!("singular normal equations"))?;
                for (u, tr) in self.masks[f].iter().enumerate() {
                    if !*tr {
                        self.unit_sse[u] = fit::sse(&set.g_u[u], &h_u[u], yy_u[t][u], &b);
                    }
                }
                beta[f] = b;
            }
        }
        Ok(CandEval {
            fit: CandFit::Fast {
                theta: self.thetas,
                beta,
            },
            unit_sse: self.unit_sse,
        })
    }
}

pub(super) fn gather<'a>(
    prob: &Problem,
    covs: &[String],
    rows: &[usize],
    store: &'a mut Vec<Vec<f64>>,
) -> Result<EffectData<'a>> {
    store.clear();
    for c in covs {
        let col = prob.x.column(c)?;
        store.push(rows.iter().map(|&i| col[i]).collect());
    }
    let mut d = EffectData::new(rows.len());
    for (c, v) in covs.iter().zip(store.iter()) {
        d.push(c, v);
    }
    Ok(d)
}

pub(super) fn evaluate_slow(
    e: &dyn Effect,
    prob: &Problem,
    tg: &Targets,
    masks: &[Vec<bool>],
) -> Result<CandEval> {
    let covs = e.covariates();
    let mut fitted = Vec::new();
    let mut unit_sse = vec![f64::NAN; prob.units.len()];
    for (f, m) in masks.iter().enumerate() {
        let rows: Vec<usize> = prob
            .units
            .iter()
            .zip(m)
            .filter(|(_, t)| **t)
            .flat_map(|(u, _)| u.clone())
            .collect();
        let target = tg.column(prob, f)?;
        let y: Vec<f64> = rows.iter().map(|&i| target[i]).collect();
        let mut store = Vec::new();
        let xd = gather(prob, &covs, &rows, &mut store)?;
        let fe = e.fit(&xd, &y)?;
        let pred = fe.predict(&prob.x.columns(&covs)?.data());
        let off = fe.offset_mm();
        for (u, t) in m.iter().enumerate() {
            if !*t {
                let r = prob.units[u].clone();
                unit_sse[u] = r.map(|i| (target[i] - off - pred[i]).powi(2)).sum();
            }
        }
        fitted.push(fe);
    }
    Ok(CandEval {
        fit: CandFit::Slow { fitted },
        unit_sse,
    })
}

/// Fold `f`'s fit ready to predict any rows: a linear form's θ and
/// coefficients with its frame, or a plugin's fitted effect.
enum FoldFit<'a> {
    Linear {
        form: Arc<dyn LinearForm>,
        frame: Frame,
        theta: f64,
        beta: &'a [f64],
    },
    Fitted(&'a dyn FittedEffect),
}

impl<'a> FoldFit<'a> {
    fn of(e: &dyn Effect, prob: &Problem, ev: &'a CandEval, f: usize) -> Result<FoldFit<'a>> {
        Ok(match &ev.fit {
            CandFit::Fast { theta, beta } => FoldFit::Linear {
                form: e.linear_form().expect("fast fit has a form"),
                frame: prob.frame(e)?,
                theta: theta[f],
                beta: &beta[f],
            },
            CandFit::Slow { fitted } => FoldFit::Fitted(fitted[f].as_ref()),
        })
    }

    /// The prediction (offset included) of the rows of `x` into `pred`. A
    /// linear form's is row by row: the same bits for a row whether `x` is
    /// one unit, the trimmed rows or the whole observable.
    fn predict(&self, x: &EffectData, pred: &mut Vec<f64>) -> Result<()> {
        pred.clear();
        match self {
            FoldFit::Linear {
                form,
                frame,
                theta,
                beta,
            } => with_columns(form.n_linear(), |buf| -> Result<()> {
                form.features(frame, x, *theta, buf)?;
                pred.resize(x.len(), beta[0]);
                for (col, bj) in buf.iter().zip(&beta[1..]) {
                    for (o, v) in pred.iter_mut().zip(col.iter()) {
                        *o += bj * v;
                    }
                }
                Ok(())
            }),
            FoldFit::Fitted(fe) => {
                let off = fe.offset_mm();
                pred.extend(fe.predict(x).into_iter().map(|p| p + off));
                Ok(())
            }
        }
    }
}

/// Fold `f`'s prediction (offset included) of the rows of `x` into `pred`
/// (f = k: the all-runs fit, the one reported and replayed).
pub fn fold_prediction(
    e: &dyn Effect,
    prob: &Problem,
    ev: &CandEval,
    f: usize,
    x: &EffectData,
    pred: &mut Vec<f64>,
) -> Result<()> {
    FoldFit::of(e, prob, ev, f)?.predict(x, pred)
}

/// Fold `f`'s fit (offset included) taken out of `target`: each unit's
/// rows predicted from their own features (a unit-sized buffer, bit for
/// bit a prediction over all rows) and subtracted; `held` receives the
/// prediction of the units fold `f` holds out, in row order (fold k holds
/// none out).
pub fn take_out_fold(
    e: &dyn Effect,
    prob: &Problem,
    ev: &CandEval,
    f: usize,
    target: &mut [f64],
    held: &mut Vec<f64>,
) -> Result<()> {
    debug_assert!(
        crate::folds::tile(&prob.units, target.len()),
        "the scoring units tile the rows"
    );
    let is_held = |u: usize| f < prob.k && prob.unit_fold[u] == f;
    let fit = FoldFit::of(e, prob, ev, f)?;
    let mut pred = Vec::new();
    // A plugin's fitted effect predicts the rows it is given with no
    // promise that a row's value is its own alone: all rows at once.
    let covs = match &fit {
        FoldFit::Linear { form, .. } => Some(form.covariates()),
        FoldFit::Fitted(_) => {
            fit.predict(&prob.x.columns(&e.covariates())?.data(), &mut pred)?;
            None
        }
    };
    for (u, r) in prob.units.iter().enumerate() {
        let p = match &covs {
            None => &pred[r.clone()],
            Some(covs) => {
                fit.predict(&prob.x.rows_of(covs, r.clone())?.data(), &mut pred)?;
                &pred[..]
            }
        };
        for (y, p) in target[r.clone()].iter_mut().zip(p) {
            *y -= p;
        }
        if is_held(u) {
            held.extend_from_slice(p);
        }
    }
    Ok(())
}

/// Contract parameters and offset of fold `f`'s fit (f = k: all runs).
pub fn params_of(
    e: &dyn Effect,
    prob: &Problem,
    ev: &CandEval,
    f: usize,
) -> (BTreeMap<String, f64>, f64) {
    match &ev.fit {
        CandFit::Fast { theta, beta } => {
            let form = e.linear_form().expect("fast");
            match prob.frame(e) {
                Ok(frame) => form.params(&frame, theta[f], &beta[f][1..], beta[f][0]),
                Err(_) => (BTreeMap::new(), f64::NAN),
            }
        }
        CandFit::Slow { fitted } => (fitted[f].params(), fitted[f].offset_mm()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effect::{catalogue, CovStats};

    /// Every candidate once, its own state and time handed to it; on one
    /// thread in the order of the time so far, longest first (ties in
    /// candidate order).
    #[test]
    fn the_costliest_candidates_are_started_first() {
        let mut cvs: Vec<(usize, f64)> = [0.5, 2.0, 0.0, 3.5, 2.0, 1.0]
            .into_iter()
            .enumerate()
            .collect();
        let seen = std::sync::Mutex::new(Vec::new());
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        one.install(|| {
            costliest_first(&mut cvs, |i, secs| {
                seen.lock().unwrap().push(*i);
                *secs += 10.0;
            })
        });
        assert_eq!(seen.into_inner().unwrap(), vec![3, 1, 4, 5, 0, 2]);
        assert_eq!(
            cvs.iter().map(|c| c.1).collect::<Vec<_>>(),
            vec![10.5, 12.0, 10.0, 13.5, 12.0, 11.0]
        );
    }

    /// A candidate's cross-validation reads the rows a chunk at a time;
    /// its fits and held-out scores are the same bits whether a chunk is
    /// one unit or a whole fold group — what lets a pass stream the runs
    /// (docs/design.md §8). Targets shared by every fold (the gap) and a
    /// target per fold after two effects were taken out — recomputed for
    /// each chunk from the fits, bit for bit the columns the fits'
    /// predictions were subtracted from, one after the other, with the
    /// held-out contributions the folds' predictions of their held-out
    /// rows.
    #[test]
    fn a_candidates_passes_give_the_same_bits_for_any_chunk_size() {
        let (runs, per_run) = (12, 700);
        let n = runs * per_run;
        let mut t_s = Vec::with_capacity(n);
        let mut x_mm = Vec::with_capacity(n);
        let mut v = Vec::with_capacity(n);
        let mut gap = Vec::with_capacity(n);
        for r in 0..runs {
            for i in 0..per_run {
                let t = i as f64 * 0.37;
                let x = ((i * 7919 + r * 31) % 997) as f64 * 0.21 - 40.0;
                let vel = 50.0 * (0.013 * i as f64 + r as f64).sin();
                t_s.push(t);
                x_mm.push(x);
                v.push(vel);
                let noise = (((i * 104_729 + r * 7) % 1000) as f64 / 1000.0 - 0.5) * 2e-4;
                gap.push(
                    0.002 * (1.0 - (-t / 60.0).exp())
                        + 1e-3 * (x / 17.0).sin()
                        + 1e-5 * vel
                        + 1e-4 * r as f64
                        + noise,
                );
            }
        }
        let names = ["t_s", "x_mm", "v_mm_s"];
        // The covariates in memory and in a column file: the same bits.
        let cols: Vec<(String, Vec<f64>)> = names
            .iter()
            .zip([&t_s, &x_mm, &v])
            .map(|(name, col)| (name.to_string(), col.clone()))
            .collect();
        let in_memory = Covariates::in_memory(n, cols.clone());
        let dir = tempfile::tempdir().unwrap();
        let file = crate::covariates::ColumnFile::create(dir.path(), n, cols.len()).unwrap();
        for (j, (_, c)) in cols.iter().enumerate() {
            file.write(j, 0, c).unwrap();
        }
        let at: Vec<usize> = (0..cols.len()).collect();
        let stats = file.stats(&at).unwrap();
        let in_file =
            Covariates::in_file(n, file, at, cols.into_iter().map(|c| c.0).collect(), stats);
        assert!(in_file.in_a_file() && !in_memory.in_a_file());
        let mut scores = Vec::new();
        for x in [&in_memory, &in_file] {
            let k = 5;
            let units: Vec<Range<usize>> =
                (0..runs).map(|r| r * per_run..(r + 1) * per_run).collect();
            let prob = Problem {
                x,
                gap: &gap,
                unit_fold: (0..runs).map(|r| (r * 3) % k).collect(),
                unit_run: (0..runs).collect(),
                units,
                k,
                frames: names
                    .iter()
                    .zip([&t_s, &x_mm, &v])
                    .map(|(name, col)| (name.to_string(), CovStats::from_values(col)))
                    .collect(),
            };
            let names: Vec<String> = names.iter().map(|s| s.to_string()).collect();
            let cands = catalogue(&names);
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            let refs: Vec<&dyn Effect> = cands.iter().map(|e| e.as_ref()).collect();
            // The gap shared by every fold, then three effects taken out (a
            // target per fold, each subtraction after the one before).
            let gap_targets = Targets::gap(&prob);
            let of_key = |key: &str| {
                refs.iter()
                    .position(|e| e.key() == key)
                    .unwrap_or_else(|| panic!("{key} in the catalogue"))
            };
            // A plugin effect without a linear form (fitted on rows, its
            // predictions kept per fold) between two linear forms; the
            // targets recomputed for every chunk (no column budget) and kept
            // as columns.
            let no_form = NoForm(refs[of_key("scale:x_mm")]);
            let taken: [&dyn Effect; 3] = [
                refs[of_key("periodic:x_mm")],
                &no_form,
                refs[of_key("drift:t_s")],
            ];
            let chain = |max_column_bytes: usize| {
                let mut tg = Targets::gap(&prob);
                let mut columns: Vec<Vec<f64>> = vec![gap.clone(); k + 1];
                for e in taken {
                    let ev = evaluate_all_in_chunks(&[e], &prob, &tg, usize::MAX, usize::MAX)
                        .pop()
                        .unwrap()
                        .0
                        .unwrap();
                    let next = tg
                        .taking_out_within(&prob, e, &ev, max_column_bytes)
                        .unwrap();
                    assert_eq!(next.columns.is_some(), max_column_bytes > 0);
                    let contrib = held_out_contribution(&prob, e, &ev).unwrap();
                    // What the targets are recomputed to equal: each fold's
                    // column less its fit, and the held-out rows' predictions.
                    let mut held_rows = vec![f64::NAN; n];
                    for (f, col) in columns.iter_mut().enumerate() {
                        let mut held = Vec::new();
                        take_out_fold(e, &prob, &ev, f, col, &mut held).unwrap();
                        let rows = prob
                            .units
                            .iter()
                            .zip(&prob.unit_fold)
                            .filter(|(_, uf)| **uf == f && f < k)
                            .flat_map(|(u, _)| u.clone());
                        for (r, p) in rows.zip(held) {
                            held_rows[r] = p;
                        }
                    }
                    assert_eq!(bits(&contrib), bits(&held_rows), "{}", e.key());
                    for (f, col) in columns.iter().enumerate() {
                        assert_eq!(bits(&next.column(&prob, f).unwrap()), bits(col), "fold {f}");
                    }
                    tg = next;
                }
                assert_eq!(tg.n_distinct(), k + 1);
                tg
            };
            let (tg, kept) = (chain(0), chain(usize::MAX));
            for tg in [gap_targets, tg, kept] {
                let mut scanned = 0;
                let whole = evaluate_all_in_chunks(&refs, &prob, &tg, usize::MAX, usize::MAX);
                scores.push(
                    whole
                        .iter()
                        .map(|w| bits(&w.0.as_ref().unwrap().unit_sse))
                        .collect::<Vec<_>>(),
                );
                for max_rows in [1, 2 * per_run + 1] {
                    let parts = evaluate_all_in_chunks(&refs, &prob, &tg, max_rows, max_rows);
                    for ((whole, part), e) in whole.iter().zip(parts).zip(&refs) {
                        let (whole, part) = (whole.0.as_ref().unwrap(), part.0.unwrap());
                        assert_eq!(bits(&whole.unit_sse), bits(&part.unit_sse), "{}", e.key());
                        let (
                            CandFit::Fast {
                                theta: ta,
                                beta: ba,
                            },
                            CandFit::Fast {
                                theta: tb,
                                beta: bb,
                            },
                        ) = (&whole.fit, &part.fit)
                        else {
                            panic!("catalogue effects are linear forms");
                        };
                        assert_eq!(bits(ta), bits(tb), "{}", e.key());
                        for (a, b) in ba.iter().zip(bb) {
                            assert_eq!(bits(a), bits(b), "{}", e.key());
                        }
                        assert!(whole.unit_sse.iter().all(|s| s.is_finite()), "{}", e.key());
                        scanned += usize::from(ta.iter().any(|t| !t.is_nan()));
                    }
                }
                assert!(scanned >= 4, "θ forms among the candidates: {scanned}");
            }
        }
        let (memory, file) = scores.split_at(scores.len() / 2);
        assert_eq!(memory, file, "the covariates in memory and in a file");
    }

    /// An effect fitted on rows only: a plugin effect with no linear form.
    struct NoForm<'a>(&'a dyn Effect);

    impl Effect for NoForm<'_> {
        fn name(&self) -> &str {
            "no_form"
        }
        fn covariates(&self) -> Vec<String> {
            self.0.covariates()
        }
        fn n_params(&self) -> usize {
            self.0.n_params()
        }
        fn fit(&self, x: &EffectData, gap: &[f64]) -> Result<Box<dyn FittedEffect>> {
            self.0.fit(x, gap)
        }
    }
}

//! Cross-validating one candidate: per-fold targets, the fast path for
//! linear forms (sufficient statistics, θ scanned per fold), the slow path
//! (refit per fold) for plugin effects, and each fold's prediction and
//! parameters.

use super::*;
use crate::effect::{LinearForm, ThetaRange};

/// Per-fold targets (fold k = all runs) and their Σy² per unit.
pub struct Targets {
    pub per_fold: Vec<Arc<Vec<f64>>>,
    distinct: Vec<Arc<Vec<f64>>>,
    of_fold: Vec<usize>,
    yy_u: Vec<Vec<f64>>,
}

impl Targets {
    /// The per-fold targets, the rest let go (so a target held by no one
    /// else can be changed in place).
    pub fn into_per_fold(self) -> Vec<Arc<Vec<f64>>> {
        self.per_fold
    }

    pub fn new(per_fold: Vec<Arc<Vec<f64>>>, units: &[Range<usize>]) -> Targets {
        let mut distinct: Vec<Arc<Vec<f64>>> = Vec::new();
        let mut of_fold = Vec::new();
        for t in &per_fold {
            match distinct.iter().position(|d| Arc::ptr_eq(d, t)) {
                Some(i) => of_fold.push(i),
                None => {
                    of_fold.push(distinct.len());
                    distinct.push(t.clone());
                }
            }
        }
        let yy_u = distinct
            .iter()
            .map(|t| {
                units
                    .iter()
                    .map(|u| dot(&t[u.clone()], &t[u.clone()]))
                    .collect()
            })
            .collect();
        Targets {
            per_fold,
            distinct,
            of_fold,
            yy_u,
        }
    }
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
const CHUNK_ROWS: usize = 1 << 20;

/// The rows of consecutive scoring units as a pass over the observable
/// sees them (docs/design.md §8): row `i` of the chunk is row
/// `first_row + i` of the observable.
pub struct Chunk<'a> {
    pub units: Range<usize>,
    pub first_row: usize,
    pub x: EffectData<'a>,
    /// Each distinct target of [`Targets`] over the chunk's rows.
    pub targets: Vec<&'a [f64]>,
}

impl Chunk<'_> {
    /// Unit `u`'s rows within the chunk.
    fn rows(&self, units: &[Range<usize>], u: usize) -> Range<usize> {
        units[u].start - self.first_row..units[u].end - self.first_row
    }
}

/// The units cut into chunks of consecutive units of at most `max_rows`
/// rows (a unit longer than that is a chunk of its own): slices of the
/// observable's columns.
pub fn chunks<'a>(prob: &Problem<'a>, tg: &'a Targets, max_rows: usize) -> Result<Vec<Chunk<'a>>> {
    let names: Vec<String> = prob.x.names().map(String::from).collect();
    let mut out = Vec::new();
    let mut a = 0;
    while a < prob.units.len() {
        let first_row = prob.units[a].start;
        let mut b = a + 1;
        while b < prob.units.len() && prob.units[b].end - first_row <= max_rows {
            b += 1;
        }
        let rows = first_row..prob.units[b - 1].end;
        out.push(Chunk {
            units: a..b,
            first_row,
            x: prob.x.rows_of(&names, rows.clone())?,
            targets: tg.distinct.iter().map(|t| &t[rows.clone()]).collect(),
        });
        a = b;
    }
    Ok(out)
}

/// Cross-validates candidates against the current targets (in parallel):
/// each candidate's cell pass and θ fit, then the score pass reading a
/// chunk once for every candidate before the next. Each candidate's result
/// (a failed fit is an error of its own) and its time in seconds.
///
/// With every row in memory the cell pass takes them as one chunk: its
/// groups are then pooled one after another, each counted first and laid
/// out at its size (`CellPool::add_groups`), instead of every group open
/// at once and growing — at 500 servo runs that is ≈ 45 MB less at the
/// diagnosis' peak.
pub fn evaluate_all(
    cands: &[&dyn Effect],
    prob: &Problem,
    tg: &Targets,
) -> Vec<(Result<CandEval>, f64)> {
    evaluate_all_in_chunks(cands, prob, tg, usize::MAX, CHUNK_ROWS)
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
    let (cell_chunks, chunks) = match (chunks(prob, tg, cell_rows), chunks(prob, tg, score_rows)) {
        (Ok(a), Ok(b)) => (a, b),
        (Err(e), _) | (_, Err(e)) => {
            let why = e.to_string();
            return cands.iter().map(|_| (Err(err!("{why}")), 0.0)).collect();
        }
    };
    // The cell pass and the θ fit, a candidate at a time: its cells live
    // from its first chunk to its fit only, so two threads hold two
    // candidates' cells, not every candidate's (at 500 servo runs the
    // fine cells of one round's candidates are ≈ 10⁶, ≈ 130 MB together).
    let mut cvs: Vec<(Cv, f64)> = cands
        .par_iter()
        .map(|e| {
            let mut secs = 0.0;
            let mut cv = Cv::Slow;
            timed(&mut secs, &mut || {
                cv = match FormCv::new(*e, prob, tg).and_then(|f| {
                    f.map(|mut f| -> Result<FormCv> {
                        for c in &cell_chunks {
                            f.cell_pass(prob, c);
                        }
                        f.fit_theta(prob, tg)?;
                        Ok(f)
                    })
                    .transpose()
                }) {
                    Ok(Some(f)) => Cv::Form(Box::new(f)),
                    Ok(None) => Cv::Slow,
                    Err(e) => Cv::Failed(e),
                }
            });
            (cv, secs)
        })
        .collect();
    // The score pass: each chunk once for every candidate.
    for c in &chunks {
        cvs.par_iter_mut().for_each(|(cv, secs)| {
            if let Cv::Form(f) = cv {
                let mut failed = None;
                timed(secs, &mut || failed = f.score_pass(prob, tg, c).err());
                if let Some(e) = failed {
                    *cv = Cv::Failed(e);
                }
            }
        });
    }
    drop(chunks);
    let masks = prob.train_masks();
    cvs.into_par_iter()
        .zip(cands.par_iter())
        .map(|((cv, secs), e)| {
            let t = std::time::Instant::now();
            let out = match cv {
                Cv::Form(f) => f.finish(prob, tg),
                Cv::Slow => evaluate_slow(*e, prob, tg, &masks),
                Cv::Failed(e) => Err(e),
            };
            (out, secs + t.elapsed().as_secs_f64())
        })
        .collect()
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
    fn new(e: &dyn Effect, prob: &Problem, tg: &Targets) -> Result<Option<FormCv>> {
        let Some(form) = e.linear_form() else {
            return Ok(None);
        };
        let frame = prob.frame(e)?;
        let masks = prob.train_masks();
        let nf = masks.len();
        let theta_range = form.theta(&frame);
        // θ is scanned over groups of units that every fold trains on
        // alike: the scan costs folds × bins, not runs × bins.
        let groups = fit::fold_groups(&masks, prob.units.len());
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
                // once would (`fit::pool_rows`).
                let cols: Vec<&[f64]> = covs
                    .iter()
                    .map(|c| prob.x.require(c))
                    .collect::<Result<_>>()?;
                let mins: Vec<f64> = frame.iter().map(|s| s.min).collect();
                let axes = fit::pool::spans(&cols, &mins)
                    .into_iter()
                    .zip(mins.iter().zip(&res))
                    .map(|(span, (&min, &r))| fit::pool::Axis::new(min, span, r / TRAIN_POOL_FINER))
                    .collect();
                Some(fit::CellPool::new(axes, tg.distinct.len(), groups.len()))
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

    /// The cell pass over one chunk: each unit's rows into its group's
    /// cells, a group's units in unit order (the order of the additions,
    /// so the same bits however the units come).
    fn cell_pass(&mut self, prob: &Problem, c: &Chunk) {
        let Some(cells) = self.cells.as_mut() else {
            return;
        };
        let cols: Vec<&[f64]> = self
            .form
            .covariates()
            .iter()
            .map(|n| c.x.col(n).expect("the pool's covariates were checked"))
            .collect();
        if c.units == (0..prob.units.len()) {
            // Every row at hand: group by group, each group's cells sealed
            // (compact) before the next group's fill.
            let groups: Vec<Vec<Range<usize>>> = self
                .groups
                .iter()
                .map(|members| members.iter().map(|&u| c.rows(&prob.units, u)).collect())
                .collect();
            cells.add_groups(&groups, &cols, None, &c.targets);
            return;
        }
        for u in c.units.clone() {
            let g = self.group_of_unit[u];
            cells.add_range(g, c.rows(&prob.units, u), &cols, None, &c.targets);
            if self.groups[g].last() == Some(&u) {
                cells.seal(g);
            }
        }
    }

    /// θ per fold — scanned on the groups' cells, or on the rows when the
    /// form is not pooled — then the coefficients of the CV folds fitted
    /// on their training cells, and the folds left to fit on blocks.
    fn fit_theta(&mut self, prob: &Problem, tg: &Targets) -> Result<()> {
        let form = self.form.as_ref();
        let frame = &self.frame;
        let nf = self.masks.len();
        if let Some(tr) = &self.theta_range {
            let group_train: Vec<Vec<bool>> = self
                .masks
                .iter()
                .map(|m| self.groups.iter().map(|g| m[g[0]]).collect())
                .collect();
            let group_yy: Vec<Vec<f64>> = tg
                .yy_u
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
                    let fine = fit::scan_rows_of_cells(
                        &form.covariates(),
                        cells.finish(),
                        &mut fine_store,
                    );
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
                    let tslices: Vec<&[f64]> = tg.distinct.iter().map(|t| t.as_slice()).collect();
                    let mut store = Vec::new();
                    let rows = scan_rows(
                        form,
                        frame,
                        &prob.x,
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
    fn score_pass(&mut self, prob: &Problem, tg: &Targets, c: &Chunk) -> Result<()> {
        let form = self.form.clone();
        let covs = form.covariates();
        with_columns(form.n_linear(), |buf| -> Result<()> {
            for u in c.units.clone() {
                let r = c.rows(&prob.units, u);
                let x = c.x.rows_of(&covs, r.clone())?;
                let f = prob.unit_fold[u];
                if let Some(b) = self.pooled_beta.get(f).and_then(|b| b.as_ref()) {
                    // Held out by CV fold f, fitted on cells at its θ.
                    let t = tg.of_fold[f];
                    form.features(&self.frame, &x, self.thetas[f], buf)?;
                    let g = fit::design_gram(buf, None, 0..r.len());
                    let h = fit::design_xy(buf, &c.targets[t][r.clone()], 0..r.len());
                    self.unit_sse[u] = fit::sse(&g, &h, tg.yy_u[t][u], b);
                }
                for set in &mut self.block_sets {
                    form.features(&self.frame, &x, set.theta, buf)?;
                    set.g_u.push(fit::design_gram(buf, None, 0..r.len()));
                    for (h_u, &t) in set.h_of.iter_mut().zip(&set.targets) {
                        h_u.push(fit::design_xy(buf, &c.targets[t][r.clone()], 0..r.len()));
                    }
                }
            }
            Ok(())
        })
    }

    /// Each block-fitted fold's coefficients from its training units'
    /// blocks (summed in unit order) and its held-out units' scores.
    fn finish(mut self, prob: &Problem, tg: &Targets) -> Result<CandEval> {
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
                        self.unit_sse[u] = fit::sse(&set.g_u[u], &h_u[u], tg.yy_u[t][u], &b);
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
        let col = prob.x.require(c)?;
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
        let y: Vec<f64> = rows.iter().map(|&i| tg.per_fold[f][i]).collect();
        let mut store = Vec::new();
        let xd = gather(prob, &covs, &rows, &mut store)?;
        let fe = e.fit(&xd, &y)?;
        let pred = fe.predict(&prob.x);
        let off = fe.offset_mm();
        for (u, t) in m.iter().enumerate() {
            if !*t {
                let r = prob.units[u].clone();
                unit_sse[u] = r.map(|i| (tg.per_fold[f][i] - off - pred[i]).powi(2)).sum();
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
            fit.predict(&prob.x, &mut pred)?;
            None
        }
    };
    for (u, r) in prob.units.iter().enumerate() {
        let p = match &covs {
            None => &pred[r.clone()],
            Some(covs) => {
                fit.predict(&prob.x.rows_of(covs, r.clone())?, &mut pred)?;
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

    /// A candidate's cross-validation reads the rows a chunk at a time;
    /// its fits and held-out scores are the same bits whether a chunk is
    /// one unit or the whole observable — what lets a pass stream the runs
    /// (docs/design.md §8). Targets that differ by fold (as after a chosen
    /// effect) and shared ones both.
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
        let mut x = EffectData::new(n);
        for (name, col) in names.iter().zip([&t_s, &x_mm, &v]) {
            x.push(name, col);
        }
        let k = 5;
        let units: Vec<Range<usize>> = (0..runs).map(|r| r * per_run..(r + 1) * per_run).collect();
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
        let shared = Arc::new(gap.clone());
        let per_fold: Vec<Arc<Vec<f64>>> = (0..=k)
            .map(|f| {
                Arc::new(
                    gap.iter()
                        .enumerate()
                        .map(|(i, g)| g - 1e-5 * f as f64 * (i % 7) as f64)
                        .collect(),
                )
            })
            .collect();
        let names: Vec<String> = names.iter().map(|s| s.to_string()).collect();
        let cands = catalogue(&names);
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let refs: Vec<&dyn Effect> = cands.iter().map(|e| e.as_ref()).collect();
        for targets in [vec![shared; k + 1], per_fold] {
            let tg = Targets::new(targets, &prob.units);
            let mut scanned = 0;
            let whole = evaluate_all_in_chunks(&refs, &prob, &tg, usize::MAX, usize::MAX);
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
}

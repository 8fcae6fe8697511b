//! sparkout-diagnose: the sim-to-real gap diagnosis (docs/design.md §7;
//! docs/formats.md §7 and "diagnosis.json (v1)"; the statistics: docs/models.md §8).
//!
//! [`diagnose`] answers, per observable: where the gap lies (cells of
//! covariate space and machines tested against the noise floor, `cells`),
//! which catalogue or plugin effect explains it (leave-runs-out CV +
//! forward selection, `select`), and how far it shrinks on held-out runs.
//! A run is a (machine, run) pair throughout.
//!
//! The steps, one file each: gather → noise → folds → candidates → select
//! → intervals → machines → cells → report (`output` assembles
//! diagnosis.json); `outliers` runs the steps a second time without the
//! isolated spikes a first pass leaves in its residual. It is
//! pure and deterministic for a given seed: names are sorted, folds come
//! from a seeded shuffle, rayon only fills vectors whose order is fixed.

// Typed errors (sparkout-core `error`) by the names every step uses.
#[allow(unused_imports)]
pub(crate) use sparkout_core::{bail, err, Context, Error};

pub mod candidates;
pub mod cells;
mod clock;
pub mod collinear;
pub mod config;
pub mod covariates;
pub mod document;
pub mod folds;
pub mod gather;
pub mod intervals;
pub mod machines;
pub mod noise;
pub mod observations;
pub mod observations_file;
pub mod outliers;
pub mod output;
pub mod per_row;
pub mod report;
pub mod run_length;
pub mod select;
pub mod student_t;

// The effect model (the `Effect` trait, the catalogue, least squares from
// sufficient statistics) and the augmented model sit in sparkout-core, below
// the plugin interface that names them; re-exported here under the names
// the diagnosis has always used.
pub use sparkout_core::augment;
pub use sparkout_core::effect;
pub use sparkout_core::effect::fit;
// The ground floor, by the module names the steps use (`crate::contracts`…).
pub use sparkout_core::Result;
pub(crate) use sparkout_core::{config_check, contracts, html, units, InputError};

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

pub use candidates::EffectScope;
pub use config::DiagnoseConfig;
pub use effect::{
    catalogue, catalogue_effect, composite, only_on, product, shape_value, CovStats, Effect,
    EffectData, FittedEffect, Kind, LinearForm,
};
pub use observations::read_observations;
pub use observations_file::{
    diagnose_indexed, diagnose_observations_file, index_observations_file, IndexedFile,
};
pub use output::{
    CellBound, CvInfo, Diagnosis, DiagnosisOutput, EffectEntry, GapSummary, MachineFit,
    ObservableSummary, Unexplained, WhereCell,
};

use crate::config_check::Checked;
use cells::ObsCell;
use clock::StepClock;
use observations::Table;

/// Notes of diagnosis.json, each said once, in first-said order.
#[derive(Default)]
pub struct Notes {
    seen: BTreeSet<String>,
    ordered: Vec<String>,
}

impl Notes {
    pub fn add(&mut self, s: String) {
        if self.seen.insert(s.clone()) {
            self.ordered.push(s);
        }
    }
    pub fn into_vec(self) -> Vec<String> {
        self.ordered
    }
}

/// What the per-observable steps hand to the fleet-level assembly.
pub struct Accum {
    /// Per row (slot), the held-out residual and each selected effect's
    /// contribution; a fleet accumulator with a spill keeps neither and
    /// writes each observable's to disk as it is merged.
    pub residual_all: Vec<f64>,
    pub contrib_cols: BTreeMap<String, Vec<f64>>,
    /// Per row, the gap: held by a fleet accumulator without a spill
    /// (diagnosis.parquet's `gap` column); empty in a pass's accumulator
    /// (the pass's rows hold their gap) and with a spill (which writes it).
    pub gap_all: Vec<f64>,
    /// Selected keys in order of first selection.
    pub selected_keys: Vec<String>,
    /// Held-out SSE each selected effect removed, in units of its
    /// observable's noise variance, summed over observables: the fleet's
    /// `selected` list is ordered by it (the effect that explains the most
    /// signal first), not by the order observables happen to be named in.
    pub explained_var: BTreeMap<String, f64>,
    pub effects: Vec<EffectEntry>,
    pub summaries: Vec<ObservableSummary>,
    pub cells: Vec<ObsCell>,
    pub augmented: Vec<augment::ModelEffect>,
    pub blocked: bool,
    pub folds_used: usize,
    pub spill: Option<per_row::ResultSpill>,
}

impl Accum {
    pub fn new(n: usize) -> Accum {
        Accum {
            residual_all: vec![0.0; n],
            contrib_cols: BTreeMap::new(),
            gap_all: Vec::new(),
            selected_keys: Vec::new(),
            explained_var: BTreeMap::new(),
            effects: Vec::new(),
            summaries: Vec::new(),
            cells: Vec::new(),
            augmented: Vec::new(),
            blocked: false,
            folds_used: 0,
            spill: None,
        }
    }

    /// A fleet accumulator of `n` rows holding its per-row results.
    pub fn fleet(n: usize) -> Accum {
        Accum {
            gap_all: vec![0.0; n],
            ..Accum::new(n)
        }
    }

    /// A fleet accumulator whose per-row results go to `spill`.
    pub fn spilled(spill: per_row::ResultSpill) -> Accum {
        Accum {
            spill: Some(spill),
            ..Accum::new(0)
        }
    }

    /// Adds one observable's results: its accumulator's slot p is table
    /// row `rows[p]`, whose gap is `gap[p]`.
    fn merge(&mut self, o: Accum, obs: u32, rows: &[usize], gap: &[f64]) -> Result<()> {
        if let Some(spill) = &mut self.spill {
            spill.push(obs, rows, gap, &o.residual_all, &o.contrib_cols)?;
        } else {
            for ((&i, r), g) in rows.iter().zip(&o.residual_all).zip(gap) {
                self.residual_all[i] = *r;
                self.gap_all[i] = *g;
            }
            let n = self.residual_all.len();
            for (k, v) in o.contrib_cols {
                let col = self.contrib_cols.entry(k).or_insert_with(|| vec![0.0; n]);
                for (&i, c) in rows.iter().zip(&v) {
                    col[i] = *c;
                }
            }
        }
        for k in o.selected_keys {
            if !self.selected_keys.contains(&k) {
                self.selected_keys.push(k);
            }
        }
        for (k, v) in o.explained_var {
            *self.explained_var.entry(k).or_insert(0.0) += v;
        }
        self.effects.extend(o.effects);
        self.summaries.extend(o.summaries);
        self.cells.extend(o.cells);
        self.augmented.extend(o.augmented);
        self.blocked |= o.blocked;
        self.folds_used = self.folds_used.max(o.folds_used);
        Ok(())
    }
}

/// Diagnoses paired observations (validated like [`read_observations`]);
/// `extra_effects` apply to every observable.
pub fn diagnose(
    obs: &arrow::array::RecordBatch,
    cfg: &DiagnoseConfig,
    extra_effects: &[Box<dyn Effect>],
) -> Result<DiagnosisOutput> {
    let everywhere = [EffectScope {
        plugin: "",
        observables: None,
        effects: extra_effects,
    }];
    diagnose_scoped(obs, cfg, &everywhere)
}

/// Diagnoses paired observations; each plugin's composites apply only to
/// the observables of its scope, the catalogue to all. Settings built in
/// code are checked here; [`diagnose_checked`] takes settings already
/// checked (the engine's and the CLI's, read from `[diagnose]` once).
pub fn diagnose_scoped(
    obs: &arrow::array::RecordBatch,
    cfg: &DiagnoseConfig,
    scopes: &[EffectScope],
) -> Result<DiagnosisOutput> {
    cfg.check()?;
    run_diagnosis(obs.clone(), cfg, scopes)
}

/// [`diagnose_scoped`] with settings already checked: nothing is checked
/// or serialised again. Takes the observations by value: the text and
/// sim/real columns are let go once the rows are indexed (a fleet's
/// observations are most of the diagnosis' memory; docs/scale.md).
pub fn diagnose_checked(
    obs: arrow::array::RecordBatch,
    cfg: &Checked<DiagnoseConfig>,
    scopes: &[EffectScope],
) -> Result<DiagnosisOutput> {
    run_diagnosis(obs, cfg, scopes)
}

/// The diagnosis proper, on settings its caller checked.
fn run_diagnosis(
    obs: arrow::array::RecordBatch,
    cfg: &DiagnoseConfig,
    scopes: &[EffectScope],
) -> Result<DiagnosisOutput> {
    let batch = observations::validate_observations(&obs, Path::new("<observations>"))?;
    drop(obs);
    let table = Table::from_batch(&batch)?;
    // From here on the rows are the table's ids, gap and covariates (the
    // batch's covariate buffers, shared); the per-machine diagnoses
    // rebuild a batch from them (`Table::rebuild`).
    drop(batch);
    diagnose_table(table, cfg, scopes, None, &|_| {})
}

/// The diagnosis of an indexed table (its covariates in memory or read per
/// observable from a file). `results_dir`: where each observable's per-row
/// results wait for diagnosis.parquet (a folder of the output, removed
/// with the output's `per_row`); None holds them in memory.
/// `progress` is told each observable as its diagnosis starts (a large
/// fleet's take minutes each).
pub fn diagnose_table(
    table: Table,
    cfg: &DiagnoseConfig,
    scopes: &[EffectScope],
    results_dir: Option<&Path>,
    progress: &dyn Fn(&str),
) -> Result<DiagnosisOutput> {
    let mut notes = Notes::default();
    for d in &table.dropped {
        notes.add(format!("covariate {d} has no finite value: skipped"));
    }
    candidates::check_wanted(cfg, scopes)?;
    let mut acc = match results_dir {
        Some(dir) => Accum::spilled(per_row::ResultSpill::create(dir)?),
        None => Accum::fleet(table.n),
    };
    let n_obs = table.obs_names.len();
    for oi in 0..n_obs {
        // An observable of a large fleet takes minutes: say which.
        progress(&format!(
            "diagnosing the sim-to-real gap: {} ({} of {n_obs})",
            table.obs_names[oi],
            oi + 1
        ));
        diagnose_observable(&table, oi, cfg, scopes, results_dir, &mut acc, &mut notes)?;
        // An observable's working set (its covariates, pooled cells, fold
        // targets) is freed in pieces the allocator keeps between live
        // allocations; given back here, the next observable starts from
        // the pages it needs (sparkout_core::alloc).
        sparkout_core::alloc::release_freed_memory();
    }
    let several_machines = table.machine_names.len() > 1;
    output::assemble(table, cfg, acc, notes, |table, d| {
        if several_machines {
            machines::localised_effects(table, d, cfg, scopes)
        } else {
            Ok(Vec::new())
        }
    })
}

/// One observable: gather, a plain pass, and — when it leaves isolated
/// spikes in its residual — a second pass without them (outliers.rs).
/// `scratch`: where large covariates wait in a column file
/// (`covariates`).
fn diagnose_observable(
    table: &Table,
    oi: usize,
    cfg: &DiagnoseConfig,
    scopes: &[EffectScope],
    scratch: Option<&Path>,
    acc: &mut Accum,
    notes: &mut Notes,
) -> Result<()> {
    let mut clock = StepClock::new(format!("{}: observable", table.obs_names[oi]));
    let mut o = gather::gather(table, oi, scratch, notes)?;
    clock.lap("gather");
    // Each pass's accumulator holds a slot per row of the observable (not
    // per row of the fleet): slot p is table row `o.rows[p]`. Its per-row
    // columns are the selection's, moved in when the pass records them.
    let mut plain = Accum::new(0);
    let mut plain_notes = Notes::default();
    let slots = Slots {
        trimmed: &[],
        trimmed_slots: &[],
        trimmed_covs: &[],
        trimmed_gap: &[],
    };
    // The spikes are found in the plain pass's held-out residual as soon as
    // its selection is done; when there are some, the rest of the plain
    // pass (intervals, machine tests, cells, …) would be thrown away, so it
    // stops there and only its residual stays (the trim report's).
    // The trim report is made as the spikes are found, from the plain
    // residual, which is then let go (8 B a row through the second pass).
    let mut found = None;
    let mut trim_report = None;
    let mut spikes_end_the_pass = |residual: &[f64]| {
        let d = outliers::detect(&o, residual);
        if let Ok((out, sigma, thr)) = &d {
            if !out.is_empty() {
                trim_report = Some(outliers::report(
                    &o,
                    out,
                    residual,
                    &table.run_names,
                    &table.run,
                    *sigma,
                    *thr,
                ));
            }
        }
        let spikes = trim_report.is_some();
        found = Some(d);
        !spikes
    };
    analyse(
        table,
        &o,
        oi,
        cfg,
        scopes,
        &mut plain,
        &mut plain_notes,
        &slots,
        &mut spikes_end_the_pass,
    )?;
    clock.lap("plain pass");
    let found = found.expect("the plain pass selects before it can stop");
    let (out, thr) = match found {
        Ok((out, _, thr)) => (out, thr),
        Err(why) => {
            notes.add(why);
            (Vec::new(), f64::NAN)
        }
    };
    if out.is_empty() {
        for n in plain_notes.into_vec() {
            notes.add(n);
        }
        // The covariates are done with; the results are written without
        // them held.
        o.cols = covariates::Covariates::none(0);
        acc.merge(plain, oi as u32, &o.rows, &o.gap)?;
        clock.lap("results");
        clock.done();
        return Ok(());
    }
    drop(plain);
    let before: f64 = o.gap.iter().map(|g| g * g).sum();
    // The robust pass reads `kept`'s rows and the trimmed rows' covariates
    // (their contributions); the full rows' table rows are put together
    // again from both at the end (where the results go).
    let n = o.n();
    let trimmed_covs: Vec<(String, Vec<f64>)> = o.cols.at(&out)?;
    let trimmed_gap: Vec<f64> = out.iter().map(|&p| o.gap[p]).collect();
    let trimmed: Vec<usize> = out.iter().map(|&p| o.rows[p]).collect();
    let mut kept = o.take_kept(&out, scratch)?;
    clock.lap("trim");
    let mut robust = Accum::new(0);
    let slots = Slots {
        trimmed: &trimmed,
        trimmed_slots: &out,
        trimmed_covs: &trimmed_covs,
        trimmed_gap: &trimmed_gap,
    };
    analyse(
        table,
        &kept,
        oi,
        cfg,
        scopes,
        &mut robust,
        notes,
        &slots,
        &mut |_| true,
    )?;
    clock.lap("spike-free pass");
    // The kept rows' gaps and table rows outlive their covariates (the
    // per-row results').
    let kept_gap = std::mem::take(&mut kept.gap);
    let kept_rows = std::mem::take(&mut kept.rows);
    drop(kept);
    let after: f64 = robust.residual_all.iter().map(|r| r.powi(2)).sum();
    let rep = trim_report.expect("made when the spikes were found");
    notes.add(format!(
        "{}: {} isolated outliers ({:.2} % of rows, |residual| > {}σ robust = {}) trimmed from fits and scores",
        o.name,
        rep.n,
        100.0 * rep.share,
        outliers::K_SIGMA,
        crate::units::format::show_in(thr, &table.obs_units[oi])
    ));
    if let Some(s) = robust.summaries.last_mut() {
        s.shrink_plain = (before > 0.0).then(|| 1.0 - (after / before).sqrt());
        s.outliers = Some(rep);
    }
    // Every row's gap again, kept and trimmed in slot order, for the
    // per-row results.
    let gap = interleave(&kept_gap, &out, &trimmed_gap);
    drop(kept_gap);
    let rows = interleave(&kept_rows, &out, &trimmed);
    drop(kept_rows);
    debug_assert_eq!(rows.len(), n);
    acc.merge(robust, oi as u32, &rows, &gap)?;
    clock.lap("results");
    clock.done();
    Ok(())
}

/// The sequence whose positions `at` (ascending) hold `at_values` and
/// whose other positions hold `rest`, in order.
fn interleave<T: Copy>(rest: &[T], at: &[usize], at_values: &[T]) -> Vec<T> {
    let n = rest.len() + at.len();
    let mut out = Vec::with_capacity(n);
    let (mut r, mut a) = (rest.iter(), at.iter().zip(at_values).peekable());
    for p in 0..n {
        match a.next_if(|(&q, _)| q == p) {
            Some((_, v)) => out.push(*v),
            None => out.push(*r.next().expect("positions tile the sequence")),
        }
    }
    out
}

/// Where one pass over an observable writes its per-row results in its
/// accumulator (a slot per row of the observable's gather): the analysed
/// rows, in order, to every slot but the trimmed ones; trimmed outlier k
/// (table row `trimmed[k]`), which gets the all-runs fits' contributions,
/// to `trimmed_slots[k]`.
pub struct Slots<'a> {
    pub trimmed: &'a [usize],
    /// Ascending.
    pub trimmed_slots: &'a [usize],
    /// The trimmed rows' covariates (name, values in `trimmed` order).
    pub trimmed_covs: &'a [(String, Vec<f64>)],
    /// The trimmed rows' gaps (in `trimmed` order).
    pub trimmed_gap: &'a [f64],
}

impl Slots<'_> {
    /// The slot of each analysed row, in row order, of `n_slots` slots:
    /// worked out as they are read rather than listed (8 B a row).
    pub fn analysed(&self, n_slots: usize) -> impl Iterator<Item = usize> + '_ {
        let mut trimmed = self.trimmed_slots.iter().peekable();
        (0..n_slots).filter(move |s| trimmed.next_if_eq(&s).is_none())
    }

    /// The analysed rows' values `v` (row order) moved in place to their
    /// slots of `n_slots`, the trimmed slots 0: from the back, so a value
    /// is read before its place is written.
    pub fn spread(&self, v: &mut Vec<f64>, n_slots: usize) {
        assert_eq!(
            v.len() + self.trimmed_slots.len(),
            n_slots,
            "a value per analysed row"
        );
        let mut src = v.len();
        // Exactly (growth would double a column's capacity).
        v.reserve_exact(n_slots - src);
        v.resize(n_slots, 0.0);
        let mut t = self.trimmed_slots.len();
        for slot in (0..n_slots).rev() {
            if t > 0 && self.trimmed_slots[t - 1] == slot {
                v[slot] = 0.0;
                t -= 1;
            } else {
                src -= 1;
                v[slot] = v[src];
            }
        }
    }
}

/// noise → folds → candidates → select → intervals → machines → cells for
/// the rows of `o`, into `acc` at `slots`. `go_on` sees the selection's
/// held-out residual (row order of `o`); false ends the pass there, and
/// the caller drops `acc`.
#[allow(clippy::too_many_arguments)]
fn analyse(
    table: &Table,
    o: &gather::ObsRows,
    oi: usize,
    cfg: &DiagnoseConfig,
    scopes: &[EffectScope],
    acc: &mut Accum,
    notes: &mut Notes,
    slots: &Slots,
    go_on: &mut dyn FnMut(&[f64]) -> bool,
) -> Result<()> {
    let n = o.n();
    let mut clock = StepClock::new(format!("{}: {n} rows diagnosed", o.name));
    let nf = noise::floor_of(table, o)?;
    clock.lap("noise");
    let fo = folds::folds(o, cfg.folds, cfg.seed, oi);
    acc.blocked |= fo.blocked;
    acc.folds_used = acc.folds_used.max(fo.k);
    let prob = select::Problem {
        x: &o.cols,
        gap: &o.gap,
        units: fo.units,
        unit_fold: fo.unit_fold,
        unit_run: fo.unit_group,
        k: fo.k,
        frames: o.cols.frames().map(|(c, s)| (c.clone(), s)).collect(),
    };
    let names = o.names();
    let builtin = catalogue(&names);
    let cands = candidates::candidates(cfg, &o.name, &names, &builtin, scopes, notes);
    // Is there a gap above noise at all? F-test of the whole observable
    // plus the practical margin (σ̂ is an estimate; see cells.rs).
    let ms = o.gap.iter().map(|g| g * g).sum::<f64>() / n as f64;
    let rms = ms.sqrt();
    let p_gap = cells::cell_p(ms, n, nf.sigma_mm, nf.df);
    let above = p_gap < cfg.alpha && rms > cfg.noise_margin * nf.sigma_mm;
    let opt = select::SelectOptions {
        alpha: cfg.alpha,
        noise_margin: cfg.noise_margin,
        sigma_mm: nf.sigma_mm,
        gap_unit: table.obs_units[oi].clone(),
        max_effects: cfg.max_effects,
        min_gain: cfg.min_gain,
        min_frequency: cfg.min_selection_frequency,
        min_gap_share: cfg.min_gap_share,
        seed: cfg.seed ^ (oi as u64).wrapping_mul(0xA24B_AED4_963E_E407),
        allow_selection: above,
    };
    clock.lap("folds, candidates");
    let mut sel = select::select(&prob, &cands, &opt)?;
    // The selection's chunks, pools and features, freed across the
    // worker threads' arenas, go back before the steps after it take
    // theirs (the observable's peak is otherwise what the arenas kept).
    sparkout_core::alloc::release_freed_memory();
    clock.lap("select");
    if !go_on(&sel.residual) {
        clock.done();
        return Ok(());
    }
    let machine_tests = output::machine_tests(table, o, &prob, &cands, &sel)?;
    clock.lap("machine tests");
    let ivs = intervals::chosen_intervals(&cands, &prob, &sel, &o.run_ranges, cfg.seed);
    clock.lap("intervals");
    acc.effects.extend(output::effect_entries(
        &o.name,
        &table.obs_units[oi],
        n,
        &cands,
        &sel,
        &machine_tests,
        &ivs,
        cfg,
    ));
    // Cells of this observable: covariates, then machines — before the
    // per-row results take the selection's residual.
    let mut cs = cells::cells(&o.cols, &o.gap, &sel.residual)?;
    cs.extend(cells::machine_cells(
        &o.run_ranges,
        &o.run_machine,
        &table.machine_names,
        &o.gap,
        &sel.residual,
    ));
    clock.lap("cells");
    let obs_selected =
        output::record_selected(o, &prob, &cands, &mut sel, nf.sigma_mm, slots, acc)?;
    clock.lap("per-row results");
    if !above {
        notes.add(format!("{}: no gap above noise", o.name));
    }
    let sse_b: f64 = sel.unit_sse_gap.iter().sum();
    let sse_a: f64 = sel.unit_sse_after.iter().sum();
    let (rb, ra) = ((sse_b / n as f64).sqrt(), (sse_a / n as f64).sqrt());
    let selected_covs: Vec<String> = {
        let mut v: Vec<String> = sel
            .chosen
            .iter()
            .flat_map(|&ci| cands[ci].covariates())
            .collect();
        v.sort();
        v.dedup();
        v
    };
    let mut collinear = collinear::collinear(
        &o.cols,
        &o.run_ranges,
        &selected_covs,
        cfg.collinear_r,
        cfg.collinear_vif,
    )?;
    for r in sel.records.iter().filter(|r| r.selected) {
        let own = cands[r.idx].covariates();
        // Every indistinguishable rival passed too: its round's SSE is there.
        let rival = |&(i, sse): &(usize, f64)| collinear::Rival {
            key: cands[i].key(),
            covariates: cands[i].covariates(),
            rms: (sse / n as f64).sqrt(),
        };
        // The rivals that remove nearly as much of the round's held-out
        // gap as the selected effect (docs/models.md §8.6).
        let removed = r.sse_before - r.sse_after;
        let passed: Vec<collinear::Rival> = r
            .also_passed
            .iter()
            .filter(|(_, sse)| r.sse_before - sse >= cfg.confound_share * removed)
            .map(rival)
            .collect();
        let indistinguishable: Vec<collinear::Rival> = r
            .also_passed
            .iter()
            .filter(|(i, _)| r.indistinguishable.contains(i))
            .map(rival)
            .collect();
        for c in collinear.iter_mut().filter(|c| own.contains(&c.covariate)) {
            c.add_confounds(&indistinguishable, true);
            c.add_confounds(&passed, false);
        }
    }
    clock.lap("collinear");
    let minor: Vec<String> = sel
        .records
        .iter()
        .filter(|r| r.minor && !r.selected)
        .map(|r| cands[r.idx].key())
        .collect();
    acc.summaries.push(ObservableSummary {
        observable: o.name.clone(),
        unit: table.obs_units[oi].clone(),
        n,
        runs: o.run_ranges.len(),
        machines: if table.has_machine {
            o.machines()
                .iter()
                .map(|&m| table.machine_names[m as usize].clone())
                .collect()
        } else {
            Vec::new()
        },
        rms_mm: rms,
        noise_floor_mm: nf.sigma_mm,
        noise_floor_source: nf.source.as_str().into(),
        gap_above_noise: above,
        p_value: p_gap,
        selected: obs_selected,
        minor,
        collinear,
        cv_rms_before_mm: rb,
        cv_rms_after_mm: ra,
        shrink: if rb > 0.0 { 1.0 - ra / rb } else { 0.0 },
        shrink_interval: intervals::shrink_interval(
            &sel.unit_sse_gap,
            &sel.unit_sse_after,
            cfg.seed ^ oi as u64,
        ),
        shrink_plain: None,
        outliers: None,
        stop_reason: sel.stop_reason.clone(),
    });
    clock.done();
    acc.cells.extend(cs.into_iter().map(|cell| ObsCell {
        observable: o.name.clone(),
        sigma_mm: nf.sigma_mm,
        df: nf.df,
        cell,
    }));
    Ok(())
}

#[cfg(test)]
mod augment_tests;
#[cfg(test)]
pub(crate) mod tests;

#[cfg(test)]
mod interleave_tests {
    #[test]
    fn values_spread_in_place_land_where_the_analysed_slots_say() {
        for trimmed in [vec![], vec![0], vec![5], vec![0, 2, 3, 6], vec![1, 4]] {
            let n = 7;
            let slots = super::Slots {
                trimmed: &[],
                trimmed_slots: &trimmed,
                trimmed_covs: &[],
                trimmed_gap: &[],
            };
            let values: Vec<f64> = (0..n - trimmed.len()).map(|i| 10.0 + i as f64).collect();
            let mut expected = vec![0.0; n];
            for (slot, v) in slots.analysed(n).zip(&values) {
                expected[slot] = *v;
            }
            let mut v = values.clone();
            slots.spread(&mut v, n);
            assert_eq!(v, expected, "trimmed {trimmed:?}");
        }
    }

    #[test]
    fn values_at_positions_interleave_with_the_rest_in_order() {
        let rest = [10.0, 11.0, 12.0];
        assert_eq!(
            super::interleave(&rest, &[0, 2, 5], &[0.5, 2.5, 5.5]),
            vec![0.5, 10.0, 2.5, 11.0, 12.0, 5.5]
        );
        assert_eq!(super::interleave(&rest, &[], &[]), rest.to_vec());
        assert_eq!(super::interleave(&[], &[0, 1], &[1.0, 2.0]), vec![1.0, 2.0]);
    }
}

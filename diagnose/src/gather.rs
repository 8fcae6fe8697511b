//! Step 1, gather: the rows of one observable, sorted by run unit — a
//! (machine, run) pair — then time, with the covariates that
//! apply to it.

use std::ops::Range;

use rayon::prelude::*;

use super::covariates::{ColumnFile, Covariates};
use super::effect::{run_span_of, CovStats};
use super::observations::Table;
use super::Notes;

/// The rows of one observable and what the later steps read from them.
pub struct ObsRows {
    pub name: String,
    /// Indices into the table, sorted by run unit, then t_s, then input order.
    pub rows: Vec<usize>,
    pub gap: Vec<f64>,
    /// Contiguous ranges of `rows` per run unit.
    pub run_ranges: Vec<Range<usize>>,
    /// Machine id (into `Table::machine_names`) of each run range (a run
    /// unit is one machine's run): 4 B a run, not a row.
    pub run_machine: Vec<u32>,
    /// Varying covariates with a finite value on every row (in memory, or
    /// in a column file of the scratch folder: `crate::covariates`).
    pub cols: Covariates,
}

impl ObsRows {
    pub fn n(&self) -> usize {
        self.rows.len()
    }
    pub fn names(&self) -> Vec<String> {
        self.cols.names().to_vec()
    }
    /// Distinct machine ids of this observable, ascending.
    pub fn machines(&self) -> Vec<u32> {
        let mut m = self.run_machine.clone();
        m.sort_unstable();
        m.dedup();
        m
    }

    /// Each row's machine id (a column as long as the rows: for the steps
    /// that refit on rows).
    pub fn machine_of_rows(&self) -> Vec<u32> {
        let mut m = Vec::with_capacity(self.n());
        for (r, &id) in self.run_ranges.iter().zip(&self.run_machine) {
            m.extend(std::iter::repeat_n(id, r.len()));
        }
        m
    }
}

/// The rows of observable `oi`. `scratch`: a folder where its covariates
/// go to a column file when they exceed the in-memory budget
/// (`crate::covariates`); read there a chunk at a time, they never all
/// sit in memory.
pub fn gather(
    table: &Table,
    oi: usize,
    scratch: Option<&std::path::Path>,
    notes: &mut Notes,
) -> crate::Result<ObsRows> {
    let budget = crate::covariates::in_memory_budget();
    gather_within(table, oi, scratch, budget, notes)
}

/// [`gather`] with covariates of more than `max_bytes` to the file.
pub(crate) fn gather_within(
    table: &Table,
    oi: usize,
    scratch: Option<&std::path::Path>,
    max_bytes: usize,
    notes: &mut Notes,
) -> crate::Result<ObsRows> {
    let oname = &table.obs_names[oi];
    // The observable's rows in table order, their gaps and covariates
    // read once.
    let asc: Vec<usize> = table.obs.rows_where(|o| o as usize == oi);
    let names = table.values.names();
    let to_file = scratch.filter(|_| asc.len() * names.len() * 8 > max_bytes);
    let (asc_gap, mut values) = match to_file {
        None => {
            let crate::observations::Gathered { gap, covariates } =
                table.values.gather(&table.obs, &asc)?;
            (gap, Values::Memory(covariates))
        }
        Some(dir) => {
            let file = ColumnFile::create(dir, asc.len(), names.len())?;
            let mut gap = Vec::with_capacity(asc.len());
            table
                .values
                .gather_chunks(&table.obs, &asc, &mut |start, g, covs| {
                    gap.extend_from_slice(g);
                    for (k, c) in covs.iter().enumerate() {
                        file.write(k, start, c)?;
                    }
                    Ok(())
                })?;
            (gap, Values::File(file))
        }
    };
    let asc_run = table.run.at(&asc);
    let t_col = names.iter().position(|n| n == "t_s");
    let t: Option<std::borrow::Cow<[f64]>> = match (&values, t_col) {
        (_, None) => None,
        (Values::Memory(v), Some(k)) => Some(std::borrow::Cow::Borrowed(&v[k])),
        (Values::File(f), Some(k)) => Some(std::borrow::Cow::Owned(f.column(k)?)),
    };
    // Sorted by run unit, then time (total order), then table order:
    // `order[p]` is the position in `asc` of the p-th row. Each row's three
    // keys are packed into one integer and sorted as integers — a
    // comparison sort reaching into the run and time columns at random was
    // most of gathering a table not in run order.
    if u32::try_from(asc.len()).is_err() {
        return Err(crate::err!(
            "{oname}: {} rows of one observable: at most {} are supported",
            asc.len(),
            u32::MAX
        ));
    }
    let t_key = |p: usize| {
        t.as_ref()
            .map_or(0, |t| super::effect::total_order_key(t[p]))
    };
    // A table in run and time order (as the join writes it) is in that
    // order already — seen in one pass, without the keys and the order
    // (24 B a row) — and its columns are taken as they are, not copied
    // while the originals are held (a second copy of every column).
    let in_order = (1..asc.len()).all(|p| (asc_run[p - 1], t_key(p - 1)) <= (asc_run[p], t_key(p)));
    let order: Vec<usize> = if in_order {
        Vec::new()
    } else {
        let mut keyed: Vec<u128> = (0..asc.len())
            .map(|p| (u128::from(asc_run[p]) << 96) | (u128::from(t_key(p)) << 32) | p as u128)
            .collect();
        keyed.sort_unstable();
        keyed.into_iter().map(|k| k as u32 as usize).collect()
    };
    drop(t);
    let permuted = |v: Vec<f64>| -> Vec<f64> {
        if in_order {
            v
        } else {
            order.iter().map(|&p| v[p]).collect()
        }
    };
    let (rows, run): (Vec<usize>, Vec<u32>) = if in_order {
        (asc, asc_run)
    } else {
        let rows = order.iter().map(|&p| asc[p]).collect();
        (rows, order.iter().map(|&p| asc_run[p]).collect())
    };
    let n = rows.len();
    let gap = permuted(asc_gap);
    let mut run_ranges: Vec<Range<usize>> = Vec::new();
    let mut s = 0;
    for i in 1..=n {
        if i == n || run[i] != run[s] {
            run_ranges.push(s..i);
            s = i;
        }
    }
    drop(run);
    // A run unit is one machine's run: its first row's machine.
    let run_machine: Vec<u32> = table
        .machine
        .at(&run_ranges.iter().map(|r| rows[r.start]).collect::<Vec<_>>());
    // Covariates: in the rows' order, how many rows have a value, and
    // their constants (frames) — in memory, or a column at a time from
    // the file (each read, put in order and sorted in place: two columns
    // at a time, one per core).
    let checked: Vec<(usize, CovStats, Option<Vec<f64>>)> = match &mut values {
        Values::Memory(v) => std::mem::take(v)
            .into_par_iter()
            .enumerate()
            .map(|(k, col)| {
                let col = permuted(col);
                let finite = col.iter().filter(|v| v.is_finite()).count();
                let span = run_span_of(&names[k], &col, &run_ranges);
                let st = CovStats::from_values(&col).with_run_span(span);
                (finite, st, Some(col))
            })
            .collect(),
        Values::File(f) => (0..names.len())
            .into_par_iter()
            .with_max_len(1)
            .map(|k| -> crate::Result<_> {
                let mut col = f.column(k)?;
                if !in_order {
                    col = permuted(col);
                    f.write(k, 0, &col)?;
                }
                let finite = col.iter().filter(|v| v.is_finite()).count();
                let span = run_span_of(&names[k], &col, &run_ranges);
                let st = CovStats::from_values_in_place(&mut col).with_run_span(span);
                Ok((finite, st, None))
            })
            .collect::<crate::Result<_>>()?,
    };
    let (mut kept, mut kept_at, mut stats) = (Vec::new(), Vec::new(), Vec::new());
    for (k, (name, (finite, st, col))) in names.iter().zip(checked).enumerate() {
        // A covariate belongs to the observables whose rows carry it
        // (docs/formats.md §7: a fleet table mixes observables, each with its
        // own covariates; the others are null there). Absent for every
        // row of this observable → not applicable; absent for some →
        // skipped and said.
        if finite == 0 {
            continue;
        }
        if finite < n {
            notes.add(format!(
                "{oname}: covariate {name} is missing (null/NaN) in {} of {n} rows: skipped",
                n - finite,
            ));
            continue;
        }
        if st.is_constant() {
            notes.add(format!("constant covariate {name} skipped"));
        } else {
            kept.push((name.clone(), col));
            kept_at.push(k);
            stats.push(st);
        }
    }
    if names.is_empty() {
        notes.add("no covariates: offset only".into());
    } else if kept.is_empty() {
        notes.add(format!("{oname}: no varying covariates: offset only"));
    }
    let cols = match values {
        Values::Memory(_) => Covariates::held(
            n,
            kept.into_iter()
                .map(|(c, v)| (c, v.expect("held in memory")))
                .collect(),
            stats,
        ),
        Values::File(f) => Covariates::in_file(
            n,
            f,
            kept_at,
            kept.into_iter().map(|c| c.0).collect(),
            stats,
        ),
    };
    Ok(ObsRows {
        name: oname.clone(),
        rows,
        gap,
        run_ranges,
        run_machine,
        cols,
    })
}

/// An observable's covariates as gathered: in memory (in `names` order),
/// or in a column file (column k: covariate k).
enum Values {
    Memory(Vec<Vec<f64>>),
    File(ColumnFile),
}

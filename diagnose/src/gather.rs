//! Step 1, gather: the rows of one observable, sorted by run unit — a
//! (machine, run) pair — then time, with the covariates that
//! apply to it.

use std::ops::Range;

use rayon::prelude::*;

use super::effect::CovStats;
use super::observations::Table;
use super::Notes;

/// One covariate of an observable: values in row order and constants (its
/// sorted values are not kept: the cells sort again, one covariate at a
/// time, rather than hold a second copy of every covariate through the
/// analysis).
pub struct Cov {
    pub name: String,
    pub v: Vec<f64>,
    pub stats: CovStats,
}

impl Cov {
    /// A covariate and its constants (from its values sorted).
    pub fn new(name: String, v: Vec<f64>) -> Cov {
        let stats = CovStats::from_values(&v);
        Cov { name, v, stats }
    }
}

/// The rows of one observable and what the later steps read from them.
pub struct ObsRows {
    pub name: String,
    /// Indices into the table, sorted by run unit, then t_s, then input order.
    pub rows: Vec<usize>,
    pub gap: Vec<f64>,
    /// Contiguous ranges of `rows` per run unit.
    pub run_ranges: Vec<Range<usize>>,
    /// Machine id (into `Table::machine_names`) per row of `rows`.
    pub machine: Vec<u32>,
    /// Varying covariates with a finite value on every row.
    pub cols: Vec<Cov>,
}

impl ObsRows {
    pub fn n(&self) -> usize {
        self.rows.len()
    }
    pub fn names(&self) -> Vec<String> {
        self.cols.iter().map(|c| c.name.clone()).collect()
    }
    /// Distinct machine ids of this observable, ascending.
    pub fn machines(&self) -> Vec<u32> {
        let mut m = self.machine.clone();
        m.sort_unstable();
        m.dedup();
        m
    }
}

pub fn gather(table: &Table, oi: usize, notes: &mut Notes) -> crate::Result<ObsRows> {
    let oname = &table.obs_names[oi];
    // The observable's rows in table order, their gaps and covariates
    // read once.
    let asc: Vec<usize> = table.obs.rows_where(|o| o as usize == oi);
    let names = table.values.names();
    let crate::observations::Gathered {
        gap: asc_gap,
        covariates: values,
    } = table.values.gather(&table.obs, &asc)?;
    let asc_run = table.run.at(&asc);
    let t = names.iter().position(|n| n == "t_s").map(|k| &values[k]);
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
    let mut keyed: Vec<u128> = (0..asc.len())
        .map(|p| {
            let t_key = t.map_or(0, |t| super::effect::total_order_key(t[p]));
            (u128::from(asc_run[p]) << 96) | (u128::from(t_key) << 32) | p as u128
        })
        .collect();
    keyed.sort_unstable();
    let order: Vec<usize> = keyed.into_iter().map(|k| k as u32 as usize).collect();
    // A table in run and time order (as the join writes it) is in that
    // order already: its columns are taken as they are, not copied while
    // the originals are held (a second copy of every column).
    let in_order = order.iter().enumerate().all(|(i, &p)| i == p);
    let permuted = |v: Vec<f64>| -> Vec<f64> {
        if in_order {
            v
        } else {
            order.iter().map(|&p| v[p]).collect()
        }
    };
    let rows: Vec<usize> = if in_order {
        asc
    } else {
        order.iter().map(|&p| asc[p]).collect()
    };
    let run: Vec<u32> = order.iter().map(|&p| asc_run[p]).collect();
    drop(asc_run);
    let n = rows.len();
    let gap = permuted(asc_gap);
    let machine: Vec<u32> = table.machine.at(&rows);
    let mut run_ranges: Vec<Range<usize>> = Vec::new();
    let mut s = 0;
    for i in 1..=n {
        if i == n || run[i] != run[s] {
            run_ranges.push(s..i);
            s = i;
        }
    }
    // Covariates: in the rows' order, with their constants (frames).
    let gathered: Vec<Cov> = names
        .par_iter()
        .zip(values.into_par_iter())
        .map(|(name, v)| Cov::new(name.clone(), permuted(v)))
        .collect();
    let mut cols = Vec::new();
    for c in gathered {
        // A covariate belongs to the observables whose rows carry it
        // (docs/formats.md §7: a fleet table mixes observables, each with its
        // own covariates; the others are null there). Absent for every
        // row of this observable → not applicable; absent for some →
        // skipped and said.
        let finite = c.v.iter().filter(|v| v.is_finite()).count();
        if finite == 0 {
            continue;
        }
        if finite < c.v.len() {
            notes.add(format!(
                "{oname}: covariate {} is missing (null/NaN) in {} of {} rows: skipped",
                c.name,
                c.v.len() - finite,
                c.v.len()
            ));
            continue;
        }
        if c.stats.is_constant() {
            notes.add(format!("constant covariate {} skipped", c.name));
        } else {
            cols.push(c);
        }
    }
    if table.values.names().is_empty() {
        notes.add("no covariates: offset only".into());
    } else if cols.is_empty() {
        notes.add(format!("{oname}: no varying covariates: offset only"));
    }
    Ok(ObsRows {
        name: oname.clone(),
        rows,
        gap,
        run_ranges,
        machine,
        cols,
    })
}

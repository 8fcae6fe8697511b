//! Step 3, folds: run units — (machine, run) pairs — are dealt
//! to k folds by a seeded shuffle; with fewer than [`MIN_UNITS`] units the
//! held-out runs are scored in contiguous blocks so the paired test has
//! enough pairs; a single run is cut into k blocks (select.rs explains why
//! units never straddle runs).

use std::ops::Range;

use rand::seq::SliceRandom;
use rand::SeedableRng;

use super::gather::ObsRows;

/// Fewer scoring units than this: held-out runs are split into blocks.
pub const MIN_UNITS: usize = 6;

/// Whether `ranges` cover rows `0..n` in order, end to end — what the
/// scoring units and the run ranges of an observable do, and what the
/// passes that walk them one at a time instead of over all rows rely on.
pub fn tile(ranges: &[Range<usize>], n: usize) -> bool {
    ranges.windows(2).all(|w| w[0].end == w[1].start)
        && ranges.first().map_or(n == 0, |r| r.start == 0)
        && ranges.last().map_or(n == 0, |r| r.end == n)
}

pub struct Folds {
    /// Scoring units, contiguous, each inside one run unit.
    pub units: Vec<Range<usize>>,
    /// The fold that holds each unit out.
    pub unit_fold: Vec<usize>,
    /// The run (or, for a single run, the block) each unit lies in: the
    /// stability resamples draw these whole.
    pub unit_group: Vec<usize>,
    pub k: usize,
    /// A single run: blocks within it instead of runs.
    pub blocked: bool,
}

/// `oi` decorrelates the shuffles of different observables.
pub fn folds(o: &ObsRows, folds: usize, seed: u64, oi: usize) -> Folds {
    let n = o.n();
    let blocked = o.run_ranges.len() < 2;
    let (fold_groups, k): (Vec<Range<usize>>, usize) = if !blocked {
        (o.run_ranges.clone(), folds.min(o.run_ranges.len()))
    } else {
        let k = folds.min(n.max(1));
        ((0..k).map(|b| b * n / k..(b + 1) * n / k).collect(), k)
    };
    let mut order: Vec<usize> = (0..fold_groups.len()).collect();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(
        seed ^ (oi as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
    );
    order.shuffle(&mut rng);
    let mut group_fold = vec![0usize; fold_groups.len()];
    for (pos, &g) in order.iter().enumerate() {
        group_fold[g] = pos % k;
    }
    let split = if fold_groups.len() >= MIN_UNITS {
        1
    } else {
        MIN_UNITS.div_ceil(fold_groups.len())
    };
    let mut units = Vec::new();
    let mut unit_fold = Vec::new();
    let mut unit_group = Vec::new();
    for (g, r) in fold_groups.iter().enumerate() {
        let parts = split.min(r.len()).max(1);
        for b in 0..parts {
            let u = r.start + b * r.len() / parts..r.start + (b + 1) * r.len() / parts;
            if !u.is_empty() {
                units.push(u);
                unit_fold.push(group_fold[g]);
                unit_group.push(g);
            }
        }
    }
    Folds {
        units,
        unit_fold,
        unit_group,
        k,
        blocked,
    }
}

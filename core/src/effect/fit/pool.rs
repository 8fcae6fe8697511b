//! Pooling rows into cells of a form's covariates, one row range at a time
//! (the cell pass, docs/design.md §8).
//!
//! A [`CellPool`] holds the cells of several groups (a fold group of the
//! θ scan, [`super::fold_groups`]) on the fleet's grid: each covariate's
//! bins of a fixed width counted from a fixed minimum. A range of rows (a
//! run, or a block of one) is pooled on its own — sums in row order — and
//! its partial cells are added to its group's in the order the ranges
//! arrive. The partial cells of a range depend on nothing but its rows, so
//! feeding the ranges in canonical order gives the same bits whether they
//! come all at once, a chunk of runs at a time, or from nodes that each
//! held only their runs.

use std::collections::HashMap;
use std::ops::Range;

use super::Pooled;

/// At most this many bins per covariate: beyond that pooling saves nothing.
pub(super) const MAX_POOL_BINS: f64 = 65_536.0;

/// One covariate's grid: first bin's lower edge, bin width, bin count.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Axis {
    pub min: f64,
    pub width: f64,
    pub bins: usize,
}

impl Axis {
    /// The grid of a covariate whose values lie in `min ..= min + span`,
    /// cells `res` wide — wider when `span / res` would exceed
    /// [`MAX_POOL_BINS`].
    pub fn new(min: f64, span: f64, res: f64) -> Axis {
        let width = res.max(span / MAX_POOL_BINS).max(1e-300);
        Axis {
            min,
            width,
            bins: (span / width) as usize + 1,
        }
    }

    /// The bin of `x` (values past the last edge in the last bin).
    #[inline(always)]
    fn bin(&self, x: f64) -> usize {
        (((x - self.min) / self.width) as usize).min(self.bins - 1)
    }

    /// Bits a bin index needs.
    fn bits(&self) -> u32 {
        usize::BITS - self.bins.leading_zeros()
    }
}

/// The span of each column over all its values, counted from `mins`: what
/// [`Axis::new`] takes when the rows are at hand.
pub fn spans(cols: &[&[f64]], mins: &[f64]) -> Vec<f64> {
    cols.iter()
        .zip(mins)
        .map(|(c, &c_min)| c.iter().fold(0.0f64, |m, v| m.max(v - c_min)))
        .collect()
}

/// Cells of each group, filled range by range ([`CellPool::add_range`]),
/// read out by [`CellPool::finish`].
pub struct CellPool {
    axes: Vec<Axis>,
    /// Numbers per cell: the count, Σw·c per covariate, Σy per target.
    stride: usize,
    groups: Vec<GroupCells>,
    /// One covariate: a range's partial bins (dense, zero between ranges)
    /// and the bins it touched.
    part: Vec<f64>,
    part_touched: Vec<usize>,
}

/// One group's cells in the order first seen: the cell's key (its bin of
/// each covariate, packed) and `stride` sums.
#[derive(Default)]
struct GroupCells {
    /// One covariate: the slot of each bin (`u32::MAX`: none yet).
    dense: Vec<u32>,
    /// Several covariates: the slot of each key.
    sparse: HashMap<u128, u32>,
    keys: Vec<u128>,
    sums: Vec<f64>,
}

impl GroupCells {
    /// Adds a range's partial cell (`key`, `sums`) to the group's: the
    /// first range's sums are kept as they are, the later ones added in
    /// the order the ranges arrive.
    #[inline]
    fn add(&mut self, slot: &mut u32, key: u128, sums: &[f64]) {
        if *slot == u32::MAX {
            *slot = u32::try_from(self.keys.len()).expect("fewer than 2³² cells in a group");
            self.keys.push(key);
            self.sums.extend_from_slice(sums);
        } else {
            let s = sums.len();
            let at = *slot as usize * s;
            self.sums[at..at + s]
                .iter_mut()
                .zip(sums)
                .for_each(|(a, p)| *a += p);
        }
    }
}

impl CellPool {
    /// An empty pool of `groups` groups on `axes` (at most 128 bits of
    /// cell key: a form pools on one to three covariates) with `targets`
    /// sums of y per cell.
    pub fn new(axes: Vec<Axis>, targets: usize, groups: usize) -> CellPool {
        let key_bits: u32 = axes.iter().map(Axis::bits).sum();
        // More would merge cells silently, so it stops here.
        assert!(
            key_bits <= 128,
            "pooling on {} covariates: too many for a cell key",
            axes.len()
        );
        CellPool {
            stride: 1 + axes.len() + targets,
            axes,
            groups: (0..groups).map(|_| GroupCells::default()).collect(),
            part: Vec::new(),
            part_touched: Vec::new(),
        }
    }

    /// Pools rows `r` of `cols` (one per axis; `weights`: each row's count
    /// when the rows are themselves cells, else 1; `targets`: y of each
    /// target) into `group`'s cells.
    pub fn add_range(
        &mut self,
        group: usize,
        r: Range<usize>,
        cols: &[&[f64]],
        weights: Option<&[f64]>,
        targets: &[&[f64]],
    ) {
        assert_eq!(cols.len(), self.axes.len(), "a column per axis");
        assert_eq!(
            self.stride,
            1 + cols.len() + targets.len(),
            "a sum per target"
        );
        if let ([c], [axis]) = (cols, self.axes.as_slice()) {
            self.add_range_1d(group, r, c, *axis, weights, targets);
        } else {
            self.add_range_sorted(group, r, cols, weights, targets);
        }
    }

    /// One covariate: dense bins, no sort. The range's rows go into the
    /// partial bins (a bin's count, Σc and Σy of every target side by
    /// side, so a row touches one line), then the touched bins into the
    /// group's cells.
    fn add_range_1d(
        &mut self,
        group: usize,
        r: Range<usize>,
        c: &[f64],
        axis: Axis,
        weights: Option<&[f64]>,
        targets: &[&[f64]],
    ) {
        let stride = self.stride;
        self.part.resize(axis.bins * stride, 0.0);
        self.part_touched.clear();
        let bin_of = |x: f64| axis.bin(x);
        let rows = (c, &bin_of, weights, targets, r);
        let (bins, touched) = (&mut self.part, &mut self.part_touched);
        // The held sums a fixed-size array for the usual target counts
        // (5 folds: 6).
        match stride {
            3 => pool_range_held([0.0; 3], rows, bins, touched),
            4 => pool_range_held([0.0; 4], rows, bins, touched),
            5 => pool_range_held([0.0; 5], rows, bins, touched),
            6 => pool_range_held([0.0; 6], rows, bins, touched),
            7 => pool_range_held([0.0; 7], rows, bins, touched),
            8 => pool_range_held([0.0; 8], rows, bins, touched),
            _ => pool_range_held(vec![0.0; stride], rows, bins, touched),
        }
        let g = &mut self.groups[group];
        if g.dense.is_empty() {
            g.dense = vec![u32::MAX; axis.bins];
        }
        for &b in &self.part_touched {
            let p = &mut self.part[b * stride..(b + 1) * stride];
            let mut slot = g.dense[b];
            g.add(&mut slot, b as u128, p);
            g.dense[b] = slot;
            p.iter_mut().for_each(|v| *v = 0.0);
        }
    }

    /// Several covariates: too many cells for dense bins, so the range's
    /// rows are sorted by (cell, row) and equal cells summed in row order.
    /// The cell (each covariate's bin in as many bits as its bin count
    /// needs, first covariate highest) and the row within the range are
    /// packed into one integer when they fit: sorting 8-byte keys instead
    /// of (u128, usize) pairs is what a two-covariate form's scan spends
    /// its time on.
    fn add_range_sorted(
        &mut self,
        group: usize,
        r: Range<usize>,
        cols: &[&[f64]],
        weights: Option<&[f64]>,
        targets: &[&[f64]],
    ) {
        let bits: Vec<u32> = self.axes.iter().map(Axis::bits).collect();
        let key_bits: u32 = bits.iter().sum();
        let row_bits = usize::BITS - r.len().leading_zeros();
        let axes = &self.axes;
        let cell_of = |i: usize| -> u128 {
            (0..cols.len()).fold(0u128, |k, j| {
                (k << bits[j]) | axes[j].bin(cols[j][i]) as u128
            })
        };
        let rows = RangeOfRows {
            r,
            cols,
            weights,
            targets,
            stride: self.stride,
        };
        let g = &mut self.groups[group];
        let mask = (1u128 << row_bits) - 1;
        if key_bits + row_bits <= 64 {
            rows.sorted_cells(
                g,
                cell_of,
                |cell, i| ((cell << row_bits) | i as u128) as u64,
                |k| u128::from(k) >> row_bits,
                |k| (u128::from(k) & mask) as usize,
            )
        } else if key_bits + row_bits <= 128 {
            rows.sorted_cells(
                g,
                cell_of,
                |cell, i| (cell << row_bits) | i as u128,
                |k| k >> row_bits,
                |k| (k & mask) as usize,
            )
        } else {
            rows.sorted_cells(g, cell_of, |cell, i| (cell, i), |k| k.0, |k| k.1)
        }
    }

    /// The groups' cells, each group's in ascending cell order: pooled
    /// covariates (a cell's mean of each), counts, Σy per target, and each
    /// group's range of cells.
    pub fn finish(self) -> Pooled {
        let (nd, stride) = (self.axes.len(), self.stride);
        let nt = stride - 1 - nd;
        let n: usize = self.groups.iter().map(|g| g.keys.len()).sum();
        let mut xc: Vec<Vec<f64>> = (0..nd).map(|_| Vec::with_capacity(n)).collect();
        let mut w = Vec::with_capacity(n);
        let mut sy: Vec<Vec<f64>> = (0..nt).map(|_| Vec::with_capacity(n)).collect();
        let mut ranges = Vec::with_capacity(self.groups.len());
        for g in self.groups {
            let mut order: Vec<u32> = (0..g.keys.len() as u32).collect();
            order.sort_unstable_by_key(|&s| g.keys[s as usize]);
            let start = w.len();
            for s in order {
                let cell = &g.sums[s as usize * stride..(s as usize + 1) * stride];
                for (x, v) in xc.iter_mut().zip(&cell[1..=nd]) {
                    x.push(v / cell[0]);
                }
                w.push(cell[0]);
                for (t, v) in sy.iter_mut().zip(&cell[1 + nd..]) {
                    t.push(*v);
                }
            }
            ranges.push(start..w.len());
        }
        (xc, w, sy, ranges)
    }
}

/// The rows of one range as [`CellPool::add_range_sorted`] pools them.
struct RangeOfRows<'a> {
    r: Range<usize>,
    cols: &'a [&'a [f64]],
    weights: Option<&'a [f64]>,
    targets: &'a [&'a [f64]],
    stride: usize,
}

impl RangeOfRows<'_> {
    /// Pools the range's rows sorted by a key `make` packs of a row's cell
    /// and index within the range — ascending by cell, then row — from
    /// which `cell` and `row` are read back (the same cells and bits
    /// whatever the key's width), each cell's sums into the group.
    fn sorted_cells<K: Ord + Copy>(
        &self,
        g: &mut GroupCells,
        cell_of: impl Fn(usize) -> u128,
        make: impl Fn(u128, usize) -> K,
        cell: impl Fn(K) -> u128,
        row: impl Fn(K) -> usize,
    ) {
        let nd = self.cols.len();
        let start = self.r.start;
        let mut keyed: Vec<K> = self
            .r
            .clone()
            .map(|i| make(cell_of(i), i - start))
            .collect();
        keyed.sort_unstable();
        let mut sums = vec![0.0f64; self.stride];
        let mut a = 0;
        while a < keyed.len() {
            let key = cell(keyed[a]);
            sums.iter_mut().for_each(|v| *v = 0.0);
            while a < keyed.len() && cell(keyed[a]) == key {
                let i = start + row(keyed[a]);
                let wi = self.weights.map_or(1.0, |w| w[i]);
                sums[0] += wi;
                for (s, c) in sums[1..=nd].iter_mut().zip(self.cols) {
                    *s += wi * c[i];
                }
                for (s, y) in sums[1 + nd..].iter_mut().zip(self.targets) {
                    *s += y[i];
                }
                a += 1;
            }
            let mut slot = g.sparse.get(&key).copied().unwrap_or(u32::MAX);
            let new = slot == u32::MAX;
            g.add(&mut slot, key, &sums);
            if new {
                g.sparse.insert(key, slot);
            }
        }
    }
}

/// One covariate's rows of a range, as [`pool_range_held`] reads them:
/// the covariate, its bin, the weights, the targets, the rows.
type RangeRows<'a, B> = (
    &'a [f64],
    &'a B,
    Option<&'a [f64]>,
    &'a [&'a [f64]],
    Range<usize>,
);

/// A range's rows of one covariate into `bins` of `held.len()` sums
/// (count, Σc, Σy of each target), the current bin's sums held apart —
/// in registers when `held` is a small array — while consecutive rows stay
/// in it: a row's adds then wait on the previous add, not on its store and
/// reload. Each sum adds the same values in the same order as adding into
/// `bins` row by row (same bits).
fn pool_range_held<H: AsMut<[f64]>, B: Fn(f64) -> usize>(
    mut held: H,
    (c, bin_of, weights, targets, r): RangeRows<B>,
    bins: &mut [f64],
    touched: &mut Vec<usize>,
) {
    let held = held.as_mut();
    let s = held.len();
    assert_eq!(targets.len() + 2, s, "a sum per target, the count and Σc");
    let mut cur = usize::MAX;
    for i in r {
        let b = bin_of(c[i]);
        if b != cur {
            if cur != usize::MAX {
                bins[cur * s..(cur + 1) * s].copy_from_slice(held);
            }
            cur = b;
            held.copy_from_slice(&bins[b * s..(b + 1) * s]);
            if held[0] == 0.0 {
                touched.push(b);
            }
        }
        // × 1.0 is exact: rows pool to the same bits with or without weights.
        let wi = weights.map_or(1.0, |w| w[i]);
        held[0] += wi;
        held[1] += wi * c[i];
        for (h, y) in held[2..].iter_mut().zip(targets) {
            *h += y[i];
        }
    }
    if cur != usize::MAX {
        bins[cur * s..(cur + 1) * s].copy_from_slice(held);
    }
}

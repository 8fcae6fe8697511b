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
/// A bin marked by [`CellPool::count_range`], not numbered yet.
const COUNTED: u32 = u32::MAX - 1;

/// At most this many cells on the compact grid of several covariates
/// ([`Compact`]); beyond, the rows are sorted by cell instead. A thread's
/// partial bins are then as large as one covariate's at most
/// ([`MAX_POOL_BINS`]) with a few more sums per bin.
const MAX_COMPACT_CELLS: usize = 1 << 18;

/// Several covariates' grid numbered over the bins some row occupies (the
/// count pass, [`CellPool::count_range`]): a covariate with few distinct
/// values (a direction of ±1) spans thousands of fine bins but occupies
/// two, so the cells some row can fall in are few enough for dense slots —
/// the one-covariate path, no sort. A cell's index is its bins' ranks in
/// mixed radix, first covariate highest: ascending index is ascending
/// cell key, so the cells come out in the sorted path's order with the
/// same sums (same rows, same order of additions).
struct Compact {
    /// The pool's axes (a copy: the cell of a row is found while the
    /// pool's groups are borrowed to add it).
    axes: Vec<Axis>,
    /// Per covariate, each bin's rank among the occupied ones
    /// (`u32::MAX`: no counted row).
    rank: Vec<Vec<u32>>,
    /// Per covariate, the index step of one rank.
    radix: Vec<usize>,
    cells: usize,
}

impl Compact {
    /// The compact grid of `occupied` bins of `axes`, `None` when its
    /// cells would be more than [`MAX_COMPACT_CELLS`].
    fn of(axes: &[Axis], occupied: &[Vec<bool>]) -> Option<Compact> {
        let counts: Vec<usize> = occupied
            .iter()
            .map(|o| o.iter().filter(|&&b| b).count().max(1))
            .collect();
        let cells = counts
            .iter()
            .try_fold(1usize, |p, &c| p.checked_mul(c))
            .filter(|&c| c <= MAX_COMPACT_CELLS)?;
        let rank = occupied
            .iter()
            .map(|o| {
                let mut n = 0u32;
                o.iter()
                    .map(|&b| {
                        if b {
                            n += 1;
                            n - 1
                        } else {
                            u32::MAX
                        }
                    })
                    .collect()
            })
            .collect();
        let mut radix = vec![1; counts.len()];
        for j in (0..counts.len().saturating_sub(1)).rev() {
            radix[j] = radix[j + 1] * counts[j + 1];
        }
        Some(Compact {
            axes: axes.to_vec(),
            rank,
            radix,
            cells,
        })
    }

    /// The cell of row `i`.
    #[inline(always)]
    fn cell<const ND: usize>(&self, cols: [&[f64]; ND], i: usize) -> usize {
        let mut at = 0;
        let per_axis = self.rank.iter().zip(&self.axes).zip(&self.radix);
        for (c, ((rank, axis), radix)) in cols.iter().zip(per_axis) {
            let r = rank[axis.bin(c[i])];
            assert!(
                r != u32::MAX,
                "a row pooled that the count pass did not see"
            );
            at += r as usize * radix;
        }
        at
    }
}

pub struct CellPool {
    axes: Vec<Axis>,
    /// Numbers per cell: the count, Σw·c per covariate, Σy per target.
    stride: usize,
    groups: Vec<GroupCells>,
    /// The cells of groups `0..emitted`, in the form [`CellPool::finish`]
    /// returns: a group is moved here (and its own storage freed) as soon
    /// as it and every group before it are sealed.
    out: Pooled,
    emitted: usize,
    /// Several covariates: the bins some counted row occupies, per
    /// covariate ([`CellPool::count_range`]).
    occupied: Vec<Vec<bool>>,
    /// Several covariates, counted: their compact grid, when small enough.
    compact: Option<Compact>,
}

thread_local! {
    /// One covariate: a range's partial bins (dense, all zero between
    /// ranges) and the bins it touched — a thread's, not a pool's: a pass
    /// holds every candidate's pool at once, and 65 537 bins of 8 sums
    /// are 4 MiB.
    static PART: std::cell::RefCell<(Vec<f64>, Vec<usize>)> = const {
        std::cell::RefCell::new((Vec::new(), Vec::new()))
    };
}

/// One group's cells. One covariate, or several on a compact grid: a
/// dense slot per bin (cell), slots in the order first seen (or in bin
/// order, given up front). Several otherwise: `keys`/`sums` sorted by key, and the partial
/// cells of the ranges added since (`pending_*`, in arrival order) merged
/// into them when they outnumber them and at the end — a sort per merge
/// instead of a hash lookup per partial cell.
#[derive(Default)]
struct GroupCells {
    /// One covariate (or a compact grid): the slot of each bin (`u32::MAX`:
    /// none yet).
    dense: Vec<u32>,
    /// Several covariates: the merged cells' keys, ascending.
    keys: Vec<u128>,
    /// `stride` sums per cell: one covariate, in slot order until sealed;
    /// several, in key order.
    sums: Vec<f64>,
    /// Cells in ascending order at their size ([`GroupCells::seal`]).
    sealed: bool,
    /// One covariate: the slots were given in bin order up front, this
    /// many ([`CellPool::count_groups`]); the sums are allocated at that
    /// size when the first range comes.
    counted: Option<usize>,
    /// Several covariates: partial cells not merged yet, in arrival order.
    pending_keys: Vec<u128>,
    pending_sums: Vec<f64>,
}

impl GroupCells {
    /// Adds a range's partial bin (`sums`) to the group's cell in `slot`
    /// (one covariate): the first range's sums are kept as they are, the
    /// later ones added in the order the ranges arrive.
    #[inline(always)]
    fn add(&mut self, slot: &mut u32, sums: &[f64]) {
        let s = sums.len();
        if *slot == u32::MAX {
            *slot = u32::try_from(self.sums.len() / s).expect("fewer than 2³² cells in a group");
            self.sums.extend_from_slice(sums);
        } else {
            let at = *slot as usize * s;
            self.sums[at..at + s]
                .iter_mut()
                .zip(sums)
                .for_each(|(a, p)| *a += p);
        }
    }

    /// The group's cells in ascending order, at their size (no index, no
    /// spare capacity): nothing more is added.
    fn seal(&mut self, stride: usize) {
        if self.sealed {
            return;
        }
        if self.dense.is_empty() {
            self.merge_pending(stride);
            self.keys = Vec::new();
            self.sums.shrink_to_fit();
        } else if self.counted.is_some() {
            self.dense = Vec::new();
        } else {
            // One covariate: the bins in order are the cells in order.
            let mut sums = Vec::with_capacity(self.sums.len());
            for &slot in self.dense.iter().filter(|&&s| s != u32::MAX) {
                let at = slot as usize * stride;
                sums.extend_from_slice(&self.sums[at..at + stride]);
            }
            (self.sums, self.dense) = (sums, Vec::new());
        }
        self.sealed = true;
    }

    /// Merges the pending partial cells into the sorted cells: each key's
    /// partial sums added in arrival order after the sums already merged
    /// (a stable sort by key keeps that order).
    fn merge_pending(&mut self, stride: usize) {
        if self.pending_keys.is_empty() {
            return;
        }
        let mut order: Vec<u32> = (0..self.pending_keys.len() as u32).collect();
        order.sort_by_key(|&i| self.pending_keys[i as usize]);
        let n = self.keys.len() + order.len();
        let (mut keys, mut sums) = (Vec::with_capacity(n), Vec::with_capacity(n * stride));
        let mut m = 0;
        let mut a = 0;
        while m < self.keys.len() || a < order.len() {
            let next_pending = order.get(a).map(|&i| self.pending_keys[i as usize]);
            let key = match (self.keys.get(m), next_pending) {
                (Some(&k), Some(p)) => k.min(p),
                (Some(&k), None) => k,
                (None, Some(p)) => p,
                (None, None) => unreachable!(),
            };
            let at = sums.len();
            if self.keys.get(m) == Some(&key) {
                sums.extend_from_slice(&self.sums[m * stride..(m + 1) * stride]);
                m += 1;
            } else {
                let i = order[a] as usize;
                sums.extend_from_slice(&self.pending_sums[i * stride..(i + 1) * stride]);
                a += 1;
            }
            while a < order.len() && self.pending_keys[order[a] as usize] == key {
                let i = order[a] as usize;
                let p = &self.pending_sums[i * stride..(i + 1) * stride];
                sums[at..].iter_mut().zip(p).for_each(|(s, v)| *s += v);
                a += 1;
            }
            keys.push(key);
        }
        (self.keys, self.sums) = (keys, sums);
        self.pending_keys.clear();
        self.pending_sums.clear();
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
        let nd = axes.len();
        CellPool {
            stride: 1 + axes.len() + targets,
            axes,
            groups: (0..groups).map(|_| GroupCells::default()).collect(),
            out: (
                vec![Vec::new(); nd],
                Vec::new(),
                vec![Vec::new(); targets],
                Vec::new(),
            ),
            emitted: 0,
            occupied: Vec::new(),
            compact: None,
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
        assert!(
            !self.groups[group].sealed,
            "a range added to a sealed group"
        );
        assert_eq!(cols.len(), self.axes.len(), "a column per axis");
        assert_eq!(
            self.stride,
            1 + cols.len() + targets.len(),
            "a sum per target"
        );
        match (cols, self.axes.as_slice(), self.compact.take()) {
            ([c], [axis], _) => {
                let axis = *axis;
                self.add_range_dense(
                    group,
                    r,
                    [*c],
                    axis.bins,
                    |i| axis.bin(c[i]),
                    weights,
                    targets,
                )
            }
            ([a, b], _, Some(k)) => self.add_range_compact(group, r, [*a, *b], k, weights, targets),
            ([a, b, c], _, Some(k)) => {
                self.add_range_compact(group, r, [*a, *b, *c], k, weights, targets)
            }
            (_, _, k) => {
                self.compact = k;
                self.add_range_sorted(group, r, cols, weights, targets);
            }
        }
    }

    /// Several covariates on their compact grid `k` (taken out of the pool
    /// for the call, put back after).
    fn add_range_compact<const ND: usize>(
        &mut self,
        group: usize,
        r: Range<usize>,
        cols: [&[f64]; ND],
        k: Compact,
        weights: Option<&[f64]>,
        targets: &[&[f64]],
    ) {
        let cell = |i| k.cell(cols, i);
        self.add_range_dense(group, r, cols, k.cells, cell, weights, targets);
        self.compact = Some(k);
    }

    /// Dense bins, no sort — one covariate's bins, or the cells of a
    /// compact grid (`bins` of them, `bin_of` row i's). The range's rows go
    /// into the partial bins (a bin's count, Σc of each covariate and Σy
    /// of every target side by side, so a row touches one line), then the
    /// touched bins into the group's cells.
    #[allow(clippy::too_many_arguments)]
    fn add_range_dense<const ND: usize>(
        &mut self,
        group: usize,
        r: Range<usize>,
        cols: [&[f64]; ND],
        bins: usize,
        bin_of: impl Fn(usize) -> usize,
        weights: Option<&[f64]>,
        targets: &[&[f64]],
    ) {
        let stride = self.stride;
        let g = &mut self.groups[group];
        if g.dense.is_empty() {
            g.dense = vec![u32::MAX; bins];
        }
        if let (Some(n), true) = (g.counted, g.sums.is_empty()) {
            g.sums = vec![0.0; n * stride];
        }
        PART.with_borrow_mut(|(part, touched)| {
            if part.len() < bins * stride {
                part.resize(bins * stride, 0.0);
            }
            touched.clear();
            let rows = (cols, &bin_of, weights, targets, r);
            let bins = &mut part[..bins * stride];
            // The held sums a fixed-size array for the usual target counts
            // (5 folds: 6).
            match stride {
                3 => pool_range_held([0.0; 3], rows, bins, touched),
                4 => pool_range_held([0.0; 4], rows, bins, touched),
                5 => pool_range_held([0.0; 5], rows, bins, touched),
                6 => pool_range_held([0.0; 6], rows, bins, touched),
                7 => pool_range_held([0.0; 7], rows, bins, touched),
                8 => pool_range_held([0.0; 8], rows, bins, touched),
                9 => pool_range_held([0.0; 9], rows, bins, touched),
                10 => pool_range_held([0.0; 10], rows, bins, touched),
                _ => pool_range_held(vec![0.0; stride], rows, bins, touched),
            }
            for &b in touched.iter() {
                let p = &mut bins[b * stride..(b + 1) * stride];
                let mut slot = g.dense[b];
                g.add(&mut slot, p);
                g.dense[b] = slot;
                p.iter_mut().for_each(|v| *v = 0.0);
            }
        });
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

    /// Pools every group — each group's ranges in order, group after
    /// group — sealing each when done ([`CellPool::count_groups`] first).
    /// A slot given up front starts at zero, and 0 + s is s: the same bits
    /// as [`CellPool::add_range`] range by range.
    pub fn add_groups(
        &mut self,
        groups: &[Vec<Range<usize>>],
        cols: &[&[f64]],
        weights: Option<&[f64]>,
        targets: &[&[f64]],
    ) {
        self.count_groups(groups, cols);
        for (g, ranges) in groups.iter().enumerate() {
            for r in ranges {
                self.add_range(g, r.clone(), cols, weights, targets);
            }
            self.seal(g);
        }
    }

    /// Counts every group's cells before any is filled (`groups`: each
    /// group's ranges, all of them; [`CellPool::count_range`]), so the
    /// ranges may then come in any order of groups.
    pub fn count_groups(&mut self, groups: &[Vec<Range<usize>>], cols: &[&[f64]]) {
        assert_eq!(groups.len(), self.groups.len(), "ranges for every group");
        let mut part = Vec::with_capacity(cols.len());
        for (g, ranges) in groups.iter().enumerate() {
            for r in ranges {
                part.clear();
                part.extend(cols.iter().map(|c| &c[r.clone()]));
                self.count_range(g, &part);
            }
        }
        self.counted();
    }

    /// Marks the bins of rows `cols` (a column per covariate) of `group` —
    /// the count of [`CellPool::count_groups`] taken a range at a time, as
    /// a pass reading the rows in chunks gives them; [`CellPool::counted`]
    /// follows the last. One covariate: each group's cells are then laid
    /// out in bin order, its sums allocated at their size when its first
    /// range comes, and the output columns once at theirs — no growth, and
    /// one group's sums besides the output at a time (the cells of a fine
    /// grid are nearly as many as the rows, so this is the pass's peak).
    /// Several covariates: the bins each covariate occupies in any group,
    /// from which the compact grid ([`Compact`]) follows when it is small.
    /// Every row later added must have been counted.
    pub fn count_range(&mut self, group: usize, cols: &[&[f64]]) {
        assert_eq!(cols.len(), self.axes.len(), "a column per axis");
        let g = &mut self.groups[group];
        assert!(
            !g.sealed && g.counted.is_none() && self.compact.is_none(),
            "groups are counted before any range is added"
        );
        if let ([c], [axis]) = (cols, self.axes.as_slice()) {
            if g.dense.is_empty() {
                g.dense = vec![u32::MAX; axis.bins];
            }
            for &x in *c {
                g.dense[axis.bin(x)] = COUNTED;
            }
            return;
        }
        if self.occupied.is_empty() {
            self.occupied = self.axes.iter().map(|a| vec![false; a.bins]).collect();
        }
        for ((c, axis), occ) in cols.iter().zip(&self.axes).zip(&mut self.occupied) {
            for &x in *c {
                occ[axis.bin(x)] = true;
            }
        }
    }

    /// The count is done ([`CellPool::count_range`]). One covariate: every
    /// group's cells numbered in bin order, the output columns reserved at
    /// their size. Several: the compact grid, if small enough.
    pub fn counted(&mut self) {
        let [axis] = self.axes.as_slice() else {
            if !self.occupied.is_empty() {
                self.compact = Compact::of(&self.axes, &self.occupied);
                self.occupied = Vec::new();
            }
            return;
        };
        let mut total = 0;
        for g in &mut self.groups {
            assert!(
                !g.sealed && g.counted.is_none(),
                "groups are counted once, before any range is added"
            );
            if g.dense.is_empty() {
                g.dense = vec![u32::MAX; axis.bins];
            }
            let mut n = 0u32;
            for s in g.dense.iter_mut().filter(|s| **s == COUNTED) {
                *s = n;
                n += 1;
            }
            g.counted = Some(n as usize);
            total += n as usize;
        }
        let n_groups = self.groups.len();
        let (xc, w, sy, ranges) = &mut self.out;
        for col in xc.iter_mut().chain(sy.iter_mut()) {
            col.reserve_exact(total);
        }
        w.reserve_exact(total);
        ranges.reserve_exact(n_groups);
    }

    /// Seals `group`'s cells ([`GroupCells::seal`]): its last range has
    /// been added. Then every sealed group next in order moves to the
    /// output: groups that come one after another hold one group's sums
    /// besides the output at a time.
    pub fn seal(&mut self, group: usize) {
        let (nd, stride) = (self.axes.len(), self.stride);
        self.groups[group].seal(stride);
        while self.emitted < self.groups.len() && self.groups[self.emitted].sealed {
            let g = std::mem::take(&mut self.groups[self.emitted]);
            let (xc, w, sy, ranges) = &mut self.out;
            let start = w.len();
            for cell in g.sums.chunks_exact(stride) {
                for (x, v) in xc.iter_mut().zip(&cell[1..=nd]) {
                    x.push(v / cell[0]);
                }
                w.push(cell[0]);
                for (t, v) in sy.iter_mut().zip(&cell[1 + nd..]) {
                    t.push(*v);
                }
            }
            ranges.push(start..w.len());
            // The group stays sealed (and empty): nothing more is added.
            self.groups[self.emitted].sealed = true;
            self.emitted += 1;
        }
    }

    /// The groups' cells, each group's in ascending cell order: pooled
    /// covariates (a cell's mean of each), counts, Σy per target, and each
    /// group's range of cells.
    pub fn finish(mut self) -> Pooled {
        for g in 0..self.groups.len() {
            if !self.groups[g].sealed {
                self.seal(g);
            }
        }
        self.out
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
            g.pending_keys.push(key);
            g.pending_sums.extend_from_slice(&sums);
        }
        if g.pending_keys.len() > g.keys.len().max(4096) {
            g.merge_pending(self.stride);
        }
    }
}

/// A range's rows as [`pool_range_held`] reads them: the covariates, row
/// i's bin, the weights, the targets, the rows.
type RangeRows<'a, const ND: usize, B> = (
    [&'a [f64]; ND],
    &'a B,
    Option<&'a [f64]>,
    &'a [&'a [f64]],
    Range<usize>,
);

/// A range's rows into `bins` of `held.len()` sums (count, Σc of each
/// covariate, Σy of each target), the current bin's sums held apart — in
/// registers when `held` is a small array — while consecutive rows stay
/// in it: a row's adds then wait on the previous add, not on its store and
/// reload. Each sum adds the same values in the same order as adding into
/// `bins` row by row (same bits).
fn pool_range_held<H: AsMut<[f64]>, const ND: usize, B: Fn(usize) -> usize>(
    mut held: H,
    (cols, bin_of, weights, targets, r): RangeRows<ND, B>,
    bins: &mut [f64],
    touched: &mut Vec<usize>,
) {
    let held = held.as_mut();
    let s = held.len();
    assert_eq!(
        targets.len() + 1 + ND,
        s,
        "a sum per target and covariate, and the count"
    );
    let mut cur = usize::MAX;
    for i in r {
        let b = bin_of(i);
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
        for (h, c) in held[1..=ND].iter_mut().zip(cols) {
            *h += wi * c[i];
        }
        for (h, y) in held[1 + ND..].iter_mut().zip(targets) {
            *h += y[i];
        }
    }
    if cur != usize::MAX {
        bins[cur * s..(cur + 1) * s].copy_from_slice(held);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Ranges fed interleaved across groups (as a pass over chunks of runs
    /// feeds them), each group sealed after its last range, give the bits
    /// of the groups pooled one after another ([`super::super::pool_rows`]):
    /// one covariate (dense bins) and two (sorted, merged many times —
    /// more partial cells than the merge threshold).
    #[test]
    fn ranges_interleaved_across_groups_pool_as_groups_one_by_one() {
        let n = 60_000;
        let mut next = super::super::tests::uniform(0x9e37_79b9_7f4a_7c15);
        let a: Vec<f64> = (0..n).map(|_| next() * 40.0).collect();
        let b: Vec<f64> = (0..n).map(|_| (next() * 3.0).floor()).collect();
        let y1: Vec<f64> = (0..n).map(|i| (i as f64 * 0.1).sin()).collect();
        let y2: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).cos() * 1e3).collect();
        // 150 ranges of 400 rows; range r belongs to group r % 4.
        let ranges: Vec<Range<usize>> = (0..150).map(|r| r * 400..(r + 1) * 400).collect();
        let groups: Vec<Vec<Range<usize>>> = (0..4)
            .map(|g| ranges.iter().skip(g).step_by(4).cloned().collect())
            .collect();
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for cols in [vec![a.as_slice()], vec![a.as_slice(), b.as_slice()]] {
            let mins = vec![0.0; cols.len()];
            let res = vec![1e-4; cols.len()];
            let targets = [y1.as_slice(), y2.as_slice()];
            let want = super::super::pool_rows(&cols, &mins, &res, None, &groups, &targets);
            let axes = spans(&cols, &mins)
                .into_iter()
                .map(|span| Axis::new(0.0, span, 1e-4))
                .collect();
            let mut pool = CellPool::new(axes, 2, 4);
            for (i, r) in ranges.iter().enumerate() {
                pool.add_range(i % 4, r.clone(), &cols, None, &targets);
                if i + 4 >= ranges.len() {
                    pool.seal(i % 4);
                }
            }
            let got = pool.finish();
            assert_eq!(got.3, want.3, "{} covariates", cols.len());
            assert!(want.1.len() > 4 * 4096, "cells: {}", want.1.len());
            assert_eq!(bits(&got.1), bits(&want.1));
            for (g, w) in got.0.iter().zip(&want.0).chain(got.2.iter().zip(&want.2)) {
                assert_eq!(bits(g), bits(w), "{} covariates", cols.len());
            }
        }
    }

    /// Pools `cols` in ranges of 400 rows dealt to 3 groups, the ranges
    /// counted first (`count`) or not — the compact grid's dense slots or
    /// the sorted cells — and returns the pool's output and whether the
    /// compact grid was used.
    fn pooled(
        cols: &[&[f64]],
        w: Option<&[f64]>,
        targets: &[&[f64]],
        count: bool,
    ) -> (Pooled, bool) {
        let n = cols[0].len();
        let ranges: Vec<Range<usize>> = (0..n / 400).map(|r| r * 400..(r + 1) * 400).collect();
        let mins: Vec<f64> = cols
            .iter()
            .map(|c| c.iter().copied().fold(f64::INFINITY, f64::min))
            .collect();
        let axes = spans(cols, &mins)
            .into_iter()
            .zip(&mins)
            .map(|(span, &m)| Axis::new(m, span, 1e-4))
            .collect();
        let mut pool = CellPool::new(axes, targets.len(), 3);
        if count {
            for (i, r) in ranges.iter().enumerate() {
                let part: Vec<&[f64]> = cols.iter().map(|c| &c[r.clone()]).collect();
                pool.count_range(i % 3, &part);
            }
            pool.counted();
        }
        let compact = pool.compact.is_some();
        for (i, r) in ranges.iter().enumerate() {
            pool.add_range(i % 3, r.clone(), cols, w, targets);
        }
        (pool.finish(), compact)
    }

    fn bits_of(p: &Pooled) -> Vec<Vec<u64>> {
        let bits = |v: &Vec<f64>| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        p.0.iter()
            .chain(std::iter::once(&p.1))
            .chain(&p.2)
            .map(bits)
            .collect()
    }

    /// Two and three covariates of few distinct values (a direction of
    /// ±1, a coarse position) pool on the compact grid's dense slots to the
    /// bits of the sorted cells, with and without weights; a grid whose
    /// occupied cells are too many falls back to sorting, same bits.
    #[test]
    fn a_compact_grid_pools_as_the_sorted_cells() {
        let n = 48_000;
        let mut next = super::super::tests::uniform(0x2545_f491_4f6c_dd1d);
        let pos: Vec<f64> = (0..n).map(|_| (next() * 300.0).floor() * 0.01).collect();
        let dir: Vec<f64> = (0..n)
            .map(|_| if next() < 0.5 { -1.0 } else { 1.0 })
            .collect();
        let level: Vec<f64> = (0..n).map(|_| (next() * 3.0).floor() * 0.5).collect();
        let fine: Vec<f64> = (0..n).map(|_| next() * 40.0).collect();
        let w: Vec<f64> = (0..n).map(|_| (next() * 5.0).floor() + 1.0).collect();
        let y1: Vec<f64> = (0..n).map(|i| (i as f64 * 0.1).sin()).collect();
        let y2: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).cos() * 1e3).collect();
        let targets = [y1.as_slice(), y2.as_slice()];
        for (cols, compact) in [
            (vec![pos.as_slice(), dir.as_slice()], true),
            (vec![dir.as_slice(), level.as_slice(), pos.as_slice()], true),
            (vec![fine.as_slice(), pos.as_slice()], false),
        ] {
            for weights in [None, Some(w.as_slice())] {
                let (want, sorted) = pooled(&cols, weights, &targets, false);
                let (got, used) = pooled(&cols, weights, &targets, true);
                assert!(!sorted);
                assert_eq!(used, compact, "{} covariates", cols.len());
                assert_eq!(got.3, want.3);
                assert_eq!(bits_of(&got), bits_of(&want), "{} covariates", cols.len());
            }
        }
    }

    /// A row the count pass did not see has no slot on the compact grid:
    /// pooling it stops rather than merging it into another cell.
    #[test]
    #[should_panic(expected = "count pass did not see")]
    fn an_uncounted_row_is_refused_on_a_compact_grid() {
        let a = [0.0, 1.0, 2.0, 1.5];
        let b = [-1.0, 1.0, -1.0, 1.0];
        let y = [1.0, 2.0, 3.0, 4.0];
        let axes = vec![Axis::new(0.0, 2.0, 0.1), Axis::new(-1.0, 2.0, 0.1)];
        let mut pool = CellPool::new(axes, 1, 1);
        pool.count_range(0, &[&a[..3], &b[..3]]);
        pool.counted();
        assert!(pool.compact.is_some());
        pool.add_range(0, 0..4, &[&a, &b], None, &[&y]);
    }
}

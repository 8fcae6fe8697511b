//! "Where is the gap?" (docs/design.md §7 point 1): cells of
//! covariate space per observable — quantile bins per covariate (one cell
//! per value for covariates with at most 8 values: `dir`, `pass`), 4×4
//! quantile tiles over (x_mm, y_mm) — each with its Σgap², RMS and a test
//! against the noise floor.
//!
//! The test: under "no gap", a cell's gaps are noise of variance σ², so
//! (Σg²/n)/σ̂² ~ F(n, df_σ) where df_σ is the noise floor's degrees of
//! freedom (σ̂ is itself estimated; a χ²(n) test would treat it as exact and
//! flag big cells for a 2 % error in σ̂). The raw gap is tested, not the gap
//! minus its mean: an offset is a gap too. Cells are significant at α after
//! Bonferroni over all cells of all observables (done by the caller).
//!
//! The quantile edges are order statistics selected from each covariate;
//! the per-cell sums are one pass over the rows in row order (a histogram
//! of at most 16 cells per binning).
//!
//! `machine` is a where-dimension too: with two or more machines
//! an observable gets one cell per machine, tested the same way, so a gap
//! present on one machine of a type is localised to that machine.

use statrs::distribution::{ContinuousCDF, FisherSnedecor, Normal};

use super::covariates::Covariates;
use super::document::{CellBound, WhereCell};

/// Number of quantile bins per covariate and per axis of the x/y tiles.
pub const QUANTILE_BINS: usize = 6;
pub const TILE_BINS: usize = 4;
/// Covariates with at most this many distinct values get one cell per value.
pub const MAX_DISCRETE_VALUES: usize = 8;

/// One cell's aggregates. `lo`/`hi` hold one value (1-D) or two (x, y tile).
#[derive(Debug, Clone)]
pub struct Cell {
    pub covariate: String,
    pub lo: Vec<f64>,
    pub hi: Vec<f64>,
    pub n: usize,
    pub sum_g2: f64,
    pub sum_r2: f64,
    /// A categorical cell (`machine`): its value; `lo`/`hi` are empty.
    pub label: Option<String>,
}

/// Upper-tail probability of F(d1, d2) at `stat`; for very large degrees of
/// freedom ln F is normal with variance 2/d1 + 2/d2 (the incomplete beta of
/// statrs loses accuracy there).
pub fn f_sf(stat: f64, d1: f64, d2: f64) -> f64 {
    if !(stat.is_finite()) {
        return if stat > 0.0 { 0.0 } else { 1.0 };
    }
    if d1 <= 0.0 || d2 <= 0.0 {
        return f64::NAN;
    }
    if d1.min(d2) > 2_000.0 {
        let z = stat.max(1e-300).ln() / (2.0 / d1 + 2.0 / d2).sqrt();
        return Normal::standard().sf(z);
    }
    match FisherSnedecor::new(d1, d2) {
        Ok(f) => f.sf(stat),
        Err(_) => f64::NAN,
    }
}

/// p-value of a cell's mean square `ms` against σ² with `df_sigma`.
pub fn cell_p(ms: f64, n: usize, sigma: f64, df_sigma: f64) -> f64 {
    if n == 0 {
        return 1.0;
    }
    if sigma.is_nan() || sigma <= 0.0 {
        return if ms > 0.0 { 0.0 } else { 1.0 };
    }
    f_sf(ms / (sigma * sigma), n as f64, df_sigma)
}

/// How one covariate is binned: one cell per value when it has at most
/// [`MAX_DISCRETE_VALUES`] distinct values, else by quantiles.
enum Binning {
    /// The distinct values, ascending.
    Discrete(Vec<f64>),
    /// The order statistics the quantile edges read: (position in the
    /// ascending values, value), positions ascending.
    Quantiles(Vec<(usize, f64)>),
}

impl Binning {
    /// The binning of `v` for edges at n·j/b (j = 1 … b − 1) for every b in
    /// `bins`. Selects those order statistics rather than sorting the
    /// values: O(n) instead of O(n log n), the same values (equal under
    /// the total order means equal bits). With a NaN the values are sorted,
    /// as the quantile edges were always taken.
    fn of(v: &[f64], bins: &[usize]) -> Binning {
        if v.iter().any(|x| x.is_nan()) {
            return Self::from_sorted(&crate::effect::sorted_values(v), bins);
        }
        if let Some(d) = distinct_at_most(v, MAX_DISCRETE_VALUES) {
            return Binning::Discrete(d);
        }
        Self::selected(v.to_vec(), bins)
    }

    /// [`Binning::of`] values the caller no longer needs in their order
    /// (read from a file for it): selected in place, no copy.
    fn of_owned(v: Vec<f64>, bins: &[usize]) -> Binning {
        if v.iter().any(|x| x.is_nan()) || distinct_at_most(&v, MAX_DISCRETE_VALUES).is_some() {
            return Self::of(&v, bins);
        }
        Self::selected(v, bins)
    }

    /// The quantile binning by selecting the edges' order statistics of
    /// `s` (reordered).
    fn selected(mut s: Vec<f64>, bins: &[usize]) -> Binning {
        let n = s.len();
        let at = edge_ranks(n, bins);
        let mut lo = 0;
        let mut out = Vec::with_capacity(at.len());
        for p in at {
            // s[lo..] holds every value ranked lo or above, so the value
            // ranked p is the (p − lo)-th smallest of it.
            let (_, x, _) = s[lo..].select_nth_unstable_by(p - lo, f64::total_cmp);
            out.push((p, *x));
            lo = p;
        }
        Binning::Quantiles(out)
    }

    /// The binning from the values ascending (NaN last): the reference the
    /// selection reproduces.
    fn from_sorted(sorted: &[f64], bins: &[usize]) -> Binning {
        // Distinct values, capped at MAX_DISCRETE_VALUES + 1.
        let mut distinct: Vec<f64> = Vec::new();
        for &x in sorted {
            if distinct.last() != Some(&x) {
                distinct.push(x);
                if distinct.len() > MAX_DISCRETE_VALUES {
                    break;
                }
            }
        }
        if distinct.len() <= MAX_DISCRETE_VALUES {
            return Binning::Discrete(distinct);
        }
        let at = edge_ranks(sorted.len(), bins);
        Binning::Quantiles(at.into_iter().map(|p| (p, sorted[p])).collect())
    }

    /// The bins of a covariate of `n` values with `bins` quantile bins.
    fn bins(&self, n: usize, bins: usize) -> Bins {
        match self {
            Binning::Discrete(distinct) => Bins::Values(distinct.clone()),
            Binning::Quantiles(at) => {
                let value = |p: usize| at[at.partition_point(|(q, _)| *q < p)].1;
                let mut edges: Vec<f64> = (1..bins).map(|j| value(n * j / bins)).collect();
                edges.dedup();
                Bins::Edges(edges)
            }
        }
    }
}

/// The ranks n·j/b (j = 1 … b − 1) of the quantile edges of every b in
/// `bins`, ascending, each once.
fn edge_ranks(n: usize, bins: &[usize]) -> Vec<usize> {
    let mut at: Vec<usize> = bins
        .iter()
        .flat_map(|&b| (1..b).map(move |j| n * j / b))
        .collect();
    at.sort_unstable();
    at.dedup();
    at
}

/// Which bin a value falls in: one per distinct value (ascending), or
/// between quantile edges (a value equal to an edge goes above it).
enum Bins {
    Values(Vec<f64>),
    Edges(Vec<f64>),
}

impl Bins {
    fn id(&self, x: f64) -> u32 {
        match self {
            Bins::Values(d) => d.partition_point(|d| *d < x) as u32,
            Bins::Edges(e) => e.partition_point(|e| *e <= x) as u32,
        }
    }
}

/// The distinct values of `v` (no NaN) ascending, when there are at most
/// `cap` (values equal under `==`, i.e. −0 and +0, count once, as the
/// first in ascending order); None as soon as there are more.
fn distinct_at_most(v: &[f64], cap: usize) -> Option<Vec<f64>> {
    // Distinct under the total order; −0 and +0 are two of them, so one
    // more than `cap` may still be `cap` under `==`.
    let mut d: Vec<f64> = Vec::new();
    for &x in v {
        if let Err(i) = d.binary_search_by(|e| e.total_cmp(&x)) {
            d.insert(i, x);
            if d.len() > cap + 1 {
                return None;
            }
        }
    }
    d.dedup_by(|b, a| a == b);
    (d.len() <= cap).then_some(d)
}

/// Aggregates every binning of one observable. `covs`: its covariates
/// (values in row order); `g`/`r`: gap and held-out residual. Each
/// covariate's quantile edges are selected from a copy let go at once; the
/// cells' sums are one pass over the rows ([`CellFold`]).
pub fn cells(covs: &Covariates, g: &[f64], r: &[f64]) -> crate::Result<Vec<Cell>> {
    use rayon::prelude::*;
    let n = g.len();
    // Each covariate on its own: in parallel when the columns are in
    // memory; read from a file, one column whole at a time, not one per
    // core (docs/design.md §8).
    // A covariate's bins: its quantile edges selected from its values read
    // whole, and — for a position of the tiles — its tile bins.
    let binning = |name: &String| -> crate::Result<(Bins, Option<Bins>)> {
        let tiled = matches!(name.as_str(), "x_mm" | "y_mm");
        let edges: &[usize] = if tiled {
            &[QUANTILE_BINS, TILE_BINS]
        } else {
            &[QUANTILE_BINS]
        };
        let b = Binning::of_owned(covs.column(name)?.into_owned(), edges);
        Ok((
            b.bins(n, QUANTILE_BINS),
            tiled.then(|| b.bins(n, TILE_BINS)),
        ))
    };
    // Its cells, folded a chunk of rows at a time.
    let fold = |name: &String, q: &Bins| -> crate::Result<Vec<Cell>> {
        let mut fold = CellFold::default();
        covs.chunked(std::slice::from_ref(name), |rows, x| {
            let v = x.col(name).expect("read");
            fold.add(|i| q.id(v[i]), &[v], &g[rows.clone()], &r[rows]);
            Ok(())
        })?;
        let mut cells = Vec::new();
        fold.finish(&[name.as_str()], &mut cells);
        Ok(cells)
    };
    let names = covs.names();
    let per_cov: Vec<(Vec<Cell>, Option<Bins>)> = if covs.in_a_file() {
        // One column whole at a time: a covariate's binning beside the
        // previous covariate's fold (two cores, one column).
        let mut out = Vec::with_capacity(names.len());
        let mut prev: Option<(&String, Bins, Option<Bins>)> = None;
        for k in 0..=names.len() {
            let (next, folded) = rayon::join(
                || names.get(k).map(|c| binning(c).map(|b| (c, b))).transpose(),
                || prev.as_ref().map(|(c, q, _)| fold(c, q)).transpose(),
            );
            if let (Some(cells), Some((_, _, tile))) = (folded?, prev.take()) {
                out.push((cells, tile));
            }
            prev = next?.map(|(c, (q, tile))| (c, q, tile));
        }
        out
    } else {
        names
            .par_iter()
            .map(|c| {
                let (q, tile) = binning(c)?;
                Ok((fold(c, &q)?, tile))
            })
            .collect::<crate::Result<_>>()?
    };
    let (mut tile_x, mut tile_y) = (None, None);
    let mut out = Vec::new();
    for (name, (cells, tile)) in covs.names().iter().zip(per_cov) {
        out.extend(cells);
        match name.as_str() {
            "x_mm" => tile_x = tile,
            "y_mm" => tile_y = tile,
            _ => {}
        }
    }
    // 2-D tiles over the positions x_mm, y_mm.
    if let (Some(bx), Some(by)) = (tile_x, tile_y) {
        let names = ["x_mm".to_string(), "y_mm".to_string()];
        let mut fold = CellFold::default();
        covs.chunked(&names, |rows, xy| {
            let (x, y) = (xy.col("x_mm").expect("read"), xy.col("y_mm").expect("read"));
            let tile = |i: usize| bx.id(x[i]) * 64 + by.id(y[i]);
            fold.add(tile, &[x, y], &g[rows.clone()], &r[rows]);
            Ok(())
        })?;
        fold.finish(&["x_mm", "y_mm"], &mut out);
    }
    Ok(out)
}

/// The cells of one binning, ascending by bin id, each with its row count,
/// Σg² and Σr² summed in row order, and the extremes of the binned
/// values (one column per covariate, at most two; NaN is passed over).
/// Rows are added a chunk at a time, in order ([`CellFold::add`]): the
/// same sums as one pass over the rows. At 1.7·10⁷ rows a polars group-by
/// per binning took 0.3–0.5 s where this takes a few hundredths.
#[derive(Default)]
struct CellFold {
    acc: Vec<Option<FoldAcc>>,
    k: usize,
}

struct FoldAcc {
    n: usize,
    sum_g2: f64,
    sum_r2: f64,
    lo: [f64; 2],
    hi: [f64; 2],
}

impl CellFold {
    /// Rows of a chunk: row i in bin `bin_of(i)`, its values
    /// `values[j][i]`, gap `g[i]` and residual `r[i]`.
    fn add(&mut self, bin_of: impl Fn(usize) -> u32, values: &[&[f64]], g: &[f64], r: &[f64]) {
        debug_assert!(values.len() <= 2);
        self.k = values.len();
        for (i, (gi, ri)) in g.iter().zip(r).enumerate() {
            let b = bin_of(i) as usize;
            if b >= self.acc.len() {
                self.acc.resize_with(b + 1, || None);
            }
            let a = self.acc[b].get_or_insert(FoldAcc {
                n: 0,
                sum_g2: 0.0,
                sum_r2: 0.0,
                lo: [f64::NAN; 2],
                hi: [f64::NAN; 2],
            });
            a.n += 1;
            a.sum_g2 += gi * gi;
            a.sum_r2 += ri * ri;
            for (j, v) in values.iter().enumerate() {
                a.lo[j] = a.lo[j].min(v[i]);
                a.hi[j] = a.hi[j].max(v[i]);
            }
        }
    }

    /// The cells, ascending by bin, named by the covariates `names`.
    fn finish(self, names: &[&str], out: &mut Vec<Cell>) {
        let k = self.k;
        out.extend(self.acc.into_iter().flatten().map(|a| Cell {
            covariate: names.join(","),
            lo: a.lo[..k].to_vec(),
            hi: a.hi[..k].to_vec(),
            n: a.n,
            sum_g2: a.sum_g2,
            sum_r2: a.sum_r2,
            label: None,
        }));
    }
}

/// One cell per machine of an observable (none with fewer than two).
/// `runs`: the rows' run ranges, `run_machine` each one's machine id.
pub fn machine_cells(
    runs: &[std::ops::Range<usize>],
    run_machine: &[u32],
    names: &[String],
    g: &[f64],
    r: &[f64],
) -> Vec<Cell> {
    let mut acc: std::collections::BTreeMap<u32, (usize, f64, f64)> = Default::default();
    let rows = runs
        .iter()
        .zip(run_machine)
        .flat_map(|(rows, &m)| rows.clone().map(move |i| (m, i)));
    for (m, i) in rows {
        let (g, r) = (g[i], r[i]);
        let a = acc.entry(m).or_insert((0, 0.0, 0.0));
        a.0 += 1;
        a.1 += g * g;
        a.2 += r * r;
    }
    if acc.len() < 2 {
        return Vec::new();
    }
    acc.into_iter()
        .map(|(m, (n, sg2, sr2))| Cell {
            covariate: "machine".into(),
            lo: Vec::new(),
            hi: Vec::new(),
            n,
            sum_g2: sg2,
            sum_r2: sr2,
            label: Some(names[m as usize].clone()),
        })
        .collect()
}

/// A cell of one observable with its noise floor σ and σ's df.
pub struct ObsCell {
    pub observable: String,
    pub sigma_mm: f64,
    pub df: f64,
    pub cell: Cell,
}

/// `where` (cells whose raw gap is significant) and `unexplained.where`
/// (cells whose held-out residual still is), Bonferroni over all cells,
/// largest RMS first. `sum_g2`/`sum_r2`: totals for the shares.
pub fn where_lists(
    all: &[ObsCell],
    sum_g2: f64,
    sum_r2: f64,
    alpha: f64,
) -> (Vec<WhereCell>, Vec<WhereCell>) {
    let m_cells = all.len().max(1) as f64;
    let bound = |c: &Cell, v: &[f64]| match &c.label {
        Some(l) => CellBound::Label(l.clone()),
        None if v.len() == 1 => CellBound::Number(v[0]),
        None => CellBound::Point(v.to_vec()),
    };
    let mk = |o: &str, c: &Cell, ss: f64, total: f64, p: f64| WhereCell {
        covariate: c.covariate.clone(),
        lo: bound(c, &c.lo),
        hi: bound(c, &c.hi),
        observable: o.to_string(),
        share: if total > 0.0 { ss / total } else { 0.0 },
        rms_mm: (ss / c.n.max(1) as f64).sqrt(),
        p_value: (p * m_cells).min(1.0),
        n: c.n,
        rms_before_mm: None,
        shrink: None,
    };
    let mut where_: Vec<WhereCell> = Vec::new();
    let mut where_after: Vec<WhereCell> = Vec::new();
    for oc in all {
        let c = &oc.cell;
        let p = cell_p(c.sum_g2 / c.n.max(1) as f64, c.n, oc.sigma_mm, oc.df);
        if p * m_cells < alpha {
            where_.push(mk(&oc.observable, c, c.sum_g2, sum_g2, p));
        }
        let pa = cell_p(c.sum_r2 / c.n.max(1) as f64, c.n, oc.sigma_mm, oc.df);
        if pa * m_cells < alpha {
            let mut w = mk(&oc.observable, c, c.sum_r2, sum_r2, pa);
            let before = (c.sum_g2 / c.n.max(1) as f64).sqrt();
            w.rms_before_mm = Some(before);
            let s = 1.0 - w.rms_mm / before;
            w.shrink = s.is_finite().then_some(s);
            where_after.push(w);
        }
    }
    let order = |a: &WhereCell, b: &WhereCell| {
        b.rms_mm
            .total_cmp(&a.rms_mm)
            .then(a.observable.cmp(&b.observable))
            .then(a.covariate.cmp(&b.covariate))
            .then(a.lo.json_text().cmp(&b.lo.json_text()))
    };
    where_.sort_by(order);
    where_after.sort_by(order);
    (where_, where_after)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantile_and_discrete_bins() {
        let v: Vec<f64> = (0..120).map(|i| i as f64).collect();
        let d: Vec<f64> = (0..120)
            .map(|i| if i % 2 == 0 { -1.0 } else { 1.0 })
            .collect();
        let g: Vec<f64> = v
            .iter()
            .map(|x| if *x >= 100.0 { 1.0 } else { 0.0 })
            .collect();
        let covs = Covariates::in_memory(120, vec![("x_mm".into(), v), ("dir".into(), d)]);
        let c = cells(&covs, &g, &g).unwrap();
        let xs: Vec<&Cell> = c.iter().filter(|c| c.covariate == "x_mm").collect();
        assert_eq!(xs.len(), QUANTILE_BINS);
        assert_eq!(xs.iter().map(|c| c.n).sum::<usize>(), 120);
        let last = xs.last().unwrap();
        assert_eq!(last.hi[0], 119.0);
        assert_eq!(last.sum_g2, 20.0);
        assert_eq!(c.iter().filter(|c| c.covariate == "dir").count(), 2);
        assert!(cell_p(1.0, 100, 0.1, 1000.0) < 1e-10);
        assert!(cell_p(0.01, 100, 0.1, 1000.0) > 0.01);
    }

    /// The selected edges and distinct values are exactly those of the
    /// sorted values, on values with ties, −0/+0, few distinct values
    /// (one past the cap under the total order only), NaN and tiny sizes.
    #[test]
    fn selected_binning_is_the_sorted_one() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        let mut cases: Vec<Vec<f64>> = vec![
            vec![],
            vec![3.0],
            vec![2.0, 1.0],
            (0..9).map(|i| i as f64).collect(),
            vec![0.0, -0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, -0.0],
            vec![0.0, -0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0],
            vec![1.0, f64::NAN, 2.0, 0.5],
        ];
        for n in [7usize, 100, 1001, 20_000] {
            cases.push((0..n).map(|_| rng.random_range(-5.0..5.0)).collect());
            cases.push((0..n).map(|_| rng.random_range(0..12) as f64).collect());
            cases.push(
                (0..n)
                    .map(|_| rng.random_range(0..4) as f64 - 1.5)
                    .collect(),
            );
            cases.push((0..n).map(|i| ((i / 97) as f64).sin()).collect());
        }
        for v in &cases {
            let want = Binning::from_sorted(
                &crate::effect::sorted_values(v),
                &[QUANTILE_BINS, TILE_BINS],
            );
            let got = Binning::of(v, &[QUANTILE_BINS, TILE_BINS]);
            for bins in [QUANTILE_BINS, TILE_BINS] {
                let ids = |b: &Binning| -> Vec<u32> {
                    let b = b.bins(v.len(), bins);
                    v.iter().map(|x| b.id(*x)).collect()
                };
                assert_eq!(ids(&got), ids(&want), "{v:?}");
            }
            match (&got, &want) {
                (Binning::Discrete(a), Binning::Discrete(b)) => {
                    let bits = |d: &[f64]| d.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(a), bits(b));
                }
                (Binning::Quantiles(a), Binning::Quantiles(b)) => {
                    let bits = |d: &[(usize, f64)]| {
                        d.iter().map(|(p, x)| (*p, x.to_bits())).collect::<Vec<_>>()
                    };
                    assert_eq!(bits(a), bits(b));
                }
                _ => panic!("discrete for one, quantiles for the other: {v:?}"),
            }
        }
    }
}

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
//! Binning and the per-cell sums run in polars (group-by over the cell id).
//!
//! `machine` is a where-dimension too: with two or more machines
//! an observable gets one cell per machine, tested the same way, so a gap
//! present on one machine of a type is localised to that machine.

use polars::prelude as pl;
use polars::prelude::{col, len, IntoLazy};
use statrs::distribution::{ContinuousCDF, FisherSnedecor, Normal};

use super::document::{CellBound, WhereCell};
use crate::Result;

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
        let n = v.len();
        if v.iter().any(|x| x.is_nan()) {
            return Self::from_sorted(&super::gather::sorted(v), bins);
        }
        if let Some(d) = distinct_at_most(v, MAX_DISCRETE_VALUES) {
            return Binning::Discrete(d);
        }
        let mut at: Vec<usize> = bins
            .iter()
            .flat_map(|&b| (1..b).map(move |j| n * j / b))
            .collect();
        at.sort_unstable();
        at.dedup();
        let mut s = v.to_vec();
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
        let n = sorted.len();
        let mut at: Vec<usize> = bins
            .iter()
            .flat_map(|&b| (1..b).map(move |j| n * j / b))
            .collect();
        at.sort_unstable();
        at.dedup();
        Binning::Quantiles(at.into_iter().map(|p| (p, sorted[p])).collect())
    }

    /// Bin index per row of `v` with `bins` quantile bins.
    fn ids(&self, v: &[f64], bins: usize) -> Vec<u32> {
        match self {
            Binning::Discrete(distinct) => v
                .iter()
                .map(|x| distinct.partition_point(|d| d < x) as u32)
                .collect(),
            Binning::Quantiles(at) => {
                let n = v.len();
                let value = |p: usize| at[at.partition_point(|(q, _)| *q < p)].1;
                let mut edges: Vec<f64> = (1..bins).map(|j| value(n * j / bins)).collect();
                edges.dedup();
                v.iter()
                    .map(|x| edges.partition_point(|e| e <= x) as u32)
                    .collect()
            }
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

/// Aggregates every binning of one observable. `covs`: (name, values in
/// row order); `g`/`r`: gap and held-out residual. Each covariate's
/// quantile edges are selected from a copy let go at once.
pub fn cells(covs: &[(&str, &[f64])], g: &[f64], r: &[f64]) -> Result<Vec<Cell>> {
    let n = g.len();
    let g2 = pl::Column::new("g2".into(), g.iter().map(|v| v * v).collect::<Vec<f64>>());
    let r2 = pl::Column::new("r2".into(), r.iter().map(|v| v * v).collect::<Vec<f64>>());
    let mut out = Vec::new();
    // One frame per binning, holding only its own columns: a frame of
    // every covariate at once held a copy of the observable's covariates.
    let (mut tile_x, mut tile_y) = (None, None);
    for (name, v) in covs {
        let tiled = matches!(*name, "x_mm" | "y_mm");
        let binning = if tiled {
            Binning::of(v, &[QUANTILE_BINS, TILE_BINS])
        } else {
            Binning::of(v, &[QUANTILE_BINS])
        };
        let bins = binning.ids(v, QUANTILE_BINS);
        match *name {
            "x_mm" => tile_x = Some(binning.ids(v, TILE_BINS)),
            "y_mm" => tile_y = Some(binning.ids(v, TILE_BINS)),
            _ => {}
        }
        drop(binning);
        let frame = vec![
            g2.clone(),
            r2.clone(),
            pl::Column::new("b".into(), bins),
            pl::Column::new("v0".into(), v.to_vec()),
        ];
        aggregate_cells(pl::DataFrame::new(n, frame)?, &[name], &mut out)?;
    }
    // 2-D tiles over the positions x_mm, y_mm.
    if let (Some(bx), Some(by)) = (tile_x, tile_y) {
        let t: Vec<u32> = bx.iter().zip(&by).map(|(a, b)| a * 64 + b).collect();
        let value = |nm: &str| covs.iter().find(|c| c.0 == nm).expect("cov").1.to_vec();
        let frame = vec![
            g2,
            r2,
            pl::Column::new("b".into(), t),
            pl::Column::new("v0".into(), value("x_mm")),
            pl::Column::new("v1".into(), value("y_mm")),
        ];
        aggregate_cells(pl::DataFrame::new(n, frame)?, &["x_mm", "y_mm"], &mut out)?;
    }
    Ok(out)
}

/// The cells of one binning: `df` holds g2, r2, the bin id `b` and the
/// covariates' values `v0`, `v1`, … (in `names` order).
fn aggregate_cells(df: pl::DataFrame, names: &[&str], out: &mut Vec<Cell>) -> Result<()> {
    let vcols: Vec<String> = (0..names.len()).map(|j| format!("v{j}")).collect();
    let mut aggs = vec![
        col("g2").sum().alias("sg2"),
        col("r2").sum().alias("sr2"),
        len().cast(pl::DataType::Float64).alias("n"),
    ];
    for (j, vc) in vcols.iter().enumerate() {
        aggs.push(col(vc.as_str()).min().alias(format!("lo{j}")));
        aggs.push(col(vc.as_str()).max().alias(format!("hi{j}")));
    }
    let agg = df
        .lazy()
        .group_by_stable([col("b")])
        .agg(aggs)
        .sort(["b"], Default::default())
        .collect()?;
    let f = |name: &str| -> Result<Vec<f64>> {
        let c = agg.column(name)?.f64()?;
        Ok((0..c.len()).map(|i| c.get(i).unwrap_or(f64::NAN)).collect())
    };
    let (sg2, sr2, cnt) = (f("sg2")?, f("sr2")?, f("n")?);
    let los: Vec<Vec<f64>> = (0..vcols.len())
        .map(|j| f(&format!("lo{j}")))
        .collect::<Result<_>>()?;
    let his: Vec<Vec<f64>> = (0..vcols.len())
        .map(|j| f(&format!("hi{j}")))
        .collect::<Result<_>>()?;
    for k in 0..sg2.len() {
        out.push(Cell {
            covariate: names.join(","),
            lo: los.iter().map(|l| l[k]).collect(),
            hi: his.iter().map(|h| h[k]).collect(),
            n: cnt[k] as usize,
            sum_g2: sg2[k],
            sum_r2: sr2[k],
            label: None,
        });
    }
    Ok(())
}

/// One cell per machine of an observable (none with fewer than two).
pub fn machine_cells(machine: &[u32], names: &[String], g: &[f64], r: &[f64]) -> Vec<Cell> {
    let mut acc: std::collections::BTreeMap<u32, (usize, f64, f64)> = Default::default();
    for ((m, g), r) in machine.iter().zip(g).zip(r) {
        let a = acc.entry(*m).or_insert((0, 0.0, 0.0));
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
        let c = cells(&[("x_mm", &v), ("dir", &d)], &g, &g).unwrap();
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
            let want = Binning::from_sorted(&crate::gather::sorted(v), &[QUANTILE_BINS, TILE_BINS]);
            let got = Binning::of(v, &[QUANTILE_BINS, TILE_BINS]);
            for bins in [QUANTILE_BINS, TILE_BINS] {
                assert_eq!(got.ids(v, bins), want.ids(v, bins), "{v:?}");
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

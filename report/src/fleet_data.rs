//! What the fleet page draws, read from fleet/observations.parquet and the
//! row-aligned fleet/diagnosis.parquet (docs/formats.md §8: one diagnosis row
//! per observation, in input order), reduced to aggregates — grid cells,
//! covariate bins, per-run RMS — so the page's size does not grow with the
//! number of rows (< 2 MB for a 1000-run fleet).

use std::collections::BTreeMap;
use std::path::Path;

use arrow::array::{Array, AsArray, RecordBatch};
use arrow::datatypes::DataType as ArrowType;

use crate::diagnose::Diagnosis;
use crate::error::Result;

/// The named columns of a Parquet file (those it has), batch by batch:
/// only what is drawn is read, and never the whole file at once (a
/// 2 000-run fleet has tens of millions of rows). The batches are decoded
/// on a thread of their own, a few ahead of the sums ([`decoded_ahead`]).
fn batches(
    path: &Path,
    wanted: impl Fn(&str) -> bool,
) -> Result<impl Iterator<Item = Result<RecordBatch>>> {
    use crate::Context;
    use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
    use parquet::arrow::ProjectionMask;
    let file = std::fs::File::open(path)
        .with_context(|| format!("cannot open {} for the fleet report", path.display()))?;
    let b = ParquetRecordBatchReaderBuilder::try_new(file)
        .with_context(|| format!("{}: not a readable Parquet file", path.display()))?;
    let idx: Vec<usize> = b
        .schema()
        .fields()
        .iter()
        .enumerate()
        .filter(|(_, f)| wanted(f.name()))
        .map(|(i, _)| i)
        .collect();
    let mask = ProjectionMask::roots(b.parquet_schema(), idx);
    let reader = b.with_projection(mask).with_batch_size(65_536).build()?;
    let at = path.to_path_buf();
    let read = reader.map(move |b| {
        use crate::Context;
        b.with_context(|| format!("{}: cannot read", at.display()))
    });
    Ok(decoded_ahead(read, path))
}

/// Batches that wait decoded, this many at most, while the consumer sums
/// the previous ones.
const DECODED_AHEAD: usize = 2;

/// [`batches`] decoded on a thread of their own, at most [`DECODED_AHEAD`]
/// ahead of the sums: decompressing and decoding the fleet tables was half
/// the report's time, the sums the other half. A reader that dies (a
/// decoder that panics on a damaged page) is an error naming the file.
fn decoded_ahead(
    it: impl Iterator<Item = Result<RecordBatch>> + Send + 'static,
    path: &Path,
) -> impl Iterator<Item = Result<RecordBatch>> {
    let path = path.to_path_buf();
    sparkout_core::ahead::produced_ahead(it, DECODED_AHEAD, move || {
        crate::err!(
            "{}: its reader stopped before the end of the file (a damaged page?); rerun `sparkout run` to rewrite the fleet tables",
            path.display()
        )
    })
}

/// Rows of a Parquet file, from its footer.
fn rows_in(path: &Path) -> Result<usize> {
    use crate::Context;
    let file = std::fs::File::open(path)
        .with_context(|| format!("cannot open {} for the fleet report", path.display()))?;
    let b = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(file)
        .with_context(|| format!("{}: not a readable Parquet file", path.display()))?;
    Ok(b.metadata().file_metadata().num_rows().max(0) as usize)
}

fn utf8(b: &RecordBatch, name: &str) -> Option<arrow::array::ArrayRef> {
    let a = b.column_by_name(name)?;
    arrow::compute::cast(a, &ArrowType::Utf8).ok()
}

fn floats(a: &dyn Array) -> Option<Vec<f64>> {
    if !a.data_type().is_numeric() {
        return None;
    }
    let c = arrow::compute::cast(a, &ArrowType::Float64).ok()?;
    let f = c.as_primitive::<arrow::datatypes::Float64Type>();
    Some(
        (0..f.len())
            .map(|i| if f.is_null(i) { f64::NAN } else { f.value(i) })
            .collect(),
    )
}

/// A numeric column of a batch (None when absent or not numeric).
fn num_col(b: &RecordBatch, name: &str) -> Option<Vec<f64>> {
    b.column_by_name(name).and_then(|a| floats(a.as_ref()))
}

/// The covariate an effect's curve is drawn against. A 2-D covariate
/// (thermal_bow:y_mm,t_s): the map shows the positions, the curve the other.
pub fn curve_covariate(effect_key: &str) -> &str {
    let covs: Vec<&str> = effect_key
        .split_once(':')
        .map(|(_, c)| c.split(',').collect())
        .unwrap_or_default();
    covs.iter()
        .find(|c| !matches!(**c, "x_mm" | "y_mm"))
        .or(covs.first())
        .copied()
        .unwrap_or("")
}

/// The numeric columns `names` of a batch (those it has), each converted
/// once per batch — rows switch group every few thousand rows, and each
/// group reads the same few columns.
fn num_cols<'a>(
    b: &RecordBatch,
    names: impl IntoIterator<Item = &'a String>,
) -> BTreeMap<&'a str, Vec<f64>> {
    names
        .into_iter()
        .filter_map(|n| num_col(b, n).map(|v| (n.as_str(), v)))
        .collect()
}

/// Bins per axis the page draws: the gap map and its thumbnail over x/y,
/// the curve against the named covariate and its thumbnail.
#[derive(Clone, Copy, Debug)]
pub struct Bins {
    pub map: usize,
    pub mini_map: usize,
    pub curve: usize,
    pub mini_curve: usize,
}

/// A map's cells: (x, y, mean of each series) for cells with data,
/// ordered by x then y.
pub type Cells = Vec<(f64, f64, Vec<f64>)>;
/// A curve's bins: (bin centre, mean of each series), ascending.
pub type Curve = Vec<(f64, Vec<f64>)>;

/// What the page draws of one (machine, observable), reduced as the rows
/// stream past: nothing here grows with the rows.
#[derive(Debug, Default)]
pub struct GroupFigures {
    /// Some held-out residual is finite (there is an "after").
    pub has_after: bool,
    /// Over x_mm/y_mm when both have a value: the mean of [gap², held-out
    /// residual²] per cell, at [`Bins::map`] and [`Bins::mini_map`].
    pub map: Option<Cells>,
    pub mini_map: Option<Cells>,
    /// Against the named effect's covariate when it has a value: the mean
    /// of [gap less the other selected effects, the named effect's
    /// contribution, held-out residual, gap] per bin, at [`Bins::curve`]
    /// and [`Bins::mini_curve`].
    pub curve: Option<Curve>,
    pub mini_curve: Option<Curve>,
    /// The named effect's contribution has a value.
    pub has_fit: bool,
}

/// The page's figures per (machine, observable); machine is "" when the
/// table has no `machine` column (a v1 table).
pub struct FleetFigures {
    pub groups: BTreeMap<(String, String), GroupFigures>,
    /// Per (machine, observable): each run's gap RMS before and held-out
    /// RMS after, from the diagnosis rows the second pass reads anyway
    /// (empty without diagnosis.parquet's `gap` and `residual_after`).
    pub per_run: BTreeMap<(String, String), Vec<RunRms>>,
}

/// The distinct finite values of a covariate up to this many are kept per
/// group: enough for every bin count drawn (the distinct values are the
/// bins when there are no more than the bins).
const AXIS_DISTINCT: usize = 64;

/// The finite values of a covariate seen in one group, reduced to what
/// its axis needs: the extremes and the first [`AXIS_DISTINCT`] distinct
/// values (sorted). -0.0 counts as 0.0.
#[derive(Clone, Debug, Default)]
struct AxisScan {
    uniq: Vec<f64>,
    lo: f64,
    hi: f64,
    seen: bool,
    more: bool,
}

impl AxisScan {
    fn push(&mut self, x: f64) {
        if !x.is_finite() {
            return;
        }
        let x = x + 0.0;
        if self.seen {
            self.lo = self.lo.min(x);
            self.hi = self.hi.max(x);
        } else {
            (self.lo, self.hi, self.seen) = (x, x, true);
        }
        if !self.more {
            if let Err(p) = self.uniq.binary_search_by(|u| u.total_cmp(&x)) {
                if self.uniq.len() < AXIS_DISTINCT {
                    self.uniq.insert(p, x);
                } else {
                    self.more = true;
                }
            }
        }
    }

    /// At most `max_bins` bins: the distinct values themselves when there
    /// are no more than that, else equal-width bins over the range.
    fn axis(&self, max_bins: usize) -> Option<Axis> {
        assert!(max_bins < AXIS_DISTINCT, "an axis of {max_bins} bins");
        if !self.seen {
            return None;
        }
        if !self.more && self.uniq.len() <= max_bins {
            return Some(Axis::Distinct(self.uniq.clone()));
        }
        Some(Axis::Width {
            lo: self.lo,
            w: (self.hi - self.lo) / max_bins as f64,
            bins: max_bins,
        })
    }
}

#[derive(Clone, Debug)]
enum Axis {
    Distinct(Vec<f64>),
    Width { lo: f64, w: f64, bins: usize },
}

impl Axis {
    fn bins(&self) -> usize {
        match self {
            Axis::Distinct(u) => u.len(),
            Axis::Width { bins, .. } => *bins,
        }
    }

    fn index(&self, x: f64) -> Option<usize> {
        if !x.is_finite() {
            return None;
        }
        let x = x + 0.0;
        Some(match self {
            Axis::Distinct(u) => u.partition_point(|v| v.total_cmp(&x).is_lt()),
            Axis::Width { lo, w, bins } => (((x - lo) / w) as usize).min(bins - 1),
        })
    }

    fn centre(&self, i: usize) -> f64 {
        match self {
            Axis::Distinct(u) => u[i],
            Axis::Width { lo, w, .. } => lo + (i as f64 + 0.5) * w,
        }
    }
}

/// Per (x, y) cell, the sum and count of each series' finite values, in
/// the order the rows come: the same sums whether the rows are at hand or
/// streaming past. The cells are dense (an axis has fewer than
/// [`AXIS_DISTINCT`] bins): a row is an index, not a map lookup — this is
/// the fleet report's per-row work.
struct Grid {
    x: Axis,
    y: Axis,
    /// Bins along y (a cell is `i * ny + j`).
    ny: usize,
    /// Per cell and series, the sum and count; whether any row fell there.
    sums: Vec<f64>,
    counts: Vec<usize>,
    touched: Vec<bool>,
    series: usize,
}

impl Grid {
    fn new(x: Axis, y: Axis, series: usize) -> Grid {
        let (nx, ny) = (x.bins(), y.bins());
        Grid {
            x,
            y,
            ny,
            sums: vec![0.0; nx * ny * series],
            counts: vec![0; nx * ny * series],
            touched: vec![false; nx * ny],
            series,
        }
    }

    fn push(&mut self, x: f64, y: f64, values: &[f64]) {
        let (Some(i), Some(j)) = (self.x.index(x), self.y.index(y)) else {
            return;
        };
        if j >= self.ny || i * self.ny + j >= self.touched.len() {
            return; // not a value of the axes' scan: no cell of the grid
        }
        let cell = i * self.ny + j;
        self.touched[cell] = true;
        let at = cell * self.series;
        for (k, v) in values.iter().enumerate() {
            if v.is_finite() {
                self.sums[at + k] += v;
                self.counts[at + k] += 1;
            }
        }
    }

    /// The touched cells in (x, y) order.
    fn finish(self) -> Cells {
        let (x, y, ny, series) = (self.x, self.y, self.ny, self.series);
        let (sums, counts) = (self.sums, self.counts);
        self.touched
            .iter()
            .enumerate()
            .filter(|(_, t)| **t)
            .map(|(cell, _)| {
                let at = cell * series;
                let means = sums[at..at + series]
                    .iter()
                    .zip(&counts[at..at + series])
                    .map(|(s, &c)| if c > 0 { s / c as f64 } else { f64::NAN })
                    .collect();
                (x.centre(cell / ny), y.centre(cell % ny), means)
            })
            .collect()
    }
}

/// Mean of each value series per (x, y) grid cell: (x, y, mean per series)
/// for cells with data, ordered by x then y. At most `max_bins`² cells.
pub fn grid_means(x: &[f64], y: &[f64], series: &[&[f64]], max_bins: usize) -> Cells {
    let scan = |v: &[f64]| {
        let mut s = AxisScan::default();
        v.iter().for_each(|&x| s.push(x));
        s.axis(max_bins)
    };
    let (Some(ax), Some(ay)) = (scan(x), scan(y)) else {
        return Vec::new();
    };
    let mut g = Grid::new(ax, ay, series.len());
    let mut row = vec![0.0; series.len()];
    for r in 0..x.len() {
        for (k, s) in series.iter().enumerate() {
            row[k] = s[r];
        }
        g.push(x[r], y[r], &row);
    }
    g.finish()
}

/// Mean of each value series per bin of `c`: (bin centre, means), bins in
/// ascending order, empty bins left out. At most `max_bins` bins.
pub fn binned_means(c: &[f64], series: &[&[f64]], max_bins: usize) -> Curve {
    let ones = vec![0.0; c.len()];
    grid_means(c, &ones, series, max_bins)
        .into_iter()
        .map(|(x, _, m)| (x, m))
        .collect()
}

/// What one observable's pictures read: the covariate its named effect
/// is drawn against and the contribution columns of the named effect and
/// of the other selected effects.
#[derive(Debug)]
struct Drawn {
    cov: Option<String>,
    fit: Option<String>,
    others: Vec<String>,
}

/// Rows in runs of one (machine, observable): the group of each row,
/// without a String per row.
struct GroupOf {
    current: Option<(String, String)>,
}

impl GroupOf {
    fn at(&mut self, m: &str, o: &str) -> (&(String, String), bool) {
        let same = matches!(&self.current, Some((cm, co)) if cm == m && co == o);
        if !same {
            self.current = Some((m.to_string(), o.to_string()));
        }
        (self.current.as_ref().expect("set"), !same)
    }
}

impl FleetFigures {
    /// Two passes over fleet/observations.parquet and, when there is a
    /// diagnosis, the row-aligned fleet/diagnosis.parquet (docs/formats.md
    /// §8: one diagnosis row per observation, in input order): the first
    /// finds each group's axes (the covariates' extremes and first
    /// distinct values), the second sums each cell and bin in row order.
    /// Memory is the groups' cells, not the rows.
    pub fn load(
        observations: &Path,
        diagnosis: Option<(&Path, &Diagnosis)>,
        bins: Bins,
    ) -> Result<Self> {
        let need = |name: &str| {
            crate::err!(
                "{}: no column `{name}`; rerun `sparkout run` to rewrite the fleet tables",
                observations.display()
            )
        };
        // Per observable, what its pictures draw.
        let mut drawn: BTreeMap<String, Drawn> = BTreeMap::new();
        for p in diagnosis.iter().flat_map(|(_, d)| &d.per_observable) {
            let Some(k) = p.selected.first() else {
                continue;
            };
            drawn.insert(
                p.observable.clone(),
                Drawn {
                    cov: Some(curve_covariate(k).to_string()),
                    fit: Some(format!("contrib_{k}")),
                    others: p
                        .selected
                        .iter()
                        .filter(|o| *o != k)
                        .map(|o| format!("contrib_{o}"))
                        .collect(),
                },
            );
        }
        let mut covs: Vec<String> = drawn.values().filter_map(|d| d.cov.clone()).collect();
        covs.sort();
        covs.dedup();
        let mut contribs: Vec<String> = drawn
            .values()
            .flat_map(|d| d.fit.iter().chain(&d.others).cloned())
            .collect();
        contribs.sort();
        contribs.dedup();
        let ob_cols = |n: &str| {
            [
                "machine",
                "run",
                "observable",
                "sim",
                "real",
                "x_mm",
                "y_mm",
            ]
            .contains(&n)
                || covs.iter().any(|c| c == n)
        };
        // Pass 1: the groups and their axes.
        #[derive(Default)]
        struct Scans {
            x: AxisScan,
            y: AxisScan,
            c: AxisScan,
        }
        let mut scans: BTreeMap<(String, String), Scans> = BTreeMap::new();
        let mut group = GroupOf { current: None };
        for b in batches(observations, ob_cols)? {
            let b = b?;
            let obs = utf8(&b, "observable").ok_or_else(|| need("observable"))?;
            let machine = utf8(&b, "machine");
            let (o_s, m_s) = (
                obs.as_string::<i32>(),
                machine.as_ref().map(|m| m.as_string::<i32>()),
            );
            let (x, y) = (num_col(&b, "x_mm"), num_col(&b, "y_mm"));
            let cov_cols = num_cols(&b, &covs);
            let mut s: Option<&mut Scans> = None;
            let mut c: Option<&Vec<f64>> = None;
            for i in 0..b.num_rows() {
                let (key, new) = group.at(m_s.map_or("", |m| m.value(i)), o_s.value(i));
                if new || s.is_none() {
                    let cov = drawn.get(&key.1).and_then(|d| d.cov.as_deref());
                    c = cov.and_then(|n| cov_cols.get(n));
                    s = Some(scans.entry(key.clone()).or_default());
                }
                let sc = s.as_deref_mut().expect("set");
                if let (Some(x), Some(y)) = (&x, &y) {
                    sc.x.push(x[i]);
                    sc.y.push(y[i]);
                }
                if let Some(c) = c {
                    sc.c.push(c[i]);
                }
            }
        }
        // Pass 2: the sums, row by row, the diagnosis beside the rows.
        struct Acc {
            g: GroupFigures,
            map: Option<Grid>,
            mini_map: Option<Grid>,
            curve: Option<Grid>,
            mini_curve: Option<Grid>,
        }
        let zero = Axis::Distinct(vec![0.0]);
        let mut acc: BTreeMap<(String, String), Acc> = scans
            .into_iter()
            .map(|(k, s)| {
                let grid = |n: usize, series: usize| match (s.x.axis(n), s.y.axis(n)) {
                    (Some(x), Some(y)) => Some(Grid::new(x, y, series)),
                    _ => None,
                };
                let curve = |n: usize| s.c.axis(n).map(|c| Grid::new(c, zero.clone(), 4));
                let a = Acc {
                    g: GroupFigures::default(),
                    map: grid(bins.map, 2),
                    mini_map: grid(bins.mini_map, 2),
                    curve: curve(bins.curve),
                    mini_curve: curve(bins.mini_curve),
                };
                (k, a)
            })
            .collect();
        let n_obs = rows_in(observations)?;
        let mut diag = match diagnosis {
            Some((dp, _)) if dp.is_file() => {
                let n_diag = rows_in(dp)?;
                let misaligned = move || {
                    crate::err!(
                        "{}: its {} rows do not line up with the {} rows of {}; rerun `sparkout run` to recompute the diagnosis",
                        dp.display(),
                        n_diag,
                        n_obs,
                        observations.display()
                    )
                };
                if n_diag != n_obs {
                    return Err(misaligned());
                }
                let it = batches(dp, |c| {
                    c == "run" || c == "gap" || c == "residual_after" || c.starts_with("contrib_")
                })?;
                Some((Lockstep::new(Box::new(it)), misaligned))
            }
            _ => None,
        };
        let mut group = GroupOf { current: None };
        let mut run_sums = RunSums::default();
        for b in batches(observations, ob_cols)? {
            let b = b?;
            if b.num_rows() == 0 {
                continue;
            }
            let obs = utf8(&b, "observable").ok_or_else(|| need("observable"))?;
            let run = utf8(&b, "run").ok_or_else(|| need("run"))?;
            let machine = utf8(&b, "machine");
            let (o_s, r_s, m_s) = (
                obs.as_string::<i32>(),
                run.as_string::<i32>(),
                machine.as_ref().map(|m| m.as_string::<i32>()),
            );
            let (x, y) = (num_col(&b, "x_mm"), num_col(&b, "y_mm"));
            // The diagnosis's rows beside this batch's.
            let d = match &mut diag {
                Some((l, misaligned)) => {
                    let d = l.take(b.num_rows())?.ok_or_else(&*misaligned)?;
                    let d_run = utf8(&d, "run").ok_or_else(&*misaligned)?;
                    if !d_run.as_string::<i32>().iter().eq(r_s.iter()) {
                        return Err(misaligned());
                    }
                    Some(d)
                }
                None => None,
            };
            let (gap, residual) = match &d {
                Some(d) => (num_col(d, "gap"), num_col(d, "residual_after")),
                None => (None, None),
            };
            if let (Some(g), Some(r)) = (&gap, &residual) {
                for i in 0..b.num_rows() {
                    run_sums.add(
                        m_s.map_or("", |m| m.value(i)),
                        o_s.value(i),
                        r_s.value(i),
                        g[i],
                        r[i],
                    );
                }
            }
            let gap = match gap {
                Some(g) => g,
                None => {
                    let sim = num_col(&b, "sim").ok_or_else(|| need("sim"))?;
                    let real = num_col(&b, "real").ok_or_else(|| need("real"))?;
                    real.iter().zip(&sim).map(|(r, s)| r - s).collect()
                }
            };
            let cov_cols = num_cols(&b, &covs);
            let contrib_cols = d
                .as_ref()
                .map(|d| num_cols(d, &contribs))
                .unwrap_or_default();
            let mut a: Option<&mut Acc> = None;
            // The current group's covariate, named contribution and others.
            let mut c: Option<&Vec<f64>> = None;
            let mut fit: Option<&Vec<f64>> = None;
            let mut others: Vec<&Vec<f64>> = Vec::new();
            for i in 0..b.num_rows() {
                let (key, new) = group.at(m_s.map_or("", |m| m.value(i)), o_s.value(i));
                if new || a.is_none() {
                    let dr = drawn.get(&key.1);
                    c = dr
                        .and_then(|d| d.cov.as_deref())
                        .and_then(|n| cov_cols.get(n));
                    fit = dr
                        .and_then(|d| d.fit.as_deref())
                        .and_then(|n| contrib_cols.get(n));
                    others = dr
                        .map(|d| {
                            d.others
                                .iter()
                                .filter_map(|o| contrib_cols.get(o.as_str()))
                                .collect()
                        })
                        .unwrap_or_default();
                    a = Some(acc.get_mut(key).expect("every group was scanned"));
                }
                let a = a.as_deref_mut().expect("set");
                let (g, r) = (gap[i], residual.as_ref().map_or(f64::NAN, |r| r[i]));
                a.g.has_after |= r.is_finite();
                if let (Some(x), Some(y)) = (&x, &y) {
                    let sq = [g * g, r * r];
                    if let Some(m) = &mut a.map {
                        m.push(x[i], y[i], &sq);
                    }
                    if let Some(m) = &mut a.mini_map {
                        m.push(x[i], y[i], &sq);
                    }
                }
                if let Some(c) = c {
                    // The gap less the other selected effects, in their order.
                    let mut partial = g;
                    for o in &others {
                        if o[i].is_finite() {
                            partial -= o[i];
                        }
                    }
                    let f = fit.map_or(f64::NAN, |f| f[i]);
                    a.g.has_fit |= f.is_finite();
                    let v = [partial, f, r, g];
                    if let Some(k) = &mut a.curve {
                        k.push(c[i], 0.0, &v);
                    }
                    if let Some(k) = &mut a.mini_curve {
                        k.push(c[i], 0.0, &v);
                    }
                }
            }
        }
        let curve =
            |g: Option<Grid>| g.map(|g| g.finish().into_iter().map(|(x, _, m)| (x, m)).collect());
        let groups = acc
            .into_iter()
            .map(|(k, a)| {
                let mut g = a.g;
                g.map = a.map.map(Grid::finish);
                g.mini_map = a.mini_map.map(Grid::finish);
                g.curve = curve(a.curve);
                g.mini_curve = curve(a.mini_curve);
                (k, g)
            })
            .collect();
        Ok(FleetFigures {
            groups,
            per_run: run_sums.finish(),
        })
    }
}

/// Batches of one file cut to the row counts of another's: the
/// diagnosis's rows beside each batch of the observations, whatever the
/// two files' batch boundaries.
struct Lockstep {
    it: Box<dyn Iterator<Item = Result<RecordBatch>>>,
    pending: Option<RecordBatch>,
}

impl Lockstep {
    fn new(it: Box<dyn Iterator<Item = Result<RecordBatch>>>) -> Lockstep {
        Lockstep { it, pending: None }
    }

    /// The next `n` rows as one batch (None when the file ends first).
    fn take(&mut self, n: usize) -> Result<Option<RecordBatch>> {
        let mut parts: Vec<RecordBatch> = Vec::new();
        let mut have = 0;
        while have < n {
            let b = match self.pending.take() {
                Some(b) => b,
                None => match self.it.next() {
                    Some(b) => b?,
                    None => return Ok(None),
                },
            };
            let want = n - have;
            if b.num_rows() > want {
                self.pending = Some(b.slice(want, b.num_rows() - want));
                parts.push(b.slice(0, want));
                have = n;
            } else {
                have += b.num_rows();
                parts.push(b);
            }
        }
        match parts.len() {
            1 => Ok(parts.pop()),
            _ => Ok(Some(arrow::compute::concat_batches(
                &parts[0].schema(),
                &parts,
            )?)),
        }
    }
}

/// One run's gap RMS before and held-out RMS after (observable's unit).
#[derive(Debug, Clone)]
pub struct RunRms {
    pub run: String,
    pub n: usize,
    pub before: f64,
    pub after: f64,
}

/// Each run's n, Σ gap² and Σ residual² per (machine, observable), summed
/// a stretch of one run at a time in row order, each stretch then added to
/// its run's sums — a group-by whose state is the runs, not the rows:
/// polars' in-memory group-by held the fleet's key strings and their row
/// encoding at once, the peak of a 2 000-run `aggregate`'s memory.
#[derive(Default)]
struct RunSums {
    sums: BTreeMap<RunKey, Sums>,
    /// The stretch being summed.
    current: Option<(RunKey, Sums)>,
}

/// (machine, observable, run).
type RunKey = (String, String, String);
/// (n, Σgap², Σresidual²).
type Sums = (usize, f64, f64);

impl RunSums {
    fn add(&mut self, m: &str, o: &str, r: &str, gap: f64, residual: f64) {
        let same =
            matches!(&self.current, Some(((cm, co, cr), _)) if cm == m && co == o && cr == r);
        if !same {
            self.close_stretch();
            self.current = Some(((m.to_string(), o.to_string(), r.to_string()), (0, 0.0, 0.0)));
        }
        if let Some((_, (n, g2, r2))) = &mut self.current {
            *n += 1;
            *g2 += gap * gap;
            *r2 += residual * residual;
        }
    }

    fn close_stretch(&mut self) {
        if let Some((k, v)) = self.current.take() {
            let e = self.sums.entry(k).or_insert((0, 0.0, 0.0));
            *e = (e.0 + v.0, e.1 + v.1, e.2 + v.2);
        }
    }

    /// Each run's RMS before and after, sorted by machine, observable, run.
    fn finish(mut self) -> BTreeMap<(String, String), Vec<RunRms>> {
        self.close_stretch();
        let mut out: BTreeMap<(String, String), Vec<RunRms>> = BTreeMap::new();
        for ((m, o, run), (n, g2, r2)) in self.sums {
            out.entry((m, o)).or_default().push(RunRms {
                run,
                n,
                before: (g2 / n as f64).sqrt(),
                after: (r2 / n as f64).sqrt(),
            });
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_means_average_within_cells_and_bound_the_cell_count() {
        // Few distinct positions: one cell each.
        let x = [0.0, 0.0, 1.0, 1.0];
        let y = [0.0, 0.0, 0.0, 2.0];
        let v = [1.0, 3.0, 5.0, 7.0];
        let g = grid_means(&x, &y, &[&v], 24);
        assert_eq!(
            g.iter().map(|c| (c.0, c.1, c.2[0])).collect::<Vec<_>>(),
            vec![(0.0, 0.0, 2.0), (1.0, 0.0, 5.0), (1.0, 2.0, 7.0)]
        );
        // Many distinct positions: equal-width bins, never more than asked.
        let x: Vec<f64> = (0..1000).map(|i| i as f64 * 0.37).collect();
        let y: Vec<f64> = (0..1000).map(|i| (i % 97) as f64).collect();
        let g = grid_means(&x, &y, &[&x], 10);
        assert!(g.len() <= 100 && g.len() > 10, "{}", g.len());
        // Each cell's mean of x lies inside its x bin.
        let w = 999.0 * 0.37 / 10.0;
        assert!(g.iter().all(|c| (c.2[0] - c.0).abs() <= w / 2.0 + 1e-9));
    }

    /// -0.0 and 0.0 are one value: one cell, not an index past the
    /// last distinct value.
    #[test]
    fn minus_zero_is_zero() {
        let c = [-0.0, 0.0, 1.0, -0.0];
        let v = [1.0, 3.0, 5.0, 7.0];
        let b = binned_means(&c, &[&v], 40);
        assert_eq!(
            format!("{b:?}"),
            "[(0.0, [3.6666666666666665]), (1.0, [5.0])]"
        );
    }

    #[test]
    fn binned_means_skip_missing_values() {
        let c = [0.0, 0.0, 1.0];
        let v = [f64::NAN, 2.0, 4.0];
        let b = binned_means(&c, &[&v], 40);
        assert_eq!(b, vec![(0.0, vec![2.0]), (1.0, vec![4.0])]);
    }
}

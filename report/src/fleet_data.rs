//! What the fleet page draws, read from fleet/observations.parquet and the
//! row-aligned fleet/diagnosis.parquet (docs/formats.md §8: one diagnosis row
//! per observation, in input order), reduced to aggregates — grid cells,
//! covariate bins, per-run RMS — so the page's size does not grow with the
//! number of rows (< 2 MB for a 1000-run fleet).

use std::collections::BTreeMap;
use std::path::Path;

use arrow::array::{Array, AsArray, RecordBatch};
use arrow::datatypes::DataType as ArrowType;

use crate::error::Result;

/// The fleet's rows, the columns the page needs, grouped by (machine,
/// observable).
pub struct FleetRows {
    /// Row indices per (machine, observable), in row order; machine is ""
    /// when the table has no `machine` column (a v1 table).
    pub groups: BTreeMap<(String, String), Vec<usize>>,
    /// real − sim, in the observable's unit.
    pub gap: Vec<f64>,
    /// Held-out residual after the selected effects (each run's residual
    /// from effects fitted on the other runs); NaN without a diagnosis.
    pub residual: Vec<f64>,
    /// The numeric columns asked for (covariates) and the diagnosis's
    /// `contrib_<effect:covariate>` columns; NaN where null.
    pub num: BTreeMap<String, Vec<f64>>,
}

/// The named columns of a Parquet file (those it has), in batches: only
/// what is drawn is read (a 1000-run fleet has millions of rows), and the
/// batches are not concatenated — the page copies what it keeps out of
/// them, so the fleet's columns are never held twice.
fn read_columns(path: &Path, wanted: impl Fn(&str) -> bool) -> Result<Vec<RecordBatch>> {
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
    let batches = reader
        .collect::<std::result::Result<Vec<_>, _>>()
        .with_context(|| format!("{}: cannot read", path.display()))?;
    Ok(batches)
}

/// Rows in all batches.
fn rows_of(batches: &[RecordBatch]) -> usize {
    batches.iter().map(RecordBatch::num_rows).sum()
}

/// Column `name` of every batch as text (None when a batch lacks it).
fn utf8_all(batches: &[RecordBatch], name: &str) -> Option<Vec<arrow::array::ArrayRef>> {
    batches.iter().map(|b| utf8(b, name)).collect()
}

/// Column `name` of every batch as one float column (None when it is not
/// numeric or a batch lacks it).
fn floats_all(batches: &[RecordBatch], name: &str) -> Option<Vec<f64>> {
    let mut out = Vec::with_capacity(rows_of(batches));
    for b in batches {
        out.extend(floats(b.column_by_name(name)?.as_ref())?);
    }
    Some(out)
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

impl FleetRows {
    /// Read the observations (key columns, sim, real and the covariates
    /// in `covariates`) and, when present, the diagnosis rows.
    pub fn load(
        observations: &Path,
        diagnosis: Option<&Path>,
        covariates: &[String],
    ) -> Result<Self> {
        let keys = ["machine", "run", "observable", "sim", "real"];
        let ob = read_columns(observations, |n| {
            keys.contains(&n) || covariates.iter().any(|c| c == n)
        })?;
        let need = |name: &str| {
            crate::err!(
                "{}: no column `{name}`; rerun `sparkout run` to rewrite the fleet tables",
                observations.display()
            )
        };
        let n = rows_of(&ob);
        let run = utf8_all(&ob, "run").ok_or_else(|| need("run"))?;
        let obs = utf8_all(&ob, "observable").ok_or_else(|| need("observable"))?;
        let machine = utf8_all(&ob, "machine");
        let mut groups: BTreeMap<(String, String), Vec<usize>> = BTreeMap::new();
        {
            // Rows come in runs of one (machine, observable): one String
            // pair per run of rows, not per row.
            let mut current: Option<((String, String), Vec<usize>)> = None;
            let mut row = 0;
            for (bi, o) in obs.iter().enumerate() {
                let o_s = o.as_string::<i32>();
                let m_s = machine.as_ref().map(|m| m[bi].as_string::<i32>());
                for i in 0..o_s.len() {
                    let (m, o) = (m_s.map(|m| m.value(i)).unwrap_or(""), o_s.value(i));
                    match &mut current {
                        Some(((cm, co), rows)) if cm == m && co == o => rows.push(row),
                        _ => {
                            if let Some((k, rows)) = current.take() {
                                groups.entry(k).or_default().extend(rows);
                            }
                            current = Some(((m.to_string(), o.to_string()), vec![row]));
                        }
                    }
                    row += 1;
                }
            }
            if let Some((k, rows)) = current {
                groups.entry(k).or_default().extend(rows);
            }
        }
        drop((obs, machine));
        let mut num = BTreeMap::new();
        if let Some(first) = ob.first() {
            for f in first.schema().fields() {
                if covariates.iter().any(|c| c == f.name()) {
                    if let Some(v) = floats_all(&ob, f.name()) {
                        num.insert(f.name().clone(), v);
                    }
                }
            }
        }
        let mut gap: Vec<f64> = Vec::with_capacity(n);
        for b in &ob {
            let col_of = |c: &str| b.column_by_name(c).and_then(|a| floats(a.as_ref()));
            let sim = col_of("sim").ok_or_else(|| need("sim"))?;
            let real = col_of("real").ok_or_else(|| need("real"))?;
            gap.extend(real.iter().zip(&sim).map(|(r, s)| r - s));
        }
        drop(ob);
        let mut residual = vec![f64::NAN; n];
        if let Some(dp) = diagnosis.filter(|p| p.is_file()) {
            let d = read_columns(dp, |c| {
                c == "run" || c == "gap" || c == "residual_after" || c.starts_with("contrib_")
            })?;
            // Row-aligned by contract; a stale file from another batch is
            // not drawn rather than drawn against the wrong rows.
            let aligned = rows_of(&d) == n
                && utf8_all(&d, "run")
                    .map(|dr| {
                        dr.iter()
                            .flat_map(|x| x.as_string::<i32>().iter())
                            .eq(run.iter().flat_map(|x| x.as_string::<i32>().iter()))
                    })
                    .unwrap_or(false);
            if !aligned {
                crate::bail!(
                    "{}: its {} rows do not line up with the {} rows of {}; rerun `sparkout run` to recompute the diagnosis",
                    dp.display(),
                    rows_of(&d),
                    n,
                    observations.display()
                );
            }
            drop(run);
            let names: Vec<String> = d
                .first()
                .map(|b| {
                    b.schema()
                        .fields()
                        .iter()
                        .map(|f| f.name().clone())
                        .collect()
                })
                .unwrap_or_default();
            for name in names {
                let Some(v) = floats_all(&d, &name) else {
                    continue;
                };
                match name.as_str() {
                    "gap" => gap = v,
                    "residual_after" => residual = v,
                    c if c.starts_with("contrib_") => {
                        num.insert(name.clone(), v);
                    }
                    _ => {}
                }
            }
        }
        Ok(FleetRows {
            groups,
            gap,
            residual,
            num,
        })
    }

    /// A numeric column's values at `rows` (None when the table lacks it
    /// or every value there is missing).
    pub fn values(&self, col: &str, rows: &[usize]) -> Option<Vec<f64>> {
        let c = self.num.get(col)?;
        let v: Vec<f64> = rows.iter().map(|&i| c[i]).collect();
        v.iter().any(|x| x.is_finite()).then_some(v)
    }

    /// `v` (a full column) at `rows`.
    pub fn at(v: &[f64], rows: &[usize]) -> Vec<f64> {
        rows.iter().map(|&i| v[i]).collect()
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

/// Per (machine, observable): each run's RMS of the gap and of the
/// held-out residual, sorted by machine, observable, run. One pass over
/// diagnosis.parquet's batches summing n, Σgap² and Σresidual² per key —
/// a group-by whose state is the runs, not the rows: polars' in-memory
/// group-by held the fleet's key strings and their row encoding at once,
/// the peak of a 2 000-run `aggregate`'s memory.
pub fn per_run_rms(diagnosis: &Path) -> Result<BTreeMap<(String, String), Vec<RunRms>>> {
    let batches = read_columns(diagnosis, |c| {
        matches!(
            c,
            "machine" | "observable" | "run" | "gap" | "residual_after"
        )
    })?;
    // (machine, observable, run) → (n, Σgap², Σresidual²)
    type Sums = (usize, f64, f64);
    let mut sums: BTreeMap<(String, String, String), Sums> = BTreeMap::new();
    let mut current: Option<((String, String, String), Sums)> = None;
    for b in &batches {
        let text = |c: &str| {
            utf8(b, c).ok_or_else(|| crate::err!("{}: no column `{c}`", diagnosis.display()))
        };
        let (obs, run) = (text("observable")?, text("run")?);
        let machine = utf8(b, "machine");
        let num = |c: &str| {
            b.column_by_name(c)
                .and_then(|a| floats(a.as_ref()))
                .ok_or_else(|| crate::err!("{}: no numeric column `{c}`", diagnosis.display()))
        };
        let (gap, resid) = (num("gap")?, num("residual_after")?);
        let (o_s, r_s) = (obs.as_string::<i32>(), run.as_string::<i32>());
        let m_s = machine.as_ref().map(|m| m.as_string::<i32>());
        for i in 0..b.num_rows() {
            let (m, o, r) = (
                m_s.map(|m| m.value(i)).unwrap_or(""),
                o_s.value(i),
                r_s.value(i),
            );
            let same = matches!(&current, Some(((cm, co, cr), _)) if cm == m && co == o && cr == r);
            if !same {
                if let Some((k, v)) = current.take() {
                    let e = sums.entry(k).or_insert((0, 0.0, 0.0));
                    *e = (e.0 + v.0, e.1 + v.1, e.2 + v.2);
                }
                current = Some(((m.to_string(), o.to_string(), r.to_string()), (0, 0.0, 0.0)));
            }
            if let Some((_, (n, g2, r2))) = &mut current {
                *n += 1;
                *g2 += gap[i] * gap[i];
                *r2 += resid[i] * resid[i];
            }
        }
    }
    if let Some((k, v)) = current {
        let e = sums.entry(k).or_insert((0, 0.0, 0.0));
        *e = (e.0 + v.0, e.1 + v.1, e.2 + v.2);
    }
    let mut out: BTreeMap<(String, String), Vec<RunRms>> = BTreeMap::new();
    for ((m, o, run), (n, g2, r2)) in sums {
        out.entry((m, o)).or_default().push(RunRms {
            run,
            n,
            before: (g2 / n as f64).sqrt(),
            after: (r2 / n as f64).sqrt(),
        });
    }
    Ok(out)
}

/// Equal-width bins of `v` (at most `max_bins`; the distinct values
/// themselves when there are no more than that): each value's bin index
/// and the bin centres.
fn bin_axis(v: &[f64], max_bins: usize) -> (Vec<Option<usize>>, Vec<f64>) {
    let mut uniq: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    uniq.sort_by(f64::total_cmp);
    uniq.dedup();
    if uniq.is_empty() {
        return (vec![None; v.len()], Vec::new());
    }
    if uniq.len() <= max_bins {
        let idx = v
            .iter()
            .map(|x| {
                x.is_finite()
                    .then(|| uniq.partition_point(|u| u.total_cmp(x).is_lt()))
            })
            .collect();
        return (idx, uniq);
    }
    let (lo, hi) = (uniq[0], uniq[uniq.len() - 1]);
    let w = (hi - lo) / max_bins as f64;
    let idx = v
        .iter()
        .map(|x| {
            x.is_finite()
                .then(|| (((x - lo) / w) as usize).min(max_bins - 1))
        })
        .collect();
    let centres = (0..max_bins).map(|k| lo + (k as f64 + 0.5) * w).collect();
    (idx, centres)
}

/// Mean of each value series per (x, y) grid cell: (x, y, mean per series)
/// for cells with data, ordered by x then y. At most `max_bins`² cells.
pub fn grid_means(
    x: &[f64],
    y: &[f64],
    series: &[&[f64]],
    max_bins: usize,
) -> Vec<(f64, f64, Vec<f64>)> {
    let (ix, cx) = bin_axis(x, max_bins);
    let (iy, cy) = bin_axis(y, max_bins);
    let mut acc: BTreeMap<(usize, usize), (Vec<f64>, Vec<usize>)> = BTreeMap::new();
    for r in 0..x.len() {
        let (Some(i), Some(j)) = (ix[r], iy[r]) else {
            continue;
        };
        let e = acc
            .entry((i, j))
            .or_insert_with(|| (vec![0.0; series.len()], vec![0; series.len()]));
        for (k, s) in series.iter().enumerate() {
            if s[r].is_finite() {
                e.0[k] += s[r];
                e.1[k] += 1;
            }
        }
    }
    acc.into_iter()
        .map(|((i, j), (sum, n))| {
            let means = sum
                .iter()
                .zip(&n)
                .map(|(s, &c)| if c > 0 { s / c as f64 } else { f64::NAN })
                .collect();
            (cx[i], cy[j], means)
        })
        .collect()
}

/// Mean of each value series per bin of `c`: (bin centre, means), bins in
/// ascending order, empty bins left out. At most `max_bins` bins.
pub fn binned_means(c: &[f64], series: &[&[f64]], max_bins: usize) -> Vec<(f64, Vec<f64>)> {
    let ones = vec![0.0; c.len()];
    grid_means(c, &ones, series, max_bins)
        .into_iter()
        .map(|(x, _, m)| (x, m))
        .collect()
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

    #[test]
    fn binned_means_skip_missing_values() {
        let c = [0.0, 0.0, 1.0];
        let v = [f64::NAN, 2.0, 4.0];
        let b = binned_means(&c, &[&v], 40);
        assert_eq!(b, vec![(0.0, vec![2.0]), (1.0, vec![4.0])]);
    }
}

//! What the fleet page draws, read from fleet/observations.parquet and the
//! row-aligned fleet/diagnosis.parquet (docs/formats.md §8: one diagnosis row
//! per observation, in input order), reduced to aggregates — grid cells,
//! covariate bins, per-run RMS — so the page's size does not grow with the
//! number of rows (< 2 MB for a 1000-run fleet).

use std::collections::BTreeMap;
use std::path::Path;

use arrow::array::{Array, AsArray, RecordBatch};
use arrow::datatypes::DataType as ArrowType;
use polars::prelude::*;

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

/// The named columns of a Parquet file (those it has), one batch: only
/// what is drawn is read (a 1000-run fleet has millions of rows).
fn read_columns(path: &Path, wanted: impl Fn(&str) -> bool) -> Result<RecordBatch> {
    use crate::Context;
    use arrow::record_batch::RecordBatchReader;
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
    let schema = reader.schema();
    let batches = reader
        .collect::<std::result::Result<Vec<_>, _>>()
        .with_context(|| format!("{}: cannot read", path.display()))?;
    Ok(arrow::compute::concat_batches(&schema, &batches)?)
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
        let run = utf8(&ob, "run").ok_or_else(|| need("run"))?;
        let obs = utf8(&ob, "observable").ok_or_else(|| need("observable"))?;
        let machine = utf8(&ob, "machine");
        let (run_s, obs_s) = (run.as_string::<i32>(), obs.as_string::<i32>());
        let mut groups: BTreeMap<(String, String), Vec<usize>> = BTreeMap::new();
        {
            // Group ids through a small map of borrowed keys: one String
            // pair per group, not per row.
            let mut ids: std::collections::HashMap<(&str, &str), Vec<usize>> =
                std::collections::HashMap::new();
            let m_s = machine.as_ref().map(|m| m.as_string::<i32>());
            for i in 0..ob.num_rows() {
                let m = m_s.map(|m| m.value(i)).unwrap_or("");
                ids.entry((m, obs_s.value(i))).or_default().push(i);
            }
            for ((m, o), rows) in ids {
                groups.insert((m.to_string(), o.to_string()), rows);
            }
        }
        let mut num = BTreeMap::new();
        for (f, a) in ob.schema().fields().iter().zip(ob.columns()) {
            if covariates.iter().any(|c| c == f.name()) {
                if let Some(v) = floats(a.as_ref()) {
                    num.insert(f.name().clone(), v);
                }
            }
        }
        let col_of = |n: &str| ob.column_by_name(n).and_then(|a| floats(a.as_ref()));
        let sim = col_of("sim").ok_or_else(|| need("sim"))?;
        let real = col_of("real").ok_or_else(|| need("real"))?;
        let mut gap: Vec<f64> = real.iter().zip(&sim).map(|(r, s)| r - s).collect();
        let mut residual = vec![f64::NAN; ob.num_rows()];
        if let Some(dp) = diagnosis.filter(|p| p.is_file()) {
            let d = read_columns(dp, |n| {
                n == "run" || n == "gap" || n == "residual_after" || n.starts_with("contrib_")
            })?;
            // Row-aligned by contract; a stale file from another batch is
            // not drawn rather than drawn against the wrong rows.
            let aligned = d.num_rows() == ob.num_rows()
                && utf8(&d, "run")
                    .map(|r| r.as_string::<i32>().iter().eq(run_s.iter()))
                    .unwrap_or(false);
            if !aligned {
                crate::bail!(
                    "{}: its {} rows do not line up with the {} rows of {}; rerun `sparkout run` to recompute the diagnosis",
                    dp.display(),
                    d.num_rows(),
                    ob.num_rows(),
                    observations.display()
                );
            }
            for (f, a) in d.schema().fields().iter().zip(d.columns()) {
                let Some(v) = floats(a.as_ref()) else {
                    continue;
                };
                match f.name().as_str() {
                    "gap" => gap = v,
                    "residual_after" => residual = v,
                    n if n.starts_with("contrib_") => {
                        num.insert(n.to_string(), v);
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
/// held-out residual — a polars group-by over diagnosis.parquet, sorted by
/// machine, observable, run.
pub fn per_run_rms(diagnosis: &Path) -> Result<BTreeMap<(String, String), Vec<RunRms>>> {
    let mut lf = LazyFrame::scan_parquet(
        PlRefPath::new(diagnosis.to_string_lossy().as_ref()),
        ScanArgsParquet::default(),
    )?;
    let has_machine = lf
        .collect_schema()?
        .iter_names()
        .any(|n| n.as_str() == "machine");
    let keys: Vec<&str> = if has_machine {
        vec!["machine", "observable", "run"]
    } else {
        vec!["observable", "run"]
    };
    let df = lf
        .group_by(keys.iter().map(|k| col(*k)).collect::<Vec<_>>())
        .agg([
            col("gap").count().alias("n"),
            (col("gap") * col("gap")).mean().sqrt().alias("before"),
            (col("residual_after") * col("residual_after"))
                .mean()
                .sqrt()
                .alias("after"),
        ])
        .sort(keys.clone(), SortMultipleOptions::default())
        .collect()?;
    let machine = if has_machine {
        Some(df.column("machine")?.str()?.clone())
    } else {
        None
    };
    let run = df.column("run")?.str()?.clone();
    let obs = df.column("observable")?.str()?.clone();
    let n = df.column("n")?.cast(&polars::prelude::DataType::Int64)?;
    let n = n.i64()?.clone();
    let before = df.column("before")?.f64()?.clone();
    let after = df.column("after")?.f64()?.clone();
    let mut out: BTreeMap<(String, String), Vec<RunRms>> = BTreeMap::new();
    for i in 0..df.height() {
        let m = machine
            .as_ref()
            .and_then(|m| m.get(i))
            .unwrap_or("")
            .to_string();
        out.entry((m, obs.get(i).unwrap_or("").to_string()))
            .or_default()
            .push(RunRms {
                run: run.get(i).unwrap_or("").to_string(),
                n: n.get(i).unwrap_or(0) as usize,
                before: before.get(i).unwrap_or(f64::NAN),
                after: after.get(i).unwrap_or(f64::NAN),
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

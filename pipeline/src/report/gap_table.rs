//! Gap per run and observable for the fleet report: a polars group-by over
//! the fleet's observations.parquet.

use std::path::Path;

use polars::prelude::*;

use crate::error::Result;

/// Rows of (run, observable, n, mean gap, RMS gap), sorted by run then
/// observable.
pub fn gap_by_run_observable(observations: &Path) -> Result<Vec<Vec<String>>> {
    let lf = LazyFrame::scan_parquet(
        PlRefPath::new(observations.to_string_lossy().as_ref()),
        ScanArgsParquet::default(),
    )?;
    let gap = col("real") - col("sim");
    let df = lf
        .group_by([col("run"), col("observable")])
        .agg([
            gap.clone().count().alias("n"),
            gap.clone().mean().alias("mean"),
            (gap.clone() * gap).mean().sqrt().alias("rms"),
        ])
        .sort(["run", "observable"], SortMultipleOptions::default())
        .collect()?;
    let run = df.column("run")?.str()?.clone();
    let obs = df.column("observable")?.str()?.clone();
    let n = df.column("n")?.cast(&DataType::Int64)?;
    let n = n.i64()?.clone();
    let mean = df.column("mean")?.f64()?.clone();
    let rms = df.column("rms")?.f64()?.clone();
    let mut rows = Vec::with_capacity(df.height());
    for i in 0..df.height() {
        rows.push(vec![
            run.get(i).unwrap_or("").to_string(),
            obs.get(i).unwrap_or("").to_string(),
            n.get(i).unwrap_or(0).to_string(),
            super::fmt_mm(mean.get(i).unwrap_or(f64::NAN)),
            super::fmt_mm(rms.get(i).unwrap_or(f64::NAN)),
        ]);
    }
    Ok(rows)
}

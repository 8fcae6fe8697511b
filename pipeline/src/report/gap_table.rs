//! Gap per machine, run and observable for the fleet report: a polars
//! group-by over the fleet's observations.parquet (issue 12: runs are
//! (machine, run) pairs; a v1 table without `machine` groups by run).

use std::path::Path;

use polars::prelude::*;

use crate::error::Result;

/// Rows of ([machine,] run, observable, n, mean gap, RMS gap), sorted by
/// machine, run, observable; and whether the machine column is there.
pub fn gap_by_run_observable(observations: &Path) -> Result<(bool, Vec<Vec<String>>)> {
    let mut lf = LazyFrame::scan_parquet(
        PlRefPath::new(observations.to_string_lossy().as_ref()),
        ScanArgsParquet::default(),
    )?;
    let has_machine = lf
        .collect_schema()?
        .iter_names()
        .any(|n| n.as_str() == "machine");
    let keys: Vec<&str> = if has_machine {
        vec!["machine", "run", "observable"]
    } else {
        vec!["run", "observable"]
    };
    let gap = col("real") - col("sim");
    let df = lf
        .group_by(keys.iter().map(|k| col(*k)).collect::<Vec<_>>())
        .agg([
            gap.clone().count().alias("n"),
            gap.clone().mean().alias("mean"),
            (gap.clone() * gap).mean().sqrt().alias("rms"),
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
    let n = df.column("n")?.cast(&DataType::Int64)?;
    let n = n.i64()?.clone();
    let mean = df.column("mean")?.f64()?.clone();
    let rms = df.column("rms")?.f64()?.clone();
    let mut rows = Vec::with_capacity(df.height());
    for i in 0..df.height() {
        let mut row = Vec::with_capacity(6);
        if let Some(m) = &machine {
            row.push(m.get(i).unwrap_or("").to_string());
        }
        row.extend([
            run.get(i).unwrap_or("").to_string(),
            obs.get(i).unwrap_or("").to_string(),
            n.get(i).unwrap_or(0).to_string(),
            super::fmt_mm(mean.get(i).unwrap_or(f64::NAN)),
            super::fmt_mm(rms.get(i).unwrap_or(f64::NAN)),
        ]);
        rows.push(row);
    }
    Ok((has_machine, rows))
}

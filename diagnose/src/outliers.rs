//! Robust to spikes: a real surface map or probe log has
//! isolated wild values (a chip under the probe, a dropout) that dominate
//! every sum of squares — the fit, the held-out score and the shrink.
//!
//! Detection runs on the held-out residual of a first, plain pass (what the
//! selected effects leave): its scale is the MAD (σ̂ = 1.4826·MAD, which
//! 1 % of spikes barely moves), and a row is an outlier when its residual is
//! more than [`K_SIGMA`]·σ̂ from the median *and* both its neighbours in
//! run/time order are not (a spike is one sample; a bump or step the
//! catalogue lacks spans many, and stays in the data for `where` to show).
//! At most [`MAX_SHARE`] of the rows may be outliers — more is not spikes
//! but structure, and nothing is trimmed (a note says so).
//!
//! The second pass trims the outliers from every fit, held-out score, noise
//! floor and cell; the shrink is then reported robustly (`shrink`, kept
//! rows) and plainly (`shrink_plain`, every row, the outliers predicted by
//! the all-runs fits).

use std::collections::BTreeMap;

use serde::Serialize;

use super::covariates::{retain_positions, Covariates};
use super::gather::ObsRows;
use super::noise::median;
use super::run_length::RunLength;

/// Threshold in robust standard deviations.
pub const K_SIGMA: f64 = 6.0;
/// Above this share of flagged rows nothing is trimmed.
pub const MAX_SHARE: f64 = 0.05;

/// diagnosis.json `per_observable[].outliers`.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct OutlierReport {
    pub n: usize,
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
    pub share: f64,
    /// Robust σ̂ of the residual and the threshold K_SIGMA·σ̂ (mm).
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
    pub sigma_robust_mm: f64,
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
    pub threshold_mm: f64,
    /// Where: count per run (`machine/run` when the table has machines).
    pub by_run: BTreeMap<String, usize>,
    /// Largest |residual| among them (mm).
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
    pub max_abs_mm: f64,
}

/// Positions (into `o.rows`) of isolated outliers of `residual` (same
/// order), or why none are trimmed.
pub fn detect(o: &ObsRows, residual: &[f64]) -> Result<(Vec<usize>, f64, f64), String> {
    let n = residual.len();
    if n < 20 {
        return Ok((Vec::new(), f64::NAN, f64::NAN));
    }
    // One buffer for both medians: the residual's, then (overwritten) the
    // deviations' — a median is the same whatever order its values are in.
    let mut buf = residual.to_vec();
    let med = median(&mut buf);
    for (d, r) in buf.iter_mut().zip(residual) {
        *d = (r - med).abs();
    }
    let sigma = 1.4826 * median(&mut buf);
    drop(buf);
    if sigma.is_nan() || sigma <= 0.0 {
        return Ok((Vec::new(), sigma, f64::NAN));
    }
    let thr = K_SIGMA * sigma;
    let big = |i: usize| (residual[i] - med).abs() > thr;
    // Isolated: neither neighbour in run/time order (inside the same run)
    // is beyond the threshold too.
    let mut out = Vec::new();
    for r in &o.run_ranges {
        for i in r.clone() {
            if big(i) && !(i > r.start && big(i - 1)) && !(i + 1 < r.end && big(i + 1)) {
                out.push(i);
            }
        }
    }
    if out.len() as f64 > MAX_SHARE * n as f64 {
        return Err(format!(
            "{}: {} of {} rows lie beyond {K_SIGMA}σ of the residual: structure, not spikes — nothing trimmed",
            o.name,
            out.len(),
            n
        ));
    }
    Ok((out, sigma, thr))
}

/// The report of trimmed rows `out` (positions into `o.rows`).
pub fn report(
    o: &ObsRows,
    out: &[usize],
    residual: &[f64],
    run_names: &[String],
    run_id: &RunLength<u32>,
    sigma: f64,
    thr: f64,
) -> OutlierReport {
    let mut by_run: BTreeMap<String, usize> = BTreeMap::new();
    for &p in out {
        *by_run
            .entry(run_names[run_id.get(o.rows[p]) as usize].clone())
            .or_default() += 1;
    }
    OutlierReport {
        n: out.len(),
        share: out.len() as f64 / o.n().max(1) as f64,
        sigma_robust_mm: sigma,
        threshold_mm: thr,
        by_run,
        max_abs_mm: out.iter().fold(0.0, |m, &p| m.max(residual[p].abs())),
    }
}

impl ObsRows {
    /// The same observable without the rows at `drop` (positions, sorted),
    /// its rows, gap, machines and covariates moved out of `self` (which
    /// keeps its name and run ranges) and filtered in place: a second copy of every covariate while the first was
    /// still held was the spike-free pass's start (≈ 90 B a row). Covariates
    /// in a file are rewritten a chunk at a time to a new one in `scratch`
    /// (or the old file's folder).
    pub fn take_kept(
        &mut self,
        drop: &[usize],
        scratch: Option<&std::path::Path>,
    ) -> crate::Result<ObsRows> {
        let (mut run_ranges, mut run_machine) = (Vec::new(), Vec::new());
        let mut start = 0;
        // `drop` is sorted and the run ranges are contiguous: each run's
        // dropped rows counted by bisection.
        for (r, &m) in self.run_ranges.iter().zip(&self.run_machine) {
            let gone =
                drop.partition_point(|&p| p < r.end) - drop.partition_point(|&p| p < r.start);
            let len = r.len() - gone;
            if len > 0 {
                run_ranges.push(start..start + len);
                run_machine.push(m);
                start += len;
            }
        }
        let mut rows = std::mem::take(&mut self.rows);
        retain_positions(&mut rows, drop);
        let mut gap = std::mem::take(&mut self.gap);
        retain_positions(&mut gap, drop);
        Ok(ObsRows {
            name: self.name.clone(),
            rows,
            gap,
            run_ranges,
            run_machine,
            // Each kept covariate sorts again for its constants.
            cols: std::mem::replace(&mut self.cols, Covariates::none(0))
                .without_rows(drop, scratch)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effect::CovStats;

    /// The kept rows are the rows not dropped, in order, with their gap,
    /// machine and covariates; a run left with no row disappears from the
    /// run ranges; the covariates' constants are those of the kept values.
    #[test]
    fn the_kept_rows_are_the_rows_not_trimmed() {
        let n = 10;
        let mut o = ObsRows {
            name: "e".into(),
            rows: (100..100 + n).collect(),
            gap: (0..n).map(|i| i as f64 * 0.5).collect(),
            run_ranges: vec![0..4, 4..5, 5..10],
            run_machine: vec![7, 8, 9],
            cols: Covariates::in_memory(
                n,
                vec![("x_mm".into(), (0..n).map(|i| (i * i) as f64).collect())],
            ),
        };
        let drop = [0, 4, 9];
        let kept = o.take_kept(&drop, None).unwrap();
        let keep: Vec<usize> = (0..n).filter(|p| !drop.contains(p)).collect();
        assert_eq!(kept.rows, keep.iter().map(|p| 100 + p).collect::<Vec<_>>());
        assert_eq!(
            kept.gap,
            keep.iter().map(|&p| p as f64 * 0.5).collect::<Vec<_>>()
        );

        let x: Vec<f64> = keep.iter().map(|&p| (p * p) as f64).collect();
        assert_eq!(*kept.cols.column("x_mm").unwrap(), x[..]);
        assert_eq!(
            kept.cols.frames().next().unwrap().1,
            CovStats::from_values(&x)
        );
        // Run 1 held only row 4: gone, with its machine.
        assert_eq!(kept.run_ranges, vec![0..3, 3..7]);
        assert_eq!(kept.run_machine, vec![7, 9]);
        assert_eq!(kept.machine_of_rows(), vec![7, 7, 7, 9, 9, 9, 9]);
        // What stays behind: the name and the runs; every row-sized
        // column moved out.
        assert_eq!(o.n(), 0);
        assert_eq!(o.run_ranges.len(), 3);
        assert!(o.cols.names().is_empty() && o.gap.is_empty());
    }
}

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
    let med = median(&mut residual.to_vec());
    let mut dev: Vec<f64> = residual.iter().map(|r| (r - med).abs()).collect();
    let sigma = 1.4826 * median(&mut dev);
    if sigma.is_nan() || sigma <= 0.0 {
        return Ok((Vec::new(), sigma, f64::NAN));
    }
    let thr = K_SIGMA * sigma;
    let big: Vec<bool> = residual.iter().map(|r| (r - med).abs() > thr).collect();
    let mut run_of = vec![0usize; n];
    for (k, r) in o.run_ranges.iter().enumerate() {
        for i in r.clone() {
            run_of[i] = k;
        }
    }
    let neighbour_big =
        |i: usize, j: Option<usize>| j.is_some_and(|j| j < n && run_of[j] == run_of[i] && big[j]);
    let out: Vec<usize> = (0..n)
        .filter(|&i| {
            big[i] && !neighbour_big(i, i.checked_sub(1)) && !neighbour_big(i, Some(i + 1))
        })
        .collect();
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
    /// The same observable without the rows at `drop` (positions, sorted).
    pub fn without(&self, drop: &[usize]) -> ObsRows {
        let keep: Vec<usize> = (0..self.n())
            .filter(|p| drop.binary_search(p).is_err())
            .collect();
        let pick = |v: &[f64]| keep.iter().map(|&p| v[p]).collect::<Vec<f64>>();
        let mut run_ranges = Vec::new();
        let mut start = 0;
        // `keep` is sorted and the run ranges are contiguous: count each
        // run's kept rows by bisection (a scan per run was O(runs × rows):
        // minutes for a 500-run fleet).
        for r in &self.run_ranges {
            let len = keep.partition_point(|&p| p < r.end) - keep.partition_point(|&p| p < r.start);
            if len > 0 {
                run_ranges.push(start..start + len);
                start += len;
            }
        }
        ObsRows {
            name: self.name.clone(),
            rows: keep.iter().map(|&p| self.rows[p]).collect(),
            gap: pick(&self.gap),
            run_ranges,
            machine: keep.iter().map(|&p| self.machine[p]).collect(),
            // Each kept covariate sorts again for its constants: in parallel.
            cols: {
                use rayon::prelude::*;
                self.cols
                    .par_iter()
                    .map(|c| super::gather::Cov::new(c.name.clone(), pick(&c.v)))
                    .collect()
            },
        }
    }
}

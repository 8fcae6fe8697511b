//! Covariates that move together within runs: an effect of one of them
//! cannot be told from an effect of the other on these runs (a raster
//! where position and time advance together, a wear that grows with the
//! clock). For each covariate of a selected effect: the covariates whose
//! within-run correlation reaches `collinear_r`, and its within-run
//! variance inflation factor against all the other covariates.
//!
//! "Within run": every covariate is centred on its run's mean before the
//! cross products are pooled, so a covariate that differs between runs
//! only (a run's start temperature) is not mistaken for one that moves
//! with another inside each run, and runs that scan in opposite
//! directions cancel each other's correlation — as they should, since
//! they are what lets the diagnosis tell the two effects apart.

use std::collections::BTreeMap;
use std::ops::Range;

use nalgebra::DMatrix;

use crate::covariates::{Covariates, READ_ROWS};
use serde::Serialize;

/// A covariate of a selected effect that moves with others within runs.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct Collinearity {
    pub covariate: String,
    /// Covariates with |within-run r| ≥ `collinear_r`, and r.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub moves_with: BTreeMap<String, f64>,
    /// Within-run variance inflation factor against every other covariate
    /// (1e6 when it is a linear combination of them).
    #[serde(deserialize_with = "sparkout_core::files::json::f64_or_nan")]
    pub vif: f64,
    /// What an engineer can change so the next runs tell the effects apart.
    pub advice: String,
    /// Candidates of the selected effect's round whose covariates are
    /// among those it moves with and that are indistinguishable from it or
    /// also passed the held-out test removing ≥ `confound_share` of what it
    /// removes (docs/models.md §8.6): the same gap explained by another
    /// cause, which these runs cannot rule out even where the selected
    /// form scores better (a
    /// three-parameter curve on time can follow a wear curve on the
    /// removed volume that rises with time in every run). Printed only
    /// when not empty — a collinear covariate that no passing rival uses
    /// is no news.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub confounds: Vec<String>,
    /// Each of `confounds`' held-out RMS in the selected effect's round,
    /// in the observable's `unit` (its entry in `effects` holds its last
    /// round's figures, which may be a later one's).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub confound_rms: BTreeMap<String, f64>,
}

/// A rival a collinearity may explain: its key, covariates and held-out
/// RMS in the selected effect's round.
pub struct Rival {
    pub key: String,
    pub covariates: Vec<String>,
    pub rms: f64,
}

impl Collinearity {
    /// Names the rivals (`key`, its covariates) this collinearity explains:
    /// those using a covariate it moves with, or — when only its VIF is
    /// high, and only for rivals `indistinguishable` from the selected
    /// effect (a high VIF names no partner, so a rival that scores worse
    /// is not pinned on it) — any covariate other than its own.
    pub fn add_confounds(&mut self, rivals: &[Rival], indistinguishable: bool) {
        for r in rivals {
            let hit = if self.moves_with.is_empty() {
                indistinguishable && r.covariates.iter().any(|c| *c != self.covariate)
            } else {
                r.covariates.iter().any(|c| self.moves_with.contains_key(c))
            };
            if hit && !self.confounds.contains(&r.key) {
                self.confounds.push(r.key.clone());
                if r.rms.is_finite() {
                    self.confound_rms.insert(r.key.clone(), r.rms);
                }
            }
        }
    }
}

/// Largest VIF reported (a covariate that is an exact combination).
const VIF_CAP: f64 = 1e6;

/// Within-run cross products of the columns over `runs` (ranges of the
/// columns), added to `s` run after run.
fn add_within_run_scatter(s: &mut DMatrix<f64>, cols: &[&[f64]], runs: &[Range<usize>]) {
    let p = cols.len();
    let mut centred = vec![Vec::new(); p];
    for r in runs {
        let len = r.len() as f64;
        for (c, col) in centred.iter_mut().zip(cols) {
            let x = &col[r.clone()];
            let m = x.iter().sum::<f64>() / len;
            *c = x.iter().map(|v| v - m).collect();
        }
        for a in 0..p {
            for b in a..p {
                let v: f64 = centred[a].iter().zip(&centred[b]).map(|(x, y)| x * y).sum();
                s[(a, b)] += v;
                if a != b {
                    s[(b, a)] += v;
                }
            }
        }
    }
}

/// The collinearity of each covariate in `of` (covariates of selected
/// effects) among the covariates `covs` (values in run order) over
/// `runs`; reported when it moves with another (|r| ≥ `max_r`) or its VIF
/// ≥ `max_vif`. One pass over the runs, a chunk of whole runs at a time:
/// the within-run cross products and each covariate's Σx² are sums over
/// runs, added in run order.
pub fn collinear(
    covs: &Covariates,
    runs: &[Range<usize>],
    of: &[String],
    max_r: f64,
    max_vif: f64,
) -> crate::Result<Vec<Collinearity>> {
    collinear_in_chunks(covs, runs, of, max_r, max_vif, READ_ROWS)
}

/// [`collinear`] reading at most `chunk_rows` rows at a time (a run longer
/// than that on its own): the same bits for any chunk size.
fn collinear_in_chunks(
    covs: &Covariates,
    runs: &[Range<usize>],
    of: &[String],
    max_r: f64,
    max_vif: f64,
    chunk_rows: usize,
) -> crate::Result<Vec<Collinearity>> {
    if of.is_empty() {
        return Ok(Vec::new());
    }
    let names = covs.names();
    let p = names.len();
    let mut s = DMatrix::<f64>::zeros(p, p);
    // Σx² of each covariate over every row, in row order (as `sum` adds).
    let mut raw = vec![-0.0f64; p];
    let mut first = 0;
    while first < runs.len() {
        let mut last = first + 1;
        while last < runs.len() && runs[last].end - runs[first].start <= chunk_rows {
            last += 1;
        }
        let span = runs[first].start..runs[last - 1].end;
        let x = covs.rows_of(names, span.clone())?;
        let cols: Vec<&[f64]> = names.iter().map(|c| x.col(c).expect("read")).collect();
        let local: Vec<Range<usize>> = runs[first..last]
            .iter()
            .map(|r| r.start - span.start..r.end - span.start)
            .collect();
        add_within_run_scatter(&mut s, &cols, &local);
        for (acc, col) in raw.iter_mut().zip(&cols) {
            for v in col.iter() {
                *acc += v * v;
            }
        }
        first = last;
    }
    // Covariates that vary within runs at all (beyond rounding of their
    // raw values).
    let live: Vec<usize> = (0..p)
        .filter(|&i| s[(i, i)].is_finite() && s[(i, i)] > 1e-20 * raw[i].max(f64::MIN_POSITIVE))
        .collect();
    let r = |a: usize, b: usize| s[(a, b)] / (s[(a, a)] * s[(b, b)]).sqrt();
    let mut out = Vec::new();
    for name in of {
        let Some(a) = names.iter().position(|c| c == name) else {
            continue;
        };
        if !live.contains(&a) {
            continue;
        }
        let moves_with: BTreeMap<String, f64> = live
            .iter()
            .filter(|&&b| b != a && r(a, b).abs() >= max_r)
            .map(|&b| (names[b].clone(), r(a, b)))
            .collect();
        let vif = vif_of(a, &live, &r);
        if moves_with.is_empty() && vif < max_vif {
            continue;
        }
        let with: Vec<String> = if moves_with.is_empty() {
            vec![format!("the other covariates (VIF {vif:.0})")]
        } else {
            moves_with
                .iter()
                .map(|(k, r)| format!("{k} (r = {r:.3})"))
                .collect()
        };
        out.push(Collinearity {
            covariate: name.clone(),
            advice: format!(
                "{name} moves with {} within every run, so effects of one cannot be told from effects of the other on these runs: vary the scan direction, the start time or the order of the passes between runs",
                with.join(", ")
            ),
            moves_with,
            vif,
            confounds: Vec::new(),
            confound_rms: BTreeMap::new(),
        });
    }
    Ok(out)
}

/// 1 / (1 − R²) of covariate `a` on the other live covariates: the
/// diagonal of the inverse within-run correlation matrix.
fn vif_of(a: usize, live: &[usize], r: &dyn Fn(usize, usize) -> f64) -> f64 {
    if live.len() < 2 {
        return 1.0;
    }
    let p = live.len();
    let corr = DMatrix::from_fn(p, p, |i, j| if i == j { 1.0 } else { r(live[i], live[j]) });
    let Some(ia) = live.iter().position(|&l| l == a) else {
        return 1.0;
    };
    match corr.try_inverse() {
        Some(inv) if inv[(ia, ia)].is_finite() && inv[(ia, ia)] > 0.0 => inv[(ia, ia)].min(VIF_CAP),
        _ => VIF_CAP,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_raster_in_one_direction_is_collinear_and_alternating_runs_are_not() {
        // Two runs of 50 rows: x advances with time; temperature rises.
        let n = 50;
        let t: Vec<f64> = (0..2 * n).map(|i| (i % n) as f64).collect();
        let temp: Vec<f64> = t.iter().map(|t| 20.0 + 0.02 * t + 1e-4 * t * t).collect();
        let same: Vec<f64> = t.clone();
        let alternating: Vec<f64> = (0..2 * n)
            .map(|i| if i < n { t[i] } else { (n - 1) as f64 - t[i] })
            .collect();
        let runs = [0..n, n..2 * n];
        let of = vec!["temp_c".to_string()];
        let covs = |x: &[f64]| {
            Covariates::in_memory(
                2 * n,
                vec![("temp_c".into(), temp.clone()), ("x_mm".into(), x.to_vec())],
            )
        };
        let c = collinear(&covs(&same), &runs, &of, 0.95, 10.0).unwrap();
        // A run at a time: the same sums in the same order.
        let one = collinear_in_chunks(&covs(&same), &runs, &of, 0.95, 10.0, 1).unwrap();
        assert_eq!(c[0].vif.to_bits(), one[0].vif.to_bits());
        assert_eq!(
            c[0].moves_with["x_mm"].to_bits(),
            one[0].moves_with["x_mm"].to_bits()
        );
        assert_eq!(c.len(), 1);
        assert!(c[0].moves_with["x_mm"] > 0.95, "{:?}", c[0]);
        assert!(c[0].vif >= 10.0 && c[0].advice.contains("scan direction"));
        let c = collinear(&covs(&alternating), &runs, &of, 0.95, 10.0).unwrap();
        assert!(c.is_empty(), "{c:?}");
    }
}

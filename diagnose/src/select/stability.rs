//! Is a selection robust and material, and can it be told from the other
//! candidates? All three read the per-unit held-out errors the round
//! already computed (`CandEval::unit_sse`): no candidate is refitted.
//!
//! - Stability: half-subsamples of the runs (every subset of ⌈G/2⌉ of the
//!   G runs when there are at most [`RESAMPLES`] such subsets, else
//!   [`RESAMPLES`] seeded draws). A candidate's `selection_frequency` is
//!   the share of subsamples on whose held-out units its gain holds: mean
//!   log RMS ratio ≥ `min_gain` and a lower held-out error. Significance
//!   is tested once, on every held-out unit (the round's paired test): on
//!   half of 6 runs a t-test has 2 degrees of freedom, and a real effect
//!   whose size differs from run to run (a warm-up that is larger on some
//!   runs) would fail it on most halves. An effect that one or two runs
//!   carry, or whose gain hovers at the margin, fails on many halves.
//! - Materiality: `gap_share` = the held-out SSE the candidate removes over
//!   the observable's explainable SSE — the held-out gap SSE minus n·σ²
//!   (the noise floor's share). A consistent but tiny improvement on a
//!   high-SNR observable is significant and stable, and still explains
//!   next to nothing.
//! - Identifiability: a candidate scored in the same round is
//!   indistinguishable from the chosen one when the 95 % Student-t interval
//!   of the mean over held-out units of ½·ln(SSE_other/SSE_chosen) contains
//!   zero, and it itself passes the selection test.

use rand::seq::SliceRandom;
use rand::SeedableRng;

use super::{paired_log_test, SelectOptions};

/// At most this many half-subsamples per round.
pub const RESAMPLES: usize = 100;

/// Masks over the units: each keeps the units of ⌈G/2⌉ of the G runs.
pub fn half_samples(unit_run: &[usize], seed: u64) -> Vec<Vec<bool>> {
    let mut runs: Vec<usize> = unit_run.to_vec();
    runs.sort_unstable();
    runs.dedup();
    let g = runs.len();
    if g < 2 {
        return Vec::new();
    }
    let h = g.div_ceil(2);
    let mask_of = |pick: &[usize]| -> Vec<bool> {
        unit_run
            .iter()
            .map(|r| pick.iter().any(|&p| runs[p] == *r))
            .collect()
    };
    if n_choose_k(g, h) <= RESAMPLES as f64 {
        let mut out = Vec::new();
        let mut idx: Vec<usize> = (0..h).collect();
        loop {
            out.push(mask_of(&idx));
            // Next h-subset in lexicographic order.
            let Some(i) = (0..h).rev().find(|&i| idx[i] < g - h + i) else {
                break;
            };
            idx[i] += 1;
            for j in i + 1..h {
                idx[j] = idx[j - 1] + 1;
            }
        }
        return out;
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut all: Vec<usize> = (0..g).collect();
    (0..RESAMPLES)
        .map(|_| {
            all.shuffle(&mut rng);
            let mut pick = all[..h].to_vec();
            pick.sort_unstable();
            mask_of(&pick)
        })
        .collect()
}

fn n_choose_k(n: usize, k: usize) -> f64 {
    (0..k).fold(1.0, |acc, i| acc * (n - i) as f64 / (i + 1) as f64)
}

/// The round's selection test on every held-out unit.
pub fn passes(before: &[f64], after: &[f64], opt: &SelectOptions) -> bool {
    let (mlr, p) = paired_log_test(before, after);
    p < opt.alpha && mlr >= opt.min_gain && after.iter().sum::<f64>() < before.iter().sum::<f64>()
}

/// Does the gain hold on the units of `mask`: mean log RMS ratio ≥
/// `min_gain` and a lower held-out error there?
pub fn gains(before: &[f64], after: &[f64], mask: &[bool], opt: &SelectOptions) -> bool {
    let (mut sb, mut sa, mut sum, mut m) = (0.0, 0.0, 0.0, 0usize);
    for ((b, a), keep) in before.iter().zip(after).zip(mask) {
        if *keep && b.is_finite() && a.is_finite() {
            sb += b;
            sa += a;
            sum += 0.5 * ((b + 1e-300) / (a + 1e-300)).ln();
            m += 1;
        }
    }
    m > 0 && sum / m as f64 >= opt.min_gain && sa < sb
}

/// Share of the half-subsamples on which the candidate's gain holds;
/// NaN without subsamples (a single unit).
pub fn selection_frequency(
    before: &[f64],
    after: &[f64],
    halves: &[Vec<bool>],
    opt: &SelectOptions,
) -> f64 {
    if halves.is_empty() {
        return f64::NAN;
    }
    let hits = halves
        .iter()
        .filter(|m| gains(before, after, m, opt))
        .count();
    hits as f64 / halves.len() as f64
}

/// Held-out SSE removed (before − after) over the explainable SSE.
pub fn gap_share(sse_before: f64, sse_after: f64, explainable: f64) -> f64 {
    if explainable > 0.0 {
        (sse_before - sse_after) / explainable
    } else {
        f64::NAN
    }
}

/// The explainable held-out SSE of an observable: its gap SSE minus the
/// noise floor's n·σ², at least a thousandth of the gap SSE (σ̂ is an
/// estimate and may come close to the gap's RMS).
pub fn explainable_sse(sse_gap: f64, n: usize, sigma: f64) -> f64 {
    let noise = n as f64 * sigma * sigma;
    let e = sse_gap - if noise.is_finite() { noise } else { 0.0 };
    e.max(1e-3 * sse_gap)
}

/// Mean over units of ½·ln(other/chosen) and its 95 % interval (NaN with
/// fewer than two finite units).
pub fn paired_interval(chosen: &[f64], other: &[f64]) -> (f64, f64, f64) {
    let d: Vec<f64> = chosen
        .iter()
        .zip(other)
        .filter(|(c, o)| c.is_finite() && o.is_finite())
        .map(|(c, o)| 0.5 * ((o + 1e-300) / (c + 1e-300)).ln())
        .collect();
    let m = d.len();
    if m < 2 {
        return (f64::NAN, f64::NAN, f64::NAN);
    }
    let mean = d.iter().sum::<f64>() / m as f64;
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (m - 1) as f64;
    let se = (var / m as f64).sqrt();
    let t = crate::student_t::t_quantile(0.975, (m - 1) as f64);
    (mean, mean - t * se, mean + t * se)
}

/// Is `other` indistinguishable from `chosen` on these held-out units?
pub fn indistinguishable(chosen: &[f64], other: &[f64]) -> bool {
    let (_, lo, hi) = paired_interval(chosen, other);
    lo <= 0.0 && hi >= 0.0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opt() -> SelectOptions {
        SelectOptions {
            gap_unit: "mm".into(),
            alpha: 0.01,
            noise_margin: 1.1,
            sigma_mm: 1.0,
            max_effects: 4,
            min_gain: 0.01,
            min_frequency: 0.8,
            min_gap_share: 0.05,
            seed: 0,
            allow_selection: true,
        }
    }

    #[test]
    fn halves_enumerate_small_fleets_and_keep_runs_whole() {
        // 4 runs, 2 units each: C(4,2) = 6 halves of 2 runs = 4 units.
        let unit_run = [0, 0, 1, 1, 2, 2, 3, 3];
        let h = half_samples(&unit_run, 7);
        assert_eq!(h.len(), 6);
        for m in &h {
            assert_eq!(m.iter().filter(|x| **x).count(), 4);
            for u in (0..8).step_by(2) {
                assert_eq!(m[u], m[u + 1], "a run is kept or dropped whole");
            }
        }
        // 12 runs: C(12,6) = 924 > RESAMPLES, so seeded draws.
        let many: Vec<usize> = (0..12).collect();
        let a = half_samples(&many, 3);
        assert_eq!(a.len(), RESAMPLES);
        assert_eq!(a, half_samples(&many, 3));
        assert!(half_samples(&[0, 0, 0], 1).is_empty());
    }

    #[test]
    fn frequency_is_low_when_one_run_carries_the_gain() {
        let unit_run: Vec<usize> = (0..8).collect();
        let halves = half_samples(&unit_run, 0);
        let before = vec![1.0; 8];
        // Every run gains 30 % with a little scatter: passes everywhere.
        let steady: Vec<f64> = (0..8).map(|u| 0.7 + 0.01 * u as f64).collect();
        assert_eq!(selection_frequency(&before, &steady, &halves, &opt()), 1.0);
        // One run gains a lot, seven lose a little: the mean gain is carried
        // by that run, and the halves without it (half of them) see none.
        let one = [0.2, 1.03, 1.04, 1.02, 1.05, 1.03, 1.04, 1.03];
        let f = selection_frequency(&before, &one, &halves, &opt());
        assert!(f < 0.6, "{f}");
    }

    #[test]
    fn interval_separates_a_worse_candidate_from_an_equal_one() {
        let chosen: Vec<f64> = (0..10).map(|u| 1.0 + 0.1 * (u % 3) as f64).collect();
        let equal: Vec<f64> = chosen
            .iter()
            .enumerate()
            .map(|(u, c)| c * if u % 2 == 0 { 1.02 } else { 0.98 })
            .collect();
        let worse: Vec<f64> = chosen.iter().map(|c| c * 1.5).collect();
        assert!(indistinguishable(&chosen, &equal));
        assert!(!indistinguishable(&chosen, &worse));
        assert!((gap_share(10.0, 6.0, 8.0) - 0.5).abs() < 1e-12);
        assert_eq!(explainable_sse(100.0, 10, 2.0), 60.0);
        assert_eq!(explainable_sse(100.0, 10, 5.0), 0.1);
    }
}

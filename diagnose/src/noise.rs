//! The noise floor σ of one observable (docs/design.md §7 point 1,
//! "Where is the gap?"; docs/models.md §8.2): the repeatability of replicate observations where
//! the table has them, else a robust estimate of point-to-point scatter.

use std::collections::BTreeMap;
use std::ops::Range;

use super::gather::ObsRows;
use super::observations::Table;

/// Which estimate the floor came from (diagnosis.json `noise_floor_source`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NoiseSource {
    Replicates,
    PointToPoint,
    /// The RMS of the table's `real_u` (a stated resolution), when larger.
    Stated,
}

impl NoiseSource {
    pub fn as_str(self) -> &'static str {
        match self {
            NoiseSource::Replicates => "replicates",
            NoiseSource::PointToPoint => "point_to_point",
            NoiseSource::Stated => "stated_uncertainty",
        }
    }
}

#[derive(Debug, Clone, Copy)]
pub struct NoiseFloor {
    pub sigma_mm: f64,
    /// Degrees of freedom of σ² (for the F-tests of cells against it).
    pub df: f64,
    pub source: NoiseSource,
}

/// Step 2, noise: the floor of one observable — replicates, else
/// point-to-point scatter within each run unit.
pub fn floor_of(table: &Table, o: &ObsRows) -> crate::Result<NoiseFloor> {
    let rep = table
        .trial
        .as_ref()
        .map_or(Ok(None), |trial| -> crate::Result<_> {
            let tr: Vec<i64> = trial.at(&o.rows);
            // One trial value throughout (e.g. `trial` null on every row of
            // this observable): no group can hold replicates, so the per-row
            // keys below (≈ 100 B a row) need not be built.
            if tr.iter().all(|&t| t == tr[0]) {
                return Ok(None);
            }
            let has_position = ["x_mm", "y_mm", "z_mm", "phi_rad"]
                .iter()
                .any(|p| o.cols.contains(p));
            if table.point.is_none() && !has_position {
                return Ok(None);
            }
            // Replicates repeat the same measurement: same run unit, point and
            // every setting (position, speed, direction, load, pass); only the
            // trial and what runs on with time (t_s, temperature, cumulative
            // usage) may differ. Keying on the point id alone would pool a
            // point probed at two speeds, or point 3 of two faces, and count
            // their real difference as noise.
            // Whole columns (the keys are per row anyway).
            let settings: Vec<std::borrow::Cow<[f64]>> = o
                .cols
                .names()
                .iter()
                .filter(|c| !is_time_like(c))
                .map(|c| o.cols.column(c))
                .collect::<crate::Result<_>>()?;
            let run = table.run.at(&o.rows);
            let point = table.point.as_ref().map(|p| p.at(&o.rows));
            let key: Vec<Vec<i64>> = run
                .iter()
                .enumerate()
                .map(|(j, &unit)| {
                    let mut k = vec![unit as i64];
                    if let Some(p) = &point {
                        k.push(p[j]);
                    }
                    k.extend(settings.iter().map(|c| c[j].to_bits() as i64));
                    k
                })
                .collect();
            Ok(replicate_floor(&o.gap, &key, &tr))
        })?;
    let nf = rep.unwrap_or_else(|| point_to_point_floor(&o.gap, &o.run_ranges));
    // A measurement cannot be compared finer than its own stated
    // uncertainty (e.g. positions logged in 1 mm steps): the floor is never
    // below the RMS of `real_u` where the table states it.
    let stated = table.real_u.as_ref().and_then(|u| {
        let v: Vec<f64> = u
            .at(&o.rows)
            .into_iter()
            .filter(|x| x.is_finite())
            .collect();
        (!v.is_empty()).then(|| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt())
    });
    Ok(match stated {
        Some(s) if s > nf.sigma_mm => NoiseFloor {
            sigma_mm: s,
            df: nf.df.max(o.rows.len() as f64),
            source: NoiseSource::Stated,
        },
        _ => nf,
    })
}

/// Covariates that change between replicates of one measurement by nature:
/// time, temperature and cumulative usage.
fn is_time_like(name: &str) -> bool {
    name == "t_s" || name == "temp_c" || name == "infeed_count" || name.ends_with("_mm3")
}

/// Minimum replicate degrees of freedom before the replicate estimate is
/// trusted over point-to-point scatter.
const MIN_REPLICATE_DF: f64 = 10.0;

/// Pooled within-group standard deviation of replicates: rows sharing a
/// `key` (run, point or position, pass) with at least two distinct trials.
/// σ² = Σ_groups Σ (g − ḡ)² / Σ (n_g − 1).
pub fn replicate_floor(gap: &[f64], key: &[Vec<i64>], trial: &[i64]) -> Option<NoiseFloor> {
    let mut groups: BTreeMap<&[i64], Vec<usize>> = BTreeMap::new();
    for (i, k) in key.iter().enumerate() {
        groups.entry(k.as_slice()).or_default().push(i);
    }
    let (mut ss, mut df) = (0.0, 0.0);
    for rows in groups.values() {
        if rows.len() < 2 {
            continue;
        }
        let t0 = trial[rows[0]];
        if rows.iter().all(|&i| trial[i] == t0) {
            continue; // not replicates: the same trial seen twice
        }
        let m = rows.iter().map(|&i| gap[i]).sum::<f64>() / rows.len() as f64;
        ss += rows.iter().map(|&i| (gap[i] - m).powi(2)).sum::<f64>();
        df += (rows.len() - 1) as f64;
    }
    (df >= MIN_REPLICATE_DF).then(|| NoiseFloor {
        sigma_mm: (ss / df).sqrt(),
        df,
        source: NoiseSource::Replicates,
    })
}

/// Robust point-to-point scatter: successive differences of the gap within
/// each run (rows ordered by time, else as given), σ = 1.4826·MAD(Δg)/√2.
/// Smooth effects barely change from one sample to the next, so Δg is
/// mostly noise; the MAD ignores the jumps at path ends and reversals.
/// Efficiency of the MAD ≈ 37 %, hence the effective df.
pub fn point_to_point_floor(gap: &[f64], runs: &[Range<usize>]) -> NoiseFloor {
    let mut d: Vec<f64> = Vec::with_capacity(gap.len());
    for r in runs {
        let g = &gap[r.clone()];
        d.extend(g.windows(2).map(|w| w[1] - w[0]));
    }
    if d.is_empty() {
        return NoiseFloor {
            sigma_mm: 0.0,
            df: 0.0,
            source: NoiseSource::PointToPoint,
        };
    }
    let med = median(&mut d.clone());
    let mut dev: Vec<f64> = d.iter().map(|v| (v - med).abs()).collect();
    let mad = median(&mut dev);
    // Quantised data (a gap that mostly repeats its value exactly) have a
    // MAD of 0 although they scatter: then the floor is the rounding noise
    // of the typical step q, q/√12 (q = median non-zero |Δg|).
    let sigma = if mad > 0.0 {
        1.4826 * mad / std::f64::consts::SQRT_2
    } else {
        let mut steps: Vec<f64> = d.iter().map(|v| v.abs()).filter(|v| *v > 0.0).collect();
        if steps.is_empty() {
            0.0
        } else {
            median(&mut steps) / 12f64.sqrt()
        }
    };
    NoiseFloor {
        sigma_mm: sigma,
        df: (0.37 * d.len() as f64).max(1.0),
        source: NoiseSource::PointToPoint,
    }
}

pub fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let m = v.len() / 2;
    let (_, x, _) = v.select_nth_unstable_by(m, f64::total_cmp);
    *x
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    #[test]
    fn replicates_and_point_to_point_recover_sigma() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let nd = Normal::new(0.0, 0.01).unwrap();
        let mut gap = Vec::new();
        let mut key = Vec::new();
        let mut trial = Vec::new();
        for p in 0..2000 {
            let smooth = 0.05 * (p as f64 / 300.0).sin();
            for t in 0..2 {
                gap.push(smooth + nd.sample(&mut rng));
                key.push(vec![0, p]);
                trial.push(t);
            }
        }
        let r = replicate_floor(&gap, &key, &trial).unwrap();
        assert!((r.sigma_mm - 0.01).abs() < 0.0008, "{}", r.sigma_mm);
        let whole: Vec<Range<usize>> = std::iter::once(0..gap.len()).collect();
        let p = point_to_point_floor(&gap, &whole);
        assert!((p.sigma_mm - 0.01).abs() < 0.001, "{}", p.sigma_mm);
    }

    #[test]
    // One block covering every row: a slice of one range is the API.
    #[allow(clippy::single_range_in_vec_init)]
    fn quantised_gap_has_a_rounding_floor_not_zero() {
        // Mostly repeated values, occasional 1 mm steps: MAD(Δg) = 0.
        let gap: Vec<f64> = (0..1000)
            .map(|i| if (i / 7) % 5 == 0 { 1.0 } else { 0.0 })
            .collect();
        let p = point_to_point_floor(&gap, &[0..gap.len()]);
        assert!(
            (p.sigma_mm - 1.0 / 12f64.sqrt()).abs() < 1e-12,
            "{}",
            p.sigma_mm
        );
    }
}

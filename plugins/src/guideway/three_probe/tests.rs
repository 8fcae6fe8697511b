use super::*;
use crate::guideway::input::tests::{geom, pass_points};
use crate::guideway::input::{prepare, InputOptions, RawReadings};
use std::path::Path;

/// Exact readings of a known h, δz, β over `passes` back-and-forth passes.
fn synth(m: usize, k: usize, passes: usize) -> (Readings, Vec<f64>, Vec<f64>) {
    let step = 30.0;
    let l = k as f64 * step;
    // Bounded at any length: a wave plus a bow of 5 µm over the travel.
    let hj = |j: usize| 2e-3 * ((j as f64) * 0.21).sin() + 5e-3 * (j as f64 / m as f64).powi(2);
    let mut raw = RawReadings::default();
    let (mut dzs, mut n) = (Vec::new(), 0i64);
    for p in 0..passes {
        for j in pass_points(m, p) {
            let dz = 1e-3 * (n as f64 * 0.05).cos() + 3e-4 * p as f64;
            let beta = 1e-6 * (n as f64 * 0.03).sin();
            raw.n.push(n);
            raw.x_mm.push(j as f64 * step);
            raw.z_mm[0].push(hj(j) + dz);
            raw.z_mm[1].push(hj(j + k) + dz + l * beta);
            raw.z_mm[2].push(hj(j + 2 * k) + dz + 2.0 * l * beta);
            dzs.push(dz);
            n += 1;
        }
    }
    let r = prepare(
        Path::new("g.parquet"),
        raw,
        &geom(l, step),
        &InputOptions::default(),
    )
    .unwrap();
    let h = (0..r.positions()).map(hj).collect();
    (r, h, dzs)
}

/// ĥ − h must be a line a + b·j and δẑ − δz = −(a + b·j) at A's point.
fn assert_exact_up_to_line(r: &Readings, s: &Separation, h: &[f64], dz: &[f64]) {
    let e: Vec<f64> = s.h_mm.iter().zip(h).map(|(a, b)| a - b).collect();
    let n = e.len() as f64;
    let xm = (n - 1.0) / 2.0;
    let ym = e.iter().sum::<f64>() / n;
    let b = e
        .iter()
        .enumerate()
        .map(|(i, y)| (i as f64 - xm) * (y - ym))
        .sum::<f64>()
        / e.iter()
            .enumerate()
            .map(|(i, _)| (i as f64 - xm).powi(2))
            .sum::<f64>();
    let line = |j: usize| ym + b * (j as f64 - xm);
    for (j, v) in e.iter().enumerate() {
        assert!(
            (v - line(j)).abs() < 1e-10,
            "h at {j}: {v} vs line (m = {n})"
        );
    }
    for (i, d) in dz.iter().enumerate() {
        let want = d - line(r.j[i]);
        assert!((s.dz_mm[i] - want).abs() < 1e-10, "dz at {i}");
    }
}

#[test]
fn both_methods_are_exact_on_noise_free_data() {
    let (r, h, dz) = synth(40, 1, 3);
    for s in [
        separate_recursion(&r).unwrap(),
        separate_lsq(&r, Reference::Line, 1e-4).unwrap(),
        separate_lsq(&r, Reference::Ends, 1e-4).unwrap(),
    ] {
        assert_exact_up_to_line(&r, &s, &h, &dz);
    }
    let ends = separate_lsq(&r, Reference::Ends, 1e-4).unwrap();
    assert!(ends.h_mm[0].abs() < 1e-12 && ends.h_mm[41].abs() < 1e-12);
    let line = separate_lsq(&r, Reference::Line, 1e-4).unwrap();
    assert!(line.h_mm.iter().sum::<f64>().abs() < 1e-10);
    assert_eq!(line.sigma_source, Some("residuals"));
    assert!(line.sigma_mm.unwrap() < 1e-12);
}

#[test]
fn single_pass_lsq_uses_the_configured_sigma() {
    let (r, _, _) = synth(30, 1, 1);
    let s = separate_lsq(&r, Reference::Line, 1e-4).unwrap();
    assert_eq!(s.sigma_source, Some("config"));
    let hs = s.h_sigma_mm.unwrap();
    // Integrated twice: the band is widest at the ends, never zero.
    assert!(hs.iter().all(|v| *v > 0.0));
    assert!(hs[0] > hs[15]);
}

/// No length limit, exact to 1e-9 mm at 3 000 and 30 000
/// points with both methods, one pass and several, k = 1 and 2.
#[test]
fn both_methods_are_exact_at_3000_and_30000_points() {
    for (m, k, passes) in [(3000, 1, 3), (3000, 2, 2), (30_000, 1, 1), (30_000, 3, 2)] {
        let (r, h, _) = synth(m, k, passes);
        assert!(r.positions() > 3000);
        for s in [
            separate_recursion(&r).unwrap(),
            separate_lsq(&r, Reference::Line, 1e-4).unwrap(),
        ] {
            // Up to the trend the method cannot see (per sub-grid).
            for sub in 0..k {
                let idx: Vec<usize> = (sub..r.positions()).step_by(k).collect();
                let e: Vec<f64> = idx.iter().map(|&j| s.h_mm[j] - h[j]).collect();
                let n = e.len() as f64;
                let tm = (n - 1.0) / 2.0;
                let em = e.iter().sum::<f64>() / n;
                let (mut sxy, mut sxx) = (0.0, 0.0);
                for (t, v) in e.iter().enumerate() {
                    sxy += (t as f64 - tm) * (v - em);
                    sxx += (t as f64 - tm).powi(2);
                }
                let worst = e
                    .iter()
                    .enumerate()
                    .map(|(t, v)| (v - em - sxy / sxx * (t as f64 - tm)).abs())
                    .fold(0.0, f64::max);
                assert!(
                    worst < 1e-9,
                    "{:?} m={m} k={k} passes={passes}: h off by {worst:e} mm",
                    s.method
                );
            }
        }
    }
}

/// Dense reference: pseudo-inverse of Σ s sᵀ, referenced as the old
/// dense solver did (orthonormal null basis, T = I − Q(RQ)⁻¹R).
fn dense_cov(r: &Readings, reference: Reference) -> nalgebra::DMatrix<f64> {
    use nalgebra::DMatrix;
    let (m, k) = (r.positions(), r.k);
    let mut nm = DMatrix::<f64>::zeros(m, m);
    const W: [f64; 3] = [1.0, -2.0, 1.0];
    for i in 0..r.len() {
        let s = stencil(r, i);
        for a in 0..3 {
            for b in 0..3 {
                nm[(s[a], s[b])] += W[a] * W[b];
            }
        }
    }
    let pinv = nm.pseudo_inverse(1e-9).unwrap();
    if reference == Reference::Line {
        return pinv;
    }
    let mut b = DMatrix::zeros(m, 2 * k);
    for j in 0..m {
        b[(j, 2 * (j % k))] = 1.0;
        b[(j, 2 * (j % k) + 1)] = j as f64;
    }
    let q = b.qr().q();
    let mut rm = DMatrix::<f64>::zeros(2 * k, m);
    for sub in 0..k {
        rm[(2 * sub, sub)] = 1.0;
        rm[(2 * sub + 1, sub + ((m - 1 - sub) / k) * k)] = 1.0;
    }
    let t = DMatrix::<f64>::identity(m, m) - &q * (&rm * &q).try_inverse().unwrap() * &rm;
    &t * pinv * t.transpose()
}

#[test]
fn covariance_band_matches_the_dense_pseudo_inverse() {
    for (m, k, passes) in [(30, 1, 1), (25, 2, 3), (20, 3, 2)] {
        let (mut r, _, _) = synth(m, k, passes);
        // Uneven counts: drop a few samples of the last pass.
        if passes > 1 {
            let keep = r.len() - 4;
            for v in r.z_mm.iter_mut() {
                v.truncate(keep);
            }
            r.j.truncate(keep);
            r.n.truncate(keep);
        }
        // Deterministic reading noise so σ comes from the residuals.
        for (p, v) in r.z_mm.iter_mut().enumerate() {
            for (i, x) in v.iter_mut().enumerate() {
                *x += 1e-4 * ((i as f64 * 12.9898 + p as f64 * 78.233).sin() * 43758.5453).fract();
            }
        }
        for reference in [Reference::Line, Reference::Ends] {
            let s = separate_lsq(&r, reference, 1e-4).unwrap();
            let var_d = 6.0 * s.sigma_mm.unwrap().powi(2);
            let dense = dense_cov(&r, reference) * var_d;
            let hs = s.h_sigma_mm.as_ref().unwrap();
            let scale = dense.diagonal().max();
            for j in 0..r.positions() {
                let want = dense[(j, j)].max(0.0).sqrt();
                assert!(
                    (hs[j] - want).abs() < 1e-6 * scale.sqrt(),
                    "{reference:?} m={m} k={k} h_sigma[{j}] {} vs {want}",
                    hs[j]
                );
            }
            // δz σ uses the off-diagonal band: check it too.
            let s2 = s.sigma_mm.unwrap().powi(2);
            for i in 0..r.len() {
                let st = stencil(&r, i);
                let wd = [-5.0 / 6.0, -2.0 / 6.0, 1.0 / 6.0];
                let mut q = 0.0;
                for a in 0..3 {
                    for b in 0..3 {
                        q += wd[a] * wd[b] * dense[(st[a], st[b])];
                    }
                }
                let want = (5.0 * s2 / 6.0 + q).sqrt();
                let got = s.dz_sigma_mm.as_ref().unwrap()[i];
                assert!(
                    (got - want).abs() < 1e-6 * want,
                    "{reference:?} dz σ {i}: {got} vs {want}"
                );
            }
        }
    }
}

//! Dynamic deflection of a simply supported beam crossed at speed v by a
//! force F and a moment M travelling with it, entering at x = 0 at t = 0
//! (docs/models.md §2.3, the standard moving-load solution):
//!
//!   W_F = −(2Fl³/(EIπ⁴)) Σ n⁻⁴ /(1 − α_n²) sin(nπx/l)[sin(nπvt/l) − α_n sin(ω_n t)]
//!   W_M = −(2Ml²/(EIπ³)) Σ n⁻³ /(1 − α_n²) sin(nπx/l)[cos(nπvt/l) − α_n cos(ω_n t)]
//!
//! with α_n = nπv/(ω_n l) = α₁/n. Two evaluations, both truncated
//! adaptively — terms are added until a bound on *everything left* (not just
//! the next term) is below the tolerance:
//! - [`series_direct`]: the series as written. Its tail falls like N⁻³
//!   (force) and N⁻² (moment), so it needs thousands of terms for 1e-9.
//! - [`series`]: the closed-form static deflection plus the series of the
//!   *difference* dynamic − static, whose terms carry a factor α_n ∝ 1/n
//!   (tail N⁻⁴ and N⁻³): a few terms at machining speeds. Production uses this.
//!
//! Signs: positive F and M give negative (downward) W, as published.

use std::f64::consts::PI;

use super::beam::Beam;

/// A series value and how many terms it took.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeriesValue {
    pub w_mm: f64,
    pub terms: usize,
}

/// Why a series cannot be evaluated.
#[derive(Debug, Clone, PartialEq)]
pub enum SeriesError {
    /// The load is at or above the first critical speed (α₁ ≥ 1): the
    /// solution resonates; the model does not apply.
    Critical { v_mm_s: f64, critical_mm_s: f64 },
    /// The tail bound did not fall below the tolerance within the cap.
    NoConvergence { terms: usize },
}

impl std::fmt::Display for SeriesError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SeriesError::Critical { v_mm_s, critical_mm_s } => write!(
                f,
                "path velocity {v_mm_s} mm/s is at or above the beam's first critical speed {critical_mm_s:.1} mm/s; the moving-load model does not apply"
            ),
            SeriesError::NoConvergence { terms } => {
                write!(f, "moving-load series did not converge in {terms} terms")
            }
        }
    }
}

const MAX_TERMS: usize = 2_000_000;

/// α₁ and the time the load reaches a (0 when v = 0: the static limit).
fn alpha1(beam: &Beam, v: f64) -> Result<f64, SeriesError> {
    let a1 = PI * v / (beam.omega(1) * beam.span_mm);
    if a1 >= 1.0 {
        return Err(SeriesError::Critical {
            v_mm_s: v,
            critical_mm_s: beam.critical_speed_mm_s(),
        });
    }
    Ok(a1)
}

/// A load crossing the beam, seen at one point: the deflection at `x_mm`
/// while the load is at `at_mm` (= v·t), moving at `v_mm_s`, pressing with
/// `force_n` and turning with `moment_n_mm`.
#[derive(Debug, Clone, Copy)]
pub struct MovingLoad {
    pub x_mm: f64,
    pub at_mm: f64,
    pub v_mm_s: f64,
    pub force_n: f64,
    pub moment_n_mm: f64,
}

/// The two series' scales, 2|F|l³/(EIπ⁴) and 2|M|l²/(EIπ³) (docs/models.md §2.3).
fn series_scales(beam: &Beam, load: &MovingLoad) -> (f64, f64) {
    let (l, ei) = (beam.span_mm, beam.ei_n_mm2);
    (
        2.0 * load.force_n.abs() * l.powi(3) / (ei * PI.powi(4)),
        2.0 * load.moment_n_mm.abs() * l * l / (ei * PI.powi(3)),
    )
}

/// Mode n of the solution: (n, its wave number nπ/l, α_n = α₁/n, ω_n).
fn mode(beam: &Beam, a1: f64, n: usize) -> (f64, f64, f64, f64) {
    let nf = n as f64;
    (nf, nf * PI / beam.span_mm, a1 / nf, beam.omega(n))
}

/// The series exactly as docs/models.md §2.3 writes it; `tol_mm` bounds the
/// truncation error of W_F + W_M. Kept beside [`series`] as its check: the
/// tests require both to agree (to 1e-11 of the static deflection).
pub fn series_direct(
    beam: &Beam,
    load: MovingLoad,
    tol_mm: f64,
) -> Result<SeriesValue, SeriesError> {
    let MovingLoad {
        x_mm: x,
        at_mm: a,
        v_mm_s: v,
        ..
    } = load;
    let a1 = alpha1(beam, v)?;
    let t = if v > 0.0 { a / v } else { 0.0 };
    let (cf, cm) = series_scales(beam, &load);
    let (mut sf, mut sm) = (0.0, 0.0);
    for n in 1..=MAX_TERMS {
        let (nf, b, an, w) = mode(beam, a1, n);
        let amp = 1.0 / (1.0 - an * an);
        let sx = (b * x).sin();
        sf += amp * sx * ((b * a).sin() - an * (w * t).sin()) / nf.powi(4);
        sm += amp * sx * ((b * a).cos() - an * (w * t).cos()) / nf.powi(3);
        // Tail beyond n: |terms| ≤ k⁻⁴/(1 − α_k) (force), k⁻³/(1 − α_k)
        // (moment), α_k ≤ α₁/(n+1); Σ_{k>n} k⁻⁴ ≤ 1/(3n³), Σ k⁻³ ≤ 1/(2n²).
        let g = 1.0 / (1.0 - a1 / (nf + 1.0));
        let tail = g * (cf / (3.0 * nf.powi(3)) + cm / (2.0 * nf * nf));
        if tail <= tol_mm {
            return Ok(SeriesValue {
                w_mm: -(load.force_n.signum() * cf * sf + load.moment_n_mm.signum() * cm * sm),
                terms: n,
            });
        }
    }
    Err(SeriesError::NoConvergence { terms: MAX_TERMS })
}

/// The same solution as the static closed forms plus the series of the
/// dynamic − static difference (Kummer's acceleration): identical value,
/// far fewer terms; exactly the static deflection at v = 0.
pub fn series(beam: &Beam, load: MovingLoad, tol_mm: f64) -> Result<SeriesValue, SeriesError> {
    let MovingLoad {
        x_mm: x,
        at_mm: a,
        v_mm_s: v,
        force_n,
        moment_n_mm,
    } = load;
    let a1 = alpha1(beam, v)?;
    let stat = -(force_n * beam.point(x, a) + moment_n_mm * beam.moment(x, a));
    if a1 == 0.0 {
        return Ok(SeriesValue {
            w_mm: stat,
            terms: 0,
        });
    }
    let t = a / v;
    let (cf, cm) = series_scales(beam, &load);
    let (mut sf, mut sm) = (0.0, 0.0);
    for n in 1..=MAX_TERMS {
        let (nf, b, an, w) = mode(beam, a1, n);
        let den = 1.0 - an * an;
        let sx = (b * x).sin();
        // dynamic − static bracket: (α² s − α sin ωt)/(1 − α²), |·| ≤ α/(1 − α).
        sf += sx * (an * an * (b * a).sin() - an * (w * t).sin()) / den / nf.powi(4);
        sm += sx * (an * an * (b * a).cos() - an * (w * t).cos()) / den / nf.powi(3);
        // Tail: α_k/(1 − α_k) ≤ (α₁/k)/(1 − α₁/(n+1)); Σ_{k>n} k⁻⁵ ≤ 1/(4n⁴),
        // Σ k⁻⁴ ≤ 1/(3n³).
        let g = a1 / (1.0 - a1 / (nf + 1.0));
        let tail = g * (cf / (4.0 * nf.powi(4)) + cm / (3.0 * nf.powi(3)));
        if tail <= tol_mm {
            return Ok(SeriesValue {
                w_mm: stat - (force_n.signum() * cf * sf + moment_n_mm.signum() * cm * sm),
                terms: n,
            });
        }
    }
    Err(SeriesError::NoConvergence { terms: MAX_TERMS })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn load(x_mm: f64, at_mm: f64, v_mm_s: f64, force_n: f64, moment_n_mm: f64) -> MovingLoad {
        MovingLoad {
            x_mm,
            at_mm,
            v_mm_s,
            force_n,
            moment_n_mm,
        }
    }

    fn stringer() -> Beam {
        // aplm-gantry stringer: steel box 250×150×8, l = 2400 mm, 3033 N.
        Beam {
            span_mm: 2400.0,
            ei_n_mm2: 2e5 * 5.22e7,
            mass_t_per_mm: 3033.0 / 9810.0 / 2400.0,
        }
    }

    #[test]
    fn v_to_zero_equals_the_static_point_load_to_1e9() {
        let b = stringer();
        let f = 3735.0;
        let scale = f * b.span_mm.powi(3) / (48.0 * b.ei_n_mm2);
        for (x, a) in [
            (1200.0, 1200.0),
            (300.0, 1700.0),
            (2000.0, 650.0),
            (50.0, 60.0),
        ] {
            let stat = -f * b.point(x, a);
            let d = series_direct(&b, load(x, a, 1e-9, f, 0.0), 1e-12 * scale).unwrap();
            let rel = (d.w_mm - stat).abs() / stat.abs();
            assert!(
                rel < 1e-9,
                "x={x} a={a}: {} vs {stat} (rel {rel:e})",
                d.w_mm
            );
            assert!(d.terms > 100, "the direct series needs many terms");
        }
    }

    #[test]
    fn moment_series_at_rest_matches_its_closed_form() {
        let b = stringer();
        let m = 2.0e4;
        let scale = m * b.span_mm.powi(2) / b.ei_n_mm2;
        for (x, a) in [(700.0, 1500.0), (1900.0, 400.0)] {
            let d = series_direct(&b, load(x, a, 0.0, 0.0, m), 1e-8 * scale).unwrap();
            let stat = -m * b.moment(x, a);
            assert!((d.w_mm - stat).abs() < 2e-8 * scale, "{} vs {stat}", d.w_mm);
        }
    }

    #[test]
    fn accelerated_series_equals_the_direct_one_at_speed() {
        let b = stringer();
        let (f, m) = (3735.0, 3.0e4);
        let scale = f * b.span_mm.powi(3) / (48.0 * b.ei_n_mm2);
        // Machining speed (9 m/min) and a fast one (α₁ ≈ 0.5) where the
        // dynamics are large.
        for v in [150.0, 0.5 * b.critical_speed_mm_s()] {
            for (x, a) in [(1200.0, 1200.0), (500.0, 1900.0), (2100.0, 300.0)] {
                let d = series_direct(&b, load(x, a, v, f, m), 1e-11 * scale).unwrap();
                let k = series(&b, load(x, a, v, f, m), 1e-11 * scale).unwrap();
                assert!(
                    (d.w_mm - k.w_mm).abs() < 1e-9 * scale,
                    "v={v} x={x}: {} vs {}",
                    d.w_mm,
                    k.w_mm
                );
                assert!(k.terms < d.terms, "{} ≥ {}", k.terms, d.terms);
            }
        }
        // At speed the dynamic deflection differs from the static one.
        let v = 0.5 * b.critical_speed_mm_s();
        let k = series(&b, load(1200.0, 1200.0, v, f, 0.0), 1e-11 * scale).unwrap();
        assert!((k.w_mm + f * b.point(1200.0, 1200.0)).abs() > 1e-3 * scale);
    }

    #[test]
    fn critical_speed_is_an_error() {
        let b = stringer();
        let e = series(
            &b,
            load(1.0, 1.0, 1.01 * b.critical_speed_mm_s(), 1.0, 0.0),
            1e-12,
        )
        .unwrap_err();
        assert!(matches!(e, SeriesError::Critical { .. }));
        assert!(e.to_string().contains("critical speed"));
    }
}

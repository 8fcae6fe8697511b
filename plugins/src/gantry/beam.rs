//! Simply supported Euler–Bernoulli beam, span l: static deflections under a
//! uniform load, a point load and a concentrated moment (docs/models.md §2.1).
//! Deflections are returned as downward magnitudes (mm) for positive loads;
//! callers put the sign on (a sag is a negative Z error).

use std::f64::consts::PI;

/// One beam of the structure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Beam {
    pub span_mm: f64,
    /// Flexural rigidity E·I, N·mm².
    pub ei_n_mm2: f64,
    /// Mass per length ρ·A, t/mm (N·s²/mm per mm), for the natural
    /// frequencies of the moving-load solution (docs/models.md §2.3).
    pub mass_t_per_mm: f64,
}

/// Σ_{n≥1} sin(nθ)/n³ in closed form (Clausen-type Fourier series of a
/// Bernoulli polynomial): θ(π − θ)(2π − θ)/12 on [0, 2π], odd, 2π-periodic.
pub fn sin_series3(theta: f64) -> f64 {
    let two_pi = 2.0 * PI;
    let mut t = theta.rem_euclid(two_pi);
    if !t.is_finite() {
        t = 0.0;
    }
    t * (PI - t) * (two_pi - t) / 12.0
}

impl Beam {
    /// Natural circular frequency of mode n: ω_n = (n²π²/l²)·sqrt(EI/(ρA)).
    pub fn omega(&self, n: usize) -> f64 {
        let b = n as f64 * PI / self.span_mm;
        b * b * (self.ei_n_mm2 / self.mass_t_per_mm).sqrt()
    }
    /// Speed at which the first mode resonates (α₁ = 1): ω₁·l/π.
    pub fn critical_speed_mm_s(&self) -> f64 {
        self.omega(1) * self.span_mm / PI
    }
    /// Deflection at x under a uniform load w (N/mm):
    /// w·x(l³ − 2lx² + x³)/(24EI); 5wl⁴/(384EI) at mid-span.
    pub fn uniform(&self, w_n_mm: f64, x: f64) -> f64 {
        let l = self.span_mm;
        w_n_mm * x * (l.powi(3) - 2.0 * l * x * x + x.powi(3)) / (24.0 * self.ei_n_mm2)
    }
    /// Influence line: deflection at x under a unit point load at a
    /// (b = l − a): b·x(l² − b² − x²)/(6EIl) for x ≤ a, mirrored beyond.
    pub fn point(&self, x: f64, a: f64) -> f64 {
        let l = self.span_mm;
        let (x, a) = if x <= a { (x, a) } else { (l - x, l - a) };
        let b = l - a;
        b * x * (l * l - b * b - x * x) / (6.0 * self.ei_n_mm2 * l)
    }
    /// Deflection at x under a unit moment at a, the static (v → 0) limit of
    /// docs/models.md §2.3's moment series: (2l²/(EIπ³)) Σ n⁻³ sin(nπx/l)
    /// cos(nπa/l) = (l²/(EIπ³))·[S₃(π(x+a)/l) + S₃(π(x−a)/l)].
    pub fn moment(&self, x: f64, a: f64) -> f64 {
        let l = self.span_mm;
        let s = sin_series3(PI * (x + a) / l) + sin_series3(PI * (x - a) / l);
        l * l / (self.ei_n_mm2 * PI.powi(3)) * s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn beam() -> Beam {
        Beam {
            span_mm: 2400.0,
            ei_n_mm2: 2e5 * 5.22e7,
            mass_t_per_mm: 1.3e-4,
        }
    }

    #[test]
    fn textbook_values() {
        let b = beam();
        let (l, ei) = (b.span_mm, b.ei_n_mm2);
        assert!((b.uniform(1.0, l / 2.0) - 5.0 * l.powi(4) / (384.0 * ei)).abs() < 1e-15);
        assert!((b.point(l / 2.0, l / 2.0) - l.powi(3) / (48.0 * ei)).abs() < 1e-15);
        // Maxwell reciprocity.
        assert!((b.point(300.0, 1700.0) - b.point(1700.0, 300.0)).abs() < 1e-18);
        assert_eq!(b.point(0.0, 800.0), 0.0);
    }

    #[test]
    fn moment_is_the_load_position_derivative_of_the_point_influence() {
        // (2l³/(EIπ⁴))Σ n⁻⁴ sin sin differentiated in a gives the moment
        // series: ∂δ(x, a)/∂a = moment(x, a).
        let b = beam();
        for (x, a) in [(500.0, 1200.0), (1800.0, 700.0), (1000.0, 1000.5)] {
            let h = 1e-3;
            let d = (b.point(x, a + h) - b.point(x, a - h)) / (2.0 * h);
            assert!(
                (d - b.moment(x, a)).abs() < 1e-7 * d.abs().max(1e-12),
                "{x} {a}: {d} vs {}",
                b.moment(x, a)
            );
        }
    }

    #[test]
    fn sin_series3_matches_its_series() {
        for th in [0.3, 1.0, 2.5, 4.0, 6.0, -1.2] {
            let s: f64 = (1..200000)
                .map(|n| (n as f64 * th).sin() / (n as f64).powi(3))
                .sum();
            assert!((s - sin_series3(th)).abs() < 1e-9, "{th}");
        }
    }
}

//! Each body's geometric straightness: piecewise second-order Lagrange
//! interpolation through its measured points, P(g) = Σ_{i=1..3} W_i(g)·z_i
//! over each 3-point section (docs/models.md §2.1).

/// A body's measured straightness, ready to interpolate.
#[derive(Debug, Clone, PartialEq)]
pub struct Straightness {
    pos_mm: Vec<f64>,
    z_mm: Vec<f64>,
}

impl Straightness {
    /// At least 3 points with strictly increasing positions; an error says
    /// which entry breaks that.
    pub fn new(pos_mm: Vec<f64>, z_mm: Vec<f64>) -> Result<Self, String> {
        if pos_mm.len() != z_mm.len() {
            return Err(format!(
                "{} positions but {} straightness values (one value per position)",
                pos_mm.len(),
                z_mm.len()
            ));
        }
        if pos_mm.len() < 3 {
            return Err(format!(
                "{} measured points; piecewise quadratic interpolation needs at least 3",
                pos_mm.len()
            ));
        }
        if let Some(i) = pos_mm.iter().chain(&z_mm).position(|v| !v.is_finite()) {
            return Err(format!("entry {} is not a finite number", i % pos_mm.len()));
        }
        if let Some(i) = pos_mm.windows(2).position(|w| w[1] <= w[0]) {
            return Err(format!(
                "positions must increase strictly: entry {} ({}) follows {}",
                i + 1,
                pos_mm[i + 1],
                pos_mm[i]
            ));
        }
        Ok(Straightness { pos_mm, z_mm })
    }

    /// First index of the 3-point section that holds `g`: sections start at
    /// 0, 2, 4, …; with an even number of points the last section reuses the
    /// last three. Outside the measured range the end section extrapolates.
    fn section(&self, g: f64) -> usize {
        let n = self.pos_mm.len();
        let last = n - 3;
        let mut s = 0;
        while s + 2 < n && g > self.pos_mm[s + 2] {
            s += 2;
        }
        s.min(last)
    }

    /// The interpolated deviation from straight at position `g` (mm).
    pub fn eval(&self, g: f64) -> f64 {
        let s = self.section(g);
        let (p, z) = (&self.pos_mm[s..s + 3], &self.z_mm[s..s + 3]);
        let w0 = (g - p[1]) * (g - p[2]) / ((p[0] - p[1]) * (p[0] - p[2]));
        let w1 = (g - p[0]) * (g - p[2]) / ((p[1] - p[0]) * (p[1] - p[2]));
        let w2 = (g - p[0]) * (g - p[1]) / ((p[2] - p[0]) * (p[2] - p[1]));
        w0 * z[0] + w1 * z[1] + w2 * z[2]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn passes_through_points_and_reproduces_quadratics() {
        let pos = vec![0.0, 300.0, 700.0, 1000.0, 1600.0];
        let q = |g: f64| 1e-8 * g * g - 2e-5 * g + 0.01;
        let s = Straightness::new(pos.clone(), pos.iter().map(|&g| q(g)).collect()).unwrap();
        for &g in &pos {
            assert!((s.eval(g) - q(g)).abs() < 1e-15);
        }
        for g in [10.0, 450.0, 999.0, 1234.5, 1600.0] {
            assert!((s.eval(g) - q(g)).abs() < 1e-12, "{g}");
        }
        // Even count: the last section reuses the last three points.
        let s4 = Straightness::new(vec![0.0, 1.0, 2.0, 3.0], vec![0.0, 1.0, 4.0, 9.0]).unwrap();
        assert!((s4.eval(2.5) - 6.25).abs() < 1e-12);
    }

    #[test]
    fn rejects_bad_points() {
        assert!(Straightness::new(vec![0.0, 1.0], vec![0.0, 0.0]).is_err());
        assert!(Straightness::new(vec![0.0, 2.0, 1.0], vec![0.0; 3])
            .unwrap_err()
            .contains("increase strictly"));
        assert!(Straightness::new(vec![0.0, 1.0, 2.0], vec![0.0; 2]).is_err());
    }
}

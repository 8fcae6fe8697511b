//! The safety envelope, checked before a setpoint frame is built: a frame
//! that fails any check is never sent (docs/design.md §11:
//! "Replay never sends a frame outside the envelope, whatever the input").

use crate::error::{Error, Result};

/// Limits, all in mm (per axis, per cycle where it says so).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Envelope {
    /// Largest |compensation| added to the commanded path.
    pub max_comp_mm: f64,
    /// Largest setpoint step between two cycles (a speed limit: step / cycle).
    pub max_step_mm: f64,
    /// Largest change of that step between two cycles (an acceleration limit).
    pub max_step_change_mm: f64,
    /// Largest |sent target − actual| from the TPDO feedback.
    pub max_following_mm: f64,
}

/// Why a setpoint was refused.
#[derive(Debug, Clone, PartialEq)]
pub struct Violation(pub String);

const AXES: [&str; 3] = ["x", "y", "z"];

impl Envelope {
    /// Every limit must be a finite number > 0 (a zero limit would stop
    /// every replay; a negative one means a typo).
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [
            ("--max-comp-mm", self.max_comp_mm),
            ("--max-step-mm", self.max_step_mm),
            ("--max-step-change-mm", self.max_step_change_mm),
            ("--max-following-mm", self.max_following_mm),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::EnvelopeLimit {
                    limit: name,
                    value: v,
                });
            }
        }
        Ok(())
    }

    /// Check one cycle's setpoint = `cmd` + `comp` (mm) against the previous
    /// sent target `prev` and the previous step `prev_step` (drive counts);
    /// the target in counts when it is inside the envelope.
    pub fn check(
        &self,
        cmd: &[f64; 3],
        comp: &[f64; 3],
        prev: &[i32; 3],
        prev_step: &[i32; 3],
        counts_per_mm: f64,
    ) -> std::result::Result<[i32; 3], Violation> {
        let mut target = [0i32; 3];
        for a in 0..3 {
            let ax = AXES[a];
            if !cmd[a].is_finite() {
                return Err(Violation(format!(
                    "axis {ax}: commanded position is {}",
                    cmd[a]
                )));
            }
            if !comp[a].is_finite() {
                return Err(Violation(format!("axis {ax}: compensation is {}", comp[a])));
            }
            if comp[a].abs() > self.max_comp_mm {
                return Err(Violation(format!(
                    "axis {ax}: |compensation| {:.4} mm > max {} mm",
                    comp[a].abs(),
                    self.max_comp_mm
                )));
            }
            let counts = ((cmd[a] + comp[a]) * counts_per_mm).round();
            if !(counts.is_finite() && counts.abs() <= i32::MAX as f64) {
                return Err(Violation(format!(
                    "axis {ax}: setpoint {} mm does not fit the drive's 32-bit position",
                    cmd[a] + comp[a]
                )));
            }
            target[a] = counts as i32;
            let step = (target[a] as i64 - prev[a] as i64) as f64 / counts_per_mm;
            if step.abs() > self.max_step_mm {
                return Err(Violation(format!(
                    "axis {ax}: step {:.4} mm in one cycle > max {} mm",
                    step.abs(),
                    self.max_step_mm
                )));
            }
            let change = step - prev_step[a] as f64 / counts_per_mm;
            if change.abs() > self.max_step_change_mm {
                return Err(Violation(format!(
                    "axis {ax}: step changes by {:.4} mm between cycles > max {} mm",
                    change.abs(),
                    self.max_step_change_mm
                )));
            }
        }
        Ok(target)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env() -> Envelope {
        Envelope {
            max_comp_mm: 0.1,
            max_step_mm: 0.5,
            max_step_change_mm: 0.05,
            max_following_mm: 0.2,
        }
    }

    #[test]
    fn inside_passes_and_quantises() {
        let t = env()
            .check(
                &[1.0, 2.0, 3.0],
                &[0.01, 0.0, -0.01],
                &[10_000, 20_000, 30_000],
                &[0; 3],
                10_000.0,
            )
            .unwrap();
        assert_eq!(t, [10_100, 20_000, 29_900]);
    }

    #[test]
    fn every_limit_and_nan_is_refused() {
        let e = env();
        let p = [0, 0, 0];
        // (cmd, comp, previous step, expected message part)
        type Case<'a> = ([f64; 3], [f64; 3], [i32; 3], &'a str);
        let cases: [Case; 6] = [
            (
                [f64::NAN, 0.0, 0.0],
                [0.0; 3],
                [0; 3],
                "commanded position is NaN",
            ),
            (
                [0.0; 3],
                [0.0, f64::INFINITY, 0.0],
                [0; 3],
                "compensation is inf",
            ),
            ([0.0; 3], [0.0, 0.0, 0.2], [0; 3], "|compensation|"),
            ([0.6, 0.0, 0.0], [0.0; 3], [6_000, 0, 0], "step 0.6000"),
            ([0.0, 0.06, 0.0], [0.0; 3], [0; 3], "step changes"),
            ([1e9, 0.0, 0.0], [0.0; 3], [0; 3], "32-bit"),
        ];
        for (cmd, comp, prev_step, what) in cases {
            let err = e.check(&cmd, &comp, &p, &prev_step, 10_000.0).unwrap_err();
            assert!(err.0.contains(what), "{what}: {}", err.0);
        }
    }

    #[test]
    fn limits_must_be_positive() {
        for bad in [0.0, -1.0, f64::NAN] {
            let mut e = env();
            e.max_step_mm = bad;
            assert!(e
                .validate()
                .unwrap_err()
                .to_string()
                .contains("--max-step-mm"));
        }
        assert!(env().validate().is_ok());
    }
}

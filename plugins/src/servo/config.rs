//! The servo machine config (`[servo]`, `[logging]` of
//! configs/machines/<machine>.toml) and the stage sections
//! (`[servo.follow]`, `[servo.observe]`), each checked before use: unknown
//! keys and bad values are errors that name the key (docs/servo.md).

use serde::{Deserialize, Serialize};
use sparkout_pipeline::config_check::{Check, Section};
use sparkout_pipeline::contracts::MachineConfig;
use sparkout_pipeline::{InputError, Result};

use super::model::AxisServo;

/// The axes a servo trace may have (docs/formats.md §4 motion.parquet).
pub const AXES: [&str; 3] = ["x", "y", "z"];

/// `[servo]` and `[servo.<axis>]`.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct ServoToml {
    kv_1_s: Option<f64>,
    ff: Option<f64>,
    x: Option<AxisToml>,
    y: Option<AxisToml>,
    z: Option<AxisToml>,
}

#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct AxisToml {
    kv_1_s: Option<f64>,
    ff: Option<f64>,
}

/// `[logging]`: how finely the controller logs (the measurement's own
/// resolution, which no model can beat: docs/servo.md "Noise floor").
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct LoggingToml {
    position_resolution_mm: Option<f64>,
    position_significant_digits: Option<i64>,
    velocity_resolution_mm_s: Option<f64>,
    velocity_significant_digits: Option<i64>,
}

/// The quantisation step of a logged value: a fixed resolution, a number of
/// significant digits (a logger printing `%.3g` has step 1 at 198.0 and 0.1
/// at 72.4), or both (the larger step wins).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Resolution {
    pub fixed: f64,
    pub significant_digits: Option<u32>,
}

impl Resolution {
    /// Step of the logged value `v`.
    pub fn step(&self, v: f64) -> f64 {
        let sig = match self.significant_digits {
            Some(n) if v != 0.0 && v.is_finite() => {
                10f64.powi(v.abs().log10().floor() as i32 - (n as i32 - 1))
            }
            _ => 0.0,
        };
        self.fixed.max(sig)
    }
    /// Standard uncertainty of a difference of two logged values (each
    /// rounded independently: uniform error of width step, σ = step/√12).
    pub fn u_diff(&self, a: f64, b: f64) -> f64 {
        (self.step(a).powi(2) + self.step(b).powi(2)).sqrt() / 12f64.sqrt()
    }
}

/// A servo machine as the stages use it.
#[derive(Debug, Clone, PartialEq)]
pub struct ServoMachine {
    /// Position loop of x, y, z.
    pub axes: [AxisServo; 3],
    pub position: Resolution,
    pub velocity: Resolution,
}

impl Section for ServoToml {}

impl Section for LoggingToml {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("position_resolution_mm", Check::NonNegative),
        ("velocity_resolution_mm_s", Check::NonNegative),
        ("position_significant_digits", Check::WholeIn(1, 17)),
        ("velocity_significant_digits", Check::WholeIn(1, 17)),
    ];
}

/// The servo machine config's sections, read once when a run's machine is
/// loaded ([`ServoMachine::from_config`] takes them from there).
pub const MACHINE_SECTIONS: &[(&str, sparkout_pipeline::config_check::SectionCheck)] = &[
    (
        "servo",
        sparkout_pipeline::config_check::SectionCheck::of::<ServoToml>(),
    ),
    (
        "logging",
        sparkout_pipeline::config_check::SectionCheck::of::<LoggingToml>(),
    ),
];

/// Default position-loop gain when the machine config gives none: 30 1/s
/// (a lag of 33 ms), typical of a machine tool's position loop.
pub const DEFAULT_KV_1_S: f64 = 30.0;

impl ServoMachine {
    pub fn from_config(m: &MachineConfig) -> Result<ServoMachine, InputError> {
        let bad = |key: &str, msg: String| InputError::new(&m.source, msg).column(key);
        let s: ServoToml = m.typed_section("servo")?;
        let log: LoggingToml = m.typed_section("logging")?;
        let mut axes = [AxisServo {
            kv_1_s: DEFAULT_KV_1_S,
            ff: 0.0,
        }; 3];
        for (i, (name, a)) in AXES.iter().zip([&s.x, &s.y, &s.z]).enumerate() {
            let a = a.clone().unwrap_or_default();
            let kv = a.kv_1_s.or(s.kv_1_s).unwrap_or(DEFAULT_KV_1_S);
            let ff = a.ff.or(s.ff).unwrap_or(0.0);
            if !(kv.is_finite() && kv > 0.0) {
                return Err(bad(
                    &format!("servo.{name}.kv_1_s"),
                    format!("position-loop gain must be > 0 (1/s), found {kv}"),
                ));
            }
            if !(ff.is_finite() && (0.0..=1.0).contains(&ff)) {
                return Err(bad(
                    &format!("servo.{name}.ff"),
                    format!("velocity feed-forward must be in [0, 1], found {ff}"),
                ));
            }
            axes[i] = AxisServo { kv_1_s: kv, ff };
        }
        let res = |fixed: Option<f64>, digits: Option<i64>, what: &str| {
            let fixed = fixed.unwrap_or(0.0);
            if !(fixed.is_finite() && fixed >= 0.0) {
                return Err(bad(
                    &format!("logging.{what}_resolution"),
                    format!("must be ≥ 0, found {fixed}"),
                ));
            }
            let digits = match digits {
                None => None,
                Some(d) if (1..=17).contains(&d) => Some(d as u32),
                Some(d) => {
                    return Err(bad(
                        &format!("logging.{what}_significant_digits"),
                        format!("must be in 1..=17, found {d}"),
                    ))
                }
            };
            Ok(Resolution {
                fixed,
                significant_digits: digits,
            })
        };
        Ok(ServoMachine {
            axes,
            position: res(
                log.position_resolution_mm,
                log.position_significant_digits,
                "position",
            )?,
            velocity: res(
                log.velocity_resolution_mm_s,
                log.velocity_significant_digits,
                "velocity",
            )?,
        })
    }
}

/// `[servo.observe]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ObserveConfig {
    /// Commanded axis speed below which the axis counts as at rest: its
    /// direction is held from the last motion (mm/s).
    pub standstill_mm_s: f64,
}

impl Default for ObserveConfig {
    fn default() -> Self {
        ObserveConfig {
            standstill_mm_s: 1e-3,
        }
    }
}

impl Section for ObserveConfig {
    const CHECKS: &'static [(&'static str, Check)] = &[("standstill_mm_s", Check::NonNegative)];
}

#[cfg(test)]
mod tests {
    use super::*;
    use sparkout_pipeline::config_check::read_section;

    fn machine(text: &str) -> Result<ServoMachine, InputError> {
        ServoMachine::from_config(&MachineConfig {
            id: "m".into(),
            source: "m.toml".into(),
            table: text.parse().unwrap(),
            text: text.into(),
            ..Default::default()
        })
    }

    #[test]
    fn builtin_machines_parse() {
        for (_, text) in super::super::builtin_machines() {
            machine(text).unwrap();
        }
        let m = machine("[servo]\nkv_1_s = 40\n[servo.z]\nkv_1_s = 20\nff = 0.5\n").unwrap();
        assert_eq!(m.axes[0].kv_1_s, 40.0);
        assert_eq!((m.axes[2].kv_1_s, m.axes[2].ff), (20.0, 0.5));
    }

    #[test]
    fn bad_values_name_the_key() {
        let e = machine("[servo]\nkv_1_s = -1\n").unwrap_err();
        assert_eq!(e.column.as_deref(), Some("servo.x.kv_1_s"));
        let e = machine("[servo.y]\nff = 2\n").unwrap_err();
        assert_eq!(e.column.as_deref(), Some("servo.y.ff"));
        let e = machine("[servo]\nkv = 3\n").unwrap_err();
        assert!(e.message.contains("kv"), "{e}");
        // Unknown key, wrong type, out of range: each names `section.key`.
        for (text, column) in [
            ("[servo]\nkv = 3\n", "servo.kv"),
            ("[servo]\nff = \"half\"\n", "servo.ff"),
            (
                "[logging]\nposition_significant_digits = 0\n",
                "logging.position_significant_digits",
            ),
        ] {
            let e = machine(text).unwrap_err();
            assert_eq!(e.column.as_deref(), Some(column), "{text}: {e}");
            assert!(e.to_string().contains("m.toml"), "{e}");
        }
        let t = |s: &str| s.parse::<toml::Table>().unwrap();
        let observe = read_section::<ObserveConfig>;
        assert!(observe(&t("standstill_mm_s = 0.01")).is_ok());
        assert!(observe(&t("standstill = 0.01")).is_err());
        assert!(observe(&t("standstill_mm_s = -1")).is_err());
    }

    #[test]
    fn significant_digit_steps() {
        let r = Resolution {
            fixed: 0.0,
            significant_digits: Some(3),
        };
        assert!((r.step(198.0) - 1.0).abs() < 1e-12);
        assert!((r.step(72.4) - 0.1).abs() < 1e-12);
        assert!((r.step(-0.025) - 0.0001).abs() < 1e-15);
        assert_eq!(r.step(0.0), 0.0);
        let f = Resolution {
            fixed: 0.025,
            significant_digits: Some(3),
        };
        assert_eq!(f.step(0.3), 0.025);
        assert!((f.u_diff(198.0, 72.4) - (1.01f64).sqrt() / 12f64.sqrt()).abs() < 1e-12);
    }
}

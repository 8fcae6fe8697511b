//! The mill's machine config (configs/machines/xfyz-mill.toml) and its stage
//! sections (`[mill.kinematics]`, `[mill.observe]`), each checked before use:
//! unknown keys and bad values are errors that say what to do.

use crate::{bail, err};
use serde::{Deserialize, Serialize};
use sparkout_pipeline::config_check::{Check, Section};
use sparkout_pipeline::contracts::MachineConfig;
use sparkout_pipeline::{ConfigError, InputError, Result};

use super::chain::{function_index, function_name, Layout, N_FUNCTIONS, V3};

/// `[axes]`: travels (min, max) in mm.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct AxesToml {
    x_mm: [f64; 2],
    y_mm: [f64; 2],
    z_mm: [f64; 2],
}

/// `[tool]`: the reflector offsets in the spindle (Z carriage) frame.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct ToolToml {
    offsets_mm: Vec<[f64; 3]>,
}

/// `[identification]` defaults (a `[mill.kinematics]` key overrides them).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct IdentToml {
    degree: Option<i64>,
    holdout_fraction: Option<f64>,
    seed: Option<i64>,
    fixed: Option<Vec<String>>,
}

/// `[tracker]`: the instrument.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct TrackerToml {
    sigma_mm: Option<f64>,
}

/// A mill as the stages use it.
#[derive(Debug, Clone, PartialEq)]
pub struct MillMachine {
    pub travels: [(f64, f64); 3],
    pub tools: Vec<V3>,
    pub degree: usize,
    pub holdout_fraction: f64,
    pub seed: u64,
    /// Error functions held at zero.
    pub fixed: Vec<usize>,
    /// Tracker noise prior (mm, per coordinate): the generator's default.
    pub tracker_sigma_mm: f64,
}

impl Section for AxesToml {}
impl Section for ToolToml {}
impl Section for IdentToml {
    const CHECKS: &'static [(&'static str, Check)] = &[("seed", Check::WholeIn(0, i64::MAX))];
}
impl Section for TrackerToml {
    const CHECKS: &'static [(&'static str, Check)] = &[("sigma_mm", Check::Positive)];
}

/// The mill machine config's sections, read once when a run's machine is
/// loaded ([`MillMachine::from_config`] takes them from there).
pub const MACHINE_SECTIONS: &[(&str, sparkout_pipeline::config_check::SectionCheck)] = &[
    (
        "axes",
        sparkout_pipeline::config_check::SectionCheck::of::<AxesToml>(),
    ),
    (
        "tool",
        sparkout_pipeline::config_check::SectionCheck::of::<ToolToml>(),
    ),
    (
        "identification",
        sparkout_pipeline::config_check::SectionCheck::of::<IdentToml>(),
    ),
    (
        "tracker",
        sparkout_pipeline::config_check::SectionCheck::of::<TrackerToml>(),
    ),
];

impl Default for AxesToml {
    fn default() -> Self {
        AxesToml {
            x_mm: [0.0; 2],
            y_mm: [0.0; 2],
            z_mm: [0.0; 2],
        }
    }
}

impl Default for ToolToml {
    fn default() -> Self {
        ToolToml {
            offsets_mm: vec![[0.0; 3]],
        }
    }
}

/// Function names → indices, with an error naming the bad one.
pub fn parse_fixed(names: &[String]) -> Result<Vec<usize>> {
    names
        .iter()
        .map(|n| {
            function_index(n).ok_or_else(|| {
                let known: Vec<String> = (0..N_FUNCTIONS).map(function_name).collect();
                err!(
                    "`fixed`: unknown error function `{n}` (known: {})",
                    known.join(", ")
                )
            })
        })
        .collect()
}

fn check_degree(d: i64) -> Result<usize> {
    if !(2..=8).contains(&d) {
        bail!("`degree` must be an integer in 2..=8 (2 is the least that leaves straightness a shape), found {d}");
    }
    Ok(d as usize)
}

fn check_holdout(f: f64) -> Result<f64> {
    if !(f.is_finite() && (0.0..0.9).contains(&f)) {
        bail!("`holdout_fraction` must be in [0, 0.9) (0 = no held-out validation), found {f}");
    }
    Ok(f)
}

impl MillMachine {
    pub fn from_config(m: &MachineConfig) -> Result<MillMachine, InputError> {
        let bad = |key: &str, msg: String| InputError::new(&m.source, msg).column(key);
        if !m.table.contains_key("axes") {
            return Err(bad(
                "axes",
                "the mill machine config needs a [axes] table".into(),
            ));
        }
        // Keys without a default: required when their section is given.
        for (section, key) in [
            ("axes", "x_mm"),
            ("axes", "y_mm"),
            ("axes", "z_mm"),
            ("tool", "offsets_mm"),
        ] {
            if m.table
                .get(section)
                .and_then(|t| t.as_table())
                .is_some_and(|t| !t.contains_key(key))
            {
                return Err(bad(
                    &format!("{section}.{key}"),
                    format!("required key [{section}].{key} is missing"),
                ));
            }
        }
        let axes: AxesToml = m.typed_section("axes")?;
        let tool: ToolToml = m.typed_section("tool")?;
        let ident: IdentToml = m.typed_section("identification")?;
        let tracker: TrackerToml = m.typed_section("tracker")?;
        let mut travels = [(0.0, 0.0); 3];
        for (a, (name, t)) in [
            ("x_mm", axes.x_mm),
            ("y_mm", axes.y_mm),
            ("z_mm", axes.z_mm),
        ]
        .into_iter()
        .enumerate()
        {
            if !(t[0].is_finite() && t[1].is_finite() && t[1] > t[0]) {
                return Err(bad(
                    &format!("axes.{name}"),
                    format!("travel must be [min, max] with max > min, found {t:?}"),
                ));
            }
            travels[a] = (t[0], t[1]);
        }
        if tool.offsets_mm.is_empty() || tool.offsets_mm.iter().flatten().any(|v| !v.is_finite()) {
            return Err(bad(
                "tool.offsets_mm",
                "needs at least one finite [x, y, z] offset".into(),
            ));
        }
        let degree = check_degree(ident.degree.unwrap_or(3))
            .map_err(|e| bad("identification.degree", e.to_string()))?;
        let holdout_fraction = check_holdout(ident.holdout_fraction.unwrap_or(0.2))
            .map_err(|e| bad("identification.holdout_fraction", e.to_string()))?;
        let seed = ident.seed.unwrap_or(0);
        if seed < 0 {
            return Err(bad("identification.seed", "must be ≥ 0".into()));
        }
        let fixed = parse_fixed(&ident.fixed.unwrap_or_default())
            .map_err(|e| bad("identification.fixed", e.to_string()))?;
        let tracker_sigma_mm = tracker.sigma_mm.unwrap_or(0.002);
        if !(tracker_sigma_mm.is_finite() && tracker_sigma_mm > 0.0) {
            return Err(bad("tracker.sigma_mm", "must be > 0".into()));
        }
        Ok(MillMachine {
            travels,
            tools: tool.offsets_mm.iter().map(|t| V3::from(*t)).collect(),
            degree,
            holdout_fraction,
            seed: seed as u64,
            fixed,
            tracker_sigma_mm,
        })
    }

    pub fn layout(&self) -> Layout {
        Layout::new(self.degree, self.travels, &self.fixed)
    }
}

/// `[mill.kinematics]`: identification settings that override the
/// machine's `[identification]` (None: the machine's), and the stage's own.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct KinematicsConfig {
    pub degree: Option<i64>,
    pub holdout_fraction: Option<f64>,
    pub seed: Option<u64>,
    pub fixed: Option<Vec<String>>,
    /// Smallest reciprocal condition number of the column-scaled Jacobian
    /// accepted as full rank.
    pub rcond: f64,
    /// Levenberg–Marquardt budget (residual evaluations).
    pub max_evaluations: usize,
    /// Volumetric map: points per axis.
    pub map_grid: usize,
    /// Spacing of the compensation table, mm.
    pub table_step_mm: f64,
}

impl Default for KinematicsConfig {
    fn default() -> Self {
        KinematicsConfig {
            degree: None,
            holdout_fraction: None,
            seed: None,
            fixed: None,
            rcond: 1e-8,
            max_evaluations: 200,
            map_grid: 7,
            table_step_mm: 25.0,
        }
    }
}

impl Section for KinematicsConfig {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("seed", Check::WholeIn(0, i64::MAX)),
        ("max_evaluations", Check::WholeIn(10, 100_000)),
        ("map_grid", Check::WholeIn(2, 50)),
        ("table_step_mm", Check::Positive),
    ];
    fn validate(&self) -> Result<()> {
        if !(self.rcond > 0.0 && self.rcond < 1e-2) {
            return Err(ConfigError::bad_value("rcond", "in (0, 0.01)", self.rcond).into());
        }
        // The same checks as the machine's [identification] (messages that
        // say why the range is what it is).
        self.degree.map(check_degree).transpose()?;
        self.holdout_fraction.map(check_holdout).transpose()?;
        self.fixed.as_deref().map(parse_fixed).transpose()?;
        Ok(())
    }
}

impl KinematicsConfig {
    /// The machine with this section's overrides applied.
    pub fn apply(&self, m: &MillMachine) -> Result<MillMachine> {
        let mut m = m.clone();
        if let Some(d) = self.degree {
            m.degree = check_degree(d)?;
        }
        if let Some(f) = self.holdout_fraction {
            m.holdout_fraction = f;
        }
        if let Some(s) = self.seed {
            m.seed = s;
        }
        if let Some(f) = &self.fixed {
            m.fixed = parse_fixed(f)?;
        }
        Ok(m)
    }
}

/// `[mill.observe]`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ObserveConfig {
    /// thermal.parquet sensor whose reading is `temp_c`; `None` = the mean
    /// of all sensors.
    pub temp_sensor: Option<String>,
}

impl Section for ObserveConfig {
    fn validate(&self) -> Result<()> {
        if self
            .temp_sensor
            .as_deref()
            .is_some_and(|s| s.trim().is_empty())
        {
            bail!("key `temp_sensor` must name a sensor of thermal.parquet (or be left out for the mean of all sensors)");
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sparkout_pipeline::config_check::read_section;

    fn machine(text: &str) -> Result<MillMachine, InputError> {
        MillMachine::from_config(&MachineConfig {
            id: "m".into(),
            source: "m.toml".into(),
            table: text.parse().unwrap(),
            text: text.into(),
            ..Default::default()
        })
    }

    #[test]
    fn builtin_machine_parses() {
        let m = machine(super::super::XFYZ_MILL_TOML).unwrap();
        assert_eq!(m.tools.len(), 3);
        assert_eq!(m.degree, 3);
        assert!(m.travels[0].1 > m.travels[0].0);
    }

    #[test]
    fn bad_machine_values_name_the_key() {
        let e = machine("[axes]\nx_mm = [0, 600]\ny_mm = [0, 400]\nz_mm = [300, 0]\n").unwrap_err();
        assert_eq!(e.column.as_deref(), Some("axes.z_mm"));
        let e =
            machine("[axes]\nx_mm = [0, 600]\ny_mm = [0, 400]\nz_mm = [0, 300]\nw_mm = [0, 1]\n")
                .unwrap_err();
        assert!(e.message.contains("w_mm"), "{e}");
        let e = machine(
            "[axes]\nx_mm = [0, 600]\ny_mm = [0, 400]\nz_mm = [0, 300]\n[identification]\nfixed = [\"ex_q\"]\n",
        )
        .unwrap_err();
        assert!(e.message.contains("ex_q"), "{e}");
        // Unknown key, wrong type, out of range, a required key left out:
        // each names `section.key`.
        let axes = "[axes]\nx_mm = [0, 600]\ny_mm = [0, 400]\nz_mm = [0, 300]\n";
        for (extra, column) in [
            ("[tracker]\nsigma = 0.002\n", "tracker.sigma"),
            ("[tracker]\nsigma_mm = \"2 um\"\n", "tracker.sigma_mm"),
            ("[tracker]\nsigma_mm = 0\n", "tracker.sigma_mm"),
            ("[identification]\nseed = -1\n", "identification.seed"),
            ("[tool]\n", "tool.offsets_mm"),
        ] {
            let e = machine(&format!("{axes}{extra}")).unwrap_err();
            assert_eq!(e.column.as_deref(), Some(column), "{extra}: {e}");
            assert!(e.to_string().contains("m.toml"), "{e}");
        }
    }

    #[test]
    fn stage_sections_reject_unknown_keys_and_bad_values() {
        let t = |s: &str| s.parse::<toml::Table>().unwrap();
        assert!(read_section::<KinematicsConfig>(&t("degree = 4\nmap_grid = 5")).is_ok());
        let e = read_section::<KinematicsConfig>(&t("degre = 4")).unwrap_err();
        assert!(e.to_string().contains("degre"), "{e}");
        assert!(read_section::<KinematicsConfig>(&t("holdout_fraction = 0.95")).is_err());
        assert!(read_section::<KinematicsConfig>(&t("degree = 1")).is_err());
        assert!(read_section::<KinematicsConfig>(&t("fixed = [\"ez_z\", \"nope\"]")).is_err());
        assert!(read_section::<KinematicsConfig>(&t("rcond = 0.5")).is_err());
        assert!(read_section::<KinematicsConfig>(&t("seed = -1")).is_err());
        let observe = read_section::<ObserveConfig>;
        assert!(observe(&t("temp_sensor = \"spindle\"")).is_ok());
        assert!(observe(&t("temp_sensor = \" \"")).is_err());
        assert!(observe(&t("sensor = 1")).is_err());
    }
}

//! `[guideway.<stage>]` config sections, one serde struct each (defaults
//! here only, each key's range as data, read by the pipeline's shared
//! `config_check::read_section`), and the settings each stage resolves from
//! them with defaults from the machine config where the source (docs/models.md §3) gives one.

use serde::{Deserialize, Serialize};
use sparkout_pipeline::config_check::{read_section, Check, Section, SectionCheck};
use sparkout_pipeline::{Result, Run};

use super::ar_fpe::Criterion;
use super::input::InputOptions;
use super::three_probe::{Method, Reference};

/// `[guideway.separate]` (docs/models.md §3.1).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SeparateSection {
    pub method: Method,
    pub reference: Reference,
    pub interpolate: bool,
    pub stuck_samples: usize,
    /// None: the machine's `[probes] sigma_mm`.
    pub probe_sigma_mm: Option<f64>,
}

impl Default for SeparateSection {
    fn default() -> Self {
        SeparateSection {
            method: Method::Lsq,
            reference: Reference::Line,
            interpolate: false,
            stuck_samples: 8,
            probe_sigma_mm: None,
        }
    }
}

impl Section for SeparateSection {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("method", Check::OneOf(&["lsq", "recursion"])),
        ("reference", Check::OneOf(&["line", "ends"])),
        ("probe_sigma_mm", Check::Positive),
        ("stuck_samples", Check::WholeIn(2, 1_000_000)),
    ];
}

impl SeparateSection {
    /// How the readings are loaded.
    pub fn input(&self) -> InputOptions {
        InputOptions {
            interpolate: self.interpolate,
            stuck_samples: self.stuck_samples,
        }
    }
}

/// `[guideway.predictor]` (docs/models.md §3.2–3.3).
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PredictorConfig {
    /// Difference order (source: 2).
    pub d: usize,
    pub p_max: usize,
    /// AR order criterion (docs/models.md §3.2: FPE; BIC and HQ are consistent alternatives).
    pub criterion: Criterion,
    /// RLS P(0) = p0·I with δz in µm (source: 100).
    pub p0: f64,
    pub forgetting: f64,
    /// Forecast steps past the last sample.
    pub horizon: usize,
    /// One-step errors of the first `warmup` predictions are left out of
    /// the prediction-error variance (RLS still converging).
    pub warmup: usize,
    /// Kalman measurement σ. None: the machine's `[table]
    /// repeatability_mm`, else [`DEFAULT_REPEATABILITY_MM`].
    pub repeatability_mm: Option<f64>,
}

/// Kalman measurement σ when neither the section nor the machine gives one.
pub const DEFAULT_REPEATABILITY_MM: f64 = 5e-4;

impl Default for PredictorConfig {
    fn default() -> Self {
        PredictorConfig {
            d: 2,
            p_max: 10,
            criterion: Criterion::Fpe,
            p0: 100.0,
            forgetting: 1.0,
            horizon: 20,
            warmup: 50,
            repeatability_mm: None,
        }
    }
}

impl Section for PredictorConfig {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("d", Check::WholeIn(0, 3)),
        ("p_max", Check::WholeIn(1, 50)),
        ("p0", Check::Positive),
        ("forgetting", Check::Fraction),
        ("horizon", Check::WholeIn(1, 100_000)),
        ("repeatability_mm", Check::Positive),
        ("warmup", Check::WholeIn(0, 1_000_000)),
        ("criterion", Check::OneOf(Criterion::NAMES)),
    ];
}

impl PredictorConfig {
    /// A section (or the run-less flags) read and checked, the machine's
    /// repeatability filling in when the section gives none.
    pub fn from_table(config: &toml::Table, run: Option<&Run>) -> Result<PredictorConfig> {
        Ok(read_section::<PredictorConfig>(config)?.resolve(run))
    }
    /// The checked section with the machine's repeatability filling in
    /// when the section gives none.
    pub fn resolve(mut self, run: Option<&Run>) -> PredictorConfig {
        self.repeatability_mm = Some(self.repeatability_mm.unwrap_or_else(|| {
            run.map(|r| {
                machine_f64(
                    machine_section::<MachineTable>(r).repeatability_mm,
                    DEFAULT_REPEATABILITY_MM,
                )
            })
            .unwrap_or(DEFAULT_REPEATABILITY_MM)
        }));
        self
    }
    /// The Kalman measurement σ (mm).
    pub fn repeatability_mm(&self) -> f64 {
        self.repeatability_mm.unwrap_or(DEFAULT_REPEATABILITY_MM)
    }
}

/// Fit a term when the run has what it needs (`auto`), or never (`off`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AutoOff {
    Auto,
    Off,
}

/// `[guideway.compensation]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CompensationConfig {
    /// g from the infeed count (and temp_c).
    pub thermal: AutoOff,
    /// The table reversal error when both directions occur.
    pub reversal: AutoOff,
    /// None: the machine's `[headstock] backlash_mm`.
    pub backlash_mm: Option<f64>,
    /// None: run `[process] infeed_mm`, then the machine's `[process]`.
    pub infeed_mm: Option<f64>,
}

impl Default for CompensationConfig {
    fn default() -> Self {
        CompensationConfig {
            thermal: AutoOff::Auto,
            reversal: AutoOff::Auto,
            backlash_mm: None,
            infeed_mm: None,
        }
    }
}

impl Section for CompensationConfig {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("thermal", Check::OneOf(&["auto", "off"])),
        ("reversal", Check::OneOf(&["auto", "off"])),
        ("backlash_mm", Check::NonNegative),
        ("infeed_mm", Check::NonNegative),
    ];
}

/// `[guideway.observe]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ObserveConfig {
    /// motion_error's sim: `straightness` from the other passes, or `model`
    /// (+ the fitted thermal and reversal terms).
    pub sim: String,
}

impl Default for ObserveConfig {
    fn default() -> Self {
        ObserveConfig {
            sim: "straightness".to_string(),
        }
    }
}

impl Section for ObserveConfig {
    const CHECKS: &'static [(&'static str, Check)] =
        &[("sim", Check::OneOf(&["straightness", "model"]))];
}

pub use sparkout_pipeline::config_check::flags_to_table;

/// A number ≥ 0 from the machine config, with a default.
pub fn machine_f64(value: Option<f64>, default: f64) -> f64 {
    value
        .filter(|v| v.is_finite() && *v >= 0.0)
        .unwrap_or(default)
}

/// A section of the run's machine config as its serde struct, as read and
/// checked when the machine was loaded (its defaults when the machine was
/// not loaded with it).
pub fn machine_section<T: Section + Clone>(run: &Run) -> T {
    run.machine.section::<T>().cloned().unwrap_or_default()
}

/// `[probes]` of a guideway machine config
/// (configs/machines/guideway-grinder.toml).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MachineProbes {
    /// Distance between neighbouring probes (mm).
    pub spacing_mm: Option<f64>,
    /// Table travel between two readings (mm).
    pub sample_step_mm: Option<f64>,
    /// Measuring range of a probe (mm).
    pub range_mm: Option<f64>,
    /// Resolution of the probes' converter (bits).
    pub adc_bits: Option<u32>,
    /// Probe noise σ (mm).
    pub sigma_mm: Option<f64>,
}

impl Section for MachineProbes {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("spacing_mm", Check::Positive),
        ("sample_step_mm", Check::Positive),
        ("range_mm", Check::Positive),
        ("adc_bits", Check::WholeIn(1, 64)),
        ("sigma_mm", Check::NonNegative),
    ];
}

/// `[table]` of a guideway machine config.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MachineTable {
    pub speed_mm_s: Option<f64>,
    pub travel_mm: Option<f64>,
    /// Positioning repeatability (mm): the predictor's default noise.
    pub repeatability_mm: Option<f64>,
}

impl Section for MachineTable {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("speed_mm_s", Check::Positive),
        ("travel_mm", Check::Positive),
        ("repeatability_mm", Check::NonNegative),
    ];
}

/// `[headstock]` of a guideway machine config.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MachineHeadstock {
    pub backlash_mm: Option<f64>,
}

impl Section for MachineHeadstock {
    const CHECKS: &'static [(&'static str, Check)] = &[("backlash_mm", Check::NonNegative)];
}

/// `[process]` of a guideway machine config: the machine's defaults for
/// what a run's `[process]` may give.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MachineProcess {
    pub infeed_mm: Option<f64>,
}

impl Section for MachineProcess {
    const CHECKS: &'static [(&'static str, Check)] = &[("infeed_mm", Check::NonNegative)];
}

/// The guideway machine config's sections the stages read.
pub const MACHINE_SECTIONS: &[(&str, SectionCheck)] = &[
    ("probes", SectionCheck::of::<MachineProbes>()),
    ("table", SectionCheck::of::<MachineTable>()),
    ("headstock", SectionCheck::of::<MachineHeadstock>()),
    ("process", SectionCheck::of::<MachineProcess>()),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_are_checked() {
        let separate = read_section::<SeparateSection>;
        let t: toml::Table = "method = \"lsq\"\nstuck_samples = 5".parse().unwrap();
        assert!(separate(&t).is_ok());
        let t: toml::Table = "method = \"fft\"".parse().unwrap();
        assert!(separate(&t).is_err());
        let t: toml::Table = "p_max = 2.5".parse().unwrap();
        let e = PredictorConfig::from_table(&t, None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("whole number"), "{e}");
        let t: toml::Table = "p_max = 12.0".parse().unwrap();
        assert_eq!(PredictorConfig::from_table(&t, None).unwrap().p_max, 12);
        let t: toml::Table = "order = 3".parse().unwrap();
        assert!(PredictorConfig::from_table(&t, None).is_err());
        let c = PredictorConfig::from_table(&toml::Table::new(), None).unwrap();
        assert_eq!((c.d, c.p_max, c.p0), (2, 10, 100.0));
        assert_eq!(c.criterion, Criterion::Fpe);
        let t: toml::Table = "criterion = \"bic\"".parse().unwrap();
        assert_eq!(
            PredictorConfig::from_table(&t, None).unwrap().criterion,
            Criterion::Bic
        );
        let t: toml::Table = "criterion = \"aic\"".parse().unwrap();
        assert!(PredictorConfig::from_table(&t, None).is_err());
    }
}

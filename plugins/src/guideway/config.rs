//! `[guideway.<stage>]` config sections: known keys and their checks (the
//! key checker is the pipeline's shared one, `config_check::check_config`,
//! which holds no robot logic), integer keys, and the settings each stage
//! reads, with defaults from the machine config where MODELS.md gives one.

use sparkout_pipeline::{Result, Run, StageContext};

pub use sparkout_pipeline::config_check::{check_config, Check};

use super::input::InputOptions;
use super::three_probe::{Method, Reference};

/// An integer key within [lo, hi]: the pipeline's one whole-number check.
pub use sparkout_pipeline::config_check::check_whole as check_int;

pub fn int(config: &toml::Table, key: &str, default: usize) -> usize {
    match config.get(key) {
        Some(toml::Value::Integer(i)) => *i as usize,
        Some(toml::Value::Float(f)) => *f as usize,
        _ => default,
    }
}

pub const SEPARATE_KEYS: &[(&str, Check)] = &[
    ("method", Check::OneOf(&["lsq", "recursion"])),
    ("reference", Check::OneOf(&["line", "ends"])),
    ("interpolate", Check::Bool),
    ("probe_sigma_mm", Check::Positive),
    ("stuck_samples", Check::AtLeastOne),
];

/// `[guideway.separate]`.
#[derive(Debug, Clone, Copy)]
pub struct SeparateConfig {
    pub method: Method,
    pub reference: Reference,
    pub input: InputOptions,
    /// Reading noise when the solve has no redundancy (default: machine
    /// `[probes] sigma_mm`).
    pub probe_sigma_mm: f64,
}

impl SeparateConfig {
    pub fn validate(config: &toml::Table) -> Result<()> {
        check_config(config, SEPARATE_KEYS)?;
        check_int(config, "stuck_samples", 2, 1_000_000)
    }
    pub fn from_ctx(ctx: &StageContext) -> SeparateConfig {
        Self::from_table(ctx.config, machine_f64(ctx.run, "probes.sigma_mm", 1e-4))
    }
    /// From a checked section; `sigma_mm` is the default reading noise.
    pub fn from_table(config: &toml::Table, sigma_mm: f64) -> SeparateConfig {
        let s = |k: &str, d: &'static str| -> String {
            config
                .get(k)
                .and_then(|v| v.as_str())
                .unwrap_or(d)
                .to_string()
        };
        SeparateConfig {
            method: Method::parse(&s("method", "lsq")).unwrap_or(Method::Lsq),
            reference: Reference::parse(&s("reference", "line")).unwrap_or(Reference::Line),
            input: InputOptions {
                interpolate: config
                    .get("interpolate")
                    .and_then(|v| v.as_bool())
                    .unwrap_or(false),
                stuck_samples: int(config, "stuck_samples", 8),
            },
            probe_sigma_mm: sparkout_pipeline::cfg_f64(config, "probe_sigma_mm")
                .unwrap_or(sigma_mm),
        }
    }
}

pub const PREDICTOR_KEYS: &[(&str, Check)] = &[
    ("d", Check::NonNegative),
    ("p_max", Check::AtLeastOne),
    ("p0", Check::Positive),
    ("forgetting", Check::Fraction),
    ("horizon", Check::AtLeastOne),
    ("repeatability_mm", Check::Positive),
    ("warmup", Check::NonNegative),
];

/// `[guideway.predictor]` (MODELS.md §3.2–3.3).
#[derive(Debug, Clone, Copy)]
pub struct PredictorConfig {
    /// Difference order (source: 2).
    pub d: usize,
    pub p_max: usize,
    /// RLS P(0) = p0·I with δz in µm (source: 100).
    pub p0: f64,
    pub forgetting: f64,
    /// Forecast steps past the last sample.
    pub horizon: usize,
    /// Kalman measurement σ (default machine `[table] repeatability_mm`).
    pub repeatability_mm: f64,
    /// One-step errors of the first `warmup` predictions are left out of
    /// the prediction-error variance (RLS still converging).
    pub warmup: usize,
}

impl PredictorConfig {
    pub fn validate(config: &toml::Table) -> Result<()> {
        check_config(config, PREDICTOR_KEYS)?;
        check_int(config, "d", 0, 3)?;
        check_int(config, "p_max", 1, 50)?;
        check_int(config, "horizon", 1, 100_000)?;
        check_int(config, "warmup", 0, 1_000_000)
    }
    pub fn from_table(config: &toml::Table, run: Option<&Run>) -> PredictorConfig {
        let f = |k: &str, d: f64| sparkout_pipeline::cfg_f64(config, k).unwrap_or(d);
        PredictorConfig {
            d: int(config, "d", 2),
            p_max: int(config, "p_max", 10),
            p0: f("p0", 100.0),
            forgetting: f("forgetting", 1.0),
            horizon: int(config, "horizon", 20),
            repeatability_mm: f(
                "repeatability_mm",
                run.map(|r| machine_f64(r, "table.repeatability_mm", 5e-4))
                    .unwrap_or(5e-4),
            ),
            warmup: int(config, "warmup", 50),
        }
    }
}

pub const COMPENSATION_KEYS: &[(&str, Check)] = &[
    ("thermal", Check::OneOf(&["auto", "off"])),
    ("reversal", Check::OneOf(&["auto", "off"])),
    ("backlash_mm", Check::NonNegative),
    ("infeed_mm", Check::NonNegative),
];

pub const OBSERVE_KEYS: &[(&str, Check)] = &[("sim", Check::OneOf(&["straightness", "model"]))];

/// Run-less stage flags (`--p-max 20`) as a config table (`p_max = 20`):
/// dashes read as underscores, values as TOML (numbers, booleans), else
/// text; the flags in `inputs` are the stage's own and are left out.
pub fn flags_to_table(args: &sparkout_pipeline::StageArgs, inputs: &[&str]) -> toml::Table {
    let mut t = toml::Table::new();
    for (k, v) in args {
        if inputs.contains(&k.as_str()) {
            continue;
        }
        let value = format!("v = {v}")
            .parse::<toml::Table>()
            .ok()
            .and_then(|mut x| x.remove("v"))
            .unwrap_or_else(|| toml::Value::String(v.clone()));
        t.insert(k.replace('-', "_"), value);
    }
    t
}

/// A positive number from the machine config, with a default.
pub fn machine_f64(run: &Run, dotted: &str, default: f64) -> f64 {
    run.machine
        .f64(dotted)
        .filter(|v| v.is_finite() && *v >= 0.0)
        .unwrap_or(default)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_are_checked() {
        let t: toml::Table = "method = \"lsq\"\nstuck_samples = 5".parse().unwrap();
        assert!(SeparateConfig::validate(&t).is_ok());
        let t: toml::Table = "method = \"fft\"".parse().unwrap();
        assert!(SeparateConfig::validate(&t).is_err());
        let t: toml::Table = "p_max = 2.5".parse().unwrap();
        let e = PredictorConfig::validate(&t).unwrap_err().to_string();
        assert!(e.contains("whole number"), "{e}");
        let t: toml::Table = "order = 3".parse().unwrap();
        assert!(PredictorConfig::validate(&t).is_err());
        let c = PredictorConfig::from_table(&toml::Table::new(), None);
        assert_eq!((c.d, c.p_max, c.p0), (2, 10, 100.0));
    }
}

//! `--effect NAME[:COVARIATE]=KEY=VALUE,...` as used by `sparkout generate`.

use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

/// An effect to inject into a generated fleet (or a fitted effect written
/// back out): catalogue name, optional covariate, named parameters.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EffectSpec {
    pub name: String,
    pub covariate: Option<String>,
    pub params: BTreeMap<String, f64>,
}

impl EffectSpec {
    /// `name:covariate` as diagnosis.json's `selected` spells it.
    pub fn key(&self) -> String {
        match &self.covariate {
            Some(c) => format!("{}:{}", self.name, c),
            None => self.name.clone(),
        }
    }
    pub fn param(&self, key: &str) -> Option<f64> {
        self.params.get(key).copied()
    }
    /// Parameter with a default when the user did not give it.
    pub fn param_or(&self, key: &str, default: f64) -> f64 {
        self.param(key).unwrap_or(default)
    }
    /// Every parameter is one of `known` and finite; the error names the
    /// effect, the parameter and the known ones (generators' `--effect`).
    pub fn check_params(&self, known: &[&str]) -> Result<(), String> {
        for (k, v) in &self.params {
            if !known.contains(&k.as_str()) {
                return Err(format!(
                    "effect `{}`: unknown parameter `{k}` (known: {})",
                    self.key(),
                    if known.is_empty() {
                        "none".to_string()
                    } else {
                        known.join(", ")
                    }
                ));
            }
            if !v.is_finite() {
                return Err(format!(
                    "effect `{}`: parameter `{k}` must be finite",
                    self.key()
                ));
            }
        }
        Ok(())
    }
}

/// Largest |value| an injected effect parameter may have: far above any
/// length (mm), gain or time constant of a machine, far below where the
/// injected values would overflow into infinity.
pub const MAX_EFFECT_PARAM: f64 = 1e6;

/// One parameter of `--effect`: finite, of a plausible size, and positive
/// where it is a scale that divides (τ, λ, radius, width): a zero or
/// negative one would write NaN or inf into every generated value.
fn check_param(spec: &str, key: &str, v: f64) -> Result<(), String> {
    if !v.is_finite() {
        return Err(format!(
            "--effect `{spec}`: `{key}` = {v} is not a finite number"
        ));
    }
    if v.abs() > MAX_EFFECT_PARAM {
        return Err(format!(
            "--effect `{spec}`: `{key}` = {v} is out of range (|value| ≤ {MAX_EFFECT_PARAM:e})"
        ));
    }
    let divisor = ["tau", "lambda", "radius", "width", "sigma", "period"]
        .iter()
        .any(|p| key.starts_with(p));
    if divisor && v <= 0.0 {
        return Err(format!(
            "--effect `{spec}`: `{key}` = {v} must be > 0 (it is a time constant or length the effect divides by)"
        ));
    }
    Ok(())
}

impl FromStr for EffectSpec {
    type Err = String;
    /// Parses `drift:t_s=amplitude_mm=0.02,tau_s=600`, `wear=k=1e-6`,
    /// `trigger_latency` (no parameters: plugin defaults).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let s = s.trim();
        if s.is_empty() {
            return Err("empty --effect; expected NAME[:COVARIATE]=KEY=VALUE,...".into());
        }
        let (head, rest) = match s.find('=') {
            Some(i) => (&s[..i], Some(&s[i + 1..])),
            None => (s, None),
        };
        let (name, covariate) = match head.split_once(':') {
            Some((n, c)) => (n.trim(), Some(c.trim().to_string())),
            None => (head.trim(), None),
        };
        if name.is_empty() {
            return Err(format!("--effect `{s}`: missing effect name"));
        }
        let mut params = BTreeMap::new();
        if let Some(rest) = rest {
            for kv in rest.split(',').filter(|p| !p.trim().is_empty()) {
                let (k, v) = kv
                    .split_once('=')
                    .ok_or_else(|| format!("--effect `{s}`: parameter `{kv}` is not KEY=VALUE"))?;
                let v: f64 = v.trim().parse().map_err(|_| {
                    format!(
                        "--effect `{s}`: value of `{}` is not a number: `{v}`",
                        k.trim()
                    )
                })?;
                check_param(s, k.trim(), v)?;
                params.insert(k.trim().to_string(), v);
            }
        }
        Ok(EffectSpec {
            name: name.to_string(),
            covariate,
            params,
        })
    }
}

impl fmt::Display for EffectSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.key())?;
        let mut first = true;
        for (k, v) in &self.params {
            write!(f, "{}{k}={v}", if first { "=" } else { "," })?;
            first = false;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_full_form() {
        let e: EffectSpec = "drift:t_s=amplitude_mm=0.02,tau_s=600".parse().unwrap();
        assert_eq!(e.name, "drift");
        assert_eq!(e.covariate.as_deref(), Some("t_s"));
        assert_eq!(e.param("amplitude_mm"), Some(0.02));
        assert_eq!(e.param("tau_s"), Some(600.0));
        assert_eq!(e.to_string(), "drift:t_s=amplitude_mm=0.02,tau_s=600");
    }

    #[test]
    fn parses_bare_and_rejects_garbage() {
        let e: EffectSpec = "trigger_latency".parse().unwrap();
        assert!(e.params.is_empty() && e.covariate.is_none());
        assert!("wear=k".parse::<EffectSpec>().is_err());
        assert!("wear=k=abc".parse::<EffectSpec>().is_err());
        assert!(":x=k=1".parse::<EffectSpec>().is_err());
    }

    #[test]
    fn rejects_non_finite_and_out_of_range_parameters() {
        for bad in [
            "drift:t_s=amplitude_mm=nan",
            "drift:t_s=amplitude_mm=inf",
            "drift:t_s=amplitude_mm=-inf",
            "drift:t_s=amplitude_mm=1e300",
            "drift:t_s=tau_s=0",
            "drift:t_s=tau_s=-5",
            "periodic:x_mm=lambda=0",
            "edge:path_end_mm=lambda_mm=-1",
        ] {
            let e = bad.parse::<EffectSpec>().unwrap_err();
            assert!(e.contains(bad), "{bad}: {e}");
        }
        assert!("drift:t_s=amplitude_mm=-0.02,tau_s=600"
            .parse::<EffectSpec>()
            .is_ok());
    }
}

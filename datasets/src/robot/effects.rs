//! The injectable effects: parsing, defaults and what each does to a run. (Part of the robot generator; see mod.rs.)

use super::*;

// Effects

/// Catalogue kinds that may be applied directly to `touch_normal`.
pub(super) const TOUCH_COVARIATES: &[&str] = &[
    "x_mm",
    "y_mm",
    "z_mm",
    "approach_mm_s",
    "approach_normal_mm_s",
    "t_s",
    "dir",
];
/// ... and to `cut_depth`.
pub(super) const CUT_COVARIATES: &[&str] = &["pass", "nominal_doc_mm", "removed_mm3", "feed_mm_s"];

/// The injectable effects, with parameters and defaults, for `--help`.
pub fn known_effects() -> Vec<(&'static str, &'static str)> {
    vec![
        (
            "trigger_latency",
            "controller registers each touch latency_s after the true contact (default latency_s=0.024, two 12 ms KRC interpolation cycles): probe touches overshoot by v·L along the approach; touch_normal gap = L·approach_normal_mm_s (v times the approach direction's component along the face's +normal axis; AE-derived touches are unaffected: the burst starts at the true contact)",
        ),
        (
            "wheel_wear",
            "dulling wheel: each pass's real cut shrinks by k_mm_per_mm3·removed_mm3 (default k_mm_per_mm3=1e-4, ≈ −22 µm by the last pass); cut_depth gap = −k·removed_mm3 (cuts clipped at 0)",
        ),
        (
            "thermal_drift",
            "the physical TCP drifts by amplitude_mm·(1 − e^(−t/tau_s)) along +z unseen by the encoders (defaults amplitude_mm=0.4, tau_s=300): xy-face touch_normal gap = −drift(t); measured heights shift by −drift(t) and each pass's infeed loses the drift increment",
        ),
        (
            "compliance",
            "depth-dependent compliance: each infeed pass's real cut is reduced by k·nominal_doc_mm² (k in 1/mm, default k=0.2: −18 µm at δ′=0.3, −2 µm at 0.1) — the model's α is calibrated on the first pass, which this shrinks too, so the cut_depth gap is k·compliance_response_mm2 (0 on pass 1, growing over the passes, persisting through spark-out; the robot plugin's depth_compliance), not −k·nominal_doc_mm²; with a covariate (compliance:nominal_doc_mm=k=…) the catalogue form k·nominal_doc_mm is added to cut_depth instead",
        ),
        (
            "backlash",
            "reversal error: touches shift by b_mm/2·dir in the face's normal-axis coordinate, dir = sign along that +axis of the last move before the approach (half the approaches follow an outward move, a reversal; default b_mm=0.12); touch_normal gap = b·dir/2 (AE-derived and probe touches alike)",
        ),
        (
            "<catalogue>:<covariate>",
            "any catalogue shape added directly to an observable's real value with the pipeline's parameter names (required, no defaults): touch_normal for covariates x_mm, y_mm, z_mm, approach_mm_s, approach_normal_mm_s, t_s, dir (offset, scale, drift, lag, backlash, bow, periodic, squareness:x_mm,y_mm); cut_depth for pass, nominal_doc_mm, removed_mm3, feed_mm_s (wear, compliance, lag, offset is touch-only)",
        ),
    ]
}

/// A catalogue shape added directly to an observable.
#[derive(Debug, Clone)]
pub(super) struct DirectEffect {
    pub(super) kind: Kind,
    pub(super) covariate: String,
    pub(super) covariate2: Option<String>,
    pub(super) params: BTreeMap<String, f64>,
}

impl DirectEffect {
    pub(super) fn value(&self, cov: &dyn Fn(&str) -> f64) -> f64 {
        let c = [cov(&self.covariate)];
        let c2 = self.covariate2.as_deref().map(|n| [cov(n)]);
        shape_value(self.kind, &self.params, &c, c2.as_ref().map(|a| &a[..]))[0]
    }
}

/// Resolved effect parameters of a fleet (zero = absent).
#[derive(Debug, Clone, Default)]
pub(super) struct Effects {
    pub(super) latency_s: f64,
    pub(super) wear_k_mm_per_mm3: f64,
    pub(super) drift: Option<(f64, f64)>,
    pub(super) compliance_k_per_mm: f64,
    pub(super) backlash_b_mm: f64,
    pub(super) touch: Vec<DirectEffect>,
    pub(super) cut: Vec<DirectEffect>,
}

impl Effects {
    pub(super) fn drift_mm(&self, t_s: f64) -> f64 {
        match self.drift {
            Some((a, tau)) => a * (1.0 - (-t_s / tau).exp()),
            None => 0.0,
        }
    }
}

pub(super) fn check_keys(spec: &EffectSpec, known: &[&str]) -> Result<()> {
    spec.check_params(known).map_err(crate::Error::msg)
}

pub(super) fn check_cov(spec: &EffectSpec, allowed: &[&str]) -> Result<()> {
    if let Some(c) = &spec.covariate {
        if !allowed.contains(&c.as_str()) {
            bail!(
                "effect `{}`: covariate `{c}` does not apply (allowed: {})",
                spec.key(),
                allowed.join(", ")
            );
        }
    }
    Ok(())
}

pub(super) fn positive(spec: &EffectSpec, key: &str, v: f64) -> Result<f64> {
    if !(v.is_finite() && v > 0.0) {
        bail!("effect `{}`: `{key}` must be > 0, got {v}", spec.key());
    }
    Ok(v)
}

pub(super) fn known_names() -> String {
    "trigger_latency, wheel_wear, thermal_drift, compliance, backlash, or a catalogue shape \
     with a covariate (offset, scale, drift, lag, backlash, bow, periodic, squareness, wear, compliance)"
        .to_string()
}

// Long on purpose (~150 lines): one match arm per effect, so the whole
// catalogue of what a spec may say is read in one place.
pub(super) fn resolve_effects(
    specs: &[EffectSpec],
    bow_range: &dyn Fn(&str) -> (f64, f64),
) -> Result<Effects> {
    let mut fx = Effects::default();
    for spec in specs {
        match (spec.name.as_str(), spec.covariate.as_deref()) {
            ("trigger_latency", _) => {
                check_cov(spec, &["approach_normal_mm_s", "approach_mm_s"])?;
                check_keys(spec, &["latency_s"])?;
                let l = spec.param_or("latency_s", DEF_LATENCY_S);
                if !(0.0..=0.5).contains(&l) {
                    bail!("effect `trigger_latency`: latency_s must be in [0, 0.5] s, got {l}");
                }
                fx.latency_s += l;
            }
            ("wheel_wear", _) => {
                check_cov(spec, &["removed_mm3"])?;
                check_keys(spec, &["k_mm_per_mm3"])?;
                fx.wear_k_mm_per_mm3 += spec.param_or("k_mm_per_mm3", DEF_WEAR_K_MM_PER_MM3);
            }
            ("thermal_drift", _) => {
                check_cov(spec, &["t_s"])?;
                check_keys(spec, &["amplitude_mm", "tau_s"])?;
                if fx.drift.is_some() {
                    bail!("effect `thermal_drift` given twice");
                }
                let a = spec.param_or("amplitude_mm", DEF_DRIFT_AMPLITUDE_MM);
                let tau = positive(spec, "tau_s", spec.param_or("tau_s", DEF_DRIFT_TAU_S))?;
                if a.abs() > 0.8 {
                    bail!("effect `thermal_drift`: |amplitude_mm| must be ≤ 0.8 (the approach standoff), got {a}");
                }
                fx.drift = Some((a, tau));
            }
            ("compliance", None) => {
                check_keys(spec, &["k"])?;
                fx.compliance_k_per_mm += spec.param_or("k", DEF_COMPLIANCE_K_PER_MM);
            }
            ("backlash", None) | ("backlash", Some("dir")) => {
                check_keys(spec, &["b_mm"])?;
                let b = spec.param_or("b_mm", DEF_BACKLASH_B_MM);
                if b.abs() > 1.0 {
                    bail!("effect `backlash`: |b_mm| must be ≤ 1.0, got {b}");
                }
                fx.backlash_b_mm += b;
            }
            (name, cov) => {
                let kind = Kind::from_name(name).ok_or_else(|| {
                    crate::err!("unknown effect `{name}` (known: {})", known_names())
                })?;
                let (keys, required): (&[&str], &[&str]) = match kind {
                    Kind::Offset => (&["offset_mm"], &["offset_mm"]),
                    Kind::Scale | Kind::Lag | Kind::Wear | Kind::Compliance | Kind::Squareness => {
                        (&["k"], &["k"])
                    }
                    Kind::Backlash => (&["b_mm"], &["b_mm"]),
                    Kind::Drift => (&["amplitude_mm", "tau_s"], &["amplitude_mm", "tau_s"]),
                    Kind::Bow => (&["amplitude_mm", "c0", "c1"], &["amplitude_mm"]),
                    Kind::Periodic => (
                        &["amplitude_mm", "lambda", "phase_rad"],
                        &["amplitude_mm", "lambda"],
                    ),
                    Kind::Inertia | Kind::Edge | Kind::Thermal => bail!(
                        "effect `{}`: not applicable to robot observables (no acceleration, path-end or temperature covariate); known: {}",
                        spec.key(),
                        known_names()
                    ),
                };
                check_keys(spec, keys)?;
                for r in required {
                    if spec.param(r).is_none() {
                        bail!(
                            "effect `{}`: catalogue shapes applied directly need their parameters ({}); missing `{r}`",
                            spec.key(),
                            required.join(", ")
                        );
                    }
                }
                for k in ["tau_s", "lambda"] {
                    if let Some(v) = spec.param(k) {
                        positive(spec, k, v)?;
                    }
                }
                let (c1, c2) = match (kind, cov) {
                    (Kind::Offset, None) => ("x_mm".to_string(), None),
                    (Kind::Offset, Some(c)) => bail!(
                        "effect `offset` takes no covariate, got `{c}`"
                    ),
                    (_, None) => bail!(
                        "effect `{name}`: a catalogue shape needs a covariate, e.g. `{name}:{}` (touch_normal: {}; cut_depth: {})",
                        default_cov(kind),
                        TOUCH_COVARIATES.join(", "),
                        CUT_COVARIATES.join(", ")
                    ),
                    (Kind::Squareness, Some(c)) => {
                        let (a, b) = c.split_once(',').ok_or_else(|| {
                            crate::err!("effect `squareness` needs two positions, e.g. squareness:x_mm,y_mm")
                        })?;
                        (a.trim().to_string(), Some(b.trim().to_string()))
                    }
                    (_, Some(c)) => (c.to_string(), None),
                };
                let on_touch = TOUCH_COVARIATES.contains(&c1.as_str());
                let on_cut = CUT_COVARIATES.contains(&c1.as_str());
                if !on_touch && !on_cut {
                    bail!(
                        "effect `{}`: covariate `{c1}` is not a robot observable covariate (touch_normal: {}; cut_depth: {})",
                        spec.key(),
                        TOUCH_COVARIATES.join(", "),
                        CUT_COVARIATES.join(", ")
                    );
                }
                if let Some(c2) = &c2 {
                    if !matches!(c1.as_str(), "x_mm" | "y_mm" | "z_mm")
                        || !matches!(c2.as_str(), "x_mm" | "y_mm" | "z_mm")
                    {
                        bail!(
                            "effect `{}`: squareness needs two of x_mm, y_mm, z_mm",
                            spec.key()
                        );
                    }
                }
                // The kind must apply to that covariate (docs/formats.md §7 table).
                if kind != Kind::Offset
                    && kind != Kind::Squareness
                    && !sparkout_pipeline::diagnose::effect::kinds_for(&c1).contains(&kind)
                {
                    bail!(
                        "effect `{}`: `{name}` does not apply to covariate `{c1}` (docs/formats.md, effect catalogue)",
                        spec.key()
                    );
                }
                let mut params = spec.params.clone();
                if kind == Kind::Bow {
                    let (lo, hi) = bow_range(&c1);
                    params.entry("c0".into()).or_insert(lo);
                    params.entry("c1".into()).or_insert(hi);
                }
                let d = DirectEffect {
                    kind,
                    covariate: c1,
                    covariate2: c2,
                    params,
                };
                if on_touch {
                    fx.touch.push(d);
                } else {
                    fx.cut.push(d);
                }
            }
        }
    }
    Ok(fx)
}

pub(super) fn default_cov(kind: Kind) -> &'static str {
    match kind {
        Kind::Drift => "t_s",
        Kind::Lag => "approach_normal_mm_s",
        Kind::Backlash => "dir",
        Kind::Wear => "removed_mm3",
        Kind::Compliance => "nominal_doc_mm",
        _ => "x_mm",
    }
}

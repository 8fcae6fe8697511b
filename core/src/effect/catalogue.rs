//! Forms as named effects, and which catalogue effects apply to which
//! covariates (by name: position, time, speed, acceleration, usage, load).

use super::*;

/// A form wrapped as an [`Effect`] under a name.
pub struct FormEffect {
    name: String,
    n_params: usize,
    form: Arc<dyn LinearForm>,
}

impl FormEffect {
    pub fn new(name: &str, n_params: usize, form: Arc<dyn LinearForm>) -> Self {
        FormEffect {
            name: name.to_string(),
            n_params,
            form,
        }
    }
}

impl Effect for FormEffect {
    fn name(&self) -> &str {
        &self.name
    }
    fn covariates(&self) -> Vec<String> {
        self.form.covariates()
    }
    fn n_params(&self) -> usize {
        self.n_params
    }
    fn fit(&self, x: &EffectData, gap: &[f64]) -> Result<Box<dyn FittedEffect>> {
        let frame: Frame = self
            .form
            .covariates()
            .iter()
            .map(|c| x.require(c).map(CovStats::from_values))
            .collect::<Result<_>>()?;
        let f = fit::fit_form(self.form.as_ref(), &frame, x, gap)?;
        Ok(Box::new(FittedForm {
            form: self.form.clone(),
            frame,
            theta: f.theta,
            coef: f.coef,
            offset: f.offset,
        }))
    }
    fn linear_form(&self) -> Option<Arc<dyn LinearForm>> {
        Some(self.form.clone())
    }
}

/// A fitted [`LinearForm`]: θ, coefficients, offset and the frame they refer to.
pub struct FittedForm {
    pub form: Arc<dyn LinearForm>,
    pub frame: Frame,
    pub theta: f64,
    pub coef: Vec<f64>,
    pub offset: f64,
}

impl FittedEffect for FittedForm {
    fn params(&self) -> BTreeMap<String, f64> {
        self.form
            .params(&self.frame, self.theta, &self.coef, self.offset)
            .0
    }
    fn offset_mm(&self) -> f64 {
        self.form
            .params(&self.frame, self.theta, &self.coef, self.offset)
            .1
    }
    /// `form(c; params)` in the contract convention: the feature-space
    /// prediction minus the contract offset (features are standardised, so
    /// part of the feature-space offset belongs to the shape).
    fn predict(&self, x: &EffectData) -> Vec<f64> {
        let mut out = vec![self.offset - self.offset_mm(); x.len()];
        with_columns(self.form.n_linear(), |feats| {
            if self
                .form
                .features(&self.frame, x, self.theta, feats)
                .is_ok()
            {
                for (f, b) in feats.iter().zip(&self.coef) {
                    for (o, v) in out.iter_mut().zip(f) {
                        *o += b * v;
                    }
                }
            }
        });
        out
    }
}

/// The catalogue effect `kind` on `covs`.
pub fn catalogue_effect(kind: Kind, covs: &[&str]) -> Box<dyn Effect> {
    Box::new(FormEffect::new(
        kind.name(),
        kind.n_params(),
        Arc::new(Shape {
            kind,
            covs: covs.iter().map(|s| s.to_string()).collect(),
        }),
    ))
}

/// Covariate kinds as docs/formats.md reads them from names.
pub(super) fn is_position(c: &str) -> bool {
    matches!(c, "x_mm" | "y_mm" | "z_mm" | "phi_rad")
}
pub(super) fn is_time(c: &str) -> bool {
    c == "t_s"
}
pub(super) fn is_speed(c: &str) -> bool {
    c.ends_with("_mm_s")
}
pub(super) fn is_accel(c: &str) -> bool {
    c.ends_with("_mm_s2")
}
pub(super) fn is_usage(c: &str) -> bool {
    c.ends_with("_mm3") || c == "pass" || c == "infeed_count"
}
pub(super) fn is_load(c: &str) -> bool {
    c.ends_with("_n") || c == "nominal_doc_mm"
}

/// Which catalogue kinds apply to a covariate (single-covariate kinds).
pub fn kinds_for(c: &str) -> Vec<Kind> {
    let mut k = Vec::new();
    if is_position(c) {
        k.extend([Kind::Scale, Kind::Bow, Kind::Periodic]);
    }
    if is_time(c) {
        k.extend([Kind::Drift, Kind::Periodic]);
    }
    if is_speed(c) {
        k.push(Kind::Lag);
    }
    if is_accel(c) {
        k.push(Kind::Inertia);
    }
    if c == "dir" {
        k.push(Kind::Backlash);
    }
    if is_usage(c) {
        k.push(Kind::Wear);
    }
    if is_load(c) {
        k.push(Kind::Compliance);
    }
    if c == "path_end_mm" {
        k.push(Kind::Edge);
    }
    if c == "temp_c" {
        k.push(Kind::Thermal);
    }
    k
}

/// Every applicable catalogue candidate for the given covariate names
/// (docs/formats.md §7 "Candidate effects"): `offset`, then each covariate's
/// kinds in the order given, then `squareness` on every pair of positions.
pub fn catalogue(covariates: &[String]) -> Vec<Box<dyn Effect>> {
    let mut out = vec![catalogue_effect(Kind::Offset, &[])];
    for c in covariates {
        for k in kinds_for(c) {
            out.push(catalogue_effect(k, &[c.as_str()]));
        }
    }
    let pos: Vec<&String> = covariates.iter().filter(|c| is_position(c)).collect();
    for i in 0..pos.len() {
        for j in i + 1..pos.len() {
            out.push(catalogue_effect(
                Kind::Squareness,
                &[pos[i].as_str(), pos[j].as_str()],
            ));
        }
    }
    out
}

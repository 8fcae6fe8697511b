//! Plugin composites: a catalogue effect under a physical name, and the
//! product of two effects (docs/design.md §7, point 2).

use super::*;

/// A catalogue (or any) effect under a physical name, e.g. the robot's
/// `trigger_latency` = `lag` on `approach_mm_s` (docs/design.md §7 point 2).
pub fn composite(name: &str, base: Box<dyn Effect>) -> Box<dyn Effect> {
    Box::new(Wrapped {
        name: Some(name.to_string()),
        only_on: Vec::new(),
        base,
    })
}

/// `base`, a candidate only for observables whose name starts with one of
/// `prefixes`: a plugin names one physical cause on observables of
/// different orders by a different form on each — the servo's lag is k·v
/// on a following error and k·a on a velocity error, its rate
/// (docs/models.md §7).
pub fn only_on(prefixes: &[&str], base: Box<dyn Effect>) -> Box<dyn Effect> {
    Box::new(Wrapped {
        name: None,
        only_on: prefixes.iter().map(|p| p.to_string()).collect(),
        base,
    })
}

/// `base` under another name ([`composite`]) or for some observables
/// only ([`only_on`]); everything else is `base`'s.
pub(super) struct Wrapped {
    name: Option<String>,
    /// Observable-name prefixes; empty: wherever `base` applies.
    only_on: Vec<String>,
    base: Box<dyn Effect>,
}

impl Effect for Wrapped {
    fn name(&self) -> &str {
        self.name.as_deref().unwrap_or_else(|| self.base.name())
    }
    fn covariates(&self) -> Vec<String> {
        self.base.covariates()
    }
    fn n_params(&self) -> usize {
        self.base.n_params()
    }
    fn fit(&self, x: &EffectData, gap: &[f64]) -> Result<Box<dyn FittedEffect>> {
        self.base.fit(x, gap)
    }
    fn linear_form(&self) -> Option<Arc<dyn LinearForm>> {
        self.base.linear_form()
    }
    /// A renamed effect replaces the catalogue candidate it names
    /// physically; a scoped one, whatever its base replaces.
    fn replaces(&self) -> Option<String> {
        match self.name {
            Some(_) => Some(self.base.key()),
            None => self.base.replaces(),
        }
    }
    fn applies_to(&self, observable: &str) -> bool {
        (self.only_on.is_empty()
            || self
                .only_on
                .iter()
                .any(|p| observable.starts_with(p.as_str())))
            && self.base.applies_to(observable)
    }
}

/// The product of two effects' shapes with one joint amplitude per pair of
/// features, e.g. the gantry's `thermal_bow` = bow(y_mm)·drift(t_s). Both
/// must be linear forms and at most one may have a nonlinear θ.
pub fn product(name: &str, a: Box<dyn Effect>, b: Box<dyn Effect>) -> Result<Box<dyn Effect>> {
    let (fa, fb) = match (a.linear_form(), b.linear_form()) {
        (Some(fa), Some(fb)) => (fa, fb),
        _ => bail!("product `{name}`: both factors must be linear forms"),
    };
    if fa.n_linear() == 0 || fb.n_linear() == 0 {
        bail!("product `{name}`: a factor has no shape (offset)");
    }
    let n_params = a.n_params() + b.n_params() - 1;
    Ok(Box::new(FormEffect::new(
        name,
        n_params,
        Arc::new(ProductForm { a: fa, b: fb }),
    )))
}

pub(super) struct ProductForm {
    a: Arc<dyn LinearForm>,
    b: Arc<dyn LinearForm>,
}

impl ProductForm {
    fn split(&self, frame: &Frame) -> (Frame, Frame) {
        let na = self.a.covariates().len();
        (frame[..na].to_vec(), frame[na..].to_vec())
    }
    /// (θ of a, θ of b): θ belongs to whichever factor has one.
    fn thetas(&self, fa: &Frame, theta: f64) -> (f64, f64) {
        if self.a.theta(fa).is_some() {
            (theta, f64::NAN)
        } else {
            (f64::NAN, theta)
        }
    }
}

impl LinearForm for ProductForm {
    fn covariates(&self) -> Vec<String> {
        let mut c = self.a.covariates();
        c.extend(self.b.covariates());
        c
    }
    fn factors(&self) -> Vec<(Kind, Vec<String>)> {
        let (a, b) = (self.a.factors(), self.b.factors());
        if a.len() == 1 && b.len() == 1 {
            a.into_iter().chain(b).collect()
        } else {
            Vec::new()
        }
    }
    fn n_linear(&self) -> usize {
        self.a.n_linear() * self.b.n_linear()
    }
    fn theta(&self, frame: &Frame) -> Option<ThetaRange> {
        let (fa, fb) = self.split(frame);
        self.a.theta(&fa).or_else(|| self.b.theta(&fb))
    }
    /// Cells of both factors' covariates: a product of two features each
    /// smooth within its factor's cell.
    fn pool_resolutions(&self, frame: &Frame) -> Option<Vec<f64>> {
        let (fa, fb) = self.split(frame);
        let mut r = self.a.pool_resolutions(&fa)?;
        r.extend(self.b.pool_resolutions(&fb)?);
        Some(r)
    }
    fn features(&self, frame: &Frame, x: &EffectData, theta: f64, out: &mut Columns) -> Result<()> {
        let (fa, fb) = self.split(frame);
        let (ta, tb) = self.thetas(&fa, theta);
        // The factors' columns are reused between calls (`with_columns`):
        // a product's θ scan runs over rows, one call per θ value tried.
        let (na, nb) = (self.a.n_linear(), self.b.n_linear());
        with_columns(na + nb, |cols| {
            let (va, vb) = cols.split_at_mut(na);
            self.a.features(&fa, x, ta, va)?;
            self.b.features(&fb, x, tb, vb)?;
            let mut j = 0;
            for ca in va.iter() {
                for cb in vb.iter() {
                    out[j].clear();
                    out[j].extend(ca.iter().zip(cb).map(|(p, q)| p * q));
                    j += 1;
                }
            }
            Ok(())
        })
    }
    fn params(&self, frame: &Frame, theta: f64, coef: &[f64], offset: f64) -> ParamsAndOffset {
        // Report the product's joint amplitudes and each factor's shape
        // parameters with a unit amplitude on the other factor.
        let (fa, fb) = self.split(frame);
        let (ta, tb) = self.thetas(&fa, theta);
        let ones_a = vec![1.0; self.a.n_linear()];
        let ones_b = vec![1.0; self.b.n_linear()];
        let (pa, _) = self.a.params(&fa, ta, &ones_a, 0.0);
        let (pb, _) = self.b.params(&fb, tb, &ones_b, 0.0);
        let mut p = BTreeMap::new();
        for (k, v) in pa {
            if v.is_finite() && !k.starts_with("amplitude") && k != "k" {
                p.insert(format!("a.{k}"), v);
            }
        }
        for (k, v) in pb {
            if v.is_finite() && !k.starts_with("amplitude") && k != "k" {
                p.insert(format!("b.{k}"), v);
            }
        }
        for (j, c) in coef.iter().enumerate() {
            p.insert(format!("coef{j}"), *c);
        }
        (p, offset)
    }
}

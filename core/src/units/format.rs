//! Engineer units on the way out: a canonical value (mm, s, mm/s and
//! their products) shown in the unit an engineer reads it in, with two to
//! three significant digits — a servo lag as `4.92 ms`, not
//! `4.915e-3 mm/(mm/s)`; a gap of 0.000435 mm as `0.435 µm`.
//!
//! Two parts: [`Dims`] is the dimension of a value (powers of mm and s and
//! of units sparkout does not convert, such as °C, N or rad) with its
//! canonical spelling for JSON; [`show`], [`show_pm`] and
//! [`show_interval`] pick the display unit by magnitude and format value,
//! standard error and interval in that one unit.

use std::collections::BTreeMap;
use std::fmt::Write;

use super::{Kind, Unit};

/// Powers of mm and s, and of units sparkout keeps as written (°C, N, rad,
/// …). `mm/(mm/s)` is `s`; `mm/mm³` stays a ratio of a length to a volume
/// ([`ParamUnit`] keeps the two sides for display).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Dims {
    pub mm: i32,
    pub s: i32,
    pub other: BTreeMap<String, i32>,
}

impl Dims {
    pub fn length() -> Dims {
        Dims {
            mm: 1,
            ..Dims::default()
        }
    }
    pub fn time() -> Dims {
        Dims {
            s: 1,
            ..Dims::default()
        }
    }
    /// The dimension of a unit as written (`mm/s`, `°C`, `N`, `mm³`, a
    /// column-name suffix such as `mm_s2`): the canonical unit of a
    /// convertible one, the text itself otherwise.
    pub fn of_unit(text: &str) -> Dims {
        let t = text.trim();
        match t {
            "" | "1" => return Dims::default(),
            "mm3" | "mm³" => {
                return Dims {
                    mm: 3,
                    ..Dims::default()
                }
            }
            "mm2" | "mm²" => {
                return Dims {
                    mm: 2,
                    ..Dims::default()
                }
            }
            "mm_s2" | "mm/s²" | "mm/s2" => {
                return Dims {
                    mm: 1,
                    s: -2,
                    ..Dims::default()
                }
            }
            "hz" | "Hz" => {
                return Dims {
                    s: -1,
                    ..Dims::default()
                }
            }
            "c" | "°C" | "degC" => return Dims::other("°C"),
            "n" | "N" => return Dims::other("N"),
            "rad" => return Dims::other("rad"),
            _ => {}
        }
        match Unit::parse(t) {
            Some(u) => match u.kind {
                Kind::Length => Dims::length(),
                Kind::Time => Dims::time(),
                Kind::Speed => Dims {
                    mm: 1,
                    s: -1,
                    ..Dims::default()
                },
            },
            None => Dims::other(t),
        }
    }
    fn other(name: &str) -> Dims {
        Dims {
            other: [(name.to_string(), 1)].into(),
            ..Dims::default()
        }
    }
    pub fn mul(&self, o: &Dims) -> Dims {
        let mut r = self.clone();
        r.mm += o.mm;
        r.s += o.s;
        for (k, v) in &o.other {
            *r.other.entry(k.clone()).or_insert(0) += v;
        }
        r.other.retain(|_, v| *v != 0);
        r
    }
    pub fn inv(&self) -> Dims {
        Dims {
            mm: -self.mm,
            s: -self.s,
            other: self.other.iter().map(|(k, v)| (k.clone(), -v)).collect(),
        }
    }
    pub fn div(&self, o: &Dims) -> Dims {
        self.mul(&o.inv())
    }
    pub fn is_one(&self) -> bool {
        self.mm == 0 && self.s == 0 && self.other.is_empty()
    }
    /// `mm`, `s²`, `mm/s`, `mm/°C`, `1/mm²`: positive powers, then `/` and
    /// the negative ones.
    pub fn canonical(&self) -> String {
        let mut num: Vec<String> = Vec::new();
        let mut den: Vec<String> = Vec::new();
        let mut put = |name: &str, p: i32| {
            if p > 0 {
                num.push(power(name, p));
            } else if p < 0 {
                den.push(power(name, -p));
            }
        };
        put("mm", self.mm);
        put("s", self.s);
        for (k, v) in &self.other {
            put(k, *v);
        }
        join(&num, &den)
    }
}

fn power(name: &str, p: i32) -> String {
    match p {
        1 => name.to_string(),
        2 => format!("{name}²"),
        3 => format!("{name}³"),
        _ => format!("{name}^{p}"),
    }
}

fn join(num: &[String], den: &[String]) -> String {
    let n = if num.is_empty() {
        "1".to_string()
    } else {
        num.join("·")
    };
    match den.len() {
        0 => n,
        1 => format!("{n}/{}", den[0]),
        _ => format!("{n}/({})", den.join("·")),
    }
}

/// The unit of a fitted parameter: what it measures over what it is per.
/// `k` of a lag on `feed_mm_s` is mm per mm/s, a time; `k` of wheel wear
/// on `removed_mm3` is mm per mm³, shown as a length per volume.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ParamUnit {
    pub num: Dims,
    pub den: Dims,
}

impl ParamUnit {
    pub fn of(d: Dims) -> ParamUnit {
        ParamUnit {
            num: d,
            den: Dims::default(),
        }
    }
    fn value(&self) -> Dims {
        self.num.div(&self.den)
    }
    /// The canonical unit as JSON names it (`s`, `mm`, `mm/mm³`, `mm/°C`,
    /// `s²`): a pure length, time, speed or their powers cancel to it;
    /// anything else keeps its two sides.
    pub fn canonical(&self) -> String {
        let v = self.value();
        if v.other.is_empty() && (v.mm == 0 || v.mm == 1) && self.den.mm <= 1 && !v.is_one() {
            return v.canonical();
        }
        if self.den.is_one() {
            return self.num.canonical();
        }
        // A ratio of like quantities other than a length slope: a number.
        if v.is_one() && !(self.num.mm == 1 && self.num.s == 0 && self.den.s == 0) {
            return "1".into();
        }
        let d = self.den.canonical();
        let d = if d.contains(['/', '·']) {
            format!("({d})")
        } else {
            d
        };
        format!("{}/{d}", self.num.canonical())
    }
    /// Display candidates, smallest unit first: (name, factor from the
    /// canonical value).
    fn candidates(&self) -> Vec<(String, f64)> {
        let v = self.value();
        let lengths = [("nm", 1e6), ("µm", 1e3), ("mm", 1.0)];
        if v.other.is_empty() && (v.mm == 0 || v.mm == 1) && self.den.mm <= 1 {
            match (v.mm, v.s) {
                (1, 0) => return cands(&lengths, ""),
                (0, 1) => return cands(&[("µs", 1e6), ("ms", 1e3), ("s", 1.0)], ""),
                (0, 2) => return cands(&[("µs²", 1e12), ("ms²", 1e6), ("s²", 1.0)], ""),
                // Speeds stay in mm/s, the unit every velocity figure of the
                // reports is in (a velocity error beside one in µm/s would
                // read as a thousand times off).
                (1, -1) => return vec![("mm/s".into(), 1.0)],
                (1, -2) => return vec![("mm/s²".into(), 1.0)],
                (0, -1) => return vec![("Hz".into(), 1.0)],
                // A length per length: a slope, read in µm/m.
                (0, 0) if self.num.mm == 1 && self.num.s == 0 && self.den.s == 0 => {
                    return vec![("µm/m".into(), 1e6), ("mm/m".into(), 1e3), ("".into(), 1.0)]
                }
                // Any other ratio (a speed per speed) is a plain number.
                (0, 0) => return vec![("".into(), 1.0)],
                _ => {}
            }
        }
        // A gap per something else: the gap's length by magnitude, the rest
        // as written (°C as K: a coefficient per degree is the same size).
        let den = self.den.canonical().replace("°C", "K");
        let den = if den.contains(['/', '·']) {
            format!("/({den})")
        } else if self.den.is_one() {
            String::new()
        } else {
            format!("/{den}")
        };
        let rest = Dims {
            mm: 0,
            ..self.num.clone()
        };
        if self.num.mm == 1 && rest.s == 0 && rest.other.is_empty() {
            return cands(&lengths, &den);
        }
        if self.num.mm == 1 && rest.s == -1 && rest.other.is_empty() {
            return cands(&[("mm/s", 1.0)], &den);
        }
        vec![(self.canonical(), 1.0)]
    }
}

fn cands(list: &[(&str, f64)], den: &str) -> Vec<(String, f64)> {
    list.iter()
        .map(|(n, f)| {
            let n = if den.is_empty() {
                n.to_string()
            } else if n.contains('/') {
                format!("({n}){den}")
            } else {
                format!("{n}{den}")
            };
            (n, *f)
        })
        .collect()
}

/// The largest display unit in which `size` (canonical) reads at least
/// 0.1 (0.435 µm, not 435 nm; 4.92 ms, not 0.00492 s); the smallest when
/// it is below that in all of them.
fn pick(c: &[(String, f64)], size: f64) -> (String, f64) {
    let a = size.abs();
    c.iter()
        .rev()
        .find(|(_, f)| a * f >= 0.09995)
        .or(c.first())
        .cloned()
        .unwrap_or_default()
}

/// Decimals that give `v` three significant digits (none for ≥ 100).
fn decimals_for(v: f64, sig: i32) -> i32 {
    let a = v.abs();
    if a == 0.0 || !a.is_finite() {
        return 0;
    }
    // Round first so 9.996 counts as 10.0 (two decimals would print 10.00).
    let e = a.log10().floor() as i32;
    let e = if (a / 10f64.powi(e) * 10f64.powi(sig - 1)).round() >= 10f64.powi(sig) {
        e + 1
    } else {
        e
    };
    (sig - 1 - e).max(0)
}

/// At most five decimals: a displayed number never has a longer tail
/// (the display unit is chosen so its digits come before that).
const MAX_DECIMALS: i32 = 5;

fn num(v: f64, d: i32) -> String {
    let d = d.clamp(0, MAX_DECIMALS) as usize;
    let s = format!("{v:.d$}");
    // "-0.00" is "0.00".
    if s.starts_with('-') && s[1..].chars().all(|c| c == '0' || c == '.') {
        s[1..].to_string()
    } else {
        s
    }
}

/// Whether the scaled value reads with three significant digits in at most
/// five decimals.
fn plain(v: f64) -> bool {
    let a = v.abs();
    a == 0.0 || a >= 1e-3
}

/// A number in plain notation, never scientific: `sig` significant digits
/// from 0.001 up, whole numbers above 1000 (`1234567`), five decimals
/// below 0.001 (`0.00019`), and `0` for what rounds to zero there — zero
/// at the resolution it is read at (the display unit is chosen so real
/// figures are well above that).
pub fn plain_number(v: f64, sig: i32) -> String {
    if !v.is_finite() {
        return "—".into();
    }
    if plain(v) {
        return num(v, decimals_for(v, sig));
    }
    let s = num(v, MAX_DECIMALS);
    if s.chars().all(|c| c == '0' || c == '.') {
        "0".into()
    } else {
        s
    }
}

fn with_unit(text: String, unit: &str) -> String {
    // "1" is the canonical unit of a pure number; it is not written.
    if unit.is_empty() || unit == "1" {
        text
    } else {
        format!("{text} {unit}")
    }
}

/// A value in engineer units: `4.92 ms`, `0.435 µm`, `58.9 mm`.
pub fn show(value: f64, unit: &ParamUnit) -> String {
    if !value.is_finite() {
        return "—".into();
    }
    let (name, f) = pick(&unit.candidates(), value);
    with_unit(plain_number(value * f, 3), &name)
}

/// A value in a unit as written (`mm`, `mm/s`, `rad`), shown by
/// magnitude: a gap in mm as nm, µm or mm.
pub fn show_in(value: f64, unit: &str) -> String {
    show(value, &ParamUnit::of(Dims::of_unit(unit)))
}

/// Values read side by side (a gap RMS, its noise floor, the RMS after)
/// in one unit: the smallest in which the largest of them stays below
/// 1000 — `106 µm (noise 0.951 µm) → 15.2 µm`, not `0.106 mm (noise
/// 0.951 µm)` — each with three significant digits.
pub fn show_group(values: &[f64], unit: &str) -> Vec<String> {
    show_group_in(values, &ParamUnit::of(Dims::of_unit(unit)))
}

/// [`show_group`] for a unit already resolved (a covariate's, a
/// parameter's).
pub fn show_group_in(values: &[f64], u: &ParamUnit) -> Vec<String> {
    let max = values
        .iter()
        .filter(|v| v.is_finite())
        .fold(0.0f64, |m, v| m.max(v.abs()));
    let (name, f) = group_unit(max, u);
    values
        .iter()
        .map(|&v| {
            if !v.is_finite() {
                return "—".into();
            }
            with_unit(plain_number(v * f, 3), &name)
        })
        .collect()
}

/// The display unit of [`show_group`] for values up to `max` (canonical):
/// the smallest in which `max` stays below 1000, and the factor from the
/// canonical value.
pub fn group_unit(max: f64, u: &ParamUnit) -> (String, f64) {
    let c = u.candidates();
    c.iter()
        .find(|(_, f)| max.abs() * f < 999.5)
        .or(c.last())
        .cloned()
        .unwrap_or_default()
}

/// The display unit for values of about `size` (canonical) and the factor
/// from the canonical value: one unit for a whole chart axis or a list of
/// values read together (a parameter over nights in nm/mm³).
pub fn display_unit(size: f64, unit: &ParamUnit) -> (String, f64) {
    pick(&unit.candidates(), size)
}

/// The unit of parameter `param` of an effect keyed `name:covariate` on an
/// observable whose gap is in `gap_unit`, when that unit is one sparkout
/// converts from (`mm`, `mm/s`); `None` for a gap in another unit (its
/// values are not in a canonical unit, so no display unit applies).
pub fn effect_param_unit(effect: &str, param: &str, gap_unit: &str) -> Option<ParamUnit> {
    matches!(gap_unit, "mm" | "mm/s")
        .then(|| param_unit(param, effect.split_once(':').map(|c| c.1), gap_unit))
}

/// A value with three significant digits in a unit as written, for values
/// that are not in a canonical unit (`2.50 deg`).
pub fn show_as_written(value: f64, unit: &str) -> String {
    with_unit(show(value, &ParamUnit::of(Dims::default())), unit)
}

/// A p-value: two significant digits, or `< 0.001` (a p-value that
/// underflows to 0 is as small as any other below that).
pub fn show_p(p: f64) -> String {
    if !p.is_finite() {
        "—".into()
    } else if p < 0.001 {
        "< 0.001".into()
    } else {
        num(p, decimals_for(p, 2))
    }
}

/// A length in mm shown in nm, µm or mm by magnitude.
pub fn show_length(mm: f64) -> String {
    show(mm, &ParamUnit::of(Dims::length()))
}

/// The decimals for a value and its standard error in one notation: three
/// significant digits of the value, and at least one of the error; a value
/// smaller than its error (zero within it) no finer than two digits of
/// the error.
fn pm_decimals(v: f64, se: f64) -> i32 {
    let d3 = decimals_for(v, 3);
    let d_se = if se > 0.0 && se.is_finite() {
        decimals_for(se, 1)
    } else {
        0
    };
    let d = d3.max(d_se);
    if se.is_finite() && v.abs() < se.abs() {
        return d.min(decimals_for(se, 2));
    }
    // Never more than six significant digits of the value.
    if v != 0.0 {
        d.min(decimals_for(v, 6))
    } else {
        d
    }
}

/// `4.92 ± 0.08 ms`: value and standard error in one unit and notation.
pub fn show_pm(value: f64, se: f64, unit: &ParamUnit) -> String {
    if !value.is_finite() {
        return "—".into();
    }
    if !se.is_finite() {
        return show(value, unit);
    }
    let size = if value.abs() >= se.abs() { value } else { se };
    let (name, f) = pick(&unit.candidates(), size);
    let (v, e) = (value * f, se * f);
    // At most five decimals (num), whatever the error's size.
    let d = pm_decimals(v, e);
    with_unit(format!("{} ± {}", num(v, d), num(e, d)), &name)
}

/// `194 s (95 % 140 … 249 s)`, or with a standard error
/// `4.92 ± 0.08 ms (95 % 4.76 … 5.08 ms)`: one unit, one notation.
pub fn show_interval(value: f64, se: Option<f64>, lo: f64, hi: f64, unit: &ParamUnit) -> String {
    if !value.is_finite() {
        return "—".into();
    }
    if !(lo.is_finite() && hi.is_finite()) {
        return match se {
            Some(se) => show_pm(value, se, unit),
            None => show(value, unit),
        };
    }
    let size = [value, lo, hi]
        .into_iter()
        .fold(0.0f64, |m, x| if x.abs() > m.abs() { x } else { m });
    let size = if value.abs() * 10.0 >= size.abs() {
        value
    } else {
        size
    };
    let (name, f) = pick(&unit.candidates(), size);
    let (v, l, h) = (value * f, lo * f, hi * f);
    let width = (h - l).abs() / 2.0;
    let d = if !(plain(v) || plain(width)) {
        // Zero at the resolution of the smallest unit, and so is its
        // interval.
        3
    } else {
        match se {
            Some(se) => pm_decimals(v, se * f),
            None => pm_decimals(v, width / 2.0),
        }
    };
    let mut s = num(v, d);
    if let Some(se) = se {
        let _ = write!(s, " ± {}", num(se * f, d));
    }
    let s = with_unit(s, &name);
    let tail = with_unit(format!("{} … {}", num(l, d), num(h, d)), &name);
    format!("{s} (95 % {tail})")
}

/// One parameter as every output writes it: `k = 4.92 ms`, or with its
/// standard error and 95 % interval `k = 4.92 ± 0.08 ms (95 % 4.76 … 5.07
/// ms)` — value, error and interval in one unit and notation.
pub fn show_param(
    name: &str,
    value: f64,
    interval: Option<(f64, f64, f64)>,
    unit: &ParamUnit,
) -> String {
    match interval {
        Some((se, lo, hi)) => format!("{name} = {}", show_interval(value, Some(se), lo, hi, unit)),
        None => format!("{name} = {}", show(value, unit)),
    }
}

/// The unit of a covariate from its name's suffix (`x_mm` → mm, `t_s` →
/// s, `temp_c` → °C), a number for a name without one.
pub fn covariate_unit(covariate: &str) -> ParamUnit {
    ParamUnit::of(Dims::of_unit(suffix_of(covariate)))
}

/// The unit of a reported diagnosis parameter, from its name, the effect's
/// covariate(s) (`x_mm,y_mm` for a 2-D form) and the observable's unit
/// (the gap's: `mm`, or `mm/s` for a velocity).
///
/// Names with a unit suffix are in that unit — except the amplitudes,
/// offsets and coefficients named `_mm` by the v1 contract, which are in
/// the gap's unit. A wavelength or decay length (`lambda`, `lambda_mm`)
/// and a frame bound (`c0`, `c1`) are in the covariate's unit; anything
/// else is the gap per the product of the covariates' units.
pub fn param_unit(param: &str, covariate: Option<&str>, gap_unit: &str) -> ParamUnit {
    // A product of two effects (`thermal_bow:y_mm,t_s` = bow(y)·drift(t)):
    // `a.*` are the first factor's shape parameters, on its covariate,
    // `b.*` the second's, and `coefN` the product's joint amplitudes, in
    // the gap's unit (each factor's shape has unit amplitude).
    if let (Some(rest), Some(cov)) = (param.strip_prefix("a."), covariate) {
        return param_unit(rest, cov.split(',').next(), gap_unit);
    }
    if let (Some(rest), Some(cov)) = (param.strip_prefix("b."), covariate) {
        return param_unit(rest, cov.split(',').nth(1), gap_unit);
    }
    if param
        .strip_prefix("coef")
        .is_some_and(|n| n.parse::<usize>().is_ok())
    {
        return ParamUnit::of(Dims::of_unit(gap_unit));
    }
    let gap = Dims::of_unit(gap_unit);
    let covs: Vec<Dims> = covariate
        .map(|c| c.split(',').map(|c| Dims::of_unit(suffix_of(c))).collect())
        .unwrap_or_default();
    let first_cov = covs.first().cloned().unwrap_or_default();
    match param {
        "offset_mm" | "amplitude_mm" | "k_mm" | "b_mm" | "tolerance_mm" => {
            return ParamUnit::of(gap)
        }
        "lambda" | "lambda_mm" | "c0" | "c1" => return ParamUnit::of(first_cov),
        _ => {}
    }
    let s = suffix_of(param);
    if !s.is_empty() {
        return ParamUnit::of(Dims::of_unit(s));
    }
    let den = covs.iter().fold(Dims::default(), |a, d| a.mul(d));
    ParamUnit { num: gap, den }
}

/// The unit suffix of a name (`feed_mm_s` → `mm_s`, `temp_c` → `c`,
/// `removed_mm3` → `mm3`), empty when it has none.
fn suffix_of(name: &str) -> &str {
    const SUFFIXES: [&str; 18] = [
        "mm_s2", "mm_min", "mm_s", "um_s", "mm3", "mm2", "mm", "um", "nm", "ms", "us", "rad", "hz",
        "s", "c", "n", "m", "deg",
    ];
    SUFFIXES
        .iter()
        .find(|s| {
            name.len() > s.len() + 1
                && name.ends_with(*s)
                && name.as_bytes()[name.len() - s.len() - 1] == b'_'
        })
        .copied()
        .unwrap_or("")
}

/// `1.50e-5 ± 0.08e-5`: value and standard error on the value's exponent
/// (the units-free form; outputs show parameters through units::format).
pub fn format_pm(value: f64, se: f64) -> String {
    if !value.is_finite() {
        return format!("{value}");
    }
    let e = if value == 0.0 {
        if se > 0.0 {
            se.abs().log10().floor() as i32
        } else {
            0
        }
    } else {
        value.abs().log10().floor() as i32
    };
    // Enough decimals that the standard error shows at least one
    // significant digit: `1.5000e-5 ± 0.0003e-5`, never `± 0.00e-5`.
    let se_digits = |se: f64| -> i32 {
        if se > 0.0 && se.is_finite() {
            (-se.log10()).ceil() as i32
        } else {
            0
        }
    };
    if (-2..4).contains(&e) {
        let d = (2 - e).max(se_digits(se)).clamp(0, 10) as usize;
        return format!("{value:.d$} ± {se:.d$}");
    }
    let s = 10f64.powi(e);
    let d = se_digits(se / s).clamp(2, 8) as usize;
    format!("{:.d$}e{e} ± {:.d$}e{e}", value / s, se / s)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pu(p: &str, c: &str) -> ParamUnit {
        param_unit(p, Some(c), "mm")
    }

    #[test]
    fn a_lag_is_a_time_in_ms() {
        let u = pu("k", "feed_mm_s");
        assert_eq!(u.canonical(), "s");
        assert_eq!(show(4.915e-3, &u), "4.92 ms");
        assert_eq!(show_pm(4.915e-3, 0.08e-3, &u), "4.92 ± 0.08 ms");
    }

    #[test]
    fn a_wavelength_is_a_length_and_an_accel_lag_is_s_squared() {
        let u = pu("lambda", "x_mm");
        assert_eq!(u.canonical(), "mm");
        assert_eq!(show(58.9, &u), "58.9 mm");
        let a = pu("k", "a_mm_s2");
        assert_eq!(a.canonical(), "s²");
        assert_eq!(show(2.5e-6, &a), "2.50 ms²");
        // A period over time is a time.
        assert_eq!(show(0.5, &pu("lambda", "t_s")), "0.500 s");
        assert_eq!(show(0.05, &pu("lambda", "t_s")), "50.0 ms");
    }

    #[test]
    fn p_values_and_axis_units() {
        assert_eq!(show_p(0.0), "< 0.001");
        assert_eq!(show_p(0.0123), "0.012");
        assert_eq!(show_p(0.5), "0.50");
        let w = pu("k", "removed_mm3");
        assert_eq!(display_unit(1.4e-5, &w), ("nm/mm³".to_string(), 1e6));
        let lag = effect_param_unit("servo_lag:feed_mm_s", "k", "mm").unwrap();
        assert_eq!(show(3.9312e-3, &lag), "3.93 ms");
        assert!(effect_param_unit("drift:t_s", "a", "deg").is_none());
        assert_eq!(show_as_written(2.5, "deg"), "2.50 deg");
        // A thermal coefficient in µm/K and a wavelength in mm.
        assert_eq!(
            show(
                1.2e-3,
                &effect_param_unit("thermal:temp_c", "k", "mm").unwrap()
            ),
            "1.20 µm/K"
        );
        assert_eq!(
            show(
                58.9,
                &effect_param_unit("periodic:x_mm", "lambda", "mm").unwrap()
            ),
            "58.9 mm"
        );
    }

    #[test]
    fn lengths_by_magnitude() {
        assert_eq!(show_length(0.00043467240783783005), "0.435 µm");
        assert_eq!(show_length(0.0145), "14.5 µm");
        assert_eq!(show_length(2.3e-6), "2.30 nm");
        assert_eq!(show_length(1.25), "1.25 mm");
        assert_eq!(show_length(0.0), "0 nm");
        assert_eq!(show_length(-0.0009996), "-1.00 µm");
        assert_eq!(show_length(-0.00009999), "-0.100 µm");
        assert_eq!(show_length(0.00002), "20.0 nm");
        assert_eq!(show_length(f64::NAN), "—");
    }

    #[test]
    fn thermal_coefficients_in_um_per_k_and_others_keep_their_sides() {
        let u = pu("k", "temp_c");
        assert_eq!(u.canonical(), "mm/°C");
        assert_eq!(show(1.2e-3, &u), "1.20 µm/K");
        let w = pu("k", "removed_mm3");
        assert_eq!(w.canonical(), "mm/mm³");
        assert_eq!(show(-9.35e-5, &w), "-93.5 nm/mm³");
        let sq = pu("k", "x_mm,y_mm");
        assert_eq!(sq.canonical(), "mm/mm²");
        // A slope of a length on a length is µm/m.
        assert_eq!(show(1.5e-5, &pu("k", "x_mm")), "15.0 µm/m");
        assert_eq!(pu("tau_s", "t_s").canonical(), "s");
        assert_eq!(pu("phase_rad", "x_mm").canonical(), "rad");
        assert_eq!(pu("t0_c", "temp_c").canonical(), "°C");
        assert_eq!(pu("c0", "x_mm").canonical(), "mm");
        // On a velocity gap the amplitude is a speed, and a lag on speed
        // is dimensionless.
        assert_eq!(
            param_unit("amplitude_mm", Some("t_s"), "mm/s").canonical(),
            "mm/s"
        );
        assert_eq!(param_unit("k", Some("a_mm_s2"), "mm/s").canonical(), "s");
        // A speed per speed is a ratio, not a slope.
        let ratio = param_unit("k", Some("cmd_v_mm_s"), "mm/s");
        assert_eq!(ratio.canonical(), "1");
        assert_eq!(show(3.78e-3, &ratio), "0.00378");
        assert_eq!(pu("k", "x_mm").canonical(), "mm/mm");
        // A product of two effects: each factor's parameters on its own
        // covariate, the joint amplitude in the gap's unit.
        assert_eq!(pu("a.c0", "y_mm,t_s").canonical(), "mm");
        assert_eq!(pu("b.tau_s", "y_mm,t_s").canonical(), "s");
        assert_eq!(show(0.0064, &pu("coef0", "y_mm,t_s")), "6.40 µm");
    }

    #[test]
    fn figures_side_by_side_share_one_unit() {
        assert_eq!(
            show_group(&[0.106, 0.000951, 0.0152], "mm"),
            ["106 µm", "0.951 µm", "15.2 µm"]
        );
        assert_eq!(show_group(&[2.84e-5, 1e-7], "mm"), ["28.4 nm", "0.100 nm"]);
        assert_eq!(
            show_group(&[0.246, 0.00211], "mm/s"),
            ["0.246 mm/s", "0.00211 mm/s"]
        );
        assert_eq!(show_group(&[f64::NAN, 2.0], "mm"), ["—", "2.00 mm"]);
    }

    #[test]
    fn value_and_interval_in_one_notation() {
        let u = pu("tau_s", "t_s");
        assert_eq!(
            show_interval(194.3, None, 140.2, 249.1, &u),
            "194 s (95 % 140 … 249 s)"
        );
        let k = pu("k", "feed_mm_s");
        assert_eq!(
            show_interval(4.915e-3, Some(0.08e-3), 4.757e-3, 5.073e-3, &k),
            "4.92 ± 0.08 ms (95 % 4.76 … 5.07 ms)"
        );
        // A standard error smaller than the value's third digit shows.
        assert_eq!(
            show_pm(2.5, 0.0012, &ParamUnit::of(Dims::time())),
            "2.500 ± 0.001 s"
        );
        // Zero with an error: the error sets the unit.
        assert_eq!(
            show_pm(0.0, 3e-6, &ParamUnit::of(Dims::length())),
            "0 ± 3 nm"
        );
        // Below the smallest unit's resolution: zero there, never
        // scientific notation.
        assert_eq!(show(3e-15, &ParamUnit::of(Dims::length())), "0 nm");
        assert_eq!(show_as_written(1.93e-4, "V"), "0.00019 V");
        // A value far inside its error: the error's digits, the error's unit.
        assert_eq!(
            show_pm(-5.48e-18, 6.54e-6, &ParamUnit::of(Dims::length())),
            "0.0 ± 6.5 nm"
        );
        let v = param_unit("offset_mm", None, "mm/s");
        assert_eq!(show_pm(-1.59e-5, 9.395e-4, &v), "-0.00002 ± 0.00094 mm/s");
        assert_eq!(
            show_interval(
                2e-20,
                Some(1e-21),
                1e-20,
                3e-20,
                &ParamUnit::of(Dims::length())
            ),
            "0.000 ± 0.000 nm (95 % 0.000 … 0.000 nm)"
        );
        assert_eq!(plain_number(1.234e7, 3), "12340000");
        assert_eq!(
            show_param(
                "lambda",
                58.9,
                Some((1.0, 57.0, 60.9)),
                &pu("lambda", "x_mm")
            ),
            "lambda = 58.9 ± 1.0 mm (95 % 57.0 … 60.9 mm)"
        );
        assert_eq!(covariate_unit("temp_c").canonical(), "°C");
    }
}

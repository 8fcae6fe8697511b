//! Surface and profile metrology shared by every machine: areal texture
//! (ISO 25178-2) and flatness (ISO 12781) of a map or point set, profile
//! parameters (ISO 21920-2) with the Gaussian profile filter (ISO 16610-21),
//! minimum-zone straightness, and readers for the text files instruments
//! export. docs/metrology.md gives every definition as implemented.
//!
//! Lengths are mm everywhere inside (the contracts' unit); a file's unit is
//! converted once, on reading, with `sparkout_pipeline::units`.
//!
//! | module | concern |
//! |---|---|
//! | [`areal`] | form removal (plane, second order) and Sq, Sa, Sz, Sp, Sv, Ssk, Sku |
//! | [`plane`] | least-squares and minimum-zone flatness of a point set |
//! | [`spikes`] | the robust outlier rule and flatness with and without spikes |
//! | [`profile`] | P and R parameters of a line profile, piecewise-linear integrals |
//! | [`gaussian`] | the Gaussian profile filter on any x spacing |
//! | [`straightness`] | least-squares and minimum-zone straightness |
//! | [`readers`] | profile tables (Parquet, CSV, instrument text) and height matrices |
//! | [`stage`] | `sparkout stage profile` and the matrix form of `flatness --surface` |

use serde_json::{json, Value};
use sparkout_pipeline::json_f64;

pub mod areal;
pub mod gaussian;
pub mod plane;
pub mod profile;
pub mod readers;
pub mod spikes;
pub mod stage;
pub mod straightness;

pub use stage::ProfileStage;

/// A length figure for JSON: canonical mm, with its unit beside it.
pub fn mm(v: f64) -> Value {
    json!({"value": json_f64(v), "unit": "mm"})
}

/// A dimensionless figure for JSON (skewness, kurtosis).
pub fn ratio(v: f64) -> Value {
    json!({"value": json_f64(v), "unit": "1"})
}

/// A length for the console, in nm, µm or mm by magnitude (4 significant
/// digits). The one place console lengths are formatted, so a shared
/// engineer-units formatter can replace it in one edit.
pub fn console_length(v_mm: f64) -> String {
    if !v_mm.is_finite() {
        return "n/a".into();
    }
    let a = v_mm.abs();
    let (v, unit) = if a == 0.0 || a >= 1.0 {
        (v_mm, "mm")
    } else if a >= 1e-3 {
        (v_mm * 1e3, "µm")
    } else {
        (v_mm * 1e6, "nm")
    };
    let digits = if v.abs() >= 100.0 {
        1
    } else if v.abs() >= 10.0 {
        2
    } else {
        3
    };
    format!("{v:.digits$} {unit}")
}

/// The `value` of a `{"value", "unit"}` figure (NaN when null).
pub(crate) fn value_of(v: &Value) -> f64 {
    v["value"].as_f64().unwrap_or(f64::NAN)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn console_lengths_pick_a_unit_by_magnitude() {
        assert_eq!(console_length(0.000_012_34), "12.34 nm");
        assert_eq!(console_length(0.001_5), "1.500 µm");
        assert_eq!(console_length(0.25), "250.0 µm");
        assert_eq!(console_length(12.5), "12.50 mm");
        assert_eq!(console_length(-0.000_000_5), "-0.500 nm");
        assert_eq!(console_length(f64::NAN), "n/a");
    }
}

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

use serde::{Deserialize, Serialize};

pub mod areal;
pub mod gaussian;
pub mod plane;
pub mod profile;
pub mod readers;
pub mod spikes;
pub mod stage;
pub mod straightness;

pub use stage::ProfileStage;

/// A figure in the JSON outputs: `{"value", "unit"}` (and a `note` where
/// the value is undefined for a stated reason). A non-finite value is
/// written `null` and read back as NaN.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Figure {
    #[serde(deserialize_with = "nan")]
    pub value: f64,
    pub unit: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

impl Figure {
    /// A length: canonical mm, with its unit beside it.
    pub fn mm(v: f64) -> Self {
        Figure {
            value: v,
            unit: "mm".into(),
            note: None,
        }
    }
    /// A dimensionless figure (skewness, kurtosis).
    pub fn ratio(v: f64) -> Self {
        Figure {
            value: v,
            unit: "1".into(),
            note: None,
        }
    }
}

/// A result that is computed, or not computed with the reason:
/// `{"not_computed": "why"}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum OrWhy<T> {
    Computed(T),
    NotComputed { not_computed: String },
}

pub(crate) use crate::typed_summary::{f64_or_nan as nan, json_number, vec_f64_or_nan as nan_vec};

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

#[cfg(test)]
mod tests {
    use super::*;

    use crate::typed_summary::reads_back as round_trip;

    #[test]
    fn every_metrology_output_reads_back_what_it_wrote() {
        use readers::{AxisInput, MatrixInput, ProfileInput, UnitInput};
        let x: Vec<f64> = (0..2001).map(|i| i as f64 * 0.003).collect();
        let z: Vec<f64> = x
            .iter()
            .map(|&u| 1e-4 * (u * 2.0).sin() + 1e-5 * (u * 90.0).sin())
            .collect();
        let axis = |c: &str| AxisInput {
            column: c.into(),
            unit: "mm".into(),
            stated_in: "the column name".into(),
        };
        // No cut-off, a cut-off that fits, one too long for the profile.
        for lambda_c in [None, Some(0.8), Some(100.0)] {
            let r = profile::analyse(
                &x,
                &z,
                profile::Settings {
                    lambda_c,
                    sampling_lengths: 5,
                },
            )
            .unwrap();
            round_trip(&r);
            let with_input = profile::ProfileReport {
                input: Some(ProfileInput {
                    file: "p.csv".into(),
                    format: "csv".into(),
                    n_points: x.len(),
                    n_not_measured: 1,
                    x: axis("x"),
                    z: axis("z"),
                    notes: vec!["a note".into()],
                }),
                ..r
            };
            assert_eq!(round_trip(&with_input).input, with_input.input);
        }
        // A map with three spikes.
        let (mut mx, mut my, mut mz) = (vec![], vec![], vec![]);
        for i in 0..20 {
            for j in 0..20 {
                let (u, v) = (i as f64, j as f64);
                mx.push(u);
                my.push(v);
                let spike = if (i * 20 + j) % 97 == 5 { 0.05 } else { 0.0 };
                mz.push(1e-3 * (u * 0.7).sin() * (v * 0.4).cos() + spike);
            }
        }
        let a = areal::surface_report(&mx, &my, &mz).unwrap();
        assert!(a.spikes.count > 0);
        let unit = |u: &str| UnitInput {
            unit: u.into(),
            stated_in: "line 2".into(),
        };
        round_trip(&stage::SurfaceFlatness {
            least_squares_mm: 0.05,
            min_zone_mm: f64::NAN,
            n: mz.len(),
            areal: a.clone(),
            input: Some(MatrixInput {
                file: "m.txt".into(),
                format: "height matrix".into(),
                rows: 20,
                columns: 20,
                pixel_x: Figure::mm(1.0),
                pixel_y: Figure::mm(1.0),
                layout: "rows".into(),
                x: unit("mm"),
                y: unit("mm"),
                z: unit("m"),
            }),
        });
        let mut b = areal::read_points_report(&mx, &my, &mz).unwrap();
        assert_eq!(b.evaluation_area.n_not_measured, None);
        b.second_order = OrWhy::NotComputed {
            not_computed: "too few points".into(),
        };
        b.spikes.threshold = Figure {
            note: Some("MAD = 0".into()),
            ..Figure::mm(f64::NAN)
        };
        let back = round_trip(&b);
        assert!(back.spikes.threshold.value.is_nan());
        assert_eq!(back.second_order, b.second_order);
    }

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

//! `[tolerance]` of run.toml or of a machine config: the limits each run
//! page's verdict judges its key figure against (docs/reports.md lists
//! them with their defaults). A run's own table wins over its machine's;
//! a key in neither takes the default. An unknown key is a typo that would
//! silently leave the default in force, so it is refused naming the key.

use std::collections::BTreeMap;

use crate::values::toml_f64;

/// (key, default, what it limits). Every value is positive, in the unit
/// its name ends with.
pub const TOLERANCE_KEYS: [(&str, f64, &str); 6] = [
    (
        "flatness_um",
        100.0,
        "gantry: minimum-zone flatness of the finished surface",
    ),
    (
        "profile_error_um",
        30.0,
        "form: RMS measured profile error along the normal",
    ),
    (
        "stock_um",
        150.0,
        "robot: stock left on the part after spark-out",
    ),
    (
        "following_error_um",
        50.0,
        "servo: peak following error of an axis",
    ),
    (
        "guideway_residual_um",
        10.0,
        "guideway: RMS offset error left after compensation (prediction residual)",
    ),
    (
        "volumetric_um",
        20.0,
        "mill: RMS volumetric error after table compensation (measured)",
    ),
];

/// Check a `[tolerance]` table: known keys, positive finite numbers.
/// Err is (dotted key, message).
pub fn check_tolerance(t: &toml::Value) -> Result<BTreeMap<String, f64>, (String, String)> {
    let Some(t) = t.as_table() else {
        return Err((
            "tolerance".into(),
            "[tolerance] must be a table of limits".into(),
        ));
    };
    let mut out = BTreeMap::new();
    for (k, v) in t {
        if !TOLERANCE_KEYS.iter().any(|(n, _, _)| n == k) {
            return Err((
                format!("tolerance.{k}"),
                format!(
                    "unknown key [tolerance].{k} (known: {})",
                    TOLERANCE_KEYS
                        .iter()
                        .map(|(n, _, _)| *n)
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            ));
        }
        match toml_f64(v).filter(|x| x.is_finite() && *x > 0.0) {
            Some(x) => {
                out.insert(k.clone(), x);
            }
            None => {
                return Err((
                    format!("tolerance.{k}"),
                    format!("[tolerance].{k} must be a positive number, found {v}"),
                ))
            }
        }
    }
    Ok(out)
}

/// The default of a tolerance key (None for an unknown key).
pub fn tolerance_default(key: &str) -> Option<f64> {
    TOLERANCE_KEYS
        .iter()
        .find(|(n, _, _)| *n == key)
        .map(|(_, d, _)| *d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_and_bad_keys_are_refused_by_name() {
        let v: toml::Value = toml::from_str::<toml::Table>("flatnes_um = 5")
            .unwrap()
            .into();
        let (k, m) = check_tolerance(&v).unwrap_err();
        assert_eq!(k, "tolerance.flatnes_um");
        assert!(m.contains("flatnes_um") && m.contains("flatness_um"), "{m}");
        let v: toml::Value = toml::from_str::<toml::Table>("flatness_um = -1")
            .unwrap()
            .into();
        assert!(check_tolerance(&v).is_err());
        let v: toml::Value = toml::from_str::<toml::Table>("flatness_um = 20")
            .unwrap()
            .into();
        assert_eq!(check_tolerance(&v).unwrap()["flatness_um"], 20.0);
    }
}

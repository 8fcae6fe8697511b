//! Conversions every plugin needs between numbers and the TOML/JSON they are
//! read from or written to, kept in one place.

use serde_json::Value;

/// A number in a TOML value; integers are accepted because TOML writes
/// `5` for a value a user means as 5.0.
pub fn toml_f64(v: &toml::Value) -> Option<f64> {
    match v {
        toml::Value::Float(f) => Some(*f),
        toml::Value::Integer(i) => Some(*i as f64),
        _ => None,
    }
}

/// A number for a JSON summary: `null` for NaN or ±∞ (JSON has neither),
/// so "not computable" reads as absent rather than as a wrong number.
pub fn json_f64(x: f64) -> Value {
    if x.is_finite() {
        Value::from(x)
    } else {
        Value::Null
    }
}

/// [`json_f64`] of an optional number: `None` is `null` too.
pub fn json_opt_f64(x: Option<f64>) -> Value {
    x.map_or(Value::Null, json_f64)
}

/// A number as a JSON artifact holds it: serde_json writes a non-finite f64
/// as `null`, which reads back as NaN (not an error). For
/// `#[serde(deserialize_with = "…")]` on an `f64` field.
pub fn f64_or_nan<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(<Option<f64> as serde::Deserialize>::deserialize(d)?.unwrap_or(f64::NAN))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_convert_and_non_finite_is_null() {
        assert_eq!(toml_f64(&toml::Value::Integer(5)), Some(5.0));
        assert_eq!(toml_f64(&toml::Value::Float(0.5)), Some(0.5));
        assert_eq!(toml_f64(&toml::Value::String("5".into())), None);
        assert_eq!(json_f64(1.5), serde_json::json!(1.5));
        assert_eq!(json_f64(f64::NAN), Value::Null);
        assert_eq!(json_opt_f64(Some(f64::INFINITY)), Value::Null);
        assert_eq!(json_opt_f64(None), Value::Null);
    }
}

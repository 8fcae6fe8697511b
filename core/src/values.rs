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

//! Stage summaries through their serde types: each `<stage>.json` a plugin
//! writes has one type that writes it (`StageOutput::typed`) and reads it
//! back (`ArtifactStore::summary_as`), so a renamed key fails to compile
//! instead of reading as missing.
//!
//! serde_json writes a non-finite f64 as `null`; a summary type reads that
//! `null` back as NaN (not an error), so a number that was NaN when written
//! is NaN when read.

use serde::de::DeserializeOwned;
use serde::{Deserialize, Deserializer};
use sparkout_pipeline::ArtifactStore;

/// The summary of `stage` as `T`; `None` when the stage has not run, or
/// when its summary does not have the type's shape (a summary cached by
/// another version of sparkout), which is logged: a report then leaves out
/// what it would have shown, as it does for a stage that has not run.
pub(crate) fn read<T: DeserializeOwned>(a: &ArtifactStore, stage: &str) -> Option<T> {
    match a.summary_as::<T>(stage)? {
        Ok(t) => Some(t),
        Err(e) => {
            tracing::warn!("{e:#}");
            None
        }
    }
}

/// `#[serde(deserialize_with = "crate::typed_summary::f64_or_nan")]`:
/// `null` → NaN; `vec_f64_or_nan` the same element-wise (the one pair of
/// readers every sparkout JSON uses).
pub(crate) use sparkout_pipeline::files::json::{f64_or_nan, vec_f64_or_nan};

/// The same for a map of numbers by name: each `null` → NaN.
pub(crate) fn map_f64_or_nan<'de, D: Deserializer<'de>>(
    d: D,
) -> Result<std::collections::BTreeMap<String, f64>, D::Error> {
    Ok(
        std::collections::BTreeMap::<String, Option<f64>>::deserialize(d)?
            .into_iter()
            .map(|(k, x)| (k, x.unwrap_or(f64::NAN)))
            .collect(),
    )
}

/// The same for a fixed-length list (a vector's components).
pub(crate) fn arr_or_nan<'de, D: Deserializer<'de>, const N: usize>(
    d: D,
) -> Result<[f64; N], D::Error> {
    let v = vec_f64_or_nan(d)?;
    let n = v.len();
    v.try_into()
        .map_err(|_| serde::de::Error::invalid_length(n, &format!("{N} numbers").as_str()))
}

/// `#[serde(default, skip_serializing_if = "Option::is_none",
/// deserialize_with = "crate::typed_summary::present")]` on an
/// `Option<Option<T>>`: a key that is absent reads as `None`, a key that
/// is `null` as `Some(None)` (serde alone reads both as `None`).
pub(crate) fn present<'de, D: Deserializer<'de>, T: Deserialize<'de>>(
    d: D,
) -> Result<Option<T>, D::Error> {
    T::deserialize(d).map(Some)
}

/// A number as serde_json prints it (`8.0`, `null` for NaN), for text that
/// has always shown the JSON value itself.
pub(crate) fn json_number(x: f64) -> String {
    serde_json::to_string(&x).unwrap_or_else(|_| "null".into())
}

/// A number for a report to show: `None` for NaN or ±∞ (written as
/// `null`: not computed).
pub(crate) fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// The round-trip test of a summary type: written through
/// `StageOutput::typed` and read back with `ArtifactStore::summary_as`, it
/// is the same summary (compared as the JSON each writes, so NaN, written
/// as `null`, equals NaN). Returns the JSON for further checks.
#[cfg(test)]
pub(crate) fn round_trip<T>(summary: &T) -> serde_json::Value
where
    T: serde::Serialize + serde::de::DeserializeOwned,
{
    let written = sparkout_pipeline::StageOutput::typed(summary)
        .unwrap()
        .summary;
    let store = sparkout_pipeline::ArtifactStore::default();
    store.set_summary("stage", written.clone());
    let read: T = store.summary_as("stage").unwrap().unwrap();
    let again = serde_json::to_value(&read).unwrap();
    assert_eq!(written, again, "a summary read back writes the same JSON");
    written
}

/// Write → read → write gives the same JSON (a NaN figure is `null` both
/// times); the value read back, for further checks.
#[cfg(test)]
pub(crate) fn reads_back<T>(v: &T) -> T
where
    T: serde::Serialize + serde::de::DeserializeOwned + std::fmt::Debug,
{
    let j = serde_json::to_value(v).unwrap();
    let back: T = serde_json::from_value(j.clone()).unwrap();
    assert_eq!(serde_json::to_value(&back).unwrap(), j, "{v:?}");
    back
}

//! JSON files read back through the serde type that wrote them. No reader
//! indexes a `serde_json::Value` by key (a renamed field would still
//! compile and read as "missing"); it deserialises the file's type, and an
//! error names the file and the field (`effects[0].params.k`), found by
//! walking the text up to where serde stopped — a lexical scan, no `Value`.

use std::path::Path;

use crate::Context;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::error::{InputError, Result};

/// A number as sparkout's JSON holds it: serde_json writes a non-finite
/// `f64` as `null`, which reads back as NaN (not an error).
pub fn f64_or_nan<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<f64, D::Error> {
    Ok(<Option<f64> as Deserialize>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// Numbers as sparkout's JSON holds them ([`f64_or_nan`], element-wise).
pub fn vec_f64_or_nan<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<Vec<f64>, D::Error> {
    Ok(<Vec<Option<f64>> as Deserialize>::deserialize(d)?
        .into_iter()
        .map(|x| x.unwrap_or(f64::NAN))
        .collect())
}

/// The two fields a versioned file opens with, read before the rest so a
/// file of another kind or version is refused by name rather than by the
/// first field its type does not know.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FileHeader {
    #[serde(default)]
    pub version: Option<u64>,
    #[serde(default)]
    pub kind: Option<String>,
}

/// `bytes` (the contents of `file`) as a `T`. A syntax error, a missing
/// field or a value of the wrong type names the file and the field.
pub fn parse_json<T: DeserializeOwned>(
    file: &Path,
    bytes: &[u8],
) -> std::result::Result<T, InputError> {
    serde_json::from_slice(bytes).map_err(|e| InputError::new(file, describe(bytes, &e)))
}

/// The file at `path` as a `T` ([`parse_json`]); a file that cannot be read
/// says so.
pub fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    Ok(parse_json(path, &bytes)?)
}

/// Where `text` (a JSON file) and `typed` (what its type read from it)
/// differ, as `field: file value ≠ typed value`; None when the type writes
/// back every field the file holds, unchanged — none unknown, dropped or
/// renamed. Compared as parsed JSON: serde_json's float parser may land
/// one ulp off a printed float, the same way on both sides. (The round
/// trip the tests of every JSON file's type make.)
pub fn reads_back_whole<T: Serialize>(typed: &T, text: &[u8]) -> Option<String> {
    let file: serde_json::Value = match serde_json::from_slice(text) {
        Ok(v) => v,
        Err(e) => return Some(format!("not JSON: {e}")),
    };
    let back = match serde_json::to_value(typed) {
        Ok(v) => v,
        Err(e) => return Some(format!("does not serialise: {e}")),
    };
    first_difference(&file, &back, &mut Vec::new())
}

fn first_difference(
    a: &serde_json::Value,
    b: &serde_json::Value,
    path: &mut Vec<Segment>,
) -> Option<String> {
    use serde_json::Value;
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            for k in x.keys().chain(y.keys().filter(|k| !x.contains_key(*k))) {
                path.push(Segment::Key(k.clone()));
                let d = match (x.get(k), y.get(k)) {
                    (Some(p), Some(q)) => first_difference(p, q, path),
                    (p, q) => Some(format!(
                        "{}: {} ≠ {}",
                        show(path),
                        p.map_or("absent".into(), |v| v.to_string()),
                        q.map_or("absent".into(), |v| v.to_string())
                    )),
                };
                path.pop();
                if d.is_some() {
                    return d;
                }
            }
            None
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => {
            for (i, (p, q)) in x.iter().zip(y).enumerate() {
                path.push(Segment::Index(i));
                let d = first_difference(p, q, path);
                path.pop();
                if d.is_some() {
                    return d;
                }
            }
            None
        }
        _ if a == b => None,
        _ => Some(format!("{}: {a} ≠ {b}", show(path))),
    }
}

/// serde_json's message with the field it stopped in: "field `a[0].b`:
/// invalid type: … (line 1, column 40)".
fn describe(bytes: &[u8], e: &serde_json::Error) -> String {
    let text = e.to_string();
    // serde_json appends " at line L column C"; the position is repeated
    // in our own words below.
    let message = match text.rfind(" at line ") {
        Some(i) if e.line() > 0 => &text[..i],
        _ => text.as_str(),
    };
    if e.line() == 0 {
        return message.to_string();
    }
    let offset = offset_of(bytes, e.line(), e.column());
    let mut path = field_at(bytes, offset);
    // A missing field is reported where its object ends: the object's path
    // plus the field's name.
    if let Some(name) = message
        .strip_prefix("missing field `")
        .and_then(|m| m.strip_suffix('`'))
    {
        path.push(Segment::Key(name.to_string()));
    }
    let where_ = format!("(line {}, column {})", e.line(), e.column());
    if path.is_empty() {
        format!("{message} {where_}")
    } else {
        format!("field `{}`: {message} {where_}", show(&path))
    }
}

/// Byte offset of 1-based `line` and `column` (serde_json's position of the
/// last byte it read).
fn offset_of(bytes: &[u8], line: usize, column: usize) -> usize {
    let mut start = 0;
    for _ in 1..line {
        match bytes[start..].iter().position(|&b| b == b'\n') {
            Some(i) => start += i + 1,
            None => break,
        }
    }
    (start + column).min(bytes.len())
}

#[derive(Debug, Clone, PartialEq)]
enum Segment {
    Key(String),
    Index(usize),
}

fn show(path: &[Segment]) -> String {
    let mut s = String::new();
    for p in path {
        match p {
            Segment::Key(k) if s.is_empty() => s.push_str(k),
            Segment::Key(k) => {
                s.push('.');
                s.push_str(k);
            }
            Segment::Index(i) => s.push_str(&format!("[{i}]")),
        }
    }
    s
}

/// The path of the value being read at byte `offset` of a JSON text: the
/// keys and indices of the objects and arrays open there.
fn field_at(bytes: &[u8], offset: usize) -> Vec<Segment> {
    enum Open {
        Object { key: Option<String>, in_value: bool },
        Array { index: usize },
    }
    let mut stack: Vec<Open> = Vec::new();
    let mut i = 0;
    let end = offset.min(bytes.len());
    while i < end {
        match bytes[i] {
            b'{' => stack.push(Open::Object {
                key: None,
                in_value: false,
            }),
            b'[' => stack.push(Open::Array { index: 0 }),
            b'}' | b']' => {
                stack.pop();
            }
            b',' => match stack.last_mut() {
                Some(Open::Array { index }) => *index += 1,
                Some(Open::Object { key, in_value }) => {
                    *key = None;
                    *in_value = false;
                }
                None => {}
            },
            b':' => {
                if let Some(Open::Object { in_value, .. }) = stack.last_mut() {
                    *in_value = true;
                }
            }
            b'"' => {
                let start = i + 1;
                let mut j = start;
                while j < bytes.len() && bytes[j] != b'"' {
                    j += if bytes[j] == b'\\' { 2 } else { 1 };
                }
                if let Some(Open::Object {
                    key,
                    in_value: false,
                }) = stack.last_mut()
                {
                    let raw = &bytes[start..j.min(bytes.len())];
                    *key = Some(
                        serde_json::from_slice::<String>(&[b"\"", raw, b"\""].concat())
                            .unwrap_or_else(|_| String::from_utf8_lossy(raw).into_owned()),
                    );
                }
                i = j;
            }
            _ => {}
        }
        i += 1;
    }
    stack
        .into_iter()
        .filter_map(|o| match o {
            Open::Object { key, .. } => key.map(Segment::Key),
            Open::Array { index } => Some(Segment::Index(index)),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, PartialEq, Serialize, Deserialize)]
    struct Inner {
        name: String,
        params: std::collections::BTreeMap<String, f64>,
        #[serde(deserialize_with = "f64_or_nan")]
        rms: f64,
    }

    #[derive(Debug, PartialEq, Serialize, Deserialize)]
    struct Outer {
        version: u32,
        effects: Vec<Inner>,
    }

    fn err(text: &str) -> String {
        parse_json::<Outer>(Path::new("m.json"), text.as_bytes())
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn a_file_reads_back_through_its_type_and_null_is_nan() {
        let o = Outer {
            version: 1,
            effects: vec![Inner {
                name: "wear".into(),
                params: [("k".to_string(), 1.5)].into(),
                rms: f64::NAN,
            }],
        };
        let text = serde_json::to_string_pretty(&o).unwrap();
        assert!(text.contains("\"rms\": null"), "{text}");
        let back: Outer = parse_json(Path::new("m.json"), text.as_bytes()).unwrap();
        assert!(back.effects[0].rms.is_nan());
        assert_eq!(serde_json::to_string_pretty(&back).unwrap(), text);
    }

    #[test]
    fn an_error_names_the_file_and_the_field() {
        let e = err(
            r#"{"version": 1, "effects": [{"name": "a", "params": {}, "rms": 1},
            {"name": "b", "params": {"tau_s": 2, "k": "fast"}, "rms": 1}]}"#,
        );
        assert!(
            e.starts_with("m.json: field `effects[1].params.k`: invalid type: string \"fast\""),
            "{e}"
        );
        assert!(e.contains("(line 2, column"), "{e}");
        let e = err(r#"{"version": 1, "effects": [{"name": "a", "rms": 1}]}"#);
        assert!(
            e.contains("field `effects[0].params`: missing field `params`"),
            "{e}"
        );
        let e = err(r#"{"effects": []}"#);
        assert!(
            e.contains("field `version`: missing field `version`"),
            "{e}"
        );
        let e = err(r#"{"version": "one", "effects": []}"#);
        assert!(e.contains("field `version`: invalid type"), "{e}");
        // Keys with escapes, strings holding brackets and commas.
        let e = err(
            r#"{"version": 1, "effects": [{"name": "a,[{\"", "params": {"x\"y": []}, "rms": 1}]}"#,
        );
        assert!(e.contains("field `effects[0].params.x\"y`"), "{e}");
        let e = err("{\"version\": 1, \"effects\": [");
        assert!(e.starts_with("m.json: "), "{e}");
    }
}

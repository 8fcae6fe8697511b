//! Errors that tell the user what is wrong and where: file, column, row.

use std::fmt;
use std::path::{Path, PathBuf};

/// A bad input: names the file, the column and (where it applies) the first
/// offending row, per docs/formats.md §1.
#[derive(Debug, Clone, PartialEq)]
pub struct InputError {
    pub file: PathBuf,
    pub column: Option<String>,
    pub row: Option<usize>,
    pub message: String,
}

impl InputError {
    pub fn new(file: impl AsRef<Path>, message: impl Into<String>) -> Self {
        InputError {
            file: file.as_ref().to_path_buf(),
            column: None,
            row: None,
            message: message.into(),
        }
    }
    pub fn column(mut self, column: impl Into<String>) -> Self {
        self.column = Some(column.into());
        self
    }
    pub fn row(mut self, row: usize) -> Self {
        self.row = Some(row);
        self
    }
}

impl fmt::Display for InputError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if let Some(c) = &self.column {
            write!(f, ", column `{c}`")?;
        }
        if let Some(r) = self.row {
            write!(f, ", row {r}")?;
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for InputError {}

/// A bad config section (`[<plugin>.<stage>]`, `[diagnose]`): typed so a
/// caller can tell an unknown key from a bad value without reading the
/// message (`sparkout stage --flag` turns the first into "not a config key
/// of this stage", the second into "bad value for this flag").
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfigError {
    #[error("unknown key `{key}` (known: {})", known_list(.known))]
    UnknownKey { key: String, known: Vec<String> },
    #[error("key `{key}` must be {want}, found {found}")]
    BadValue {
        key: String,
        want: String,
        found: String,
    },
    /// A value serde could not read (wrong type, wrong shape); the message
    /// names the key.
    #[error("{0}")]
    Invalid(String),
    /// A key's value of the wrong type or shape.
    #[error("key `{key}`: {message}")]
    WrongType { key: String, message: String },
    /// A key that must be given is not.
    #[error("required key `{key}` is missing")]
    Missing { key: String },
}

impl ConfigError {
    pub fn bad_value(key: &str, want: impl Into<String>, found: impl fmt::Display) -> Self {
        ConfigError::BadValue {
            key: key.to_string(),
            want: want.into(),
            found: found.to_string(),
        }
    }
    /// The key the error is about, when it names one.
    pub fn key(&self) -> Option<&str> {
        match self {
            ConfigError::UnknownKey { key, .. }
            | ConfigError::BadValue { key, .. }
            | ConfigError::WrongType { key, .. }
            | ConfigError::Missing { key } => Some(key),
            ConfigError::Invalid(_) => None,
        }
    }
    /// Whether an error of any kind is an unknown config key.
    pub fn is_unknown_key(e: &anyhow::Error) -> bool {
        matches!(
            e.downcast_ref::<ConfigError>(),
            Some(ConfigError::UnknownKey { .. })
        )
    }
}

fn known_list(known: &[String]) -> String {
    if known.is_empty() {
        "none".to_string()
    } else {
        known.join(", ")
    }
}

/// Shorthand used across the pipeline: errors carry context via anyhow, bad
/// input is an [`InputError`] inside it (downcast to tell the two apart).
pub type Result<T, E = anyhow::Error> = std::result::Result<T, E>;

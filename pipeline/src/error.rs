//! Errors that tell the user what is wrong and where: file, column, row.

use std::fmt;
use std::path::{Path, PathBuf};

/// A bad input: names the file, the column and (where it applies) the first
/// offending row, per CONTRACTS.md "Conventions".
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

/// Shorthand used across the pipeline: errors carry context via anyhow, bad
/// input is an [`InputError`] inside it (downcast to tell the two apart).
pub type Result<T, E = anyhow::Error> = std::result::Result<T, E>;

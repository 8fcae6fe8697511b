//! Reading a foreign table: CSV (optionally gzip-compressed, `.csv.gz`), or
//! Parquet with any column names. The CSV reader is the small RFC 4180
//! parser in `csv.rs` (the `csv` crate turns on serde's default feature,
//! which rebuilds polars and arrow for a few lines of parsing). Cells are kept as text
//! with the file line they came from, so a value that does not parse is
//! reported by file, column and row like any bad input (docs/formats.md
//! "Conventions").

use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};

use arrow::array::{Array, StringArray};
use arrow::compute::cast;
use arrow::datatypes::DataType;

use super::mapping::SourceRef;
use crate::error::InputError;

/// A source table, column-major, all cells as text (`None` = empty/null).
#[derive(Debug, Clone)]
pub struct SourceTable {
    pub path: PathBuf,
    pub headers: Vec<String>,
    pub columns: Vec<Vec<Option<String>>>,
    /// File line of each row (1-based) for CSV; `None` for Parquet.
    pub lines: Option<Vec<u64>>,
}

impl SourceTable {
    pub fn n_rows(&self) -> usize {
        self.columns.first().map_or(0, |c| c.len())
    }

    /// Where row `i` is, for messages: `row 12 (line 14)`.
    pub fn row_label(&self, i: usize) -> String {
        match &self.lines {
            Some(l) => format!("row {i} (line {} of the file)", l[i]),
            None => format!("row {i}"),
        }
    }

    /// The column a mapping names, or an error listing what the file has.
    pub fn column(&self, r: &SourceRef) -> Result<usize, InputError> {
        let found = match r {
            SourceRef::Name(n) => self.headers.iter().position(|h| h == n),
            SourceRef::Index(i) => (*i < self.headers.len()).then_some(*i),
        };
        found.ok_or_else(|| {
            let shown: Vec<String> = self
                .headers
                .iter()
                .enumerate()
                .take(60)
                .map(|(i, h)| format!("#{i} {h:?}"))
                .collect();
            InputError::new(
                &self.path,
                format!(
                    "the mapping names source column {r}, which the file does not have (columns: {})",
                    shown.join(", ")
                ),
            )
            .column(r.to_string())
        })
    }

    /// Read a CSV, `.csv.gz` or Parquet file (by extension; anything not
    /// Parquet is read as delimited text).
    pub fn read(path: &Path, delimiter: u8) -> Result<SourceTable, InputError> {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().to_lowercase())
            .unwrap_or_default();
        if name.ends_with(".parquet") || name.ends_with(".pq") {
            Self::read_parquet(path)
        } else {
            let file =
                File::open(path).map_err(|e| InputError::new(path, format!("cannot open: {e}")))?;
            let reader: Box<dyn Read> = if name.ends_with(".gz") {
                Box::new(flate2::read::MultiGzDecoder::new(file))
            } else {
                Box::new(file)
            };
            Self::read_csv(path, reader, delimiter)
        }
    }

    fn read_csv(path: &Path, reader: impl Read, delimiter: u8) -> Result<SourceTable, InputError> {
        let mut rdr = super::csv::Records::new(std::io::BufReader::new(reader), delimiter);
        let (_, header) = rdr
            .next_record()
            .map_err(|e| csv_error(path, e))?
            .ok_or_else(|| InputError::new(path, "no header line (an empty file?)"))?;
        let headers: Vec<String> = header
            .into_iter()
            .enumerate()
            .map(|(i, h)| {
                let h = if i == 0 {
                    h.trim_start_matches('\u{feff}').to_string()
                } else {
                    h
                };
                h.trim().to_string()
            })
            .collect();
        let mut columns: Vec<Vec<Option<String>>> = vec![Vec::new(); headers.len()];
        let mut lines = Vec::new();
        while let Some((line, rec)) = rdr.next_record().map_err(|e| csv_error(path, e))? {
            if rec.len() == 1 && rec[0].trim().is_empty() {
                continue; // a blank line
            }
            if rec.len() != headers.len() {
                return Err(InputError::new(
                    path,
                    format!(
                        "line {line} has {} fields, the header {} (a missing or extra delimiter?)",
                        rec.len(),
                        headers.len()
                    ),
                )
                .row(lines.len()));
            }
            lines.push(line);
            for (c, v) in columns.iter_mut().zip(rec) {
                let v = v.trim();
                c.push((!v.is_empty()).then(|| v.to_string()));
            }
        }
        Ok(SourceTable {
            path: path.to_path_buf(),
            headers,
            columns,
            lines: Some(lines),
        })
    }

    fn read_parquet(path: &Path) -> Result<SourceTable, InputError> {
        let batch = crate::contracts::read_parquet(path)
            .map_err(|e| InputError::new(path, format!("{e:#}")))?;
        let mut headers = Vec::new();
        let mut columns = Vec::new();
        for (f, col) in batch.schema().fields().iter().zip(batch.columns()) {
            let text = cast(col, &DataType::Utf8).map_err(|e| {
                InputError::new(
                    path,
                    format!("cannot read column of type {}: {e}", f.data_type()),
                )
                .column(f.name())
            })?;
            let text = text
                .as_any()
                .downcast_ref::<StringArray>()
                .expect("cast to Utf8");
            headers.push(f.name().clone());
            columns.push(
                (0..text.len())
                    .map(|i| (!text.is_null(i)).then(|| text.value(i).to_string()))
                    .collect(),
            );
        }
        Ok(SourceTable {
            path: path.to_path_buf(),
            headers,
            columns,
            lines: None,
        })
    }
}

fn csv_error(path: &Path, e: super::csv::CsvError) -> InputError {
    InputError::new(path, format!("not readable as CSV: {e}"))
}

//! Validated, in-memory tables (everything but the AE log, which streams: see
//! `ae_stream`). A `Table` is an arrow `RecordBatch` whose contract columns
//! have been checked and normalised to their v1 types; extra columns are kept
//! untouched (docs/formats.md: "extra columns are kept and passed through").

use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow::array::{
    Array, ArrayRef, Float32Array, Float64Array, Int32Array, Int64Array, Int8Array, StringArray,
};
use arrow::datatypes::{DataType, Field, Schema};
use arrow::record_batch::RecordBatch;

pub(crate) use super::convert::type_accepted;
use super::convert::{earliest_unix_s, is_time_column, normalise, TimeOrigin};
pub(crate) use super::parquet_file::open_parquet;
use super::parquet_file::read_all;
use super::schema::{ColumnKind, TableSchema};
use crate::error::InputError;

#[derive(Debug, Clone)]
pub struct Table {
    path: PathBuf,
    batch: RecordBatch,
}

pub(crate) fn arrow_type(kind: ColumnKind) -> DataType {
    match kind {
        ColumnKind::F64 => DataType::Float64,
        ColumnKind::F32 => DataType::Float32,
        ColumnKind::I32 => DataType::Int32,
        ColumnKind::I64 => DataType::Int64,
        ColumnKind::I8 => DataType::Int8,
        ColumnKind::Utf8 => DataType::Utf8,
    }
}

/// Check the file's schema against the contract: required columns present,
/// known columns of an accepted type.
pub(crate) fn check_schema(
    path: &Path,
    schema: &TableSchema,
    file_schema: &Schema,
) -> Result<(), InputError> {
    for spec in schema.columns {
        match file_schema.field_with_name(spec.name) {
            Ok(field) => {
                if !type_accepted(spec.kind, spec.name, field.data_type()) {
                    return Err(InputError::new(
                        path,
                        format!(
                            "wrong type {} (the contract says {}; see docs/formats.md)",
                            field.data_type(),
                            spec.kind.label()
                        ),
                    )
                    .column(spec.name));
                }
            }
            Err(_) if spec.required => {
                let have: Vec<&str> = file_schema
                    .fields()
                    .iter()
                    .map(|f| f.name().as_str())
                    .collect();
                return Err(InputError::new(
                    path,
                    format!(
                        "required column missing from `{}` (columns present: {})",
                        schema.name,
                        have.join(", ")
                    ),
                )
                .column(spec.name));
            }
            Err(_) => {}
        }
    }
    Ok(())
}

/// First row (0-based, within `offset`) that is null, NaN or infinite.
pub(crate) fn first_non_finite(col: &dyn Array) -> Option<(usize, &'static str)> {
    if col.null_count() > 0 {
        let i = (0..col.len()).find(|&i| col.is_null(i)).unwrap_or(0);
        return Some((i, "null"));
    }
    let classify = |v: f64| if v.is_nan() { "NaN" } else { "infinite value" };
    if let Some(a) = col.as_any().downcast_ref::<Float64Array>() {
        return first_failing(a.values(), |v| v.is_finite()).map(|i| (i, classify(a.value(i))));
    }
    if let Some(a) = col.as_any().downcast_ref::<Float32Array>() {
        return first_failing(a.values(), |v| v.is_finite())
            .map(|i| (i, classify(a.value(i) as f64)));
    }
    None
}

/// First row of a float column holding NaN in a non-null cell. In an
/// optional column a value not recorded at a row is null (pandas writes NaN
/// as null); a NaN there is a failed computation, refused like one in a
/// required column.
pub(crate) fn first_nan(col: &dyn Array) -> Option<usize> {
    let nan_at = |i: usize, v: f64| v.is_nan() && !col.is_null(i);
    if let Some(a) = col.as_any().downcast_ref::<Float64Array>() {
        return if col.null_count() == 0 {
            first_failing(a.values(), |v| !v.is_nan())
        } else {
            (0..a.len()).find(|&i| nan_at(i, a.value(i)))
        };
    }
    if let Some(a) = col.as_any().downcast_ref::<Float32Array>() {
        return (0..a.len()).find(|&i| nan_at(i, a.value(i) as f64));
    }
    None
}

/// The first index whose value fails `ok`. Scans in chunks whose test has
/// no early exit (so it vectorises), then finds the index inside the first
/// failing chunk: validating an AE log runs at memory speed, where a
/// `position` with a branch per sample cost a fifth of the ingest.
pub(crate) fn first_failing<T: Copy>(v: &[T], ok: impl Fn(T) -> bool) -> Option<usize> {
    const CHUNK: usize = 512;
    v.chunks(CHUNK).enumerate().find_map(|(c, chunk)| {
        let all_ok = chunk.iter().fold(true, |acc, &x| acc & ok(x));
        (!all_ok).then(|| c * CHUNK + chunk.iter().position(|&x| !ok(x)).unwrap_or(0))
    })
}

/// Whether every value lies in `lo..=hi` (so is finite: NaN fails both
/// comparisons), in one vectorised pass with no early exit per value. The
/// AE stream runs this instead of the finite check and the plausible-range
/// check one after the other; only a column that fails it is scanned again
/// by those two, to name the first failure as they always did.
pub(crate) fn all_within<T: Copy + Into<f64>>(v: &[T], lo: f64, hi: f64) -> bool {
    const CHUNK: usize = 512;
    v.chunks(CHUNK).all(|chunk| {
        chunk.iter().fold(true, |acc, &x| {
            let x: f64 = x.into();
            acc & (x >= lo) & (x <= hi)
        })
    })
}

/// A time column's three checks in one pass — every stamp in `lo..=hi`,
/// none below its predecessor — and, as a by-product, the largest step
/// between neighbours (the AE detector splits recording blocks at steps
/// beyond 1.5 samples; knowing the largest spares it a scan of its own).
/// `None` when any check fails: the separate checks then name the first
/// failure. A slice of one stamp has a largest step of −∞.
pub(crate) fn time_column_scan(t: &[f64], lo: f64, hi: f64) -> Option<f64> {
    let (&first, &last) = (t.first()?, t.last()?);
    // Non-decreasing stamps lie between the first and the last, so the range
    // needs only those two once every step is known to be ≥ 0.
    let in_range = |x: f64| (x >= lo) & (x <= hi);
    if !(in_range(first) & in_range(last)) {
        return None;
    }
    // Min/max of the steps in four lanes (`minpd`/`maxpd`, no branch or
    // flag per value: a flag-and-compare loop stayed scalar and cost 7 % of
    // AE ingest). Comparisons skip NaN, so a NaN is caught by the sum of the
    // steps, which any NaN stamp (or ∞ − ∞) turns NaN.
    const LANES: usize = 4;
    let mut min_step = [f64::INFINITY; LANES];
    let mut max_step = [f64::NEG_INFINITY; LANES];
    let mut sum_step = [0.0; LANES];
    let mut lane = |l: usize, x: f64, y: f64| {
        let d = y - x;
        min_step[l] = if d < min_step[l] { d } else { min_step[l] };
        max_step[l] = if d > max_step[l] { d } else { max_step[l] };
        sum_step[l] += d;
    };
    let mut from = t[..t.len() - 1].chunks_exact(LANES);
    let mut to = t[1..].chunks_exact(LANES);
    for (x, y) in (&mut from).zip(&mut to) {
        for l in 0..LANES {
            lane(l, x[l], y[l]);
        }
    }
    for (&x, &y) in from.remainder().iter().zip(to.remainder()) {
        lane(0, x, y);
    }
    let ok = (0..LANES).all(|l| (min_step[l] >= 0.0) & !sum_step[l].is_nan());
    ok.then(|| max_step.into_iter().fold(f64::NEG_INFINITY, f64::max))
}

/// The first row whose time stamp is below its predecessor's.
pub(crate) fn first_decrease(t: &[f64]) -> Option<usize> {
    if t.len() < 2 {
        return None;
    }
    // Pairs (t[i], t[i+1]) as the slice shifted by one; a pair is fine
    // unless t[i+1] < t[i] (a NaN is the finite check's to report).
    let later = &t[1..];
    let ok_pairs = |c: usize, len: usize| {
        t[c..c + len]
            .iter()
            .zip(&later[c..c + len])
            .fold(true, |acc, (a, b)| {
                acc & ((*b >= *a) | a.is_nan() | b.is_nan())
            })
    };
    const CHUNK: usize = 512;
    let n = later.len();
    (0..n).step_by(CHUNK).find_map(|c| {
        let len = CHUNK.min(n - c);
        (!ok_pairs(c, len)).then(|| {
            c + 1
                + t[c..c + len]
                    .iter()
                    .zip(&later[c..c + len])
                    .position(|(a, b)| b < a)
                    .unwrap_or(0)
        })
    })
}

impl Table {
    /// Read and validate a whole table (not for AE logs: use `AeStream`).
    /// Timestamps in time columns count from the table's earliest one; a
    /// run's tables use [`Table::read_at`] with the run's start.
    pub fn read(path: &Path, schema: &TableSchema) -> Result<Table, InputError> {
        Self::read_at(path, schema, &TimeOrigin::TableStart)
    }

    /// Read and validate a whole table, timestamps measured from `origin`.
    pub fn read_at(
        path: &Path,
        schema: &TableSchema,
        origin: &TimeOrigin,
    ) -> Result<Table, InputError> {
        let builder = open_parquet(path)?;
        check_schema(path, schema, builder.schema())?;
        let batch = read_all(path, builder)?;
        Self::from_batch_at(path, schema, batch, origin)
    }

    /// Validate and normalise an in-memory batch against a schema.
    pub fn from_batch(
        path: &Path,
        schema: &TableSchema,
        batch: RecordBatch,
    ) -> Result<Table, InputError> {
        Self::from_batch_at(path, schema, batch, &TimeOrigin::TableStart)
    }

    /// [`Table::from_batch`] with timestamps measured from `origin`.
    pub fn from_batch_at(
        path: &Path,
        schema: &TableSchema,
        batch: RecordBatch,
        origin: &TimeOrigin,
    ) -> Result<Table, InputError> {
        check_schema(path, schema, &batch.schema())?;
        // One origin for every time column of the table, so t_start_s and
        // t_end_s stay comparable.
        let origin = match origin {
            TimeOrigin::TableStart => batch
                .schema()
                .fields()
                .iter()
                .zip(batch.columns())
                .filter(|(f, _)| is_time_column(f.name()) && schema.column(f.name()).is_some())
                .filter_map(|(_, c)| earliest_unix_s(c.as_ref()))
                .reduce(f64::min)
                .map_or(TimeOrigin::TableStart, TimeOrigin::UnixS),
            o => o.clone(),
        };
        if batch.num_rows() == 0 {
            return Err(InputError::new(
                path,
                format!(
                    "table `{}` is empty (a required table needs rows)",
                    schema.name
                ),
            ));
        }
        let mut fields = Vec::with_capacity(batch.num_columns());
        let mut columns: Vec<ArrayRef> = Vec::with_capacity(batch.num_columns());
        for (field, col) in batch.schema().fields().iter().zip(batch.columns()) {
            match schema.column(field.name()) {
                Some(spec) => {
                    check_stated_unit(path, field)?;
                    let target = match spec.kind {
                        // Keep f32 signals f32 (memory), everything else canonical.
                        ColumnKind::F32 if col.data_type() == &DataType::Float32 => {
                            DataType::Float32
                        }
                        ColumnKind::F32 => DataType::Float64,
                        k => arrow_type(k),
                    };
                    let col = normalise(path, spec.name, col, &target, &origin)?;
                    if spec.required {
                        if let Some((row, what)) = first_non_finite(col.as_ref()) {
                            return Err(InputError::new(
                                path,
                                format!("{what} in a required column"),
                            )
                            .column(spec.name)
                            .row(row));
                        }
                    } else if let Some(row) = first_nan(col.as_ref()) {
                        return Err(InputError::new(
                            path,
                            "NaN in an optional column; a value not recorded at a row is null, not NaN (pandas writes NaN as null; polars: fill_nan(None)), or leave the column out",
                        )
                        .column(spec.name)
                        .row(row));
                    }
                    fields.push(Field::new(field.name(), target, !spec.required));
                    columns.push(col);
                }
                None => {
                    fields.push(field.as_ref().clone());
                    columns.push(col.clone());
                }
            }
        }
        let batch = RecordBatch::try_new(Arc::new(Schema::new(fields)), columns)
            .map_err(|e| InputError::new(path, format!("cannot assemble table: {e}")))?;
        super::plausible::check_batch(path, schema, &batch)?;
        let table = Table {
            path: path.to_path_buf(),
            batch,
        };
        if schema.monotonic_t_s {
            if let Some(t) = table.opt_f64("t_s") {
                if let Some(row) = first_decrease(t) {
                    return Err(InputError::new(
                        path,
                        format!(
                            "t_s decreases ({} after {}); timestamps must be non-decreasing",
                            t[row],
                            t[row - 1]
                        ),
                    )
                    .column("t_s")
                    .row(row));
                }
            }
        }
        Ok(table)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
    pub fn batch(&self) -> &RecordBatch {
        &self.batch
    }
    pub fn len(&self) -> usize {
        self.batch.num_rows()
    }
    pub fn is_empty(&self) -> bool {
        self.batch.num_rows() == 0
    }
    pub fn has(&self, column: &str) -> bool {
        self.batch.column_by_name(column).is_some()
    }
    fn missing(&self, column: &str) -> InputError {
        InputError::new(&self.path, "column missing").column(column)
    }
    fn col(&self, column: &str) -> Result<&ArrayRef, InputError> {
        self.batch
            .column_by_name(column)
            .ok_or_else(|| self.missing(column))
    }

    /// A float64 column's values (contract columns are normalised to f64).
    pub fn f64(&self, column: &str) -> Result<&[f64], InputError> {
        self.col(column)?
            .as_any()
            .downcast_ref::<Float64Array>()
            .map(|a| a.values().as_ref())
            .ok_or_else(|| InputError::new(&self.path, "expected float64").column(column))
    }
    pub fn opt_f64(&self, column: &str) -> Option<&[f64]> {
        self.f64(column).ok()
    }
    pub fn f32(&self, column: &str) -> Result<&[f32], InputError> {
        self.col(column)?
            .as_any()
            .downcast_ref::<Float32Array>()
            .map(|a| a.values().as_ref())
            .ok_or_else(|| InputError::new(&self.path, "expected float32").column(column))
    }
    pub fn i32(&self, column: &str) -> Result<&[i32], InputError> {
        self.col(column)?
            .as_any()
            .downcast_ref::<Int32Array>()
            .map(|a| a.values().as_ref())
            .ok_or_else(|| InputError::new(&self.path, "expected int32").column(column))
    }
    pub fn opt_i32(&self, column: &str) -> Option<&[i32]> {
        self.i32(column).ok()
    }
    pub fn i64(&self, column: &str) -> Result<&[i64], InputError> {
        self.col(column)?
            .as_any()
            .downcast_ref::<Int64Array>()
            .map(|a| a.values().as_ref())
            .ok_or_else(|| InputError::new(&self.path, "expected int64").column(column))
    }
    pub fn i8(&self, column: &str) -> Result<&[i8], InputError> {
        self.col(column)?
            .as_any()
            .downcast_ref::<Int8Array>()
            .map(|a| a.values().as_ref())
            .ok_or_else(|| InputError::new(&self.path, "expected int8").column(column))
    }
    /// A text column as string slices.
    pub fn str(&self, column: &str) -> Result<Vec<&str>, InputError> {
        let a = self
            .col(column)?
            .as_any()
            .downcast_ref::<StringArray>()
            .ok_or_else(|| InputError::new(&self.path, "expected utf8").column(column))?;
        Ok((0..a.len()).map(|i| a.value(i)).collect())
    }
}

/// A contract column's name states its unit (`cmd_x_mm`); Parquet field
/// metadata `unit` that says otherwise is a conflict (docs/formats.md
/// "Units"), not a value to trust or ignore.
fn check_stated_unit(path: &Path, field: &Field) -> Result<(), InputError> {
    let Some(text) = field.metadata().get("unit") else {
        return Ok(());
    };
    let Some(kind) = crate::units::Unit::from_suffix(field.name()).map(|u| u.kind) else {
        return Ok(());
    };
    let stated = [crate::units::Stated {
        text: text.clone(),
        source: crate::units::Source::FieldMetadata,
    }];
    crate::units::resolve(field.name(), kind, &stated)
        .map(|_| ())
        .map_err(|e| InputError::new(path, e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn field_metadata_that_contradicts_the_name_is_refused() {
        let f = |unit: &str| {
            Field::new("z_mm", DataType::Float64, false).with_metadata(
                std::collections::HashMap::from([("unit".to_string(), unit.to_string())]),
            )
        };
        assert!(check_stated_unit(Path::new("t.parquet"), &f("mm")).is_ok());
        let e = check_stated_unit(Path::new("t.parquet"), &f("um"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("t.parquet") && e.contains("`z_mm`") && e.contains("um"),
            "{e}"
        );
    }

    /// The chunked scans find exactly the row a plain scan finds — at chunk
    /// boundaries, with NaN (a decrease only where `<` says so), and none.
    #[test]
    fn chunked_scans_agree_with_plain_ones() {
        let naive_decrease = |t: &[f64]| t.windows(2).position(|w| w[1] < w[0]).map(|i| i + 1);
        let naive_fail = |v: &[f64]| v.iter().position(|x| !x.is_finite());
        for n in [0usize, 1, 2, 511, 512, 513, 1024, 1500] {
            let base: Vec<f64> = (0..n).map(|i| i as f64 * 0.5).collect();
            assert_eq!(first_decrease(&base), None);
            assert_eq!(first_failing(&base, |x: f64| x.is_finite()), None);
            for at in [0usize, 1, 510, 511, 512, 513, 1023, 1499] {
                if at >= n {
                    continue;
                }
                let mut t = base.clone();
                t[at] = -1.0;
                assert_eq!(first_decrease(&t), naive_decrease(&t), "n {n} at {at}");
                let mut t = base.clone();
                t[at] = f64::NAN;
                assert_eq!(first_decrease(&t), naive_decrease(&t), "NaN, n {n} at {at}");
                assert_eq!(first_failing(&t, |x: f64| x.is_finite()), naive_fail(&t));
                t[at] = f64::INFINITY;
                assert_eq!(first_failing(&t, |x: f64| x.is_finite()), Some(at));
            }
        }
        let a = Float32Array::from(vec![1.0f32, 2.0, f32::NAN, f32::INFINITY]);
        assert_eq!(first_non_finite(&a), Some((2, "NaN")));
    }

    /// The fused one-pass checks the AE stream relies on accept exactly what
    /// the separate checks accept (finite, in range, non-decreasing), and
    /// the time scan's largest step is the plain one — for every corruption
    /// at every position around the lane and chunk edges.
    #[test]
    fn fused_scans_accept_what_the_separate_checks_accept() {
        let (lo, hi) = (-1e6, 1e7);
        let separate_time = |t: &[f64]| {
            t.iter().all(|&x| x.is_finite() && x >= lo && x <= hi)
                && t.windows(2).all(|w| w[1] >= w[0])
        };
        let plain_max_step = |t: &[f64]| {
            t.windows(2)
                .map(|w| w[1] - w[0])
                .fold(f64::NEG_INFINITY, f64::max)
        };
        let bad_values = [
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            -2e6,
            2e7,
            -1.0,
            1e6,
        ];
        for n in [1usize, 2, 3, 4, 5, 7, 8, 9, 13, 511, 512, 513] {
            // Uneven steps with one gap, so the largest step is one place.
            let base: Vec<f64> = (0..n)
                .map(|i| i as f64 * 1e-3 + if i >= n / 2 { 0.25 } else { 0.0 })
                .collect();
            assert_eq!(
                time_column_scan(&base, lo, hi),
                Some(plain_max_step(&base)),
                "n {n}"
            );
            for at in 0..n {
                for &bad in &bad_values {
                    let mut t = base.clone();
                    t[at] = bad;
                    let fused = time_column_scan(&t, lo, hi);
                    assert_eq!(fused.is_some(), separate_time(&t), "n {n}, t[{at}] = {bad}");
                    if let Some(m) = fused {
                        assert_eq!(m, plain_max_step(&t), "n {n}, t[{at}] = {bad}");
                    }
                }
                let v: Vec<f32> = (0..n).map(|i| (i as f32 * 0.37).sin()).collect();
                for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -100.5, 100.5] {
                    let mut w = v.clone();
                    w[at] = bad;
                    let separate = w.iter().all(|x| x.is_finite() && x.abs() <= 100.0);
                    assert_eq!(all_within(&w, -100.0, 100.0), separate, "v[{at}] = {bad}");
                }
                assert!(all_within(&v, -100.0, 100.0));
            }
        }
        assert_eq!(time_column_scan(&[], lo, hi), None);
    }
}

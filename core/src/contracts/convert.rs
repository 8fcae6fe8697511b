//! Normalising a column to its contract type, with checks (docs/formats.md,
//! "Column types"). Readers accept what other tools write — any integer or
//! float width, decimals, utf8 / large_utf8 / utf8-view / dictionary text,
//! timestamps for time columns — and convert to the contract's type; a value
//! that does not survive the conversion (an int64 beyond int32, 2.5 in an
//! integer column) is an error naming its row, never a silent null.

use std::path::Path;
use std::sync::Arc;

use arrow::array::{Array, ArrayRef, AsArray, Float64Array};
use arrow::compute::cast;
use arrow::datatypes::{DataType, Float64Type, TimeUnit};
use arrow::util::display::array_value_to_string;

use super::schema::ColumnKind;
use crate::error::InputError;

/// What a timestamp in a time column (`t_s`, `t_start_s`, …) is measured
/// from, to become seconds (the contract's time is seconds since the run's
/// start).
#[derive(Debug, Clone, PartialEq)]
pub enum TimeOrigin {
    /// The earliest timestamp of the table (a table read on its own).
    TableStart,
    /// This instant, seconds since the Unix epoch (a run's `[run].started`).
    UnixS(f64),
    /// No origin is known: timestamps are an error that says what to add
    /// (a run whose run.toml has no `started`).
    Missing,
}

/// Columns holding instants: `t_s` and `t_<name>_s` (e.g. `t_start_s`).
pub fn is_time_column(name: &str) -> bool {
    name == "t_s" || (name.starts_with("t_") && name.ends_with("_s"))
}

fn is_text(dt: &DataType) -> bool {
    match dt {
        DataType::Utf8 | DataType::LargeUtf8 | DataType::Utf8View => true,
        DataType::Dictionary(_, v) => is_text(v),
        _ => false,
    }
}

/// Whether a physical type can be converted to a logical kind.
pub fn type_accepted(kind: ColumnKind, name: &str, dt: &DataType) -> bool {
    match kind {
        ColumnKind::F64 | ColumnKind::F32 => {
            dt.is_numeric() || (is_time_column(name) && matches!(dt, DataType::Timestamp(..)))
        }
        ColumnKind::I32 | ColumnKind::I64 | ColumnKind::I8 => dt.is_integer() || dt.is_floating(),
        ColumnKind::Utf8 => is_text(dt),
    }
}

fn units_per_s(u: &TimeUnit) -> f64 {
    match u {
        TimeUnit::Second => 1.0,
        TimeUnit::Millisecond => 1e3,
        TimeUnit::Microsecond => 1e6,
        TimeUnit::Nanosecond => 1e9,
    }
}

/// Seconds since the Unix epoch of the earliest non-null timestamp.
pub fn earliest_unix_s(col: &dyn Array) -> Option<f64> {
    let DataType::Timestamp(unit, _) = col.data_type() else {
        return None;
    };
    let raw = cast(col, &DataType::Int64).ok()?;
    let v = raw.as_primitive::<arrow::datatypes::Int64Type>();
    let min = (0..v.len())
        .filter(|&i| v.is_valid(i))
        .map(|i| v.value(i))
        .min()?;
    Some(min as f64 / units_per_s(unit))
}

/// Timestamps → float64 seconds since `origin_unix_s`. The difference is
/// taken in the file's integer unit first, so nanosecond stamps keep their
/// resolution (an absolute time in f64 seconds would keep only ~0.2 µs).
fn timestamps_to_s(col: &dyn Array, unit: &TimeUnit, origin_unix_s: f64) -> ArrayRef {
    let per_s = units_per_s(unit);
    let raw = cast(col, &DataType::Int64).expect("timestamp → int64");
    let v = raw.as_primitive::<arrow::datatypes::Int64Type>();
    let o_whole = origin_unix_s.floor();
    let o_units = (o_whole as i64).saturating_mul(per_s as i64);
    let o_frac = origin_unix_s - o_whole;
    let out: Float64Array = (0..v.len())
        .map(|i| {
            v.is_valid(i)
                .then(|| (v.value(i).saturating_sub(o_units)) as f64 / per_s - o_frac)
        })
        .collect();
    Arc::new(out)
}

/// Convert `col` (contract column `name`) to `target`, checking that every
/// value survives. `origin` applies to timestamps only.
pub fn normalise(
    path: &Path,
    name: &str,
    col: &ArrayRef,
    target: &DataType,
    origin: &TimeOrigin,
) -> Result<ArrayRef, InputError> {
    let err = |msg: String| InputError::new(path, msg).column(name);
    if col.data_type() == target {
        return Ok(col.clone());
    }
    if let DataType::Timestamp(unit, _) = col.data_type() {
        let origin_s = match origin {
            TimeOrigin::UnixS(t0) => *t0,
            TimeOrigin::TableStart => earliest_unix_s(col.as_ref()).unwrap_or(0.0),
            TimeOrigin::Missing => {
                return Err(err(format!(
                    "holds timestamps ({}); give [run].started in run.toml (a date-time such as 2026-11-20T08:00:00Z) so they can be turned into seconds since the run's start (docs/formats.md, run.toml)",
                    col.data_type()
                )))
            }
        };
        let s = timestamps_to_s(col.as_ref(), unit, origin_s);
        return cast(&s, target).map_err(|e| err(format!("cannot convert to {target}: {e}")));
    }
    let converted =
        cast(col, target).map_err(|e| err(format!("cannot convert to {target}: {e}")))?;
    if target.is_integer() && col.data_type().is_floating() {
        // Integer columns written as floats (pandas does this to an int
        // column with a missing value): each value must be a whole number.
        let f = cast(col, &DataType::Float64).expect("float → float64");
        let f = f.as_primitive::<Float64Type>();
        for i in 0..f.len() {
            let v = f.value(i);
            if f.is_valid(i) && (v.fract() != 0.0 || converted.is_null(i)) {
                return Err(err(format!(
                    "value {v} is not a whole number that fits in {target} (an integer column)"
                ))
                .row(i));
            }
        }
    } else if converted.null_count() != col.null_count() {
        // A safe cast turns values that do not fit into nulls: name the first.
        if let Some(i) = (0..col.len()).find(|&i| col.is_valid(i) && converted.is_null(i)) {
            let v = array_value_to_string(col.as_ref(), i).unwrap_or_default();
            return Err(err(format!(
                "value {v} does not fit in {target} (the contract type)"
            ))
            .row(i));
        }
    }
    Ok(converted)
}

/// Days since 1970-01-01 of a civil (proleptic Gregorian) date — H.
/// Hinnant's days_from_civil.
pub fn days_from_civil(y: i64, m: i64, d: i64) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (m + 9) % 12;
    let doy = (153 * mp + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// The civil date (year, month, day) of a day count since 1970-01-01: the
/// inverse of [`days_from_civil`].
pub fn civil_from_days(z: i64) -> (i64, i64, i64) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + if m <= 2 { 1 } else { 0 };
    (y, m, d)
}

/// `YYYY-MM-DD[T ]HH:MM:SS[.frac][Z|±HH:MM]` (RFC 3339 / TOML datetime;
/// a local time without offset is taken as UTC) → seconds since the epoch.
pub fn parse_datetime_unix_s(s: &str) -> Option<f64> {
    let s = s.trim().trim_matches('"');
    let (date, rest) = s.split_at_checked(10)?;
    let mut d = date.split('-');
    let (y, m, day): (i64, i64, i64) = (
        d.next()?.parse().ok()?,
        d.next()?.parse().ok()?,
        d.next()?.parse().ok()?,
    );
    if !(1..=12).contains(&m) || !(1..=31).contains(&day) {
        return None;
    }
    let mut secs = days_from_civil(y, m, day) as f64 * 86_400.0;
    if rest.is_empty() {
        return Some(secs);
    }
    let rest = rest.strip_prefix(['T', 't', ' '])?;
    let (clock, offset) = match rest.find(['Z', 'z', '+', '-']) {
        Some(i) => rest.split_at(i),
        None => (rest, ""),
    };
    let mut c = clock.split(':');
    let h: f64 = c.next()?.parse().ok()?;
    let mi: f64 = c.next()?.parse().ok()?;
    let sec: f64 = c.next().map(|v| v.parse().ok()).unwrap_or(Some(0.0))?;
    secs += h * 3600.0 + mi * 60.0 + sec;
    if let Some(o) = offset.strip_prefix(['+', '-']) {
        let sign = if offset.starts_with('-') { -1.0 } else { 1.0 };
        let (oh, om) = o.split_once(':')?;
        let o_s = oh.parse::<f64>().ok()? * 3600.0 + om.parse::<f64>().ok()? * 60.0;
        // 08:00+02:00 is 06:00 UTC.
        secs -= sign * o_s;
    }
    Some(secs)
}

#[cfg(test)]
mod tests {
    use super::*;
    use arrow::array::{Float32Array, Int64Array, StringArray, TimestampMicrosecondArray};

    #[test]
    fn datetimes_parse_to_unix_seconds() {
        assert_eq!(parse_datetime_unix_s("1970-01-01T00:00:00Z"), Some(0.0));
        // python: datetime(2026, 11, 20, 8, tzinfo=timezone.utc).timestamp()
        assert_eq!(
            parse_datetime_unix_s("2026-11-20T08:00:00Z"),
            Some(1_795_161_600.0)
        );
        assert_eq!(
            parse_datetime_unix_s("2026-11-20 08:00:00.25"),
            Some(1_795_161_600.25)
        );
        assert_eq!(
            parse_datetime_unix_s("2026-11-20T10:00:00+02:00"),
            parse_datetime_unix_s("2026-11-20T08:00:00Z")
        );
        assert_eq!(parse_datetime_unix_s("2000-03-01"), Some(951_868_800.0));
        assert_eq!(parse_datetime_unix_s("2000-13-01"), None);
    }

    #[test]
    fn narrowing_and_float_to_int_are_checked() {
        let p = Path::new("t.parquet");
        let o = TimeOrigin::TableStart;
        let big: ArrayRef = Arc::new(Int64Array::from(vec![1, 2, 1 << 40]));
        let e = normalise(p, "point", &big, &DataType::Int32, &o).unwrap_err();
        assert_eq!((e.column.as_deref(), e.row), (Some("point"), Some(2)));
        let half: ArrayRef = Arc::new(Float32Array::from(vec![1.0, 2.5]));
        let e = normalise(p, "point", &half, &DataType::Int32, &o).unwrap_err();
        assert_eq!(e.row, Some(1));
        let whole: ArrayRef = Arc::new(Float32Array::from(vec![1.0, -2.0]));
        let a = normalise(p, "point", &whole, &DataType::Int32, &o).unwrap();
        assert_eq!(
            a.as_primitive::<arrow::datatypes::Int32Type>().values(),
            &[1, -2]
        );
        let s: ArrayRef = Arc::new(StringArray::from(vec!["a"]));
        assert!(!type_accepted(ColumnKind::F64, "x_mm", s.data_type()));
    }

    #[test]
    fn timestamps_become_seconds_since_the_origin() {
        let p = Path::new("t.parquet");
        let t0 = parse_datetime_unix_s("2026-11-20T08:00:00Z").unwrap();
        let us = (t0 as i64) * 1_000_000;
        let ts: ArrayRef = Arc::new(TimestampMicrosecondArray::from(vec![
            us + 1_500_000,
            us + 2_000_001,
        ]));
        let a = normalise(p, "t_s", &ts, &DataType::Float64, &TimeOrigin::UnixS(t0)).unwrap();
        let v = a.as_primitive::<Float64Type>().values();
        assert_eq!(v[0], 1.5);
        assert!((v[1] - 2.000001).abs() < 1e-12);
        let a = normalise(p, "t_s", &ts, &DataType::Float64, &TimeOrigin::TableStart).unwrap();
        assert_eq!(a.as_primitive::<Float64Type>().value(0), 0.0);
        let e = normalise(p, "t_s", &ts, &DataType::Float64, &TimeOrigin::Missing).unwrap_err();
        assert!(e.message.contains("started"), "{e}");
        assert!(type_accepted(ColumnKind::F64, "t_s", ts.data_type()));
        assert!(!type_accepted(ColumnKind::F64, "x_mm", ts.data_type()));
    }
}

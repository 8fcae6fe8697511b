//! Plausibility, not just finiteness: every contract column has a range its
//! unit makes plausible on a grinding/polishing machine, and a value outside
//! it rejects the run with the likely cause (a wrong unit, usually). A finite
//! 1e300 passes a NaN check and then turns every downstream sum into inf;
//! metres where the contract says mm pass every check and give a wrong
//! answer. The ranges are documented in docs/formats.md ("Plausible ranges");
//! a test checks the two agree.

use arrow::array::{Array, Float32Array, Float64Array, Int32Array, Int64Array, Int8Array};

use super::schema::{TableRegistry, TableSchema};
use super::table::first_failing;
use crate::error::InputError;

/// A plausible interval for a column, and what a value beyond each end most
/// likely means.
#[derive(Debug, Clone, Copy)]
pub struct Range {
    pub lo: f64,
    pub hi: f64,
    pub unit: &'static str,
    /// Why a value below `lo` is probably there.
    pub below: &'static str,
    /// Why a value above `hi` is probably there.
    pub above: &'static str,
}

/// Lengths: the largest machine of the contract (a gantry bed) is a few
/// metres and a guide-way trace tens of metres; 1 km is implausible in any
/// of them, while a few metres written in µm (10⁶ and more) is caught.
pub const LENGTH: Range = Range {
    lo: -1e6,
    hi: 1e6,
    unit: "mm",
    below: "values look like µm or nm (divide by 1000 or 10⁶) or encoder counts",
    above: "values look like µm or nm (divide by 1000 or 10⁶) or encoder counts",
};
/// A measured deviation from nominal (probe readings, surface heights).
pub const DEVIATION: Range = Range {
    lo: -100.0,
    hi: 100.0,
    unit: "mm",
    below: "a deviation beyond 100 mm: values look like µm (divide by 1000)",
    above: "a deviation beyond 100 mm: values look like µm (divide by 1000)",
};
pub const TIME: Range = Range {
    lo: -1e6,
    hi: 1e7,
    unit: "s",
    below: "t_s is seconds since the run's start (docs/formats.md); values look like ms, µs or an absolute (epoch) time",
    above: "t_s is seconds since the run's start (docs/formats.md); values look like ms, µs or an absolute (epoch) time — subtract the start and convert to s",
};
pub const SPEED: Range = Range {
    lo: 0.0,
    hi: 1e5,
    unit: "mm/s",
    below: "a speed cannot be negative",
    above: "values look like mm/min (divide by 60) or µm/s (divide by 1000)",
};
/// A signed axis velocity (motion v1.1 `cmd_v_<axis>_mm_s`, `act_v_…`).
pub const AXIS_VELOCITY: Range = Range {
    lo: -1e5,
    hi: 1e5,
    unit: "mm/s",
    below: "values look like mm/min (divide by 60) or µm/s (divide by 1000)",
    above: "values look like mm/min (divide by 60) or µm/s (divide by 1000)",
};
/// A signed axis acceleration (motion v1.1 `cmd_a_<axis>_mm_s2`, `act_a_…`):
/// machine tools reach tens of m/s², 10⁷ mm/s² (1 000 g) is implausible.
pub const AXIS_ACCELERATION: Range = Range {
    lo: -1e7,
    hi: 1e7,
    unit: "mm/s²",
    below: "values look like µm/s² (divide by 1000) or a wrong column",
    above: "values look like µm/s² (divide by 1000) or a wrong column",
};
pub const TEMPERATURE: Range = Range {
    lo: -60.0,
    hi: 200.0,
    unit: "°C",
    below: "values look like a sensor fault code",
    above: "values look like kelvin (subtract 273.15) or °F",
};
pub const UNIT_VECTOR: Range = Range {
    lo: -1.000_001,
    hi: 1.000_001,
    unit: "",
    below: "a unit direction has components in [−1, 1]: normalise it",
    above: "a unit direction has components in [−1, 1]: normalise it",
};
pub const ANGLE: Range = Range {
    lo: -std::f64::consts::TAU - 1e-6,
    hi: std::f64::consts::TAU + 1e-6,
    unit: "rad",
    below: "values look like degrees: multiply by π/180 (0.0174533)",
    above: "values look like degrees: multiply by π/180 (0.0174533)",
};
pub const RADIUS: Range = Range {
    lo: 0.0,
    hi: 1e4,
    unit: "mm",
    below: "a radius cannot be negative",
    above: "values look like µm (divide by 1000)",
};
pub const COUNT: Range = Range {
    lo: 0.0,
    hi: 2.0e9,
    unit: "",
    below: "an id or index is never negative",
    above: "an id or index this large looks like a wrong column",
};
pub const DIRECTION: Range = Range {
    lo: -1.0,
    hi: 1.0,
    unit: "",
    below: "dir is +1 or −1",
    above: "dir is +1 or −1",
};
pub const AE_VOLTS: Range = Range {
    lo: -100.0,
    hi: 100.0,
    unit: "V",
    below: "values look like millivolts or raw ADC counts: convert to volts",
    above: "values look like millivolts or raw ADC counts: convert to volts",
};
pub const DEPTH_OF_CUT: Range = Range {
    lo: 0.0,
    hi: 50.0,
    unit: "mm",
    below: "a programmed depth of cut is ≥ 0 (0 for spark-out)",
    above: "values look like µm (divide by 1000)",
};
pub const SEGMENT: Range = Range {
    lo: -1.0,
    hi: 2.0e9,
    unit: "",
    below: "segment is a plan seq or −1 when none",
    above: "an id this large looks like a wrong column",
};
pub const PASS: Range = Range {
    lo: 1.0,
    hi: 1e6,
    unit: "",
    below: "passes are numbered from 1",
    above: "a pass number this large looks like a wrong column",
};

/// The range for a column of a unit-suffixed name (docs/formats.md
/// "Conventions": the unit is in the name).
pub fn range_by_suffix(column: &str) -> Option<Range> {
    if column.ends_with("_mm_s2") {
        Some(AXIS_ACCELERATION)
    } else if column.ends_with("_mm_s")
        && (column.starts_with("cmd_v_") || column.starts_with("act_v_"))
    {
        Some(AXIS_VELOCITY)
    } else if column.ends_with("_mm_s") {
        Some(SPEED)
    } else if column.ends_with("_mm") {
        Some(LENGTH)
    } else if column.ends_with("_s") {
        Some(TIME)
    } else if column.ends_with("_c") {
        Some(TEMPERATURE)
    } else if column == "point" || column == "trial" {
        Some(COUNT)
    } else {
        None
    }
}

/// The plausible range of a table's column: the table's own
/// ([`TableSchema::ranges`]), else its unit suffix's.
pub fn range_for(table: &TableSchema, column: &str) -> Option<Range> {
    table
        .ranges
        .iter()
        .find(|(c, _)| *c == column)
        .map(|(_, r)| *r)
        .or_else(|| range_by_suffix(column))
}

/// Every (table, column, range) of the registered tables, for the docs
/// and tests.
pub fn all_ranges(tables: &TableRegistry) -> Vec<(&'static str, &'static str, Range)> {
    tables
        .iter()
        .flat_map(|t| {
            t.columns
                .iter()
                .filter_map(move |c| range_for(t, c.name).map(|r| (t.name, c.name, r)))
        })
        .collect()
}

/// Whole-column magnitudes a wrong unit gives away even when every value is
/// in range: a robot program, a guideway travel or a form profile spans tens
/// to thousands of mm; all of its positions within ±`max_abs_below` mm is
/// what metres look like.
#[derive(Debug, Clone, Copy)]
pub struct MetresRule {
    pub columns: &'static [&'static str],
    pub max_abs_below: f64,
}

fn values(col: &dyn Array) -> Option<Box<dyn Iterator<Item = (usize, f64)> + '_>> {
    let any = col.as_any();
    macro_rules! iter {
        ($t:ty) => {
            if let Some(a) = any.downcast_ref::<$t>() {
                return Some(Box::new(
                    (0..a.len())
                        .filter(move |&i| !a.is_null(i))
                        .map(move |i| (i, a.value(i) as f64)),
                ));
            }
        };
    }
    iter!(Float64Array);
    iter!(Float32Array);
    iter!(Int64Array);
    iter!(Int32Array);
    iter!(Int8Array);
    None
}

/// The first value of a column outside its range, as the error the user
/// reads: file, column, row, value, range and the likely cause. `row0` is the
/// row of the column's first value within the file (streamed tables).
pub fn check_column(
    path: &std::path::Path,
    table: &TableSchema,
    column: &str,
    col: &dyn Array,
    row0: usize,
) -> Result<(), InputError> {
    let Some(r) = range_for(table, column) else {
        return Ok(());
    };
    // NaN is the finite check's to report, not this one's.
    let in_range = |v: f64| v.is_nan() | ((v >= r.lo) & (v <= r.hi));
    let any = col.as_any();
    let bad = if col.null_count() > 0 {
        values(col).and_then(|mut it| it.find(|(_, v)| !in_range(*v)))
    } else if let Some(a) = any.downcast_ref::<Float64Array>() {
        first_failing(a.values(), in_range).map(|i| (i, a.value(i)))
    } else if let Some(a) = any.downcast_ref::<Float32Array>() {
        first_failing(a.values(), |v| in_range(v as f64)).map(|i| (i, a.value(i) as f64))
    } else {
        values(col).and_then(|mut it| it.find(|(_, v)| !in_range(*v)))
    };
    if let Some((i, v)) = bad {
        let why = if v < r.lo { r.below } else { r.above };
        return Err(InputError::new(
            path,
            format!(
                "implausible value {v} (plausible for `{column}`: {} to {}{}{}); {why}",
                r.lo,
                r.hi,
                if r.unit.is_empty() { "" } else { " " },
                r.unit
            ),
        )
        .column(column)
        .row(row0 + i));
    }
    Ok(())
}

/// Every contract column of an in-memory table against its range, then the
/// table's metres rules.
pub fn check_batch(
    path: &std::path::Path,
    schema: &TableSchema,
    batch: &arrow::record_batch::RecordBatch,
) -> Result<(), InputError> {
    for spec in schema.columns {
        if let Some(col) = batch.column_by_name(spec.name) {
            check_column(path, schema, spec.name, col.as_ref(), 0)?;
        }
    }
    for rule in schema.metres_rule.iter() {
        let mut max_abs = 0.0f64;
        let mut present = false;
        for c in rule.columns {
            if let Some(it) = batch.column_by_name(c).and_then(|c| values(c.as_ref())) {
                present = true;
                max_abs = it.fold(max_abs, |m, (_, v)| m.max(v.abs()));
            }
        }
        if present && batch.num_rows() > 1 && max_abs > 0.0 && max_abs < rule.max_abs_below {
            return Err(InputError::new(
                path,
                format!(
                    "every value of {} lies within ±{} mm (largest |value| {max_abs}): values look like metres — multiply by 1000 (the contract's lengths are in mm)",
                    rule.columns.join(", "),
                    rule.max_abs_below
                ),
            )
            .column(rule.columns[0]));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_length_time_speed_column_has_a_range() {
        for t in TableRegistry::shared().iter() {
            for c in t.columns {
                let numeric_text =
                    matches!(c.name, "face" | "method" | "state" | "stage" | "sensor");
                if !numeric_text {
                    assert!(
                        range_for(t, c.name).is_some(),
                        "{}.{} has no plausible range",
                        t.name,
                        c.name
                    );
                }
            }
        }
    }

    #[test]
    fn ranges_are_documented() {
        // Read at run time, not `include_str!`: the docs live outside this
        // crate, so a packaged crate could not build its tests otherwise.
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/validation.md");
        let doc = std::fs::read_to_string(path).unwrap();
        let doc = doc.as_str();
        for (t, c, r) in all_ranges(&TableRegistry::shared()) {
            let row = format!("| {t} | {c} | {} | {} |", r.lo, r.hi);
            assert!(
                doc.contains(&row),
                "docs/validation.md lacks the row `{row}`"
            );
        }
    }
}

//! The guide-way's own table (docs/formats.md §4): three-probe readings
//! along the way. Registered with the engine through `MachinePlugin::tables`.

use sparkout_pipeline::contracts::plausible::{MetresRule, COUNT, DEVIATION, DIRECTION};
use sparkout_pipeline::contracts::schema::{opt, req, ColumnKind::*, TableSchema};

pub const GUIDEWAY: TableSchema = TableSchema {
    name: "guideway",
    columns: &[
        req("n", I64),
        req("x_mm", F64),
        req("za_mm", F64),
        req("zb_mm", F64),
        req("zc_mm", F64),
        opt("dir", I8),
        opt("t_s", F64),
        opt("temp_c", F64),
    ],
    monotonic_t_s: true,
    ranges: &[
        ("n", COUNT),
        ("za_mm", DEVIATION),
        ("zb_mm", DEVIATION),
        ("zc_mm", DEVIATION),
        ("dir", DIRECTION),
    ],
    metres_rule: Some(MetresRule {
        columns: &["x_mm"],
        max_abs_below: 2.5,
    }),
};

/// The guide-way's tables.
pub const TABLES: &[TableSchema] = &[GUIDEWAY];

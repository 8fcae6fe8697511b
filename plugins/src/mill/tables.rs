//! The mill's own table (docs/formats.md §4): laser-tracker points, nominal
//! and measured. Registered with the engine through `MachinePlugin::tables`.

use sparkout_pipeline::contracts::plausible::MetresRule;
use sparkout_pipeline::contracts::schema::{opt, req, ColumnKind::*, TableSchema};

pub const TRACKER: TableSchema = TableSchema {
    name: "tracker",
    columns: &[
        req("point", I32),
        req("x_mm", F64),
        req("y_mm", F64),
        req("z_mm", F64),
        req("mx_mm", F64),
        req("my_mm", F64),
        req("mz_mm", F64),
        opt("t_s", F64),
    ],
    monotonic_t_s: true,
    ranges: &[],
    metres_rule: Some(MetresRule {
        columns: &["x_mm", "y_mm", "z_mm"],
        max_abs_below: 2.5,
    }),
};

/// The mill's tables.
pub const TABLES: &[TableSchema] = &[TRACKER];

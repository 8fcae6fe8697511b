//! The gantry's own table (docs/formats.md §4): surface topography per
//! state. Registered with the engine through `MachinePlugin::tables`.

use sparkout_pipeline::contracts::plausible::DEVIATION;
use sparkout_pipeline::contracts::schema::{opt, req, ColumnKind::*, TableSchema};

pub const TOPOGRAPHY: TableSchema = TableSchema {
    name: "topography",
    columns: &[
        req("state", Utf8),
        req("x_mm", F64),
        req("y_mm", F64),
        req("z_mm", F64),
        opt("t_s", F64),
    ],
    monotonic_t_s: false,
    ranges: &[("z_mm", DEVIATION)],
    metres_rule: None,
};

/// The gantry's tables.
pub const TABLES: &[TableSchema] = &[TOPOGRAPHY];

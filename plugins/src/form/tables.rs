//! The form grinder's own table (docs/formats.md §4): the workpiece profile
//! in polar form. Registered with the engine through `MachinePlugin::tables`.

use sparkout_pipeline::contracts::plausible::{MetresRule, ANGLE, RADIUS};
use sparkout_pipeline::contracts::schema::{opt, req, ColumnKind::*, TableSchema};

pub const PROFILE: TableSchema = TableSchema {
    name: "profile",
    columns: &[
        req("state", Utf8),
        req("phi_rad", F64),
        req("r_mm", F64),
        opt("wheel_radius_mm", F64),
    ],
    monotonic_t_s: false,
    ranges: &[
        ("phi_rad", ANGLE),
        ("r_mm", RADIUS),
        ("wheel_radius_mm", RADIUS),
    ],
    metres_rule: Some(MetresRule {
        columns: &["r_mm"],
        max_abs_below: 1.0,
    }),
};

/// The form grinder's tables.
pub const TABLES: &[TableSchema] = &[PROFILE];

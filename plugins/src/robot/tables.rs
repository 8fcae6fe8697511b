//! The robot cell's own tables (docs/formats.md §4): touch probes, the
//! planned approaches and the grinding passes. Registered with the engine
//! through `MachinePlugin::tables`; the AE and motion logs are shared.

use sparkout_pipeline::contracts::plausible::{MetresRule, COUNT, DEPTH_OF_CUT, PASS, UNIT_VECTOR};
use sparkout_pipeline::contracts::schema::{opt, req, ColumnKind::*, TableSchema};

/// The columns that name one probing point (face, point, trial, method,
/// approach speed, nominal position), shared by probe.parquet (a touch)
/// and plan.parquet (a planned approach), between their own columns.
macro_rules! probing_point_columns {
    ([$($before:expr),*], [$($after:expr),*]) => {
        &[
            $($before,)*
            req("face", Utf8),
            req("point", I32),
            req("trial", I32),
            req("method", Utf8),
            req("approach_mm_s", F64),
            req("nom_x_mm", F64),
            req("nom_y_mm", F64),
            req("nom_z_mm", F64),
            $($after,)*
        ]
    };
}

pub const PROBE: TableSchema = TableSchema {
    name: "probe",
    columns: probing_point_columns!(
        [req("t_s", F64)],
        [req("x_mm", F64), req("y_mm", F64), req("z_mm", F64)]
    ),
    monotonic_t_s: true,
    ranges: &[],
    metres_rule: Some(MetresRule {
        columns: &["nom_x_mm", "nom_y_mm", "nom_z_mm"],
        max_abs_below: 2.5,
    }),
};

pub const PLAN: TableSchema = TableSchema {
    name: "plan",
    columns: probing_point_columns!(
        [req("seq", I32)],
        [req("dir_x", F64), req("dir_y", F64), req("dir_z", F64)]
    ),
    monotonic_t_s: false,
    ranges: &[
        ("seq", COUNT),
        ("dir_x", UNIT_VECTOR),
        ("dir_y", UNIT_VECTOR),
        ("dir_z", UNIT_VECTOR),
    ],
    metres_rule: Some(MetresRule {
        columns: &["nom_x_mm", "nom_y_mm", "nom_z_mm"],
        max_abs_below: 2.5,
    }),
};

pub const PASSES: TableSchema = TableSchema {
    name: "passes",
    columns: &[
        req("pass", I32),
        req("stage", Utf8),
        req("nominal_doc_mm", F64),
        req("feed_mm_s", F64),
        req("height_before_mm", F64),
        req("height_after_mm", F64),
        opt("t_start_s", F64),
        opt("t_end_s", F64),
    ],
    monotonic_t_s: false,
    ranges: &[("pass", PASS), ("nominal_doc_mm", DEPTH_OF_CUT)],
    metres_rule: None,
};

/// The robot cell's tables, in registration order.
pub const TABLES: &[TableSchema] = &[PROBE, PLAN, PASSES];

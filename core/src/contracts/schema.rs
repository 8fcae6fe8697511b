//! The v1 table schemas of docs/formats.md §4, as data: one place that says which
//! columns each table has, their types and whether they are required.

/// Logical column type. Readers accept wider physical types where the
/// contract allows (float32 for float64, any integer width for integers,
/// utf8 or large_utf8 for text) and normalise to this type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColumnKind {
    F64,
    F32,
    I32,
    I64,
    I8,
    Utf8,
}

impl ColumnKind {
    pub fn label(self) -> &'static str {
        match self {
            ColumnKind::F64 => "float64",
            ColumnKind::F32 => "float32",
            ColumnKind::I32 => "int32",
            ColumnKind::I64 => "int64",
            ColumnKind::I8 => "int8",
            ColumnKind::Utf8 => "utf8",
        }
    }
}

#[derive(Debug, Clone, Copy)]
pub struct ColumnSpec {
    pub name: &'static str,
    pub kind: ColumnKind,
    pub required: bool,
}

const fn req(name: &'static str, kind: ColumnKind) -> ColumnSpec {
    ColumnSpec {
        name,
        kind,
        required: true,
    }
}
const fn opt(name: &'static str, kind: ColumnKind) -> ColumnSpec {
    ColumnSpec {
        name,
        kind,
        required: false,
    }
}

/// One v1 table: its file stem, columns and whether `t_s` must be monotonic.
#[derive(Debug, Clone, Copy)]
pub struct TableSchema {
    pub name: &'static str,
    pub columns: &'static [ColumnSpec],
    /// docs/formats.md: `t_s` is monotonic non-decreasing within a table — for
    /// the time-series tables. Tables keyed by state (topography) or by
    /// probe point may be measured in any order and are not checked.
    pub monotonic_t_s: bool,
}

impl TableSchema {
    pub fn file_name(&self) -> String {
        format!("{}.parquet", self.name)
    }
    pub fn column(&self, name: &str) -> Option<&ColumnSpec> {
        self.columns.iter().find(|c| c.name == name)
    }
}

use ColumnKind::*;

pub const AE: TableSchema = TableSchema {
    name: "ae",
    columns: &[req("t_s", F64), req("ae_v", F32)],
    monotonic_t_s: true,
};

pub const MOTION: TableSchema = TableSchema {
    name: "motion",
    columns: &[
        req("t_s", F64),
        req("cmd_x_mm", F64),
        req("cmd_y_mm", F64),
        req("cmd_z_mm", F64),
        opt("act_x_mm", F64),
        opt("act_y_mm", F64),
        opt("act_z_mm", F64),
        opt("feed_mm_s", F64),
        opt("segment", I32),
        // v1.1 (servo traces, docs/servo.md): per-axis velocity and
        // acceleration where the controller logs them.
        opt("cmd_v_x_mm_s", F64),
        opt("cmd_v_y_mm_s", F64),
        opt("cmd_v_z_mm_s", F64),
        opt("act_v_x_mm_s", F64),
        opt("act_v_y_mm_s", F64),
        opt("act_v_z_mm_s", F64),
        opt("cmd_a_x_mm_s2", F64),
        opt("cmd_a_y_mm_s2", F64),
        opt("cmd_a_z_mm_s2", F64),
        opt("act_a_x_mm_s2", F64),
        opt("act_a_y_mm_s2", F64),
        opt("act_a_z_mm_s2", F64),
    ],
    monotonic_t_s: true,
};

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
};

pub const PLAN: TableSchema = TableSchema {
    name: "plan",
    columns: probing_point_columns!(
        [req("seq", I32)],
        [req("dir_x", F64), req("dir_y", F64), req("dir_z", F64)]
    ),
    monotonic_t_s: false,
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
};

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
};

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
};

pub const PROFILE: TableSchema = TableSchema {
    name: "profile",
    columns: &[
        req("state", Utf8),
        req("phi_rad", F64),
        req("r_mm", F64),
        opt("wheel_radius_mm", F64),
    ],
    monotonic_t_s: false,
};

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
};

pub const THERMAL: TableSchema = TableSchema {
    name: "thermal",
    columns: &[req("t_s", F64), req("sensor", Utf8), req("temp_c", F64)],
    monotonic_t_s: true,
};

/// Every v1 recorded-run table.
pub const ALL_TABLES: &[TableSchema] = &[
    AE, MOTION, PROBE, PLAN, PASSES, TOPOGRAPHY, GUIDEWAY, PROFILE, TRACKER, THERMAL,
];

pub fn table_schema(name: &str) -> Option<&'static TableSchema> {
    ALL_TABLES.iter().find(|t| t.name == name)
}

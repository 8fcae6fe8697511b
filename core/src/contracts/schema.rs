//! Table schemas as data (docs/formats.md §4): which columns a table has,
//! their types, whether they are required and what values are plausible.
//!
//! The tables any machine may record — the AE log, the motion log, the
//! thermal log — are declared here; a machine type's own tables (the robot's
//! probe points, the gantry's topography, …) are declared by the plugin that
//! owns them ([`crate::traits::MachinePlugin::tables`]) and registered with
//! the engine in a [`TableRegistry`], so nothing below the plugins names a
//! machine's table.

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

/// A required column.
pub const fn req(name: &'static str, kind: ColumnKind) -> ColumnSpec {
    ColumnSpec {
        name,
        kind,
        required: true,
    }
}
/// An optional column.
pub const fn opt(name: &'static str, kind: ColumnKind) -> ColumnSpec {
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
    /// Plausible ranges of columns the unit suffix rule does not cover, or
    /// covers too loosely (docs/validation.md; `plausible::range_for`).
    pub ranges: &'static [(&'static str, Range)],
    /// Positions whose whole-column magnitude gives metres away
    /// (`plausible::MetresRule`).
    pub metres_rule: Option<MetresRule>,
}

impl TableSchema {
    pub fn file_name(&self) -> String {
        format!("{}.parquet", self.name)
    }
    pub fn column(&self, name: &str) -> Option<&ColumnSpec> {
        self.columns.iter().find(|c| c.name == name)
    }
}

use super::plausible::{MetresRule, Range, AE_VOLTS, SEGMENT};
use ColumnKind::*;

pub const AE: TableSchema = TableSchema {
    name: "ae",
    columns: &[req("t_s", F64), req("ae_v", F32)],
    monotonic_t_s: true,
    ranges: &[("ae_v", AE_VOLTS)],
    metres_rule: None,
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
    ranges: &[("segment", SEGMENT)],
    metres_rule: Some(MetresRule {
        columns: &["cmd_x_mm", "cmd_y_mm", "cmd_z_mm"],
        max_abs_below: 2.5,
    }),
};

pub const THERMAL: TableSchema = TableSchema {
    name: "thermal",
    columns: &[req("t_s", F64), req("sensor", Utf8), req("temp_c", F64)],
    monotonic_t_s: true,
    ranges: &[],
    metres_rule: None,
};

/// The tables any machine may record, declared here; a plugin's own come
/// from [`crate::traits::MachinePlugin::tables`].
pub const SHARED_TABLES: &[TableSchema] = &[AE, MOTION, THERMAL];

/// The tables a batch knows: the shared ones and every registered plugin's.
/// Two tables of one name are refused at registration (a file name means
/// one schema).
#[derive(Debug, Clone)]
pub struct TableRegistry {
    tables: Vec<&'static TableSchema>,
}

/// Two registries are equal when they know the same tables in the same
/// order (a table name is one schema).
impl PartialEq for TableRegistry {
    fn eq(&self, other: &Self) -> bool {
        self.names() == other.names()
    }
}

impl Default for TableRegistry {
    fn default() -> Self {
        TableRegistry::shared()
    }
}

impl TableRegistry {
    /// The shared tables alone.
    pub fn shared() -> TableRegistry {
        TableRegistry {
            tables: SHARED_TABLES.iter().collect(),
        }
    }
    /// Adds `owner`'s tables; an error names a table declared twice.
    pub fn register(&mut self, owner: &str, tables: &'static [TableSchema]) -> crate::Result<()> {
        for t in tables {
            if self.get(t.name).is_some() {
                crate::bail!(
                    "{owner} declares table `{}`, which is already declared (a table name is one schema: rename the plugin's table)",
                    t.name
                );
            }
            self.tables.push(t);
        }
        Ok(())
    }
    /// The shared tables and each owner's, registered in order.
    pub fn of<'a>(
        owners: impl IntoIterator<Item = (&'a str, &'static [TableSchema])>,
    ) -> crate::Result<TableRegistry> {
        let mut r = TableRegistry::shared();
        for (owner, tables) in owners {
            r.register(owner, tables)?;
        }
        Ok(r)
    }
    pub fn get(&self, name: &str) -> Option<&'static TableSchema> {
        self.tables.iter().copied().find(|t| t.name == name)
    }
    pub fn iter(&self) -> impl Iterator<Item = &'static TableSchema> + '_ {
        self.tables.iter().copied()
    }
    pub fn names(&self) -> Vec<&'static str> {
        self.tables.iter().map(|t| t.name).collect()
    }
}

//! Data contracts v1 (docs/formats.md): schemas, validated readers, atomic
//! writers, run.toml and machine configs.

pub mod ae_stream;
pub mod batch;
pub mod config_keys;
pub mod convert;
pub mod input_file;
pub mod motion;
pub mod parquet_file;
pub mod plausible;
pub mod run;
pub mod schema;
pub mod table;
pub mod tolerance;

// Output files (atomic writes, safe names) sit below the contracts, in
// `crate::files`, so object storage can use them without the contracts.
pub use crate::files::{names, write};
pub use ae_stream::{AeChunk, AeStream};
pub use batch::{
    batch_f64, batch_i32, batch_str, column_names, numeric_column, read_parquet, BatchBuilder,
};
pub use convert::TimeOrigin;
pub use motion::MotionColumns;
pub use parquet_file::open_parquet;
pub use run::{
    discover, discover_runs, AeKind, AeSpec, Discovery, MachineConfig, MachineResolver, RunSpec,
    Skipped,
};
pub use schema::{ColumnKind, ColumnSpec, TableRegistry, TableSchema, SHARED_TABLES};
pub use table::Table;
pub use write::{
    remove_orphaned_temps, write_atomic, write_json_atomic, write_parquet_atomic,
    write_parquet_batches_atomic,
};

//! Data contracts v1 (CONTRACTS.md): schemas, validated readers, atomic
//! writers, run.toml and machine configs.

pub mod ae_stream;
pub mod batch;
pub mod motion;
pub mod run;
pub mod schema;
pub mod table;
pub mod write;

pub use ae_stream::{AeChunk, AeStream};
pub use batch::{batch_f64, batch_i32, batch_str, read_parquet, BatchBuilder};
pub use motion::MotionColumns;
pub use run::{discover_runs, AeKind, AeSpec, MachineConfig, MachineResolver, RunSpec};
pub use schema::{table_schema, ColumnKind, ColumnSpec, TableSchema, ALL_TABLES};
pub use table::Table;
pub use write::{
    write_atomic, write_json_atomic, write_parquet_atomic, write_parquet_batches_atomic,
};

//! Files sparkout writes: atomic writes (a reader never sees half a file)
//! and names checked before they become paths (docs/formats.md "Names").
//! Below the contracts and object storage, which both write through it.

pub mod json;
pub mod names;
pub mod write;

/// The per-run cache file in a run's output directory: what the stages
/// computed and the key they computed it for.
pub const RUN_CACHE_FILE: &str = ".sparkout-cache.json";

/// A run's paired observations (its `observe` stage's artifact) and the
/// fleet's, joined (docs/formats.md §7).
pub const OBSERVATIONS_FILE: &str = "observations.parquet";

/// The lock file that holds an output directory for one batch.
pub const LOCK_FILE: &str = ".sparkout.lock";

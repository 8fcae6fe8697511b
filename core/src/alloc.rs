//! The allocator's trade-off for a batch processor. glibc's malloc hands
//! every allocation above its mmap threshold (128 KiB, raised adaptively)
//! its own fresh pages and gives freed memory back to the kernel; the AE
//! stream decodes a few-MiB batch per row group, so each batch paid page
//! faults and page clearing — a fifth of the CPU of an ingest
//! (`perf record`, docs/benchmarks.md). Keeping allocations up to 32 MiB
//! on the heap and freed memory up to 128 MiB for reuse made the ingest
//! ≈ 30 % faster for a few MiB more resident memory.
//!
//! glibc also gives threads arenas of their own as they contend, up to 8
//! per core, and each keeps its freed memory: the diagnosis' worker
//! threads free chunk-sized buffers in several arenas, which held up to
//! ≈ 150 MB more resident memory at 2 000 servo runs than the live heap
//! (peak RSS 450–515 MB for a 270 MB heap; 395–417 MB with one arena per
//! core or fewer, at the same speed — docs/scale.md). Arenas are capped at
//! one per core.

// glibc <malloc.h>'s mallopt parameters.
const M_TRIM_THRESHOLD: i32 = -1;
const M_MMAP_THRESHOLD: i32 = -3;
const M_ARENA_MAX: i32 = -8;

/// Sets one of glibc's malloc parameters; a no-op off glibc.
fn set_malloc_param(param: i32, value: i32) {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        extern "C" {
            fn mallopt(param: std::ffi::c_int, value: std::ffi::c_int) -> std::ffi::c_int;
        }
        // SAFETY: mallopt only sets an allocator parameter (glibc takes
        // the main arena's lock to set it).
        unsafe {
            mallopt(param, value);
        }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    let _ = (param, value);
}

/// Call once, first thing in a binary (the `sparkout` main and the bench
/// mains); a no-op off glibc.
pub fn keep_freed_memory() {
    // 32 MiB is the largest mmap threshold glibc accepts on 64-bit.
    set_malloc_param(M_MMAP_THRESHOLD, 32 << 20);
    set_malloc_param(M_TRIM_THRESHOLD, 128 << 20);
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    set_malloc_param(M_ARENA_MAX, cores.clamp(1, 64) as i32);
}

/// From now on, threads that have no malloc arena yet share the main one
/// (threads that already have one keep it). Called first thing in
/// `aggregate`, which runs only the fleet steps: the diagnosis' worker
/// threads then allocate from one arena, whose freed chunks every thread
/// reuses, instead of two that each keep their own. At 2 000 servo runs
/// the aggregate's resident peak fell from 352–398 MB (five runs) to
/// 340–366 MB (six) and varied less; at 500 runs from 275–282 to
/// 262–267 MB; the time did not move beyond the machine's noise
/// (docs/scale.md). A single-node `run` keeps an arena per worker: its
/// per-run stages allocate side by side. A no-op off glibc.
pub fn share_one_arena() {
    set_malloc_param(M_ARENA_MAX, 1);
}

/// Gives the pages of freed allocations back to the kernel, in every
/// malloc arena. Called between the fleet steps of `aggregate` and `run`:
/// the join reads thousands of per-run tables in small buffers that are
/// freed once concatenated; kept by the allocator (they sit between live
/// allocations, so no ordinary trim reaches them), they were ≈ 150 B per
/// observation row of resident memory through the diagnosis and the
/// report. A no-op off glibc.
pub fn release_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        extern "C" {
            fn malloc_trim(pad: usize) -> std::ffi::c_int;
        }
        // SAFETY: malloc_trim only returns free pages to the kernel; it is
        // thread-safe (it locks each arena in turn).
        unsafe {
            malloc_trim(0);
        }
    }
}

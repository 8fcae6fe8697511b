//! The allocator's trade-off for a batch processor. glibc's malloc hands
//! every allocation above its mmap threshold (128 KiB, raised adaptively)
//! its own fresh pages and gives freed memory back to the kernel; the AE
//! stream decodes a few-MiB batch per row group, so each batch paid page
//! faults and page clearing — a fifth of the CPU of an ingest
//! (`perf record`, docs/benchmarks.md). Keeping allocations up to 32 MiB
//! on the heap and freed memory up to 128 MiB for reuse made the ingest
//! ≈ 30 % faster for a few MiB more resident memory.

/// Call once, first thing in a binary (the `sparkout` main and the bench
/// mains); a no-op off glibc.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // glibc <malloc.h>: M_TRIM_THRESHOLD = -1, M_MMAP_THRESHOLD = -3.
        // 32 MiB is the largest mmap threshold glibc accepts on 64-bit.
        extern "C" {
            fn mallopt(param: std::ffi::c_int, value: std::ffi::c_int) -> std::ffi::c_int;
        }
        const M_TRIM_THRESHOLD: std::ffi::c_int = -1;
        const M_MMAP_THRESHOLD: std::ffi::c_int = -3;
        // SAFETY: mallopt only sets allocator parameters; called before
        // any thread of ours allocates concurrently.
        unsafe {
            mallopt(M_MMAP_THRESHOLD, 32 << 20);
            mallopt(M_TRIM_THRESHOLD, 128 << 20);
        }
    }
}

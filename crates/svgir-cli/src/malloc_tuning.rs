//! Keeps freed memory in the process instead of returning it to the kernel.
//!
//! Every training iteration allocates and frees the same large buffers (per-pixel outputs, tile
//! records, per-entry gradients: tens of MB at 400x400). With glibc's defaults, buffers this size
//! are `mmap`ed and unmapped on free, or trimmed off the heap top, so each iteration page-faults
//! them in again: on the 2-core development VM that was 0.7-0.9 s of system time per 8
//! rasterizer forward+backward calls on lego (75.9k Gaussians, 400x400), and 15-25% of the wall
//! time. Raising the mmap threshold to its maximum (32 MiB) and disabling trimming drops it to
//! 0.15 s. Buffers above 32 MiB were still mapped per call: at 200k Gaussians the SH gradient
//! (42 MB) and the tile records (50 MB) were page-faulted in on every iteration, so `mmap` is now
//! off altogether (`M_MMAP_MAX = 0`) and such buffers come from the heap and are reused: `svgir
//! bench raster --ply` on a trained 217.7k-Gaussian lego, 2 threads, 176 -> 165 ms (per-Gaussian
//! backward 25.5 -> 15.6 ms; 2026-11-25).
//!
//! The rayon workers allocate from glibc's per-thread arenas, whose heaps are shrunk (pages given
//! back with `madvise`) whenever their free top exceeds the top pad, whatever the trim
//! threshold. A 64 MiB top pad keeps those pages too: `svgir bench raster` at 400x400 / 100k,
//! backward 64 -> 57 ms (2 threads, 2026-11-25), the difference being page faults on the
//! per-Gaussian gradient arrays.

/// Applies the tuning (glibc on Linux only; elsewhere a no-op).
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // From glibc's <malloc.h>.
        const M_TRIM_THRESHOLD: i32 = -1;
        const M_TOP_PAD: i32 = -2;
        const M_MMAP_THRESHOLD: i32 = -3;
        const M_MMAP_MAX: i32 = -4;
        extern "C" {
            fn mallopt(param: i32, value: i32) -> i32;
        }
        // SAFETY: mallopt only changes allocator parameters; it is called before any thread is
        // started, and invalid values are rejected by glibc (returning 0), not undefined.
        unsafe {
            mallopt(M_MMAP_THRESHOLD, 32 * 1024 * 1024);
            mallopt(M_TRIM_THRESHOLD, i32::MAX);
            mallopt(M_TOP_PAD, 64 * 1024 * 1024);
            mallopt(M_MMAP_MAX, 0);
        }
    }
}

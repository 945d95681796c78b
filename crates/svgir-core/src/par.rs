//! Large buffers filled by the rayon workers.
//!
//! `vec![0.0; n]` of a block the allocator hands back from its heap (as it does for the
//! per-iteration buffers of training, with the 64 MiB top pad of `svgir_raster`'s malloc
//! tuning) is a `memset` on the calling thread, while the workers wait for the next parallel
//! loop. In a stage-2 iteration those fills were about a quarter of the serial time
//! (docs/performance.md). [`filled`] writes the elements in parallel chunks instead; the values
//! are the same.
//!
//! Work split: chunks of [`CHUNK_BYTES`]; buffers under [`SERIAL_BYTES`] are filled on the
//! calling thread, where waking the workers would cost more than the fill.

use rayon::prelude::*;
use std::mem::MaybeUninit;

/// Bytes per parallel chunk.
pub const CHUNK_BYTES: usize = 1 << 18;
/// Buffers smaller than this are filled serially.
pub const SERIAL_BYTES: usize = 1 << 17;

/// A vector of `n` copies of `value`, written by the rayon workers when it is large.
pub fn filled<T: Copy + Send + Sync>(n: usize, value: T) -> Vec<T> {
    let size = size_of::<T>().max(1);
    if n * size < SERIAL_BYTES {
        return vec![value; n];
    }
    let mut v: Vec<MaybeUninit<T>> = Vec::with_capacity(n);
    // SAFETY: `MaybeUninit` needs no initialisation, and the capacity is `n`.
    unsafe { v.set_len(n) };
    v.par_chunks_mut((CHUNK_BYTES / size).max(1)).for_each(|c| c.fill(MaybeUninit::new(value)));
    let mut v = std::mem::ManuallyDrop::new(v);
    // SAFETY: every element was written above, and `MaybeUninit<T>` has `T`'s layout.
    unsafe { Vec::from_raw_parts(v.as_mut_ptr() as *mut T, v.len(), v.capacity()) }
}

/// Makes `v` hold `n` copies of `value` (reusing its buffer when it already has `n` elements),
/// written by the rayon workers when it is large.
pub fn refill<T: Copy + Send + Sync>(v: &mut Vec<T>, n: usize, value: T) {
    let size = size_of::<T>().max(1);
    if n * size < SERIAL_BYTES {
        v.clear();
        v.resize(n, value);
    } else if v.len() == n {
        v.par_chunks_mut((CHUNK_BYTES / size).max(1)).for_each(|c| c.fill(value));
    } else {
        *v = filled(n, value);
    }
}

/// A vector of `n` all-zero values, written by the rayon workers when it is large.
pub fn zeroed<T: bytemuck::Zeroable + Copy + Send + Sync>(n: usize) -> Vec<T> {
    filled(n, T::zeroed())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fills_equal_vec_macro_on_both_sides_of_the_threshold() {
        for n in [0, 1, 1000, SERIAL_BYTES / 4 - 1, SERIAL_BYTES / 4, 3 * CHUNK_BYTES / 4 + 7] {
            assert_eq!(filled(n, 1.5f32), vec![1.5f32; n], "n = {n}");
            assert_eq!(zeroed::<[f64; 3]>(n), vec![[0.0f64; 3]; n], "n = {n}");
            assert_eq!(filled(n, 7u32).len(), n);
            for start in [0, n, n + 5] {
                let mut v = vec![2.0f32; start];
                refill(&mut v, n, -1.0);
                assert_eq!(v, vec![-1.0f32; n], "n = {n}, from {start}");
            }
        }
    }
}

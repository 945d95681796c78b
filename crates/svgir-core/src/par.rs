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
//!
//! [`Disjoint`] lets parallel tasks write one buffer at places that are not contiguous runs
//! (a tile's pixels are a piece of each of its rows), each task in its own segments.

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

/// `add(&mut acc[i], &part[i])` for each part in order, for every `i`: the elements in parallel
/// chunks, each element's sum in part order, so the result has the bits of the serial loop
/// over the parts. For per-task partial sums (say of the light's gradient) reduced after a
/// parallel loop.
pub fn add_parts_in_order<T: Send + Sync, P: AsRef<[T]> + Sync>(
    acc: &mut [T],
    parts: &[P],
    add: impl Fn(&mut T, &T) + Sync,
) {
    const ELEMS: usize = 256;
    acc.par_chunks_mut(ELEMS).enumerate().for_each(|(c, a)| {
        for p in parts {
            for (x, y) in a.iter_mut().zip(&p.as_ref()[c * ELEMS..]) {
                add(x, y);
            }
        }
    });
}

/// A mutable slice that parallel tasks write at once, each in segments no other task touches.
///
/// Splitting a slice into `&mut` pieces needs the pieces to be contiguous runs; the pixels of an
/// image tile are a short run in each of several rows. Each task asks for its runs with
/// [`Disjoint::seg`], whose caller promises that no two live segments overlap.
pub struct Disjoint<'a, T> {
    ptr: *mut T,
    len: usize,
    _borrow: std::marker::PhantomData<&'a mut [T]>,
}

// SAFETY: a `Disjoint` hands out only non-overlapping segments (the contract of `seg`), so
// sharing it between threads is sharing disjoint `&mut [T]`, which is `Send` when `T` is.
unsafe impl<T: Send> Send for Disjoint<'_, T> {}
unsafe impl<T: Send> Sync for Disjoint<'_, T> {}

impl<'a, T> Disjoint<'a, T> {
    /// Borrows `v` for parallel writes.
    pub fn new(v: &'a mut [T]) -> Self {
        Self { ptr: v.as_mut_ptr(), len: v.len(), _borrow: std::marker::PhantomData }
    }

    /// Elements in the whole slice.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the slice is empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The `len` elements from `start`.
    ///
    /// # Safety
    /// No other segment that overlaps this one is alive (in this task or another) while the
    /// returned slice is.
    ///
    /// # Panics
    /// If the segment does not lie inside the slice.
    #[allow(clippy::mut_from_ref)]
    #[inline]
    pub unsafe fn seg(&self, start: usize, len: usize) -> &'a mut [T] {
        assert!(start <= self.len && len <= self.len - start, "segment {start}+{len} outside {}", self.len);
        // SAFETY: in bounds (checked above); exclusive by the caller's contract; the borrow of
        // the whole slice lives for 'a.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(start), len) }
    }
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

    #[test]
    fn disjoint_segments_cover_the_slice_from_parallel_tasks() {
        // A 7-wide, 5-tall "image" written by 3-column "tiles" at once, each through its rows.
        let (w, h) = (7usize, 5usize);
        let mut img = vec![0u32; w * h];
        let d = Disjoint::new(&mut img);
        assert_eq!(d.len(), w * h);
        (0..w.div_ceil(3)).into_par_iter().for_each(|tx| {
            let (x0, x1) = (3 * tx, (3 * tx + 3).min(w));
            for y in 0..h {
                // SAFETY: tile `tx` alone owns columns x0..x1.
                let row = unsafe { d.seg(y * w + x0, x1 - x0) };
                for (i, v) in row.iter_mut().enumerate() {
                    *v = (y * w + x0 + i) as u32 + 1;
                }
            }
        });
        assert_eq!(img, (1..=(w * h) as u32).collect::<Vec<_>>());
    }

    #[test]
    fn parts_add_in_order_with_the_serial_bits() {
        // Values whose f32 sum depends on the order.
        let parts: Vec<Vec<f32>> = (0..9)
            .map(|p| (0..1000).map(|i| ((i * 31 + p * 7) % 97) as f32 * 10f32.powi(p % 5 - 2)).collect())
            .collect();
        let mut want = vec![0.5f32; 1000];
        for p in &parts {
            for (a, x) in want.iter_mut().zip(p) {
                *a += x;
            }
        }
        let mut got = vec![0.5f32; 1000];
        rayon::ThreadPoolBuilder::new().num_threads(3).build().unwrap().install(|| {
            add_parts_in_order(&mut got, &parts, |a, x| *a += x);
        });
        assert_eq!(
            got.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            want.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
        );
    }

    #[test]
    #[should_panic(expected = "outside")]
    fn a_segment_past_the_end_panics() {
        let mut v = vec![0u8; 4];
        let d = Disjoint::new(&mut v);
        // SAFETY: the only segment.
        let _ = unsafe { d.seg(2, 3) };
    }
}

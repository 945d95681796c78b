//! Micro-buffer samples kept on the GPU across shading calls.
//!
//! Stage 2 shades the same micro-buffers (the traced one, or its fixed interleaved subsets) at
//! every iteration, forward and backward, and an evaluation or a relighting shades one
//! micro-buffer for every view. Packing and uploading the 16-byte samples at each call was most
//! of a call's transfer (at K = 64, 1 KB a Gaussian of about 1.3 KB). So the shader keeps the
//! packed samples of the micro-buffers it shaded last, each in chunks of whole Gaussians (no
//! larger than a dispatch's batch, so a batch binds one chunk), up to a byte budget; the least
//! recently used goes first.
//!
//! A micro-buffer is known by its allocation (the address of its samples), its sizes, its
//! direction set, and a fingerprint of its content: every Gaussian's axis and azimuth offset,
//! and 16k samples spread over it. The trainer and the relighter never change a traced
//! micro-buffer in place (they trace a new one); a change the fingerprint cannot see (a few
//! samples of one in place) would be shaded with the old samples, so code that edits samples
//! in place calls [`SampleCache::clear`].

use crate::samples::{pack, SAMPLE_BYTES};
use std::sync::Mutex;
use svgir_trace::MicroBuffer;

/// Default budget of kept samples (bytes).
pub const RESIDENT_BYTES: u64 = 1 << 30;

/// Samples spread over a micro-buffer that its fingerprint reads.
const PRINT_SAMPLES: usize = 16384;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Key {
    addr: usize,
    n: usize,
    k: usize,
    interleave: (usize, usize),
    chunk: usize,
    print: u64,
}

impl Key {
    fn of(mb: &MicroBuffer, chunk: usize) -> Self {
        let mut h = Fold::default();
        for (nrm, xi) in mb.normals.iter().zip(&mb.xi) {
            h.add(u64::from(nrm.x.to_bits()) | u64::from(nrm.y.to_bits()) << 32);
            h.add(u64::from(nrm.z.to_bits()) | u64::from(xi.to_bits()) << 32);
        }
        let total = mb.vis.len();
        let step = (total / PRINT_SAMPLES).max(1);
        for s in (0..total).step_by(step).chain(total.saturating_sub(1)..total) {
            let [r, g, b] = mb.radiance[s].map(u64::from);
            let [u, v] = mb.uv[s].map(u64::from);
            h.add(u64::from(mb.vis[s]) | r << 16 | g << 32 | b << 48);
            h.add(u64::from(mb.first_hit[s]) | u << 32 | v << 48);
        }
        Self {
            addr: mb.vis.as_ptr() as usize,
            n: mb.len(),
            k: mb.k,
            interleave: (mb.interleave.stride, mb.interleave.phase),
            chunk,
            print: h.0,
        }
    }
}

/// A multiply-rotate fold of 64-bit words (FxHash's step): fast, and enough to tell traces apart.
#[derive(Default)]
struct Fold(u64);

impl Fold {
    fn add(&mut self, x: u64) {
        self.0 = (self.0.rotate_left(5) ^ x).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
}

struct Entry {
    key: Key,
    chunks: Vec<wgpu::Buffer>,
    bytes: u64,
}

/// The packed samples of recently shaded micro-buffers, on the GPU.
pub(crate) struct SampleCache {
    /// Most bytes kept; 0 keeps nothing (every call uploads its batches).
    pub budget: u64,
    /// Least recently used first.
    entries: Mutex<Vec<Entry>>,
}

impl SampleCache {
    pub(crate) fn new(budget: u64) -> Self {
        Self { budget, entries: Mutex::new(Vec::new()) }
    }

    /// The packed samples of `mb`, in chunks of `chunk` Gaussians (chunk c holds Gaussians
    /// `c * chunk ..`), uploaded at the first call and kept; `None` when they exceed the budget
    /// (the caller uploads each batch itself).
    pub(crate) fn get(&self, device: &wgpu::Device, mb: &MicroBuffer, chunk: usize) -> Option<Vec<wgpu::Buffer>> {
        let chunk = chunk.max(1);
        let bytes = mb.vis.len() as u64 * SAMPLE_BYTES;
        if bytes == 0 || bytes > self.budget {
            return None;
        }
        let key = Key::of(mb, chunk);
        let mut entries = self.entries.lock().ok()?;
        if let Some(i) = entries.iter().position(|e| e.key == key) {
            let e = entries.remove(i);
            let chunks = e.chunks.clone();
            entries.push(e);
            return Some(chunks);
        }
        let mut kept: u64 = entries.iter().map(|e| e.bytes).sum();
        while kept + bytes > self.budget && !entries.is_empty() {
            kept -= entries.remove(0).bytes;
        }
        let n = mb.len();
        let chunks: Vec<wgpu::Buffer> = (0..n)
            .step_by(chunk)
            .map(|g0| crate::buffers::upload(device, "shade samples (kept)", &pack(mb, g0..(g0 + chunk).min(n))))
            .collect();
        entries.push(Entry { key, chunks: chunks.clone(), bytes });
        Some(chunks)
    }

    /// Drops every kept micro-buffer.
    pub(crate) fn clear(&self) {
        if let Ok(mut e) = self.entries.lock() {
            e.clear();
        }
    }

    /// Micro-buffers kept, and their bytes.
    pub(crate) fn kept(&self) -> (usize, u64) {
        self.entries.lock().map(|e| (e.len(), e.iter().map(|x| x.bytes).sum())).unwrap_or((0, 0))
    }
}

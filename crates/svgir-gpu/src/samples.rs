//! The micro-buffer samples' GPU layout: 16 bytes a sample, `(V unorm16 | L.r f16 << 16,
//! L.g | L.b << 16, first hit, u~ | v~ << 16)`, as `shaders/trace.wgsl` writes them and
//! `shaders/shade.wgsl` reads them. The halves are `svgir_trace::MicroBuffer`'s own fields, so
//! packing and unpacking move bits only.

use svgir_trace::MicroBuffer;

/// Bytes per packed sample on the GPU.
pub const SAMPLE_BYTES: u64 = 16;

/// The packed samples of Gaussians `range` of `mb`, in j * K + k order.
pub fn pack(mb: &MicroBuffer, range: std::ops::Range<usize>) -> Vec<[u32; 4]> {
    let (a, b) = (range.start * mb.k, range.end * mb.k);
    (a..b)
        .map(|s| {
            let [lr, lg, lb] = mb.radiance[s].map(u32::from);
            let [u, v] = mb.uv[s].map(u32::from);
            [u32::from(mb.vis[s]) | (lr << 16), lg | (lb << 16), mb.first_hit[s], u | (v << 16)]
        })
        .collect()
}

/// Appends packed samples to `mb`'s V, L, first hits and (u~, v~).
pub fn unpack_into(words: &[[u32; 4]], mb: &mut MicroBuffer) {
    let lo = |x: u32| (x & 0xffff) as u16;
    let hi = |x: u32| (x >> 16) as u16;
    for w in words {
        mb.vis.push(lo(w[0]));
        mb.radiance.push([hi(w[0]), lo(w[1]), hi(w[1])]);
        mb.first_hit.push(w[2]);
        mb.uv.push([lo(w[3]), hi(w[3])]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use svgir_trace::Interleave;

    #[test]
    fn pack_then_unpack_is_the_identity() {
        let k = 3;
        let n = 4;
        let s = n * k;
        let word = |i: usize, salt: usize| ((i * 7919 + salt * 104_729) % 65_536) as u16;
        let mb = MicroBuffer {
            k,
            normals: vec![glam::Vec3::Z; n],
            xi: vec![0.0; n],
            vis: (0..s).map(|i| word(i, 1)).collect(),
            radiance: (0..s).map(|i| [word(i, 2), word(i, 3), word(i, 4)]).collect(),
            first_hit: (0..s).map(|i| if i % 3 == 0 { u32::MAX } else { (i * 31) as u32 }).collect(),
            uv: (0..s).map(|i| [word(i, 5), word(i, 6)]).collect(),
            interleave: Interleave::default(),
        };
        let mut back = MicroBuffer { vis: vec![], radiance: vec![], first_hit: vec![], uv: vec![], ..mb.clone() };
        unpack_into(&pack(&mb, 0..1), &mut back);
        unpack_into(&pack(&mb, 1..n), &mut back);
        assert_eq!(back, mb);
    }
}

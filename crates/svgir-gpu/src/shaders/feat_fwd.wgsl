// Forward compositing of feature tables (SPEC 1, Eqn 3; stage 2's PBR pass): one workgroup per
// 16 x 16 tile, one thread per pixel, front to back over the tile's list in batches staged in
// workgroup memory, with raster_fwd.wgsl's rules for which entries a pixel composites. Each hit
// interpolates its Gaussian's colour row and extra row (`feat`) at the hit's (u, v) and adds
// them with weight alpha T, by FMA as the CPU kernels.
//
// Outputs per pixel (F.pix = 7 + ce floats): colour (+ T_N bg), alpha, depth (undivided), median
// depth, final T, the extra channels. Saved for the backward: the final T and the count of list
// entries up to the last composited one (`ncon`).

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<uniform> F: Feat;
@group(0) @binding(2) var<storage, read> splat: array<f32>;
@group(0) @binding(3) var<storage, read> rect: array<u32>;
@group(0) @binding(4) var<storage, read> ranges: array<u32>;
@group(0) @binding(5) var<storage, read> tval: array<u32>;
@group(0) @binding(6) var<storage, read> egauss: array<u32>;
@group(0) @binding(7) var<storage, read> feat: array<f32>;
@group(0) @binding(8) var<storage, read_write> img: array<f32>;
@group(0) @binding(9) var<storage, read_write> ncon: array<u32>;
// Loops cut short (loop_guard.wgsl): bit 4.
@group(0) @binding(10) var<storage, read_write> status: array<atomic<u32>, 2>;

const BATCH: u32 = 128u;

// The batch arrays and `stage` are in stage.wgsl; the batch's Gaussians, for their rows.
var<workgroup> s_g: array<u32, BATCH>;
var<workgroup> done_count: atomic<u32>;

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) tid: u32) {
    let tile = wid.y * P.tiles_x + wid.x;
    let px = wid.x * TILE + tid % TILE;
    let py = wid.y * TILE + tid / TILE;
    let inside = px < P.width && py < P.height;
    let xf = f32(px) + 0.5;
    let yf = f32(py) + 0.5;
    let near = P.clip.x;
    let t_stop = P.clip.z;
    let geom = (P.flags & FLAG_GEOMETRY) != 0u;
    let r0 = ranges[tile * 2u];
    let r1 = ranges[tile * 2u + 1u];

    var t = 1.0;
    var color = vec3<f32>(0.0);
    var ext: array<f32, MAX_EXTRA>;
    var depth = 0.0;
    var median = 0.0;
    var nc = 0u;
    var done = !inside;
    if tid == 0u {
        atomicStore(&done_count, 0u);
    }
    workgroupBarrier();
    if done {
        atomicAdd(&done_count, 1u);
    }
    for (var b0 = r0; b0 < r1; b0 += BATCH) {
        workgroupBarrier();
        if workgroupUniformLoad(&done_count) == 256u {
            break;
        }
        let e = b0 + tid;
        if tid < BATCH && e < r1 {
            let g = egauss[tval[e]];
            stage(tid, g);
            s_g[tid] = g;
        }
        workgroupBarrier();
        let cnt = min(BATCH, r1 - b0);
        for (var j = 0u; j < cnt; j++) {
            if done {
                break;
            }
            let rc = s_rect[j];
            if px < rc.x || px >= rc.y || py < rc.z || py >= rc.w {
                continue;
            }
            let co = s_co[j];
            let ev = eval_px(s_a[j], s_bw[j], s_b0[j], s_hw[j], co.xy, co.z, xf, yf, near);
            if ev.alpha == 0.0 {
                continue;
            }
            let test = t * (1.0 - ev.alpha);
            if test < t_stop {
                done = true;
                atomicAdd(&done_count, 1u);
                break;
            }
            let w = ev.alpha * t;
            let g = s_g[j];
            let wv = vertex_weights(F.m, ev.u, ev.v);
            let col = vec3<f32>(
                feat_value(0u, 3u, 3u, g, 0u, wv),
                feat_value(0u, 3u, 3u, g, 1u, wv),
                feat_value(0u, 3u, 3u, g, 2u, wv),
            );
            color = fma(vec3<f32>(w), col, color);
            if geom {
                depth += w * ev.z;
                if t > 0.5 {
                    median = ev.z;
                }
            }
            // Four channels an iteration (loop_guard.wgsl counts iterations on lavapipe).
            for (var c = 0u; c < F.ce; c += 4u) {
                ext[c] = fma(w, feat_value(F.ext_at, F.ce, F.lerped, g, c, wv), ext[c]);
                if c + 1u < F.ce {
                    ext[c + 1u] = fma(w, feat_value(F.ext_at, F.ce, F.lerped, g, c + 1u, wv), ext[c + 1u]);
                }
                if c + 2u < F.ce {
                    ext[c + 2u] = fma(w, feat_value(F.ext_at, F.ce, F.lerped, g, c + 2u, wv), ext[c + 2u]);
                }
                if c + 3u < F.ce {
                    ext[c + 3u] = fma(w, feat_value(F.ext_at, F.ce, F.lerped, g, c + 3u, wv), ext[c + 3u]);
                }
            }
            t = test;
            nc = b0 + j - r0 + 1u;
        }
    }
    if inside {
        let p = py * P.width + px;
        let o = p * F.pix;
        let c = color + t * P.bg.xyz;
        img[o] = c.x;
        img[o + 1u] = c.y;
        img[o + 2u] = c.z;
        img[o + 3u] = 1.0 - t;
        img[o + 4u] = depth;
        img[o + 5u] = median;
        img[o + 6u] = t;
        for (var k = 0u; k < F.ce; k++) {
            img[o + 7u + k] = ext[k];
        }
        ncon[p] = nc;
    }
    guard_loops(4u);
}

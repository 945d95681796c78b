// Backward of feat_fwd.wgsl with the geometry frozen (SPEC 6; svgir_raster::backward's
// frozen-geometry path): one workgroup per tile, one thread per pixel, back to front over the
// entries up to the tile's last composited one, in batches staged in workgroup memory. Per
// pixel, T is walked back from the saved final T and the suffix sum
// `acc = sum_{j>i} g_j w_j + T_N gC.bg` runs along, with `g_i = gC.c_i + gO + gD z_i + gE.f_i`
// and `dL/dalpha_i = T_i g_i - acc / (1 - alpha_i)` (backward.rs). The chain stops at the
// opacity: no gradient reaches the positions, rotations or scales.
//
// Per entry, its slot `grads[entry * F.fd ..]` gets: dL/d opacity, the weight sum (for the
// shaded sets), dL/d colour row (3 per vertex: w w_vtx gC) and dL/d extra row (per vertex
// w w_vtx gE for the interpolated channels; w gE at vertex 0 for the uniform ones). The pixels'
// values are added in chunks of CHUNK floats: within each subgroup (subgroupAdd; its size is read
// at run time, never assumed), then the subgroups' partial sums by the subgroups (partials.wgsl),
// as raster_bwd.wgsl does, so no atomics and the same sums at every run.

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<uniform> F: Feat;
@group(0) @binding(2) var<storage, read> splat: array<f32>;
@group(0) @binding(3) var<storage, read> rect: array<u32>;
@group(0) @binding(4) var<storage, read> ranges: array<u32>;
@group(0) @binding(5) var<storage, read> tval: array<u32>;
@group(0) @binding(6) var<storage, read> egauss: array<u32>;
@group(0) @binding(7) var<storage, read> feat: array<f32>;
@group(0) @binding(8) var<storage, read> img: array<f32>;
@group(0) @binding(9) var<storage, read> ncon: array<u32>;
// Per pixel (F.vpix = 5 + ce floats): dL/d colour (3), alpha, depth, extra channels.
@group(0) @binding(10) var<storage, read> vout: array<f32>;
@group(0) @binding(11) var<storage, read_write> grads: array<f32>;
// Loops cut short (loop_guard.wgsl): bit 8.
@group(0) @binding(12) var<storage, read_write> status: array<atomic<u32>, 2>;

const BATCH: u32 = 64u;
const CHUNK: u32 = 24u;
const MAX_SUBGROUPS: u32 = 64u;

// The batch arrays and `stage` are in stage.wgsl.
var<workgroup> s_g: array<u32, BATCH>;
var<workgroup> s_slot: array<u32, BATCH>;
var<workgroup> partial: array<array<vec4<f32>, 6>, MAX_SUBGROUPS>;
var<workgroup> max_n: atomic<u32>;

// Float q of a pixel's contribution to an entry's slot (layout above).
fn slot_value(q: u32, v_o: f32, w: f32, wv_in: array<f32, 6>, gc: vec3<f32>, ge_in: array<f32, MAX_EXTRA>) -> f32 {
    var wv = wv_in;
    var ge = ge_in;
    if q >= F.fd {
        return 0.0;
    }
    if q == 0u {
        return v_o;
    }
    if q == 1u {
        return w;
    }
    let ncol = 3u * F.m;
    if q < 2u + ncol {
        let r = q - 2u;
        return w * wv[r / 3u] * gc[r % 3u];
    }
    let r = q - 2u - ncol;
    let vtx = r / F.ce;
    let c = r % F.ce;
    if c < F.lerped {
        return w * wv[vtx] * ge[c];
    }
    return select(0.0, w * ge[c], vtx == 0u);
}

// Floats q .. q + 3 of the slot.
fn slot4(q: u32, v_o: f32, w: f32, wv: array<f32, 6>, gc: vec3<f32>, ge: array<f32, MAX_EXTRA>) -> vec4<f32> {
    return vec4<f32>(
        slot_value(q, v_o, w, wv, gc, ge),
        slot_value(q + 1u, v_o, w, wv, gc, ge),
        slot_value(q + 2u, v_o, w, wv, gc, ge),
        slot_value(q + 3u, v_o, w, wv, gc, ge),
    );
}

@compute @workgroup_size(256)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) tid: u32,
    @builtin(subgroup_invocation_id) sg_lane: u32,
    @builtin(subgroup_id) sg: u32,
    @builtin(subgroup_size) sg_size: u32,
    @builtin(num_subgroups) n_sg: u32,
) {
    let tile = wid.y * P.tiles_x + wid.x;
    let px = wid.x * TILE + tid % TILE;
    let py = wid.y * TILE + tid / TILE;
    let inside = px < P.width && py < P.height;
    let xf = f32(px) + 0.5;
    let yf = f32(py) + 0.5;
    let near = P.clip.x;
    let geom = (P.flags & FLAG_GEOMETRY) != 0u;
    let r0 = ranges[tile * 2u];
    let chunks = (F.fd + CHUNK - 1u) / CHUNK;

    var t = 1.0;
    var acc = 0.0;
    var gc = vec3<f32>(0.0);
    var go = 0.0;
    var gd = 0.0;
    var ge: array<f32, MAX_EXTRA>;
    var nc = 0u;
    if tid == 0u {
        atomicStore(&max_n, 0u);
    }
    workgroupBarrier();
    if inside {
        let p = py * P.width + px;
        let v = p * F.vpix;
        t = img[p * F.pix + 6u];
        nc = ncon[p];
        gc = vec3<f32>(vout[v], vout[v + 1u], vout[v + 2u]);
        go = vout[v + 3u];
        if geom {
            gd = vout[v + 4u];
        }
        for (var c = 0u; c < F.ce; c++) {
            ge[c] = vout[v + 5u + c];
        }
        acc = t * dot(gc, P.bg.xyz);
        atomicMax(&max_n, nc);
    }
    let last = workgroupUniformLoad(&max_n);
    // Batches from the back: entries [lo, hi) of the tile's list, hi descending.
    var hi = last;
    while hi > 0u {
        let lo = select(0u, hi - BATCH, hi > BATCH);
        workgroupBarrier();
        let le = lo + tid;
        if tid < BATCH && le < hi {
            let e = r0 + le;
            let slot = tval[e];
            let g = egauss[slot];
            stage(tid, g);
            s_g[tid] = g;
            s_slot[tid] = slot;
        }
        workgroupBarrier();
        for (var jj = hi; jj > lo; jj--) {
            let local = jj - 1u;
            let j = local - lo;
            var w = 0.0;
            var v_o = 0.0;
            var wv: array<f32, 6>;
            let rc = s_rect[j];
            let in_rect = px >= rc.x && px < rc.y && py >= rc.z && py < rc.w;
            if inside && local < nc && in_rect {
                let co = s_co[j];
                let o = co.z;
                let ev = eval_px(s_a[j], s_bw[j], s_b0[j], s_hw[j], co.xy, o, xf, yf, near);
                if ev.alpha != 0.0 {
                    let inv_one_m = 1.0 / (1.0 - ev.alpha);
                    let ti = t * inv_one_m;
                    t = ti;
                    w = ev.alpha * ti;
                    let g = s_g[j];
                    wv = vertex_weights(F.m, ev.u, ev.v);
                    let col = vec3<f32>(
                        feat_value(0u, 3u, 3u, g, 0u, wv),
                        feat_value(0u, 3u, 3u, g, 1u, wv),
                        feat_value(0u, 3u, 3u, g, 2u, wv),
                    );
                    var gw = dot(gc, col) + go + gd * ev.z;
                    // Four channels an iteration, in order (loop_guard.wgsl).
                    for (var c = 0u; c < F.ce; c += 4u) {
                        gw += ge[c] * feat_value(F.ext_at, F.ce, F.lerped, g, c, wv);
                        if c + 1u < F.ce {
                            gw += ge[c + 1u] * feat_value(F.ext_at, F.ce, F.lerped, g, c + 1u, wv);
                        }
                        if c + 2u < F.ce {
                            gw += ge[c + 2u] * feat_value(F.ext_at, F.ce, F.lerped, g, c + 2u, wv);
                        }
                        if c + 3u < F.ce {
                            gw += ge[c + 3u] * feat_value(F.ext_at, F.ce, F.lerped, g, c + 3u, wv);
                        }
                    }
                    let v_alpha = ti * gw - acc * inv_one_m;
                    acc += gw * w;
                    // alpha = min(o G, 0.99): the clamp passes no gradient.
                    if !(o * ev.g > 0.99) {
                        v_o = v_alpha * ev.g;
                    }
                }
            }
            for (var k = 0u; k < chunks; k++) {
                // Chunk k of the slot: six groups of four floats, unrolled (loop_guard.wgsl
                // counts every loop iteration on lavapipe).
                var c = array<vec4<f32>, 6>();
                if w != 0.0 {
                    let q = k * CHUNK;
                    c[0] = slot4(q, v_o, w, wv, gc, ge);
                    c[1] = slot4(q + 4u, v_o, w, wv, gc, ge);
                    c[2] = slot4(q + 8u, v_o, w, wv, gc, ge);
                    c[3] = slot4(q + 12u, v_o, w, wv, gc, ge);
                    c[4] = slot4(q + 16u, v_o, w, wv, gc, ge);
                    c[5] = slot4(q + 20u, v_o, w, wv, gc, ge);
                }
                stage_partials(c[0], c[1], c[2], c[3], c[4], c[5], sg, sg_lane);
                workgroupBarrier();
                let q = k * CHUNK;
                write_partials(s_slot[j] * F.fd + q, min(CHUNK, F.fd - q), sg, sg_lane, sg_size, n_sg);
                workgroupBarrier();
            }
        }
        hi = lo;
    }
    guard_loops(8u);
}

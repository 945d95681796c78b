// Backward of raster_fwd.wgsl (svgir_raster::backward's maths): one workgroup per tile, one
// thread per pixel, back to front over the entries up to the tile's last composited one, in
// batches staged in workgroup memory. Per pixel, T is walked back from the saved final T by
// dividing by (1 - alpha) and the suffix sum `acc = sum_{j>i} g_j w_j + T_N gC.bg` runs along;
// see backward.rs for the formulas.
//
// Reduction, without atomics: for each entry, the pixels' contributions (DIM values, below) are
// added within each subgroup (subgroupAdd; its size is read at run time, never assumed), the
// subgroups' partial sums are staged in workgroup memory and added by the subgroups
// (partials.wgsl), which write the entry's own slot `grads[entry * DIM ..]`. Every slot belongs to one
// (tile, Gaussian) entry, so the per-Gaussian sums (project_bwd.wgsl) need no atomics either and
// the result is the same at every run.
//
// Slot layout (DIM = 24): v_color (3), h_depth (3), v_center (2), v_opacity, v_normal (3),
// sum gp (3), sum x gp (3), sum y gp (3), weight sum (for pruning), two unused.

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> splat: array<f32>;
@group(0) @binding(2) var<storage, read> rect: array<u32>;
@group(0) @binding(3) var<storage, read> ranges: array<u32>;
@group(0) @binding(4) var<storage, read> tval: array<u32>;
@group(0) @binding(5) var<storage, read> egauss: array<u32>;
@group(0) @binding(6) var<storage, read> img: array<f32>;
@group(0) @binding(7) var<storage, read> ncon: array<u32>;
// Per pixel: dL/d colour (3), alpha, depth, normal (3), distortion (9).
@group(0) @binding(8) var<storage, read> vout: array<f32>;
@group(0) @binding(9) var<storage, read_write> grads: array<f32>;
// Loops cut short (loop_guard.wgsl): bit 2.
@group(0) @binding(10) var<storage, read_write> status: array<atomic<u32>, 2>;

const BATCH: u32 = 64u;
const PIX: u32 = 13u;
const VPIX: u32 = 9u;
const DIM: u32 = 24u;
const MAX_SUBGROUPS: u32 = 64u;

// The batch arrays and `stage` are in stage.wgsl.
var<workgroup> s_slot: array<u32, BATCH>;
var<workgroup> partial: array<array<vec4<f32>, 6>, MAX_SUBGROUPS>;
var<workgroup> max_n: atomic<u32>;

// One-dimensional workgroups: subgroup built-ins need them.
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
    let far = P.clip.y;
    let m_scale = far / (far - near);
    let dist_on = (P.flags & FLAG_DISTORTION) != 0u;
    let geom = (P.flags & FLAG_GEOMETRY) != 0u;
    let normals = geom && (P.flags & FLAG_NORMALS) != 0u;
    let r0 = ranges[tile * 2u];

    var t = 1.0;
    var acc = 0.0;
    var gc = vec3<f32>(0.0);
    var gn = vec3<f32>(0.0);
    var go = 0.0;
    var gd = 0.0;
    var gdist = 0.0;
    var a_fin = 0.0;
    var m1 = 0.0;
    var m2 = 0.0;
    var nc = 0u;
    if tid == 0u {
        atomicStore(&max_n, 0u);
    }
    workgroupBarrier();
    if inside {
        let p = py * P.width + px;
        let o = p * PIX;
        let v = p * VPIX;
        t = img[o + 10u];
        nc = ncon[p];
        gc = vec3<f32>(vout[v], vout[v + 1u], vout[v + 2u]);
        go = vout[v + 3u];
        if geom {
            gd = vout[v + 4u];
        }
        if normals {
            gn = vec3<f32>(vout[v + 5u], vout[v + 6u], vout[v + 7u]);
        }
        if dist_on {
            gdist = vout[v + 8u];
        }
        a_fin = 1.0 - t;
        m1 = img[o + 11u];
        m2 = img[o + 12u];
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
            s_slot[tid] = slot;
        }
        workgroupBarrier();
        for (var jj = hi; jj > lo; jj--) {
            let local = jj - 1u;
            let j = local - lo;
            var c0 = vec4<f32>(0.0); // v_color, h_depth.x
            var c1 = vec4<f32>(0.0); // h_depth.yz, v_center
            var c2 = vec4<f32>(0.0); // v_opacity, v_normal
            var c3 = vec4<f32>(0.0); // sum gp, sum x gp .x
            var c4 = vec4<f32>(0.0); // sum x gp .yz, sum y gp .xy
            var c5 = vec4<f32>(0.0); // sum y gp .z, weight
            let rc = s_rect[j];
            let in_rect = px >= rc.x && px < rc.y && py >= rc.z && py < rc.w;
            if inside && local < nc && in_rect {
                let co = s_co[j];
                let o = co.z;
                let hw = s_hw[j];
                let ev = eval_px(s_a[j], s_bw[j], s_b0[j], hw, co.xy, o, xf, yf, near);
                if ev.alpha != 0.0 {
                    let inv_one_m = 1.0 / (1.0 - ev.alpha);
                    let ti = t * inv_one_m;
                    t = ti;
                    let w = ev.alpha * ti;
                    let col = s_col[j];
                    let nrm = s_n[j];
                    var m = 0.0;
                    var dm_dz = 0.0;
                    if dist_on {
                        let inv_z = 1.0 / ev.z;
                        m = m_scale * (1.0 - near * inv_z);
                        dm_dz = m_scale * near * inv_z * inv_z;
                    }
                    var gw = dot(gc, col) + go + gd * ev.z + dot(gn, nrm);
                    if dist_on {
                        gw += gdist * (a_fin * m * m - 2.0 * m * m1 + m2);
                    }
                    let v_alpha = ti * gw - acc * inv_one_m;
                    acc += gw * w;
                    var v_z = w * gd;
                    if dist_on {
                        v_z += gdist * 2.0 * w * (m * a_fin - m1) * dm_dz;
                    }
                    // splat.rs, intersect_backward.
                    var gu = v_z * hw.x;
                    var gv = v_z * hw.y;
                    let h_depth = v_z * vec3<f32>(ev.u, ev.v, 1.0);
                    var v_c = vec2<f32>(0.0);
                    var v_o = 0.0;
                    let clamped = o * ev.g > 0.99;
                    if !clamped {
                        v_o = v_alpha * ev.g;
                        let v_rho = -0.5 * v_alpha * o * ev.g;
                        let rho3 = ev.u * ev.u + ev.v * ev.v;
                        let dx = co.x - xf;
                        let dy = co.y - yf;
                        let rho2 = 2.0 * (dx * dx + dy * dy);
                        if rho3 <= rho2 {
                            gu += 2.0 * v_rho * ev.u;
                            gv += 2.0 * v_rho * ev.v;
                        } else {
                            v_c = 4.0 * v_rho * vec2<f32>(dx, dy);
                        }
                    }
                    let inv = ev.inv_pz;
                    let gp = vec3<f32>(gu * inv, gv * inv, -(gu * ev.u + gv * ev.v) * inv);
                    let gpx = xf * gp;
                    let gpy = yf * gp;
                    let v_col = w * gc;
                    let v_n = w * gn;
                    c0 = vec4<f32>(v_col, h_depth.x);
                    c1 = vec4<f32>(h_depth.y, h_depth.z, v_c.x, v_c.y);
                    c2 = vec4<f32>(v_o, v_n);
                    c3 = vec4<f32>(gp, gpx.x);
                    c4 = vec4<f32>(gpx.y, gpx.z, gpy.x, gpy.y);
                    c5 = vec4<f32>(gpy.z, w, 0.0, 0.0);
                }
            }
            stage_partials(c0, c1, c2, c3, c4, c5, sg, sg_lane);
            workgroupBarrier();
            write_partials(s_slot[j] * DIM, DIM, sg, sg_lane, sg_size, n_sg);
            workgroupBarrier();
        }
        hi = lo;
    }
    guard_loops(2u);
}

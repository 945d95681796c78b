// Forward compositing (SPEC 1, Eqn 3): one workgroup per 16 x 16 tile, one thread per pixel,
// front to back over the tile's list in batches of BATCH entries staged in workgroup memory.
// Per pixel exactly svgir_raster's rules (forward.rs): an entry outside the splat's box or that
// fails the exact ray-splat tests is skipped; one that would take T below t_stop ends the pixel
// uncomposited. The tile stops when all its pixels have ended.
//
// Outputs: colour (+ T_N bg), alpha, depth (undivided), median depth (z of the last entry
// composited while T > 0.5), camera-facing normal, 2DGS's running-sum distortion. Saved for the
// backward: final T, the count of list entries up to the last composited one, and the distortion
// moments M1 = sum w m, M2 = sum w m^2.

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> splat: array<f32>;
@group(0) @binding(2) var<storage, read> rect: array<u32>;
@group(0) @binding(3) var<storage, read> ranges: array<u32>;
@group(0) @binding(4) var<storage, read> tval: array<u32>;
@group(0) @binding(5) var<storage, read> egauss: array<u32>;
// Per pixel: colour (3), alpha, depth, median, normal (3), distortion, final T, M1, M2 (13).
@group(0) @binding(6) var<storage, read_write> img: array<f32>;
@group(0) @binding(7) var<storage, read_write> ncon: array<u32>;
// Loops cut short (loop_guard.wgsl): bit 1.
@group(0) @binding(8) var<storage, read_write> status: array<atomic<u32>, 2>;

const BATCH: u32 = 128u;
const PIX: u32 = 13u;

// The batch arrays and `stage` are in stage.wgsl.
var<workgroup> done_count: atomic<u32>;

// One-dimensional workgroups: subgroup built-ins need them.
@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) tid: u32) {
    let tile = wid.y * P.tiles_x + wid.x;
    let px = wid.x * TILE + tid % TILE;
    let py = wid.y * TILE + tid / TILE;
    let inside = px < P.width && py < P.height;
    let xf = f32(px) + 0.5;
    let yf = f32(py) + 0.5;
    let near = P.clip.x;
    let far = P.clip.y;
    let t_stop = P.clip.z;
    let m_scale = far / (far - near);
    let dist_on = (P.flags & FLAG_DISTORTION) != 0u;
    let geom = (P.flags & FLAG_GEOMETRY) != 0u;
    let normals = geom && (P.flags & FLAG_NORMALS) != 0u;
    let r0 = ranges[tile * 2u];
    let r1 = ranges[tile * 2u + 1u];

    var t = 1.0;
    var color = vec3<f32>(0.0);
    var normal = vec3<f32>(0.0);
    var depth = 0.0;
    var median = 0.0;
    var dist = 0.0;
    var m1 = 0.0;
    var m2 = 0.0;
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
            color += w * s_col[j];
            if normals {
                normal += w * s_n[j];
            }
            if geom {
                depth += w * ev.z;
                if t > 0.5 {
                    median = ev.z;
                }
            }
            if dist_on {
                // 2DGS running-sum distortion: w_i (m_i^2 A_i + M2 - 2 m_i M1), A_i = 1 - T_i.
                let m = m_scale * (1.0 - near / ev.z);
                dist += (m * m * (1.0 - t) + m2 - 2.0 * m * m1) * w;
                m1 += m * w;
                m2 += m * m * w;
            }
            t = test;
            nc = b0 + j - r0 + 1u;
        }
    }
    if inside {
        let p = py * P.width + px;
        let o = p * PIX;
        let c = color + t * P.bg.xyz;
        img[o] = c.x;
        img[o + 1u] = c.y;
        img[o + 2u] = c.z;
        img[o + 3u] = 1.0 - t;
        img[o + 4u] = depth;
        img[o + 5u] = median;
        img[o + 6u] = normal.x;
        img[o + 7u] = normal.y;
        img[o + 8u] = normal.z;
        img[o + 9u] = dist;
        img[o + 10u] = t;
        img[o + 11u] = m1;
        img[o + 12u] = m2;
        ncon[p] = nc;
    }
    guard_loops(1u);
}

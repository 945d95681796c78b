// The micro-buffer march on the GPU (SPEC 5, Eqn 12), as svgir_trace::traverse and
// svgir_trace::microbuffer compute it on the CPU: for ray (j, k) from Gaussian j's centre along
// its k-th Fibonacci hemisphere direction, every hit in (t, id) order -- never t alone -- with
// the continuation offsets, the transmittance T, the visibility transmittance and, with
// F_RADIANCE, the traced radiance; written packed, 16 bytes a sample.
//
// Work split: one thread per ray, rays `base .. base + count` of this dispatch in the order
// j * K + k, so the 64 threads of a workgroup are one Gaussian's (or two's) rays: one origin,
// nearby directions, the same BVH nodes. Each thread runs the CPU's k-buffer with restarts: a
// traversal of the BVH (built on the CPU, svgir_trace::Bvh, read as is) collects the FIRST_PASS
// (later KBUF) smallest keys after a cursor in private arrays, pruning nodes that start past the
// buffer's last key; the buffer is consumed in order, and a full buffer restarts the traversal
// after its last key. No atomics, no shared memory, no host round trip: one dispatch per chunk.
//
// Saves nothing for a backward: stage 2 freezes the geometry (SPEC 6), so the samples are
// constants of its objective. With F_RECORD each ray also writes its direction and the first
// `record_max` hits it consumed (t, id, alpha, u, v), for the tests against the CPU traversal.

struct TraceParams {
    t_max: f32,
    eps: f32,
    eps_scale: f32,
    t_stop: f32,
    v_cut: f32,
    l_max: f32,
    vis_gain: f32,
    _pad0: f32,
    nodes: u32,      // BVH nodes (0: every ray escapes)
    k: u32,          // directions per Gaussian
    base: u32,       // first ray of this dispatch (j * K + k)
    count: u32,      // rays in this dispatch
    sh_degree: u32,  // min(model degree, radiance degree)
    flags: u32,
    record_max: u32, // hits recorded per ray with F_RECORD
    _pad1: u32,
}

const F_CULL: u32 = 1u;     // TraceParams::cull_backfaces
const F_LINEAR: u32 = 2u;   // TraceParams::linear_radiance
const F_RADIANCE: u32 = 4u; // march (with L) rather than march_visibility
const F_RECORD: u32 = 8u;   // write the consumed hits to `record`
const F_FIXED: u32 = 16u;   // `fib` holds one direction per k, the same for every Gaussian

const KBUF: u32 = 16u;       // svgir_trace::traverse::KBUF
const FIRST_PASS: u32 = 4u;  // svgir_trace::traverse::FIRST_PASS
const STACK: u32 = 104u;     // 2 * bvh::MAX_DEPTH + 8
const NO_HIT: u32 = 0xffffffffu;
const PARALLEL_EPS: f32 = 1e-12;
const SUPPORT_R2: f32 = 9.0;
const ALPHA_MIN: f32 = 1.0 / 255.0;
const ALPHA_MAX: f32 = 0.99;

@group(0) @binding(0) var<uniform> P: TraceParams;
// Node i: (lo, bitcast offset), (hi, bitcast count) -- svgir_trace::Node's 32 bytes.
@group(0) @binding(1) var<storage, read> nodes: array<vec4<f32>>;
// Disk i in leaf order: (center, opacity), (normal, max scale), (t_u / s_u, bitcast id),
// (t_v / s_v, 0) -- svgir_trace::Disk's 64 bytes.
@group(0) @binding(2) var<storage, read> disks: array<vec4<f32>>;
// 16 x RGB SH coefficients per Gaussian (svgir_core::ShCoeffs).
@group(0) @binding(3) var<storage, read> sh: array<f32>;
// Per Gaussian: (origin, t_start), (b1, cos xi), (b2, sin xi), (axis, 0): the ray source and its
// hemisphere frame (svgir_shading::HemiFrame), prepared on the CPU.
@group(0) @binding(4) var<storage, read> sources: array<vec4<f32>>;
// Per direction k: (cos g_k, sin g_k, r_k, z_k) (svgir_shading::FibTable); with F_FIXED the
// directions themselves, (d_k, 0).
@group(0) @binding(5) var<storage, read> fib: array<vec4<f32>>;
// Per ray of the dispatch: (V unorm16 | L.r f16 << 16, L.g | L.b << 16, first hit, u~ | v~ << 16).
@group(0) @binding(6) var<storage, read_write> samples: array<vec4<u32>>;
// F_RECORD: per ray 1 + 2 * record_max vec4s: (dir, bitcast hits consumed), then per hit
// (t, bitcast id, alpha, u), (v, 0, 0, 0).
@group(0) @binding(7) var<storage, read_write> record: array<vec4<f32>>;
// Loops cut short (loop_guard.wgsl): bit 16.
@group(0) @binding(8) var<storage, read_write> status: array<atomic<u32>, 2>;

var<private> kb_t: array<f32, KBUF>;
var<private> kb_id: array<u32, KBUF>;
var<private> kb_a: array<f32, KBUF>;
var<private> kb_u: array<f32, KBUF>;
var<private> kb_v: array<f32, KBUF>;
var<private> kb_s: array<f32, KBUF>;
var<private> kb_len: u32;
var<private> st_node: array<u32, STACK>;
var<private> st_t: array<f32, STACK>;

struct Ray {
    o: vec3<f32>,
    d: vec3<f32>,
    t_start: f32,
    ignore: u32,
}

// A position in the (t, id) order; `open` is the CPU's id = -1 (accepts t >= t).
struct Cursor {
    t: f32,
    id: u32,
    open: bool,
}

fn accepts(c: Cursor, t: f32, id: u32) -> bool {
    return t > c.t || (t == c.t && (c.open || id > c.id));
}

fn key_less(t0: f32, id0: u32, t1: f32, id1: u32) -> bool {
    return t0 < t1 || (t0 == t1 && id0 < id1);
}

// Cursor::max: the later of the two (an open cursor sorts before every id at its t).
fn cursor_max(a: Cursor, b: Cursor) -> Cursor {
    if b.t > a.t || (b.t == a.t && !b.open && (a.open || b.id > a.id)) {
        return b;
    }
    return a;
}

// Cursor::after: where the march resumes after consuming a hit (SPEC 5 continuation offset).
fn cursor_after(t: f32, id: u32, max_scale: f32) -> Cursor {
    let off = P.eps + P.eps_scale * max_scale;
    let ta = t + off;
    if off > 0.0 && ta > t {
        return Cursor(ta, 0u, true);
    }
    return Cursor(t, id, false);
}

// KBuffer::admits for a buffer of capacity `cap`.
fn admits(t: f32, id: u32, cap: u32) -> bool {
    return kb_len < cap || key_less(t, id, kb_t[kb_len - 1u], kb_id[kb_len - 1u]);
}

// KBuffer::insert (the caller has checked `admits`).
fn kb_insert(t: f32, id: u32, a: f32, u: f32, v: f32, s: f32, cap: u32) {
    if kb_len == cap {
        kb_len -= 1u;
    }
    var i = kb_len;
    while i > 0u && key_less(t, id, kb_t[i - 1u], kb_id[i - 1u]) {
        kb_t[i] = kb_t[i - 1u];
        kb_id[i] = kb_id[i - 1u];
        kb_a[i] = kb_a[i - 1u];
        kb_u[i] = kb_u[i - 1u];
        kb_v[i] = kb_v[i - 1u];
        kb_s[i] = kb_s[i - 1u];
        i -= 1u;
    }
    kb_t[i] = t;
    kb_id[i] = id;
    kb_a[i] = a;
    kb_u[i] = u;
    kb_v[i] = v;
    kb_s[i] = s;
    kb_len += 1u;
}

// Entry and exit distance of node i's box.
fn slab(i: u32, o: vec3<f32>, inv: vec3<f32>) -> vec2<f32> {
    let t0 = (nodes[2u * i].xyz - o) * inv;
    let t1 = (nodes[2u * i + 1u].xyz - o) * inv;
    let a = min(t0, t1);
    let b = max(t0, t1);
    return vec2<f32>(max(a.x, max(a.y, a.z)), min(b.x, min(b.y, b.z)));
}

// Bvh::collect: the `cap` smallest keys accepted by `cursor` with t < t_max into kb_*.
fn collect(ray: Ray, cursor: Cursor, cap: u32) {
    kb_len = 0u;
    if P.nodes == 0u {
        return;
    }
    // Exact zeros would make 0 * inf = NaN in the slab test (as on the CPU).
    let tiny = vec3<f32>(1e-30);
    let dc = select(ray.d, select(-tiny, tiny, ray.d >= vec3<f32>(0.0)), abs(ray.d) < tiny);
    let inv = vec3<f32>(1.0) / dc;
    let root = slab(0u, ray.o, inv);
    if root.x > root.y || root.y < cursor.t || root.x > P.t_max {
        return;
    }
    var sp = 1u;
    st_node[0] = 0u;
    st_t[0] = root.x;
    while sp > 0u {
        sp -= 1u;
        let i = st_node[sp];
        let tn = st_t[sp];
        var limit = P.t_max;
        if kb_len == cap {
            limit = kb_t[kb_len - 1u];
        }
        if tn > limit {
            continue;
        }
        let lo = nodes[2u * i];
        let hi = nodes[2u * i + 1u];
        let offset = bitcast<u32>(lo.w);
        let count = bitcast<u32>(hi.w);
        if count > 0u {
            for (var q = offset; q < offset + count; q++) {
                let c = disks[4u * q];
                let nm = disks[4u * q + 1u];
                let au = disks[4u * q + 2u];
                let id = bitcast<u32>(au.w);
                // may_hit: never the ray's own disk; optionally only against the normal.
                if id == ray.ignore || ((P.flags & F_CULL) != 0u && dot(nm.xyz, ray.d) >= 0.0) {
                    continue;
                }
                // Disk::intersect_if, with the key tested before the tangent coordinates.
                let denom = dot(nm.xyz, ray.d);
                if abs(denom) < PARALLEL_EPS {
                    continue;
                }
                let rel = ray.o - c.xyz;
                let t = -dot(nm.xyz, rel) / denom;
                if !(t < P.t_max && accepts(cursor, t, id) && admits(t, id, cap)) {
                    continue;
                }
                let x = rel + t * ray.d;
                let u = dot(x, au.xyz);
                let v = dot(x, disks[4u * q + 3u].xyz);
                let r2 = u * u + v * v;
                if !(r2 <= SUPPORT_R2) {
                    continue;
                }
                let alpha = min(c.w * exp(-0.5 * r2), ALPHA_MAX);
                if alpha < ALPHA_MIN {
                    continue;
                }
                kb_insert(t, id, alpha, u, v, nm.w, cap);
            }
        } else {
            let l = i + 1u;
            let r = offset;
            let ls = slab(l, ray.o, inv);
            let rs = slab(r, ray.o, inv);
            let lok = ls.x <= ls.y && ls.y >= cursor.t && ls.x <= limit;
            let rok = rs.x <= rs.y && rs.y >= cursor.t && rs.x <= limit;
            // The far child first, so the near one is processed next.
            if lok && rok {
                if ls.x <= rs.x {
                    st_node[sp] = r;
                    st_t[sp] = rs.x;
                    st_node[sp + 1u] = l;
                    st_t[sp + 1u] = ls.x;
                } else {
                    st_node[sp] = l;
                    st_t[sp] = ls.x;
                    st_node[sp + 1u] = r;
                    st_t[sp + 1u] = rs.x;
                }
                sp += 2u;
            } else if lok {
                st_node[sp] = l;
                st_t[sp] = ls.x;
                sp += 1u;
            } else if rok {
                st_node[sp] = r;
                st_t[sp] = rs.x;
                sp += 1u;
            }
        }
    }
}

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        return c / 12.92;
    }
    return pow((c + 0.055) / 1.055, 2.4);
}

// The hit Gaussian's SH colour towards d: max(0, 0.5 + SH(d)) (ShCoeffs::eval), sRGB-decoded
// with F_LINEAR.
fn sh_color(id: u32, d: vec3<f32>) -> vec3<f32> {
    var b: array<f32, 16>;
    sh_basis(P.sh_degree, d, &b);
    let n = (P.sh_degree + 1u) * (P.sh_degree + 1u);
    var c = vec3<f32>(0.5);
    for (var k = 0u; k < n; k++) {
        let o = id * 48u + 3u * k;
        c += b[k] * vec3<f32>(sh[o], sh[o + 1u], sh[o + 2u]);
    }
    c = max(c, vec3<f32>(0.0));
    if (P.flags & F_LINEAR) != 0u {
        c = vec3<f32>(srgb_to_linear(c.x), srgb_to_linear(c.y), srgb_to_linear(c.z));
    }
    return c;
}

// svgir_trace::pack::f16_from_f32: IEEE half bits, round to nearest even.
fn f16_bits(x: f32) -> u32 {
    let b = bitcast<u32>(x);
    let sign = (b >> 16u) & 0x8000u;
    let ex = i32((b >> 23u) & 0xffu);
    let man = b & 0x007fffffu;
    if ex == 0xff {
        return sign | 0x7c00u | select(0u, 0x200u, man != 0u);
    }
    let e = ex - 127 + 15;
    if e >= 0x1f {
        return sign | 0x7c00u;
    }
    if e <= 0 {
        if e < -10 {
            return sign;
        }
        let m = man | 0x00800000u;
        let shift = u32(14 - e);
        let half = 1u << (shift - 1u);
        let rem = m & ((1u << shift) - 1u);
        var r = m >> shift;
        if rem > half || (rem == half && (r & 1u) == 1u) {
            r += 1u;
        }
        return sign | r;
    }
    var r = (u32(e) << 10u) | (man >> 13u);
    let rem = man & 0x1fffu;
    if rem > 0x1000u || (rem == 0x1000u && (r & 1u) == 1u) {
        r += 1u;
    }
    return sign | r;
}

// svgir_trace::pack::unorm16.
fn unorm16(x: f32) -> u32 {
    return u32(clamp(x, 0.0, 1.0) * 65535.0 + 0.5);
}

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let local = (wid.x + wid.y * nwg.x) * 64u + li;
    if local >= P.count {
        return;
    }
    let ray_id = P.base + local;
    let j = ray_id / P.k;
    let kk = ray_id % P.k;
    // The ray (Ray::from_gaussian) along direction kk (HemiFrame::dir).
    let s0 = sources[4u * j];
    let s1 = sources[4u * j + 1u];
    let s2 = sources[4u * j + 2u];
    let s3 = sources[4u * j + 3u];
    let f = fib[kk];
    var d: vec3<f32>;
    if (P.flags & F_FIXED) != 0u {
        // A light's column (svgir_trace::bright::trace_column): the same direction for every
        // Gaussian, 0 below its hemisphere.
        d = f.xyz;
        if dot(s3.xyz, d) <= 0.0 {
            samples[local] = vec4<u32>(0u, 0u, NO_HIT, 0u);
            return;
        }
    } else {
        let cphi = f.x * s1.w - f.y * s2.w;
        let sphi = f.y * s1.w + f.x * s2.w;
        d = s1.xyz * (f.z * cphi) + s2.xyz * (f.z * sphi) + s3.xyz * f.w;
    }
    let ray = Ray(s0.xyz, d, s0.w, j);
    let recording = (P.flags & F_RECORD) != 0u;
    let rbase = local * (1u + 2u * P.record_max);

    // HitSource::for_each_hit with the march (or the visibility march) as the visitor.
    var cursor = Cursor(ray.t_start, 0u, true);
    var cont = cursor;
    var cap = FIRST_PASS;
    var l = vec3<f32>(0.0);
    var tr = 1.0;
    var tv = 1.0;
    var first = NO_HIT;
    var fu = 0.0;
    var fv = 0.0;
    var hits = 0u;
    var done = false;
    loop {
        collect(ray, cursor, cap);
        let full = kb_len == cap;
        for (var h = 0u; h < kb_len; h++) {
            if !accepts(cont, kb_t[h], kb_id[h]) {
                continue;
            }
            let a = kb_a[h];
            if first == NO_HIT {
                first = kb_id[h];
                fu = kb_u[h];
                fv = kb_v[h];
            }
            if recording && hits < P.record_max {
                record[rbase + 1u + 2u * hits] = vec4<f32>(kb_t[h], bitcast<f32>(kb_id[h]), a, kb_u[h]);
                record[rbase + 2u + 2u * hits] = vec4<f32>(kb_v[h], 0.0, 0.0, 0.0);
            }
            hits += 1u;
            if (P.flags & F_RADIANCE) != 0u {
                l += sh_color(kb_id[h], ray.d) * (a * tr);
            }
            tr *= 1.0 - a;
            tv *= 1.0 - min(a * P.vis_gain, ALPHA_MAX);
            var more = tr >= P.t_stop;
            if (P.flags & F_RADIANCE) == 0u {
                more = more && tv >= P.v_cut;
            }
            if !more {
                done = true;
                break;
            }
            cont = cursor_after(kb_t[h], kb_id[h], kb_s[h]);
        }
        if done || !full {
            break;
        }
        cursor = cursor_max(cont, Cursor(kb_t[kb_len - 1u], kb_id[kb_len - 1u], false));
        cap = KBUF;
    }
    if recording {
        record[rbase] = vec4<f32>(d, bitcast<f32>(hits));
    }
    let lc = clamp(l, vec3<f32>(0.0), vec3<f32>(P.l_max));
    let vis = select(tv, 0.0, tv < P.v_cut);
    var uv = 0u;
    if first != NO_HIT {
        uv = unorm16(clamp(0.5 + 0.5 * fu, 0.001, 0.999)) | (unorm16(clamp(0.5 + 0.5 * fv, 0.001, 0.999)) << 16u);
    }
    samples[local] = vec4<u32>(unorm16(vis) | (f16_bits(lc.x) << 16u), f16_bits(lc.y) | (f16_bits(lc.z) << 16u), first, uv);
    guard_loops(16u);
}

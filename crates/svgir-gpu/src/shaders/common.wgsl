// Shared by the rasterizer's kernels: the per-render parameters, the splat record's layout,
// the quaternion rotation and the SH basis (3DGS's signs, as svgir_core::sh).

struct Params {
    // World-to-camera rotation rows (w unused) and translation.
    r0: vec4<f32>,
    r1: vec4<f32>,
    r2: vec4<f32>,
    t: vec4<f32>,
    // Camera centre in world space (w unused).
    center: vec4<f32>,
    // fx, fy, cx, cy.
    k: vec4<f32>,
    // near, far, t_stop, unused.
    clip: vec4<f32>,
    // Background colour (w unused).
    bg: vec4<f32>,
    n: u32,
    width: u32,
    height: u32,
    sh_degree: u32,
    tiles_x: u32,
    tiles_y: u32,
    // Bit 0: distortion, bit 1: geometry (depth, median depth), bit 2: normals.
    flags: u32,
    // Length of the entry buffers: a render that bins more entries keeps the first `capacity`
    // and flags the overflow in `count` (bin_total.wgsl).
    capacity: u32,
}

// The binning counters (`count` buffer, u32s): entries kept, entries binned, whether this
// render overflowed, the most entries binned and the overflowed renders since the host last
// cleared them.
const C_KEPT: u32 = 0u;
const C_TOTAL: u32 = 1u;
const C_OVERFLOW: u32 = 2u;
const C_MAX: u32 = 3u;
const C_OVERFLOWS: u32 = 4u;

// The splat record, SPLAT floats per Gaussian (see project.wgsl).
const SPLAT: u32 = 24u;
const S_H: u32 = 0u;        // H rows T_u, T_v, T_w (9)
const S_CENTER: u32 = 9u;   // projected centre, pixels (2)
const S_OPACITY: u32 = 11u; // sigmoid(opacity logit)
const S_DEPTH: u32 = 12u;   // camera depth of the centre
const S_NORMAL: u32 = 13u;  // world normal flipped to face the camera (3)
const S_FLIP: u32 = 16u;    // +1 or -1
const S_SCALE: u32 = 17u;   // exp(log-scales) (2)
const S_COLOR: u32 = 19u;   // SH colour, clamped at 0 (3)
const S_CLAMPED: u32 = 22u; // bit c set when colour channel c was clamped, as a float
const S_RADIUS: u32 = 23u;  // 2DGS's 3-sigma screen radius

const FLAG_DISTORTION: u32 = 1u;
const FLAG_GEOMETRY: u32 = 2u;
const FLAG_NORMALS: u32 = 4u;

const TILE: u32 = 16u;

// Floats per Gaussian of the parameter gradients besides SH (project_bwd.wgsl): position 3,
// rotation 4, log-scale 2, opacity logit, screen-position gradient norm, composited weight.
const VP: u32 = 12u;

const SH_C0: f32 = 0.2820948;
const SH_C1: f32 = 0.48860252;

// Rotation matrix columns (t_u, t_v, n) of the normalised quaternion (x, y, z, w), as
// svgir_raster::preprocess::quat_to_rot; returns the matrix as three rows.
fn quat_rows(q: vec4<f32>) -> mat3x3<f32> {
    let len = sqrt(dot(q.xyz, q.xyz) + q.w * q.w);
    let x = q.x / len;
    let y = q.y / len;
    let z = q.z / len;
    let w = q.w / len;
    // mat3x3 is column-major: column c here holds row c of R.
    return mat3x3<f32>(
        vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)),
        vec3<f32>(2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)),
        vec3<f32>(2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)),
    );
}

// Column c of the rotation whose rows are `rows` (rows[i] = row i).
fn rot_col(rows: mat3x3<f32>, c: u32) -> vec3<f32> {
    return vec3<f32>(rows[0][c], rows[1][c], rows[2][c]);
}

// World-to-camera rotation applied to v.
fn cam_rot(p: Params, v: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(p.r0.xyz, v), dot(p.r1.xyz, v), dot(p.r2.xyz, v));
}

// Its transpose applied to v.
fn cam_rot_t(p: Params, v: vec3<f32>) -> vec3<f32> {
    return p.r0.xyz * v.x + p.r1.xyz * v.y + p.r2.xyz * v.z;
}

// The SH basis up to `deg` for the unit direction d (svgir_core::sh::basis).
fn sh_basis(deg: u32, d: vec3<f32>, b: ptr<function, array<f32, 16>>) {
    let x = d.x;
    let y = d.y;
    let z = d.z;
    for (var k = 0u; k < 16u; k++) {
        (*b)[k] = 0.0;
    }
    (*b)[0] = SH_C0;
    if deg < 1u {
        return;
    }
    (*b)[1] = -SH_C1 * y;
    (*b)[2] = SH_C1 * z;
    (*b)[3] = -SH_C1 * x;
    if deg < 2u {
        return;
    }
    let xx = x * x;
    let yy = y * y;
    let zz = z * z;
    (*b)[4] = 1.0925485 * x * y;
    (*b)[5] = -1.0925485 * y * z;
    (*b)[6] = 0.31539157 * (2.0 * zz - xx - yy);
    (*b)[7] = -1.0925485 * x * z;
    (*b)[8] = 0.54627424 * (xx - yy);
    if deg < 3u {
        return;
    }
    (*b)[9] = -0.5900436 * y * (3.0 * xx - yy);
    (*b)[10] = 2.8906114 * x * y * z;
    (*b)[11] = -0.4570458 * y * (4.0 * zz - xx - yy);
    (*b)[12] = 0.37317634 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
    (*b)[13] = -0.4570458 * x * (4.0 * zz - xx - yy);
    (*b)[14] = 1.4453057 * z * (xx - yy);
    (*b)[15] = -0.5900436 * x * (xx - 3.0 * yy);
}

// Its Jacobian: g[k] = d basis_k / d (x, y, z) (svgir_core::sh::basis_grad).
fn sh_basis_grad(deg: u32, d: vec3<f32>, g: ptr<function, array<vec3<f32>, 16>>) {
    let x = d.x;
    let y = d.y;
    let z = d.z;
    for (var k = 0u; k < 16u; k++) {
        (*g)[k] = vec3<f32>(0.0);
    }
    if deg < 1u {
        return;
    }
    (*g)[1] = vec3<f32>(0.0, -SH_C1, 0.0);
    (*g)[2] = vec3<f32>(0.0, 0.0, SH_C1);
    (*g)[3] = vec3<f32>(-SH_C1, 0.0, 0.0);
    if deg < 2u {
        return;
    }
    (*g)[4] = 1.0925485 * vec3<f32>(y, x, 0.0);
    (*g)[5] = -1.0925485 * vec3<f32>(0.0, z, y);
    (*g)[6] = 0.31539157 * vec3<f32>(-2.0 * x, -2.0 * y, 4.0 * z);
    (*g)[7] = -1.0925485 * vec3<f32>(z, 0.0, x);
    (*g)[8] = 0.54627424 * vec3<f32>(2.0 * x, -2.0 * y, 0.0);
    if deg < 3u {
        return;
    }
    let xx = x * x;
    let yy = y * y;
    let zz = z * z;
    (*g)[9] = -0.5900436 * vec3<f32>(6.0 * x * y, 3.0 * xx - 3.0 * yy, 0.0);
    (*g)[10] = 2.8906114 * vec3<f32>(y * z, x * z, x * y);
    (*g)[11] = -0.4570458 * vec3<f32>(-2.0 * x * y, 4.0 * zz - xx - 3.0 * yy, 8.0 * y * z);
    (*g)[12] = 0.37317634 * vec3<f32>(-6.0 * x * z, -6.0 * y * z, 6.0 * zz - 3.0 * xx - 3.0 * yy);
    (*g)[13] = -0.4570458 * vec3<f32>(4.0 * zz - 3.0 * xx - yy, -2.0 * x * y, 8.0 * x * z);
    (*g)[14] = 1.4453057 * vec3<f32>(2.0 * x * z, -2.0 * y * z, xx - yy);
    (*g)[15] = -0.5900436 * vec3<f32>(3.0 * xx - 3.0 * yy, -6.0 * x * y, 0.0);
}

// exp(x) as svgir_core::float::exp_f32 (what the CPU kernels' exp_fast is): 2^n p(r),
// x = n ln2 + r, p the degree-6 Taylor polynomial in Estrin's form. The driver's own exp may be
// a coarser approximation (Vulkan allows 3 + 2|x| ulp); this one is the same on every device.
fn exp_poly(x_in: f32) -> f32 {
    let x = clamp(x_in, -87.0, 88.0);
    // round() rather than the CPU's 1.5 * 2^23 shifter, which a driver's algebraic
    // simplification may cancel (lavapipe's does); both round half to even.
    let n = round(x * 1.4426950408889634);
    let r = x - n * 0.69314575 - n * 1.4286068e-6;
    let r2 = r * r;
    let r4 = r2 * r2;
    let a = 1.0 + r;
    let b = 0.5 + r * (1.0 / 6.0);
    let d = (1.0 / 24.0 + r * (1.0 / 120.0)) + r2 * (1.0 / 720.0);
    let p = (a + r2 * b) + r4 * d;
    let bits = u32(i32(n) + 127) << 23u;
    return p * bitcast<f32>(bits);
}

// One ray-splat evaluation at pixel centre (x, y), as svgir_raster::splat::eval_px: returns
// (alpha or 0 when the pixel is skipped, u, v, z, g, 1 / p.z). `a` = T_v x T_w, `bw` = T_u x
// T_w, `b0` = T_u x T_v (the plane set-up), `hw` = T_w.
struct Eval {
    alpha: f32,
    u: f32,
    v: f32,
    z: f32,
    g: f32,
    inv_pz: f32,
}

fn eval_px(a: vec3<f32>, bw: vec3<f32>, b0: vec3<f32>, hw: vec3<f32>, c: vec2<f32>, o: f32, x: f32, y: f32, near: f32) -> Eval {
    let b = y * bw - b0;
    let px = x * a.x - b.x;
    let py = x * a.y - b.y;
    let pz = x * a.z - b.z;
    let inv = 1.0 / pz;
    let u = px * inv;
    let v = py * inv;
    let rho3 = u * u + v * v;
    let dx = c.x - x;
    let dy = c.y - y;
    let rho2 = 2.0 * (dx * dx + dy * dy);
    let rho = select(rho2, rho3, rho3 <= rho2);
    let z = u * hw.x + v * hw.y + hw.z;
    let g = exp_poly(-0.5 * rho);
    let aa = o * g;
    let alpha = select(aa, 0.99, aa > 0.99);
    let valid = pz != 0.0 && rho <= 9.0 && z >= near && alpha >= (1.0 / 255.0);
    return Eval(select(0.0, alpha, valid), u, v, z, g, inv);
}

// The splats of one batch of a tile's list staged in workgroup memory, shared by raster_fwd.wgsl
// and raster_bwd.wgsl (each sets BATCH and binds `splat` and `rect`): the cross products of H's
// rows the ray-splat hit needs (SPLAT's record, see project.wgsl), T_w, centre and opacity,
// normal, colour and the screen box.

var<workgroup> s_a: array<vec3<f32>, BATCH>;
var<workgroup> s_bw: array<vec3<f32>, BATCH>;
var<workgroup> s_b0: array<vec3<f32>, BATCH>;
var<workgroup> s_hw: array<vec3<f32>, BATCH>;
// centre x, y, opacity, unused
var<workgroup> s_co: array<vec4<f32>, BATCH>;
var<workgroup> s_n: array<vec3<f32>, BATCH>;
var<workgroup> s_col: array<vec3<f32>, BATCH>;
var<workgroup> s_rect: array<vec4<u32>, BATCH>;

// Stages Gaussian g into batch slot k.
fn stage(k: u32, g: u32) {
    let s = g * SPLAT;
    let hu = vec3<f32>(splat[s], splat[s + 1u], splat[s + 2u]);
    let hv = vec3<f32>(splat[s + 3u], splat[s + 4u], splat[s + 5u]);
    let hw = vec3<f32>(splat[s + 6u], splat[s + 7u], splat[s + 8u]);
    s_a[k] = cross(hv, hw);
    s_bw[k] = cross(hu, hw);
    s_b0[k] = cross(hu, hv);
    s_hw[k] = hw;
    s_co[k] = vec4<f32>(splat[s + S_CENTER], splat[s + S_CENTER + 1u], splat[s + S_OPACITY], 0.0);
    s_n[k] = vec3<f32>(splat[s + S_NORMAL], splat[s + S_NORMAL + 1u], splat[s + S_NORMAL + 2u]);
    s_col[k] = vec3<f32>(splat[s + S_COLOR], splat[s + S_COLOR + 1u], splat[s + S_COLOR + 2u]);
    s_rect[k] = vec4<u32>(rect[g * 4u], rect[g * 4u + 1u], rect[g * 4u + 2u], rect[g * 4u + 3u]);
}

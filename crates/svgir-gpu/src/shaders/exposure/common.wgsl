// Shared by the per-photo colour correction's kernels (svgir_train::exposure, its CPU oracle):
// the loss compares the render's object corrected, `A f + b a + bg (1 - a)` for a render
// `c = f + bg (1 - a)`, with photo i; A (3x3, row-major) and b are the 12 numbers of the photo's
// row in `params` (a row is 64 floats, so that the host can bind one row at a 256-byte offset
// for the Adam step, adam.wgsl).

struct ExposureParams {
    // Pixels of the render.
    npx: u32,
    // First float of this photo's row in `params`.
    row: u32,
    // Workgroups of the per-pixel kernels (rows of `partials`).
    groups: u32,
    _pad: u32,
    // The background the render is composited over (xyz).
    bg: vec4<f32>,
}

// The forward's per-pixel record (raster_fwd.wgsl): colour 0..3, opacity 3, of 13 floats.
const PIX: u32 = 13u;
// The output gradients (raster_bwd.wgsl): colour 0..3, opacity 3, of 9 floats.
const VPIX: u32 = 9u;
// Gradient floats per photo: A's 9, then b's 3.
const PARAMS: u32 = 12u;

// Shared by the feature raster's kernels (feat_fwd, feat_bwd, feat_sum): the feature tables'
// uniform.

struct Feat {
    // Vertices per Gaussian (1, 2, 4 or 6), shared by both tables.
    m: u32,
    // Extra channels per vertex (0..=MAX_EXTRA), and how many of them are interpolated (the
    // rest hold one value per Gaussian, read at vertex 0).
    ce: u32,
    lerped: u32,
    // Floats per entry slot and per Gaussian of the gradients: opacity, weight, colour (3 m),
    // extra (m ce).
    fd: u32,
    // Floats per pixel of the outputs (7 + ce) and of the output gradients (5 + ce).
    pix: u32,
    vpix: u32,
    // Where the extra table starts in `feat` (after the colour table's n m 3 floats).
    ext_at: u32,
    pad: u32,
}

const MAX_EXTRA: u32 = 16u;

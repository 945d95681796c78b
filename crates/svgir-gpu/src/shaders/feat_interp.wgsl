// Shared by feat_fwd.wgsl and feat_bwd.wgsl (each binds `F` and `feat`): the Gaussian-vertex
// interpolation weights (SPEC 3, svgir_raster::interp) and one channel of a feature table at a
// hit (svgir_raster::forward::FeatView::eval).

// SPEC 3: u~ = clamp(0.5 + 0.5 u, 0.001, 0.999).
fn norm_coord(u: f32) -> f32 {
    return clamp(0.5 + 0.5 * u, 0.001, 0.999);
}

// Weights of the m vertices at the hit (u, v) in sigma units; vertex order u~ fastest
// (interp.rs): M = 2 linear, M = 4 bilinear, M = 6 quadratic Lagrange in u~ times linear in v~.
fn vertex_weights(m: u32, u: f32, v: f32) -> array<f32, 6> {
    var w: array<f32, 6>;
    if m == 1u {
        w[0] = 1.0;
        return w;
    }
    let ut = norm_coord(u);
    let vt = norm_coord(v);
    if m == 2u {
        w[0] = 1.0 - ut;
        w[1] = ut;
    } else if m == 4u {
        w[0] = (1.0 - ut) * (1.0 - vt);
        w[1] = ut * (1.0 - vt);
        w[2] = (1.0 - ut) * vt;
        w[3] = ut * vt;
    } else {
        let l0 = 2.0 * (ut - 0.5) * (ut - 1.0);
        let l1 = -4.0 * ut * (ut - 1.0);
        let l2 = 2.0 * ut * (ut - 0.5);
        w[0] = l0 * (1.0 - vt);
        w[1] = l1 * (1.0 - vt);
        w[2] = l2 * (1.0 - vt);
        w[3] = l0 * vt;
        w[4] = l1 * vt;
        w[5] = l2 * vt;
    }
    return w;
}

// Channel c of Gaussian g's row in the table at `at` (`chans` channels a vertex, the first
// `lerped` interpolated) at weights w: vertex 0's product, then the others' by FMA in vertex
// order, as the CPU kernels; a uniform channel as vertex 0 holds it.
fn feat_value(at: u32, chans: u32, lerped: u32, g: u32, c: u32, w_in: array<f32, 6>) -> f32 {
    var w = w_in;
    let base = at + g * F.m * chans;
    if F.m == 1u || c >= lerped {
        return feat[base + c];
    }
    // The vertices in order, as the CPU's loop adds them, written out: lavapipe counts every
    // loop iteration against its cap (loop_guard.wgsl).
    var out = w[0] * feat[base + c];
    out = fma(w[1], feat[base + chans + c], out);
    if F.m > 2u {
        out = fma(w[2], feat[base + 2u * chans + c], out);
        out = fma(w[3], feat[base + 3u * chans + c], out);
    }
    if F.m > 4u {
        out = fma(w[4], feat[base + 4u * chans + c], out);
        out = fma(w[5], feat[base + 5u * chans + c], out);
    }
    return out;
}

//! svgir-raster: the differentiable Gaussian-surfel rasterizer on the CPU (SPEC 1 and 3), forward
//! and hand-written backward.
//!
//! Geometry is 2DGS's exact ray-splat intersection in our OpenCV / pixel-centre convention: per
//! Gaussian the 3x3 matrix `H = K [R_c s_u t_u | R_c s_v t_v | R_c p + t_c]` maps tangent
//! coordinates `(u, v, 1)` (sigma units) to homogeneous pixel coordinates `(x w, y w, w)`, with
//! `w` the camera depth. Its rows are 2DGS's `T_u, T_v, T_w`; the pixel centre `(i + 0.5, j + 0.5)`
//! gives the planes `k = x T_w - T_u`, `l = y T_w - T_v` whose cross product is the hit `(u, v)`.
//! See [`splat`] for the per-pixel rules (filter, cut-offs), [`preprocess`] for culling and the
//! screen box, [`forward`] / [`backward`](mod@backward) for compositing.
//!
//! Every kernel is generic over [`Float`]: training uses `f32` ([`render`], [`backward()`]); the
//! tests run the same code in `f64` against finite differences of the dense [`reference`](mod@reference) renderer.

#![warn(missing_docs)]
// The lane kernels (AVX2 / AVX-512) and their helpers are compiled for x86-64 only; on other
// targets the generic kernels run and those helpers go unused. Dead code is still caught by the
// x86-64 build, which CI lints.
#![cfg_attr(not(target_arch = "x86_64"), allow(dead_code, unused_variables, unused_mut))]

pub mod backward;
mod backward_simd;
/// Timing tables for `svgir bench` (reads `/proc` and the clock).
#[cfg(feature = "bench")]
pub mod bench;
pub mod feature_raster;
pub mod fixtures;
pub mod forward;
mod forward_simd;
pub mod interp;
mod lane_groups;
pub mod phases;
pub mod preprocess;
pub mod preprocess_backward;
mod preprocess_backward_simd;
mod preprocess_simd;
pub mod reference;
pub mod simd;
pub mod splat;
pub mod tiles;
pub mod vec3;

use rayon::prelude::*;
use svgir_core::{Camera, ShCoeffs, Surfels};

pub use backward::backward_generic;
#[cfg(feature = "bench")]
pub use bench::bench_table;
pub use feature_raster::{CpuFeatureRaster, FeatureRaster, PassGrads, PassState};
pub use forward::render_generic;
pub use phases::PhaseTimes;
pub use simd::Simd;
pub use svgir_core::Float;

/// Rasterizer settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RasterConfig {
    /// Ray-splat hits closer than this (camera depth) are skipped; centres closer are culled.
    pub near: f32,
    /// Far value of the 2DGS depth-distortion depth mapping `m(z)`.
    pub far: f32,
    /// Compositing stops before a Gaussian would push transmittance below this (SPEC 1).
    pub t_stop: f32,
    /// Tile side in pixels (1..=64). The choice changes no image bit (every pixel composites the
    /// same Gaussians in the same order), and gradients only by the rounding of the per-entry
    /// sums. 32 by default: a splat of a trained scene covers a few pixels, so per-(tile,
    /// Gaussian) work -- records, lane-group listing, per-entry sums -- dominates, and 32-px tiles
    /// have a quarter fewer entries than GPU-style 16-px ones. Forward+backward, 2 threads:
    /// 400x400 / 100k random 82-84 -> 74-76 ms, lego_400's 246k trained Gaussians 150 -> 139 ms,
    /// the 256x256 and 128x128 scenes 5-10% faster; 48 and 64 measured no better than 32
    /// (docs/performance.md).
    pub tile: u32,
    /// Compute the depth-distortion output (2DGS). When false it is left at 0 and a gradient
    /// given for it is ignored, which saves a division and the moments per composited pixel
    /// (training with a zero distortion weight, as 2DGS on object scenes).
    pub distortion: bool,
    /// Compute the depth, median-depth and normal outputs. When false they are left at 0 and
    /// gradients given for them are ignored; colour, alpha and distortion are unchanged to the
    /// bit. The f32 tile kernels then skip those accumulators (about 5% of a forward+backward
    /// on a trained lego): for a loss that reads colour alone (3DGS's, the `views` profile).
    pub geometry: bool,
    /// With `geometry`, compute the normal output too. When false it is left at 0 and a gradient
    /// given for it is ignored, while depth and median depth are computed as before (to the
    /// bit): for a loss that reads the depth but not the splats' normals (stage 2's PBR pass,
    /// whose shading normals come as feature channels), three accumulators fewer per pixel.
    pub normals: bool,
    /// Compute the gradients of positions, rotations and log-scales (and the densification
    /// statistic `v_mean2d_norm`). When false they are returned as zeros, and the f32 tile
    /// kernels skip every per-pixel term that only reaches them: the hit's (u, v) and depth chain,
    /// the derivatives of the vertex weights, the centre and normal sums (a third of the
    /// backward tile work of stage 2's feature render, whose geometry is frozen, SPEC 6). The
    /// opacity, SH, colour, feature and background gradients keep their bits.
    pub geometry_grads: bool,
    /// Which f32 tile kernels run ([`Simd::Auto`]: `SVGIR_SIMD` or the best the CPU has). The
    /// choice changes no image bit, and gradients only by the rounding of per-Gaussian sums.
    pub simd: Simd,
    /// A backward of this render follows: the SIMD forward keeps its lane groups for it (six
    /// bytes a group, a few per (tile, Gaussian) entry), so the backward need not list each
    /// entry's pixels again (a fifth of its tile work on the random 400 x 400 / 100k scene).
    /// False for a render no backward reads, which saves the forward that writing; a backward
    /// of it still works, listing each entry itself, with the same gradients up to rounding.
    pub for_backward: bool,
}

impl Default for RasterConfig {
    fn default() -> Self {
        Self {
            near: 0.2,
            far: 1e4,
            t_stop: 1e-4,
            tile: 32,
            distortion: true,
            geometry: true,
            normals: true,
            geometry_grads: true,
            simd: Simd::Auto,
            for_backward: true,
        }
    }
}

/// Why an input cannot be rendered.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RasterError {
    /// The surfel arrays disagree in length or content (message says which).
    #[error("surfel arrays are inconsistent: {0}")]
    Surfels(String),
    /// A buffer has the wrong length: `what` names it, `expected` and `got` are value counts.
    #[error("{what}: expected {expected} values, got {got}")]
    Length {
        /// The buffer's name.
        what: &'static str,
        /// Values it must hold.
        expected: usize,
        /// Values it holds.
        got: usize,
    },
    /// A feature table (named) has a vertex count other than 1, 2, 4 or 6.
    #[error("{0}: unsupported vertex count {1} (1, 2, 4 or 6)")]
    Vertices(&'static str, usize),
    /// Colour features with a channel count other than 3.
    #[error("colour features must have 3 channels, got {0}")]
    ColorChannels(usize),
    /// A feature table (named) with more uniform channels than channels, or colour features
    /// with any ([`FeaturesOf::uniform`]).
    #[error("{what}: {uniform} uniform channels of {channels} (colour features allow none)")]
    Uniform {
        /// The table's name.
        what: &'static str,
        /// Its uniform channels.
        uniform: usize,
        /// Its channels.
        channels: usize,
    },
    /// [`try_render_reusing`] given a prior render of other Gaussians, another camera or
    /// settings, or colours not interpolated from vertices.
    #[error("a render can reuse only a projection of the same Gaussians by the same camera and settings, with colours from several vertices")]
    Reuse,
    /// [`sh_colors_backward`] given a render whose colours are not its Gaussians' SH colours.
    #[error("SH colour gradients need the forward state of a render with SH colours of the same Gaussians")]
    NotSh,
    /// `RasterConfig::tile` outside 1..=64.
    #[error("tile size must be in 1..=64, got {0}")]
    Tile(u32),
    /// A [`FeatureRaster`] backward given the state of another backend's render.
    #[error("a feature render's backward needs the state of a render by the same backend")]
    State,
    /// A device backend's failure, or an input it cannot take (the message says which).
    #[error("{0}")]
    Device(String),
}

/// Read access to the raw Gaussian parameters in the kernels' scalar type. [`Surfels`] implements
/// it for both `f32` and `f64`; tests implement it on `f64` arrays to perturb parameters finely.
pub trait GaussianParams<F: Float>: Sync {
    /// Number of Gaussians.
    fn count(&self) -> usize;
    /// SH degree of the colour coefficients (0..=3).
    fn sh_degree(&self) -> u32;
    /// World-space centre of Gaussian `i`.
    fn position(&self, i: usize) -> [F; 3];
    /// Raw (unnormalised) quaternion, glam order `x, y, z, w`.
    fn rotation(&self, i: usize) -> [F; 4];
    /// Log of the two tangent-axis standard deviations `(s_u, s_v)` of Gaussian `i`.
    fn log_scale(&self, i: usize) -> [F; 2];
    /// Opacity logit of Gaussian `i` (opacity is its sigmoid, SPEC 1).
    fn opacity_logit(&self, i: usize) -> F;
    /// Coefficient `k` (0..16) of channel `ch`.
    fn sh(&self, i: usize, k: usize, ch: usize) -> F;
}

impl<F: Float> GaussianParams<F> for Surfels {
    fn count(&self) -> usize {
        self.len()
    }
    fn sh_degree(&self) -> u32 {
        self.sh_degree
    }
    #[inline]
    fn position(&self, i: usize) -> [F; 3] {
        self.positions[i].to_array().map(F::from_f32)
    }
    #[inline]
    fn rotation(&self, i: usize) -> [F; 4] {
        self.rotations[i].to_array().map(F::from_f32)
    }
    #[inline]
    fn log_scale(&self, i: usize) -> [F; 2] {
        self.log_scales[i].to_array().map(F::from_f32)
    }
    #[inline]
    fn opacity_logit(&self, i: usize) -> F {
        F::from_f32(self.opacity_logits[i])
    }
    #[inline]
    fn sh(&self, i: usize, k: usize, ch: usize) -> F {
        F::from_f32(self.sh[i].0[k][ch])
    }
}

/// Per-Gaussian feature rows, `data.len() == n * vertices * channels`, layout
/// `[gaussian][vertex][channel]`. `vertices` is 1 (constant per Gaussian) or M = 2, 4, 6 (Gaussian
/// vertices interpolated at the pixel's tangent coordinates with the SPEC 3 weights, see [`interp`]).
#[derive(Clone, Copy, Debug)]
pub struct FeaturesOf<'a, F> {
    /// Values, `[gaussian][vertex][channel]`.
    pub data: &'a [F],
    /// Vertices per Gaussian: 1, or M = 2, 4, 6 (SPEC 3).
    pub vertices: usize,
    /// Channels per vertex.
    pub channels: usize,
    /// How many of the last channels hold one value per Gaussian (stored at every vertex):
    /// with several vertices the kernels read these at vertex 0 instead of interpolating them,
    /// and return their gradients at vertex 0 (the other vertices' are 0). Interpolating a
    /// constant gives the constant (the SPEC 3 weights sum to one), so only the rounding and
    /// the work change. Stage 2's PBR pass carries the SH colour so (`sh_channels`).
    pub uniform: usize,
}
/// [`FeaturesOf`] in `f32`, as training uses it.
pub type Features<'a> = FeaturesOf<'a, f32>;

/// Where Gaussian colours come from.
#[derive(Clone, Copy, Debug)]
pub enum ColorSourceOf<'a, F> {
    /// SH of the surfels, degree `sh_degree`, view direction `normalize(p - cam_center)`,
    /// colour `max(0, 0.5 + SH)` as 3DGS; evaluated once per Gaussian in [`preprocess`].
    Sh,
    /// Given colours (`channels == 3`), possibly per vertex.
    Features(FeaturesOf<'a, F>),
}
/// [`ColorSourceOf`] in `f32`, as training uses it.
pub type ColorSource<'a> = ColorSourceOf<'a, f32>;

/// Colour behind the Gaussians, weighted by the final transmittance.
#[derive(Clone, Copy, Debug)]
pub enum BackgroundOf<'a, F> {
    /// One RGB colour for every pixel.
    Color([F; 3]),
    /// Per-pixel RGB, `H * W * 3`.
    Image(&'a [F]),
}
/// [`BackgroundOf`] in `f32`, as training uses it.
pub type Background<'a> = BackgroundOf<'a, f32>;

/// Everything one render reads.
pub struct RenderInputOf<'a, F: Float, P: GaussianParams<F> + ?Sized> {
    /// The Gaussians' raw parameters.
    pub surfels: &'a P,
    /// The camera rendered from.
    pub camera: &'a Camera,
    /// Where the Gaussians' colours come from.
    pub colors: ColorSourceOf<'a, F>,
    /// Optional extra features composited like colour into [`RenderOutputOf::extra`].
    pub extra: Option<FeaturesOf<'a, F>>,
    /// Colour behind the Gaussians.
    pub background: BackgroundOf<'a, F>,
}
/// [`RenderInputOf`] in `f32` over [`Surfels`], as training uses it.
pub type RenderInput<'a> = RenderInputOf<'a, f32, Surfels>;

/// Rendered buffers, row-major, interleaved channels.
#[derive(Clone, Debug, Default)]
pub struct RenderOutputOf<F> {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// `H*W*3`: `sum_i c_i w_i + T_N * bg`.
    pub color: Vec<F>,
    /// `H*W`: `O = 1 - T_N`.
    pub alpha: Vec<F>,
    /// `H*W`: `sum_i w_i z_i` (NOT divided by O; callers divide).
    pub depth: Vec<F>,
    /// `H*W`: z of the last Gaussian composited while T > 0.5; 0 where nothing was composited.
    /// No gradient.
    pub median_depth: Vec<F>,
    /// `H*W*3`: `sum_i w_i n_i`, world space, each n flipped to face the camera.
    pub normal: Vec<F>,
    /// `H*W`: 2DGS depth distortion in its running-sum form, which is
    /// `sum_{j<i} w_i w_j (m_i - m_j)^2` with `m(z) = far/(far-near) (1 - near/z)` (squared
    /// differences as 2DGS's code, not the paper's absolute value).
    pub distortion: Vec<F>,
    /// `H*W*C`: `sum_i w_i f_i` (interpolated features if vertices > 1); empty without extra.
    pub extra: Vec<F>,
    /// Channels of `extra`.
    pub extra_channels: usize,
    /// Per Gaussian: sum over pixels of w_i (for pruning).
    pub accum_weight: Vec<F>,
    /// Per Gaussian: screen radius in pixels (0 = not visible).
    pub max_radius: Vec<f32>,
}
/// [`RenderOutputOf`] in `f32`, as training uses it.
pub type RenderOutput = RenderOutputOf<f32>;

/// What [`backward()`] needs from [`render`]: per-Gaussian projected data and SH colours, the tile
/// lists sorted by (depth, id), and per pixel the final T, the count of list entries up to the
/// last composited one, and the distortion moments `sum w m`, `sum w m^2`.
#[derive(Clone, Debug, Default)]
pub struct ForwardStateOf<F> {
    /// Shared with the later renders that reuse it ([`try_render_reusing`]).
    pub(crate) proj: std::sync::Arc<Projection<F>>,
    pub(crate) final_t: Vec<F>,
    pub(crate) n_contrib: Vec<u32>,
    pub(crate) moment1: Vec<F>,
    pub(crate) moment2: Vec<F>,
    /// Per (tile, Gaussian) entry, the weight `alpha T` it composited over its pixels: zero
    /// exactly when it composited none (or the tile finished before it), which lets the backward
    /// pass it by without listing its pixels.
    pub(crate) entry_weight: Vec<F>,
    /// The SIMD forward's lane groups, kept so that the backward need not list them again: per
    /// tile its groups, per entry where they lie; `group_lanes` is their width (0 when none were
    /// kept: the scalar and f64 kernels). The backward keeps to the pixels that composited each
    /// entry with a per-lane test of `n_contrib`.
    pub(crate) tile_groups: Vec<Vec<lane_groups::GroupSlot>>,
    pub(crate) entry_groups: Vec<lane_groups::EntryGroups>,
    pub(crate) group_lanes: usize,
    /// Wall time of the forward's phases.
    pub phases: PhaseTimes,
}
/// [`ForwardStateOf`] in `f32`, as training uses it.
pub type ForwardState = ForwardStateOf<f32>;

/// What a render derives from the Gaussians' geometry and opacity and the camera before any
/// pixel: the splats (and, for SH colours, each Gaussian's colour), the tile lists sorted by
/// (depth, id) and their per-entry records; with the camera and settings it was made for.
#[derive(Clone, Debug, Default)]
pub(crate) struct Projection<F> {
    pub(crate) splats: Vec<preprocess::Splat<F>>,
    pub(crate) sh_colors: Vec<[F; 3]>,
    pub(crate) recs: Vec<tiles::TileRec<F>>,
    pub(crate) bins: tiles::TileBins,
    pub(crate) camera: Option<Camera>,
    pub(crate) near: f32,
}

/// The projection of a render ([`try_project`], [`ForwardStateOf::projected`]): what a later
/// render of the same Gaussians by the same camera reuses ([`try_render_reusing`]), and what
/// [`sh_colors_backward`] reads.
#[derive(Clone, Debug)]
pub struct Projected {
    proj: std::sync::Arc<Projection<f32>>,
}

impl Projected {
    /// Per Gaussian, its screen radius in pixels when it is in view, else 0 (a render's
    /// [`RenderOutputOf::max_radius`]).
    pub fn max_radius(&self) -> Vec<f32> {
        forward::max_radius(&self.proj.splats)
    }

    /// Per Gaussian, its colour `max(0, 0.5 + SH(view))` for [`ColorSource::Sh`] inputs (0 for
    /// culled Gaussians); empty for other colour sources.
    pub fn sh_colors(&self) -> &[[f32; 3]] {
        &self.proj.sh_colors
    }
}

impl ForwardState {
    /// This render's projection, shared (not copied).
    pub fn projected(&self) -> Projected {
        Projected { proj: self.proj.clone() }
    }
}

impl<F> ForwardStateOf<F> {
    /// The colour each Gaussian composited, `max(0, 0.5 + SH(view))`, for a render of
    /// [`ColorSource::Sh`] (0 for culled Gaussians); empty for other colour sources.
    pub fn sh_colors(&self) -> &[[F; 3]] {
        &self.proj.sh_colors
    }

    /// Number of (Gaussian, tile) pairs this render binned.
    pub fn num_tile_entries(&self) -> usize {
        self.proj.bins.ids.len()
    }

    /// Gaussian-pixel pairs inside the Gaussians' boxes clipped to their tiles: an upper bound on
    /// the ray-splat evaluations of one forward pass.
    pub fn box_evaluations(&self) -> u64 {
        let b = &self.proj.bins;
        let mut total = 0u64;
        for (t, r) in b.ranges.iter().enumerate() {
            let tx = t as u32 % b.tiles_x * b.tile;
            let ty = t as u32 / b.tiles_x * b.tile;
            for &g in &b.ids[r[0] as usize..r[1] as usize] {
                let s = &self.proj.splats[g as usize].rect;
                let w = s[1].min(tx + b.tile).saturating_sub(s[0].max(tx));
                let h = s[3].min(ty + b.tile).saturating_sub(s[2].max(ty));
                total += w as u64 * h as u64;
            }
        }
        total
    }
}

/// Gradients of the loss w.r.t. each output (same layouts as [`RenderOutputOf`]); `None` = zero.
#[derive(Clone, Copy, Debug, Default)]
pub struct OutputGradsOf<'a, F> {
    /// `dL/d color`, `H*W*3`.
    pub color: Option<&'a [F]>,
    /// `dL/d alpha`, `H*W`.
    pub alpha: Option<&'a [F]>,
    /// `dL/d depth` (the undivided weighted depth), `H*W`.
    pub depth: Option<&'a [F]>,
    /// `dL/d normal`, `H*W*3`.
    pub normal: Option<&'a [F]>,
    /// `dL/d distortion`, `H*W`.
    pub distortion: Option<&'a [F]>,
    /// `dL/d extra`, `H*W*C`.
    pub extra: Option<&'a [F]>,
}
/// [`OutputGradsOf`] in `f32`, as training uses it.
pub type OutputGrads<'a> = OutputGradsOf<'a, f32>;

/// Gradients w.r.t. the raw parameters stored in [`Surfels`] and the other inputs.
#[derive(Clone, Debug)]
pub struct GradsOf<F: Float> {
    /// W.r.t. the world-space centres, one per Gaussian.
    pub v_positions: Vec<F::V3>,
    /// W.r.t. the raw unnormalised quaternion.
    pub v_rotations: Vec<F::Q>,
    /// W.r.t. the log-scales `(log s_u, log s_v)`, one per Gaussian.
    pub v_log_scales: Vec<F::V2>,
    /// W.r.t. the opacity logits, one per Gaussian.
    pub v_opacity_logits: Vec<F>,
    /// Zero if the colours came from features.
    pub v_sh: Vec<F::Sh>,
    /// Same layout as the colour features (empty for SH).
    pub v_color_features: Vec<F>,
    /// Same layout as the extra features (empty without).
    pub v_extra: Vec<F>,
    /// 3 for a constant background, `H*W*3` for an image.
    pub v_background: Vec<F>,
    /// Per Gaussian, for densification: the norm of dL/d(projected centre, pixels), defined as
    /// the full position gradient (rasterisation and SH view direction) restricted to moving the
    /// 3D centre parallel to the image plane and expressed per pixel:
    /// `|(g_c.x z / f_x, g_c.y z / f_y)|` with `g_c = R_c dL/dp` in camera axes and `z` the
    /// centre's depth. 0 for culled Gaussians.
    pub v_mean2d_norm: Vec<F>,
    /// Wall time of the backward's phases.
    pub phases: PhaseTimes,
}
/// [`GradsOf`] in `f32`, as training uses it.
pub type Grads = GradsOf<f32>;

/// Checks lengths, vertex counts and surfel arrays; [`render`] panics on what this rejects.
pub fn check_input<F: Float, P: GaussianParams<F> + ?Sized>(
    input: &RenderInputOf<F, P>,
    cfg: &RasterConfig,
) -> Result<(), RasterError> {
    let n = input.surfels.count();
    let px = input.camera.width() as usize * input.camera.height() as usize;
    if !(1..=64).contains(&cfg.tile) {
        return Err(RasterError::Tile(cfg.tile));
    }
    let check_f = |what: &'static str, f: &FeaturesOf<F>| {
        if !interp::supported_vertices(f.vertices) {
            return Err(RasterError::Vertices(what, f.vertices));
        }
        if f.uniform > f.channels {
            return Err(RasterError::Uniform { what, uniform: f.uniform, channels: f.channels });
        }
        let expected = n * f.vertices * f.channels;
        if f.data.len() != expected {
            return Err(RasterError::Length { what, expected, got: f.data.len() });
        }
        Ok(())
    };
    if let ColorSourceOf::Features(f) = &input.colors {
        if f.channels != 3 {
            return Err(RasterError::ColorChannels(f.channels));
        }
        if f.uniform > 0 {
            return Err(RasterError::Uniform { what: "colour features", uniform: f.uniform, channels: f.channels });
        }
        check_f("colour features", f)?;
    }
    if let Some(f) = &input.extra {
        check_f("extra features", f)?;
    }
    if let BackgroundOf::Image(b) = input.background {
        if b.len() != px * 3 {
            return Err(RasterError::Length { what: "background image", expected: px * 3, got: b.len() });
        }
    }
    Ok(())
}

/// Renders `input` (f32). Panics on inputs [`check_input`] rejects; use [`try_render`] for data
/// that was not validated.
pub fn render(input: &RenderInput, cfg: &RasterConfig) -> (RenderOutput, ForwardState) {
    try_render(input, cfg).unwrap_or_else(|e| panic!("svgir-raster: bad render input: {e}"))
}

/// [`render`] with input validation (including [`Surfels::check`]).
pub fn try_render(input: &RenderInput, cfg: &RasterConfig) -> Result<(RenderOutput, ForwardState), RasterError> {
    input.surfels.check().map_err(RasterError::Surfels)?;
    check_input(input, cfg)?;
    Ok(render_generic(input, cfg))
}

/// The projection alone of a render of `input` (its splats, their tile lists and records; no
/// pixel), for a later [`try_render_reusing`] or [`sh_colors_backward`]. The same values as the
/// projection [`try_render`] makes.
pub fn try_project(input: &RenderInput, cfg: &RasterConfig) -> Result<Projected, RasterError> {
    input.surfels.check().map_err(RasterError::Surfels)?;
    check_input(input, cfg)?;
    Ok(Projected { proj: std::sync::Arc::new(forward::project(input, cfg)) })
}

/// [`try_render`] reusing the projection `prior` (the splats, their tile lists and records) of
/// the same Gaussians -- positions, rotations, scales and opacities unchanged since -- by the
/// same camera with the same `near` and tile size: stage 2's PBR pass after its SH pass. Its
/// colours must come from a feature table of several vertices, since the records carry the
/// prior render's one colour per Gaussian. Outputs, state and gradients are those of
/// [`try_render`] (bit for bit; the Gaussians themselves are the caller's promise, the rest is
/// checked).
pub fn try_render_reusing(
    input: &RenderInput,
    cfg: &RasterConfig,
    prior: &Projected,
) -> Result<(RenderOutput, ForwardState), RasterError> {
    check_input(input, cfg)?;
    let p = &prior.proj;
    let interpolated = matches!(input.colors, ColorSourceOf::Features(f) if f.vertices > 1);
    let same_view = p.camera.as_ref() == Some(input.camera) && p.near == cfg.near && p.bins.tile == cfg.tile;
    if !interpolated || !same_view || p.splats.len() != input.surfels.len() {
        return Err(RasterError::Reuse);
    }
    Ok(forward::render_projected(input, cfg, p.clone(), phases::Stopwatch::start()))
}

/// Gradients of a loss whose output gradients are `grads`, for the render that produced `state`
/// and `out` from the same `input`.
pub fn backward(
    input: &RenderInput,
    cfg: &RasterConfig,
    state: &ForwardState,
    out: &RenderOutput,
    grads: &OutputGrads,
) -> Grads {
    backward_generic(input, cfg, state, out, grads)
}

/// The SH coefficients' gradients for the per-Gaussian colours of a [`ColorSource::Sh`] render
/// ([`ForwardStateOf::sh_colors`]), given d loss / d colour per Gaussian: the SH rows that
/// [`backward()`] would give if those colours reached the loss through the render itself. A
/// clamped channel passes no gradient, nor does a culled Gaussian (a zero row). For a caller
/// that composites the same colours in another pass of the same Gaussians (stage 2 carries them
/// in its PBR pass) and so needs no backward of this render. Only the coefficients: the
/// gradient through the view direction to the centre is left out (SPEC 6 freezes it).
pub fn sh_colors_backward(
    input: &RenderInput,
    prior: &Projected,
    v_colors: &[[f32; 3]],
) -> Result<Vec<ShCoeffs>, RasterError> {
    let n = input.surfels.len();
    let splats = &prior.proj.splats;
    if !matches!(input.colors, ColorSourceOf::Sh) || prior.proj.sh_colors.len() != n || splats.len() != n {
        return Err(RasterError::NotSh);
    }
    if v_colors.len() != n {
        return Err(RasterError::Length {
            what: "per-Gaussian colour gradients",
            expected: 3 * n,
            got: 3 * v_colors.len(),
        });
    }
    let cam = preprocess::Cam::<f32>::new(input.camera);
    let mut v_sh = vec![ShCoeffs::default(); n];
    v_sh.par_iter_mut().enumerate().with_min_len(1024).for_each(|(i, row)| {
        // A Gaussian no pixel saw has a zero gradient: its row stays zero.
        if splats[i].visible() && v_colors[i] != [0.0; 3] {
            let rows = preprocess_backward::sh_color_rows(input.surfels, &cam, &splats[i], &v_colors[i], i);
            *row = <f32 as Float>::sh(&rows);
        }
    });
    Ok(v_sh)
}

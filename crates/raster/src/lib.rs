//! Differentiable tile-based CPU rasterizer for 3D Gaussian splats.
//!
//! The semantics are the classic 3DGS / gsplat 1.5 forward (see [`project`] and
//! [`kernel`]); correctness is checked against gsplat's PyTorch reference and a dense
//! PyTorch compositor (fixtures from `tools/raster_fixtures.py`).
//!
//! - [`render`]: RGB, alpha, accumulated depth and any number of extra feature
//!   channels in one pass, plus the [`Frame`] state the backward pass needs.
//! - [`backward`]: gradients to means, log-scales, rotations, opacity logits, SH
//!   coefficients (including the view-direction → mean path) and features, from
//!   gradients on RGB, alpha, depth and features.
//! - [`gaussian_stats`]: per-Gaussian statistics of a view (visibility, blend-weight
//!   sum, pixel count, projected mean) and the splat-back of a per-pixel image: the
//!   blend-weight-weighted mean per Gaussian, the transpose of rendering.
//!
//! Work is split into 16×16 tiles processed in parallel with rayon. The per-Gaussian
//! passes (the projection in [`bin`], the backward's in `per_gaussian`) take eight
//! Gaussians at a time in the lanes of [`lanes::F8`], with the bits the one-at-a-time
//! code gives.

// Lane loops index several per-pixel arrays in lockstep; `!(x > 0.0)` is used on
// purpose where NaN must take the rejecting branch.
#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord)]

pub mod bin;
pub mod fastexp;
pub mod kernel;
pub mod lanes;
mod par;
mod per_gaussian;
pub mod project;
pub mod sh;
pub mod synthetic;
pub mod weights;

use bin::Binned;
use kernel::{Accum, ForwardState, PixelGrads, TileOut};
pub use project::ClampGrad;
use project::{GaussianParams, View};
use rayon::prelude::*;
pub use transsplat_scene::sh_coeffs;
use transsplat_scene::{Camera, Gaussians};

/// Borrowed Gaussian parameters plus optional extra feature channels.
#[derive(Clone, Copy, Debug)]
pub struct Splats<'a> {
    pub means: &'a [[f32; 3]],
    pub log_scales: &'a [[f32; 3]],
    pub rotations: &'a [[f32; 4]],
    pub opacity_logits: &'a [f32],
    /// `[gaussian][coefficient][channel]` with `sh_coeffs(sh_degree)` coefficients.
    pub sh: &'a [f32],
    /// Degree of the SH layout in `sh`.
    pub sh_degree: u32,
    /// Degree evaluated when rendering (≤ `sh_degree`; raised during training).
    pub active_sh_degree: u32,
    /// `[gaussian][channel]`, `num_features` channels.
    pub features: &'a [f32],
    pub num_features: usize,
}

impl<'a> Splats<'a> {
    /// Views a scene's parameters (no extra features, all SH degrees active).
    pub fn new(g: &'a Gaussians) -> Self {
        Splats {
            means: &g.means,
            log_scales: &g.log_scales,
            rotations: &g.rotations,
            opacity_logits: &g.opacity_logits,
            sh: &g.sh,
            sh_degree: g.sh_degree,
            active_sh_degree: g.sh_degree,
            features: &[],
            num_features: 0,
        }
    }

    /// Adds feature channels to render (`features.len() == len() * num_features`).
    pub fn with_features(mut self, features: &'a [f32], num_features: usize) -> Self {
        assert_eq!(features.len(), self.len() * num_features, "feature array does not match the Gaussians");
        self.features = features;
        self.num_features = num_features;
        self
    }

    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.means.len()
    }

    /// True when there are no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }

    #[inline(always)]
    fn params(&self, i: usize) -> GaussianParams<'a> {
        let k = sh_coeffs(self.sh_degree) * 3;
        GaussianParams {
            mean: self.means[i],
            log_scale: self.log_scales[i],
            quat: self.rotations[i],
            opacity_logit: self.opacity_logits[i],
            sh: &self.sh[i * k..(i + 1) * k],
            active_degree: self.active_sh_degree.min(self.sh_degree),
        }
    }

    /// Gaussians `idx` in the lanes of [`lanes::F8`] (lane `l` is [`Splats::params`] of
    /// `idx[l]`), their active SH coefficients gathered into `sh`: the input of the
    /// per-Gaussian passes that take eight at a time.
    #[inline(always)]
    fn params8<'s>(&self, idx: [usize; 8], sh: &'s mut [lanes::F8; 48]) -> GaussianParams<'s, lanes::F8> {
        use lanes::F8;
        let active_degree = self.active_sh_degree.min(self.sh_degree);
        let (kc, nsh) = (sh_coeffs(self.sh_degree) * 3, sh_coeffs(active_degree) * 3);
        for (t, v) in sh[..nsh].iter_mut().enumerate() {
            *v = F8::from_fn(|l| self.sh[idx[l] * kc + t]);
        }
        GaussianParams {
            mean: std::array::from_fn(|c| F8::from_fn(|l| self.means[idx[l]][c])),
            log_scale: std::array::from_fn(|c| F8::from_fn(|l| self.log_scales[idx[l]][c])),
            quat: std::array::from_fn(|c| F8::from_fn(|l| self.rotations[idx[l]][c])),
            opacity_logit: F8::from_fn(|l| self.opacity_logits[idx[l]]),
            sh: &sh[..nsh],
            active_degree,
        }
    }
}

/// Rendering options.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RenderOptions {
    /// Colour behind the Gaussians (linear RGB).
    pub background: [f32; 3],
}

/// The rendered images of one view, row-major, pixel-interleaved channels.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    /// `H × W × 3`, including the background.
    pub rgb: Vec<f32>,
    /// `H × W`: 1 − final transmittance.
    pub alpha: Vec<f32>,
    /// `H × W`: accumulated depth Σ wᵢ zᵢ (divide by alpha for the expected depth).
    pub depth: Vec<f32>,
    /// `H × W × num_features`: Σ wᵢ fᵢ (no background).
    pub features: Vec<f32>,
    pub num_features: usize,
}

impl Image {
    /// Expected depth Σ wᵢ zᵢ / Σ wᵢ per pixel (0 where nothing was blended).
    pub fn expected_depth(&self) -> Vec<f32> {
        self.depth.iter().zip(&self.alpha).map(|(&d, &a)| if a > 0.0 { d / a } else { 0.0 }).collect()
    }
}

/// Per-view state kept from [`render`] for [`backward`] and [`gaussian_stats`].
#[derive(Clone, Debug, Default)]
pub struct Frame {
    pub binned: Binned,
    /// `H × W` final transmittance.
    pub final_t: Vec<f32>,
    /// `H × W`: 1 + position in its tile list of the last Gaussian blended at the pixel.
    pub last: Vec<u32>,
    pub background: [f32; 3],
    /// Seconds spent projecting, sorting and binning (the rest of [`render`] is the
    /// tile pass), for stage timings.
    pub binning_s: f64,
}

impl Frame {
    /// Per-Gaussian projected 2D means (pixels); meaningful where `radii` is non-zero.
    pub fn means2d(&self) -> &[[f32; 2]] {
        &self.binned.means2d
    }
    /// Per-Gaussian pixel radii (x, y); (0, 0) for culled Gaussians.
    pub fn radii(&self) -> &[[u32; 2]] {
        &self.binned.radii
    }
}

pub(crate) fn validate(splats: &Splats, cam: &Camera) {
    let n = splats.len();
    assert!(
        splats.log_scales.len() == n
            && splats.rotations.len() == n
            && splats.opacity_logits.len() == n
            && splats.sh.len() == n * sh_coeffs(splats.sh_degree) * 3
            && splats.features.len() == n * splats.num_features,
        "inconsistent Gaussian arrays"
    );
    assert!(cam.width > 0 && cam.height > 0, "camera {:?} has zero image size", cam.name);
}

/// Renders one view (forward pass).
pub fn render(splats: &Splats, cam: &Camera, opts: &RenderOptions) -> (Image, Frame) {
    validate(splats, cam);
    let view = View::new(cam);
    let clock = std::time::Instant::now();
    let binned = bin::bin(splats, &view);
    let binning_s = clock.elapsed().as_secs_f64();
    let prof = bin::Profile::start();
    let (w, h, f) = (binned.width, binned.height, binned.num_features);
    let mut img = Image {
        width: w,
        height: h,
        rgb: vec![0.0; w * h * 3],
        alpha: vec![0.0; w * h],
        depth: vec![0.0; w * h],
        features: vec![0.0; w * h * f],
        num_features: f,
    };
    let mut final_t = vec![1.0f32; w * h];
    let mut last = vec![0u32; w * h];
    let ptrs = (
        par::SharedMut(img.rgb.as_mut_ptr()),
        par::SharedMut(img.alpha.as_mut_ptr()),
        par::SharedMut(img.depth.as_mut_ptr()),
        par::SharedMut(img.features.as_mut_ptr()),
        par::SharedMut(final_t.as_mut_ptr()),
        par::SharedMut(last.as_mut_ptr()),
    );
    let bg = opts.background;
    let num_tiles = binned.tiles_x * binned.tiles_y;
    (0..num_tiles).into_par_iter().for_each_init(
        || TileOut::new(f),
        |out, tile| {
            kernel::forward_tile(&binned, tile, out, None);
            let (x0, y0, x1, y1) = binned.tile_rect(tile);
            for y in y0..y1 {
                for x in x0..x1 {
                    let (r, c) = (y - y0, x - x0);
                    let q = y * w + x;
                    let t = out.t[r][c];
                    // SAFETY: every pixel belongs to exactly one tile; tiles write disjoint pixels.
                    unsafe {
                        for ch in 0..3 {
                            *ptrs.0.get().add(q * 3 + ch) = out.rgb[ch][r][c] + t * bg[ch];
                        }
                        *ptrs.1.get().add(q) = 1.0 - t;
                        *ptrs.2.get().add(q) = out.depth[r][c];
                        for k in 0..f {
                            *ptrs.3.get().add(q * f + k) = out.feat[k][r][c];
                        }
                        *ptrs.4.get().add(q) = t;
                        *ptrs.5.get().add(q) = out.last[r][c];
                    }
                }
            }
        },
    );
    prof.lap("tiles");
    (img, Frame { binned, final_t, last, background: bg, binning_s })
}

/// Gradients of a scalar loss with respect to the rendered images of one view.
/// Empty slices mean zero; otherwise sizes match [`Image`].
#[derive(Clone, Copy, Debug, Default)]
pub struct ImageGrads<'a> {
    pub rgb: &'a [f32],
    pub alpha: &'a [f32],
    pub depth: &'a [f32],
    pub features: &'a [f32],
    /// How the colour clamp at 0 passes these gradients to the SH coefficients
    /// ([`ClampGrad::Exact`] by default: the derivative of what is rendered).
    pub clamp: ClampGrad,
}

/// Gradients with respect to every Gaussian parameter (same layouts as [`Splats`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Grads {
    pub means: Vec<[f32; 3]>,
    pub log_scales: Vec<[f32; 3]>,
    pub rotations: Vec<[f32; 4]>,
    pub opacity_logits: Vec<f32>,
    pub sh: Vec<f32>,
    pub features: Vec<f32>,
    /// Gradient with respect to the projected 2D mean, in pixels (for densification).
    pub means2d: Vec<[f32; 2]>,
}

impl Grads {
    /// Sets the rows `rows` (as returned by [`backward`]) back to zero: the SH rows
    /// (most of the bytes) on one thread, the rest on another.
    pub fn clear_rows(&mut self, rows: &[u32]) {
        let n = self.means.len();
        let kc = self.sh.len().checked_div(n).unwrap_or(0);
        let f = self.features.len().checked_div(n).unwrap_or(0);
        let Grads { means, log_scales, rotations, opacity_logits, sh, features, means2d } = self;
        rayon::join(
            || rows.iter().for_each(|&i| sh[i as usize * kc..][..kc].fill(0.0)),
            || {
                for &i in rows {
                    let i = i as usize;
                    means[i] = [0.0; 3];
                    log_scales[i] = [0.0; 3];
                    rotations[i] = [0.0; 4];
                    opacity_logits[i] = 0.0;
                    features[i * f..(i + 1) * f].fill(0.0);
                    means2d[i] = [0.0; 2];
                }
            },
        );
    }

    /// All-zero gradients for `n` Gaussians.
    pub fn zeros(n: usize, sh_degree: u32, num_features: usize) -> Self {
        Grads {
            means: vec![[0.0; 3]; n],
            log_scales: vec![[0.0; 3]; n],
            rotations: vec![[0.0; 4]; n],
            opacity_logits: vec![0.0; n],
            sh: vec![0.0; n * sh_coeffs(sh_degree) * 3],
            features: vec![0.0; n * num_features],
            means2d: vec![[0.0; 2]; n],
        }
    }
}

/// Backward pass of [`render`]: gradients of the loss with respect to the Gaussian
/// parameters, given its gradients with respect to the rendered images. Gradients
/// are added into `grads` (so several views can be accumulated).
///
/// Returns the Gaussians whose rows it added to, ascending: those some pixel's
/// gradient reached. Every other row is left exactly as it was, so a caller that
/// keeps `grads` zero between steps can clear just these rows ([`Grads::clear_rows`])
/// and step the optimiser over just these.
pub fn backward(splats: &Splats, cam: &Camera, frame: &Frame, g: &ImageGrads, grads: &mut Grads) -> Vec<u32> {
    validate(splats, cam);
    let b = &frame.binned;
    let (w, h, f) = (b.width, b.height, b.num_features);
    for (name, v, want) in [
        ("rgb", g.rgb, w * h * 3),
        ("alpha", g.alpha, w * h),
        ("depth", g.depth, w * h),
        ("features", g.features, w * h * f),
    ] {
        assert!(v.is_empty() || v.len() == want, "{name} gradient has {} values, expected {want}", v.len());
    }
    let n = splats.len();
    assert!(
        grads.means.len() == n
            && grads.log_scales.len() == n
            && grads.rotations.len() == n
            && grads.opacity_logits.len() == n
            && grads.sh.len() == n * sh_coeffs(splats.sh_degree) * 3
            && grads.features.len() >= n * f
            && grads.means2d.len() == n,
        "gradient arrays do not match the Gaussians"
    );
    let stride = kernel::grad_stride(f);
    let st = ForwardState { final_t: &frame.final_t, last: &frame.last, background: frame.background };
    let pg = PixelGrads { rgb: g.rgb, alpha: g.alpha, depth: g.depth, features: g.features };
    let m = b.splats.len();
    let num_tiles = b.tiles_x * b.tiles_y;
    let prof = bin::Profile::start();
    let bufs = par::for_each_with_buffers(
        num_tiles,
        || vec![0.0f32; m * stride],
        |tile, buf| kernel::backward_tile(b, tile, &st, &pg, buf),
    );
    prof.lap("backward tiles");
    let acc = par::sum_into_first(bufs);
    if acc.is_empty() {
        return Vec::new();
    }
    // The projection backward is linear in the splat gradients: a splat that no pixel
    // reached (occluded behind saturated pixels) contributes exactly zero. Found here in
    // depth order, where the accumulator streams, not by a random read per Gaussian.
    let reached: Vec<(u32, u32)> = acc
        .par_chunks(stride)
        .zip(b.ids.par_iter())
        .enumerate()
        .filter(|(_, (a, _))| a.iter().any(|&v| v != 0.0))
        .map(|(j, (_, &id))| (id, j as u32))
        .collect();
    // Each Gaussian's accumulator row (its depth position), or NOT_REACHED.
    let mut at = vec![per_gaussian::NOT_REACHED; n];
    for &(i, j) in &reached {
        at[i as usize] = j;
    }
    drop(reached);
    prof.lap("backward reached");
    let view = View::new(cam);
    let kc = sh_coeffs(splats.sh_degree) * 3;
    let inputs = per_gaussian::Inputs { splats, view: &view, acc: &acc, stride, clamp: g.clamp };
    // Runs of rows in index order (per_gaussian's module doc), one unit of work each.
    let rows = per_gaussian::ROWS;
    let Grads { means, log_scales, rotations, opacity_logits, sh, features, means2d } = grads;
    let features: Vec<&mut [f32]> = match f {
        0 => (0..n.div_ceil(rows)).map(|_| <&mut [f32]>::default()).collect(),
        _ => features[..n * f].chunks_mut(f * rows).collect(),
    };
    let runs: Vec<per_gaussian::Run> = means
        .chunks_mut(rows)
        .zip(log_scales.chunks_mut(rows))
        .zip(rotations.chunks_mut(rows).zip(opacity_logits.chunks_mut(rows)))
        .zip(sh.chunks_mut(kc * rows).zip(means2d.chunks_mut(rows)))
        .zip(features.into_iter().zip(at.chunks(rows)))
        .enumerate()
        .map(|(c, ((((means, log_scales), (rotations, opacity_logits)), (sh, means2d)), (features, at)))| {
            per_gaussian::Run {
                first: c * rows,
                at,
                means,
                log_scales,
                rotations,
                opacity_logits,
                sh,
                features,
                means2d,
            }
        })
        .collect();
    let avx2 = transsplat_scene::cpu::has_avx2();
    // Each run returns its reached rows, ascending: in run order, every reached row.
    let reached: Vec<Vec<u32>> =
        runs.into_par_iter().map(|run| per_gaussian::run(avx2, &inputs, run)).collect();
    prof.lap("backward per-Gaussian");
    reached.concat()
}

/// Per-Gaussian statistics of one view (docs/method.md#m1-visibility-and-source-masses), and the splat-back.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GaussianStats {
    /// Σ_p T_i(p) α_i(p): total blend weight.
    pub weight_sum: Vec<f32>,
    /// Σ_p α_i(p) over the pixels where it was blended.
    pub alpha_sum: Vec<f32>,
    /// Number of pixels where it was blended.
    pub pixel_count: Vec<u32>,
    /// ν_i = Σ T α / Σ α ∈ [0, 1]: mean transmittance where it blends (0 if never).
    pub visibility: Vec<f32>,
    /// Projected 2D mean in pixels (valid where `pixel_count > 0`).
    pub means2d: Vec<[f32; 2]>,
    /// Splat-back: `channels` values per Gaussian, Σ_p w G(p) / Σ_p w (0 if never blended).
    pub splat: Vec<f32>,
    pub channels: usize,
}

/// Statistics of every Gaussian in one view and, when `image` is given
/// (`H × W × channels`), the blend-weight-weighted mean of the image per Gaussian:
/// the transpose of rendering, used to lift masks and features onto Gaussians.
pub fn gaussian_stats(splats: &Splats, cam: &Camera, image: Option<(&[f32], usize)>) -> GaussianStats {
    gaussian_stats_capped(splats, cam, image, 0)
}

/// [`gaussian_stats`] whose last `capped` image channels are splatted back capped:
/// Σ_p min(w_i(p), G(p)) / Σ_p w_i(p), the share of the Gaussian's blend weight that a
/// per-pixel share G(p) ∈ [0, 1] of the pixel can account for
/// (docs/method.md#m6-residual-and-gate, the coverage ω).
pub fn gaussian_stats_capped(
    splats: &Splats,
    cam: &Camera,
    image: Option<(&[f32], usize)>,
    capped: usize,
) -> GaussianStats {
    validate(splats, cam);
    let view = View::new(cam);
    let mut only = *splats;
    only.features = &[];
    only.num_features = 0;
    let b = bin::bin(&only, &view);
    let (img, channels) = image.unwrap_or((&[], 0));
    assert!(img.len() == b.width * b.height * channels, "splat-back image has the wrong size");
    let accum = Accum { image: img, channels, capped };
    let stride = accum.stride();
    let m = b.splats.len();
    let num_tiles = b.tiles_x * b.tiles_y;
    let bufs = par::for_each_with_buffers(
        num_tiles,
        || (TileOut::new(0), vec![0.0f32; m * stride]),
        |tile, (out, buf)| kernel::forward_tile(&b, tile, out, Some((&accum, buf))),
    );
    let acc = par::sum_into_first(bufs.into_iter().map(|(_, b)| b).collect());
    let n = splats.len();
    let mut s = GaussianStats {
        weight_sum: vec![0.0; n],
        alpha_sum: vec![0.0; n],
        pixel_count: vec![0; n],
        visibility: vec![0.0; n],
        means2d: b.means2d.clone(),
        splat: vec![0.0; n * channels],
        channels,
    };
    // Index order (see `backward`): the writes stream, the accumulator rows are gathered.
    let pos = depth_positions(&b.ids, n);
    const C: usize = 4096;
    let row = |j: u32| &acc[j as usize * stride..(j as usize + 1) * stride];
    (
        s.weight_sum.par_chunks_mut(C),
        s.alpha_sum.par_chunks_mut(C),
        s.pixel_count.par_chunks_mut(C),
        s.visibility.par_chunks_mut(C),
        pos.par_chunks(C),
    )
        .into_par_iter()
        .for_each(|(ws, al, pc, vis, pos)| {
            for (k, &j) in pos.iter().enumerate().filter(|(_, &j)| j != u32::MAX) {
                let a = row(j);
                ws[k] = a[0];
                al[k] = a[1];
                pc[k] = a[2] as u32;
                if a[1] > 0.0 {
                    vis[k] = (a[0] / a[1]).min(1.0);
                }
            }
        });
    if channels > 0 {
        s.splat.par_chunks_mut(C * channels).zip(pos.par_chunks(C)).for_each(|(sp, pos)| {
            for (k, &j) in pos.iter().enumerate().filter(|(_, &j)| j != u32::MAX) {
                let a = row(j);
                if a[0] > 0.0 {
                    for c in 0..channels {
                        sp[k * channels + c] = a[3 + c] / a[0];
                    }
                }
            }
        });
    }
    s
}

/// `pos[i]` = the position of Gaussian i in the depth-sorted list `ids` (u32::MAX when
/// it is not in the list).
fn depth_positions(ids: &[u32], n: usize) -> Vec<u32> {
    let mut pos = vec![u32::MAX; n];
    for (j, &id) in ids.iter().enumerate() {
        pos[id as usize] = j as u32;
    }
    pos
}

//! The step's render when only a known set of Gaussians can change colour
//! (docs/method.md#m10-speed).
//!
//! With frozen geometry and opacity, a view's render is linear in the colours with
//! fixed blend weights ([`transsplat_raster::weights`]). When the method has a colour
//! mask, only the Gaussians that were ever inside it can change colour (its own terms
//! move only colours that already differ from the source), so a step renders
//!
//! Î(p) = I⁰(p) + Σ_{i ∈ U} w_i(p) (c_i − c_i⁰)
//!
//! with I⁰ the view's source render and U the covered Gaussians, and takes the colour
//! gradient of L_img as Σ_p w_i(p) ∂L/∂Î(p) for the masked Gaussians alone. Both cost
//! a pass over U's (pixel, weight) pairs, not over every Gaussian in the view. The
//! weights are built when the mask first reaches a Gaussian not yet covered.

use transsplat_raster::weights::{blend_weights, colour_sh_backward, colours, BlendWeights};
use transsplat_raster::ClampGrad;
use transsplat_raster::Splats;
use transsplat_scene::{Camera, Gaussians};

/// The largest share of the Gaussians covered: past it the loop renders in full. A
/// chosen bound (a view's pairs then approach a full render's, and their memory grows
/// with them), not a measured crossover.
pub const MAX_SHARE: f64 = 0.25;

/// One usable view: its source render I⁰ and the weights and source colours c⁰ of the
/// covered Gaussians it sees.
struct View {
    base: Vec<f32>,
    weights: BlendWeights,
    c0: Vec<[f32; 3]>,
}

/// The covered set U and the views' weights over it.
pub struct Delta {
    covered: Vec<bool>,
    /// The covered Gaussians, ascending.
    rows: Vec<u32>,
    views: Vec<View>,
}

impl Delta {
    /// Covers the Gaussians of the source scene `source` whose colour differs from
    /// the model's `sh` plus those in `mask`, for the usable views `cams` with their
    /// source renders `bases`; `None` when that is more than [`MAX_SHARE`] of them.
    pub fn new(
        source: &Gaussians,
        sh: &[f32],
        mask: &[bool],
        cams: &[&Camera],
        bases: Vec<Vec<f32>>,
    ) -> Option<Self> {
        let k = source.sh_coeffs() * 3;
        let covered: Vec<bool> = mask
            .iter()
            .enumerate()
            .map(|(i, &m)| m || sh[i * k..(i + 1) * k] != source.sh[i * k..(i + 1) * k])
            .collect();
        let views = bases
            .into_iter()
            .map(|base| View { base, weights: Default::default(), c0: Vec::new() })
            .collect();
        let mut d = Delta { covered, rows: Vec::new(), views };
        d.rebuild(source, cams).then_some(d)
    }

    /// Makes the weights cover `mask` too (rebuilding them when it reaches a Gaussian
    /// not covered yet); false when that is more than [`MAX_SHARE`] of them.
    pub fn cover(&mut self, source: &Gaussians, mask: &[bool], cams: &[&Camera]) -> bool {
        let mut grew = false;
        for (c, &m) in self.covered.iter_mut().zip(mask) {
            grew |= m && !*c;
            *c |= m;
        }
        !grew || self.rebuild(source, cams)
    }

    /// The views' weights and source colours over the covered set.
    fn rebuild(&mut self, source: &Gaussians, cams: &[&Camera]) -> bool {
        let count = self.covered.iter().filter(|&&c| c).count();
        if count as f64 > MAX_SHARE * self.covered.len() as f64 {
            return false;
        }
        self.rows = (0..self.covered.len() as u32).filter(|&i| self.covered[i as usize]).collect();
        let splats = Splats::new(source);
        let t = std::time::Instant::now();
        for (v, cam) in self.views.iter_mut().zip(cams) {
            v.weights = blend_weights(&splats, cam, &self.covered);
            v.c0 = colours(&splats, cam, &v.weights.ids);
        }
        tracing::debug!(
            "blend weights of {count} Gaussians: {} pairs over {} views, {:.2} s",
            self.views.iter().map(|v| v.weights.len()).sum::<usize>(),
            self.views.len(),
            t.elapsed().as_secs_f64()
        );
        true
    }

    /// The covered Gaussians, ascending: the only rows a step writes.
    pub fn rows(&self) -> &[u32] {
        &self.rows
    }

    /// Zeroes the covered Gaussians' rows of `grad_sh`, the only rows a step writes.
    pub fn zero_rows(&self, grad_sh: &mut [f32]) {
        let k = grad_sh.len() / self.covered.len().max(1);
        for &i in &self.rows {
            grad_sh[i as usize * k..(i as usize + 1) * k].fill(0.0);
        }
    }

    /// Renders usable view `k` (camera `cam`) with the colours of `splats`.
    pub fn render(&self, k: usize, splats: &Splats, cam: &Camera) -> Vec<f32> {
        let v = &self.views[k];
        let c = colours(splats, cam, &v.weights.ids);
        let change: Vec<[f32; 3]> =
            c.iter().zip(&v.c0).map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]]).collect();
        let mut rgb = v.base.clone();
        v.weights.add(&change, &mut rgb);
        rgb
    }

    /// The colour lift's Δ_i (docs/method.md#m9-the-edit-loop) from the views' weights:
    /// Σ_v Σ_p w_i^v(p) r_v(p) / Σ_v Σ_p w_i^v(p), with r_v = `targets[v]` minus the
    /// view's current render; `N × 3`, 0 outside the covered set (the same values as
    /// [`crate::lift::lift_each`] of the residuals, without binning every Gaussian).
    pub fn lift(&self, splats: &Splats, cams: &[&Camera], targets: &[&[f32]]) -> Vec<f32> {
        let n = self.covered.len();
        let (mut num, mut den) = (vec![0.0f64; n * 3], vec![0.0f64; n]);
        for (k, (v, cam)) in self.views.iter().zip(cams).enumerate() {
            let rgb = self.render(k, splats, cam);
            let residual: Vec<f32> = targets[k].iter().zip(&rgb).map(|(t, c)| t - c).collect();
            let sums = v.weights.transpose(&vec![1.0; residual.len()]);
            for ((&i, r), w) in v.weights.ids.iter().zip(v.weights.transpose(&residual)).zip(sums) {
                let i = i as usize;
                den[i] += w[0] as f64;
                for c in 0..3 {
                    num[i * 3 + c] += r[c] as f64;
                }
            }
        }
        crate::lift::weighted_means(&num, &den, 3)
    }

    /// Adds the SH gradients of the Gaussians in `mask` from the image gradient
    /// `grad_rgb` of usable view `k` into `grad_sh`, through the colour clamp as
    /// `clamp` says.
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        k: usize,
        splats: &Splats,
        cam: &Camera,
        grad_rgb: &[f32],
        mask: &[bool],
        grad_sh: &mut [f32],
        clamp: ClampGrad,
    ) {
        let v = &self.views[k];
        let vcol = v.weights.transpose(grad_rgb);
        let (ids, vcol): (Vec<u32>, Vec<[f32; 3]>) =
            v.weights.ids.iter().zip(vcol).filter(|(&i, _)| mask[i as usize]).unzip();
        colour_sh_backward(splats, cam, &ids, &vcol, grad_sh, clamp);
    }
}

//! Blend weights of chosen Gaussians in one view, for renders in which only their
//! colours change.
//!
//! A pixel's colour is C(p) = Σ_i w_i(p) c_i + T(p) bg with w_i(p) = T_i(p) α_i(p)
//! (eq. 2 of the paper). The weights depend on the means, scales, rotations and
//! opacities only, never on the colours, so while those are frozen C(p) is linear in
//! the colours with fixed coefficients. If only the Gaussians of a set U can change
//! colour, a render is the render with the original colours plus
//! Σ_{i ∈ U} w_i(p) (c_i − c_i⁰), and the colour gradient of a loss is
//! ∂L/∂c_i = Σ_p w_i(p) ∂L/∂C(p): both cost a pass over U's (pixel, weight) pairs
//! instead of a pass over every Gaussian of the view.
//!
//! [`blend_weights`] records those pairs with the compositing rules of
//! [`crate::kernel`] (the same expressions, so the same values); a tile is walked
//! only up to its last chosen splat.

use crate::bin::{bin, Binned, TILE};
use crate::fastexp::exp_neg;
use crate::kernel::{ALPHA_MIN, T_MIN};
use crate::project::{view_colour, ClampGrad, View};
use crate::{validate, Splats};
use rayon::prelude::*;
use transsplat_scene::Camera;

/// The weights w_i(p) of the chosen Gaussians that blend somewhere in one view.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BlendWeights {
    pub width: usize,
    pub height: usize,
    /// The chosen Gaussians with at least one weight, ascending.
    pub ids: Vec<u32>,
    /// (pixel, position in `ids`, weight), grouped by tile.
    entries: Vec<(u32, u32, f32)>,
    /// Tile `t`'s entries are `entries[tiles[t]..tiles[t + 1]]`.
    tiles: Vec<u32>,
}

impl BlendWeights {
    /// Number of (pixel, Gaussian) weights.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// True when no chosen Gaussian blends in the view.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Adds Σ_k w_k(p) v_k to `rgb` (`H × W × 3`), for one value `v_k` per entry of
    /// [`BlendWeights::ids`].
    pub fn add(&self, values: &[[f32; 3]], rgb: &mut [f32]) {
        assert_eq!(values.len(), self.ids.len(), "one value per chosen Gaussian");
        assert_eq!(rgb.len(), self.width * self.height * 3, "image does not match the weights");
        let out = crate::par::SharedMut(rgb.as_mut_ptr());
        (0..self.tiles.len().saturating_sub(1)).into_par_iter().for_each(|t| {
            for &(q, k, w) in &self.entries[self.tiles[t] as usize..self.tiles[t + 1] as usize] {
                let v = values[k as usize];
                for c in 0..3 {
                    // SAFETY: a tile's entries name only its own pixels; tiles are disjoint.
                    unsafe { *out.get().add(q as usize * 3 + c) += w * v[c] };
                }
            }
        });
    }

    /// Σ_p w_k(p) g(p) for each entry of [`BlendWeights::ids`]: the transpose of
    /// [`BlendWeights::add`], e.g. ∂L/∂c_k from ∂L/∂C (`H × W × 3`).
    pub fn transpose(&self, g: &[f32]) -> Vec<[f32; 3]> {
        assert_eq!(g.len(), self.width * self.height * 3, "image does not match the weights");
        let m = self.ids.len();
        let bufs = crate::par::for_each_with_buffers(
            self.tiles.len().saturating_sub(1),
            || vec![0.0f32; m * 3],
            |t, buf| {
                for &(q, k, w) in &self.entries[self.tiles[t] as usize..self.tiles[t + 1] as usize] {
                    for c in 0..3 {
                        buf[k as usize * 3 + c] += w * g[q as usize * 3 + c];
                    }
                }
            },
        );
        let sum = crate::par::sum_into_first(bufs);
        if sum.is_empty() {
            return vec![[0.0; 3]; m];
        }
        sum.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
    }
}

/// The blend weights in view `cam` of the Gaussians where `chosen` is true.
pub fn blend_weights(splats: &Splats, cam: &Camera, chosen: &[bool]) -> BlendWeights {
    validate(splats, cam);
    assert_eq!(chosen.len(), splats.len(), "one flag per Gaussian");
    let mut only = *splats;
    only.features = &[];
    only.num_features = 0;
    let b = bin(&only, &View::new(cam));
    let num_tiles = b.tiles_x * b.tiles_y;
    let per_tile: Vec<Vec<(u32, u32, f32)>> =
        (0..num_tiles).into_par_iter().map(|t| tile_weights(&b, t, chosen)).collect();
    // Positions in `ids` of the chosen Gaussians that have a weight somewhere.
    let mut pos = vec![u32::MAX; splats.len()];
    for e in per_tile.iter().flatten() {
        pos[e.1 as usize] = 0;
    }
    let ids: Vec<u32> = (0..splats.len() as u32).filter(|&i| pos[i as usize] == 0).collect();
    for (k, &i) in ids.iter().enumerate() {
        pos[i as usize] = k as u32;
    }
    let mut tiles = Vec::with_capacity(num_tiles + 1);
    let mut entries = Vec::with_capacity(per_tile.iter().map(Vec::len).sum());
    for list in per_tile {
        tiles.push(entries.len() as u32);
        entries.extend(list.into_iter().map(|(q, i, w)| (q, pos[i as usize], w)));
    }
    tiles.push(entries.len() as u32);
    BlendWeights { width: b.width, height: b.height, ids, entries, tiles }
}

/// The (pixel, Gaussian id, weight) of the chosen splats of tile `t`, by the rules of
/// [`crate::kernel::forward_tile`]: α = min(0.999, o e^{−σ}), skip σ < 0 or
/// α < 1/255, stop a pixel without blending when T(1 − α) ≤ 1e-4. Splats are applied
/// front to back to the pixels of their box (outside it α < 1/255, see
/// [`crate::bin`]), up to the last chosen one.
fn tile_weights(b: &Binned, t: usize, chosen: &[bool]) -> Vec<(u32, u32, f32)> {
    let list = b.tile_list(t);
    let Some(last) = list.iter().rposition(|&j| chosen[b.ids[j as usize] as usize]) else {
        return Vec::new();
    };
    let (x0, y0, x1, y1) = b.tile_rect(t);
    // T per pixel of the tile; a stopped pixel holds −1.
    let mut tt = [[1.0f32; TILE]; TILE];
    let mut live = (x1 - x0) * (y1 - y0);
    let mut out = Vec::new();
    // First and last pixel index along one axis whose centre lies within `e` of `m`.
    let span = |m: f32, e: f32, lo: usize, hi: usize| {
        let a = (m - e - 0.5).ceil().max(lo as f32) as usize;
        let z = ((m + e - 0.5).floor() + 1.0).clamp(0.0, hi as f32) as usize;
        (a.max(lo), z.max(a.max(lo)))
    };
    for &j in &list[..=last] {
        let s = &b.splats[j as usize];
        let id = b.ids[j as usize];
        let keep = chosen[id as usize];
        let (ya, yz) = span(s.y, s.ey, y0, y1);
        let (xa, xz) = span(s.x, s.ex, x0, x1);
        for py in ya..yz {
            // The kernel's expressions, in its order.
            let dy = s.y - (py as f32 + 0.5);
            let cdy = 0.5 * s.c * dy * dy;
            let bdy = s.b * dy;
            for px in xa..xz {
                let t = &mut tt[py - y0][px - x0];
                if *t < 0.0 {
                    continue;
                }
                let dx = s.x - (px as f32 + 0.5);
                let sigma = 0.5 * s.a * dx * dx + cdy + bdy * dx;
                let alpha = (s.opacity * exp_neg(-sigma)).min(0.999);
                if !(sigma >= 0.0) || !(alpha >= ALPHA_MIN) {
                    continue;
                }
                let next_t = *t * (1.0 - alpha);
                if next_t <= T_MIN {
                    *t = -1.0;
                    live -= 1;
                    continue;
                }
                if keep {
                    out.push(((py * b.width + px) as u32, id, alpha * *t));
                }
                *t = next_t;
            }
        }
        if live == 0 {
            break;
        }
    }
    out
}

/// The colour each of `ids` is rendered with in view `cam` ([`view_colour`]).
pub fn colours(splats: &Splats, cam: &Camera, ids: &[u32]) -> Vec<[f32; 3]> {
    let view = View::new(cam);
    ids.par_iter().with_min_len(1024).map(|&i| view_colour(&view, &splats.params(i as usize))).collect()
}

/// Adds the SH gradients of the colour gradients `v_colour` (one per entry of `ids`,
/// seen from `cam`) into `grad_sh` (`[gaussian][coefficient][channel]`, every
/// coefficient of the layout; inactive ones get nothing), through the colour clamp as
/// `clamp` says.
pub fn colour_sh_backward(
    splats: &Splats,
    cam: &Camera,
    ids: &[u32],
    v_colour: &[[f32; 3]],
    grad_sh: &mut [f32],
    clamp: ClampGrad,
) {
    assert_eq!(ids.len(), v_colour.len(), "one colour gradient per Gaussian");
    let kc = crate::sh_coeffs(splats.sh_degree) * 3;
    assert_eq!(grad_sh.len(), splats.len() * kc, "SH gradient does not match the Gaussians");
    let view = View::new(cam);
    let nsh = crate::sh_coeffs(splats.active_sh_degree.min(splats.sh_degree)) * 3;
    let rows: Vec<[f32; 48]> = ids
        .par_iter()
        .zip(v_colour)
        .with_min_len(1024)
        .map(|(&i, &vc)| {
            let mut v = [0.0f32; 48];
            crate::project::colour_backward(&view, &splats.params(i as usize), vc, &mut v[..nsh], clamp);
            v
        })
        .collect();
    for (&i, v) in ids.iter().zip(&rows) {
        for (d, s) in grad_sh[i as usize * kc..][..nsh].iter_mut().zip(v) {
            *d += s;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{backward, render, Grads, ImageGrads, RenderOptions};
    use transsplat_scene::Gaussians;

    /// A few overlapping Gaussians in front of a camera at the origin looking down +z.
    fn scene() -> (Gaussians, Camera) {
        let mut g = Gaussians { sh_degree: 1, ..Default::default() };
        for k in 0..40 {
            let f = k as f32;
            g.means.push([(f * 0.37).sin() * 0.6, (f * 0.53).cos() * 0.5, 3.0 + (f * 0.29).sin()]);
            g.log_scales.push([-1.6 + 0.3 * (f * 0.7).sin(), -1.8, -1.7]);
            g.rotations.push([1.0, 0.1 * (f * 0.3).sin(), 0.0, 0.05]);
            g.opacity_logits.push(1.5 * (f * 0.41).cos());
            for c in 0..12 {
                g.sh.push(0.4 * ((f + 1.0) * (c as f32 + 1.0) * 0.13).sin());
            }
        }
        let cam = Camera::pinhole("c", 40, 30, 40.0);
        (g, cam)
    }

    #[test]
    fn a_colour_change_of_the_chosen_renders_as_the_full_render() {
        let (g, cam) = scene();
        let chosen: Vec<bool> = (0..g.len()).map(|i| i % 3 == 0).collect();
        let opts = RenderOptions { background: [0.2, 0.3, 0.4] };
        let (before, _) = render(&Splats::new(&g), &cam, &opts);
        let w = blend_weights(&Splats::new(&g), &cam, &chosen);
        assert!(!w.is_empty() && w.ids.iter().all(|&i| chosen[i as usize]));
        let c0 = colours(&Splats::new(&g), &cam, &w.ids);
        // Recolour the chosen Gaussians (DC terms only) and render in full.
        let mut g2 = g.clone();
        for i in (0..g.len()).filter(|&i| chosen[i]) {
            g2.sh[i * 12] += 0.3;
            g2.sh[i * 12 + 2] -= 0.5;
        }
        let (after, _) = render(&Splats::new(&g2), &cam, &opts);
        let c1 = colours(&Splats::new(&g2), &cam, &w.ids);
        let delta: Vec<[f32; 3]> =
            c1.iter().zip(&c0).map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]]).collect();
        let mut rgb = before.rgb.clone();
        w.add(&delta, &mut rgb);
        let worst = rgb.iter().zip(&after.rgb).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(worst < 1e-5, "largest difference {worst}");
        assert!(after.rgb.iter().zip(&before.rgb).any(|(a, b)| (a - b).abs() > 0.05), "the edit shows");
    }

    #[test]
    fn the_transpose_gives_the_backward_pass_colour_gradients() {
        let (g, cam) = scene();
        let chosen = vec![true; g.len()];
        let opts = RenderOptions::default();
        let splats = Splats::new(&g);
        let (img, frame) = render(&splats, &cam, &opts);
        let grad_rgb: Vec<f32> = (0..img.rgb.len()).map(|k| ((k as f32) * 0.71).sin()).collect();
        let mut full = Grads::zeros(g.len(), 1, 0);
        backward(&splats, &cam, &frame, &ImageGrads { rgb: &grad_rgb, ..Default::default() }, &mut full);
        let w = blend_weights(&splats, &cam, &chosen);
        let vcol = w.transpose(&grad_rgb);
        let mut sh = vec![0.0f32; g.sh.len()];
        colour_sh_backward(&splats, &cam, &w.ids, &vcol, &mut sh, ClampGrad::Exact);
        let scale = full.sh.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(scale > 1e-3, "the test image reaches the colours");
        for (k, (a, b)) in sh.iter().zip(&full.sh).enumerate() {
            assert!((a - b).abs() <= 1e-4 * scale, "coefficient {k}: {a} vs {b}");
        }
    }
}

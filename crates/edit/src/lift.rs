//! Lifting per-view planes onto the Gaussians: the splat-back of each view (the
//! transpose of rendering, docs/method.md#m3-transport-cost-and-features) averaged
//! over views by blend weight, x_i = Σ_v W_i^v x̄_i^v / Σ_v W_i^v. It gives the
//! initial semantic latents (docs/method.md#m8-semantic-space), masklift's mask, and
//! the colour lift's step from the edited views' residuals
//! (docs/method.md#m9-the-edit-loop, [`shift_dc`]).

use rayon::prelude::*;
use std::borrow::Cow;
use transsplat_raster::{gaussian_stats, Splats};
use transsplat_scene::{Camera, Gaussians, SH_C0 as C0};

/// Lifts `planes` (`H × W × channels` each, aligned with `cams`) onto the Gaussians of
/// `g`: `N × channels`, 0 for a Gaussian that no view blends.
pub fn lift(g: &Gaussians, cams: &[&Camera], planes: &[&[f32]], channels: usize) -> Vec<f32> {
    lift_each(g, cams, channels, |v| Cow::Borrowed(planes[v]))
}

/// [`lift`] with view `v`'s plane made by `plane(v)` when its turn comes, so only one
/// plane is held at a time.
pub fn lift_each<'a>(
    g: &Gaussians,
    cams: &[&Camera],
    channels: usize,
    mut plane: impl FnMut(usize) -> Cow<'a, [f32]>,
) -> Vec<f32> {
    let n = g.len();
    let mut num = vec![0.0f64; n * channels];
    let mut den = vec![0.0f64; n];
    let s = Splats::new(g);
    let c = channels.max(1);
    for (v, cam) in cams.iter().enumerate() {
        let plane = plane(v);
        let st = gaussian_stats(&s, cam, Some((&plane, channels)));
        (num.par_chunks_mut(c), den.par_iter_mut(), st.splat.par_chunks(c), st.weight_sum.par_iter())
            .into_par_iter()
            .with_min_len(4096)
            .for_each(|(num, den, splat, &w)| {
                let w = w as f64;
                if w > 0.0 {
                    *den += w;
                    for (a, &x) in num.iter_mut().zip(splat) {
                        *a += w * x as f64;
                    }
                }
            });
    }
    weighted_means(&num, &den, channels)
}

/// The means Σ w x / Σ w of `channels` values per Gaussian from their weighted sums
/// `num` and weight sums `den`; 0 where the weight is 0.
pub fn weighted_means(num: &[f64], den: &[f64], channels: usize) -> Vec<f32> {
    (0..num.len())
        .map(|j| if den[j / channels] > 0.0 { (num[j] / den[j / channels]) as f32 } else { 0.0 })
        .collect()
}

/// The colour lift's update (docs/method.md#m9-the-edit-loop): adds each allowed
/// Gaussian's lifted residual Δ_i (`delta`, `N × 3` display RGB) to its DC colour
/// c = C0·f_dc + ½, a channel clamped below 0 starting from the 0 it shows:
/// c' = max(c, 0) + Δ. `k` SH values per Gaussian (DC first); `allowed = None`
/// allows every Gaussian.
pub fn shift_dc(sh: &mut [f32], k: usize, delta: &[f32], allowed: Option<&[bool]>) {
    sh.par_chunks_mut(k).zip(delta.par_chunks(3)).enumerate().for_each(|(i, (row, d))| {
        if allowed.is_none_or(|a| a[i]) {
            for (f, &d) in row[..3].iter_mut().zip(d) {
                let c = (C0 * *f + 0.5).max(0.0) + d;
                *f = (c - 0.5) / C0;
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use transsplat_builtin::{build, SceneConfig};

    /// Constant planes lift to the blend-weighted mean of the constants over the views
    /// that blend each Gaussian (weights from the rasterizer's own statistics), and to
    /// 0 where no view blends it.
    #[test]
    fn constant_planes_lift_to_their_weighted_mean() {
        let scene =
            build("tabletop", &SceneConfig { width: 32, height: 24, views: 3, ..SceneConfig::quick() })
                .unwrap();
        let g = &scene.gaussians;
        let cams: Vec<&Camera> = scene.cameras[..2].iter().collect();
        let px = |c: &Camera| (c.width * c.height) as usize;
        let (p0, p1) = (vec![0.25f32; px(cams[0])], vec![0.75f32; px(cams[1])]);
        let lifted = lift(g, &cams, &[&p0, &p1], 1);
        let s = Splats::new(g);
        let w0 = gaussian_stats(&s, cams[0], None).weight_sum;
        let w1 = gaussian_stats(&s, cams[1], None).weight_sum;
        let (mut both, mut none) = (0, 0);
        for i in 0..g.len() {
            let (a, b) = (w0[i] as f64, w1[i] as f64);
            let want = if a + b > 0.0 { (0.25 * a + 0.75 * b) / (a + b) } else { 0.0 };
            assert!((lifted[i] as f64 - want).abs() < 1e-6, "Gaussian {i}: {} vs {want}", lifted[i]);
            both += (a > 0.0 && b > 0.0) as usize;
            none += (a + b == 0.0) as usize;
        }
        assert!(both > 100 && none > 0, "the test must see shared and unseen Gaussians ({both}, {none})");
    }

    /// Hand-computed: a channel at colour 0.3 moves by Δ, one clamped below 0 (colour
    /// −0.2) starts from 0, the view-dependent coefficients and a Gaussian outside the
    /// mask keep their values.
    #[test]
    fn the_lift_shifts_the_shown_dc_colour_inside_the_mask() {
        let f = |c: f32| (c - 0.5) / C0;
        let mut sh = vec![f(0.3), f(-0.2), f(0.9), 0.5, 0.6, 0.7, f(0.3), f(0.3), f(0.3), 0.1, 0.2, 0.3];
        let before = sh.clone();
        let delta = [0.2, 0.4, -0.5, 0.2, 0.2, 0.2];
        shift_dc(&mut sh, 6, &delta, Some(&[true, false]));
        let shown: Vec<f32> = sh[..3].iter().map(|&v| C0 * v + 0.5).collect();
        for (got, want) in shown.iter().zip([0.5, 0.4, 0.4]) {
            assert!((got - want).abs() < 1e-5, "{shown:?}");
        }
        assert_eq!(sh[3..], before[3..]);
        shift_dc(&mut sh, 6, &delta, None);
        let shown = C0 * sh[6] + 0.5;
        assert!((shown - 0.5).abs() < 1e-5, "{shown}");
    }
}

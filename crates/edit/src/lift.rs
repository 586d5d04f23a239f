//! Lifting per-view planes onto the Gaussians: the splat-back of each view (the
//! transpose of rendering, docs/method.md#m3-transport-cost-and-features) averaged
//! over views by blend weight, x_i = Σ_v W_i^v x̄_i^v / Σ_v W_i^v. It gives the
//! initial semantic latents (docs/method.md#m8-semantic-space) and masklift's mask.

use rayon::prelude::*;
use transsplat_raster::{gaussian_stats, Splats};
use transsplat_scene::{Camera, Gaussians};

/// Lifts `planes` (`H × W × channels` each, aligned with `cams`) onto the Gaussians of
/// `g`: `N × channels`, 0 for a Gaussian that no view blends.
pub fn lift(g: &Gaussians, cams: &[&Camera], planes: &[&[f32]], channels: usize) -> Vec<f32> {
    let n = g.len();
    let mut num = vec![0.0f64; n * channels];
    let mut den = vec![0.0f64; n];
    let s = Splats::new(g);
    let c = channels.max(1);
    for (cam, plane) in cams.iter().zip(planes) {
        let st = gaussian_stats(&s, cam, Some((plane, channels)));
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
    (0..n * channels)
        .map(|j| if den[j / channels] > 0.0 { (num[j] / den[j / channels]) as f32 } else { 0.0 })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use transsplat_scenes::{build, SceneConfig};

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
}

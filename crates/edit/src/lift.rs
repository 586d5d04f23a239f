//! Lifting per-view planes onto the Gaussians: the splat-back of each view (the
//! transpose of rendering, docs/method.md#m3-transport-cost-and-features) averaged
//! over views by blend weight, x_i = Σ_v W_i^v x̄_i^v / Σ_v W_i^v. It gives the
//! initial semantic latents (docs/method.md#m8-semantic-space) and masklift's mask.

use transsplat_raster::{gaussian_stats, Splats};
use transsplat_scene::{Camera, Gaussians};

/// Lifts `planes` (`H × W × channels` each, aligned with `cams`) onto the Gaussians of
/// `g`: `N × channels`, 0 for a Gaussian that no view blends.
pub fn lift(g: &Gaussians, cams: &[&Camera], planes: &[&[f32]], channels: usize) -> Vec<f32> {
    let n = g.len();
    let mut num = vec![0.0f64; n * channels];
    let mut den = vec![0.0f64; n];
    let s = Splats::new(g);
    for (cam, plane) in cams.iter().zip(planes) {
        let st = gaussian_stats(&s, cam, Some((plane, channels)));
        for i in 0..n {
            let w = st.weight_sum[i] as f64;
            if w > 0.0 {
                den[i] += w;
                for k in 0..channels {
                    num[i * channels + k] += w * st.splat[i * channels + k] as f64;
                }
            }
        }
    }
    (0..n * channels)
        .map(|j| if den[j / channels] > 0.0 { (num[j] / den[j / channels]) as f32 } else { 0.0 })
        .collect()
}

//! Per-Gaussian values rendered as a heat map: the value is splatted as a feature
//! channel, divided by alpha, and mapped through a perceptual colour map.

use transsplat_raster::{render, RenderOptions, Splats};
use transsplat_scene::{Camera, Gaussians};

/// A compact approximation of the viridis colour map for t in [0, 1].
pub fn viridis(t: f32) -> [f32; 3] {
    const STOPS: [[f32; 3]; 5] = [
        [0.267, 0.005, 0.329],
        [0.229, 0.322, 0.546],
        [0.128, 0.567, 0.551],
        [0.369, 0.789, 0.383],
        [0.993, 0.906, 0.144],
    ];
    let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 } * 4.0;
    let i = (t.floor() as usize).min(3);
    let f = t - i as f32;
    std::array::from_fn(|k| STOPS[i][k] * (1.0 - f) + STOPS[i + 1][k] * f)
}

/// Renders `values` (one per Gaussian, in [0, 1]) from `cam` as an RGB heat map
/// (`H × W × 3`); pixels with little coverage fade to black.
pub fn render_values(g: &Gaussians, values: &[f32], cam: &Camera) -> Vec<f32> {
    let s = Splats::new(g).with_features(values, 1);
    let (img, _) = render(&s, cam, &RenderOptions::default());
    img.features
        .iter()
        .zip(&img.alpha)
        .flat_map(|(&f, &a)| {
            let c = viridis(if a > 1e-3 { f / a } else { 0.0 });
            let k = a.clamp(0.0, 1.0);
            [c[0] * k, c[1] * k, c[2] * k]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn colour_map_ends() {
        let lo = super::viridis(0.0);
        let hi = super::viridis(1.0);
        assert!(lo[2] > lo[1] && hi[0] > 0.9 && hi[1] > 0.8);
        assert_eq!(super::viridis(f32::NAN), lo);
    }
}

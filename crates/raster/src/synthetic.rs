//! A reproducible synthetic scene and camera, for benchmarks and tests.
//!
//! The scene imitates the depth complexity of a real capture: Gaussians fill the
//! view frustum between depths 2 and 8 with sizes scaled to the count, anisotropic,
//! with opacities spread like a trained scene's, SH degree 3, so that most pixels
//! saturate (T ≤ 1e-4) after tens to a few hundred blends whatever the count.

use transsplat_scene::{rng::SplitMix64, Camera, Gaussians};

/// The benchmark camera: at the origin looking down +z, 60° horizontal field of view.
pub fn bench_camera(width: u32, height: u32) -> Camera {
    let fx = 0.5 * width as f32 / (30f32.to_radians()).tan();
    Camera::pinhole("bench", width, height, fx)
}

/// `n` Gaussians filling the frustum of [`bench_camera`] (resolution-independent).
pub fn bench_scene(n: usize, seed: u64) -> Gaussians {
    let mut rng = SplitMix64::new(seed ^ 0x5EED);
    let tan = 30f32.to_radians().tan();
    // Footprint area per Gaussian ∝ 1/n keeps ~120 overlaps per pixel.
    let pixel_sigma = (0.5 * 512.0 * 512.0 * 120.0 / (n as f32 * std::f32::consts::PI * 9.0)).sqrt();
    let fx = 256.0 / tan;
    let mut g = Gaussians { sh_degree: 3, ..Default::default() };
    g.means.reserve(n);
    g.sh.reserve(n * 48);
    for _ in 0..n {
        let z = 2.0 + 6.0 * rng.uniform();
        let x = (rng.uniform() * 2.2 - 1.1) * tan * z;
        let y = (rng.uniform() * 2.2 - 1.1) * tan * z;
        g.means.push([x, y, z]);
        let s = (pixel_sigma * z / fx * (0.5 * rng.normal()).exp()).ln();
        g.log_scales.push([s + 0.4 * rng.normal(), s + 0.4 * rng.normal(), s - 0.5]);
        g.rotations.push([rng.normal(), rng.normal(), rng.normal(), rng.normal()]);
        g.opacity_logits.push(1.5 * rng.normal() + 0.5);
        for k in 0..16 {
            for _ in 0..3 {
                g.sh.push(if k == 0 { rng.normal() * 0.8 } else { rng.normal() * 0.1 });
            }
        }
    }
    g
}

//! A reproducible synthetic scene for rasterizer benchmarks, and the benchmark.
//!
//! The scene imitates the depth complexity of a real capture: Gaussians fill the
//! view frustum between depths 2 and 8 with sizes scaled to the count, anisotropic,
//! with opacities spread like a trained scene's, SH degree 3, so that most pixels
//! saturate (T ≤ 1e-4) after tens to a few hundred blends whatever the count.

use crate::{backward, gaussian_stats, render, Grads, ImageGrads, RenderOptions, Splats};
use transsplat_scene::timing::best_of;
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

/// Timings of one benchmark configuration (seconds, best of the repetitions).
#[derive(Clone, Debug, Default)]
pub struct BenchResult {
    pub gaussians: usize,
    pub width: u32,
    pub height: u32,
    pub forward: f64,
    /// Projection, depth sort and tile binning alone (part of `forward`).
    pub binning: f64,
    /// The backward with a freshly allocated gradient buffer (its page faults included).
    pub backward: f64,
    /// The backward into one reused gradient buffer, zero on entry (its written rows
    /// cleared after each repetition, untimed), as [`crate::backward`]'s caller in
    /// training keeps it.
    pub backward_reused: f64,
    pub splat_back: f64,
    /// Gaussian–pixel pairs blended.
    pub blended_pairs: u64,
    /// Pixels that reached the transmittance stop.
    pub saturated_fraction: f64,
    /// Median over pixels of the number of tile-list entries traversed.
    pub median_traversed: u32,
    pub intersections: usize,
}

/// Runs forward, backward and splat-back on the synthetic scene.
pub fn run(n: usize, width: u32, height: u32, reps: usize) -> BenchResult {
    run_on(&bench_scene(n, 7), &bench_camera(width, height), reps)
}

/// Runs forward, backward and splat-back of `g` seen by `cam` (any scene, so other
/// implementations can be timed on identical input).
pub fn run_on(g: &Gaussians, cam: &Camera, reps: usize) -> BenchResult {
    let (n, width, height) = (g.len(), cam.width, cam.height);
    let s = Splats::new(g);
    let opts = RenderOptions { background: [0.0; 3] };
    let (forward, (img, frame)) = best_of(0, reps, || render(&s, cam, &opts));
    let view = crate::project::View::new(cam);
    let (binning, _) = best_of(0, reps, || crate::bin::bin(&s, &view));
    let px = (width * height) as usize;
    let v: Vec<f32> = (0..px * 3).map(|i| ((i * 7919) % 17) as f32 / 17.0 - 0.5).collect();
    let va: Vec<f32> = v[..px].to_vec();
    let (bwd, _) = best_of(0, reps, || {
        let mut grads = Grads::zeros(g.len(), g.sh_degree, 0);
        backward(&s, cam, &frame, &ImageGrads { rgb: &v, alpha: &va, ..Default::default() }, &mut grads);
        grads
    });
    let ig = ImageGrads { rgb: &v, alpha: &va, ..Default::default() };
    let mut grads = Grads::zeros(g.len(), g.sh_degree, 0);
    let mut backward_reused = f64::INFINITY;
    for _ in 0..reps.max(1) {
        let t = std::time::Instant::now();
        let rows = backward(&s, cam, &frame, &ig, &mut grads);
        backward_reused = backward_reused.min(t.elapsed().as_secs_f64());
        grads.clear_rows(&rows);
    }
    drop(grads);
    let feat: Vec<f32> = v.clone();
    let (splat, stats) = best_of(0, reps, || gaussian_stats(&s, cam, Some((&feat, 3))));
    let mut traversed = frame.last.clone();
    traversed.sort_unstable();
    BenchResult {
        gaussians: n,
        width,
        height,
        forward,
        binning,
        backward: bwd,
        backward_reused,
        splat_back: splat,
        blended_pairs: stats.pixel_count.iter().map(|&c| c as u64).sum(),
        saturated_fraction: img.alpha.iter().filter(|&&a| a > 0.999).count() as f64 / px as f64,
        median_traversed: traversed[traversed.len() / 2],
        intersections: frame.binned.intersections(),
    }
}

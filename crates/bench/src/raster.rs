//! `bench raster`: forward, binning, backward and splat-back of the rasterizer timed on
//! the synthetic scene ([`transsplat_raster::synthetic`]) or on any scene.

use crate::timing::best_of;
use transsplat_raster::synthetic::{bench_camera, bench_scene};
use transsplat_raster::{backward, gaussian_stats, render, Grads, ImageGrads, RenderOptions, Splats};
use transsplat_scene::{Camera, Gaussians};

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
    /// cleared after each repetition, untimed), as [`transsplat_raster::backward`]'s caller in
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
    let view = transsplat_raster::project::View::new(cam);
    let (binning, _) = best_of(0, reps, || transsplat_raster::bin::bin(&s, &view));
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

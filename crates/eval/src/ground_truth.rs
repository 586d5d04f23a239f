//! Scores an edited scene against the ground-truth edit of a built-in scene on its
//! test views (every 8th camera).
//!
//! - target PSNR: inside the target mask (the ground-truth edited scene's label
//!   render), against the ground-truth edit;
//! - background PSNR: where the target has no visible weight (< 1/255), against the
//!   original (unedited) render — leakage;
//! - PSNR and SSIM: whole image against the ground-truth edit.
//!
//! Masked PSNRs pool the squared error over all test views (a small target gives
//! few pixels per view); PSNR and SSIM are means over views.

use crate::metrics::{psnr_from_mse, squared_error, ssim};
use transsplat_raster::{render, RenderOptions, Splats};
use transsplat_scene::Gaussians;
use transsplat_scenes::Scene;

/// Ground-truth metrics of one edited scene.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct GtMetrics {
    pub target_psnr: f64,
    pub background_psnr: f64,
    pub psnr: f64,
    pub ssim: f64,
}

/// Renders of the source and ground-truth scenes on the test views, computed once
/// and shared by every method's evaluation.
pub struct Reference {
    pub views: Vec<usize>,
    pub source: Vec<Vec<f32>>,
    pub truth: Vec<Vec<f32>>,
    pub target_mask: Vec<Vec<bool>>,
    /// Pixels where the target contributes no visible weight (< 1/255): the
    /// background set, so a correct edit of the target's outline is not leakage.
    pub background_mask: Vec<Vec<bool>>,
    pub background: [f32; 3],
}

impl Reference {
    /// Prepares the references for `scene` edited into `truth` (target `label`).
    pub fn new(scene: &Scene, truth: &Gaussians, label: u32) -> Self {
        let views = scene.test_views();
        let opts = RenderOptions { background: scene.background };
        let (ss, ts) = (Splats::new(&scene.gaussians), Splats::new(truth));
        let mut r = Reference {
            views: views.clone(),
            source: vec![],
            truth: vec![],
            target_mask: vec![],
            background_mask: vec![],
            background: scene.background,
        };
        for &v in &views {
            let cam = &scene.cameras[v];
            r.source.push(render(&ss, cam, &opts).0.rgb);
            r.truth.push(render(&ts, cam, &opts).0.rgb);
            let lr = scene.render_edited(truth, v).expect("test view exists");
            r.target_mask.push(lr.mask(label));
            r.background_mask.push(lr.weight(label).iter().map(|&w| w < 1.0 / 255.0).collect());
        }
        r
    }

    /// How well `scene_like` (a scene trained from the built-in scene's renders)
    /// reproduces the unedited truth on the test views: PSNR inside the target mask and
    /// over the background, against the source renders. The target value bounds what an
    /// edit of that scene can reach on target PSNR (its reconstruction error stays).
    pub fn fidelity(&self, scene: &Scene, scene_like: &Gaussians) -> (f64, f64) {
        let opts = RenderOptions { background: self.background };
        let s = Splats::new(scene_like);
        let (mut se_t, mut n_t, mut se_b, mut n_b) = (0.0, 0, 0.0, 0);
        for (k, &v) in self.views.iter().enumerate() {
            let img = render(&s, &scene.cameras[v], &opts).0.rgb;
            let (a, b) = squared_error(&img, &self.source[k], Some(&self.target_mask[k]));
            (se_t, n_t) = (se_t + a, n_t + b);
            let (a, b) = squared_error(&img, &self.source[k], Some(&self.background_mask[k]));
            (se_b, n_b) = (se_b + a, n_b + b);
        }
        let masked = |se: f64, n: usize| if n == 0 { f64::NAN } else { psnr_from_mse(se / n as f64) };
        (masked(se_t, n_t), masked(se_b, n_b))
    }

    /// The same references with the source renders taken from `source` (a scene
    /// trained from the built-in scene's renders): background PSNR then measures what an
    /// edit changed outside the target rather than the trained scene's own error.
    pub fn with_source(mut self, scene: &Scene, source: &Gaussians) -> Self {
        let opts = RenderOptions { background: self.background };
        let s = Splats::new(source);
        self.source = self.views.iter().map(|&v| render(&s, &scene.cameras[v], &opts).0.rgb).collect();
        self
    }

    /// Scores `edited` (rendered on the same test views).
    pub fn score(&self, scene: &Scene, edited: &Gaussians) -> GtMetrics {
        let opts = RenderOptions { background: self.background };
        let s = Splats::new(edited);
        let (mut se_t, mut n_t, mut se_b, mut n_b) = (0.0, 0, 0.0, 0);
        let (mut psnr_sum, mut ssim_sum) = (0.0, 0.0);
        for (k, &v) in self.views.iter().enumerate() {
            let cam = &scene.cameras[v];
            let img = render(&s, cam, &opts).0.rgb;
            let inside = &self.target_mask[k];
            let outside = &self.background_mask[k];
            let (a, b) = squared_error(&img, &self.truth[k], Some(inside));
            se_t += a;
            n_t += b;
            let (a, b) = squared_error(&img, &self.source[k], Some(outside));
            se_b += a;
            n_b += b;
            let (a, b) = squared_error(&img, &self.truth[k], None);
            psnr_sum += psnr_from_mse(a / b.max(1) as f64);
            ssim_sum += ssim(&img, &self.truth[k], cam.width as usize, cam.height as usize);
        }
        let nv = self.views.len().max(1) as f64;
        // NaN (JSON null) when a set is empty, e.g. the target is in no test view.
        let masked = |se: f64, n: usize| if n == 0 { f64::NAN } else { psnr_from_mse(se / n as f64) };
        GtMetrics {
            target_psnr: masked(se_t, n_t),
            background_psnr: masked(se_b, n_b),
            psnr: psnr_sum / nv,
            ssim: ssim_sum / nv,
        }
    }
}

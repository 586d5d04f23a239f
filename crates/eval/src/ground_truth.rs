//! Scores an edited scene against the ground-truth edit of a built-in scene on its
//! test views (every 8th camera).
//!
//! - target PSNR: inside the target mask (the pixels of the ground-truth edited scene's
//!   label render whose label is one of the target labels), against the ground-truth
//!   edit;
//! - background PSNR: where the target has no visible weight (the summed weight of the
//!   target labels, min(1, Σ w_l), below 1/255), against the original (unedited)
//!   render — leakage. When the target includes label 0, the background itself (a
//!   global edit), nothing lies outside the edit: the set is empty and the value NaN;
//! - silhouette PSNR: within [`SILHOUETTE_RADIUS`] of the target mask's outline, on
//!   both sides, against the ground-truth edit. The target PSNR counts the inside of
//!   the outline only, so an edit that carries the new colour past the outline gains
//!   there and pays just outside it, which the target set does not see and the
//!   background set sees at most in part, diluted over the frame; the band scores
//!   both sides alike (docs/method.md#v2-ground-truth-metrics);
//! - PSNR and SSIM: whole image against the ground-truth edit.
//! - the background PSNR of each view, and of the worst view: a leak seen from a few
//!   cameras (a halo the editor's spill left on the table, say) hides in the pooled
//!   value; the worst view shows it.
//!
//! Masked PSNRs pool the squared error over all test views (a small target gives
//! few pixels per view); PSNR and SSIM are means over views. Every PSNR is capped at
//! [`PSNR_CAP`]: below 8-bit quantisation, differences are ties.

use crate::metrics::{psnr_from_mse, squared_error, ssim};
use transsplat_builtin::masks::grow;
use transsplat_builtin::{LabelRender, Scene};
use transsplat_raster::{render, RenderOptions, Splats};
use transsplat_scene::{Camera, Gaussians};

/// PSNRs above this are reported as this: an error below half an 8-bit level
/// everywhere (a PSNR of about 54 dB) is no visible difference, so higher values are
/// ties, and 60 dB leaves room above that for a few stray pixels.
pub const PSNR_CAP: f64 = 60.0;

/// Half-width of the silhouette band, as a fraction of the image diagonal (at least one
/// pixel): about the blur of a trained scene's outline at the suite's sizes, and the
/// scale the prototypes' closing works at (docs/method.md#m2-prototypes).
pub const SILHOUETTE_RADIUS: f32 = 0.01;

/// The silhouette band of a `w × h` target mask: the pixels within r =
/// max(1, [`SILHOUETTE_RADIUS`] · diagonal) pixels (Euclidean) of the other side, inside
/// the mask or outside it: the mask grown by r and not in the mask shrunk by r. Empty
/// when the mask is empty or covers the whole image.
pub fn silhouette_band(target: &[bool], w: usize, h: usize) -> Vec<bool> {
    let r = (SILHOUETTE_RADIUS * ((w * w + h * h) as f32).sqrt()).max(1.0);
    let (grown, shrunk) = (grow(target, w, h, r), grow(target, w, h, -r));
    grown.iter().zip(&shrunk).map(|(&g, &s)| g && !s).collect()
}

/// The target mask (pixels labelled with one of `labels`) and the background set (the
/// target's summed weight below 1/255; empty for a global edit, whose labels include 0)
/// of one view's label render.
fn target_sets(lr: &LabelRender, labels: &[u32]) -> (Vec<bool>, Vec<bool>) {
    let global = labels.contains(&0);
    (lr.mask_of(labels), lr.weight_of(labels).iter().map(|&w| !global && w < 1.0 / 255.0).collect())
}

/// A PSNR capped at [`PSNR_CAP`] (NaN stays NaN).
fn capped(psnr: f64) -> f64 {
    if psnr > PSNR_CAP {
        PSNR_CAP
    } else {
        psnr
    }
}

/// Ground-truth metrics of one edited scene.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct GtMetrics {
    pub target_psnr: f64,
    pub background_psnr: f64,
    /// The lowest background PSNR of a test view (NaN when no view has background).
    pub background_psnr_worst: f64,
    /// Each test view's background PSNR (NaN where it has no background pixel).
    pub background_psnr_views: Vec<f64>,
    /// Inside the silhouette band ([`silhouette_band`]), against the ground-truth edit
    /// (NaN when no test view has one).
    pub silhouette_psnr: f64,
    pub psnr: f64,
    pub ssim: f64,
}

/// Renders of the source and ground-truth scenes on the test views, computed once
/// and shared by every method's evaluation.
#[derive(Clone)]
pub struct Reference {
    pub views: Vec<usize>,
    pub source: Vec<Vec<f32>>,
    pub truth: Vec<Vec<f32>>,
    pub target_mask: Vec<Vec<bool>>,
    /// Pixels where the target contributes no visible weight (< 1/255): the
    /// background set, so a correct edit of the target's outline is not leakage.
    pub background_mask: Vec<Vec<bool>>,
    /// The target mask's silhouette band ([`silhouette_band`]).
    pub silhouette_mask: Vec<Vec<bool>>,
    pub background: [f32; 3],
}

impl Reference {
    /// Prepares the references for `scene` edited into `truth`; `labels` are the target
    /// labels (the objects the edit changes; every label, 0 included, for a global edit).
    pub fn new(scene: &Scene, truth: &Gaussians, labels: &[u32]) -> Self {
        let views = scene.test_views();
        let opts = RenderOptions { background: scene.background };
        let (ss, ts) = (Splats::new(&scene.gaussians), Splats::new(truth));
        let mut r = Reference {
            views: views.clone(),
            source: vec![],
            truth: vec![],
            target_mask: vec![],
            background_mask: vec![],
            silhouette_mask: vec![],
            background: scene.background,
        };
        for &v in &views {
            let cam = &scene.cameras[v];
            r.source.push(render(&ss, cam, &opts).0.rgb);
            r.truth.push(render(&ts, cam, &opts).0.rgb);
            let lr = scene.render_edited(truth, v).expect("test view exists");
            let (target, background) = target_sets(&lr, labels);
            r.silhouette_mask.push(silhouette_band(&target, cam.width as usize, cam.height as usize));
            r.target_mask.push(target);
            r.background_mask.push(background);
        }
        r
    }

    /// References from images: `source[k]` and `truth[k]` of test view `views[k]`, the
    /// truth's labels from `truth_labels[k]` (a capture's segmentation, say), `labels`
    /// the target's (see [`Reference::new`]).
    pub fn from_images(
        views: Vec<usize>,
        source: Vec<Vec<f32>>,
        truth_labels: &[LabelRender],
        labels: &[u32],
        background: [f32; 3],
    ) -> Self {
        let (target_mask, background_mask): (Vec<_>, _) =
            truth_labels.iter().map(|lr| target_sets(lr, labels)).unzip();
        let silhouette_mask = target_mask
            .iter()
            .zip(truth_labels)
            .map(|(t, lr)| silhouette_band(t, lr.width, lr.height))
            .collect();
        let truth = truth_labels.iter().map(|lr| lr.rgb.clone()).collect();
        Reference { views, source, truth, target_mask, background_mask, silhouette_mask, background }
    }

    /// How well `scene_like` (a scene trained from the built-in scene's renders)
    /// reproduces the unedited truth on the test views: PSNR inside the target mask and
    /// over the background, against the source renders. The target value bounds what an
    /// edit of that scene can reach on target PSNR (its reconstruction error stays).
    pub fn fidelity(&self, cameras: &[Camera], scene_like: &Gaussians) -> (f64, f64) {
        let opts = RenderOptions { background: self.background };
        let s = Splats::new(scene_like);
        let (mut se_t, mut n_t, mut se_b, mut n_b) = (0.0, 0, 0.0, 0);
        for (k, &v) in self.views.iter().enumerate() {
            let img = render(&s, &cameras[v], &opts).0.rgb;
            let (a, b) = squared_error(&img, &self.source[k], Some(&self.target_mask[k]));
            (se_t, n_t) = (se_t + a, n_t + b);
            let (a, b) = squared_error(&img, &self.source[k], Some(&self.background_mask[k]));
            (se_b, n_b) = (se_b + a, n_b + b);
        }
        let masked = |se: f64, n: usize| if n == 0 { f64::NAN } else { capped(psnr_from_mse(se / n as f64)) };
        (masked(se_t, n_t), masked(se_b, n_b))
    }

    /// The same references with the source renders taken from `source` (a scene
    /// trained from the built-in scene's renders): background PSNR then measures what an
    /// edit changed outside the target rather than the trained scene's own error.
    pub fn with_source(mut self, cameras: &[Camera], source: &Gaussians) -> Self {
        let opts = RenderOptions { background: self.background };
        let s = Splats::new(source);
        self.source = self.views.iter().map(|&v| render(&s, &cameras[v], &opts).0.rgb).collect();
        self
    }

    /// Scores `edited` (rendered on the same test views).
    pub fn score(&self, cameras: &[Camera], edited: &Gaussians) -> GtMetrics {
        let opts = RenderOptions { background: self.background };
        let s = Splats::new(edited);
        let (mut se_t, mut n_t, mut se_b, mut n_b) = (0.0, 0, 0.0, 0);
        let (mut se_s, mut n_s) = (0.0, 0);
        let (mut psnr_sum, mut ssim_sum) = (0.0, 0.0);
        let mut background_views = Vec::with_capacity(self.views.len());
        for (k, &v) in self.views.iter().enumerate() {
            let cam = &cameras[v];
            let img = render(&s, cam, &opts).0.rgb;
            let inside = &self.target_mask[k];
            let outside = &self.background_mask[k];
            let (a, b) = squared_error(&img, &self.truth[k], Some(inside));
            se_t += a;
            n_t += b;
            let (a, b) = squared_error(&img, &self.source[k], Some(outside));
            se_b += a;
            n_b += b;
            background_views.push(if b == 0 { f64::NAN } else { capped(psnr_from_mse(a / b as f64)) });
            let (a, b) = squared_error(&img, &self.truth[k], Some(&self.silhouette_mask[k]));
            se_s += a;
            n_s += b;
            let (a, b) = squared_error(&img, &self.truth[k], None);
            psnr_sum += capped(psnr_from_mse(a / b.max(1) as f64));
            ssim_sum += ssim(&img, &self.truth[k], cam.width as usize, cam.height as usize);
        }
        let nv = self.views.len().max(1) as f64;
        // NaN (JSON null) when a set is empty, e.g. the target is in no test view.
        let masked = |se: f64, n: usize| if n == 0 { f64::NAN } else { capped(psnr_from_mse(se / n as f64)) };
        let worst = background_views.iter().copied().filter(|v| v.is_finite()).fold(f64::NAN, f64::min);
        GtMetrics {
            target_psnr: masked(se_t, n_t),
            background_psnr: masked(se_b, n_b),
            background_psnr_worst: worst,
            background_psnr_views: background_views,
            silhouette_psnr: masked(se_s, n_s),
            psnr: psnr_sum / nv,
            ssim: ssim_sum / nv,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use transsplat_builtin::{build, SceneConfig, Style};

    #[test]
    fn a_label_set_unites_the_masks_and_a_global_edit_has_no_background() {
        let s = build("tabletop", &SceneConfig::quick()).unwrap();
        let (ball, cone) = (s.label_of("ball").unwrap(), s.label_of("cone").unwrap());
        let blue = [0.1, 0.2, 0.9];
        let truth =
            transsplat_builtin::recolor(&s.recolor(ball, blue).unwrap(), &s.labels, cone, blue).unwrap();
        let both = Reference::new(&s, &truth, &[ball, cone]);
        let one = Reference::new(&s, &truth, &[ball]);
        for k in 0..both.views.len() {
            let lr = s.render_edited(&truth, both.views[k]).unwrap();
            for p in 0..lr.labels.len() {
                let l = lr.labels[p];
                assert_eq!(both.target_mask[k][p], l == ball || l == cone);
                // outside = the summed weight of the two labels below 1/255
                let w = (lr.weight(ball)[p] + lr.weight(cone)[p]).min(1.0);
                assert_eq!(both.background_mask[k][p], w < 1.0 / 255.0, "view {k} pixel {p}");
                assert!(
                    !both.background_mask[k][p] || one.background_mask[k][p],
                    "outside both is outside one"
                );
            }
        }
        // the truth scores perfectly inside; the source leaks nothing outside (capped)
        let m = both.score(&s.cameras, &truth);
        assert!(m.target_psnr == PSNR_CAP && m.background_psnr == PSNR_CAP, "{m:?}");
        assert_eq!(m.background_psnr_views, vec![PSNR_CAP; both.views.len()]);
        assert_eq!(m.background_psnr_worst, PSNR_CAP);
        // a leak in one view only: the worst view shows it, the pooled value less so
        let mut leaky = both.clone();
        leaky.source[0]
            .iter_mut()
            .zip(&both.background_mask[0].iter().flat_map(|&b| [b; 3]).collect::<Vec<_>>())
            .for_each(|(v, &b)| {
                if b {
                    *v = (*v + 0.1).min(1.0);
                }
            });
        let m = leaky.score(&s.cameras, &truth);
        assert!(m.background_psnr_views[1..].iter().all(|&v| v == PSNR_CAP), "{m:?}");
        assert!(m.background_psnr_views[0] < 25.0, "{m:?}");
        assert_eq!(m.background_psnr_worst, m.background_psnr_views[0]);
        assert!(m.background_psnr > m.background_psnr_worst, "{m:?}");
        // a global edit: every pixel is target, nothing is background
        let autumn = s.restyle(Style::Autumn).unwrap();
        let all: Vec<u32> = (0..s.num_labels() as u32).collect();
        let g = Reference::new(&s, &autumn, &all);
        assert!(g.target_mask.iter().flatten().all(|&t| t));
        assert!(g.background_mask.iter().flatten().all(|&b| !b));
        let m = g.score(&s.cameras, &s.gaussians);
        assert!(m.background_psnr.is_nan() && m.background_psnr_worst.is_nan(), "{m:?}");
        assert!(m.background_psnr_views.iter().all(|v| v.is_nan()));
        assert!(
            m.target_psnr.is_finite() && m.target_psnr < 30.0,
            "the unedited scene misses the style: {m:?}"
        );
        assert_eq!(g.score(&s.cameras, &autumn).target_psnr, PSNR_CAP);
    }

    /// A 4 × 4 square in a 10 × 10 image (diagonal 14.1, so r = 1 px): the band is the
    /// square's 12 border pixels and the 16 pixels that touch it edge-on (the corners'
    /// diagonal neighbours lie √2 away); an empty or full mask has no outline.
    #[test]
    fn the_silhouette_band_is_one_radius_on_either_side_of_the_outline() {
        let (w, h) = (10, 10);
        let inside = |x: usize, y: usize| (3..7).contains(&x) && (3..7).contains(&y);
        let target: Vec<bool> = (0..w * h).map(|p| inside(p % w, p / w)).collect();
        let band = silhouette_band(&target, w, h);
        for (p, &in_band) in band.iter().enumerate() {
            let (x, y) = (p % w, p / w);
            let (dx, dy) = (
                3usize.saturating_sub(x).max(x.saturating_sub(6)),
                3usize.saturating_sub(y).max(y.saturating_sub(6)),
            );
            let expected = if inside(x, y) {
                x == 3 || x == 6 || y == 3 || y == 6
            } else {
                (dx == 1 && dy == 0) || (dx == 0 && dy == 1)
            };
            assert_eq!(in_band, expected, "pixel ({x}, {y})");
        }
        assert_eq!(band.iter().filter(|&&b| b).count(), 28);
        assert!(silhouette_band(&[false; 100], w, h).iter().all(|&b| !b));
        assert!(silhouette_band(&[true; 100], w, h).iter().all(|&b| !b));
    }

    /// The band sees both sides of the outline: a truth changed only on the band's
    /// outer side (where an edit that carries its colour past the outline differs)
    /// leaves the target PSNR perfect and costs silhouette PSNR.
    #[test]
    fn the_silhouette_scores_the_outline_outside_the_target() {
        let s = build("tabletop", &SceneConfig::quick()).unwrap();
        let ball = s.label_of("ball").unwrap();
        let truth = s.recolor(ball, [0.1, 0.2, 0.9]).unwrap();
        let r = Reference::new(&s, &truth, &[ball]);
        let m = r.score(&s.cameras, &truth);
        assert_eq!((m.target_psnr, m.silhouette_psnr), (PSNR_CAP, PSNR_CAP), "{m:?}");
        let (mut shifted, mut inner, mut outer) = (r.clone(), 0, 0);
        for k in 0..r.views.len() {
            for p in 0..r.target_mask[k].len() {
                match (r.silhouette_mask[k][p], r.target_mask[k][p]) {
                    (true, true) => inner += 1,
                    (true, false) => {
                        outer += 1;
                        shifted.truth[k][3 * p..3 * p + 3].iter_mut().for_each(|v| *v = 1.0 - *v);
                    }
                    _ => {}
                }
            }
        }
        assert!(inner > 0 && outer > 0, "{inner} {outer}");
        let m = shifted.score(&s.cameras, &truth);
        assert_eq!(m.target_psnr, PSNR_CAP, "{m:?}");
        assert!(m.silhouette_psnr < 30.0, "{m:?}");
    }
}

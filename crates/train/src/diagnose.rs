//! Why a held-out view scores far below the others: floaters or extrapolation.
//!
//! A test view far below the mean test PSNR has one of two causes, which call for
//! different remedies:
//!
//! - **Floaters**: the view sees splats in front of what the training views saw there,
//!   splats no training view can see where this one does. From the training cameras
//!   they sit far off (in the sky, say), behind the camera, or nowhere they contribute;
//!   from the held-out camera they are near, and cover the image as haze or blobs.
//! - **Extrapolation**: the view sees the scene the training views saw, at the depths
//!   they see it, from an angle they did not constrain: from outside them (a higher
//!   ring, a wider angle, a part they saw from one side or not at all), or from between
//!   them where their geometry is wrong but consistent (a surface seen only at grazing
//!   angles, whose splats float where every training view accepts them: the far floor
//!   of docs/method.md T2). Nothing sits in front of it that they do not also see.
//!
//! They are told apart by depth ([`diagnose`]). Each splat that contributes to the test
//! view (blend weight Σ T α > 0) is compared with its depth in the training views where
//! it contributes at least [`SEEN_WEIGHT`]: a splat at less than [`NEAR_RATIO`] of its
//! nearest such training depth is *near content no training view's depth holds*; so is
//! a splat no training view sees that lies nearer than [`NEAR_RATIO`] of the test view's
//! median depth. When such splats carry at least [`FLOATER_SHARE`] of the test view's
//! blend weight, the verdict is floaters; otherwise extrapolation. The depth of a splat
//! is its mean's camera-space z, the quantity the rasterizer sorts by.

use crate::trainer::Trainer;
use rayon::prelude::*;
use transsplat_raster::gaussian_stats;
use transsplat_raster::project::View;
use transsplat_scene::Camera;

/// A splat nearer than this fraction of where the training views see it is "near".
pub const NEAR_RATIO: f32 = 0.25;
/// Blend weight (in pixels' worth, Σ_p T α) from which a training view counts as seeing a splat.
pub const SEEN_WEIGHT: f32 = 0.5;
/// Share of the test view's blend weight in near splats from which the verdict is floaters.
pub const FLOATER_SHARE: f32 = 0.05;

/// What makes a low test view low.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cause {
    /// Splats in front of the view that no training view sees at that depth.
    Floaters,
    /// The view sees what the training views saw, at their depths, from an angle they
    /// did not constrain.
    Extrapolation,
}

impl Cause {
    /// The name used in logs and `train.json`.
    pub fn name(self) -> &'static str {
        match self {
            Cause::Floaters => "floaters",
            Cause::Extrapolation => "extrapolation",
        }
    }
}

/// The verdict on one test view.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Diagnosis {
    pub cause: Cause,
    /// Share of the view's blend weight in near splats (module doc).
    pub near_share: f32,
}

/// Camera-space depth of a world point, as the rasterizer computes it.
fn depth(view: &View, p: [f32; 3]) -> f32 {
    view.to_camera(p)[2]
}

/// Diagnoses `test` against the training cameras `train` (module doc). Renders the
/// per-splat statistics of every training view once: for a flagged view only.
pub fn diagnose(trainer: &Trainer, test: &Camera, train: &[Camera]) -> Diagnosis {
    let splats = trainer.splats();
    let means = &trainer.model.gaussians.means;
    let seen_in_test = gaussian_stats(&splats, test, None).weight_sum;
    let test_view = View::new(test);
    // Per splat, the nearest depth at which a training view sees it (∞ if none does).
    let nearest = train
        .par_iter()
        .map(|cam| {
            let w = gaussian_stats(&splats, cam, None).weight_sum;
            let view = View::new(cam);
            means
                .iter()
                .zip(&w)
                .map(|(&m, &w)| if w >= SEEN_WEIGHT { depth(&view, m) } else { f32::INFINITY })
                .collect::<Vec<f32>>()
        })
        .reduce(
            || vec![f32::INFINITY; means.len()],
            |a, b| a.iter().zip(&b).map(|(x, y)| x.min(*y)).collect(),
        );
    let contributing: Vec<(f32, f32, f32)> = seen_in_test
        .iter()
        .zip(means)
        .zip(&nearest)
        .filter(|((&w, _), _)| w > 0.0)
        .map(|((&w, &m), &near)| (w, depth(&test_view, m), near))
        .collect();
    let total: f32 = contributing.iter().map(|c| c.0).sum();
    if !(total > 0.0) {
        return Diagnosis { cause: Cause::Extrapolation, near_share: 0.0 };
    }
    let median = weighted_median(contributing.iter().map(|&(w, d, _)| (d, w)).collect());
    let near_weight: f32 = contributing
        .iter()
        .filter(
            |&&(_, d, near)| {
                if near.is_finite() {
                    d < NEAR_RATIO * near
                } else {
                    d < NEAR_RATIO * median
                }
            },
        )
        .fold(0.0, |sum, c| sum + c.0);
    let near_share = near_weight / total;
    let cause = if near_share >= FLOATER_SHARE { Cause::Floaters } else { Cause::Extrapolation };
    Diagnosis { cause, near_share }
}

/// The value at half the total weight of `(value, weight)` pairs.
fn weighted_median(mut pairs: Vec<(f32, f32)>) -> f32 {
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let half = pairs.iter().map(|p| p.1).sum::<f32>() / 2.0;
    let mut acc = 0.0;
    for &(v, w) in &pairs {
        acc += w;
        if acc >= half {
            return v;
        }
    }
    pairs.last().map_or(0.0, |p| p.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weighted_median_by_hand() {
        assert_eq!(weighted_median(vec![(5.0, 1.0), (1.0, 1.0), (3.0, 1.0)]), 3.0);
        assert_eq!(weighted_median(vec![(5.0, 10.0), (1.0, 1.0), (3.0, 1.0)]), 5.0);
        assert_eq!(weighted_median(vec![(2.0, 3.0), (9.0, 1.0)]), 2.0);
    }
}

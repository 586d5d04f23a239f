//! The simulated segmenter: a built-in scene's true target mask, corrupted per view the
//! way text-grounded segmenters (CLIPSeg, Grounded-SAM) fail, at a chosen severity. It
//! exists to measure what a segmenter's errors do to each method (issue #43); it is not a
//! substitute for a real segmenter.
//!
//! The true mask of a view is the pixels whose label (in the source scene's label render)
//! is one of the target's. With s ≥ 0 the severity (s = 0 returns the true mask exactly)
//! and a generator seeded by (seed, view index), so a view's mask does not depend on the
//! order of the views, the draws are made in this order for every view:
//!
//! 1. Boundary error: the mask grows (d > 0) or shrinks (d < 0) by |d| pixels,
//!    d = round(s · U(−2, 2)) (a Euclidean distance transform of the mask or of its
//!    complement).
//! 2. A thin part dropped: with probability min(1, 0.3 s) a morphological opening of
//!    radius r = max(1, round(s)) pixels (shrink by r, grow by r) removes every part
//!    thinner than 2r, a stem or a handle.
//! 3. The look-alike included: with probability min(1, 0.25 s) the distractor's pixels
//!    (the non-target object nearest in colour, as the simulated editor picks it) join
//!    the mask.
//! 4. Over-segmentation: with probability min(0.3, 0.1 s) the label the target stands on
//!    (the non-target label with the most pixels within 3 pixels of the target's
//!    boundary, the background included) joins the mask: the whole table, the ground.
//! 5. A miss: with probability min(0.4, 0.1 s) the view's mask is empty (the target was
//!    not found), whatever items 1–4 drew.
//!
//! A global edit (every label targeted) gets the whole image as its mask.

use crate::masks::grow;
use crate::Scene;
use transsplat_editors::segment::Segmenter;
use transsplat_editors::{Error, SourceView};
use transsplat_scene::rng::SplitMix64;

/// The simulated segmenter of a built-in scene (see the module doc).
#[derive(Clone, Debug)]
pub struct SimulatedSegmenter {
    scene: Scene,
    target: Vec<u32>,
    distractor: Option<u32>,
    severity: f32,
    seed: u64,
}

impl SimulatedSegmenter {
    /// Masks of `target` (labels of `scene`) at `severity` (negative or NaN is read as 0)
    /// with the look-alike `distractor`, seeded by `seed`.
    pub fn new(scene: &Scene, target: &[u32], distractor: Option<u32>, severity: f32, seed: u64) -> Self {
        let severity = if severity.is_finite() { severity.max(0.0) } else { 0.0 };
        SimulatedSegmenter { scene: scene.clone(), target: target.to_vec(), distractor, severity, seed }
    }

    /// The mask of camera `index` at `w × h` (module doc).
    fn mask(&self, index: usize, w: usize, h: usize) -> Vec<f32> {
        let Some(r) = self.scene.render_view(index) else { return vec![0.0; w * h] };
        if (r.width, r.height) != (w, h) {
            return vec![0.0; w * h];
        }
        if self.target.contains(&0) {
            return vec![1.0; w * h];
        }
        let mut rng = SplitMix64::new(
            self.seed ^ 0x5E6_0000 ^ (index as u64).wrapping_add(1).wrapping_mul(0x9E37_79B9),
        );
        rng.next_u64();
        let s = self.severity;
        let truth = r.mask_of(&self.target);
        let shift = (s * rng.range(-2.0, 2.0)).round();
        let opens = rng.uniform() < (0.3 * s).min(1.0);
        let radius = s.round().max(1.0);
        let with_distractor = rng.uniform() < (0.25 * s).min(1.0);
        let over = rng.uniform() < (0.1 * s).min(0.3);
        let missed = rng.uniform() < (0.1 * s).min(0.4);
        if missed {
            return vec![0.0; w * h];
        }
        let mut mask = grow(&truth, w, h, shift);
        if opens {
            mask = grow(&grow(&mask, w, h, -radius), w, h, radius);
        }
        if with_distractor {
            if let Some(d) = self.distractor {
                mask.iter_mut().zip(r.mask(d)).for_each(|(m, d)| *m |= d);
            }
        }
        if over {
            if let Some(support) = support_label(&r.labels, &truth, &self.target, w, h) {
                mask.iter_mut().zip(r.mask(support)).for_each(|(m, d)| *m |= d);
            }
        }
        mask.into_iter().map(|m| if m { 1.0 } else { 0.0 }).collect()
    }
}

/// The non-target label with the most pixels within 3 pixels outside the target's mask.
fn support_label(labels: &[u32], truth: &[bool], target: &[u32], w: usize, h: usize) -> Option<u32> {
    let ring = grow(truth, w, h, 3.0);
    let mut counts = std::collections::BTreeMap::<u32, usize>::new();
    for ((&l, &in_ring), &inside) in labels.iter().zip(&ring).zip(truth) {
        if in_ring && !inside && !target.contains(&l) {
            *counts.entry(l).or_default() += 1;
        }
    }
    counts.into_iter().max_by_key(|&(l, n)| (n, std::cmp::Reverse(l))).map(|(l, _)| l)
}

impl Segmenter for SimulatedSegmenter {
    fn name(&self) -> &str {
        "simulated-segmenter"
    }

    fn segment(&mut self, views: &[SourceView], _phrase: &str) -> Result<Vec<Option<Vec<f32>>>, Error> {
        Ok(views
            .iter()
            .map(|v| {
                let (w, h) = v.size();
                let m = self.mask(v.index, w, h);
                m.iter().any(|&x| x > 0.5).then_some(m)
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{build, SceneConfig};

    #[test]
    fn severity_zero_is_the_truth_and_errors_grow_with_severity() {
        let scene = build("tabletop", &SceneConfig::quick()).unwrap();
        let ball = scene.label_of("ball").unwrap();
        let views: Vec<usize> = scene.train_views();
        let perfect = SimulatedSegmenter::new(&scene, &[ball], None, 0.0, 1);
        let (mut wrong_zero, mut wrong_high, mut misses) = (0usize, 0usize, 0usize);
        for &v in &views {
            let r = scene.render_view(v).unwrap();
            let truth = r.mask_of(&[ball]);
            let m = perfect.mask(v, r.width, r.height);
            wrong_zero += m.iter().zip(&truth).filter(|(&m, &t)| (m > 0.5) != t).count();
            let noisy = SimulatedSegmenter::new(&scene, &[ball], None, 3.0, 1).mask(v, r.width, r.height);
            wrong_high += noisy.iter().zip(&truth).filter(|(&m, &t)| (m > 0.5) != t).count();
            misses += usize::from(noisy.iter().all(|&x| x == 0.0));
        }
        assert_eq!(wrong_zero, 0, "severity 0 is the true mask");
        assert!(wrong_high > 0 && misses < views.len(), "severity 3 errs but not everywhere");
        // reproducible, per view
        let r = scene.render_view(views[1]).unwrap();
        let a = SimulatedSegmenter::new(&scene, &[ball], None, 2.0, 7).mask(views[1], r.width, r.height);
        let b = SimulatedSegmenter::new(&scene, &[ball], None, 2.0, 7).mask(views[1], r.width, r.height);
        assert_eq!(a, b);
        assert_eq!(a.len(), r.width * r.height);
    }

    #[test]
    fn grow_and_shrink_by_hand() {
        // a 5 × 5 image with the centre pixel set
        let mut m = vec![false; 25];
        m[12] = true;
        let grown = grow(&m, 5, 5, 1.0);
        assert_eq!(grown.iter().filter(|&&x| x).count(), 5, "a plus of radius 1");
        assert_eq!(grow(&grown, 5, 5, -1.0), m, "shrinking the plus by 1 leaves its centre");
        assert!(grow(&m, 5, 5, -1.0).iter().all(|&x| !x), "a single pixel is thinner than 2");
    }
}

//! Ground-truth object masks: the per-Gaussian labels rendered as one-hot feature
//! channels with the rasterizer, in the same pass as the colour image.
//!
//! A pixel's label is the channel with the largest blend weight where the rendered
//! alpha exceeds 0.5, and 0 (background) elsewhere. The per-label soft mask is that
//! label's blend weight divided by the alpha. Pixels where a label has exactly zero
//! weight receive no contribution at all from its Gaussians.
//!
//! Also the geometry of binary masks that the simulated editor, the simulated segmenter
//! and the ground-truth scores share: the Euclidean distance to a mask
//! ([`distance_to`]) and a mask grown or shrunk by it ([`grow`]).

use crate::catalog::Scene;
use transsplat_raster::{render, RenderOptions, Splats};
use transsplat_scene::{Camera, Gaussians};

/// Squared Euclidean distance transform of one line (Felzenszwalb & Huttenlocher):
/// `d[q] = min_p (q − p)² + f[p]`.
fn edt_line(f: &[f64], d: &mut [f64]) {
    let n = f.len();
    if n == 0 {
        return;
    }
    let mut v = vec![0usize; n];
    let mut z = vec![0.0f64; n + 1];
    let mut k = 0usize;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    let inter = |q: usize, p: usize| {
        ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * q as f64 - 2.0 * p as f64)
    };
    for q in 1..n {
        let mut s = inter(q, v[k]);
        while s <= z[k] {
            k -= 1;
            s = inter(q, v[k]);
        }
        k += 1;
        v[k] = q;
        z[k] = s;
        z[k + 1] = f64::INFINITY;
    }
    k = 0;
    for (q, dq) in d.iter_mut().enumerate() {
        while z[k + 1] < q as f64 {
            k += 1;
        }
        let p = v[k];
        *dq = (q as f64 - p as f64).powi(2) + f[p];
    }
}

/// Euclidean distance (pixels) from every pixel to the nearest `true` of `mask`;
/// `None` when the mask is empty.
pub fn distance_to(mask: &[bool], w: usize, h: usize) -> Option<Vec<f32>> {
    if !mask.iter().any(|&m| m) {
        return None;
    }
    const FAR: f64 = 1e18;
    let mut g: Vec<f64> = mask.iter().map(|&m| if m { 0.0 } else { FAR }).collect();
    let mut line = vec![0.0f64; w.max(h)];
    let mut out = vec![0.0f64; w.max(h)];
    for y in 0..h {
        line[..w].copy_from_slice(&g[y * w..(y + 1) * w]);
        edt_line(&line[..w], &mut out[..w]);
        g[y * w..(y + 1) * w].copy_from_slice(&out[..w]);
    }
    for x in 0..w {
        for y in 0..h {
            line[y] = g[y * w + x];
        }
        edt_line(&line[..h], &mut out[..h]);
        for y in 0..h {
            g[y * w + x] = out[y];
        }
    }
    Some(g.into_iter().map(|v| v.min(FAR).sqrt() as f32).collect())
}

/// A `w × h` `mask` grown (d > 0) or shrunk (d < 0) by |d| pixels (Euclidean distance,
/// [`distance_to`]); an empty mask, or a full one shrunk, is returned as it is.
pub fn grow(mask: &[bool], w: usize, h: usize, d: f32) -> Vec<bool> {
    if d > 0.0 {
        match distance_to(mask, w, h) {
            Some(dist) => dist.iter().map(|&x| x <= d).collect(),
            None => mask.to_vec(),
        }
    } else if d < 0.0 {
        let outside: Vec<bool> = mask.iter().map(|&m| !m).collect();
        match distance_to(&outside, w, h) {
            Some(dist) => dist.iter().map(|&x| x > -d).collect(),
            None => mask.to_vec(),
        }
    } else {
        mask.to_vec()
    }
}

/// Alpha above which a pixel gets a label.
pub const ALPHA_THRESHOLD: f32 = 0.5;

/// One view rendered with its label channels.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LabelRender {
    pub width: usize,
    pub height: usize,
    /// `H × W × 3` colour, including the background.
    pub rgb: Vec<f32>,
    /// `H × W` alpha.
    pub alpha: Vec<f32>,
    /// `H × W × num_labels`: blend weight of each label (sums to alpha).
    pub weights: Vec<f32>,
    pub num_labels: usize,
    /// `H × W` label per pixel (argmax of `weights` where alpha > 0.5, else 0).
    pub labels: Vec<u32>,
}

impl LabelRender {
    /// Binary mask of `label`.
    pub fn mask(&self, label: u32) -> Vec<bool> {
        self.labels.iter().map(|&l| l == label).collect()
    }

    /// Binary mask of a set of labels: pixels whose label is one of `labels`.
    pub fn mask_of(&self, labels: &[u32]) -> Vec<bool> {
        self.labels.iter().map(|l| labels.contains(l)).collect()
    }

    /// Blend weight of a set of labels per pixel: w = min(1, Σ_{l ∈ labels} w_l), each
    /// label counted once (0 where none of them contributes).
    pub fn weight_of(&self, labels: &[u32]) -> Vec<f32> {
        let mut out = vec![0.0f32; self.width * self.height];
        let mut seen: Vec<u32> = Vec::with_capacity(labels.len());
        for &l in labels {
            if seen.contains(&l) || l as usize >= self.num_labels {
                continue;
            }
            seen.push(l);
            for (o, w) in out.iter_mut().zip(self.weights.chunks_exact(self.num_labels)) {
                *o += w[l as usize];
            }
        }
        for o in out.iter_mut() {
            *o = o.min(1.0);
        }
        out
    }

    /// A view whose labels come from a label image sampled `factor` times finer than
    /// `rgb` in each direction (a supersampled segmentation, as a mesh renderer writes it):
    /// a label's weight in a pixel is the share of the pixel's `factor²` samples that show
    /// it (its coverage, as a blend weight is for a render), the alpha is 1, and the
    /// pixel's label the one with the most samples (the lowest on a tie). `samples` are
    /// row-major at `factor·width × factor·height`; labels ≥ `num_labels` count for none.
    pub fn from_samples(
        rgb: Vec<f32>,
        width: usize,
        height: usize,
        samples: &[u32],
        factor: usize,
        num_labels: usize,
    ) -> Self {
        assert_eq!(rgb.len(), width * height * 3, "rgb is H × W × 3");
        assert_eq!(samples.len(), width * height * factor * factor, "samples are factor² per pixel");
        let share = 1.0 / (factor * factor) as f32;
        let mut weights = vec![0.0f32; width * height * num_labels];
        for (sy, row) in samples.chunks_exact(width * factor).enumerate() {
            for (sx, &l) in row.iter().enumerate() {
                if (l as usize) < num_labels {
                    let pixel = (sy / factor) * width + sx / factor;
                    weights[pixel * num_labels + l as usize] += share;
                }
            }
        }
        let labels = weights
            .chunks_exact(num_labels.max(1))
            .map(|w| {
                w.iter().enumerate().fold((0, 0.0), |best, (l, &v)| if v > best.1 { (l, v) } else { best }).0
                    as u32
            })
            .collect();
        LabelRender { width, height, rgb, alpha: vec![1.0; width * height], weights, num_labels, labels }
    }

    /// Number of pixels labelled `label`.
    pub fn area(&self, label: u32) -> usize {
        self.labels.iter().filter(|&&l| l == label).count()
    }

    /// Raw blend weight of `label` per pixel (0 where its Gaussians contribute nothing).
    pub fn weight(&self, label: u32) -> Vec<f32> {
        let l = label as usize;
        if l >= self.num_labels {
            return vec![0.0; self.width * self.height];
        }
        self.weights.chunks_exact(self.num_labels).map(|w| w[l]).collect()
    }

    /// Soft mask of `label`: its share of the pixel's opacity (weight / alpha).
    pub fn soft(&self, label: u32) -> Vec<f32> {
        self.weight(label)
            .iter()
            .zip(&self.alpha)
            .map(|(&w, &a)| if a > 1e-6 { (w / a).min(1.0) } else { 0.0 })
            .collect()
    }
}

/// One-hot encoding of `labels` with `num_labels` channels (labels ≥ `num_labels`
/// get no channel).
pub fn one_hot(labels: &[u32], num_labels: usize) -> Vec<f32> {
    let mut f = vec![0.0f32; labels.len() * num_labels];
    for (i, &l) in labels.iter().enumerate() {
        if (l as usize) < num_labels {
            f[i * num_labels + l as usize] = 1.0;
        }
    }
    f
}

/// Renders `g` from `cam` with the label channels. `labels.len()` must equal `g.len()`
/// (checked: a mismatch renders no label channel rather than panicking).
pub fn render_labels(
    g: &Gaussians,
    labels: &[u32],
    num_labels: usize,
    cam: &Camera,
    background: [f32; 3],
) -> LabelRender {
    let num_labels = if labels.len() == g.len() { num_labels.max(1) } else { 1 };
    let feats = if labels.len() == g.len() { one_hot(labels, num_labels) } else { vec![0.0; g.len()] };
    let splats = Splats::new(g).with_features(&feats, num_labels);
    let (img, _) = render(&splats, cam, &RenderOptions { background });
    let labels_px = img
        .features
        .chunks_exact(num_labels)
        .zip(&img.alpha)
        .map(|(w, &a)| {
            if a <= ALPHA_THRESHOLD {
                return 0;
            }
            let mut best = 0;
            for (k, &v) in w.iter().enumerate() {
                if v > w[best] {
                    best = k;
                }
            }
            best as u32
        })
        .collect();
    LabelRender {
        width: img.width,
        height: img.height,
        rgb: img.rgb,
        alpha: img.alpha,
        weights: img.features,
        num_labels,
        labels: labels_px,
    }
}

impl Scene {
    /// Renders view `index` of the scene with its label channels.
    pub fn render_view(&self, index: usize) -> Option<LabelRender> {
        let cam = self.cameras.get(index)?;
        Some(render_labels(&self.gaussians, &self.labels, self.num_labels(), cam, self.background))
    }

    /// Renders other Gaussians (e.g. an edited copy) with this scene's labels and camera.
    pub fn render_edited(&self, g: &Gaussians, index: usize) -> Option<LabelRender> {
        let cam = self.cameras.get(index)?;
        Some(render_labels(g, &self.labels, self.num_labels(), cam, self.background))
    }

    /// Ground-truth label mask of every view.
    pub fn masks(&self) -> Vec<Vec<u32>> {
        (0..self.cameras.len()).filter_map(|i| self.render_view(i)).map(|r| r.labels).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::LabelRender;

    #[test]
    fn weight_and_mask_of_a_label_set_by_hand() {
        // two pixels, three labels: weights (0.1, 0.5, 0.3) and (0.0, 0.7, 0.6)
        let r = LabelRender {
            width: 2,
            height: 1,
            rgb: vec![0.0; 6],
            alpha: vec![0.9, 1.0],
            weights: vec![0.1, 0.5, 0.3, 0.0, 0.7, 0.6],
            num_labels: 3,
            labels: vec![1, 1],
        };
        let w = r.weight_of(&[1, 2]);
        assert!((w[0] - 0.8).abs() < 1e-6 && w[1] == 1.0, "{w:?}"); // 0.7 + 0.6 clamped
        assert_eq!(r.weight_of(&[2, 2, 7]), vec![0.3, 0.6], "repeats and unknown labels count nothing");
        assert_eq!(r.weight_of(&[]), vec![0.0, 0.0]);
        assert_eq!(r.weight_of(&[1]), r.weight(1));
        assert_eq!(r.mask_of(&[0, 1]), vec![true, true]);
        assert_eq!(r.mask_of(&[2]), vec![false, false]);
    }

    #[test]
    fn coverage_from_supersampled_labels_by_hand() {
        // a 2 × 1 image sampled 2 × 2 per pixel: pixel 0 sees labels (0, 1, 1, 1), pixel 1
        // sees (2, 2, 1, 9): 9 is no label of the three
        let samples = [0, 1, 2, 2, 1, 1, 1, 9];
        let r = LabelRender::from_samples(vec![0.5; 6], 2, 1, &samples, 2, 3);
        assert_eq!(r.weight(0), vec![0.25, 0.0]);
        assert_eq!(r.weight(1), vec![0.75, 0.25]);
        assert_eq!(r.weight(2), vec![0.0, 0.5]);
        assert_eq!(r.labels, vec![1, 2]);
        assert_eq!(r.alpha, vec![1.0, 1.0]);
        // a tie goes to the lowest label
        let r = LabelRender::from_samples(vec![0.5; 3], 1, 1, &[2, 1, 1, 2], 2, 3);
        assert_eq!(r.labels, vec![1]);
    }
}

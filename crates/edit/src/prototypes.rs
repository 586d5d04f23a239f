//! Prompt-aware prototype extraction (paper Sec. 3.2 and appendix A.1).
//!
//! Ā = A / (max(max A, P) + ε_a), with P = 0 (each view by its own peak, as in the paper)
//! unless the view's peak is under δ_a times the job's typical attention peak
//! ([`typical_peak`]), where P is that typical peak and the view has no support; opted
//! into, P is the typical peak for every view ([`Normalise`]). Ā is closed
//! (grey-level morphology, [`grey_closing`]) over a square of radius `close_radius` × the
//! image diagonal; support Ω = {Ā ≥ δ_a} ∩ mask with connected components below a minimum
//! area dropped; weighted k-means on pixel coordinates (k-means++ seeding, then Lloyd)
//! with weights Ā partitions Ω into M regions; each region gives a
//! prototype (u_m, e_m, ψ_m, b_m).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Settings of prototype extraction.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PrototypeConfig {
    /// Number of prototypes per view (M).
    pub count: usize,
    /// Support threshold δ_a on the normalised attention.
    pub threshold: f32,
    /// Connected components smaller than this fraction of the image are dropped.
    pub min_area_fraction: f32,
    /// Radius of the grey-level closing of Ā, as a fraction of the image diagonal
    /// (0: none, as in the paper; docs/method.md#m2-prototypes).
    pub close_radius: f32,
    /// Lloyd iterations after k-means++ seeding.
    pub lloyd_iters: usize,
    /// How a target mask (the editor's or a segmenter's) restricts the support: the
    /// weight of Ā outside the mask. 0 is the paper's hard intersection Ω = {Ā ≥ δ_a} ∩ M;
    /// above 0 the mask is a prior on Ā (docs/method.md#e7-the-segmentation-constraint),
    /// and 1 ignores it.
    pub outside_mask: f32,
    /// What Ā is normalised by ([`Normalise`]).
    pub normalise: Normalise,
}

/// What a view's attention is normalised by (docs/method.md#m2-prototypes).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Normalise {
    /// The view's own peak (the paper): every view's attention reaches 1 somewhere.
    View,
    /// The view's own peak, unless it is under δ_a times the job's typical peak
    /// ([`typical_peak`]); then the typical peak, under which its attention reaches δ_a
    /// nowhere and the view has no support (the default): a view whose attention stays
    /// far below every other view's did not edit anything the others did.
    #[default]
    Floor,
    /// The larger of the view's own peak and the job's typical peak: a view whose
    /// attention stays below the other views' does not see it as full evidence, and one
    /// under δ_a of the typical peak is under the floor as with [`Normalise::Floor`]. Opt-in: it
    /// also weakens the views that see a small target, whose blurred attention peaks lower
    /// (docs/results.md, "Settings measured and not made default").
    Job,
}

impl Normalise {
    /// The job's typical peak over the edited views' `attentions` ([`typical_peak`]) when
    /// this rule needs one, else 0.
    pub fn typical<'a>(self, attentions: impl IntoIterator<Item = &'a [f32]>) -> f32 {
        match self {
            Normalise::View => 0.0,
            Normalise::Floor | Normalise::Job => typical_peak(attentions),
        }
    }

    /// The peak P that a view's Ā divides by when it is larger than the view's own
    /// ([`ViewEvidence::peak`]; 0: the view's own), for a view whose attention peaks at
    /// `own`, given the job's `typical` peak ([`Normalise::typical`]) and the support
    /// threshold δ_a.
    pub fn peak(self, own: f32, typical: f32, threshold: f32) -> f32 {
        match self {
            Normalise::View => 0.0,
            Normalise::Floor if own < threshold * typical => typical,
            Normalise::Floor => 0.0,
            Normalise::Job => typical,
        }
    }
}

impl Default for PrototypeConfig {
    fn default() -> Self {
        PrototypeConfig {
            count: 32,
            threshold: 0.3,
            min_area_fraction: 2e-4,
            close_radius: 0.01,
            lloyd_iters: 10,
            outside_mask: 0.0,
            normalise: Normalise::Floor,
        }
    }
}

impl PrototypeConfig {
    /// The peak a view with `attention` is normalised against ([`ViewEvidence::peak`],
    /// [`Normalise::peak`]), given the job's `typical` peak ([`Normalise::typical`]).
    pub fn view_peak(&self, attention: &[f32], typical: f32) -> f32 {
        self.normalise.peak(attention_peak(attention), typical, self.threshold)
    }
}

/// A view's attention peak: its largest finite value (0 when it has none).
pub fn attention_peak(attention: &[f32]) -> f32 {
    attention.iter().fold(0.0f32, |m, &v| if v.is_finite() { m.max(v) } else { m })
}

/// Whether a view's attention stays under δ_a (`threshold`) on the scale it is
/// normalised by ([`ViewEvidence::peak`]), so that its support is empty for want of
/// attention: with [`Normalise::Floor`] or [`Normalise::Job`] a view whose peak is under
/// δ_a times the job's typical one (never with [`Normalise::View`]). Such a view edited
/// nothing the other views did; it supports none of the Gaussians it sees, and says so
/// (docs/method.md#m2-prototypes).
pub fn below_floor(ev: &ViewEvidence, threshold: f32) -> bool {
    attention_peak(ev.attention) < threshold * ev.peak
}

/// The job's typical attention peak (docs/method.md#m2-prototypes): the median of the
/// edited views' peaks ([`attention_peak`]; the upper one of an even count), 0 for no
/// view. By default ([`Normalise::Floor`]) a view whose own peak is under δ_a times this
/// has no support; with [`Normalise::Job`] every view's Ā divides by the larger of this
/// and its own peak.
///
/// *Why:* normalised by its own peak, every view's attention reaches 1 somewhere,
/// whatever the editor did there. A view the editor left unedited then turns its
/// attention's noise into full evidence, and a folder edit's change map, in a view where
/// the target's edit is missing, turns the texture a decoder blurred into it. The other
/// views say what an edit's attention peaks at; the median is not moved by one view that
/// peaks far above the rest. *Why a floor, not the typical peak for every view:* a
/// blurred attention peaks lower where the target is small, so with [`Normalise::Job`] the
/// views that see a small or far target lose support (docs/results.md, "Settings measured
/// and not made default"); such a view peaks within a factor of two of the others, an
/// unedited one at a tenth.
pub fn typical_peak<'a>(attentions: impl IntoIterator<Item = &'a [f32]>) -> f32 {
    let mut peaks: Vec<f32> = attentions.into_iter().map(attention_peak).collect();
    if peaks.is_empty() {
        return 0.0;
    }
    let k = peaks.len() / 2;
    *peaks.select_nth_unstable_by(k, f32::total_cmp).1
}

/// The prototypes of one view; `m = b.len()`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Prototypes {
    /// Attention-weighted centroids u_m in pixels (appendix eq. for u_m^v).
    pub u: Vec<[f32; 2]>,
    /// L2-normalised semantic descriptors e_m, `m × d` (eq. for e_m^v).
    pub e: Vec<f32>,
    pub d: usize,
    /// L2-normalised appearance descriptors ψ_m, `m × d_a` (eq. for ψ_m^v).
    pub psi: Vec<f32>,
    pub d_app: usize,
    /// Mass shares b_m, summing to 1 (eq. for b_m^v).
    pub b: Vec<f32>,
}

impl Prototypes {
    /// Number of prototypes.
    pub fn len(&self) -> usize {
        self.b.len()
    }
    /// True when the view carries no evidence.
    pub fn is_empty(&self) -> bool {
        self.b.is_empty()
    }
}

/// Per-view inputs to prototype extraction (row-major `H × W` planes).
#[derive(Clone, Copy, Debug)]
pub struct ViewEvidence<'a> {
    pub width: usize,
    pub height: usize,
    /// Text-relevant attention A_v, `H × W`, ≥ 0.
    pub attention: &'a [f32],
    /// Optional target mask in [0, 1], `H × W` (> 0.5 is inside).
    pub mask: Option<&'a [f32]>,
    /// Semantic features E_v, `H × W × d`.
    pub semantic: &'a [f32],
    pub d: usize,
    /// Appearance features Φ_v, `H × W × d_a`.
    pub appearance: &'a [f32],
    pub d_app: usize,
    /// The peak Ā divides by when it is larger than the view's own peak
    /// ([`Normalise::peak`]; 0: the view's own peak alone, as in the paper).
    pub peak: f32,
}

/// A view's support Ω and normalised attention Ā, computed once per view
/// ([`view_support`]) and read by the prototypes, the evidence plane and masklift.
#[derive(Clone, Debug, PartialEq)]
pub struct Support {
    /// Ω, `H × W`.
    pub omega: Vec<bool>,
    /// Ā (closed), `H × W`.
    pub abar: Vec<f32>,
}

/// The support Ω as a boolean plane: thresholded normalised attention inside the
/// mask, with connected components (4-neighbour) smaller than `min_area` removed.
/// Ā is closed over a square of radius `close` pixels first ([`grey_closing`]; 0:
/// not).
///
/// The mask: with `outside_mask` = 0 (the paper's M_sam constraint) a pixel outside it
/// is outside Ω. Above 0 the mask is a prior on Ā instead, Ā(p) ← Ā(p) · `outside_mask`
/// outside it (docs/method.md#e7-the-segmentation-constraint): the attention and the
/// mask are two detectors of the target, and a pixel only one of them marks keeps the
/// attention's evidence at that weight. Strong attention a mask missed (its boundary
/// drawn inside the object, a thin part dropped) stays in Ω at a reduced weight, while
/// an editor's weak spill outside the mask falls below δ_a.
pub fn support(
    ev: &ViewEvidence,
    threshold: f32,
    min_area: usize,
    close: usize,
    outside_mask: f32,
) -> Support {
    let (w, h) = (ev.width, ev.height);
    let max = attention_peak(ev.attention).max(ev.peak);
    let abar: Vec<f32> =
        ev.attention.iter().map(|&v| if v.is_finite() && v > 0.0 { v / (max + 1e-8) } else { 0.0 }).collect();
    let mut abar = if close > 0 { grey_closing(&abar, w, h, close) } else { abar };
    let hard = outside_mask <= 0.0;
    if let (Some(mask), false) = (ev.mask, hard) {
        for (a, &m) in abar.iter_mut().zip(mask) {
            if m <= 0.5 {
                *a *= outside_mask;
            }
        }
    }
    let mut omega: Vec<bool> = abar
        .iter()
        .enumerate()
        .map(|(p, &a)| a >= threshold && a > 0.0 && (!hard || ev.mask.is_none_or(|m| m[p] > 0.5)))
        .collect();
    // Connected components by flood fill; small ones are removed.
    let mut seen = vec![false; w * h];
    let mut stack = Vec::new();
    let mut comp = Vec::new();
    for start in 0..w * h {
        if !omega[start] || seen[start] {
            continue;
        }
        comp.clear();
        stack.push(start);
        seen[start] = true;
        while let Some(p) = stack.pop() {
            comp.push(p);
            let (x, y) = (p % w, p / w);
            let mut visit = |q: usize| {
                if omega[q] && !seen[q] {
                    seen[q] = true;
                    stack.push(q);
                }
            };
            if x > 0 {
                visit(p - 1);
            }
            if x + 1 < w {
                visit(p + 1);
            }
            if y > 0 {
                visit(p - w);
            }
            if y + 1 < h {
                visit(p + w);
            }
        }
        if comp.len() < min_area {
            for &p in &comp {
                omega[p] = false;
            }
        }
    }
    Support { omega, abar }
}

/// Grey-level closing of an `h × w` plane by a (2r+1)² square: a max filter then a min
/// filter, each separable (the window is clipped at the border).
///
/// *Why (docs/method.md#m2-prototypes):* a 2D editor's attention is noisy, and Ā is
/// normalised by its maximum, which one noisy peak sets: multiplicative noise then
/// drops a large share of the edited object below δ_a and leaves Ω full of holes (the
/// measurement is in docs/method.md M2). Closing fills dips narrower than the square and keeps edges and peaks: a convex
/// object's outline is unchanged, so it does not grow Ω into the background the way a
/// blur or a dilation would. The radius is a fraction of the diagonal, about one
/// latent cell of a Stable-Diffusion editor (1/64 of the side, 1.1 % of the diagonal),
/// the scale at which its attention is resolved.
pub fn grey_closing(a: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    if r == 0 {
        return a.to_vec();
    }
    let dilated = filter_2d(a, w, h, r, f32::max, f32::NEG_INFINITY);
    filter_2d(&dilated, w, h, r, f32::min, f32::INFINITY)
}

/// The running `op` (max or min, with `identity` its neutral value) over a
/// (2r+1)² square, clipped at the border: rows, then columns.
fn filter_2d(a: &[f32], w: usize, h: usize, r: usize, op: fn(f32, f32) -> f32, identity: f32) -> Vec<f32> {
    let mut rows = vec![0.0f32; w * h];
    for (src, dst) in a.chunks_exact(w).zip(rows.chunks_exact_mut(w)) {
        running(src, dst, r, op, identity);
    }
    let mut out = vec![0.0f32; w * h];
    let (mut col, mut res) = (vec![0.0f32; h], vec![0.0f32; h]);
    for x in 0..w {
        col.iter_mut().enumerate().for_each(|(y, c)| *c = rows[y * w + x]);
        running(&col, &mut res, r, op, identity);
        res.iter().enumerate().for_each(|(y, &v)| out[y * w + x] = v);
    }
    out
}

/// `dst[i] = op(src[i − r ..= i + r])` (clipped at both ends) in O(n) whatever r: the
/// van Herk / Gil-Werman scheme, prefix and suffix runs within blocks of 2r + 1, so a
/// window is one suffix run and one prefix run.
fn running(src: &[f32], dst: &mut [f32], r: usize, op: fn(f32, f32) -> f32, identity: f32) {
    let (n, k) = (src.len(), 2 * r + 1);
    // Padded by r identities on the left and up to a whole block on the right.
    let m = (n + 2 * r).div_ceil(k) * k;
    let at = |i: usize| if i >= r && i - r < n { src[i - r] } else { identity };
    let (mut pre, mut suf) = (vec![identity; m], vec![identity; m]);
    for i in 0..m {
        pre[i] = if i % k == 0 { at(i) } else { op(pre[i - 1], at(i)) };
    }
    for i in (0..m).rev() {
        suf[i] = if i % k == k - 1 { at(i) } else { op(suf[i + 1], at(i)) };
    }
    // The window of output i covers padded positions i ..= i + 2r.
    for (i, d) in dst.iter_mut().enumerate() {
        *d = op(suf[i], pre[i + 2 * r]);
    }
}

/// Weighted k-means of 2D points: k-means++ seeding then `iters` Lloyd steps.
/// Returns the cluster of each point (clusters may end up empty).
pub fn weighted_kmeans(pts: &[[f32; 2]], wts: &[f32], k: usize, iters: usize, seed: u64) -> Vec<usize> {
    let n = pts.len();
    if n == 0 || k == 0 {
        return vec![0; n];
    }
    let k = k.min(n);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let d2 = |a: [f32; 2], b: [f32; 2]| (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2);
    let total: f64 = wts.iter().map(|&w| w as f64).sum();
    // First centre: drawn proportionally to the weights.
    let pick = |rng: &mut ChaCha8Rng, score: &dyn Fn(usize) -> f64, sum: f64| -> usize {
        let mut r = rng.gen::<f64>() * sum;
        for i in 0..n {
            r -= score(i);
            if r <= 0.0 {
                return i;
            }
        }
        n - 1
    };
    let mut centres = vec![pts[pick(&mut rng, &|i| wts[i] as f64, total)]];
    let mut best: Vec<f32> = pts.iter().map(|&p| d2(p, centres[0])).collect();
    while centres.len() < k {
        let sum: f64 = (0..n).map(|i| wts[i] as f64 * best[i] as f64).sum();
        if sum <= 0.0 {
            break;
        }
        let c = pts[pick(&mut rng, &|i| wts[i] as f64 * best[i] as f64, sum)];
        centres.push(c);
        for (b, &p) in best.iter_mut().zip(pts) {
            *b = b.min(d2(p, c));
        }
    }
    let mut assign = vec![0usize; n];
    for it in 0..=iters {
        let mut changed = false;
        for (i, &p) in pts.iter().enumerate() {
            let (mut bi, mut bd) = (0, f32::INFINITY);
            for (c, &q) in centres.iter().enumerate() {
                let d = d2(p, q);
                if d < bd {
                    bd = d;
                    bi = c;
                }
            }
            changed |= assign[i] != bi;
            assign[i] = bi;
        }
        if it == iters || (!changed && it > 0) {
            break;
        }
        let mut acc = vec![[0.0f64; 3]; centres.len()];
        for (i, &p) in pts.iter().enumerate() {
            let a = &mut acc[assign[i]];
            a[0] += wts[i] as f64 * p[0] as f64;
            a[1] += wts[i] as f64 * p[1] as f64;
            a[2] += wts[i] as f64;
        }
        for (c, a) in centres.iter_mut().zip(&acc) {
            if a[2] > 0.0 {
                *c = [(a[0] / a[2]) as f32, (a[1] / a[2]) as f32];
            }
        }
    }
    assign
}

/// The support Ω and normalised attention Ā of a view with the configured threshold
/// δ_a and minimum component area (a fraction of the image, at least one pixel).
pub fn view_support(ev: &ViewEvidence, cfg: &PrototypeConfig) -> Support {
    let min_area = ((cfg.min_area_fraction * (ev.width * ev.height) as f32).ceil() as usize).max(1);
    let diag = ((ev.width * ev.width + ev.height * ev.height) as f32).sqrt();
    support(ev, cfg.threshold, min_area, (cfg.close_radius * diag).round() as usize, cfg.outside_mask)
}

/// The view's evidence per pixel, in [0, 1] (docs/method.md#m4-the-uot-solver): on the
/// support Ω, the normalised attention relative to its median over Ω,
/// min(1, Ā(p) / median_Ω Ā); 0 off Ω. Its splat-back is a Gaussian's coverage ω_i^v
/// (evidence-mass balancing and the coverage bound of the gate).
///
/// *Why not 1_Ω:* Ω is a threshold of the attention, so a pixel where the editor's
/// attention has faded to a third of its peak (the edge of a spill ring) counts as
/// much as the edited object. Relative to the typical attention of the support, the
/// object's pixels count fully and weaker evidence in proportion. The median, not the
/// maximum Ā is normalised by: one noisy peak does not lower every other pixel.
pub fn evidence_plane(sup: &Support) -> Vec<f32> {
    let Support { omega, abar } = sup;
    let mut inside: Vec<f32> = omega.iter().zip(abar).filter(|(&o, _)| o).map(|(_, &a)| a).collect();
    if inside.is_empty() {
        return vec![0.0; omega.len()];
    }
    let k = inside.len() / 2;
    let median = *inside.select_nth_unstable_by(k, f32::total_cmp).1;
    omega.iter().zip(abar).map(|(&o, &a)| if o { (a / median).min(1.0) } else { 0.0 }).collect()
}

/// Pixel-level prototypes for the `no_prototype` ablation: a seeded subsample of
/// `samples` support pixels (of `sup`, the view's [`view_support`]), each its own
/// prototype with mass ∝ Ā.
pub fn pixels(ev: &ViewEvidence, sup: &Support, samples: usize, seed: u64) -> Prototypes {
    use rand::seq::SliceRandom;
    let Support { omega, abar } = sup;
    let mut idx: Vec<usize> = (0..omega.len()).filter(|&i| omega[i]).collect();
    idx.shuffle(&mut ChaCha8Rng::seed_from_u64(seed));
    idx.truncate(samples);
    let (d, da) = (ev.d, ev.d_app);
    let mut out = Prototypes { d, d_app: da, ..Default::default() };
    let total: f32 = idx.iter().map(|&i| abar[i]).sum();
    for &i in &idx {
        out.u.push([(i % ev.width) as f32 + 0.5, (i / ev.width) as f32 + 0.5]);
        let mut e = ev.semantic[i * d..(i + 1) * d].to_vec();
        crate::normalize(&mut e, 1e-8);
        out.e.extend(e);
        let mut a = ev.appearance[i * da..(i + 1) * da].to_vec();
        crate::normalize(&mut a, 1e-8);
        out.psi.extend(a);
        out.b.push(abar[i] / total);
    }
    out
}

/// Extracts the prototypes of one view (appendix A.1) from its support `sup`
/// ([`view_support`]). An empty result means the view carries no editing evidence.
pub fn extract(ev: &ViewEvidence, sup: &Support, cfg: &PrototypeConfig, seed: u64) -> Prototypes {
    let (w, h, d, da) = (ev.width, ev.height, ev.d, ev.d_app);
    let Support { omega, abar } = sup;
    let idx: Vec<usize> = (0..w * h).filter(|&p| omega[p]).collect();
    if idx.is_empty() {
        return Prototypes { d, d_app: da, ..Default::default() };
    }
    let pts: Vec<[f32; 2]> = idx.iter().map(|&p| [(p % w) as f32 + 0.5, (p / w) as f32 + 0.5]).collect();
    let wts: Vec<f32> = idx.iter().map(|&p| abar[p]).collect();
    let assign = weighted_kmeans(&pts, &wts, cfg.count, cfg.lloyd_iters, seed);
    let k = assign.iter().max().map_or(0, |&m| m + 1);
    let mut kappa = vec![0.0f64; k];
    let mut u = vec![[0.0f64; 2]; k];
    let mut e = vec![0.0f64; k * d];
    let mut psi = vec![0.0f64; k * da];
    for (n, &p) in idx.iter().enumerate() {
        let (c, a) = (assign[n], wts[n] as f64);
        kappa[c] += a;
        u[c][0] += a * pts[n][0] as f64;
        u[c][1] += a * pts[n][1] as f64;
        for j in 0..d {
            e[c * d + j] += a * ev.semantic[p * d + j] as f64;
        }
        for j in 0..da {
            psi[c * da + j] += a * ev.appearance[p * da + j] as f64;
        }
    }
    let total: f64 = kappa.iter().sum();
    let mut out = Prototypes { d, d_app: da, ..Default::default() };
    for c in 0..k {
        if kappa[c] <= 0.0 {
            continue;
        }
        out.u.push([(u[c][0] / kappa[c]) as f32, (u[c][1] / kappa[c]) as f32]);
        let mut ec: Vec<f32> = (0..d).map(|j| (e[c * d + j] / kappa[c]) as f32).collect();
        crate::normalize(&mut ec, 1e-8);
        out.e.extend(ec);
        let mut pc: Vec<f32> = (0..da).map(|j| (psi[c * da + j] / kappa[c]) as f32).collect();
        crate::normalize(&mut pc, 1e-8);
        out.psi.extend(pc);
        out.b.push((kappa[c] / total) as f32);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn evidence<'a>(w: usize, h: usize, att: &'a [f32], sem: &'a [f32], app: &'a [f32]) -> ViewEvidence<'a> {
        ViewEvidence {
            width: w,
            height: h,
            attention: att,
            mask: None,
            semantic: sem,
            d: 2,
            appearance: app,
            d_app: 1,
            peak: 0.0,
        }
    }

    #[test]
    fn two_blobs_give_two_prototypes_with_hand_computed_statistics() {
        // 10x4 image: blob A = 2x2 pixels at x 1..3, y 1..3 with attention 1 and semantic
        // (1, 0); blob B = 2x2 pixels at x 7..9 with attention 0.5 and semantic (0, 2).
        let (w, h) = (10, 4);
        let mut att = vec![0.0f32; w * h];
        let mut sem = vec![0.0f32; w * h * 2];
        let app = vec![1.0f32; w * h];
        for y in 1..3 {
            for x in 1..3 {
                att[y * w + x] = 1.0;
                sem[(y * w + x) * 2] = 1.0;
            }
            for x in 7..9 {
                att[y * w + x] = 0.5;
                sem[(y * w + x) * 2 + 1] = 2.0;
            }
        }
        let cfg = PrototypeConfig {
            count: 2,
            threshold: 0.1,
            min_area_fraction: 0.0,
            close_radius: 0.0,
            lloyd_iters: 5,
            outside_mask: 0.0,
            normalise: Normalise::View,
        };
        let ev = evidence(w, h, &att, &sem, &app);
        let p = extract(&ev, &view_support(&ev, &cfg), &cfg, 3);
        assert_eq!(p.len(), 2);
        let (a, b) = if p.u[0][0] < p.u[1][0] { (0, 1) } else { (1, 0) };
        assert!((p.u[a][0] - 2.0).abs() < 1e-5 && (p.u[a][1] - 2.0).abs() < 1e-5, "{:?}", p.u);
        assert!((p.u[b][0] - 8.0).abs() < 1e-5 && (p.u[b][1] - 2.0).abs() < 1e-5);
        // Masses: Ā = 1 and 0.5 over 4 pixels each → 4/6 and 2/6.
        assert!((p.b[a] - 4.0 / 6.0).abs() < 1e-4 && (p.b[b] - 2.0 / 6.0).abs() < 1e-4, "{:?}", p.b);
        // Normalised semantic descriptors.
        assert!((p.e[a * 2] - 1.0).abs() < 1e-4 && p.e[a * 2 + 1].abs() < 1e-6);
        assert!((p.e[b * 2 + 1] - 1.0).abs() < 1e-4);
        assert!((p.psi[0] - 1.0).abs() < 1e-4);
    }

    #[test]
    fn small_components_and_masked_pixels_are_dropped() {
        let (w, h) = (8, 8);
        let mut att = vec![0.0f32; w * h];
        att[0] = 1.0; // an isolated pixel
        for y in 4..8 {
            for x in 4..8 {
                att[y * w + x] = 1.0;
            }
        }
        let sem = vec![1.0f32; w * h * 2];
        let app = vec![1.0f32; w * h];
        let ev = evidence(w, h, &att, &sem, &app);
        let omega = support(&ev, 0.5, 2, 0, 0.0).omega;
        assert!(!omega[0], "isolated pixel kept");
        assert_eq!(omega.iter().filter(|&&o| o).count(), 16);
        let mut mask = vec![0.0f32; w * h];
        mask[4 * w + 4] = 1.0;
        mask[4 * w + 5] = 1.0;
        let ev = ViewEvidence { mask: Some(&mask), ..ev };
        let omega = support(&ev, 0.5, 1, 0, 0.0).omega;
        assert_eq!(omega.iter().filter(|&&o| o).count(), 2);
    }

    #[test]
    fn a_soft_mask_keeps_strong_attention_outside_it_and_drops_weak_spill() {
        // One row: the object (Ā = 1) at x = 0..4, of which the mask covers x = 0..2;
        // the editor's spill (Ā = 0.4) at x = 4..6; nothing beyond.
        let w = 8;
        let att = [1.0, 1.0, 1.0, 1.0, 0.4, 0.4, 0.0, 0.0];
        let mask = [1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let (sem, app) = (vec![1.0f32; w * 2], vec![1.0f32; w]);
        let ev = ViewEvidence { mask: Some(&mask), ..evidence(w, 1, &att, &sem, &app) };
        // Hard (the paper): only the masked object pixels.
        let hard = support(&ev, 0.3, 1, 0, 0.0);
        assert_eq!(hard.omega, [true, true, false, false, false, false, false, false]);
        // Soft at 1/2: the object outside the mask stays at Ā = 0.5 ≥ 0.3, the spill
        // falls to 0.2 < 0.3.
        let soft = support(&ev, 0.3, 1, 0, 0.5);
        assert_eq!(soft.omega, [true, true, true, true, false, false, false, false]);
        assert_eq!(&soft.abar[..6], &[1.0, 1.0, 0.5, 0.5, 0.2, 0.2]);
        // Its evidence plane: relative to the median over Ω (the upper median of
        // 1, 1, 0.5, 0.5 is 1), the object outside the mask counts half.
        assert_eq!(&evidence_plane(&soft)[..5], &[1.0, 1.0, 0.5, 0.5, 0.0]);
        // Without a mask, or at weight 1, the mask changes nothing.
        let free = ViewEvidence { mask: None, ..ev };
        assert_eq!(support(&ev, 0.3, 1, 0, 1.0), support(&free, 0.3, 1, 0, 0.5));
    }

    /// Attention (0, 0.25, 0.5, 1.0, 0.8, 0.1) over a 6 × 1 image: Ā = A / max, Ω = Ā ≥ 0.3
    /// = pixels 2, 3, 4; the median of Ā over Ω is 0.8, so the plane is
    /// (0, 0, 0.5/0.8, 1, 1, 0). No attention at all gives an all-zero plane.
    #[test]
    fn evidence_plane_by_hand() {
        let att = [0.0f32, 0.25, 0.5, 1.0, 0.8, 0.1];
        let (sem, app) = (vec![0.0f32; 12], vec![0.0f32; 6]);
        let cfg = PrototypeConfig { threshold: 0.3, min_area_fraction: 0.0, ..Default::default() };
        let plane = evidence_plane(&view_support(&evidence(6, 1, &att, &sem, &app), &cfg));
        let want = [0.0, 0.0, 0.5 / 0.8, 1.0, 1.0, 0.0];
        for (a, b) in plane.iter().zip(want) {
            assert!((a - b).abs() < 1e-6, "{plane:?}");
        }
        let z = [0.0f32; 6];
        assert_eq!(evidence_plane(&view_support(&evidence(6, 1, &z, &sem, &app), &cfg)), vec![0.0; 6]);
    }

    /// The typical peak is the median of the views' peaks (the upper one of an even
    /// count; a NaN or an infinity is no peak: counted, ∞ would make it 3); `View` asks
    /// for none. A view that peaks at 0.2 against a typical 1.0 keeps Ā = A (all under
    /// δ_a = 0.3: no support), where its own peak would make 0.2 → 1; a view that peaks
    /// above the typical peak is normalised by its own, as without it. The floor
    /// (δ_a = 0.3) divides a view by the typical peak only under 0.3 of it: 0.2 → 1.0
    /// (no support), 0.5 → 0 (its own peak).
    #[test]
    fn a_view_is_normalised_by_the_larger_of_its_peak_and_the_typical_one() {
        let views: [&[f32]; 4] = [&[0.2, f32::NAN, f32::INFINITY], &[3.0, 0.1], &[0.9], &[1.0, 0.5]];
        assert_eq!(typical_peak(views), 1.0);
        let typical = |n: Normalise| n.typical(views);
        assert_eq!(
            (typical(Normalise::Job), typical(Normalise::Floor), typical(Normalise::View)),
            (1.0, 1.0, 0.0)
        );
        let peaks = |n: Normalise| [0.2, 0.29, 0.3, 0.5, 3.0].map(|own| n.peak(own, 1.0, 0.3));
        assert_eq!(peaks(Normalise::Floor), [1.0, 1.0, 0.0, 0.0, 0.0]);
        assert_eq!(peaks(Normalise::Job), [1.0; 5]);
        assert_eq!(peaks(Normalise::View), [0.0; 5]);
        assert_eq!(Normalise::Floor.peak(0.0, 0.0, 0.3), 0.0, "no typical peak: no floor");
        let floor = PrototypeConfig { threshold: 0.3, ..Default::default() };
        assert_eq!((floor.view_peak(&[0.1, 0.2], 1.0), floor.view_peak(&[0.5, f32::NAN], 1.0)), (1.0, 0.0));
        assert_eq!(typical_peak([&[0.2f32][..], &[0.6]]), 0.6);
        assert_eq!(typical_peak(std::iter::empty::<&[f32]>()), 0.0);
        let (sem, app) = (vec![0.0f32; 8], vec![0.0f32; 4]);
        let cfg = PrototypeConfig { threshold: 0.3, min_area_fraction: 0.0, ..Default::default() };
        let weak = [0.0f32, 0.1, 0.2, 0.05];
        let own = view_support(&evidence(4, 1, &weak, &sem, &app), &cfg);
        assert_eq!(own.omega, vec![false, true, true, false]);
        let under = ViewEvidence { peak: 1.0, ..evidence(4, 1, &weak, &sem, &app) };
        let typical = view_support(&under, &cfg);
        assert_eq!(typical.omega, vec![false; 4]);
        assert!(below_floor(&under, 0.3) && !below_floor(&evidence(4, 1, &weak, &sem, &app), 0.3));
        for (a, b) in typical.abar.iter().zip(weak) {
            assert!((a - b).abs() < 1e-6, "{:?}", typical.abar);
        }
        let strong = [0.0f32, 1.0, 2.0, 0.5];
        let over = ViewEvidence { peak: 1.0, ..evidence(4, 1, &strong, &sem, &app) };
        assert_eq!(view_support(&over, &cfg), view_support(&evidence(4, 1, &strong, &sem, &app), &cfg));
        assert!(!below_floor(&over, 0.3));
    }

    /// Closing by radius 1 on a 5 × 3 plane: a one-pixel dip inside a plateau is
    /// filled to the plateau's level (its 3 × 3 max is 1, the min of those maxima 1);
    /// the plateau's edge and the zero background stay, so the outline does not grow.
    #[test]
    fn closing_fills_a_dip_and_keeps_the_edge() {
        #[rustfmt::skip]
        let a = [
            1.0, 1.0, 1.0, 0.0, 0.0,
            1.0, 0.2, 1.0, 0.0, 0.0,
            1.0, 1.0, 1.0, 0.0, 0.0f32,
        ];
        let c = grey_closing(&a, 5, 3, 1);
        #[rustfmt::skip]
        let want = [
            1.0, 1.0, 1.0, 0.0, 0.0,
            1.0, 1.0, 1.0, 0.0, 0.0,
            1.0, 1.0, 1.0, 0.0, 0.0f32,
        ];
        assert_eq!(c, want);
        // Radius 0 is the identity; closing never lowers a value (it is extensive).
        assert_eq!(grey_closing(&a, 5, 3, 0), a);
        let noisy: Vec<f32> = (0..15).map(|i| ((i * 7) % 5) as f32 / 4.0).collect();
        assert!(grey_closing(&noisy, 5, 3, 1).iter().zip(&noisy).all(|(c, a)| c >= a));
    }

    /// The O(n) closing against its definition, max then min over the clipped
    /// (2r+1)² window pixel by pixel, on random planes of several shapes and radii
    /// (windows wider than the plane included).
    #[test]
    fn closing_equals_the_windowed_max_then_min() {
        let naive = |a: &[f32], w: usize, h: usize, r: usize, max: bool| -> Vec<f32> {
            (0..w * h)
                .map(|p| {
                    let (x, y) = (p % w, p / w);
                    let (xs, ys) =
                        (x.saturating_sub(r)..=(x + r).min(w - 1), y.saturating_sub(r)..=(y + r).min(h - 1));
                    let vals = ys.flat_map(|yy| xs.clone().map(move |xx| a[yy * w + xx]));
                    if max {
                        vals.fold(f32::NEG_INFINITY, f32::max)
                    } else {
                        vals.fold(f32::INFINITY, f32::min)
                    }
                })
                .collect()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for &(w, h) in &[(1, 1), (7, 1), (1, 9), (13, 11), (40, 23)] {
            let a: Vec<f32> = (0..w * h).map(|_| rng.gen_range(0.0f32..1.0)).collect();
            for r in [1, 2, 3, 5, 30] {
                let want = naive(&naive(&a, w, h, r, true), w, h, r, false);
                assert_eq!(grey_closing(&a, w, h, r), want, "{w}x{h}, r = {r}");
            }
        }
    }

    /// The support of a plateau with noisy dips below δ_a away from its edge: without
    /// closing the dips are holes in Ω, with it Ω is the whole plateau and nothing
    /// outside it. (A dip on the edge stays: closing fills what is surrounded.)
    #[test]
    fn closing_removes_holes_from_the_support() {
        let (w, h) = (12, 12);
        let att: Vec<f32> = (0..w * h)
            .map(|p| {
                let (x, y) = (p % w, p / w);
                let inside = (2..10).contains(&x) && (2..10).contains(&y);
                let interior = (3..9).contains(&x) && (3..9).contains(&y);
                match (inside, interior && (x + 2 * y) % 3 == 0) {
                    (true, true) => 0.1,
                    (true, false) => 1.0,
                    _ => 0.0,
                }
            })
            .collect();
        let (sem, app) = (vec![0.0f32; 2 * w * h], vec![0.0f32; w * h]);
        let ev = evidence(w, h, &att, &sem, &app);
        let plateau = |p: usize| (2..10).contains(&(p % w)) && (2..10).contains(&(p / w));
        let open = support(&ev, 0.3, 1, 0, 0.0).omega;
        assert!((0..w * h).any(|p| plateau(p) && !open[p]), "the test needs holes");
        let closed = support(&ev, 0.3, 1, 1, 0.0).omega;
        assert!((0..w * h).all(|p| closed[p] == plateau(p)));
    }

    #[test]
    fn no_attention_means_no_evidence() {
        let z = vec![0.0f32; 16];
        let sem = vec![0.0f32; 32];
        let ev = evidence(4, 4, &z, &sem, &z);
        let cfg = PrototypeConfig::default();
        let p = extract(&ev, &view_support(&ev, &cfg), &cfg, 0);
        assert!(p.is_empty());
    }

    #[test]
    fn kmeans_separates_well_separated_clusters() {
        let mut pts = Vec::new();
        for i in 0..50 {
            let t = i as f32 * 0.1;
            pts.push([t.sin(), t.cos()]);
            pts.push([100.0 + t.cos(), 50.0 + t.sin()]);
            pts.push([-80.0 + t.sin(), 90.0]);
        }
        let w = vec![1.0; pts.len()];
        let a = weighted_kmeans(&pts, &w, 3, 10, 1);
        for c in 0..3 {
            let first = a[c];
            assert!((0..50).all(|i| a[i * 3 + c] == first));
        }
        assert!(a[0] != a[1] && a[1] != a[2] && a[0] != a[2]);
    }
}

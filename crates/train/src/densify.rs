//! Adaptive density control as in INRIA 3DGS (`GaussianModel.densify_and_prune`,
//! `train.py`): statistics, clone, split, prune, opacity reset.
//!
//! **Gradient units.** INRIA thresholds the mean norm of the gradient with respect
//! to the projected mean in normalised device coordinates (NDC, −1..1 across the
//! image): its rasterizer multiplies the pixel-space gradient by
//! `∂pixel/∂ndc = W/2` (x) and `H/2` (y) (`ddelx_dx = 0.5 * W` in
//! `backward.cu`), because `pixel = ((ndc + 1) W − 1) / 2`. Our rasterizer's
//! `Grads::means2d` is ∂L/∂pixel, so [`DensifyStats::record`] accumulates
//! `‖(gx · W/2, gy · H/2)‖` per view in which the Gaussian is visible (radius > 0)
//! and the threshold 2e-4 means what it means in INRIA (gsplat's default strategy
//! does the same conversion). The loss must be a mean over pixels, as INRIA's is.
//!
//! **Clone / split.** A Gaussian whose mean accumulated gradient reaches the
//! threshold is cloned (an identical copy is appended) when its largest scale is
//! ≤ `percent_dense · extent`, and split otherwise: it is replaced by two Gaussians
//! whose means are drawn from 𝒩(μ, R diag(s²) Rᵀ) and whose scales are s / 1.6,
//! other parameters copied.
//!
//! **Prune.** After clone/split: opacity < `min_opacity`; after the first opacity
//! reset also (as INRIA) world scale above `max_world_scale · reach` and screen
//! radius above `max_screen_radius` px. INRIA's reach is the extent; ours is
//! max(extent, distance from the cameras' centre) when the centre is known
//! ([`Bounds`]): content beyond the camera ring (a far floor, a sky) is seen with a
//! pixel footprint that grows with its distance, so it is legitimately large, and
//! INRIA's fixed bound removes it at every densification after the first reset, and
//! the sky then shows the background colour (the training views can paint it back
//! only with nearer Gaussians, a likely source of floaters; not measured). On the open
//! tabletop (`train_open` test, four seeds) the distance-scaled bound gains 4.7 dB of
//! test PSNR on average (docs/results.md, "Training on open captures"). INRIA's code
//! zeroes `max_radii2D` just before this
//! test, which disables the screen-size rule in practice, and gsplat's default strategy
//! leaves it off; so does our default. [`DensifyConfig::max_screen_radius`] applies it
//! as the paper describes, using the largest radius (max of our per-axis radii) seen
//! since the last densification (new Gaussians have no radius recorded yet). On a
//! 48-view 256² open capture, 7000 steps, the 20 px rule removed the far floor and sky
//! at every densification after a reset and the holes set off bursts of splits: 31.20
//! dB and 315,850 Gaussians with it, 39.30 dB and 200,619 without (docs/results.md, "Against
//! reference trainers"). [`DensifyCounts::pruned_by`] says which rule pruned how many.
//!
//! **Camera reach.** Before the first opacity reset nothing bounds a Gaussian's size
//! (INRIA's size rules wait for it), and on an open capture the far floor and the sky,
//! where SfM gives no points, are covered by Gaussians that grow to tens of metres. From
//! the training cameras such a Gaussian is harmless: it sits in the sky, or behind the
//! camera and culled. But a camera whose image plane passes near its mean, a held-out
//! view say, projects it with the affine (EWA) approximation at a depth of a fraction
//! of a metre: the 2D covariance grows as 1/depth² and the splat covers the whole frame
//! as a veil, though the ellipsoid itself lies far from the camera. The projected
//! centre then lies about d/σ of its projected σ from the image, d being the mean's
//! distance from the camera, so whether the veil shows is set by d/σ: the rasterizer
//! draws a splat to 3.33 σ (below that, α < 1/255 even at opacity 1). So at every
//! densification, from the first, a Gaussian whose sphere of [`DensifyConfig::camera_reach`]
//! times its largest scale (default 3.33) reaches a training camera is pruned
//! ([`PruneRule::CameraReach`]): no camera near the training ones can then see it as a
//! veil. Gaussians of ordinary size (centimetres at metres from the cameras) are far
//! inside the bound; a sparse far point cloud (metres apart at tens of metres) stays
//! inside it too, where a bound of 0.1 × the distance applied from the start pruned it
//! and lost the far floor (the small open-capture test, 25.9 → 23.6 dB). Measured in
//! docs/method.md T2.
//!
//! **Budget.** [`DensifyConfig::max_gaussians`] caps the count, for a fixed memory or
//! for comparing trainers at equal size (gsplat's MCMC strategy has such a cap, Taming
//! 3DGS a scheduled one). When the candidates would grow the model past the cap, they
//! are taken largest mean gradient first while they fit (a split costs `split_count − 1`
//! rows, a clone one); the others wait for the next densification, and
//! prunes make room again. INRIA has no cap: without one every candidate densifies.
//! A tight cap is spent early on texture and can leave parts of the sky uncovered;
//! the comparison at equal size is in docs/results.md, "Against reference trainers".
//!
//! Every function takes an optional per-Gaussian mask: only Gaussians with
//! `mask[i] == true` may be cloned, split, pruned or reset (their new copies inherit
//! the permission).

use crate::model::Reindex;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use transsplat_scene::{sigmoid, Gaussians};

/// The densification schedule and thresholds (INRIA defaults).
#[derive(Clone, Debug, PartialEq)]
pub struct DensifyConfig {
    /// Densify at steps `> from_step` (INRIA `densify_from_iter`)...
    pub from_step: u64,
    /// ... and `< until_step` (`densify_until_iter`); statistics are recorded until then.
    pub until_step: u64,
    /// ... every `interval` steps (`densification_interval`).
    pub interval: u64,
    /// Mean NDC-space positional gradient norm that triggers clone/split.
    pub grad_threshold: f32,
    /// Clone when the largest scale is ≤ this × extent, split otherwise.
    pub percent_dense: f32,
    /// Number of Gaussians a split one becomes.
    pub split_count: usize,
    /// Prune opacity below this.
    pub min_opacity: f32,
    /// Reset opacities every this many steps (0 = never), while densifying.
    pub opacity_reset_interval: u64,
    /// Opacity after a reset is min(current, this).
    pub opacity_reset_value: f32,
    /// Prune screen radius above this many pixels (after the first reset); `None` = never.
    /// The paper states 20 px; the default is `None`, as INRIA's code and gsplat behave,
    /// because on a real-size capture the rule cost 8 dB (module doc). It still helps
    /// short low-resolution runs (`train_open`: 26.0 against 24.9 dB over seeds 4–8 at
    /// 96×72), which ask for it.
    pub max_screen_radius: Option<f32>,
    /// Prune largest world scale above this × extent (after the first reset).
    pub max_world_scale: f32,
    /// Prune, at every densification, a Gaussian whose sphere of this many times its
    /// largest scale contains a training camera (module doc, **Camera reach**); `None`
    /// = never, as INRIA. Needs the cameras ([`Bounds::cameras`]).
    pub camera_reach: Option<f32>,
    /// Raise the active SH degree every this many steps (0 = start at the maximum).
    pub sh_degree_interval: u64,
    /// Never grow past this many Gaussians (module doc, **Budget**); `None` = no cap, as INRIA.
    pub max_gaussians: Option<usize>,
}

impl Default for DensifyConfig {
    fn default() -> Self {
        DensifyConfig {
            from_step: 500,
            until_step: 15_000,
            interval: 100,
            grad_threshold: 2e-4,
            percent_dense: 0.01,
            split_count: 2,
            min_opacity: 0.005,
            opacity_reset_interval: 3000,
            opacity_reset_value: 0.01,
            max_screen_radius: None,
            max_world_scale: 0.1,
            camera_reach: Some(CAMERA_REACH_SIGMAS),
            sh_degree_interval: 1000,
            max_gaussians: None,
        }
    }
}

/// The default [`DensifyConfig::camera_reach`]: the rasterizer's support (a splat is
/// drawn to 3.33 σ; `raster::project`).
pub const CAMERA_REACH_SIGMAS: f32 = 3.33;

/// Steps a run needs after an opacity reset to recover (see
/// [`DensifyConfig::resets_opacity`]).
pub const RESET_RECOVERY_STEPS: u64 = 500;

impl DensifyConfig {
    /// No densification, pruning or opacity reset at all.
    pub fn disabled() -> Self {
        DensifyConfig { from_step: u64::MAX, until_step: 0, opacity_reset_interval: 0, ..Default::default() }
    }

    /// Whether statistics are recorded after `step` (1-based).
    pub fn records(&self, step: u64) -> bool {
        step < self.until_step
    }

    /// Whether to densify and prune after `step`.
    pub fn densifies(&self, step: u64) -> bool {
        step < self.until_step
            && step > self.from_step
            && self.interval > 0
            && step.is_multiple_of(self.interval)
    }

    /// Whether to reset opacities after `step` of a run of `iterations` steps: every
    /// `opacity_reset_interval` steps while densifying, but never within the last
    /// [`RESET_RECOVERY_STEPS`] of the run. A reset sets every opacity to at most 0.01
    /// and needs a few hundred steps to recover; INRIA's 30k schedule always leaves
    /// that time (its last reset is at 12000), but a run of 3000 steps would otherwise
    /// reset at its very last step and end with every Gaussian nearly transparent.
    pub fn resets_opacity(&self, step: u64, iterations: u64) -> bool {
        step < self.until_step
            && self.opacity_reset_interval > 0
            && step.is_multiple_of(self.opacity_reset_interval)
            && step.saturating_add(RESET_RECOVERY_STEPS) <= iterations
    }

    /// Whether the size-based pruning applies at `step` (after the first reset).
    pub fn prunes_large(&self, step: u64) -> bool {
        self.opacity_reset_interval > 0 && step > self.opacity_reset_interval
    }
}

/// Per-Gaussian densification statistics since the last densification.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DensifyStats {
    /// Σ over views of ‖∂L/∂(NDC mean)‖.
    pub grad_accum: Vec<f32>,
    /// Number of views in which the Gaussian was visible.
    pub denom: Vec<u32>,
    /// Largest screen radius (pixels) seen.
    pub max_radii: Vec<f32>,
}

impl DensifyStats {
    /// Zero statistics for `n` Gaussians.
    pub fn new(n: usize) -> Self {
        DensifyStats { grad_accum: vec![0.0; n], denom: vec![0; n], max_radii: vec![0.0; n] }
    }

    /// Applies `r`; fresh rows start at zero.
    pub fn reindex(&mut self, r: &Reindex) {
        // Exhaustive destructuring: a new field must be handled here.
        let DensifyStats { grad_accum, denom, max_radii } = self;
        *grad_accum = r.gather_fresh_zero(grad_accum, 1, 0.0);
        *denom = r.gather_fresh_zero(denom, 1, 0);
        *max_radii = r.gather_fresh_zero(max_radii, 1, 0.0);
    }

    /// Adds one view: `means2d_grad` is ∂L/∂(pixel mean) from the rasterizer's
    /// backward pass, `radii` the view's per-axis radii (0 = not visible).
    pub fn record(&mut self, means2d_grad: &[[f32; 2]], radii: &[[u32; 2]], width: u32, height: u32) {
        let (sx, sy) = (0.5 * width as f32, 0.5 * height as f32);
        assert!(
            means2d_grad.len() == self.denom.len() && radii.len() == self.denom.len(),
            "densification statistics do not match the view"
        );
        let DensifyStats { grad_accum, denom, max_radii } = self;
        (grad_accum, denom, max_radii, means2d_grad, radii).into_par_iter().with_min_len(1 << 14).for_each(
            |(acc, d, max_r, g, r)| {
                let rad = r[0].max(r[1]);
                if rad == 0 {
                    return;
                }
                let (gx, gy) = (g[0] * sx, g[1] * sy);
                *acc += (gx * gx + gy * gy).sqrt();
                *d += 1;
                *max_r = max_r.max(rad as f32);
            },
        );
    }

    /// Mean gradient norm per Gaussian (0 where never visible).
    pub fn mean_grad(&self) -> Vec<f32> {
        self.grad_accum
            .iter()
            .zip(&self.denom)
            .map(|(&a, &d)| if d > 0 { a / d as f32 } else { 0.0 })
            .collect()
    }

    /// Clears the statistics (INRIA resets them after every densification).
    pub fn clear(&mut self) {
        self.grad_accum.fill(0.0);
        self.denom.fill(0);
        self.max_radii.fill(0.0);
    }
}

/// What one densification did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct DensifyCounts {
    pub cloned: usize,
    pub split: usize,
    /// Candidates held back by [`DensifyConfig::max_gaussians`].
    pub deferred: usize,
    /// How many were pruned by each rule, indexed by [`PruneRule`] (a Gaussian failing
    /// several counts under the first: opacity, then world size, then screen size).
    pub pruned_by: [usize; 4],
    /// MCMC ([`crate::mcmc`]): dead Gaussians moved onto alive ones.
    pub relocated: usize,
    /// MCMC: Gaussians added by growth.
    pub added: usize,
}

impl DensifyCounts {
    /// How many were pruned, by any rule.
    pub fn pruned(&self) -> usize {
        self.pruned_by.iter().sum()
    }
}

/// Why a Gaussian was pruned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PruneRule {
    /// Opacity below `min_opacity`.
    Opacity = 0,
    /// Largest world scale above `max_world_scale` × reach (after the first reset).
    WorldSize = 1,
    /// Largest screen radius above `max_screen_radius` (after the first reset).
    ScreenSize = 2,
    /// A sphere of `camera_reach` × the largest scale contains a training camera.
    CameraReach = 3,
}

/// A densification plan: the rearrangement plus the new means and log-scales of the
/// split samples (rows `first_split..` of the new arrangement).
#[derive(Clone, Debug, Default)]
pub struct DensifyPlan {
    pub reindex: Reindex,
    pub split_means: Vec<[f32; 3]>,
    pub split_log_scales: Vec<[f32; 3]>,
    /// Row (in the new arrangement) of the first split sample.
    pub first_split: usize,
    pub counts: DensifyCounts,
}

fn allowed(mask: Option<&[bool]>, i: usize) -> bool {
    mask.is_none_or(|m| m[i])
}

fn max_scale(ls: &[f32; 3]) -> f32 {
    ls[0].max(ls[1]).max(ls[2]).exp()
}

/// Rotation matrix of a (w, x, y, z) quaternion, normalised (identity if zero):
/// the rasterizer's own, so densification and rendering agree.
pub use transsplat_raster::project::rotation_matrix as quat_matrix;

/// Standard normal sample (Box–Muller).
pub(crate) fn normal(rng: &mut ChaCha8Rng) -> f32 {
    let u: f32 = rng.gen_range(f32::EPSILON..1.0);
    let v: f32 = rng.gen();
    (-2.0 * u.ln()).sqrt() * (std::f32::consts::TAU * v).cos()
}

/// The size of the scene for densification: INRIA's camera extent, and the cameras'
/// centre when known (module doc, **Prune**).
#[derive(Clone, Debug, PartialEq)]
pub struct Bounds {
    pub extent: f32,
    pub centre: Option<[f32; 3]>,
    /// The training cameras' centres (empty when unknown: no camera-reach rule).
    pub cameras: Vec<[f32; 3]>,
}

impl Bounds {
    /// INRIA's bounds: the extent alone.
    pub fn extent(extent: f32) -> Self {
        Bounds { extent, centre: None, cameras: Vec::new() }
    }

    /// Whether a sphere of `radius` about `mean` contains a training camera.
    fn reaches_a_camera(&self, mean: [f32; 3], radius: f32) -> bool {
        let r2 = radius * radius;
        self.cameras.iter().any(|&c| squared_distance(mean, c) < r2)
    }

    /// The distance that scales the world-size prune rule at `mean`:
    /// max(extent, ‖mean − centre‖), or the extent when the centre is unknown.
    fn reach(&self, mean: [f32; 3]) -> f32 {
        match self.centre {
            Some(c) => self.extent.max(squared_distance(mean, c).sqrt()),
            None => self.extent,
        }
    }
}

fn squared_distance(a: [f32; 3], b: [f32; 3]) -> f32 {
    (0..3).map(|k| (a[k] - b[k]) * (a[k] - b[k])).sum()
}

/// Whether Gaussian parameters fail the prune test.
struct PruneTest<'a> {
    min_opacity: f32,
    bounds: &'a Bounds,
    large: Option<(f32, Option<f32>)>, // (max world scale per unit of reach, max screen radius)
    camera_reach: Option<f32>,
}

impl<'a> PruneTest<'a> {
    fn new(cfg: &DensifyConfig, bounds: &'a Bounds, step: u64) -> Self {
        let large = cfg.prunes_large(step).then_some((cfg.max_world_scale, cfg.max_screen_radius));
        PruneTest { min_opacity: cfg.min_opacity, bounds, large, camera_reach: cfg.camera_reach }
    }
    /// The first rule the Gaussian fails, if any.
    fn rule(
        &self,
        opacity_logit: f32,
        log_scale: &[f32; 3],
        mean: [f32; 3],
        radius: f32,
    ) -> Option<PruneRule> {
        if !(sigmoid(opacity_logit) >= self.min_opacity) {
            return Some(PruneRule::Opacity);
        }
        if self.camera_reach.is_some_and(|k| self.bounds.reaches_a_camera(mean, k * max_scale(log_scale))) {
            return Some(PruneRule::CameraReach);
        }
        let (ws, ss) = self.large?;
        if max_scale(log_scale) > ws * self.bounds.reach(mean) {
            Some(PruneRule::WorldSize)
        } else if ss.is_some_and(|s| radius > s) {
            Some(PruneRule::ScreenSize)
        } else {
            None
        }
    }
}

/// Plans INRIA's `densify_and_prune` at `step`: clone, split, then prune.
pub fn plan_densify(
    g: &Gaussians,
    stats: &DensifyStats,
    cfg: &DensifyConfig,
    bounds: &Bounds,
    step: u64,
    mask: Option<&[bool]>,
    rng: &mut ChaCha8Rng,
) -> DensifyPlan {
    let n = g.len();
    assert!(mask.is_none_or(|m| m.len() == n), "densification mask does not match the Gaussians");
    let grads = stats.mean_grad();
    let dense = cfg.percent_dense * bounds.extent;
    let k = cfg.split_count.max(1);
    let clones = |i: usize| max_scale(&g.log_scales[i]) <= dense;
    let mut candidates: Vec<usize> =
        (0..n).filter(|&i| grads[i] >= cfg.grad_threshold && allowed(mask, i)).collect();
    let wanted = candidates.len();
    if let Some(cap) = cfg.max_gaussians {
        candidates =
            within_budget(candidates, &grads, cap.saturating_sub(n), |i| if clones(i) { 1 } else { k - 1 });
    }
    let deferred = wanted - candidates.len();
    let (clone, split): (Vec<usize>, Vec<usize>) = candidates.into_iter().partition(|&i| clones(i));
    let shrink = (0.8 * k as f32).ln();
    let mut split_means = Vec::with_capacity(split.len() * k);
    let mut split_log_scales = Vec::with_capacity(split.len() * k);
    for &i in &split {
        let r = quat_matrix(g.rotations[i]);
        let s = g.log_scales[i].map(f32::exp);
        for _ in 0..k {
            let z = [normal(rng) * s[0], normal(rng) * s[1], normal(rng) * s[2]];
            let m = g.means[i];
            split_means
                .push(std::array::from_fn(|a| m[a] + r[a][0] * z[0] + r[a][1] * z[1] + r[a][2] * z[2]));
            split_log_scales.push(g.log_scales[i].map(|v| v - shrink));
        }
    }
    // Candidate rows: originals that were not split, clones, split samples.
    let is_split = {
        let mut v = vec![false; n];
        split.iter().for_each(|&i| v[i] = true);
        v
    };
    let test = PruneTest::new(cfg, bounds, step);
    let mut src: Vec<u32> = Vec::with_capacity(n + clone.len() + split_means.len());
    let mut pruned_by = [0usize; 4];
    // Counts the rule a candidate fails; true when it is pruned.
    let mut pruned = |rule: Option<PruneRule>| rule.map(|r| pruned_by[r as usize] += 1).is_some();
    for i in 0..n {
        if is_split[i] {
            continue;
        }
        if !(allowed(mask, i)
            && pruned(test.rule(g.opacity_logits[i], &g.log_scales[i], g.means[i], stats.max_radii[i])))
        {
            src.push(i as u32);
        }
    }
    let fresh_from = src.len();
    for &i in &clone {
        // Clones are copies: same prune test, but no screen radius recorded yet.
        if !pruned(test.rule(g.opacity_logits[i], &g.log_scales[i], g.means[i], 0.0)) {
            src.push(i as u32);
        }
    }
    let first_split = src.len();
    let mut kept_means = Vec::new();
    let mut kept_scales = Vec::new();
    for (j, &i) in split.iter().enumerate() {
        for s in 0..k {
            let (m, ls) = (split_means[j * k + s], split_log_scales[j * k + s]);
            if !pruned(test.rule(g.opacity_logits[i], &ls, m, 0.0)) {
                src.push(i as u32);
                kept_means.push(m);
                kept_scales.push(ls);
            }
        }
    }
    DensifyPlan {
        reindex: Reindex { src, fresh_from, old_len: n },
        split_means: kept_means,
        split_log_scales: kept_scales,
        first_split,
        counts: DensifyCounts {
            cloned: clone.len(),
            split: split.len(),
            deferred,
            pruned_by,
            ..Default::default()
        },
    }
}

/// The candidates that fit in `room` new rows, largest mean gradient first (ties by
/// index), each costing `cost(i)` rows; returned in index order (module doc, **Budget**).
fn within_budget(
    mut candidates: Vec<usize>,
    grads: &[f32],
    room: usize,
    cost: impl Fn(usize) -> usize,
) -> Vec<usize> {
    candidates.sort_by(|&a, &b| grads[b].total_cmp(&grads[a]).then(a.cmp(&b)));
    let mut spent = 0;
    let mut kept: Vec<usize> = candidates
        .into_iter()
        .filter(|&i| {
            let fits = spent + cost(i) <= room;
            if fits {
                spent += cost(i);
            }
            fits
        })
        .collect();
    kept.sort_unstable();
    kept
}

/// Plans pruning alone (opacity, and size when `step` is after the first reset).
pub fn plan_prune(
    g: &Gaussians,
    stats: &DensifyStats,
    cfg: &DensifyConfig,
    bounds: &Bounds,
    step: u64,
    mask: Option<&[bool]>,
) -> Reindex {
    assert!(mask.is_none_or(|m| m.len() == g.len()), "prune mask does not match the Gaussians");
    let test = PruneTest::new(cfg, bounds, step);
    let keep: Vec<bool> = (0..g.len())
        .map(|i| {
            !(allowed(mask, i)
                && test.rule(g.opacity_logits[i], &g.log_scales[i], g.means[i], stats.max_radii[i]).is_some())
        })
        .collect();
    Reindex::keep(&keep)
}

/// INRIA's `reset_opacity`: opacity ← min(opacity, `value`) (as a logit) for the
/// allowed Gaussians. Returns which were touched (the caller zeroes their opacity
/// moments, as INRIA replaces the optimiser state).
pub fn reset_opacity(g: &mut Gaussians, value: f32, mask: Option<&[bool]>) -> Vec<bool> {
    let cap = (value / (1.0 - value)).ln();
    let mut touched = vec![false; g.len()];
    for (i, o) in g.opacity_logits.iter_mut().enumerate() {
        if allowed(mask, i) {
            *o = o.min(cap);
            touched[i] = true;
        }
    }
    touched
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_world_size_rule_grows_with_distance_from_the_cameras() {
        // Three opaque Gaussians of largest scale 1: near the cameras' centre, 20 away,
        // and 20 away but 3 large. Extent 2.5, so INRIA's bound is 0.25 everywhere; with
        // the centre known it is 0.1 · max(2.5, distance): 0.25 near, 2 at distance 20.
        let g = Gaussians {
            means: vec![[1.0, 0.0, 0.0], [0.0, 20.0, 0.0], [0.0, 0.0, -20.0]],
            log_scales: vec![[0.0, -1.0, -2.0], [0.0, -1.0, -2.0], [3f32.ln(), 0.0, 0.0]],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; 3],
            opacity_logits: vec![4.0; 3],
            sh_degree: 0,
            sh: vec![0.0; 9],
            ..Default::default()
        };
        let cfg =
            DensifyConfig { opacity_reset_interval: 100, max_screen_radius: None, ..Default::default() };
        let stats = DensifyStats::new(3);
        let kept = |b: &Bounds, step: u64| plan_prune(&g, &stats, &cfg, b, step, None).src;
        let inria = Bounds::extent(2.5);
        let ours = Bounds { extent: 2.5, centre: Some([0.0; 3]), cameras: Vec::new() };
        assert_eq!(kept(&inria, 101), Vec::<u32>::new());
        assert_eq!(kept(&ours, 101), vec![1]);
        // Before the first reset no size rule applies.
        assert_eq!(kept(&inria, 100), vec![0, 1, 2]);
    }

    #[test]
    fn each_prune_is_counted_under_the_first_rule_it_fails() {
        // Four Gaussians, no gradient (nothing cloned or split), after the first reset:
        // transparent (and too large: counted as opacity), too large in the world,
        // too large on screen, and one that passes every rule.
        let g = Gaussians {
            means: vec![[0.0; 3]; 4],
            log_scales: vec![[2.0; 3], [2.0; 3], [-3.0; 3], [-3.0; 3]],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; 4],
            opacity_logits: vec![-9.0, 4.0, 4.0, 4.0],
            sh_degree: 0,
            sh: vec![0.0; 12],
            ..Default::default()
        };
        let cfg = DensifyConfig {
            opacity_reset_interval: 100,
            max_screen_radius: Some(20.0),
            ..Default::default()
        };
        let mut stats = DensifyStats::new(4);
        stats.max_radii = vec![30.0, 30.0, 30.0, 19.0];
        let mut rng = <ChaCha8Rng as rand::SeedableRng>::seed_from_u64(0);
        let plan = plan_densify(&g, &stats, &cfg, &Bounds::extent(1.0), 101, None, &mut rng);
        assert_eq!(plan.counts.pruned_by, [1, 1, 1, 0]);
        assert_eq!(plan.counts.pruned(), 3);
        assert_eq!(plan.reindex.src, vec![3]);
        // Before the first reset only the opacity rule applies.
        let plan = plan_densify(&g, &stats, &cfg, &Bounds::extent(1.0), 100, None, &mut rng);
        assert_eq!(plan.counts.pruned_by, [1, 0, 0, 0]);
    }

    #[test]
    fn a_budget_densifies_the_largest_gradients_first_and_never_grows_past_it() {
        // 40 opaque Gaussians; only the first four have gradients above the threshold:
        // 0, 1 and 3 small (cloned), 2 large (split into two, one more row), mean
        // gradients 5e-4, 9e-4, 1e-3, 3e-4.
        let n = 40;
        let mut log_scales = vec![[-6.0; 3]; n];
        log_scales[2] = [0.0; 3];
        let g = Gaussians {
            means: vec![[0.0; 3]; n],
            log_scales,
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; n],
            opacity_logits: vec![4.0; n],
            sh_degree: 0,
            sh: vec![0.0; 3 * n],
            ..Default::default()
        };
        let mut stats = DensifyStats::new(n);
        stats.grad_accum[..4].copy_from_slice(&[5e-4, 9e-4, 1e-3, 3e-4]);
        stats.denom = vec![1; n];
        let mut rng = <ChaCha8Rng as rand::SeedableRng>::seed_from_u64(0);
        let mut plan_with = |cap: Option<usize>| {
            let cfg = DensifyConfig { max_gaussians: cap, ..Default::default() };
            let p = plan_densify(&g, &stats, &cfg, &Bounds::extent(1.0), 200, None, &mut rng);
            let tail = p.reindex.src[p.reindex.src.len() - 4..].to_vec();
            (p.counts.cloned, p.counts.split, p.counts.deferred, p.reindex.src.len(), tail)
        };
        // No cap: 3 clones and 1 split, 40 + 3 + 1 rows.
        assert_eq!(plan_with(None), (3, 1, 0, 44, vec![1, 3, 2, 2]));
        // A far cap: the same.
        assert_eq!(plan_with(Some(100)), (3, 1, 0, 44, vec![1, 3, 2, 2]));
        // Cap 42, room for 2: the split of 2 (1e-3) and the clone of 1 (9e-4); 0 and 3
        // wait. The tail: the last original, the clone, two split rows.
        assert_eq!(plan_with(Some(42)), (1, 1, 2, 42, vec![39, 1, 2, 2]));
        // Cap 41: room for 1, the split of 2 alone.
        assert_eq!(plan_with(Some(41)), (0, 1, 3, 41, vec![38, 39, 2, 2]));
        // At the cap: nothing grows.
        assert_eq!(plan_with(Some(40)), (0, 0, 4, 40, vec![36, 37, 38, 39]));
    }

    #[test]
    fn a_gaussian_whose_support_reaches_a_camera_is_pruned_from_the_first_densification() {
        // Cameras at the origin and at (0, 0, 10). Largest scale 1 at distance 3 from the
        // first camera (3.33 σ reaches it); 0.8 at distance 3 (2.66 does not); 3 at
        // distance 10.5 from the second (9.99 does not); 4 at distance 13.3 from the
        // second (13.32 reaches it); a wide transparent one, counted as opacity.
        let means = vec![[3.0, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 20.5], [0.0, 13.3, 10.0], [1.0; 3]];
        let scales = [1.0f32, 0.8, 3.0, 4.0, 5.0];
        let g = Gaussians {
            log_scales: scales.iter().map(|s| [s.ln(), (0.1 * s).ln(), (0.1 * s).ln()]).collect(),
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; 5],
            opacity_logits: vec![4.0, 4.0, 4.0, 4.0, -9.0],
            sh_degree: 0,
            sh: vec![0.0; 15],
            means,
            ..Default::default()
        };
        let stats = DensifyStats::new(5);
        let bounds = Bounds {
            extent: 100.0,
            centre: Some([0.0, 0.0, 5.0]),
            cameras: vec![[0.0; 3], [0.0, 0.0, 10.0]],
        };
        let cfg = DensifyConfig::default();
        let mut rng = <ChaCha8Rng as rand::SeedableRng>::seed_from_u64(0);
        // Step 600: long before the first reset, when no size rule of INRIA's applies.
        let plan = plan_densify(&g, &stats, &cfg, &bounds, 600, None, &mut rng);
        assert_eq!(plan.reindex.src, vec![1, 2]);
        assert_eq!(plan.counts.pruned_by, [1, 0, 0, 2]);
        // Off (INRIA), or without cameras: only the transparent one goes.
        let inria = DensifyConfig { camera_reach: None, ..DensifyConfig::default() };
        assert_eq!(plan_prune(&g, &stats, &inria, &bounds, 600, None).src, vec![0, 1, 2, 3]);
        let blind = Bounds { cameras: Vec::new(), ..bounds };
        assert_eq!(plan_prune(&g, &stats, &cfg, &blind, 600, None).src, vec![0, 1, 2, 3]);
    }
}

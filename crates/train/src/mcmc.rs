//! The MCMC densification strategy of Kheradmand et al., "3D Gaussian Splatting as
//! Markov Chain Monte Carlo" (NeurIPS 2024), as gsplat's `MCMCStrategy` runs it: a
//! fixed budget of Gaussians instead of INRIA's gradient-driven clone and split.
//!
//! - **Relocation** (every `interval` steps inside the densification window): every
//!   Gaussian whose opacity fell to `min_opacity` or below is *dead*; each one is moved
//!   onto an alive Gaussian drawn with probability ∝ opacity (with replacement). A
//!   Gaussian drawn k times becomes N = k + 1 copies of itself whose opacity and scale
//!   follow the paper's eq. 9 ([`relocation`]), so the N copies render about as the one
//!   did. Dead rows are overwritten in place; the Adam moments of every row involved
//!   start again at zero (gsplat zeroes the drawn rows'; we zero the overwritten rows'
//!   too, since they hold a new Gaussian).
//! - **Growth**: then `min(cap, ⌊(1 + growth) n⌋) − n` new Gaussians are drawn the same
//!   way (∝ opacity) and appended as eq. 9 copies. The budget `cap` is
//!   [`crate::DensifyConfig::max_gaussians`].
//! - **Noise** (every step, after Adam): each mean moves by Σ ε · λ · lr_μ · g(o), with
//!   Σ = R S² Rᵀ its covariance, ε ~ 𝒩(0, I), λ = `noise_lr` (5·10⁵), lr_μ the step's
//!   position learning rate and g(o) = 1/(1 + e^{−100 (1 − o − 0.995)}) (the paper's
//!   eq. 10 with gsplat's gate): the Langevin exploration term, large only for nearly
//!   transparent Gaussians. Where g(o) < 10⁻¹⁰ (o above about 0.24) a row is skipped
//!   (a departure from gsplat, which moves every row): the move dropped is 10¹⁰ times
//!   smaller than a fully transparent Gaussian of the same shape would take.
//! - **Regularisers** (every step, added to the image loss's gradient): λ_o · mean(o)
//!   and λ_s · mean(s) over every Gaussian (and every axis), λ_o = λ_s = 0.01, which
//!   push unused Gaussians towards transparency so that relocation finds them.
//!
//! No opacity reset and no size pruning: dead Gaussians are reused instead. The run
//! starts from opacity 0.5 and a tenth of INRIA's initial scale (gsplat's MCMC
//! preset), see [`McmcConfig::init_opacity`]. Why it exists and what it measured:
//! docs/method.md#t1-densification-strategies.

use crate::densify::{normal, quat_matrix};
use crate::init::logit;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use transsplat_raster::Grads;
use transsplat_scene::{sigmoid, Gaussians};

use crate::model::Reindex;

/// Settings of the MCMC strategy (gsplat's defaults).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct McmcConfig {
    /// λ of the position noise (gsplat `noise_lr`).
    pub noise_lr: f32,
    /// Weight of the mean-opacity regulariser (gsplat `opacity_reg`).
    pub opacity_reg: f32,
    /// Weight of the mean-scale regulariser (gsplat `scale_reg`).
    pub scale_reg: f32,
    /// Growth per densification, as a fraction of the count (gsplat: 5 %).
    pub growth: f32,
    /// Opacity of the initial Gaussians (gsplat's MCMC preset: 0.5; INRIA: 0.1).
    pub init_opacity: f32,
    /// Factor on the initial scales (gsplat's MCMC preset: 0.1).
    pub init_scale: f32,
}

impl Default for McmcConfig {
    fn default() -> Self {
        McmcConfig {
            noise_lr: 5e5,
            opacity_reg: 0.01,
            scale_reg: 0.01,
            growth: 0.05,
            init_opacity: 0.5,
            init_scale: 0.1,
        }
    }
}

/// The budget when none is given (gsplat's `cap_max`).
pub const DEFAULT_CAP: usize = 1_000_000;

/// Copies per Gaussian beyond which eq. 9 is evaluated as for this many (gsplat's
/// binomial table has 51 rows).
const MAX_COPIES: u32 = 51;

/// Eq. 9 of the paper: a Gaussian of opacity `o` replaced by `n` copies of itself. Returns
/// (o', f): each copy has opacity o' = 1 − (1 − o)^{1/n}, so that n of them stacked
/// transmit what the one did at its centre, and scale f · s with
/// f = o / Σ_{i=1}^{n} Σ_{k=0}^{i−1} C(i−1, k) (−1)^k o'^{k+1} / √(k+1).
pub fn relocation(o: f32, n: u32) -> (f32, f32) {
    let n = n.clamp(1, MAX_COPIES);
    let o = o as f64;
    let new_o = 1.0 - (1.0 - o).powf(1.0 / n as f64);
    let mut denom = 0.0f64;
    for i in 1..=n {
        let mut binom = 1.0f64; // C(i − 1, k), built up over k
        for k in 0..i {
            if k > 0 {
                binom = binom * (i - k) as f64 / k as f64;
            }
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            denom += binom * sign * new_o.powi(k as i32 + 1) / ((k + 1) as f64).sqrt();
        }
    }
    (new_o as f32, (o / denom) as f32)
}

/// Draws `count` rows of `allowed` with probability ∝ `weights[row]` (with replacement).
fn draw(weights: &[f32], allowed: &[u32], count: usize, rng: &mut ChaCha8Rng) -> Vec<u32> {
    let mut cdf = Vec::with_capacity(allowed.len());
    let mut total = 0.0f64;
    for &i in allowed {
        total += weights[i as usize].max(0.0) as f64;
        cdf.push(total);
    }
    if !(total > 0.0) {
        return Vec::new();
    }
    (0..count)
        .map(|_| {
            let u = rng.gen::<f64>() * total;
            let k = cdf.partition_point(|&c| c <= u).min(allowed.len() - 1);
            allowed[k]
        })
        .collect()
}

/// Gives each drawn row its eq. 9 opacity and scale for (times drawn + 1) copies.
fn apply_relocation(g: &mut Gaussians, drawn: &[u32], min_opacity: f32) {
    let mut times = std::collections::BTreeMap::<u32, u32>::new();
    for &i in drawn {
        *times.entry(i).or_default() += 1;
    }
    for (&i, &k) in &times {
        let i = i as usize;
        let (o, f) = relocation(sigmoid(g.opacity_logits[i]), k + 1);
        let o = o.clamp(min_opacity, 1.0 - f32::EPSILON);
        g.opacity_logits[i] = logit(o);
        g.log_scales[i] = g.log_scales[i].map(|s| s + f.ln());
    }
}

/// One stage of relocation or growth: the rearrangement to apply after the drawn rows'
/// opacity and scale were set (by the planning function, on the model) and the rows (in
/// the new arrangement) whose Adam moments restart at zero. Fresh rows start at zero
/// anyway.
#[derive(Clone, Debug, Default)]
pub struct McmcPlan {
    pub reindex: Reindex,
    pub restart: Vec<bool>,
}

/// Every row's opacity, and the rows with `mask[i]` (all when there is no mask).
fn opacities_and_allowed(g: &Gaussians, mask: Option<&[bool]>) -> (Vec<f32>, Vec<u32>) {
    let opacity = g.opacity_logits.iter().map(|&l| sigmoid(l)).collect();
    let allowed = (0..g.len() as u32).filter(|&i| mask.is_none_or(|m| m[i as usize])).collect();
    (opacity, allowed)
}

/// Relocation (module doc): moves every dead row (opacity ≤ `min_opacity`) onto an alive
/// one drawn ∝ opacity, after setting the drawn rows' eq. 9 opacity and scale in `g`.
/// Only rows with `mask[i]` may die or be drawn. In place: no row is added or removed.
pub fn plan_relocate(
    g: &mut Gaussians,
    min_opacity: f32,
    mask: Option<&[bool]>,
    rng: &mut ChaCha8Rng,
) -> McmcPlan {
    let n = g.len();
    let (opacity, allowed) = opacities_and_allowed(g, mask);
    let (dead, alive): (Vec<u32>, Vec<u32>) =
        allowed.into_iter().partition(|&i| opacity[i as usize] <= min_opacity);
    let drawn = draw(&opacity, &alive, dead.len(), rng);
    apply_relocation(g, &drawn, min_opacity);
    let mut src: Vec<u32> = (0..n as u32).collect();
    let mut restart = vec![false; n];
    for (&d, &s) in dead.iter().zip(&drawn) {
        src[d as usize] = s;
        restart[d as usize] = true;
        restart[s as usize] = true;
    }
    McmcPlan { reindex: Reindex { src, fresh_from: n, old_len: n }, restart }
}

/// Growth (module doc): appends min(`cap`, ⌊(1 + growth) n⌋) − n copies of rows drawn
/// ∝ opacity among those with `mask[i]`, after setting the drawn rows' eq. 9 opacity and
/// scale in `g`.
pub fn plan_grow(
    g: &mut Gaussians,
    cfg: &McmcConfig,
    min_opacity: f32,
    cap: usize,
    mask: Option<&[bool]>,
    rng: &mut ChaCha8Rng,
) -> McmcPlan {
    let n = g.len();
    let (opacity, pool) = opacities_and_allowed(g, mask);
    let target = cap.min(((1.0 + cfg.growth as f64) * n as f64) as usize);
    let drawn = draw(&opacity, &pool, target.saturating_sub(n), rng);
    apply_relocation(g, &drawn, min_opacity);
    let mut restart = vec![false; n + drawn.len()];
    drawn.iter().for_each(|&s| restart[s as usize] = true);
    let src: Vec<u32> = (0..n as u32).chain(drawn.iter().copied()).collect();
    McmcPlan { reindex: Reindex { src, fresh_from: n, old_len: n }, restart }
}

/// The noise gate g(o) = 1/(1 + e^{−100 (1 − o − 0.995)}) (module doc).
fn noise_gate(o: f32) -> f32 {
    1.0 / (1.0 + (-100.0 * (1.0 - o - 0.995)).exp())
}

/// Moves every mean by Σ ε · `scale` · g(o) (module doc, **Noise**; `scale` = λ lr_μ).
/// One seed is drawn from `rng`; rows are taken in fixed chunks, each with its own
/// stream of that seed, so the result does not depend on the thread count.
pub fn inject_noise(g: &mut Gaussians, scale: f32, rng: &mut ChaCha8Rng) {
    const ROWS: usize = 4096;
    let seed: u64 = rng.gen();
    let Gaussians { means, log_scales, rotations, opacity_logits, .. } = g;
    means
        .par_chunks_mut(ROWS)
        .zip(log_scales.par_chunks(ROWS))
        .zip(rotations.par_chunks(ROWS).zip(opacity_logits.par_chunks(ROWS)))
        .enumerate()
        .for_each(|(c, ((means, log_scales), (rotations, logits)))| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            rng.set_stream(c as u64);
            for (((m, ls), q), &l) in means.iter_mut().zip(log_scales).zip(rotations).zip(logits) {
                let gate = noise_gate(sigmoid(l));
                if !(gate >= 1e-10) {
                    continue;
                }
                let r = quat_matrix(*q);
                let s2 = ls.map(|v| (2.0 * v).exp());
                let e = [normal(&mut rng), normal(&mut rng), normal(&mut rng)];
                // Σ e = R S² Rᵀ e.
                let rte: [f32; 3] =
                    std::array::from_fn(|k| (0..3).map(|a| r[a][k] * e[a]).sum::<f32>() * s2[k]);
                for a in 0..3 {
                    m[a] += scale * gate * (0..3).map(|k| r[a][k] * rte[k]).sum::<f32>();
                }
            }
        });
}

/// Adds the gradients of λ_o · mean(o) and λ_s · mean(s) (module doc, **Regularisers**)
/// to every row of `grads`.
pub fn add_regularisers(g: &Gaussians, cfg: &McmcConfig, grads: &mut Grads) {
    let n = g.len().max(1) as f32;
    let (wo, ws) = (cfg.opacity_reg / n, cfg.scale_reg / (3.0 * n));
    grads.opacity_logits.par_iter_mut().zip(&g.opacity_logits).with_min_len(4096).for_each(|(d, &l)| {
        let o = sigmoid(l);
        *d += wo * o * (1.0 - o);
    });
    grads.log_scales.par_iter_mut().zip(&g.log_scales).with_min_len(4096).for_each(|(d, ls)| {
        for k in 0..3 {
            d[k] += ws * ls[k].exp();
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_copy_is_the_gaussian_itself_and_two_copies_match_eq_9_by_hand() {
        let (o, f) = relocation(0.7, 1);
        assert!((o - 0.7).abs() < 1e-6 && (f - 1.0).abs() < 1e-6, "{o} {f}");
        // n = 2: o' = 1 − √(1 − o); denominator (i = 1) o' + (i = 2) o' − o'²/√2.
        let o = 0.64f64;
        let op = 1.0 - (1.0 - o).sqrt();
        let want = o / (2.0 * op - op * op / 2f64.sqrt());
        let (got_o, got_f) = relocation(0.64, 2);
        assert!((got_o as f64 - op).abs() < 1e-6, "{got_o} {op}");
        assert!((got_f as f64 - want).abs() < 1e-5, "{got_f} {want}");
        // n copies stacked at the centre transmit what the one did: (1 − o')^n = 1 − o.
        for n in [2, 3, 7, 20] {
            let (op, _) = relocation(0.3, n);
            assert!(((1.0 - op).powi(n as i32) - 0.7).abs() < 1e-5, "n = {n}");
        }
    }

    fn cloud(opacities: &[f32]) -> Gaussians {
        let n = opacities.len();
        Gaussians {
            means: (0..n).map(|i| [i as f32, 0.0, 0.0]).collect(),
            log_scales: vec![[-2.0; 3]; n],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; n],
            opacity_logits: opacities.iter().map(|&o| logit(o)).collect(),
            sh_degree: 0,
            sh: vec![0.0; n * 3],
            ..Default::default()
        }
    }

    #[test]
    fn dead_gaussians_move_onto_alive_ones_and_growth_stops_at_the_cap() {
        let mut g = cloud(&[0.001, 0.9, 0.002, 0.5]);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let p = plan_relocate(&mut g, 0.005, None, &mut rng);
        let r = &p.reindex;
        assert_eq!((r.old_len, r.len(), r.fresh_from), (4, 4, 4));
        // Alive rows keep their place; dead rows copy an alive one, and both restart.
        assert_eq!((r.src[1], r.src[3]), (1, 3));
        assert!([1, 3].contains(&r.src[0]) && [1, 3].contains(&r.src[2]));
        assert!(p.restart[0] && p.restart[2] && (p.restart[1] || p.restart[3]));
        // A drawn source now has the eq. 9 opacity of its copies, below its own.
        for s in [r.src[0], r.src[2]] {
            let want = if r.src[0] == r.src[2] { 3 } else { 2 };
            let o0 = if s == 1 { 0.9 } else { 0.5 };
            let (o, f) = relocation(o0, want);
            assert!((sigmoid(g.opacity_logits[s as usize]) - o).abs() < 1e-5);
            assert!((g.log_scales[s as usize][0] - (-2.0 + f.ln())).abs() < 1e-5);
        }
        let mut m = crate::model::Model::new(g, 0);
        m.reindex(&p.reindex);
        let grow = McmcConfig { growth: 1.0, ..Default::default() };
        let grown = plan_grow(&mut m.gaussians, &grow, 0.005, 6, None, &mut rng);
        let r = &grown.reindex;
        assert_eq!((r.old_len, r.len(), r.fresh_from), (4, 6, 4));
        assert!(r.src[4..].iter().all(|&s| grown.restart[s as usize]));
        // A mask keeps the other rows out of both.
        let mut g = cloud(&[0.001, 0.9, 0.002, 0.5]);
        let mask = [true, false, false, true];
        let p = plan_relocate(&mut g, 0.005, Some(&mask), &mut rng);
        assert_eq!(p.reindex.src, [3, 1, 2, 3]);
        let mut m = crate::model::Model::new(g, 0);
        m.reindex(&p.reindex);
        let p = plan_grow(&mut m.gaussians, &grow, 0.005, 100, Some(&mask), &mut rng);
        assert_eq!(p.reindex.len(), 8);
        assert!(p.reindex.src[4..].iter().all(|&s| s == 0 || s == 3));
    }

    #[test]
    fn noise_moves_only_nearly_transparent_gaussians_along_their_covariance() {
        let mut g = cloud(&[0.001, 0.9]);
        // A flat Gaussian: its noise stays in the plane of its two large axes.
        g.log_scales[0] = [0.0, 0.0, -20.0];
        let before = g.means.clone();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        inject_noise(&mut g, 0.1, &mut rng);
        assert_eq!(g.means[1], before[1]);
        let d: Vec<f32> = (0..3).map(|k| g.means[0][k] - before[0][k]).collect();
        assert!(d[0].abs() + d[1].abs() > 1e-3, "{d:?}");
        assert!(d[2].abs() < 1e-9, "{d:?}");
    }

    #[test]
    fn draws_are_proportional_to_the_weights_of_the_allowed_rows() {
        let weights = [1.0, 3.0, 0.0, 100.0];
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let drawn = draw(&weights, &[0, 1, 2], 40_000, &mut rng);
        let count = |r: u32| drawn.iter().filter(|&&d| d == r).count() as f64;
        assert_eq!(count(2) + count(3), 0.0, "zero weight, or not allowed");
        let ratio = count(1) / count(0);
        assert!((ratio - 3.0).abs() < 0.1, "{ratio}");
        assert!(draw(&[0.0, 0.0], &[0, 1], 5, &mut rng).is_empty(), "nothing to draw from");
    }

    #[test]
    fn noise_does_not_depend_on_the_thread_count() {
        let opacities: Vec<f32> = (0..10_000).map(|i| if i % 3 == 0 { 0.001 } else { 0.6 }).collect();
        let run = |threads: usize| {
            let mut g = cloud(&opacities);
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| inject_noise(&mut g, 0.1, &mut ChaCha8Rng::seed_from_u64(9)));
            g.means
        };
        let (one, two) = (run(1), run(2));
        assert_eq!(one, two);
        assert_ne!(one, cloud(&opacities).means, "the transparent rows moved");
    }

    #[test]
    fn the_regularisers_gradients_match_finite_differences() {
        let g = cloud(&[0.2, 0.7, 0.5]);
        let cfg = McmcConfig::default();
        let loss = |g: &Gaussians| {
            let n = g.len() as f64;
            let o: f64 = g.opacity_logits.iter().map(|&l| sigmoid(l) as f64).sum::<f64>() / n;
            let s: f64 = g.log_scales.iter().flatten().map(|&v| (v as f64).exp()).sum::<f64>() / (3.0 * n);
            cfg.opacity_reg as f64 * o + cfg.scale_reg as f64 * s
        };
        let mut grads = Grads::zeros(3, 0, 0);
        add_regularisers(&g, &cfg, &mut grads);
        let h = 1e-3f32;
        for i in 0..3 {
            let (mut a, mut b) = (g.clone(), g.clone());
            a.opacity_logits[i] += h;
            b.opacity_logits[i] -= h;
            let fd = (loss(&a) - loss(&b)) / (2.0 * h as f64);
            assert!((grads.opacity_logits[i] as f64 - fd).abs() < 1e-6, "{} {fd}", grads.opacity_logits[i]);
            let (mut a, mut b) = (g.clone(), g.clone());
            a.log_scales[i][1] += h;
            b.log_scales[i][1] -= h;
            let fd = (loss(&a) - loss(&b)) / (2.0 * h as f64);
            assert!((grads.log_scales[i][1] as f64 - fd).abs() < 1e-6, "{} {fd}", grads.log_scales[i][1]);
        }
    }
}

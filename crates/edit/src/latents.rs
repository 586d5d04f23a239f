//! The semantic latents' optimisation, advanced in batches (docs/method.md#m10-speed).
//!
//! The latents s_i move only under L_sem and L_uot (the steps render colour only), and
//! given what a round fixes (z̄, γ, the view plans) the gradient of Gaussian i at a
//! step depends on s_i alone: λ_sem 2γ_i (s_i − z̄_i) plus, when the step's view plan
//! holds i, L_uot's term ([`crate::losses`]). Each step therefore only records which
//! view it used; when the latents are read (a round, a checkpoint, the end of the
//! run) every row is taken through the recorded steps at once, while it sits in
//! cache, with the trainer's Adam arithmetic (`transsplat_train::adam::Hyper`, one step
//! counter for the group): the same latents, bit for bit, as stepping them with the
//! colours, for one pass over memory instead of one per step.

use crate::view::ViewTransport;
use rayon::prelude::*;
use transsplat_train::adam::Hyper;

/// What the steps since the last round share: the round's fixed quantities and the
/// loss weights.
pub struct Terms<'a> {
    /// z̄ (`N × d`), `None` before the first round (then no L_sem).
    pub zbar: Option<&'a [f32]>,
    pub gamma: &'a [f32],
    /// The round's view plans (for L_uot).
    pub plans: &'a [ViewTransport],
    /// λ_sem of the loss, λ_uot, and the cost's λ_sem (inside L_uot's gradient).
    pub l_sem: f32,
    pub l_uot: f32,
    pub cost_sem: f32,
}

/// Adam state of the latents and the steps recorded since the last advance.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Latents {
    pub m: Vec<f32>,
    pub v: Vec<f32>,
    /// Adam steps taken (the bias corrections' t).
    pub step: u64,
    /// (step of the loop, position of that step's view plan in [`Terms::plans`]).
    pending: Vec<(usize, Option<usize>)>,
}

/// Rows per batch: s, z̄, m and v of 1024 rows of 16 channels fit in L2.
const ROWS: usize = 1024;

impl Latents {
    /// Records a step on the view whose plan is `plan` (a position in the round's
    /// plans; `None` when the view has none).
    pub fn record(&mut self, step: usize, plan: Option<usize>) {
        self.pending.push((step, plan));
    }

    /// Steps recorded and not yet applied.
    pub fn pending(&self) -> usize {
        self.pending.len()
    }

    /// Applies the recorded steps to the latents `s` (`N × d`) with learning rate `lr`
    /// and Adam's (β₁, β₂, eps); returns each step's λ L_sem, or the first step at
    /// which a latent became NaN or infinite.
    pub fn advance(
        &mut self,
        s: &mut [f32],
        d: usize,
        terms: &Terms,
        lr: f32,
        (b1, b2, eps): (f32, f32, f32),
    ) -> Result<Vec<(usize, f64)>, usize> {
        let steps = std::mem::take(&mut self.pending);
        if steps.is_empty() || d == 0 {
            return Ok(steps.iter().map(|&(k, _)| (k, 0.0)).collect());
        }
        if self.m.len() != s.len() {
            self.m = vec![0.0; s.len()];
            self.v = vec![0.0; s.len()];
        }
        let hyper: Vec<Hyper> =
            (1..=steps.len() as u64).map(|k| Hyper::at(lr, (b1, b2), eps, self.step + k)).collect();
        self.step += steps.len() as u64;
        for p in terms.plans {
            assert!(p.idx.windows(2).all(|w| w[0] < w[1]), "view plan rows must ascend");
        }
        let avx2 = transsplat_scene::cpu::has_avx2();
        let batch = Batch { d, terms, steps: &steps, hyper: &hyper };
        let chunks: Vec<(Vec<f64>, Option<usize>)> =
            (s.par_chunks_mut(ROWS * d), self.m.par_chunks_mut(ROWS * d), self.v.par_chunks_mut(ROWS * d))
                .into_par_iter()
                .enumerate()
                .map(|(c, (s, m, v))| {
                    #[cfg(target_arch = "x86_64")]
                    if avx2 {
                        // SAFETY: AVX2 and FMA detected at run time.
                        return unsafe { batch.run_avx2(c * ROWS, s, m, v) };
                    }
                    batch.run_any(c * ROWS, s, m, v)
                })
                .collect();
        let mut loss = vec![0.0f64; steps.len()];
        let mut bad: Option<usize> = None;
        for (l, b) in chunks {
            loss.iter_mut().zip(&l).for_each(|(a, b)| *a += b);
            bad = match (bad, b) {
                (Some(x), Some(y)) => Some(x.min(y)),
                (x, y) => x.or(y),
            };
        }
        match bad {
            Some(k) => Err(steps[k].0),
            None => Ok(steps.iter().zip(loss).map(|(&(k, _), l)| (k, terms.l_sem as f64 * l)).collect()),
        }
    }
}

/// What every batch of an advance shares: the row width, the round's terms, the
/// recorded steps and their Adam constants.
struct Batch<'a> {
    d: usize,
    terms: &'a Terms<'a>,
    steps: &'a [(usize, Option<usize>)],
    hyper: &'a [Hyper],
}

impl Batch<'_> {
    /// [`Self::run`] compiled for AVX2: the same operations (no fused multiply-adds;
    /// square roots and divisions are exact in both), so the same bits.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn run_avx2(
        &self,
        r0: usize,
        s: &mut [f32],
        m: &mut [f32],
        v: &mut [f32],
    ) -> (Vec<f64>, Option<usize>) {
        self.run_any(r0, s, m, v)
    }

    /// [`Self::run`] with the row width known to the compiler for the default d = 16
    /// (its row loops then unroll into vector instructions; the same operations in
    /// the same order, so the same bits).
    #[inline(always)]
    fn run_any(&self, r0: usize, s: &mut [f32], m: &mut [f32], v: &mut [f32]) -> (Vec<f64>, Option<usize>) {
        match self.d {
            16 => self.run::<16>(r0, s, m, v),
            _ => self.run::<0>(r0, s, m, v),
        }
    }

    /// Takes rows `r0..` (the chunk `s`, `m`, `v`) through every recorded step; returns
    /// each step's L_sem sum over the chunk and the first step with a non-finite latent.
    /// `D` is the row width when it is known at compile time (0: `self.d`).
    #[inline(always)]
    fn run<const D: usize>(
        &self,
        r0: usize,
        s: &mut [f32],
        m: &mut [f32],
        v: &mut [f32],
    ) -> (Vec<f64>, Option<usize>) {
        let Batch { d, terms, steps, hyper } = *self;
        let d = if D > 0 { D } else { d };
        let rows = s.len() / d;
        let mut loss = vec![0.0f64; steps.len()];
        let mut bad = None;
        let (mut gbuf, mut prow) = (vec![0.0f32; d], vec![0.0f32; d]);
        let g = &mut gbuf[..d];
        for (k, (&(_, plan), h)) in steps.iter().zip(hyper).enumerate() {
            // This chunk's entries of the step's plan (its rows ascend).
            let (idx, plan, lo) = match plan.map(|p| &terms.plans[p]) {
                Some(p) => {
                    let lo = p.idx.partition_point(|&i| (i as usize) < r0);
                    let hi = p.idx.partition_point(|&i| (i as usize) < r0 + rows);
                    (&p.idx[lo..hi], Some(p), lo)
                }
                None => (&[][..], None, 0),
            };
            let mut next = 0;
            let mut nonfinite = false;
            for r in 0..rows {
                let i = r0 + r;
                let si = &mut s[r * d..(r + 1) * d];
                g.fill(0.0);
                // L_sem = Σ γ ‖s − z̄‖² (losses::semantic, same expressions for the
                // gradient; the row's loss is summed in f32).
                if let Some(z) = terms.zbar {
                    let gm = terms.gamma[i];
                    let zi = &z[i * d..(i + 1) * d];
                    // Index loops, not iterator adapters: inside the AVX2 copy the
                    // adapters were left as calls (a quarter of the time, by perf).
                    for j in 0..d {
                        let diff = si[j] - zi[j];
                        g[j] += terms.l_sem * 2.0 * gm * diff;
                    }
                    // The loss in eight partial sums, so it does not serialise the row.
                    let mut lanes = [0.0f32; 8];
                    let tail = (d / 8) * 8;
                    for c in (0..tail).step_by(8) {
                        for l in 0..8 {
                            let diff = si[c + l] - zi[c + l];
                            lanes[l] += gm * diff * diff;
                        }
                    }
                    let (mut rest, mut sum) = (-0.0f32, -0.0f32);
                    for j in tail..d {
                        rest += gm * (si[j] - zi[j]) * (si[j] - zi[j]);
                    }
                    for lane in lanes {
                        sum += lane;
                    }
                    loss[k] += (sum + rest) as f64;
                }
                // L_uot through the plan (losses::transport_semantic, same expressions).
                if next < idx.len() && idx[next] as usize == i {
                    plan.expect("a plan holds idx").plan_row(lo + next, &mut prow);
                    let p = &prow[..d];
                    next += 1;
                    let n = si.iter().map(|x| x * x).sum::<f32>().sqrt();
                    // NaN takes this branch, as in losses::transport_semantic.
                    if n.is_nan() || n > 1e-12 {
                        let sp = si.iter().zip(p).map(|(a, b)| a * b).sum::<f32>() / n;
                        for j in 0..d {
                            g[j] += -terms.l_uot * terms.cost_sem * (p[j] - sp * si[j] / n) / n;
                        }
                    }
                }
                // The trainer's Adam update, element by element.
                let (mr, vr) = (&mut m[r * d..(r + 1) * d], &mut v[r * d..(r + 1) * d]);
                for j in 0..d {
                    h.update(&mut si[j], &mut mr[j], &mut vr[j], g[j]);
                    nonfinite |= !si[j].is_finite();
                }
            }
            if nonfinite && bad.is_none() {
                bad = Some(k);
            }
        }
        (loss, bad)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::losses;

    /// The batch equals stepping: L_sem and L_uot into a gradient, then Adam, step by
    /// step, over rows that span several batches and plans that hold some of them.
    #[test]
    fn advancing_in_a_batch_is_bit_identical_to_stepping() {
        // d = 16 takes the copy with the row width fixed at compile time, d = 3 the other.
        for d in [3, 16] {
            batch_equals_stepping(d);
        }
    }

    fn batch_equals_stepping(d: usize) {
        let n = 2500;
        let s0: Vec<f32> = (0..n * d).map(|k| ((k as f32) * 0.37).sin()).collect();
        let z: Vec<f32> = (0..n * d).map(|k| ((k as f32) * 0.11).cos()).collect();
        let gamma: Vec<f32> = (0..n).map(|i| (i % 7) as f32 / 7.0).collect();
        let plan = |step: usize| {
            let idx: Vec<u32> = (0..n as u32).filter(|i| (i + step as u32).is_multiple_of(5)).collect();
            let y = (0..idx.len() * d).map(|k| ((k + step) as f32 * 0.7).sin() * 0.2).collect();
            let w = (0..idx.len()).map(|k| ((k + step) as f32 * 0.3).cos().abs()).collect();
            ViewTransport { idx, y, w, delta: 1e-3, ..Default::default() }
        };
        let plans = [plan(0), plan(1)];
        let terms =
            Terms { zbar: Some(&z), gamma: &gamma, plans: &plans, l_sem: 1.0, l_uot: 0.1, cost_sem: 1.5 };
        let (lr, b1, b2, eps) = (0.01f32, 0.9f32, 0.999f32, 1e-15f32);
        let views = [Some(0), None, Some(1), Some(0), Some(1)];

        let mut batched = s0.clone();
        let mut lat = Latents::default();
        for (k, &p) in views.iter().enumerate() {
            lat.record(k, p);
        }
        let loss = lat.advance(&mut batched, d, &terms, lr, (b1, b2, eps)).unwrap();

        let (mut s, mut m, mut v) = (s0, vec![0.0f32; n * d], vec![0.0f32; n * d]);
        for (k, &p) in views.iter().enumerate() {
            let mut g = vec![0.0f32; n * d];
            let l = losses::semantic(&s, &z, &gamma, d, 1.0, &mut g);
            assert!((l - loss[k].1).abs() <= 1e-5 * l.abs(), "step {k}: {l} vs {}", loss[k].1);
            if let Some(p) = p {
                let plan = &plans[p];
                let mut plan_e = vec![0.0f32; plan.idx.len() * d];
                for (k, row) in plan_e.chunks_mut(d).enumerate() {
                    plan.plan_row(k, row);
                }
                losses::transport_semantic(&s, &plan.idx, &plan_e, d, 1.5, 0.1, &mut g);
            }
            let t = k as i32 + 1;
            let (step_size, bc2) = (lr / (1.0 - b1.powi(t)), (1.0 - b2.powi(t)).sqrt());
            for j in 0..n * d {
                m[j] = b1 * m[j] + (1.0 - b1) * g[j];
                v[j] = b2 * v[j] + (1.0 - b2) * g[j] * g[j];
                s[j] -= step_size * m[j] / (v[j].sqrt() / bc2 + eps);
            }
        }
        let bits = |x: &[f32]| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&batched), bits(&s));
        assert_eq!((bits(&lat.m), bits(&lat.v), lat.step), (bits(&m), bits(&v), 5));
        assert_eq!(lat.pending(), 0);
    }

    #[test]
    fn a_non_finite_latent_names_its_step() {
        let z = vec![f32::INFINITY; 4];
        let terms =
            Terms { zbar: Some(&z), gamma: &[1.0, 1.0], plans: &[], l_sem: 1.0, l_uot: 0.0, cost_sem: 1.0 };
        let mut lat = Latents::default();
        lat.record(7, None);
        lat.record(8, None);
        let mut s = vec![0.5f32; 4];
        assert_eq!(lat.advance(&mut s, 2, &terms, 0.01, (0.9, 0.999, 1e-15)), Err(7));
    }
}

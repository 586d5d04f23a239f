//! The stabilised-scaling solver (docs/method.md#m4-the-uot-solver; paper eq. (5) / appendix "View-wise
//! Unbalanced Semantic Transport").
//!
//! # The iteration
//! With potentials f, g and kappa_s = tau_s/(tau_s+eps) (1 if tau_s = inf), one
//! Gauss–Seidel sweep is
//!
//! ```text
//! f_i = -kappa_s eps LSE_j( ln b_j + (g_j - C_ij)/eps )     (all i, using the old g)
//! g_j = -kappa_t eps LSE_i( ln a_i + (f_i - C_ij)/eps )     (all j, using the new f)
//! T_ij = a_i b_j exp((f_i + g_j - C_ij)/eps)
//! ```
//!
//! which is POT's `sinkhorn_knopp_unbalanced` (`reg_type="kl"`, reference `a b^T`) with
//! u = e^{f/eps}, v = e^{g/eps}: `u = (a / K v)^kappa_s`, `v = (b / K^T u)^kappa_t` with
//! `K = a b^T ⊙ e^{-C/eps}`.
//!
//! # Stabilised scaling
//! The kernel is stored once in `f32` relative to reference offsets (alpha_i, beta_j):
//! `K_ij = exp((alpha_i + beta_j - C_ij)/eps)`, with `alpha_i = min_j (C_ij - beta_j)`
//! so every row's largest entry is exactly 1 (no overflow; entries below e^-87 are
//! flushed to 0, never denormal). With g = beta + eps lv and f = kappa_s (alpha - eps q)
//! the two log-sum-exps become matrix–vector products:
//!
//! ```text
//! q_i   = ln sum_j K_ij (b_j e^{lv_j})                      (row pass, dot product)
//! lw_i  = ln a_i + (f_i - alpha_i)/eps = lc_i - kappa_s q_i,  lc_i = ln a_i - (1-kappa_s) alpha_i/eps
//! LSE'_j = ln sum_i e^{lw_i} K_ij - beta_j/eps               (same pass, axpy)
//! ```
//!
//! Both products read a kernel row once, so one sweep is one pass over the n x M kernel
//! (rayon over chunks of 256 rows; per-row logs/exps are vectorised over the chunk).
//! Scales never leave `f32` range: the column factor is shifted by its maximum and the
//! row weights by the chunk's maximum log-weight; chunk sums are combined in `f64`.
//!
//! When the column scalings drift (spread of lv over the live targets > 30) the kernel is
//! rebuilt around the current g ("absorption"; this is the only place with per-entry
//! exps). Where a product still underflows, that row (or column) is computed exactly by
//! log-sum-exp from the costs, and the kernel is rebuilt for the next sweep.
//!
//! Flushing an entry below e^-87 relative to its row maximum loses at most
//! e^{-87 + 30 + ln(b_max/b_min)} of that row's largest plan entry.
//!
//! Dense problems with m a multiple of 8 (up to 64; m = 32 in the paper) use explicit
//! AVX2 kernels (eight rows per step) when the CPU has AVX2 + FMA; other shapes use the
//! generic loops. `TRANSSPLAT_UOT_PROFILE=1` prints per-sweep timings to stderr.

#![allow(clippy::needless_range_loop)] // chunk loops index several parallel arrays

use crate::error::{Error, Result};
use crate::fastmath;
use crate::layout::{split_chunks, with_layout, DenseFixed, Layout};
use crate::problem::{Problem, Support};
use crate::solution::{finish, Potentials, Raw, Solution};
use crate::Params;
use rayon::prelude::*;
use transsplat_scene::cpu::has_avx2;

/// Engine rows per parallel chunk.
const CH: usize = 256;
/// Below this a row product (or column sum) is recomputed exactly.
const S_MIN: f32 = 1e-30;
/// Rebuild the kernel when max lv - min lv over live targets exceeds this.
const SPREAD: f64 = 30.0;

/// Per-row state of a chunk (struct of arrays). alpha_i: row reference offset (+inf
/// marks a row without any finite entry, f_i = +inf); lc_i = ln a_i - (1 - kappa_s)
/// alpha_i / eps; q_i with f_i = kappa_s (alpha_i - eps q_i).
struct RowsMut<'a> {
    alpha: &'a mut [f64],
    lc: &'a mut [f64],
    q: &'a mut [f64],
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Col {
    Live,
    /// b_j = 0: excluded (its plan column is 0, g_j reported as 0).
    ZeroMass,
    /// No source can send it mass: g_j = +inf, plan column 0.
    Dead,
}

/// Per-sweep constants.
struct Ctx<'c> {
    eps: f64,
    inv_eps: f64,
    ks: f64,
    a: &'c [f32],
    /// beta_j for live targets, -inf otherwise (so their kernel entries are 0).
    beta_eff: &'c [f64],
    /// b_j e^{lv_j - lv_shift} for live targets, 0 otherwise.
    cv: &'c [f32],
    /// ln b_j + lv_j for live targets, -inf otherwise.
    lnb_lv: &'c [f64],
    lv_shift: f64,
    rebuild: bool,
    final_pass: bool,
    /// Track max |Δq| (only needed with a tolerance).
    track: bool,
}

#[derive(Clone, Copy, Debug, Default)]
struct ChunkOut {
    /// Log shift of this chunk's column accumulators (-inf: nothing accumulated).
    w: f64,
    /// max |Δq| over the chunk.
    dq: f64,
    fallbacks: u32,
    /// Final pass: sum over rows of sum_j T_ij C_ij.
    lin: f64,
}

pub(crate) fn kappa(tau: f64, eps: f64) -> f64 {
    if tau.is_infinite() {
        1.0
    } else {
        tau / (tau + eps)
    }
}

/// Rebuilds one kernel row around the current beta; keeps f_i unchanged.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn rebuild_row<L: Layout>(
    l: &L,
    ctx: &Ctx,
    r: usize,
    lo: usize,
    k: &mut [f32],
    alpha: &mut f64,
    lc: &mut f64,
    q: &mut f64,
) {
    let costs = &l.costs()[lo..lo + k.len()];
    let f_old = ctx.ks * (*alpha - ctx.eps * *q);
    let mut amin = f64::INFINITY;
    for (e, &c) in costs.iter().enumerate() {
        let j = l.col(lo, lo + e);
        amin = amin.min(c as f64 - ctx.beta_eff[j]);
    }
    if amin == f64::INFINITY {
        k.fill(0.0);
        (*alpha, *lc, *q) = (f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
        return;
    }
    for (e, (kv, &c)) in k.iter_mut().zip(costs).enumerate() {
        let j = l.col(lo, lo + e);
        *kv = (((amin + ctx.beta_eff[j]) - c as f64) * ctx.inv_eps) as f32;
    }
    fastmath::exp_slice(k);
    let a = ctx.a[l.source(r)];
    let ln_a = if a > 1e-30 { fastmath::ln(a) as f64 } else { (a as f64).ln() };
    *lc = if a > 0.0 { ln_a - (1.0 - ctx.ks) * amin * ctx.inv_eps } else { f64::NEG_INFINITY };
    *q = if f_old.is_finite() {
        amin * ctx.inv_eps - f_old / (ctx.ks * ctx.eps)
    } else if f_old == f64::INFINITY {
        f64::NEG_INFINITY
    } else {
        0.0
    };
    *alpha = amin;
}

/// Exact q_i = ln sum_j b_j e^{lv_j} K_ij from the costs (log-sum-exp).
fn exact_row_q<L: Layout>(l: &L, ctx: &Ctx, lo: usize, hi: usize, alpha: f64) -> f64 {
    let costs = &l.costs()[lo..hi];
    let x = |e: usize, c: f32| {
        let j = l.col(lo, lo + e);
        ctx.lnb_lv[j] + ((alpha + ctx.beta_eff[j]) - c as f64) * ctx.inv_eps
    };
    let mx = costs.iter().enumerate().map(|(e, &c)| x(e, c)).fold(f64::NEG_INFINITY, f64::max);
    if !mx.is_finite() {
        return f64::NEG_INFINITY;
    }
    let s: f64 = costs.iter().enumerate().map(|(e, &c)| (x(e, c) - mx).exp()).sum();
    mx + s.ln()
}

/// One chunk of a sweep: (rebuild,) row products, row update, column accumulation.
/// In the final pass the rows are not updated; the row masses and the linear cost are
/// written instead. The common path is branch-free over the chunk; rows whose product
/// underflows are redone exactly afterwards.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn chunk_body<L: Layout>(
    l: &L,
    ctx: &Ctx,
    r0: usize,
    e0: usize,
    k: &mut [f32],
    rows: RowsMut,
    acc_out: &mut [f64],
    row_mass: &mut [f64],
) -> ChunkOut {
    let nr = rows.q.len();
    let mut out = ChunkOut { w: f64::NEG_INFINITY, ..Default::default() };
    let mut s_buf = [0f32; CH];
    let mut x_buf = [0f32; CH];
    let mut qn = [0f64; CH];
    let mut lw = [f64::NEG_INFINITY; CH];
    if ctx.rebuild {
        for rr in 0..nr {
            let (lo, hi) = l.range(r0 + rr);
            let kr = &mut k[lo - e0..hi - e0];
            rebuild_row(l, ctx, r0 + rr, lo, kr, &mut rows.alpha[rr], &mut rows.lc[rr], &mut rows.q[rr]);
        }
    }
    // Row products and their logs: q_i = lv_shift + ln sum_j K_ij cv_j.
    l.dots(r0, e0, k, ctx.cv, &mut s_buf[..nr]);
    let mut any_slow = false;
    for rr in 0..nr {
        any_slow |= s_buf[rr].is_nan() || s_buf[rr] <= S_MIN;
        x_buf[rr] = s_buf[rr].max(S_MIN);
    }
    fastmath::ln_slice(&mut x_buf[..nr]);
    for rr in 0..nr {
        qn[rr] = ctx.lv_shift + x_buf[rr] as f64;
    }
    if any_slow {
        for rr in 0..nr {
            if s_buf[rr] > S_MIN {
                continue;
            }
            if rows.alpha[rr] == f64::INFINITY {
                qn[rr] = f64::NEG_INFINITY;
                continue;
            }
            let (lo, hi) = l.range(r0 + rr);
            out.fallbacks += 1;
            qn[rr] = exact_row_q(l, ctx, lo, hi, rows.alpha[rr]);
            if qn[rr] == f64::NEG_INFINITY && !ctx.final_pass {
                // No live target reachable: f_i = +inf, the row carries nothing.
                rows.alpha[rr] = f64::INFINITY;
                rows.lc[rr] = f64::NEG_INFINITY;
            }
        }
    }
    if ctx.final_pass {
        for rr in 0..nr {
            let lwi = if rows.lc[rr] == f64::NEG_INFINITY {
                f64::NEG_INFINITY
            } else {
                rows.lc[rr] - ctx.ks * rows.q[rr]
            };
            lw[rr] = lwi;
            let x = lwi + qn[rr];
            row_mass[rr] = if x > -745.0 { x.exp() } else { 0.0 };
            if row_mass[rr] == 0.0 {
                continue;
            }
            // Linear cost sum_j T_ij C_ij with T_ij = e^{lw_i} K_ij b_j e^{lv_j}.
            let (lo, hi) = l.range(r0 + rr);
            let kr = &k[lo - e0..hi - e0];
            let costs = &l.costs()[lo..hi];
            out.lin += if s_buf[rr] > S_MIN {
                let mut t = 0.0f32;
                for (e, (kv, c)) in kr.iter().zip(costs).enumerate() {
                    // Select, not branch (vectorises); K = 0 where C = +inf.
                    let x = *kv * ctx.cv[l.col(lo, lo + e)] * *c;
                    t += if *kv != 0.0 { x } else { 0.0 };
                }
                (lwi + ctx.lv_shift).exp() * t as f64
            } else {
                let mut t = 0.0f64;
                for (e, c) in costs.iter().enumerate() {
                    let j = l.col(lo, lo + e);
                    let x =
                        lwi + ctx.lnb_lv[j] + ((rows.alpha[rr] + ctx.beta_eff[j]) - *c as f64) * ctx.inv_eps;
                    if x > -745.0 {
                        t += x.exp() * *c as f64;
                    }
                }
                t
            };
        }
    } else {
        if ctx.track {
            let mut dq = 0f64;
            for rr in 0..nr {
                let (a, b) = (qn[rr], rows.q[rr]);
                let d = if a.is_finite() && b.is_finite() { (a - b).abs() } else { 0.0 };
                dq = dq.max(d);
            }
            out.dq = dq;
        }
        for rr in 0..nr {
            rows.q[rr] = qn[rr];
            let lc = rows.lc[rr];
            lw[rr] = if lc == f64::NEG_INFINITY { f64::NEG_INFINITY } else { lc - ctx.ks * qn[rr] };
        }
    }
    // Column accumulation with a chunk-local shift.
    let w = lw[..nr].iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if w > f64::NEG_INFINITY {
        for rr in 0..nr {
            x_buf[rr] = (lw[rr] - w) as f32;
        }
        fastmath::exp_slice(&mut x_buf[..nr]);
        let m = l.m();
        let mut stack = [0f32; 64];
        let mut heap = Vec::new();
        let acc: &mut [f32] = if m <= 64 {
            &mut stack[..m]
        } else {
            heap.resize(m, 0f32);
            &mut heap
        };
        l.axpys(r0, e0, k, &x_buf[..nr], acc);
        for (o, a) in acc_out.iter_mut().zip(acc.iter()) {
            *o = *a as f64;
        }
        out.w = w;
    } else {
        acc_out.fill(0.0);
    }
    out
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn chunk_avx2<L: Layout>(
    l: &L,
    ctx: &Ctx,
    r0: usize,
    e0: usize,
    k: &mut [f32],
    rows: RowsMut,
    acc_out: &mut [f64],
    row_mass: &mut [f64],
) -> ChunkOut {
    chunk_body(l, ctx, r0, e0, k, rows, acc_out, row_mass)
}

#[allow(clippy::too_many_arguments)]
fn chunk_dispatch<L: Layout>(
    avx2: bool,
    l: &L,
    ctx: &Ctx,
    r0: usize,
    e0: usize,
    k: &mut [f32],
    rows: RowsMut,
    acc_out: &mut [f64],
    row_mass: &mut [f64],
) -> ChunkOut {
    #[cfg(target_arch = "x86_64")]
    if avx2 {
        // SAFETY: the CPU supports AVX2 and FMA (checked at runtime by the caller).
        return unsafe { chunk_avx2(l, ctx, r0, e0, k, rows, acc_out, row_mass) };
    }
    let _ = avx2;
    chunk_body(l, ctx, r0, e0, k, rows, acc_out, row_mass)
}

struct Engine<'p, L: Layout> {
    l: L,
    a: &'p [f32],
    b: &'p [f32],
    eps: f64,
    ks: f64,
    kt: f64,
    kernel: Vec<f32>,
    alpha: Vec<f64>,
    lc: Vec<f64>,
    q: Vec<f64>,
    beta: Vec<f64>,
    lv: Vec<f64>,
    col: Vec<Col>,
    /// LSE'_j of the last column update (ln sum_i a_i e^{(f_i - C_ij)/eps}).
    lse_col: Vec<f64>,
    rebuild: bool,
    avx2: bool,
    track: bool,
    rebuilds: usize,
    fallbacks: usize,
    /// Scratch: per-chunk column accumulators, row masses.
    acc: Vec<f64>,
    row_mass: Vec<f64>,
}

struct PassOut {
    /// Column log-sums ln sum_i e^{lw_i} K_ij (-inf when nothing reached j).
    col_log: Vec<f64>,
    dq: f64,
    lin: f64,
}

impl<'p, L: Layout> Engine<'p, L> {
    fn new(l: L, p: &Problem<'p>, params: &Params, ws: &mut Workspace) -> Self {
        let (n_rows, m) = (l.rows(), l.m());
        let nnz = if n_rows == 0 { 0 } else { l.range(n_rows - 1).1 };
        let eps = params.eps;
        let ks = kappa(params.tau_s, eps);
        let kt = kappa(params.tau_t, eps);
        let (f0, g0): (Option<&[f64]>, Option<&[f64]>) = match &params.warm_start {
            Some(w) => (Some(&w.f), Some(&w.g)),
            None => (None, None),
        };
        let mut q = take_len(&mut ws.q, n_rows);
        q.par_iter_mut().enumerate().for_each(|(r, q)| {
            let f = f0.map(|f| f[l.source(r)]).unwrap_or(0.0);
            let f = if f.is_finite() { f } else { 0.0 };
            *q = -f / (ks * eps);
        });
        let beta: Vec<f64> = (0..m)
            .map(|j| {
                let g = g0.map(|g| g[j]).unwrap_or(0.0);
                if g.is_finite() {
                    g
                } else {
                    0.0
                }
            })
            .collect();
        let col = p.b.iter().map(|&b| if b > 0.0 { Col::Live } else { Col::ZeroMass }).collect();
        let n_chunks = n_rows.div_ceil(CH);
        Engine {
            l,
            a: p.a,
            b: p.b,
            eps,
            ks,
            kt,
            kernel: take_len(&mut ws.kernel, nnz),
            alpha: take_len(&mut ws.alpha, n_rows),
            lc: take_len(&mut ws.lc, n_rows),
            q,
            beta,
            lv: vec![0.0; m],
            col,
            lse_col: vec![f64::NEG_INFINITY; m],
            rebuild: true,
            avx2: has_avx2(),
            track: params.tol.is_some(),
            rebuilds: 0,
            fallbacks: 0,
            acc: take_len(&mut ws.acc, n_chunks * m),
            row_mass: take_len(&mut ws.row_mass, n_rows),
        }
    }

    /// One pass over the kernel (a sweep's f-update and column sums, or the final pass).
    fn pass(&mut self, final_pass: bool) -> PassOut {
        let m = self.l.m();
        let live = |j: usize| self.col[j] == Col::Live;
        let beta_eff: Vec<f64> =
            (0..m).map(|j| if live(j) { self.beta[j] } else { f64::NEG_INFINITY }).collect();
        let lnb_lv: Vec<f64> = (0..m)
            .map(|j| if live(j) { (self.b[j] as f64).ln() + self.lv[j] } else { f64::NEG_INFINITY })
            .collect();
        let lv_shift = lnb_lv.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let cv: Vec<f32> = lnb_lv
            .iter()
            .map(|&x| {
                let y = x - lv_shift;
                if y > -87.0 {
                    y.exp() as f32
                } else {
                    0.0
                }
            })
            .collect();
        let ctx = Ctx {
            eps: self.eps,
            inv_eps: 1.0 / self.eps,
            ks: self.ks,
            a: self.a,
            beta_eff: &beta_eff,
            cv: &cv,
            lnb_lv: &lnb_lv,
            lv_shift: if lv_shift.is_finite() { lv_shift } else { 0.0 },
            rebuild: self.rebuild,
            final_pass,
            track: self.track,
        };
        if self.rebuild {
            self.rebuilds += 1;
        }
        self.rebuild = false;
        let avx2 = self.avx2;
        let l = &self.l;
        let chunks = split_chunks(l, CH, &mut self.kernel);
        let outs: Vec<ChunkOut> = chunks
            .into_par_iter()
            .zip(self.alpha.par_chunks_mut(CH))
            .zip(self.lc.par_chunks_mut(CH))
            .zip(self.q.par_chunks_mut(CH))
            .zip(self.acc.par_chunks_mut(m.max(1)))
            .zip(self.row_mass.par_chunks_mut(CH))
            .map(|((((((r0, e0, k), alpha), lc), q), acc), rm)| {
                chunk_dispatch(avx2, l, &ctx, r0, e0, k, RowsMut { alpha, lc, q }, acc, rm)
            })
            .collect();
        // Deterministic combination in chunk order.
        let w = outs.iter().map(|o| o.w).fold(f64::NEG_INFINITY, f64::max);
        let mut tot = vec![0f64; m];
        let mut dq = 0f64;
        let mut lin = 0f64;
        for (ci, o) in outs.iter().enumerate() {
            dq = dq.max(o.dq);
            lin += o.lin;
            self.fallbacks += o.fallbacks as usize;
            if o.w > f64::NEG_INFINITY {
                let s = (o.w - w).exp();
                for (t, x) in tot.iter_mut().zip(&self.acc[ci * m..(ci + 1) * m]) {
                    *t += s * x;
                }
            }
        }
        if outs.iter().any(|o| o.fallbacks > 0) {
            self.rebuild = true;
        }
        let mut col_log = vec![f64::NEG_INFINITY; m];
        for j in 0..m {
            if self.col[j] != Col::Live {
                continue;
            }
            col_log[j] = if tot[j] > 1e-30 {
                w + tot[j].ln()
            } else {
                self.fallbacks += 1;
                self.rebuild = true;
                self.exact_col_log(j, &beta_eff)
            };
        }
        PassOut { col_log, dq, lin }
    }

    /// Exact ln sum_i e^{lw_i} K_ij = ln sum_i e^{lw_i + (alpha_i + beta_j - C_ij)/eps}.
    fn exact_col_log(&self, j: usize, beta_eff: &[f64]) -> f64 {
        let l = &self.l;
        let inv_eps = 1.0 / self.eps;
        let x = |r: usize| -> f64 {
            if self.alpha[r] == f64::INFINITY || self.lc[r] == f64::NEG_INFINITY {
                return f64::NEG_INFINITY;
            }
            let (lo, hi) = l.range(r);
            match l.find(lo, hi, j) {
                Some(e) => {
                    let lw = self.lc[r] - self.ks * self.q[r];
                    lw + ((self.alpha[r] + beta_eff[j]) - l.costs()[e] as f64) * inv_eps
                }
                None => f64::NEG_INFINITY,
            }
        };
        let n = l.rows();
        let mx = (0..n).into_par_iter().map(x).reduce(|| f64::NEG_INFINITY, f64::max);
        if !mx.is_finite() {
            return f64::NEG_INFINITY;
        }
        let s: f64 = crate::det_chunks(n, 8192, |range| range.map(|r| (x(r) - mx).exp()).sum::<f64>())
            .into_iter()
            .sum();
        mx + s.ln()
    }

    /// Column update from a sweep's column sums: g_j = -kappa_t eps LSE'_j.
    /// Returns max |Δg|.
    fn update_cols(&mut self, col_log: &[f64]) -> f64 {
        let m = self.l.m();
        let mut dg = 0f64;
        for j in 0..m {
            if self.col[j] != Col::Live {
                continue;
            }
            let lse = col_log[j] - self.beta[j] / self.eps;
            self.lse_col[j] = lse;
            if lse == f64::NEG_INFINITY {
                self.col[j] = Col::Dead;
                continue;
            }
            let g_old = self.beta[j] + self.eps * self.lv[j];
            let g = -self.kt * self.eps * lse;
            dg = dg.max((g - g_old).abs());
            self.lv[j] = (g - self.beta[j]) / self.eps;
        }
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for j in 0..m {
            if self.col[j] == Col::Live {
                lo = lo.min(self.lv[j]);
                hi = hi.max(self.lv[j]);
            }
        }
        if hi - lo > SPREAD || self.rebuild {
            self.absorb();
        }
        dg
    }

    /// Moves the column scalings into beta and schedules a kernel rebuild.
    fn absorb(&mut self) {
        for j in 0..self.l.m() {
            if self.col[j] == Col::Live {
                self.beta[j] += self.eps * self.lv[j];
                self.lv[j] = 0.0;
            }
        }
        self.rebuild = true;
    }

    fn g(&self) -> Vec<f64> {
        (0..self.l.m())
            .map(|j| match self.col[j] {
                Col::Live => self.beta[j] + self.eps * self.lv[j],
                Col::ZeroMass => 0.0,
                Col::Dead => f64::INFINITY,
            })
            .collect()
    }
}

/// Solves with the stabilised-scaling engine (see the module docs).
/// Buffers of the stabilised-scaling solver (the kernel is n x m `f32`), kept between
/// solves so that repeated solves (every view, every transport round) do not pay for
/// fresh memory: first-touch page faults on a 128 MB kernel cost more than the 30
/// sweeps themselves. One workspace per thread of concurrent solves.
#[derive(Debug, Default)]
pub struct Workspace {
    kernel: Vec<f32>,
    alpha: Vec<f64>,
    lc: Vec<f64>,
    q: Vec<f64>,
    acc: Vec<f64>,
    row_mass: Vec<f64>,
}

impl Workspace {
    /// An empty workspace (grows on first use).
    pub fn new() -> Self {
        Self::default()
    }

    /// Bytes currently held.
    pub fn bytes(&self) -> usize {
        self.kernel.capacity() * 4
            + 8 * (self.alpha.capacity()
                + self.lc.capacity()
                + self.q.capacity()
                + self.acc.capacity()
                + self.row_mass.capacity())
    }
}

/// Takes `v` out of the workspace with length `len`. Existing contents are kept (every
/// buffer is fully written before it is read), so reuse does not touch memory.
fn take_len<T: Copy + Default>(v: &mut Vec<T>, len: usize) -> Vec<T> {
    let mut v = std::mem::take(v);
    if v.len() >= len {
        v.truncate(len);
    } else {
        v.resize(len, T::default());
    }
    v
}

pub(crate) fn solve_scaling(p: &Problem<'_>, params: &Params, ws: &mut Workspace) -> Result<Solution> {
    if let Support::Dense(cost) = &p.support {
        let n = p.n();
        macro_rules! fixed {
            ($($nb:literal)*) => {
                match p.m() {
                    $(m if m == 8 * $nb => return run(DenseFixed::<$nb> { cost, n, avx2: has_avx2() }, p, params, ws),)*
                    _ => {}
                }
            };
        }
        fixed!(1 2 3 4 5 6 7 8);
    }
    with_layout!(p, l => run(l, p, params, ws))
}

fn run<L: Layout>(l: L, p: &Problem<'_>, params: &Params, ws: &mut Workspace) -> Result<Solution> {
    let n = p.n();
    let m = p.m();
    let prof = std::env::var_os("TRANSSPLAT_UOT_PROFILE").is_some();
    let t0 = std::time::Instant::now();
    let mut e = Engine::new(l, p, params, ws);
    if prof {
        eprintln!("uot-profile: setup {:.2} ms", t0.elapsed().as_secs_f64() * 1e3);
    }
    let mut iterations = 0;
    let mut converged = false;
    let mut last_change = f64::INFINITY;
    for it in 0..params.max_iters {
        let t1 = std::time::Instant::now();
        let rebuilding = e.rebuild;
        let out = e.pass(false);
        if prof {
            eprintln!(
                "uot-profile: sweep {it} pass {:.2} ms rebuild {rebuilding}",
                t1.elapsed().as_secs_f64() * 1e3
            );
        }
        let df = e.ks * e.eps * out.dq;
        let dg = e.update_cols(&out.col_log);
        iterations = it + 1;
        last_change = df.max(dg) / e.eps;
        if let Some(tol) = params.tol {
            if last_change <= tol {
                converged = true;
                break;
            }
        }
    }
    let fin = e.pass(true);
    // Column masses c_j = b_j e^{lv_j} sum_i e^{lw_i} K_ij.
    let col_mass: Vec<f64> = (0..m)
        .map(|j| {
            if e.col[j] != Col::Live || fin.col_log[j] == f64::NEG_INFINITY {
                0.0
            } else {
                ((e.b[j] as f64).ln() + e.lv[j] + fin.col_log[j]).exp()
            }
        })
        .collect();
    let g = e.g();
    let mut f = vec![f64::INFINITY; n];
    let mut row_mass = vec![0f64; n];
    for r in 0..e.l.rows() {
        let i = e.l.source(r);
        f[i] = if e.alpha[r] == f64::INFINITY { f64::INFINITY } else { e.ks * (e.alpha[r] - e.eps * e.q[r]) };
        row_mass[i] = e.row_mass[r];
    }
    // Hand the buffers back for the next solve.
    ws.kernel = std::mem::take(&mut e.kernel);
    ws.alpha = std::mem::take(&mut e.alpha);
    ws.lc = std::mem::take(&mut e.lc);
    ws.q = std::mem::take(&mut e.q);
    ws.acc = std::mem::take(&mut e.acc);
    ws.row_mass = std::mem::take(&mut e.row_mass);
    let raw = Raw {
        potentials: Potentials { f, g },
        row_mass,
        col_mass,
        transport_cost: fin.lin,
        iterations,
        converged,
        last_change,
        rebuilds: e.rebuilds,
        fallbacks: e.fallbacks,
    };
    Ok(finish(p, params, raw))
}

/// Checks that hard marginals can be met (every positive mass on a hard side has a
/// finite-cost entry to some positive mass on the other side) and balanced totals.
pub(crate) fn check_feasible(p: &Problem<'_>, params: &Params) -> Result<()> {
    let hard_s = params.tau_s.is_infinite();
    let hard_t = params.tau_t.is_infinite();
    if !hard_s && !hard_t {
        return Ok(());
    }
    let sa: f64 = p.a.iter().map(|&x| x as f64).sum();
    let sb: f64 = p.b.iter().map(|&x| x as f64).sum();
    if hard_s && hard_t && (sa - sb).abs() > 1e-4 * sa.max(sb) {
        return Err(Error::MassMismatch { a: sa, b: sb });
    }
    with_layout!(p, l => {
        let m = l.m();
        // Rows: any finite entry to a positive-mass target; columns: reached by a
        // positive-mass source.
        let per_row = |r: usize| -> (bool, Vec<bool>) {
            let (lo, hi) = l.range(r);
            let ai = p.a[l.source(r)] > 0.0;
            let mut ok = false;
            let mut reach = vec![false; if ai { m } else { 0 }];
            for e in lo..hi {
                if l.costs()[e].is_finite() {
                    let j = l.col(lo, e);
                    ok |= p.b[j] > 0.0;
                    if ai {
                        reach[j] = true;
                    }
                }
            }
            (ok, reach)
        };
        let rows = l.rows();
        let (bad_row, reach) = (0..rows)
            .into_par_iter()
            .fold(
                || (None::<usize>, vec![false; m]),
                |(bad, mut reach), r| {
                    let (ok, rr) = per_row(r);
                    for (x, y) in reach.iter_mut().zip(&rr) {
                        *x |= *y;
                    }
                    let i = l.source(r);
                    let bad = if bad.is_none() && hard_s && !ok && p.a[i] > 0.0 { Some(i) } else { bad };
                    (bad, reach)
                },
            )
            .reduce(
                || (None, vec![false; m]),
                |x, y| {
                    let bad = match (x.0, y.0) {
                        (Some(a), Some(b)) => Some(a.min(b)),
                        (a, b) => a.or(b),
                    };
                    (bad, x.1.iter().zip(&y.1).map(|(a, b)| *a || *b).collect())
                },
            );
        if hard_s {
            // Sources without any entry (sparse support) also count.
            let mut has_row = vec![false; p.n()];
            for r in 0..rows {
                has_row[l.source(r)] = true;
            }
            let missing = (0..p.n()).find(|&i| !has_row[i] && p.a[i] > 0.0);
            let bad = match (bad_row, missing) {
                (Some(x), Some(y)) => Some(x.min(y)),
                (x, y) => x.or(y),
            };
            if let Some(i) = bad {
                return Err(Error::Infeasible {
                    side: "s",
                    which: "source",
                    index: i,
                    mass: p.a[i],
                    other: "target",
                });
            }
        }
        if hard_t {
            if let Some(j) = (0..m).find(|&j| p.b[j] > 0.0 && !reach[j]) {
                return Err(Error::Infeasible {
                    side: "t",
                    which: "target",
                    index: j,
                    mass: p.b[j],
                    other: "source",
                });
            }
        }
        Ok(())
    })
}

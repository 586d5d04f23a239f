//! The result of a solve: potentials, marginals, primal / dual values, and the plan
//! and plan-derived quantities recomputed on demand from the potentials (no dense
//! plan is kept).

use crate::fastmath;
use crate::layout::{with_layout, Layout};
use crate::problem::{Problem, Support};
use crate::Params;
use rayon::prelude::*;

/// Dual potentials: the plan is `T_ij = a_i b_j exp((f_i + g_j - C_ij)/eps)`.
/// A source with no finite-cost entry to a positive-mass target has f_i = +inf (its row
/// is empty); likewise g_j = +inf. Targets with b_j = 0 are left out of the iteration
/// and report g_j = 0. POT's `log["logu"]`, `log["logv"]` are f/eps, g/eps.
#[derive(Clone, Debug, PartialEq)]
pub struct Potentials {
    pub f: Vec<f64>,
    pub g: Vec<f64>,
}

/// Scalar results of a solve.
#[derive(Clone, Debug, PartialEq)]
pub struct Stats {
    /// Primal objective at the returned plan with generalised KL (paper eq. (5)):
    /// `<C,T> + eps KL(T||a b^T) + tau_s KL(T1||a) + tau_t KL(T^T 1||b)`,
    /// `KL(p||q) = sum p ln(p/q) - p + q`. A marginal term with tau = inf is left out
    /// (see [`Stats::source_error`] / [`Stats::target_error`] for how well it holds).
    pub objective: f64,
    /// Dual value at the returned potentials:
    /// `sum_i a_i phi_s(f_i) + sum_j b_j phi_t(g_j) - eps (sum T - sum a sum b)`,
    /// `phi(x) = tau (1 - e^{-x/tau})`, or `x` when tau = inf.
    pub dual: f64,
    /// `objective - dual` (>= 0 up to rounding when both taus are finite; 0 at the
    /// optimum, Proposition 1).
    pub gap: f64,
    /// `<C,T>` alone (POT's `log["cost"]`).
    pub transport_cost: f64,
    /// `sum_ij T_ij`.
    pub transported_mass: f64,
    /// `sum_i |(T1)_i - a_i|`.
    pub source_error: f64,
    /// `sum_j |(T^T 1)_j - b_j|`.
    pub target_error: f64,
    /// Sweeps run.
    pub iterations: usize,
    /// True if a tolerance was given and met.
    pub converged: bool,
    /// max(|Δf|, |Δg|)/eps in the last sweep (the change of ln u, ln v); inf if none ran.
    pub last_change: f64,
    /// Kernel (re)builds, including the first.
    pub rebuilds: usize,
    /// Rows or columns recomputed by exact log-sum-exp.
    pub fallbacks: usize,
}

/// What a solver hands to [`finish`].
pub(crate) struct Raw {
    pub potentials: Potentials,
    pub row_mass: Vec<f64>,
    pub col_mass: Vec<f64>,
    pub transport_cost: f64,
    pub iterations: usize,
    pub converged: bool,
    pub last_change: f64,
    pub rebuilds: usize,
    pub fallbacks: usize,
}

/// Solution of one transport problem.
#[derive(Clone, Debug)]
pub struct Solution {
    pub potentials: Potentials,
    /// Transported mass per source, `w_i = sum_j T_ij` (paper eq. for w_i^v).
    pub row_mass: Vec<f64>,
    /// Received mass per target, `sum_i T_ij`.
    pub col_mass: Vec<f64>,
    pub stats: Stats,
    /// eps the problem was solved with (needed to rebuild plan entries).
    pub eps: f64,
}

fn kl(p: f64, q: f64) -> f64 {
    if p <= 0.0 {
        q
    } else {
        p * (p / q).ln() - p + q
    }
}

fn phi(x: f64, tau: f64) -> f64 {
    if tau.is_infinite() {
        x
    } else {
        -tau * (-x / tau).exp_m1()
    }
}

/// Objective, dual and marginal errors from potentials and marginals. Uses
/// `<C,T> + eps KL(T||ab^T) = sum_i f_i r_i + sum_j g_j c_j - eps sum T + eps |a||b|`,
/// valid because T has the Gibbs form of the potentials.
pub(crate) fn finish(p: &Problem<'_>, params: &Params, raw: Raw) -> Solution {
    let eps = params.eps;
    let (a, b) = (p.a, p.b);
    let f = &raw.potentials.f;
    let g = &raw.potentials.g;
    let sa: f64 = a.iter().map(|&x| x as f64).sum();
    let sb: f64 = b.iter().map(|&x| x as f64).sum();
    // Per-source sums in parallel over fixed chunks, combined in order, so the result
    // does not depend on thread scheduling: (f r, mass, KL(r|a), |r - a|, dual term).
    let (fr, mass, kl_s, err_s, dual_s) = crate::det_chunks(a.len(), 8192, |range| {
        let mut acc = (0.0, 0.0, 0.0, 0.0, 0.0);
        for i in range {
            let (r, ai) = (raw.row_mass[i], a[i] as f64);
            acc.0 += if r > 0.0 { f[i] * r } else { 0.0 };
            acc.1 += r;
            acc.2 += kl(r, ai);
            acc.3 += (r - ai).abs();
            acc.4 += if ai > 0.0 { ai * phi(f[i], params.tau_s) } else { 0.0 };
        }
        acc
    })
    .into_iter()
    .fold((0.0, 0.0, 0.0, 0.0, 0.0), |x, y| (x.0 + y.0, x.1 + y.1, x.2 + y.2, x.3 + y.3, x.4 + y.4));
    let mut gc = 0.0;
    let mut kl_t = 0.0;
    let mut err_t = 0.0;
    let mut dual_t = 0.0;
    for j in 0..b.len() {
        let (c, bj) = (raw.col_mass[j], b[j] as f64);
        if c > 0.0 {
            gc += g[j] * c;
        }
        kl_t += kl(c, bj);
        err_t += (c - bj).abs();
        if bj > 0.0 {
            dual_t += bj * phi(g[j], params.tau_t);
        }
    }
    let ref_mass = sa * sb;
    let mut objective = fr + gc - eps * mass + eps * ref_mass;
    if params.tau_s.is_finite() {
        objective += params.tau_s * kl_s;
    }
    if params.tau_t.is_finite() {
        objective += params.tau_t * kl_t;
    }
    let dual = dual_s + dual_t - eps * (mass - ref_mass);
    Solution {
        stats: Stats {
            objective,
            dual,
            gap: objective - dual,
            transport_cost: raw.transport_cost,
            transported_mass: mass,
            source_error: err_s,
            target_error: err_t,
            iterations: raw.iterations,
            converged: raw.converged,
            last_change: raw.last_change,
            rebuilds: raw.rebuilds,
            fallbacks: raw.fallbacks,
        },
        potentials: raw.potentials,
        row_mass: raw.row_mass,
        col_mass: raw.col_mass,
        eps,
    }
}

impl Solution {
    /// The solution of a problem with no mass on one side: an empty plan. The objective
    /// keeps the finite-tau marginal terms (`tau KL(0||x) = tau sum x`).
    pub(crate) fn empty(p: &Problem<'_>, params: &Params) -> Solution {
        let raw = Raw {
            potentials: Potentials { f: vec![0.0; p.n()], g: vec![0.0; p.m()] },
            row_mass: vec![0.0; p.n()],
            col_mass: vec![0.0; p.m()],
            transport_cost: 0.0,
            iterations: 0,
            converged: true,
            last_change: 0.0,
            rebuilds: 0,
            fallbacks: 0,
        };
        let mut s = finish(p, params, raw);
        // The dual supremum equals the primal here (potentials at +inf on the side
        // that has mass); report no gap rather than the value at f = g = 0.
        s.stats.dual = s.stats.objective;
        s.stats.gap = 0.0;
        s
    }

    /// The plan entries of engine row `r` (source i, masses `a`, `ln_b` = ln b),
    /// `T_ij = a_i b_j exp((f_i + g_j - C_ij)/eps)` (0 if any factor is 0 or the
    /// exponent is below -87), into `out`: the exponents in `f64`, then the branch-free
    /// [`fastmath::exp`] over the whole buffer, which vectorises; the values are those of
    /// the per-entry formula bit for bit.
    #[inline(always)]
    fn row_plan<L: Layout>(&self, l: &L, r: usize, a: &[f32], ln_b: &[f64], out: &mut Vec<f32>) {
        let ((lo, hi), i) = (l.range(r), l.source(r));
        let ln_a = (a[i] as f64).ln();
        let (fi, g, c) = (self.potentials.f[i], &self.potentials.g, &l.costs()[lo..hi]);
        out.clear();
        out.extend(c.iter().enumerate().map(|(k, &cij)| {
            let j = l.col(lo, lo + k);
            let x = ln_a + ln_b[j] + ((fi + g[j]) - cij as f64) / self.eps;
            if x > -87.0 {
                x as f32
            } else {
                f32::NEG_INFINITY
            }
        }));
        fastmath::exp_slice(out);
    }

    /// Calls `visit(i, cols_and_values)` for every source row with a nonzero support,
    /// in parallel; `buf` holds the row's plan entries aligned with its support entries.
    fn for_rows<F>(&self, p: &Problem<'_>, visit: F)
    where
        F: Fn(usize, usize, &[f32]) + Sync,
    {
        let ln_b: Vec<f64> = p.b.iter().map(|&x| (x as f64).ln()).collect();
        with_layout!(p, l => {
            (0..l.rows()).into_par_iter().for_each_init(Vec::new, |buf: &mut Vec<f32>, r| {
                self.row_plan(&l, r, p.a, &ln_b, buf);
                visit(r, l.range(r).0, buf);
            })
        })
    }

    /// The dense `n x m` plan (row-major), zeros outside a sparse support.
    pub fn dense_plan(&self, p: &Problem<'_>) -> Vec<f32> {
        let m = p.m();
        let mut out = vec![0f32; p.n() * m];
        match &p.support {
            Support::Dense(cost) => {
                let ln_b: Vec<f64> = p.b.iter().map(|&x| (x as f64).ln()).collect();
                let l = crate::layout::Dense { cost, n: p.n(), m };
                out.par_chunks_mut(m.max(1)).enumerate().for_each_init(Vec::new, |buf, (i, row)| {
                    self.row_plan(&l, i, p.a, &ln_b, buf);
                    row.copy_from_slice(buf);
                });
            }
            Support::Sparse(s) => {
                for ((i, j, _), t) in s.iter().zip(self.sparse_plan(p)) {
                    out[i * m + j] = t;
                }
            }
        }
        out
    }

    /// The plan on the problem's support: for a sparse problem one value per support
    /// entry in [`crate::SparseCost::iter`] order; for a dense problem the dense plan.
    pub fn sparse_plan(&self, p: &Problem<'_>) -> Vec<f32> {
        match &p.support {
            Support::Dense(_) => self.dense_plan(p),
            Support::Sparse(s) => {
                let out: Vec<std::sync::atomic::AtomicU32> =
                    (0..s.nnz()).map(|_| std::sync::atomic::AtomicU32::new(0)).collect();
                self.for_rows(p, |_, lo, vals| {
                    for (k, v) in vals.iter().enumerate() {
                        out[lo + k].store(v.to_bits(), std::sync::atomic::Ordering::Relaxed);
                    }
                });
                out.into_iter().map(|x| f32::from_bits(x.into_inner())).collect()
            }
        }
    }

    /// Gradient of the optimal objective with respect to the cost, in the layout of
    /// [`Solution::sparse_plan`]. By the envelope theorem (the objective is minimised
    /// over T and linear in C) it is the optimal plan T* itself; the edit engine pushes
    /// it through the cost's dependence on the semantic latents (docs/method.md#m7-losses).
    pub fn cost_gradient(&self, p: &Problem<'_>) -> Vec<f32> {
        self.sparse_plan(p)
    }

    /// Plan-weighted means of target vectors and transported masses, without a dense
    /// plan (paper eq. for y_i^v and w_i^v):
    /// `y_i = sum_j T_ij e_j / (sum_j T_ij + delta)`, `w_i = sum_j T_ij`.
    /// `targets` is row-major `m x d`. Returns `(y: n x d, w: n)`.
    pub fn target_means(
        &self,
        p: &Problem<'_>,
        targets: &[f32],
        d: usize,
        delta: f32,
    ) -> (Vec<f32>, Vec<f32>) {
        let (n, m) = (p.n(), p.m());
        assert_eq!(targets.len(), m * d, "targets must be m x d");
        let ln_b: Vec<f64> = p.b.iter().map(|&x| (x as f64).ln()).collect();
        let avx2 = transsplat_scene::cpu::has_avx2();
        with_layout!(p, l => {
            // Per engine row (= per source when dense), then scattered to sources.
            let rows = l.rows();
            // d = 0 still fills w: one padding value per row, dropped below.
            let mut y = vec![0f32; rows * d.max(1)];
            let mut w = vec![0f32; rows];
            const CHUNK: usize = 64;
            y.par_chunks_mut(CHUNK * d.max(1)).zip(w.par_chunks_mut(CHUNK)).enumerate().for_each_init(
                Vec::new,
                |buf, (c, (yc, wc))| {
                    let rows = MeansRows { l: &l, a: p.a, ln_b: &ln_b, targets, d, delta };
                    #[cfg(target_arch = "x86_64")]
                    if avx2 {
                        // SAFETY: AVX2 and FMA detected at run time.
                        return unsafe { rows.run_avx2(self, c * CHUNK, yc, wc, buf) };
                    }
                    rows.run(self, c * CHUNK, yc, wc, buf)
                },
            );
            y.truncate(rows * d);
            if rows == n && (0..rows.min(1)).all(|r| l.source(r) == r) && crate::layout::is_dense(p) {
                (y, w)
            } else {
                let mut ys = vec![0f32; n * d];
                let mut ws = vec![0f32; n];
                for r in 0..rows {
                    let i = l.source(r);
                    ws[i] = w[r];
                    ys[i * d..(i + 1) * d].copy_from_slice(&y[r * d..(r + 1) * d]);
                }
                (ys, ws)
            }
        })
    }
}

/// [`Solution::target_means`] over a chunk of engine rows.
struct MeansRows<'a, L> {
    l: &'a L,
    a: &'a [f32],
    ln_b: &'a [f64],
    targets: &'a [f32],
    d: usize,
    delta: f32,
}

impl<L: Layout> MeansRows<'_, L> {
    /// Rows `r0..r0 + w.len()`: `w_r = sum_j T_rj`, `y_r = sum_j T_rj e_j / (w_r + delta)`
    /// (entries in column order, zero entries skipped).
    #[inline(always)]
    fn run(&self, sol: &Solution, r0: usize, y: &mut [f32], w: &mut [f32], buf: &mut Vec<f32>) {
        let d = self.d;
        for (rr, wi) in w.iter_mut().enumerate() {
            let lo = self.l.range(r0 + rr).0;
            sol.row_plan(self.l, r0 + rr, self.a, self.ln_b, buf);
            let yi = &mut y[rr * d..(rr + 1) * d];
            let mut sum = 0f32;
            for &t in buf.iter() {
                if t > 0.0 {
                    sum += t;
                }
            }
            // Eight components at a time in a register, summed over the entries in order.
            for (c0, yc) in (0..d).step_by(8).zip(yi.chunks_mut(8)) {
                let mut acc = [0f32; 8];
                for (k, &t) in buf.iter().enumerate() {
                    if t > 0.0 {
                        let j = self.l.col(lo, lo + k);
                        let e = &self.targets[j * d + c0..j * d + c0 + yc.len()];
                        if let Ok(e) = <&[f32; 8]>::try_from(e) {
                            for l in 0..8 {
                                acc[l] += e[l] * t;
                            }
                        } else {
                            for (a, &x) in acc.iter_mut().zip(e) {
                                *a += x * t;
                            }
                        }
                    }
                }
                yc.copy_from_slice(&acc[..yc.len()]);
            }
            let den = sum + self.delta;
            if den > 0.0 {
                for v in yi.iter_mut() {
                    *v /= den;
                }
            }
            *wi = sum;
        }
    }

    /// [`Self::run`] compiled for AVX2 (the same operations, no fused multiply-adds, so
    /// the same values).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn run_avx2(&self, sol: &Solution, r0: usize, y: &mut [f32], w: &mut [f32], buf: &mut Vec<f32>) {
        self.run(sol, r0, y, w, buf)
    }
}

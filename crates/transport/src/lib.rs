//! Entropic unbalanced optimal transport, the view-wise solver of TransSplat (paper
//! Sec. 3.3, eq. (5); appendix "View-wise Unbalanced Semantic Transport"; docs/method.md#m4-the-uot-solver).
//! Knows nothing about Gaussians: n sources with masses `a`, m targets with masses `b`,
//! a cost `C` (dense, top-k or any sparse support) and
//!
//! ```text
//! T* = argmin_{T >= 0} <C,T> + eps KL(T || a b^T) + tau_s KL(T1 || a) + tau_t KL(T^T 1 || b)
//! ```
//!
//! with the generalised KL `sum p ln(p/q) - p + q`; `tau = inf` makes that marginal hard.
//! The iteration is the Gauss–Seidel log-domain fixed point (f, then g) and matches
//! POT's `ot.unbalanced.sinkhorn_unbalanced(a, b, C, reg=eps, reg_m=(tau_s, tau_t),
//! reg_type="kl")` iterate for iterate; it runs as stabilised scaling on an `f32` kernel
//! ([`engine`](crate) docs in `src/engine.rs`), one pass over the kernel per sweep.
//!
//! ```
//! use transsplat_transport::{solve, Params, Problem};
//! let a = [0.5f32, 0.5];
//! let b = [0.5f32, 0.5];
//! let c = [0.0f32, 1.0, 1.0, 0.0];
//! let p = Problem::dense(&a, &b, &c).unwrap();
//! let s = solve(&p, &Params::new(1.0, 1.0, 1.0)).unwrap();
//! let t = s.dense_plan(&p);
//! assert!((t[0] - 0.3220536).abs() < 1e-5); // POT's docstring example
//! ```

mod engine;
mod error;
mod fastmath;
mod layout;
mod problem;
pub mod reference;
mod solution;

pub use engine::Workspace;
pub use error::{Error, Result};
pub use problem::{Problem, SparseCost, Support};
pub use solution::{Potentials, Solution, Stats};

/// Solver parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct Params {
    /// Entropic regularisation, > 0.
    pub eps: f64,
    /// Source marginal relaxation, > 0; `f64::INFINITY` for a hard marginal.
    pub tau_s: f64,
    /// Target marginal relaxation, > 0; `f64::INFINITY` for a hard marginal.
    pub tau_t: f64,
    /// Number of sweeps (the paper uses 30), or the cap when `tol` is set.
    pub max_iters: usize,
    /// Stop when max(|Δf|, |Δg|)/eps over a sweep (the change of ln u, ln v) is <= tol.
    /// The `f32` kernel puts the floor near 1e-6.
    pub tol: Option<f64>,
    /// Starting potentials (e.g. from the previous transport round). Because a sweep
    /// updates f first, only `g` influences the iterates; `f` is what an
    /// `max_iters = 0` solve reports. Non-finite entries start from 0.
    pub warm_start: Option<Potentials>,
}

impl Params {
    /// `eps`, `tau_s`, `tau_t` with 30 sweeps, no tolerance, cold start (f = g = 0, as POT).
    pub fn new(eps: f64, tau_s: f64, tau_t: f64) -> Self {
        Params { eps, tau_s, tau_t, max_iters: 30, tol: None, warm_start: None }
    }

    /// Checks the parameters (not the problem).
    pub fn validate(&self) -> Result<()> {
        if !(self.eps.is_finite() && self.eps > 0.0) {
            return Err(Error::BadEps(self.eps));
        }
        for (side, value) in [("s", self.tau_s), ("t", self.tau_t)] {
            if value.is_nan() || value <= 0.0 {
                return Err(Error::BadTau { side, value });
            }
        }
        if let Some(t) = self.tol {
            if !(t.is_finite() && t > 0.0) {
                return Err(Error::BadTol(t));
            }
        }
        Ok(())
    }
}

/// `f` over fixed chunks of `0..n` in parallel, results in chunk order: callers
/// combine them sequentially so floating-point sums do not depend on scheduling.
pub(crate) fn det_chunks<T: Send>(
    n: usize,
    chunk: usize,
    f: impl Fn(std::ops::Range<usize>) -> T + Sync,
) -> Vec<T> {
    use rayon::prelude::*;
    (0..n.div_ceil(chunk)).into_par_iter().map(|c| f(c * chunk..((c + 1) * chunk).min(n))).collect()
}

/// Validation shared by the solvers; `Some` for problems whose answer is the empty plan.
pub(crate) fn prepare(p: &Problem<'_>, params: &Params) -> Result<Option<Solution>> {
    params.validate()?;
    if let Some(w) = &params.warm_start {
        if w.f.len() != p.n() {
            return Err(Error::Shape { what: "warm-start f", got: w.f.len(), expected: p.n() });
        }
        if w.g.len() != p.m() {
            return Err(Error::Shape { what: "warm-start g", got: w.g.len(), expected: p.m() });
        }
        if w.f.iter().chain(&w.g).any(|x| x.is_nan()) {
            return Err(Error::BadWarmStart("NaN potential".into()));
        }
    }
    let any_a = p.a.iter().any(|&x| x > 0.0);
    let any_b = p.b.iter().any(|&x| x > 0.0);
    if !any_a || !any_b {
        return Ok(Some(Solution::empty(p, params)));
    }
    engine::check_feasible(p, params)?;
    Ok(None)
}

/// Solves the entropic unbalanced transport problem (paper eq. (5), T_v*) with the
/// stabilised-scaling engine: `params.max_iters` Gauss–Seidel sweeps (f then g), or
/// fewer if `params.tol` is met. Errors on bad parameters, a wrong-sized warm start, or
/// hard marginals that cannot be met. A problem with no mass on one side gives an
/// empty plan.
pub fn solve(p: &Problem<'_>, params: &Params) -> Result<Solution> {
    solve_with(&mut Workspace::new(), p, params)
}

/// [`solve`] reusing the buffers of `ws` (see [`Workspace`]); results are identical.
pub fn solve_with(ws: &mut Workspace, p: &Problem<'_>, params: &Params) -> Result<Solution> {
    if let Some(s) = prepare(p, params)? {
        return Ok(s);
    }
    engine::solve_scaling(p, params, ws)
}

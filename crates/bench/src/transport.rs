//! `bench transport`: the solver timed on reproducible view-like random problems
//! ([`bench_problem`]): the dense solve (cold and with a reused workspace), the plan
//! means the edit reads, the top-k solve, and the naive log-domain baseline with its
//! plan deviation.

use crate::timing::try_best_of;
use rayon::prelude::*;
use std::path::Path;
use std::time::Instant;
use transsplat_scene::npy;
use transsplat_transport::{reference, solve, solve_with, Params, Problem, Solution, Workspace};

/// What a run measures besides the solver's own parameters.
#[derive(Clone, Debug)]
pub struct Settings {
    /// Targets (prototypes).
    pub m: usize,
    /// k of the top-k runs.
    pub topk: usize,
    /// Timed repetitions (the minimum is reported).
    pub repeat: usize,
    /// Also time the naive two-exp log-domain baseline.
    pub baseline: bool,
    /// Seed of the problems.
    pub seed: u64,
    pub params: Params,
}

/// The timings of one problem size (milliseconds, best of the repetitions).
#[derive(Clone, Debug, serde::Serialize)]
pub struct SizeResult {
    pub n: usize,
    pub m: usize,
    #[serde(skip)]
    pub generate_s: f64,
    pub dense_ms: f64,
    pub dense_cold_ms: f64,
    pub dense_validation_ms: f64,
    pub means_ms: f64,
    pub topk_ms: f64,
    pub topk_selection_ms: f64,
    pub baseline_ms: Option<f64>,
    pub speedup_vs_baseline: Option<f64>,
    pub dense_objective: f64,
    pub topk_objective: f64,
    #[serde(skip)]
    pub dense_summary: String,
    #[serde(skip)]
    pub topk_summary: String,
    #[serde(skip)]
    pub baseline_summary: Option<String>,
    /// The baseline plan's largest deviation from the dense plan, over its largest entry.
    #[serde(skip)]
    pub baseline_plan_deviation: Option<f64>,
}

/// Why a run failed: the solver refused, or writing the problem failed.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Transport(#[from] transsplat_transport::Error),
    #[error(transparent)]
    Io(#[from] transsplat_scene::Error),
}

/// Times the solver on the problem of `n` sources; with `write_problem`, also writes it
/// as `a_N.npy`, `b_N.npy`, `C_N.npy` there (for tools/bench_pot.py).
pub fn run(n: usize, s: &Settings, write_problem: Option<&Path>) -> Result<SizeResult, Error> {
    let params = &s.params;
    let t0 = Instant::now();
    let (a, b, c) = bench_problem(n, s.m, s.seed);
    let generate_s = t0.elapsed().as_secs_f64();
    if let Some(dir) = write_problem {
        std::fs::create_dir_all(dir).map_err(|e| transsplat_scene::Error::io(dir, e))?;
        npy::write(&dir.join(format!("a_{n}.npy")), &[n], &a)?;
        npy::write(&dir.join(format!("b_{n}.npy")), &[s.m], &b)?;
        npy::write(&dir.join(format!("C_{n}.npy")), &[n, s.m], &c)?;
    }
    let best_of = |f: &mut dyn FnMut() -> Result<Solution, Error>| try_best_of(0, s.repeat, f);
    // Dense: validation + solve. "cold" allocates the n x m kernel afresh (first-touch
    // page faults included); "warm" reuses a Workspace, as repeated solves do.
    let (t_valid, _) = try_best_of(0, s.repeat, || Problem::dense(&a, &b, &c).map(|p| p.nnz()))?;
    let (t_cold, _) = best_of(&mut || Ok(solve(&Problem::dense(&a, &b, &c)?, params)?))?;
    let mut ws = Workspace::new();
    solve_with(&mut ws, &Problem::dense(&a, &b, &c)?, params)?;
    let (t_dense, sd) = best_of(&mut || Ok(solve_with(&mut ws, &Problem::dense(&a, &b, &c)?, params)?))?;
    drop(ws);
    // What the edit reads from each plan: w and the plan-weighted means of 16-d
    // target vectors (Solution::target_means).
    let e: Vec<f32> = (0..s.m * 16).map(|k| unif(s.seed, (1 << 41) + k as u64) as f32 - 0.5).collect();
    let pd = Problem::dense(&a, &b, &c)?;
    let (t_means, _) = try_best_of(0, s.repeat, || Ok::<_, Error>(sd.target_means(&pd, &e, 16, 1e-8)))?;
    // Top-k: selection (with validation) + solve.
    let (t_sel, _) = try_best_of(0, s.repeat, || Problem::top_k(&a, &b, &c, s.topk).map(|p| p.nnz()))?;
    let (t_topk, sk) = best_of(&mut || Ok(solve(&Problem::top_k(&a, &b, &c, s.topk)?, params)?))?;
    let base = if s.baseline {
        let (t, sb) = try_best_of(0, 1, || reference::solve_log_domain(&pd, params))?;
        let dev = max_plan_dev(&sd, &sb, &pd);
        Some((t, sb, dev))
    } else {
        None
    };
    Ok(SizeResult {
        n,
        m: s.m,
        generate_s,
        dense_ms: t_dense * 1e3,
        dense_cold_ms: t_cold * 1e3,
        dense_validation_ms: t_valid * 1e3,
        means_ms: t_means * 1e3,
        topk_ms: t_topk * 1e3,
        topk_selection_ms: t_sel * 1e3,
        baseline_ms: base.as_ref().map(|b| b.0 * 1e3),
        speedup_vs_baseline: base.as_ref().map(|b| b.0 / t_dense),
        dense_objective: sd.stats.objective,
        topk_objective: sk.stats.objective,
        dense_summary: summary(&sd),
        topk_summary: summary(&sk),
        baseline_summary: base.as_ref().map(|b| summary(&b.1)),
        baseline_plan_deviation: base.as_ref().map(|b| b.2),
    })
}

fn summary(s: &Solution) -> String {
    format!(
        "objective {:.6e}, gap {:.2e}, mass {:.4}, rebuilds {}",
        s.stats.objective, s.stats.gap, s.stats.transported_mass, s.stats.rebuilds
    )
}

/// splitmix64 hash of (seed, k) mapped to [0, 1).
fn unif(seed: u64, k: u64) -> f64 {
    let mut z = seed.wrapping_add(k.wrapping_add(1).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

const DSEM: usize = 16;

/// A view-like random problem: Gaussians at image positions x_i with semantic
/// latents s_i, prototypes at u_j with features e_j (d = 16), cost
/// 4 |x_i - u_j|^2 + (1 - cos(s_i, e_j)) (coordinates normalised to the unit square),
/// masses a ∝ (visibility·opacity)-like weights, b ∝ prototype shares.
pub fn bench_problem(n: usize, m: usize, seed: u64) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let stride = (2 + DSEM + 1) as u64;
    let point = |base: u64, idx: usize| -> ([f64; 2], [f64; DSEM], f64) {
        let k0 = base + idx as u64 * stride;
        let x = [unif(seed, k0), unif(seed, k0 + 1)];
        let mut s = [0f64; DSEM];
        let mut nrm = 0.0;
        for (d, v) in s.iter_mut().enumerate() {
            *v = unif(seed, k0 + 2 + d as u64) - 0.5;
            nrm += *v * *v;
        }
        let nrm = nrm.sqrt().max(1e-12);
        s.iter_mut().for_each(|v| *v /= nrm);
        (x, s, unif(seed, k0 + 2 + DSEM as u64))
    };
    let targets: Vec<_> = (0..m).map(|j| point(1 << 40, j)).collect();
    let mut a = vec![0f32; n];
    let mut c = vec![0f32; n * m];
    c.par_chunks_mut(m).zip(a.par_iter_mut()).enumerate().for_each(|(i, (row, ai))| {
        let (x, s, w) = point(0, i);
        *ai = (w * w + 1e-3) as f32;
        for (j, (u, e, _)) in targets.iter().enumerate() {
            let dx = x[0] - u[0];
            let dy = x[1] - u[1];
            let cos: f64 = s.iter().zip(e).map(|(p, q)| p * q).sum();
            row[j] = (4.0 * (dx * dx + dy * dy) + (1.0 - cos)) as f32;
        }
    });
    let sa: f64 = a.iter().map(|&x| x as f64).sum();
    a.iter_mut().for_each(|x| *x = (*x as f64 / sa) as f32);
    let mut b: Vec<f32> = targets.iter().map(|t| (t.2 + 0.1) as f32).collect();
    let sb: f64 = b.iter().map(|&x| x as f64).sum();
    b.iter_mut().for_each(|x| *x = (*x as f64 / sb) as f32);
    (a, b, c)
}

fn max_plan_dev(x: &Solution, y: &Solution, p: &Problem<'_>) -> f64 {
    let tx = x.dense_plan(p);
    let ty = y.dense_plan(p);
    let mx = ty.iter().fold(0f32, |m, v| m.max(*v)) as f64;
    let d = tx.iter().zip(&ty).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max) as f64;
    d / mx.max(f64::MIN_POSITIVE)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bench_problem_is_reproducible_and_valid() {
        let (a, b, c) = bench_problem(1000, 8, 3);
        let (a2, _, c2) = bench_problem(1000, 8, 3);
        assert_eq!(a, a2);
        assert_eq!(c, c2);
        assert!(c.iter().all(|&x| (0.0..=10.0).contains(&x)));
        assert!((a.iter().sum::<f32>() - 1.0).abs() < 1e-4 && (b.iter().sum::<f32>() - 1.0).abs() < 1e-5);
    }
}

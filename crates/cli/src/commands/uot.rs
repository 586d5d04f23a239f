//! `transsplat uot` (solve one transport problem from .npy files) and
//! `transsplat bench transport` (solver timings on reproducible random problems).

use anyhow::{bail, Context, Result};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::time::Instant;
use transsplat_bench::timing::try_best_of;
use transsplat_scene::npy;
use transsplat_transport::{reference, solve, solve_with, Params, Problem, Solution, Workspace};

/// Parses a marginal relaxation: a positive number or `inf`.
fn parse_tau(s: &str) -> std::result::Result<f64, String> {
    match s.trim().to_ascii_lowercase().as_str() {
        "inf" | "+inf" | "infinity" | "+infinity" => Ok(f64::INFINITY),
        t => t.parse::<f64>().map_err(|e| format!("{s:?} is not a number or 'inf': {e}")),
    }
}

/// JSON for a float that may be infinite ("inf") or NaN ("nan").
fn num(x: f64) -> serde_json::Value {
    if x.is_finite() {
        serde_json::json!(x)
    } else if x.is_nan() {
        serde_json::json!("nan")
    } else if x > 0.0 {
        serde_json::json!("inf")
    } else {
        serde_json::json!("-inf")
    }
}

/// Arguments of `transsplat uot`.
#[derive(clap::Args, Debug)]
pub struct UotArgs {
    /// Cost matrix, float .npy of shape (n, m); +inf entries are excluded.
    #[arg(long)]
    pub cost: PathBuf,
    /// Source masses, .npy of shape (n,).
    #[arg(long)]
    pub source: PathBuf,
    /// Target masses, .npy of shape (m,).
    #[arg(long)]
    pub target: PathBuf,
    /// Entropic regularisation eps > 0.
    #[arg(long, value_parser = super::common::finite_f64)]
    pub eps: f64,
    /// Source marginal relaxation tau_s > 0, or `inf` for a hard marginal.
    #[arg(long, value_parser = parse_tau)]
    pub tau_s: f64,
    /// Target marginal relaxation tau_t > 0, or `inf` for a hard marginal.
    #[arg(long, value_parser = parse_tau)]
    pub tau_t: f64,
    /// Gauss-Seidel sweeps (the cap when --tol is given).
    #[arg(long, default_value_t = 30)]
    pub iters: usize,
    /// Stop when the potentials change by at most tol*eps in a sweep.
    #[arg(long, value_parser = super::common::finite_f64)]
    pub tol: Option<f64>,
    /// Keep each target's k cheapest sources (0 = dense).
    #[arg(long, default_value_t = 0)]
    pub topk: usize,
    /// Write the dense plan (float32 .npy, shape (n, m)) here, atomically.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Solve with the plain f64 log-domain reference solver instead (slow; for checks).
    #[arg(long)]
    pub reference: bool,
}

fn read_npy(path: &Path, what: &str, dims: usize) -> Result<npy::Array> {
    let arr = npy::read(path).with_context(|| format!("reading {what}"))?;
    if arr.shape.len() != dims {
        bail!("{what} {} has shape {:?}, expected {dims} dimension(s)", path.display(), arr.shape);
    }
    Ok(arr)
}

/// Runs `transsplat uot`.
pub fn run(args: &UotArgs) -> Result<()> {
    if let Some(out) = &args.out {
        super::common::check_output(out, &[&args.cost, &args.source, &args.target])?;
    }
    let c = read_npy(&args.cost, "cost", 2)?;
    let a = read_npy(&args.source, "source masses", 1)?;
    let b = read_npy(&args.target, "target masses", 1)?;
    let (n, m) = (c.shape[0], c.shape[1]);
    for (arr, path, what, len) in [(&a, &args.source, "source", n), (&b, &args.target, "target", m)] {
        if arr.shape[0] != len {
            bail!(
                "{}: {} {what} masses, but the cost {} is {n} x {m}",
                path.display(),
                arr.shape[0],
                args.cost.display()
            );
        }
    }
    let params =
        Params { max_iters: args.iters, tol: args.tol, ..Params::new(args.eps, args.tau_s, args.tau_t) };
    params.validate()?;
    let t0 = Instant::now();
    let p = Problem::top_k(&a.data, &b.data, &c.data, args.topk).map_err(|e| {
        // Name the file a bad value came from.
        let file = match &e {
            transsplat_transport::Error::BadCost { .. } => Some(&args.cost),
            transsplat_transport::Error::BadMass { which: "source", .. } => Some(&args.source),
            transsplat_transport::Error::BadMass { .. } => Some(&args.target),
            _ => None,
        };
        match file {
            Some(f) => anyhow::anyhow!("{}: {e}", f.display()),
            None => e.into(),
        }
    })?;
    let s = if args.reference { reference::solve_log_domain(&p, &params)? } else { solve(&p, &params)? };
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    if let Some(out) = &args.out {
        npy::write(out, &[n, m], &s.dense_plan(&p)).with_context(|| format!("writing {}", out.display()))?;
    }
    let st = &s.stats;
    println!(
        "uot: {n} x {m} ({} entries), eps {}, tau_s {}, tau_t {}: {} sweeps in {ms:.1} ms",
        p.nnz(),
        args.eps,
        args.tau_s,
        args.tau_t,
        st.iterations
    );
    println!(
        "objective {:.9e}  dual {:.9e}  gap {:.3e}  <C,T> {:.9e}  mass {:.9e}",
        st.objective, st.dual, st.gap, st.transport_cost, st.transported_mass
    );
    let json = serde_json::json!({
        "objective": num(st.objective),
        "dual": num(st.dual),
        "gap": num(st.gap),
        "transport_cost": num(st.transport_cost),
        "transported_mass": num(st.transported_mass),
        "source_error": num(st.source_error),
        "target_error": num(st.target_error),
        "iterations": st.iterations,
        "converged": st.converged,
        "last_change": num(st.last_change),
        "n": n,
        "m": m,
        "nnz": p.nnz(),
        "eps": args.eps,
        "tau_s": num(args.tau_s),
        "tau_t": num(args.tau_t),
        "topk": args.topk,
        "solver": if args.reference { "log-domain-f64" } else { "stabilised-scaling" },
        "time_ms": ms,
        "plan": args.out.as_ref().map(|p| p.display().to_string()),
    });
    println!("{json}");
    Ok(())
}

/// Arguments of `transsplat bench transport`.
#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    /// Numbers of sources.
    #[arg(long, value_delimiter = ',', default_values_t = vec![100_000usize, 1_000_000])]
    pub sizes: Vec<usize>,
    /// Number of targets (prototypes).
    #[arg(long, default_value_t = 32)]
    pub m: usize,
    /// Sweeps per solve.
    #[arg(long, default_value_t = 30)]
    pub iters: usize,
    /// k of the top-k runs.
    #[arg(long, default_value_t = 128)]
    pub topk: usize,
    #[arg(long, value_parser = super::common::finite_f64, default_value_t = 0.05)]
    pub eps: f64,
    #[arg(long, value_parser = parse_tau, default_value = "1")]
    pub tau_s: f64,
    #[arg(long, value_parser = parse_tau, default_value = "1")]
    pub tau_t: f64,
    /// Timed repetitions (the minimum is reported). Dense times are "warm" (a reused
    /// Workspace) unless marked cold.
    #[arg(long, default_value_t = 5)]
    pub repeat: usize,
    /// Skip the naive two-exp log-domain baseline.
    #[arg(long)]
    pub no_baseline: bool,
    /// Random seed of the problems.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// Also write each problem as a_N.npy, b_N.npy, C_N.npy into this folder (for
    /// tools/bench_pot.py).
    #[arg(long)]
    pub write_problem: Option<PathBuf>,
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

/// [`try_best_of`] without warm-up, with the error type fixed for `?` in the closures.
fn best_of<T>(repeat: usize, f: impl FnMut() -> Result<T>) -> Result<(f64, T)> {
    try_best_of(0, repeat, f)
}

/// Runs `transsplat bench transport`.
pub fn bench(args: &BenchArgs) -> Result<()> {
    let params = Params { max_iters: args.iters, ..Params::new(args.eps, args.tau_s, args.tau_t) };
    params.validate()?;
    println!(
        "bench transport: m = {}, {} sweeps, eps {}, tau_s {}, tau_t {}, top-k {}, {} threads, best of {}",
        args.m,
        args.iters,
        args.eps,
        args.tau_s,
        args.tau_t,
        args.topk,
        rayon::current_num_threads(),
        args.repeat
    );
    let mut results = Vec::new();
    for &n in &args.sizes {
        let t0 = Instant::now();
        let (a, b, c) = bench_problem(n, args.m, args.seed);
        let gen_s = t0.elapsed().as_secs_f64();
        if let Some(dir) = &args.write_problem {
            std::fs::create_dir_all(dir)?;
            npy::write(&dir.join(format!("a_{n}.npy")), &[n], &a)?;
            npy::write(&dir.join(format!("b_{n}.npy")), &[args.m], &b)?;
            npy::write(&dir.join(format!("C_{n}.npy")), &[n, args.m], &c)?;
        }
        let summary = |s: &Solution| {
            format!(
                "objective {:.6e}, gap {:.2e}, mass {:.4}, rebuilds {}",
                s.stats.objective, s.stats.gap, s.stats.transported_mass, s.stats.rebuilds
            )
        };
        // Dense: validation + solve. "cold" allocates the n x m kernel afresh (first-touch
        // page faults included); "warm" reuses a Workspace, as repeated solves do.
        let (t_valid, _) = best_of(args.repeat, || Ok(Problem::dense(&a, &b, &c)?.nnz()))?;
        let (t_cold, _) = best_of(args.repeat, || {
            let p = Problem::dense(&a, &b, &c)?;
            Ok(solve(&p, &params)?)
        })?;
        let mut ws = Workspace::new();
        solve_with(&mut ws, &Problem::dense(&a, &b, &c)?, &params)?;
        let (t_dense, sd) = best_of(args.repeat, || {
            let p = Problem::dense(&a, &b, &c)?;
            Ok(solve_with(&mut ws, &p, &params)?)
        })?;
        drop(ws);
        // What the edit reads from each plan: w and the plan-weighted means of 16-d
        // target vectors (Solution::target_means).
        let e: Vec<f32> =
            (0..args.m * 16).map(|k| unif(args.seed, (1 << 41) + k as u64) as f32 - 0.5).collect();
        let pd = Problem::dense(&a, &b, &c)?;
        let (t_means, _) = best_of(args.repeat, || Ok(sd.target_means(&pd, &e, 16, 1e-8)))?;
        // Top-k: selection (with validation) + solve.
        let (t_sel, _) = best_of(args.repeat, || Ok(Problem::top_k(&a, &b, &c, args.topk)?.nnz()))?;
        let (t_topk, sk) = best_of(args.repeat, || {
            let p = Problem::top_k(&a, &b, &c, args.topk)?;
            Ok(solve(&p, &params)?)
        })?;
        let base = if args.no_baseline {
            None
        } else {
            let p = Problem::dense(&a, &b, &c)?;
            let (t, s) = best_of(1, || Ok(reference::solve_log_domain(&p, &params)?))?;
            let pd = Problem::dense(&a, &b, &c)?;
            let dev = max_plan_dev(&sd, &s, &pd);
            Some((t, s, dev))
        };
        println!("n = {n} x {} (generated in {:.2} s)", args.m, gen_s);
        println!(
            "  dense     {:>9.1} ms warm   ({:.1} ms cold, validation {:.1} ms)   {}",
            t_dense * 1e3,
            t_cold * 1e3,
            t_valid * 1e3,
            summary(&sd)
        );
        println!("  plan means (d = 16) {:>9.1} ms", t_means * 1e3);
        println!(
            "  top-{:<4}  {:>9.1} ms   (selection {:.1} ms)   {}",
            args.topk,
            t_topk * 1e3,
            t_sel * 1e3,
            summary(&sk)
        );
        if let Some((t, s, dev)) = &base {
            println!(
                "  naive log-domain f64 (2 exps/entry/sweep) {:>9.1} ms   {}   -> dense is {:.1}x faster; plan max |diff| / max entry = {:.2e}",
                t * 1e3,
                summary(s),
                t / t_dense,
                dev
            );
        }
        results.push(serde_json::json!({
            "n": n,
            "m": args.m,
            "dense_ms": t_dense * 1e3,
            "dense_cold_ms": t_cold * 1e3,
            "dense_validation_ms": t_valid * 1e3,
            "means_ms": t_means * 1e3,
            "topk_ms": t_topk * 1e3,
            "topk_selection_ms": t_sel * 1e3,
            "baseline_ms": base.as_ref().map(|b| b.0 * 1e3),
            "speedup_vs_baseline": base.as_ref().map(|b| b.0 / t_dense),
            "dense_objective": sd.stats.objective,
            "topk_objective": sk.stats.objective,
        }));
    }
    println!(
        "{}",
        serde_json::json!({
            "bench": "transport",
            "iters": args.iters,
            "eps": args.eps,
            "tau_s": num(args.tau_s),
            "tau_t": num(args.tau_t),
            "topk": args.topk,
            "threads": rayon::current_num_threads(),
            "results": results,
        })
    );
    Ok(())
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
    fn tau_parsing() {
        assert_eq!(parse_tau("inf").unwrap(), f64::INFINITY);
        assert_eq!(parse_tau("Infinity").unwrap(), f64::INFINITY);
        assert_eq!(parse_tau("0.5").unwrap(), 0.5);
        assert!(parse_tau("abc").is_err());
    }

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

//! `transsplat uot` (solve one transport problem from .npy files) and
//! `transsplat bench transport` (solver timings on reproducible random problems).

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::time::Instant;
use transsplat_bench::transport as transport_bench;
use transsplat_scene::npy;
use transsplat_transport::{reference, solve, Params, Problem};

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

/// Runs `transsplat bench transport`.
pub fn bench(args: &BenchArgs) -> Result<()> {
    let settings = transport_bench::Settings {
        m: args.m,
        topk: args.topk,
        repeat: args.repeat,
        baseline: !args.no_baseline,
        seed: args.seed,
        params: Params { max_iters: args.iters, ..Params::new(args.eps, args.tau_s, args.tau_t) },
    };
    settings.params.validate()?;
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
        let r = transport_bench::run(n, &settings, args.write_problem.as_deref())?;
        println!("n = {n} x {} (generated in {:.2} s)", args.m, r.generate_s);
        println!(
            "  dense     {:>9.1} ms warm   ({:.1} ms cold, validation {:.1} ms)   {}",
            r.dense_ms, r.dense_cold_ms, r.dense_validation_ms, r.dense_summary
        );
        println!("  plan means (d = 16) {:>9.1} ms", r.means_ms);
        println!(
            "  top-{:<4}  {:>9.1} ms   (selection {:.1} ms)   {}",
            args.topk, r.topk_ms, r.topk_selection_ms, r.topk_summary
        );
        if let (Some(t), Some(summary), Some(dev)) =
            (r.baseline_ms, &r.baseline_summary, r.baseline_plan_deviation)
        {
            println!(
                "  naive log-domain f64 (2 exps/entry/sweep) {t:>9.1} ms   {summary}   -> dense is {:.1}x faster; plan max |diff| / max entry = {dev:.2e}",
                t / r.dense_ms,
            );
        }
        results.push(r);
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
}

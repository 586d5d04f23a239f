//! Plain log-domain solver in `f64`: the same Gauss–Seidel fixed point as the
//! stabilised engine (docs/method.md#m4-the-uot-solver), computed by a log-sum-exp over every entry in
//! both half-sweeps, i.e. two exps per entry per sweep. It is the test oracle and the
//! baseline of `transsplat bench transport`; use [`crate::solve`] for real work.

use crate::engine::kappa;
use crate::error::Result;
use crate::layout::{with_layout, Layout};
use crate::problem::Problem;
use crate::solution::{finish, Potentials, Raw, Solution};
use crate::Params;
use rayon::prelude::*;

const ROWS_PER_TASK: usize = 1024;

/// Solves like [`crate::solve`] but with plain log-sum-exp updates in `f64`.
pub fn solve_log_domain(p: &Problem<'_>, params: &Params) -> Result<Solution> {
    if let Some(s) = crate::prepare(p, params)? {
        return Ok(s);
    }
    with_layout!(p, l => run(&l, p, params))
}

fn lse(xs: impl Iterator<Item = f64> + Clone) -> f64 {
    let mx = xs.clone().fold(f64::NEG_INFINITY, f64::max);
    if !mx.is_finite() {
        return mx;
    }
    mx + xs.map(|x| (x - mx).exp()).sum::<f64>().ln()
}

fn run<L: Layout>(l: &L, p: &Problem<'_>, params: &Params) -> Result<Solution> {
    let (n, m) = (p.n(), p.m());
    let eps = params.eps;
    let (ks, kt) = (kappa(params.tau_s, eps), kappa(params.tau_t, eps));
    let ln_a: Vec<f64> = p.a.iter().map(|&x| (x as f64).ln()).collect();
    let ln_b: Vec<f64> = p.b.iter().map(|&x| (x as f64).ln()).collect();
    let rows = l.rows();
    let mut f = vec![f64::INFINITY; n];
    let mut g: Vec<f64> = match &params.warm_start {
        Some(w) => w.g.iter().map(|&x| if x.is_finite() { x } else { 0.0 }).collect(),
        None => vec![0.0; m],
    };
    if let Some(w) = &params.warm_start {
        for r in 0..rows {
            let i = l.source(r);
            f[i] = if w.f[i].is_finite() { w.f[i] } else { 0.0 };
        }
    } else {
        for r in 0..rows {
            f[l.source(r)] = 0.0;
        }
    }
    // Targets that no positive-mass source reaches keep g = +inf once found.
    let mut dead = vec![false; m];
    let mut iterations = 0;
    let mut converged = false;
    let mut last_change = f64::INFINITY;
    for it in 0..params.max_iters {
        // f-update (one exp per entry).
        let new_f: Vec<f64> = (0..rows)
            .into_par_iter()
            .map(|r| {
                let (lo, hi) = l.range(r);
                let v = lse((lo..hi).filter_map(|e| {
                    let j = l.col(lo, e);
                    (p.b[j] > 0.0 && !dead[j]).then(|| ln_b[j] + (g[j] - l.costs()[e] as f64) / eps)
                }));
                -ks * eps * v
            })
            .collect();
        let mut df = 0f64;
        for (r, v) in new_f.into_iter().enumerate() {
            let i = l.source(r);
            if v.is_finite() && f[i].is_finite() {
                df = df.max((v - f[i]).abs());
            }
            f[i] = v;
        }
        // g-update (one exp per entry): per-column max, then shifted sums.
        let x = |r: usize, e: usize| -> f64 {
            let i = l.source(r);
            if p.a[i] > 0.0 && f[i].is_finite() {
                ln_a[i] + (f[i] - l.costs()[e] as f64) / eps
            } else {
                f64::NEG_INFINITY
            }
        };
        let chunks: Vec<usize> = (0..rows.div_ceil(ROWS_PER_TASK)).collect();
        let mx = chunks
            .par_iter()
            .map(|&c| {
                let mut mx = vec![f64::NEG_INFINITY; m];
                for r in c * ROWS_PER_TASK..((c + 1) * ROWS_PER_TASK).min(rows) {
                    let (lo, hi) = l.range(r);
                    for e in lo..hi {
                        let j = l.col(lo, e);
                        mx[j] = mx[j].max(x(r, e));
                    }
                }
                mx
            })
            .reduce(|| vec![f64::NEG_INFINITY; m], |a, b| a.iter().zip(&b).map(|(x, y)| x.max(*y)).collect());
        let sums: Vec<Vec<f64>> = chunks
            .par_iter()
            .map(|&c| {
                let mut s = vec![0f64; m];
                for r in c * ROWS_PER_TASK..((c + 1) * ROWS_PER_TASK).min(rows) {
                    let (lo, hi) = l.range(r);
                    for e in lo..hi {
                        let j = l.col(lo, e);
                        if mx[j].is_finite() {
                            s[j] += (x(r, e) - mx[j]).exp();
                        }
                    }
                }
                s
            })
            .collect();
        let mut dg = 0f64;
        for j in 0..m {
            if p.b[j] <= 0.0 {
                g[j] = 0.0;
                continue;
            }
            if !mx[j].is_finite() {
                dead[j] = true;
                g[j] = f64::INFINITY;
                continue;
            }
            let s: f64 = sums.iter().map(|v| v[j]).sum();
            let v = -kt * eps * (mx[j] + s.ln());
            dg = dg.max((v - g[j]).abs());
            g[j] = v;
        }
        iterations = it + 1;
        last_change = df.max(dg) / eps;
        if let Some(tol) = params.tol {
            if last_change <= tol {
                converged = true;
                break;
            }
        }
    }
    // Exact marginals and linear cost.
    let t = |i: usize, j: usize, c: f32| -> f64 {
        if p.a[i] > 0.0 && p.b[j] > 0.0 && f[i].is_finite() && g[j].is_finite() {
            (ln_a[i] + ln_b[j] + (f[i] + g[j] - c as f64) / eps).exp()
        } else {
            0.0
        }
    };
    let per_row: Vec<(f64, f64)> = (0..rows)
        .into_par_iter()
        .map(|r| {
            let (lo, hi) = l.range(r);
            let i = l.source(r);
            let (mut rm, mut lin) = (0.0, 0.0);
            for e in lo..hi {
                let c = l.costs()[e];
                let v = t(i, l.col(lo, e), c);
                if v > 0.0 {
                    rm += v;
                    lin += v * c as f64;
                }
            }
            (rm, lin)
        })
        .collect();
    let col_parts: Vec<Vec<f64>> = (0..rows.div_ceil(ROWS_PER_TASK))
        .into_par_iter()
        .map(|c| {
            let mut s = vec![0f64; m];
            for r in c * ROWS_PER_TASK..((c + 1) * ROWS_PER_TASK).min(rows) {
                let (lo, hi) = l.range(r);
                for e in lo..hi {
                    let j = l.col(lo, e);
                    s[j] += t(l.source(r), j, l.costs()[e]);
                }
            }
            s
        })
        .collect();
    let mut row_mass = vec![0f64; n];
    let mut lin = 0.0;
    for (r, (rm, li)) in per_row.into_iter().enumerate() {
        row_mass[l.source(r)] = rm;
        lin += li;
    }
    let col_mass: Vec<f64> = (0..m).map(|j| col_parts.iter().map(|v| v[j]).sum()).collect();
    let raw = Raw {
        potentials: Potentials { f, g },
        row_mass,
        col_mass,
        transport_cost: lin,
        iterations,
        converged,
        last_change,
        rebuilds: 0,
        fallbacks: 0,
    };
    Ok(finish(p, params, raw))
}

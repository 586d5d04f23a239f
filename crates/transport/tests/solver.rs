//! Solver behaviour: closed forms, agreement with the plain log-domain oracle,
//! Proposition 1 (uniqueness from any start, vanishing duality gap), sparse vs dense,
//! bad input and extreme scales.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use transsplat_transport::{reference, solve, Error, Params, Potentials, Problem, SparseCost};

const INF: f64 = f64::INFINITY;

struct Gen {
    a: Vec<f32>,
    b: Vec<f32>,
    c: Vec<f32>,
}

/// Random problem: points in the unit square, cost = scale * squared distance, masses
/// log-uniform in [min_mass, 1] then scaled to the given totals.
fn gen(seed: u64, n: usize, m: usize, scale: f32, min_mass: f32, tot_a: f32, tot_b: f32) -> Gen {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    let x: Vec<[f32; 2]> = (0..n).map(|_| [r.gen(), r.gen()]).collect();
    let u: Vec<[f32; 2]> = (0..m).map(|_| [r.gen(), r.gen()]).collect();
    let mut c = vec![0f32; n * m];
    for i in 0..n {
        for j in 0..m {
            let dx = x[i][0] - u[j][0];
            let dy = x[i][1] - u[j][1];
            c[i * m + j] = scale * (dx * dx + dy * dy);
        }
    }
    let lm = min_mass.ln();
    let mut mass = |k: usize, tot: f32| {
        let v: Vec<f32> = (0..k).map(|_| (lm * r.gen::<f32>()).exp()).collect();
        let s: f32 = v.iter().sum();
        v.into_iter().map(|x| x * tot / s).collect::<Vec<f32>>()
    };
    let a = mass(n, tot_a);
    let b = mass(m, tot_b);
    Gen { a, b, c }
}

fn params(eps: f64, ts: f64, tt: f64, iters: usize, tol: Option<f64>) -> Params {
    Params { max_iters: iters, tol, ..Params::new(eps, ts, tt) }
}

fn max_abs_diff(x: &[f32], y: &[f32]) -> f32 {
    x.iter().zip(y).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max)
}

fn max_abs(x: &[f32]) -> f32 {
    x.iter().fold(0.0, |a, b| a.max(b.abs()))
}

/// Closed form for 1 x 1: stationarity of
/// c t + eps KL(t|ab) + ts KL(t|a) + tt KL(t|b) gives
/// ln t = (-c + (eps + ts) ln a + (eps + tt) ln b) / (eps + ts + tt).
#[test]
fn one_by_one_closed_form() {
    for &(a, b, c, eps, ts, tt) in &[
        (0.7f32, 0.2f32, 0.3f32, 0.1f64, 1.0f64, 0.5f64),
        (1.0, 1.0, 2.0, 0.5, 0.1, 10.0),
        (1e-3, 3.0, 0.0, 0.01, 2.0, 2.0),
        (0.4, 0.9, 5.0, 1.0, 0.3, 0.3),
    ] {
        let p = Problem::dense(std::slice::from_ref(&a), std::slice::from_ref(&b), std::slice::from_ref(&c))
            .unwrap();
        let s = solve(&p, &params(eps, ts, tt, 100_000, Some(1e-9))).unwrap();
        let (la, lb) = ((a as f64).ln(), (b as f64).ln());
        let t = ((-(c as f64) + (eps + ts) * la + (eps + tt) * lb) / (eps + ts + tt)).exp();
        let got = s.dense_plan(&p)[0] as f64;
        assert!((got - t).abs() < 2e-5 * t, "1x1 {a} {b} {c} {eps} {ts} {tt}: {got} vs {t}");
        assert!((s.row_mass[0] - t).abs() < 2e-5 * t);
        let kl = |p: f64, q: f64| p * (p / q).ln() - p + q;
        let obj = c as f64 * t + eps * kl(t, (a * b) as f64) + ts * kl(t, a as f64) + tt * kl(t, b as f64);
        assert!(
            (s.stats.objective - obj).abs() < 1e-5 * obj.abs().max(1e-3),
            "{} vs {obj}",
            s.stats.objective
        );
        assert!(s.stats.gap.abs() < 1e-5 * obj.abs().max(1e-3), "gap {}", s.stats.gap);
    }
}

/// 1 x 1 balanced: the plan is the common mass whatever the cost.
#[test]
fn one_by_one_balanced() {
    let p = Problem::dense(&[0.25], &[0.25], &[7.0]).unwrap();
    let s = solve(&p, &params(0.05, INF, INF, 3, None)).unwrap();
    assert!((s.dense_plan(&p)[0] - 0.25).abs() < 1e-6);
    assert!((s.stats.transport_cost - 1.75).abs() < 1e-5);
}

/// POT's docstring example for `sinkhorn_unbalanced` (values printed by POT).
#[test]
fn pot_docstring_example() {
    let p = Problem::dense(&[0.5, 0.5], &[0.5, 0.5], &[0.0, 1.0, 1.0, 0.0]).unwrap();
    let s = solve(&p, &Params { max_iters: 1000, tol: Some(1e-9), ..Params::new(1.0, 1.0, 1.0) }).unwrap();
    let t = s.dense_plan(&p);
    let want = [0.3220536f32, 0.1184769, 0.1184769, 0.3220536];
    assert!(max_abs_diff(&t, &want) < 2e-6, "{t:?}");
}

/// The stabilised engine against the plain f64 log-domain oracle, on a grid of
/// eps / tau / sizes, after 30 sweeps and at convergence.
#[test]
fn engine_matches_log_domain_oracle() {
    let mut seed = 1;
    for &(n, m) in &[(1usize, 7usize), (50, 32), (400, 32), (1500, 5)] {
        for &eps in &[0.005, 0.03, 0.2, 1.0] {
            for &(ts, tt) in &[(0.1, 0.1), (1.0, 10.0), (10.0, 1.0), (INF, 1.0), (1.0, INF), (INF, INF)] {
                seed += 1;
                let (ta, tb) = if ts == INF && tt == INF { (1.0, 1.0) } else { (1.0, 0.6) };
                let g = gen(seed, n, m, 2.0, 1e-7, ta, tb);
                let p = Problem::dense(&g.a, &g.b, &g.c).unwrap();
                for (iters, tol) in [(30, None), (5000, Some(1e-7))] {
                    let pr = params(eps, ts, tt, iters, tol);
                    let s = solve(&p, &pr).unwrap();
                    // The f64 oracle converges further than the f32 kernel's noise floor.
                    let pr_ref = params(eps, ts, tt, iters, tol.map(|_| 1e-10));
                    let r = reference::solve_log_domain(&p, &pr_ref).unwrap();
                    let (ts_, tr_) = (s.dense_plan(&p), r.dense_plan(&p));
                    let scale = max_abs(&tr_);
                    let d = max_abs_diff(&ts_, &tr_);
                    let ctx = format!("n={n} m={m} eps={eps} ts={ts} tt={tt} iters={iters}: ");
                    assert!(d <= 1e-4 * scale, "{ctx}plan diff {d} (max {scale}), stats {:?}", s.stats);
                    let (o1, o2) = (s.stats.objective, r.stats.objective);
                    assert!((o1 - o2).abs() <= 1e-4 * o2.abs().max(1e-6), "{ctx}objective {o1} vs {o2}");
                }
            }
        }
    }
}

/// Proposition 1: from different starting potentials the solver reaches the same plan,
/// and the duality gap vanishes at convergence.
#[test]
fn proposition_1_unique_minimiser_zero_gap() {
    for (seed, eps, ts, tt) in [(11u64, 0.05, 0.5, 2.0), (12, 0.2, 1.0, 1.0), (13, 0.02, 5.0, 0.3)] {
        let g = gen(seed, 400, 32, 3.0, 1e-5, 1.0, 0.5);
        let p = Problem::dense(&g.a, &g.b, &g.c).unwrap();
        let base = params(eps, ts, tt, 50_000, Some(1e-6));
        let s0 = solve(&p, &base).unwrap();
        assert!(s0.stats.converged);
        let t0 = s0.dense_plan(&p);
        let scale = max_abs(&t0);
        let mut r = ChaCha8Rng::seed_from_u64(seed);
        for k in 0..3 {
            let f: Vec<f64> = (0..p.n()).map(|_| r.gen_range(-3.0..3.0)).collect();
            let gg: Vec<f64> = (0..p.m()).map(|_| r.gen_range(-3.0..3.0) * (k as f64 + 1.0)).collect();
            let pr = Params { warm_start: Some(Potentials { f, g: gg }), ..base.clone() };
            let s = solve(&p, &pr).unwrap();
            assert!(s.stats.converged);
            let d = max_abs_diff(&s.dense_plan(&p), &t0);
            assert!(d <= 1e-4 * scale, "start {k}: plan differs by {d} (max {scale})");
        }
        let rel_gap = s0.stats.gap / s0.stats.objective.abs();
        assert!(rel_gap.abs() < 1e-6, "gap {} objective {}", s0.stats.gap, s0.stats.objective);
        // Away from convergence the gap is clearly positive.
        let s1 = solve(&p, &params(eps, ts, tt, 1, None)).unwrap();
        assert!(s1.stats.gap > 1e3 * s0.stats.gap.abs(), "{} vs {}", s1.stats.gap, s0.stats.gap);
    }
}

/// The dual is a lower bound and the primal an upper bound of the optimum at every sweep.
#[test]
fn weak_duality_along_the_way() {
    let g = gen(5, 300, 16, 2.0, 1e-4, 1.0, 0.8);
    let p = Problem::dense(&g.a, &g.b, &g.c).unwrap();
    let opt = solve(&p, &params(0.05, 1.0, 2.0, 50_000, Some(1e-9))).unwrap().stats.objective;
    for it in [1, 2, 5, 30] {
        let s = solve(&p, &params(0.05, 1.0, 2.0, it, None)).unwrap();
        assert!(s.stats.dual <= opt + 1e-7 && s.stats.objective >= opt - 1e-7, "{it}: {:?}", s.stats);
    }
}

/// A sparse support equals the dense problem with +inf cost off the support; top-k
/// equals the explicit support it selects.
#[test]
fn sparse_matches_dense_with_infinite_costs() {
    let (n, m, k) = (2000, 32, 40);
    let g = gen(21, n, m, 4.0, 1e-6, 1.0, 0.7);
    let sp = SparseCost::top_k(&g.c, n, m, k).unwrap();
    assert_eq!(sp.nnz(), k * m);
    let mut dense_inf = vec![f32::INFINITY; n * m];
    let (mut si, mut sj, mut sc) = (vec![], vec![], vec![]);
    for (i, j, c) in sp.iter() {
        dense_inf[i * m + j] = c;
        si.push(i as u32);
        sj.push(j as u32);
        sc.push(c);
    }
    for &(eps, ts, tt) in &[(0.05, 1.0, 1.0), (0.01, 0.2, 5.0), (0.3, 2.0, INF)] {
        let pr = params(eps, ts, tt, 30, None);
        let pd = Problem::dense(&g.a, &g.b, &dense_inf).unwrap();
        let pk = Problem::top_k(&g.a, &g.b, &g.c, k).unwrap();
        let trip = SparseCost::from_triplets(n, m, &si, &sj, &sc).unwrap();
        let pt = Problem::sparse(&g.a, &g.b, trip).unwrap();
        let sd = solve(&pd, &pr).unwrap();
        let sk = solve(&pk, &pr).unwrap();
        let st = solve(&pt, &pr).unwrap();
        let td = sd.dense_plan(&pd);
        let tk = sk.dense_plan(&pk);
        let tt_ = st.dense_plan(&pt);
        let scale = max_abs(&td);
        assert!(max_abs_diff(&td, &tk) <= 1e-5 * scale, "eps {eps}");
        assert_eq!(tk, tt_);
        assert!((sd.stats.objective - sk.stats.objective).abs() <= 1e-5 * sd.stats.objective.abs());
        assert!((sd.stats.dual - sk.stats.dual).abs() <= 1e-5 * sd.stats.dual.abs());
        // Sources without support carry nothing and have f = +inf.
        let unsupported = (0..n).find(|&i| !sp.active_sources().contains(&(i as u32))).unwrap();
        assert_eq!(sk.row_mass[unsupported], 0.0);
        assert_eq!(sk.potentials.f[unsupported], f64::INFINITY);
        // The sparse plan follows the support's entry order.
        let vals = sk.sparse_plan(&pk);
        for ((i, j, _), v) in sp.iter().zip(&vals) {
            assert_eq!(*v, tk[i * m + j]);
        }
        // And the oracle agrees on the sparse problem too.
        let r = reference::solve_log_domain(&pk, &pr).unwrap();
        assert!(max_abs_diff(&r.dense_plan(&pk), &tk) <= 1e-4 * scale);
    }
}

/// Plan-weighted target means and transported masses without a dense plan.
#[test]
fn target_means_match_dense_plan() {
    let (n, m, d) = (500, 32, 16);
    let g = gen(31, n, m, 2.0, 1e-5, 1.0, 1.0);
    let mut r = ChaCha8Rng::seed_from_u64(3);
    let e: Vec<f32> = (0..m * d).map(|_| r.gen_range(-1.0..1.0)).collect();
    for k in [0, 20] {
        let p = Problem::top_k(&g.a, &g.b, &g.c, k).unwrap();
        let s = solve(&p, &params(0.05, 1.0, 1.0, 30, None)).unwrap();
        let t = s.dense_plan(&p);
        let delta = 1e-6f32;
        let (y, w) = s.target_means(&p, &e, d, delta);
        for i in 0..n {
            let wi: f64 = (0..m).map(|j| t[i * m + j] as f64).sum();
            assert!((w[i] as f64 - wi).abs() <= 1e-5 * wi + 1e-12);
            assert!((s.row_mass[i] - wi).abs() <= 1e-5 * wi + 1e-12, "{} vs {wi}", s.row_mass[i]);
            for c in 0..d {
                let num: f64 = (0..m).map(|j| t[i * m + j] as f64 * e[j * d + c] as f64).sum();
                let want = num / (wi + delta as f64);
                assert!((y[i * d + c] as f64 - want).abs() < 1e-5, "y[{i},{c}] {} vs {want}", y[i * d + c]);
            }
        }
        // Target vectors whose length is not a multiple of eight (the register blocks'
        // remainder): the first five components of each e_j.
        let d5 = 5;
        let e5: Vec<f32> = e.chunks(d).flat_map(|ej| ej[..d5].to_vec()).collect();
        let (y5, w5) = s.target_means(&p, &e5, d5, delta);
        assert_eq!(w5, w);
        for i in 0..n {
            for c in 0..d5 {
                let num: f64 = (0..m).map(|j| t[i * m + j] as f64 * e5[j * d5 + c] as f64).sum();
                let want = num / (w[i] as f64 + delta as f64);
                assert!(
                    (y5[i * d5 + c] as f64 - want).abs() < 1e-5,
                    "d = 5: y[{i},{c}] {} vs {want}",
                    y5[i * d5 + c]
                );
            }
        }
        // Without target vectors: the same masses, no means.
        let (y0, w0) = s.target_means(&p, &[], 0, delta);
        assert!(y0.is_empty());
        assert_eq!(w0, w);
        let cg = s.cost_gradient(&p);
        if k == 0 {
            assert_eq!(cg, t);
        }
    }
}

#[test]
fn bad_input_is_a_clear_error() {
    let a = [0.5f32, 0.5];
    let b = [1.0f32];
    let c = [1.0f32, 2.0];
    assert!(matches!(Problem::dense(&a, &b, &c[..1]), Err(Error::Shape { .. })));
    assert!(matches!(Problem::dense(&[0.5, -0.1], &b, &c), Err(Error::BadMass { index: 1, .. })));
    assert!(matches!(Problem::dense(&[0.5, f32::NAN], &b, &c), Err(Error::BadMass { .. })));
    assert!(matches!(Problem::dense(&a, &[f32::INFINITY], &c), Err(Error::BadMass { .. })));
    assert!(matches!(
        Problem::dense(&a, &b, &[1.0, f32::NAN]),
        Err(Error::BadCost { source_index: 1, target: 0, .. })
    ));
    assert!(matches!(Problem::dense(&a, &b, &[-1.0, 1.0]), Err(Error::BadCost { .. })));
    let p = Problem::dense(&a, &b, &c).unwrap();
    for (eps, ts, tt) in [(0.0, 1.0, 1.0), (-1.0, 1.0, 1.0), (f64::NAN, 1.0, 1.0), (INF, 1.0, 1.0)] {
        assert!(matches!(solve(&p, &Params::new(eps, ts, tt)), Err(Error::BadEps(_))));
    }
    for (ts, tt) in [(0.0, 1.0), (1.0, -2.0), (f64::NAN, 1.0)] {
        assert!(matches!(solve(&p, &Params::new(0.1, ts, tt)), Err(Error::BadTau { .. })));
    }
    let warm = Params {
        warm_start: Some(Potentials { f: vec![0.0; 3], g: vec![0.0] }),
        ..Params::new(0.1, 1.0, 1.0)
    };
    assert!(matches!(solve(&p, &warm), Err(Error::Shape { .. })));
    // Hard marginals that cannot be met.
    let pi = Problem::dense(&a, &b, &[1.0, f32::INFINITY]).unwrap();
    assert!(matches!(solve(&pi, &Params::new(0.1, INF, 1.0)), Err(Error::Infeasible { index: 1, .. })));
    assert!(solve(&pi, &Params::new(0.1, 1.0, INF)).is_ok());
    assert!(solve(&p, &Params::new(0.1, INF, INF)).is_ok());
    let pm = Problem::dense(&a, &[2.0], &c).unwrap();
    assert!(matches!(solve(&pm, &Params::new(0.1, INF, INF)), Err(Error::MassMismatch { .. })));
    let e = solve(&pm, &Params::new(0.1, INF, INF)).unwrap_err().to_string();
    assert!(e.contains("equal total masses"), "{e}");
}

#[test]
fn zero_masses_give_an_empty_plan() {
    let c = [1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0];
    for (a, b) in
        [([0f32, 0.0], [0f32, 0.0, 0.0]), ([0.0, 0.0], [0.2, 0.3, 0.0]), ([0.5, 0.5], [0.0, 0.0, 0.0])]
    {
        let p = Problem::dense(&a, &b, &c).unwrap();
        for (ts, tt) in [(1.0, 1.0), (INF, 2.0), (INF, INF)] {
            let s = solve(&p, &Params::new(0.1, ts, tt)).unwrap();
            assert!(s.dense_plan(&p).iter().all(|&x| x == 0.0));
            assert!(s.row_mass.iter().chain(&s.col_mass).all(|&x| x == 0.0));
            let st = &s.stats;
            for v in [st.objective, st.dual, st.gap, st.transported_mass, st.transport_cost] {
                assert!(v.is_finite(), "{st:?}");
            }
        }
    }
    // Some zero masses inside an otherwise normal problem.
    let a = [0.0f32, 0.6, 0.4];
    let b = [0.5f32, 0.0];
    let p = Problem::dense(&a, &b, &c).unwrap();
    let s = solve(&p, &Params::new(0.1, 1.0, 1.0)).unwrap();
    let t = s.dense_plan(&p);
    assert!(t.iter().all(|x| x.is_finite()));
    assert_eq!(t[0], 0.0);
    assert_eq!(t[1], 0.0);
    assert_eq!(t[3], 0.0);
    assert!(t[2] > 0.0);
    assert!(s.stats.objective.is_finite() && s.stats.gap.is_finite());
}

/// eps far below the cost range: finite results, and still the oracle's answer.
#[test]
fn tiny_eps_large_costs() {
    let g = gen(41, 300, 32, 100.0, 1e-7, 1.0, 0.5);
    let p = Problem::dense(&g.a, &g.b, &g.c).unwrap();
    for (ts, tt) in [(1.0, 1.0), (0.1, INF), (INF, 10.0)] {
        for iters in [30, 3000] {
            let pr = params(1e-3, ts, tt, iters, None);
            let s = solve(&p, &pr).unwrap();
            let t = s.dense_plan(&p);
            assert!(t.iter().all(|x| x.is_finite()));
            let st = &s.stats;
            for v in [st.objective, st.dual, st.gap, st.transported_mass, st.transport_cost] {
                assert!(v.is_finite(), "{st:?}");
            }
            assert!(s.potentials.f.iter().chain(&s.potentials.g).all(|x| !x.is_nan()));
            let r = reference::solve_log_domain(&p, &pr).unwrap();
            let tr = r.dense_plan(&p);
            let scale = max_abs(&tr);
            assert!(max_abs_diff(&t, &tr) <= 1e-3 * scale, "ts {ts} tt {tt}: {:?}", s.stats);
            let (o1, o2) = (s.stats.objective, r.stats.objective);
            assert!((o1 - o2).abs() <= 1e-3 * o2.abs(), "{o1} vs {o2}");
        }
    }
    // Costs that are all huge compared with eps: the plan is (numerically) empty but finite.
    let c = vec![100.0f32; 4 * 3];
    let p = Problem::dense(&[0.25; 4], &[0.3; 3], &c).unwrap();
    let s = solve(&p, &Params::new(1e-3, 1.0, 1.0)).unwrap();
    assert!(s.dense_plan(&p).iter().all(|x| x.is_finite()));
    assert!(s.stats.objective.is_finite() && s.stats.objective > 0.0);
}

/// Deterministic: the same input gives bit-identical output.
#[test]
fn deterministic() {
    let g = gen(51, 5000, 32, 2.0, 1e-6, 1.0, 1.0);
    let p = Problem::dense(&g.a, &g.b, &g.c).unwrap();
    let pr = Params::new(0.03, 1.0, 1.0);
    let s1 = solve(&p, &pr).unwrap();
    let s2 = solve(&p, &pr).unwrap();
    assert_eq!(s1.potentials, s2.potentials);
    assert_eq!(s1.stats, s2.stats);
}

/// Reusing a workspace across problems of different shapes gives the same results as
/// fresh solves.
#[test]
fn workspace_reuse_is_transparent() {
    use transsplat_transport::{solve_with, Workspace};
    let mut ws = Workspace::new();
    for (seed, n, m, k) in
        [(61u64, 3000usize, 32usize, 0usize), (62, 500, 32, 0), (63, 4000, 24, 0), (64, 2000, 32, 50)]
    {
        let g = gen(seed, n, m, 2.0, 1e-6, 1.0, 0.8);
        let p = Problem::top_k(&g.a, &g.b, &g.c, k).unwrap();
        let pr = Params::new(0.03, 1.0, 2.0);
        let fresh = solve(&p, &pr).unwrap();
        let reused = solve_with(&mut ws, &p, &pr).unwrap();
        assert_eq!(fresh.potentials, reused.potentials);
        assert_eq!(fresh.stats, reused.stats);
    }
    assert!(ws.bytes() > 0);
}

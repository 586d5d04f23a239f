//! Parity with POT 0.9.x `ot.unbalanced.sinkhorn_unbalanced(a, b, C, reg=eps,
//! reg_m=(tau_s, tau_t), reg_type="kl")` on the fixtures written by
//! `tools/uot_fixtures.py`: eps in [0.005, 1], tau in {0.1, 1, 10, inf}, masses down to
//! 1e-7, sizes up to 10^4 x 32, after 30 iterations and at convergence.
//! Criteria: plan entries within 1e-3 of the plan's largest entry (all entries for small
//! cases, 576 sampled entries including the 64 largest otherwise), row and column sums
//! within 1e-3 of the largest, objective (generalised KL) and <C,T> within 1e-3 relative.

use serde_json::Value;
use std::path::PathBuf;
use transsplat_scene::npy;
use transsplat_transport::{solve, Params, Problem};

fn dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures")
}

/// splitmix64 uniforms, as `uniforms` in tools/uot_fixtures.py.
fn uniforms(seed: u64, start: u64, count: usize) -> Vec<f64> {
    (0..count as u64)
        .map(|k| {
            let mut z = seed.wrapping_add((start + k + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15));
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            (z >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
        })
        .collect()
}

fn cost(seed: u64, n: usize, m: usize, scale: f64) -> Vec<f32> {
    let u = uniforms(seed, 0, 2 * n + 2 * m);
    let (x, y) = u.split_at(2 * n);
    let mut c = vec![0f32; n * m];
    for i in 0..n {
        for j in 0..m {
            let dx = x[2 * i] - y[2 * j];
            let dy = x[2 * i + 1] - y[2 * j + 1];
            c[i * m + j] = (scale * (dx * dx + dy * dy)) as f32;
        }
    }
    c
}

fn tau(v: &Value) -> f64 {
    match v {
        Value::String(s) if s == "inf" => f64::INFINITY,
        v => v.as_f64().expect("tau"),
    }
}

struct Worst {
    plan: f64,
    marg: f64,
    obj: f64,
    lin: f64,
}

#[test]
fn pot_parity() {
    let index: Value =
        serde_json::from_slice(&std::fs::read(dir().join("index.json")).expect("fixtures/index.json"))
            .unwrap();
    let data = npy::read(&dir().join("data.npy")).expect("fixtures/data.npy").data;
    let get = |v: &Value| -> &[f32] {
        let o = v[0].as_u64().unwrap() as usize;
        let l = v[1].as_u64().unwrap() as usize;
        &data[o..o + l]
    };
    let cases = index["cases"].as_array().unwrap();
    assert!(cases.len() >= 100, "fixture index too small");
    let mut worst = [
        ("30", Worst { plan: 0.0, marg: 0.0, obj: 0.0, lin: 0.0 }),
        ("conv", Worst { plan: 0.0, marg: 0.0, obj: 0.0, lin: 0.0 }),
    ];
    let mut failures = Vec::new();
    for cs in cases {
        let name = cs["name"].as_str().unwrap();
        let (n, m) = (cs["n"].as_u64().unwrap() as usize, cs["m"].as_u64().unwrap() as usize);
        let eps = cs["eps"].as_f64().unwrap();
        let (ts, tt) = (tau(&cs["tau_s"]), tau(&cs["tau_t"]));
        let mode = cs["mode"].as_str().unwrap();
        let c = cost(cs["seed"].as_u64().unwrap(), n, m, cs["scale"].as_f64().unwrap());
        let chk = &cs["cost_check"];
        let sum: f64 = c.iter().map(|&x| x as f64).sum();
        assert!(
            (sum - chk["sum"].as_f64().unwrap()).abs() <= 1e-9 * sum.abs(),
            "{name}: cost regeneration differs"
        );
        assert_eq!(c[0], chk["first"].as_f64().unwrap() as f32, "{name}");
        assert_eq!(c[n * m - 1], chk["last"].as_f64().unwrap() as f32, "{name}");
        let (a, b) = (get(&cs["a"]), get(&cs["b"]));
        let p = Problem::dense(a, b, &c).unwrap();
        let params = if mode == "30" {
            Params::new(eps, ts, tt)
        } else {
            Params { max_iters: 60_000, tol: Some(2e-7), ..Params::new(eps, ts, tt) }
        };
        let s = solve(&p, &params).unwrap();
        let tmax = cs["plan_max"].as_f64().unwrap();
        let plan_err = if let Some(pl) = cs.get("plan") {
            let t = s.dense_plan(&p);
            t.iter().zip(get(pl)).map(|(x, y)| (x - y).abs() as f64).fold(0.0, f64::max)
        } else {
            let idx = get(&cs["sample_idx"]);
            let val = get(&cs["sample_val"]);
            let t = s.dense_plan(&p);
            idx.iter().zip(val).map(|(&k, &v)| (t[k as usize] - v).abs() as f64).fold(0.0, f64::max)
        } / tmax;
        let marg = |ours: &[f64], want: &[f32]| {
            let mx = want.iter().fold(0f32, |x, y| x.max(*y)) as f64;
            ours.iter().zip(want).map(|(x, y)| (x - *y as f64).abs()).fold(0.0, f64::max) / mx
        };
        let marg_err = marg(&s.row_mass, get(&cs["rows"])).max(marg(&s.col_mass, get(&cs["cols"])));
        let o = cs["objective"].as_f64().unwrap();
        let obj_err = (s.stats.objective - o).abs() / o.abs();
        let lc = cs["linear_cost"].as_f64().unwrap();
        let lin_err = (s.stats.transport_cost - lc).abs() / lc.abs();
        let w = &mut worst[if mode == "30" { 0 } else { 1 }].1;
        w.plan = w.plan.max(plan_err);
        w.marg = w.marg.max(marg_err);
        w.obj = w.obj.max(obj_err);
        w.lin = w.lin.max(lin_err);
        if plan_err > 1e-3 || marg_err > 1e-3 || obj_err > 1e-3 || lin_err > 1e-3 {
            failures.push(format!(
                "{name} n={n} m={m} eps={eps} tau=({ts},{tt}) {mode}: plan {plan_err:.2e} marginals {marg_err:.2e} \
                 objective {obj_err:.2e} ({} vs {o}) <C,T> {lin_err:.2e}, {} sweeps",
                s.stats.objective, s.stats.iterations
            ));
        }
    }
    for (mode, w) in &worst {
        println!(
            "worst over {mode} cases: plan {:.2e} of max entry, marginals {:.2e}, objective {:.2e}, <C,T> {:.2e}",
            w.plan, w.marg, w.obj, w.lin
        );
    }
    assert!(
        failures.is_empty(),
        "{} of {} cases differ from POT:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n")
    );
}

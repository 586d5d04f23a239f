#!/usr/bin/env python3
"""Parity fixtures for the unbalanced transport solver (crates/transport).

Runs POT's ``ot.unbalanced.sinkhorn_unbalanced(a, b, C, reg=eps, reg_m=(tau_s, tau_t),
reg_type="kl")`` (POT >= 0.9.5; its default reference measure for reg_type="kl" is
c = a b^T, which is exactly the paper's KL(T || a b^T), so no ``c=`` argument is needed)
on reproducible random problems and writes what the Rust test
``crates/transport/tests/pot_parity.rs`` compares against.

Run by hand (CI runs no Python):  pip install pot numpy && python3 tools/uot_fixtures.py

Problems. Costs are not stored: both sides regenerate them from a seed with splitmix64
(``uniforms`` below, mirrored in the Rust test): points x_i, u_j in the unit square,
C_ij = float32(scale * ((x_i0-u_j0)^2 + (x_i1-u_j1)^2)), evaluated in float64 in exactly
that operation order. Masses are log-uniform in [1e-7, 1] (so the smallest are ~1e-7 of
the largest), scaled to a total, and stored as float32. POT runs in float64 on exactly
those float32 values.

Results per case: the objective recomputed here with the generalised KL
(sum p log(p/q) - p + q; POT's total_cost drops the mass terms), POT's linear cost
log["cost"], the number of POT iterations, row and column sums of the plan, and the plan
itself when it has at most 2048 entries, otherwise 512 sampled entries plus the 64
largest (indices stored as float32, exact below 2^24). All arrays are float32 and
concatenated into one ``data.npy``; ``index.json`` gives each as [offset, length].

"30 iterations" cases run numItermax=30 with stopThr=0 (never met); "converged" cases
run to stopThr=1e-10 (POT's relative change of the scalings u, v), at most 50000
iterations, accepting a last change below 1e-8 (slow contraction at tau ~ 10, eps =
0.005), or below 1e-6 for balanced cases, which stall at the floor set by the float32
totals of a and b differing by ~1e-9.
"""

import json
import os
import sys
import warnings

import numpy as np
import ot

OUT = os.path.join(os.path.dirname(__file__), "..", "crates", "transport", "tests", "fixtures")
MASK = (1 << 64) - 1


def uniforms(seed, start, count):
    """splitmix64(seed + (k+1) * golden) >> 11, scaled to [0, 1), for k in [start, start+count)."""
    k = np.arange(start, start + count, dtype=np.uint64)
    z = np.uint64(seed) + (k + np.uint64(1)) * np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)).astype(np.float64) * (1.0 / float(1 << 53))


def cost(seed, n, m, scale):
    u = uniforms(seed, 0, 2 * n + 2 * m)
    x = u[: 2 * n].reshape(n, 2)
    y = u[2 * n :].reshape(m, 2)
    dx = x[:, None, 0] - y[None, :, 0]
    dy = x[:, None, 1] - y[None, :, 1]
    return (scale * (dx * dx + dy * dy)).astype(np.float32)


def masses(seed, start, k, total):
    u = uniforms(seed, start, k)
    v = np.exp(np.log(1e-7) * u)
    return (v * (total / v.sum())).astype(np.float32)


def blob_get(blob, ref):
    return np.concatenate(blob)[ref[0] : ref[0] + ref[1]]


def gen_kl(p, q):
    p = np.asarray(p, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    pos = p > 0
    out = np.sum(q - p)
    out += np.sum(p[pos] * np.log(p[pos] / q[pos]))
    return float(out)


def objective(T, C, a, b, eps, ts, tt):
    obj = float(np.sum(T * C)) + eps * gen_kl(T, a[:, None] * b[None, :])
    if np.isfinite(ts):
        obj += ts * gen_kl(T.sum(1), a)
    if np.isfinite(tt):
        obj += tt * gen_kl(T.sum(0), b)
    return obj


def tau_json(t):
    return "inf" if not np.isfinite(t) else t


INF = float("inf")
TAUS = [(0.1, 0.1), (1.0, 10.0), (10.0, 1.0), (INF, 1.0), (1.0, INF), (INF, INF), (10.0, 10.0)]


def cases():
    out = []
    # Small, full plans stored: every eps x tau, both modes.
    for ei, eps in enumerate([0.005, 0.02, 0.1, 1.0]):
        for ti, (ts, tt) in enumerate(TAUS):
            for mode in ["30", "conv"]:
                out.append(dict(n=60, m=32, eps=eps, tau_s=ts, tau_t=tt, mode=mode, seed=100 + ei * 10 + ti, scale=1.0))
    # Medium: the same grid, summaries.
    for ei, eps in enumerate([0.005, 0.02, 0.1, 1.0]):
        for ti, (ts, tt) in enumerate(TAUS):
            for mode in ["30", "conv"]:
                out.append(dict(n=1000, m=32, eps=eps, tau_s=ts, tau_t=tt, mode=mode, seed=200 + ei * 10 + ti, scale=2.0))
    # Large: 10^4 x 32.
    for eps in [0.01, 0.1]:
        for ts, tt in [(1.0, 1.0), (INF, 1.0), (0.1, 10.0), (INF, INF)]:
            for mode in ["30", "conv"]:
                out.append(dict(n=10000, m=32, eps=eps, tau_s=ts, tau_t=tt, mode=mode, seed=300, scale=2.0))
    # Tiny odd shapes.
    out.append(dict(n=1, m=1, eps=0.1, tau_s=1.0, tau_t=0.5, mode="conv", seed=1, scale=3.0))
    out.append(dict(n=5, m=3, eps=0.05, tau_s=0.1, tau_t=INF, mode="30", seed=2, scale=3.0))
    out.append(dict(n=3, m=7, eps=0.5, tau_s=INF, tau_t=INF, mode="conv", seed=3, scale=3.0))
    return out


def main():
    os.makedirs(OUT, exist_ok=True)
    for f in os.listdir(OUT):
        if f.endswith(".npy") or f == "index.json":
            os.remove(os.path.join(OUT, f))
    index = {"generator": "tools/uot_fixtures.py", "pot_version": ot.__version__, "numpy_version": np.__version__, "cases": []}
    mass_files = {}

    blob = []
    blob_len = 0

    def save(name, arr):
        """Appends a float32 array to the single data file; returns [offset, length]."""
        nonlocal blob_len
        arr = np.ascontiguousarray(arr, dtype=np.float32).ravel()
        ref = [blob_len, int(arr.size)]
        blob.append(arr)
        blob_len += arr.size
        return ref

    for ci, cs in enumerate(cases()):
        n, m, eps, ts, tt = cs["n"], cs["m"], cs["eps"], cs["tau_s"], cs["tau_t"]
        seed = cs["seed"]
        balanced = not np.isfinite(ts) and not np.isfinite(tt)
        tot_a, tot_b = (1.0, 1.0) if balanced else (1.0, 0.6)
        key = (seed, n, m, tot_a, tot_b)
        if key not in mass_files:
            a = masses(seed, 2 * n + 2 * m, n, tot_a)
            b = masses(seed, 3 * n + 2 * m, m, tot_b)
            mass_files[key] = (save("a", a), save("b", b))
        fa, fb = mass_files[key]
        a = blob_get(blob, fa).astype(np.float64)
        b = blob_get(blob, fb).astype(np.float64)
        C32 = cost(seed, n, m, cs["scale"])
        C = C32.astype(np.float64)
        iters, thr = (30, 0.0) if cs["mode"] == "30" else (50000, 1e-10)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            T, log = ot.unbalanced.sinkhorn_unbalanced(
                a, b, C, reg=eps, reg_m=(ts, tt), reg_type="kl", numItermax=iters, stopThr=thr, log=True
            )
        pot_iters = len(log["err"])
        if cs["mode"] == "conv" and pot_iters >= iters:
            # Balanced problems whose float32 totals differ by ~1e-9 stall at that floor
            # (the hard marginals cannot both hold); anything else must converge.
            if not (log["err"][-1] < 1e-8 or (balanced and log["err"][-1] < 1e-6)):
                sys.exit(f"case {ci}: POT did not converge in {iters} iterations (err {log['err'][-1]})")
        assert np.all(np.isfinite(T))
        name = f"c{ci:03d}"
        entry = dict(
            name=name,
            n=n,
            m=m,
            eps=eps,
            tau_s=tau_json(ts),
            tau_t=tau_json(tt),
            mode=cs["mode"],
            iters=iters if cs["mode"] == "30" else None,
            pot_iterations=pot_iters,
            seed=seed,
            scale=cs["scale"],
            a=fa,
            b=fb,
            cost_check=dict(sum=float(C.sum()), first=float(C32.flat[0]), last=float(C32.flat[-1])),
            objective=objective(T, C, a, b, eps, ts, tt),
            linear_cost=float(log["cost"]),
            plan_max=float(T.max()),
            rows=save(None, T.sum(1).astype(np.float32)),
            cols=save(None, T.sum(0).astype(np.float32)),
        )
        if n * m <= 2048:
            entry["plan"] = save(None, T.astype(np.float32))
        else:
            rng = np.random.default_rng(seed + ci)
            idx = np.unique(np.concatenate([rng.choice(n * m, 512, replace=False), np.argsort(T.ravel())[-64:]]))
            entry["sample_idx"] = save(None, idx.astype(np.float32))
            entry["sample_val"] = save(None, T.ravel()[idx].astype(np.float32))
        index["cases"].append(entry)
        print(f"{name}: n={n} m={m} eps={eps} tau=({ts},{tt}) {cs['mode']}: POT {pot_iters} its, objective {entry['objective']:.6e}")
    np.save(os.path.join(OUT, "data.npy"), np.concatenate(blob))
    with open(os.path.join(OUT, "index.json"), "w") as f:
        json.dump(index, f, indent=1)
    total_bytes = sum(os.path.getsize(os.path.join(OUT, x)) for x in ["data.npy", "index.json"])
    print(f"{len(index['cases'])} cases, {total_bytes / 1e6:.2f} MB in {os.path.normpath(OUT)}")


if __name__ == "__main__":
    main()

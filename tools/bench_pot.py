#!/usr/bin/env python3
"""Times POT on the exact problems of `transsplat bench transport`.

    transsplat bench transport --write-problem /tmp/uot_bench      # writes a_N, b_N, C_N .npy
    python3 tools/bench_pot.py /tmp/uot_bench [--eps 0.05 --tau-s 1 --tau-t 1 --iters 30]

Runs ``ot.unbalanced.sinkhorn_unbalanced(a, b, C, reg=eps, reg_m=(tau_s, tau_t),
reg_type="kl", numItermax=iters, stopThr=0)`` (stopThr=0 is never met, so exactly
`iters` iterations) in float64, as POT is normally used, and also in float32, and prints
the best-of-`--repeat` wall time per size. Pass the Rust bench's times with
``--rust-ms N=ms,...`` to get the ratio printed. Needs `pip install pot numpy`.
"""

import argparse
import glob
import json
import os
import re
import time
import warnings

import numpy as np
import ot


def tau(s):
    return float("inf") if s.lower() in ("inf", "infinity") else float(s)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dir")
    ap.add_argument("--eps", type=float, default=0.05)
    ap.add_argument("--tau-s", type=tau, default=1.0)
    ap.add_argument("--tau-t", type=tau, default=1.0)
    ap.add_argument("--iters", type=int, default=30)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--rust-ms", default="", help="e.g. 100000=41.0,1000000=464.4")
    args = ap.parse_args()
    rust = {}
    for kv in filter(None, args.rust_ms.split(",")):
        k, v = kv.split("=")
        rust[int(k)] = float(v)
    sizes = sorted(int(re.search(r"C_(\d+)\.npy", p).group(1)) for p in glob.glob(os.path.join(args.dir, "C_*.npy")))
    if not sizes:
        raise SystemExit(f"no C_N.npy in {args.dir}; run `transsplat bench transport --write-problem {args.dir}`")
    results = []
    for n in sizes:
        a32 = np.load(os.path.join(args.dir, f"a_{n}.npy"))
        b32 = np.load(os.path.join(args.dir, f"b_{n}.npy"))
        C32 = np.load(os.path.join(args.dir, f"C_{n}.npy"))
        row = {"n": n, "m": int(C32.shape[1]), "pot_version": ot.__version__}
        for dtype in (np.float64, np.float32):
            a, b, C = a32.astype(dtype), b32.astype(dtype), C32.astype(dtype)
            best = float("inf")
            objective = None
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    T = ot.unbalanced.sinkhorn_unbalanced(
                        a, b, C, reg=args.eps, reg_m=(args.tau_s, args.tau_t), reg_type="kl",
                        numItermax=args.iters, stopThr=0.0,
                    )
                best = min(best, time.perf_counter() - t0)
                mass = float(T.sum())
            key = "float64" if dtype == np.float64 else "float32"
            row[f"pot_{key}_ms"] = best * 1e3
            row[f"pot_{key}_mass"] = mass
            line = f"n = {n} x {C32.shape[1]}: POT {key} {best * 1e3:9.1f} ms (plan mass {mass:.4f})"
            if n in rust:
                row[f"ratio_{key}"] = best * 1e3 / rust[n]
                line += f"   -> Rust {rust[n]:.1f} ms is {best * 1e3 / rust[n]:.1f}x faster"
            print(line, flush=True)
        results.append(row)
    print(json.dumps({"bench": "pot", "eps": args.eps, "tau_s": str(args.tau_s), "tau_t": str(args.tau_t), "iters": args.iters, "results": results}))


if __name__ == "__main__":
    main()

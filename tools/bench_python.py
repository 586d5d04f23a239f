#!/usr/bin/env python3
"""The overhead of a rasterization call from Python against the same call in the
binary: the synthetic scene and camera of `transsplat bench raster` (identical input),
forward and backward, best of REPS, in one session.

    tools/bench_python.py [--gaussians 100000,1000000] [--size 512] [--reps 5]

Needs the `transsplat` package installed (tools/python_tests.sh builds it) and
target/release/transsplat. Prints one table; ratios > 1 mean Python is slower.
"""

import argparse
import json
import pathlib
import subprocess
import time

import numpy as np

import transsplat

ROOT = pathlib.Path(__file__).resolve().parents[1]


def best(reps, fn):
    t = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        t.append(time.perf_counter() - t0)
    return min(t)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--gaussians", default="100000,1000000")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--reps", type=int, default=5)
    args = ap.parse_args()
    counts = [int(c) for c in args.gaussians.split(",")]
    rows = []
    for n in counts:
        g, cam = transsplat._core.bench_scene(n, args.size)
        a = (
            g["means"], g["quats"], np.exp(g["log_scales"]), 1 / (1 + np.exp(-g["opacity_logits"])), g["sh"],
            cam["viewmats"], cam["Ks"], args.size, args.size,
        )
        a = tuple(np.ascontiguousarray(x, np.float32) if isinstance(x, np.ndarray) else x for x in a)
        fwd = best(args.reps, lambda: transsplat.rasterization(*a, sh_degree=3))
        _, _, meta = transsplat.rasterization(*a, sh_degree=3)
        px = args.size * args.size
        v = (((np.arange(px * 3) * 7919) % 17) / 17.0 - 0.5).astype(np.float32)
        vc = v.reshape(1, args.size, args.size, 3)
        va = v[:px].reshape(1, args.size, args.size, 1)
        bwd = best(args.reps, lambda: meta["vjp"](vc, va))
        r = subprocess.run(
            [str(ROOT / "target/release/transsplat"), "bench", "raster", "--gaussians", str(n),
             "--size", str(args.size), "--reps", str(args.reps)],
            capture_output=True, text=True, check=True,
        )
        rust = json.loads([l for l in r.stdout.splitlines() if l.startswith("{")][-1])
        rows.append((n, fwd, rust["forward_s"], bwd, rust["backward_s"]))
    print(f"{'gaussians':>10} {'py fwd s':>9} {'rust fwd s':>10} {'ratio':>6} {'py bwd s':>9} {'rust bwd s':>10} {'ratio':>6}")
    for n, pf, rf, pb, rb in rows:
        print(f"{n:>10} {pf:>9.4f} {rf:>10.4f} {pf / rf:>6.3f} {pb:>9.4f} {rb:>10.4f} {pb / rb:>6.3f}")


if __name__ == "__main__":
    main()

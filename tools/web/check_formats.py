"""Checks our scene exports with a real reader: PlayCanvas splat-transform.

1. Our compressed PLY of a built-in scene has the same body, byte for byte, as the one
   splat-transform writes from the same PLY (same Morton order, chunk bounds and codes).
2. splat-transform reads our compressed PLY and our .spz with the same Gaussian count
   (its `-m` summary), and writes them back as plain PLYs.
3. Those PLYs, rendered by transsplat at the scene's cameras, match the original scene's
   renders within the format's quantisation (PSNR printed and bounded below).

Usage: python check_formats.py BIN SPLAT_TRANSFORM WORKDIR. Exits non-zero on failure.
"""

import glob
import os
import re
import subprocess
import sys

import numpy as np


def run(*args):
    r = subprocess.run([str(a) for a in args], capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"command failed: {' '.join(map(str, args))}\n{r.stdout}\n{r.stderr}")
    return r.stdout


def body(path):
    b = open(path, "rb").read()
    return b[b.index(b"end_header\n") + 11 :]


def row_count(st, path):
    out = run(st, path, "-m", "null")
    m = re.search(r"Row Count:\**\s*([0-9]+)", out)
    if not m:
        sys.exit(f"no row count in splat-transform's summary of {path}:\n{out}")
    return int(m.group(1))


def psnr(a, b):
    mse = np.mean((np.clip(a, 0, 1) - np.clip(b, 0, 1)) ** 2)
    return 10 * np.log10(1.0 / max(mse, 1e-12))


def main():
    bin_, st, work = sys.argv[1:4]
    os.makedirs(work, exist_ok=True)
    ds = os.path.join(work, "ds")
    run(bin_, "scene", "tabletop", "--out", ds, "--force")
    src = os.path.join(ds, "point_cloud", "iteration_0", "point_cloud.ply")
    count = int(re.search(r"gaussians\s+([0-9]+)", run(bin_, "info", src)).group(1))
    ours_c = os.path.join(work, "ours.compressed.ply")
    ours_s = os.path.join(work, "ours.spz")
    run(bin_, "convert", src, ours_c)
    run(bin_, "convert", src, ours_s)

    theirs_c = os.path.join(work, "theirs.compressed.ply")
    run(st, "-w", src, theirs_c)
    same = body(ours_c) == body(theirs_c)
    print(f"compressed PLY body identical to splat-transform's: {same}")
    if not same:
        sys.exit("our compressed PLY differs from splat-transform's")

    failures = []
    renders = {}
    for name, path, floor in [("compressed PLY", ours_c, 45.0), ("SPZ", ours_s, 42.0)]:
        n = row_count(st, path)
        back = os.path.join(work, f"st_{os.path.basename(path)}.ply")
        run(st, "-w", path, back)
        out = os.path.join(work, f"r_{os.path.basename(path)}")
        run(bin_, "render", "--scene", back, "--cameras", os.path.join(ds, "cameras.json"), "--out", out, "--raw")
        renders[name] = (out, n, floor)
    ref = os.path.join(work, "r_src")
    run(bin_, "render", "--scene", src, "--cameras", os.path.join(ds, "cameras.json"), "--out", ref, "--raw")
    for name, (out, n, floor) in renders.items():
        ps = [psnr(np.load(f), np.load(os.path.join(out, os.path.basename(f)))) for f in sorted(glob.glob(f"{ref}/*.npy"))]
        print(
            f"{name}: splat-transform reads {n} Gaussians (of {count}); its plain-PLY rewrite renders at "
            f"mean {np.mean(ps):.2f} dB, min {np.min(ps):.2f} dB PSNR against the original over {len(ps)} views"
        )
        if n != count:
            failures.append(f"{name}: {n} Gaussians read, {count} written")
        if np.min(ps) < floor:
            failures.append(f"{name}: PSNR {np.min(ps):.2f} below {floor}")
    if failures:
        sys.exit("; ".join(failures))
    print("formats check passed")


if __name__ == "__main__":
    main()

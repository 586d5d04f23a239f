#!/usr/bin/env python3
"""Where a trained mesh capture's held-out views lose: floor and sky against the table
and objects, bands of rows, and the heights of the far Gaussians.

    python3 tools/train_view_breakdown.py --train OUT --capture caps/rings

OUT is a `transsplat train` output folder (its `test_renders/` and newest
`point_cloud.ply`); the capture is the folder `tools/mesh_captures.py` wrote (its
`images/` and `labels/`). Prints, per test view, the PSNR of the whole image, of the
pixels whose every supersample is label 0 (floor or sky), of the others (table and
objects), and of eight bands of rows; then the mean and the worst view's distance below
it for each; then, per distance band from the table's axis, how much of the Gaussians'
opacity lies on the floor (|z| < 5 cm) and above it (z > 20 cm), and their median
largest scale and opacity. Needs numpy and pillow. docs/results.md, "Training on mesh
captures", quotes its output.
"""

import argparse
import glob
import os
import re

import numpy as np
from PIL import Image


def psnr(err):
    return -10.0 * np.log10(max(float(err.mean()), 1e-12))


def read_ply(path):
    data = open(path, "rb").read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode()
    props = re.findall(r"property float (\S+)", header)
    if len(props) != header.count("property "):
        raise SystemExit(f"{path}: only all-float PLYs are read here")
    n = int(re.search(r"element vertex (\d+)", header).group(1))
    rows = np.frombuffer(data[end:], dtype="<f4", count=n * len(props)).reshape(n, len(props))
    return {name: rows[:, k] for k, name in enumerate(props)}


def views(train, capture):
    scores = []
    for path in sorted(glob.glob(os.path.join(train, "test_renders", "*.png"))):
        name = os.path.basename(path)
        truth = np.asarray(Image.open(os.path.join(capture, "images", name)).convert("RGB"), float) / 255
        render = np.asarray(Image.open(path).convert("RGB"), float) / 255
        err = ((truth - render) ** 2).mean(-1)
        labels = np.asarray(Image.open(os.path.join(capture, "labels", name)))
        s = labels.shape[0] // err.shape[0]
        floor = (labels.reshape(err.shape[0], s, err.shape[1], s) == 0).all(axis=(1, 3))
        bands = np.array_split(err, 8, axis=0)
        scores.append((name, psnr(err), psnr(err[floor]), psnr(err[~floor]), [psnr(b) for b in bands]))
    return scores


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--train", required=True, help="a transsplat train output folder")
    ap.add_argument("--capture", required=True, help="the capture folder it was trained from")
    args = ap.parse_args()
    scores = views(args.train, args.capture)
    if not scores:
        raise SystemExit(f"{args.train}: no test_renders/*.png")
    for name, whole, floor, rest, bands in scores:
        print(f"{name}: whole {whole:.2f}, floor and sky {floor:.2f}, table and objects {rest:.2f} dB;"
              f" bands of rows {' '.join(f'{b:.1f}' for b in bands)}")
    table = np.array([s[1:4] for s in scores])
    for k, what in enumerate(["whole", "floor and sky", "table and objects"]):
        col = table[:, k]
        print(f"{what}: mean {col.mean():.2f} dB, worst view {col.mean() - col.min():.2f} dB below")
    plys = glob.glob(os.path.join(args.train, "point_cloud", "iteration_*", "point_cloud.ply"))
    ply = max(plys, key=lambda p: int(re.search(r"iteration_(\d+)", p).group(1)))
    g = read_ply(ply)
    r = np.hypot(g["x"], g["y"])
    opacity = 1 / (1 + np.exp(-g["opacity"]))
    largest = np.exp(np.stack([g["scale_0"], g["scale_1"], g["scale_2"]], 1)).max(1)
    print(f"{ply}: {len(r)} Gaussians")
    for lo, hi in [(2, 4), (4, 8), (8, 16), (16, 40)]:
        m = (r >= lo) & (r < hi)
        if not m.any():
            continue
        w, z = opacity[m], g["z"][m]
        print(f"{lo}-{hi} m from the axis: {m.sum()} Gaussians; opacity on the floor"
              f" {w[np.abs(z) < 0.05].sum() / w.sum():.2f}, above 20 cm {w[z > 0.2].sum() / w.sum():.2f};"
              f" median largest scale {np.median(largest[m]):.3f} m, opacity {np.median(w):.2f}")


if __name__ == "__main__":
    main()

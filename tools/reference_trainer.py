#!/usr/bin/env python3
"""Side-by-side anchor for `transsplat train` against a reference 3DGS trainer (issue #14).

    python3 tools/reference_trainer.py --opensplat /path/to/opensplat --out /tmp/anchor \
        [--size 256] [--iters 7000] [--views 48] [--points 6000] [--scene tabletop]
        [--transsplat-args "--strategy mcmc --max-gaussians 14000" --transsplat-label mcmc14k]

What it does, in order (every step is skipped when its output already exists, so an
interrupted run continues):

1. `transsplat scene SCENE --open --views V --width S --height S --points P` writes the
   capture: a built-in scene rendered with a large far background (a checkerboard floor
   to 20 m under a sky dome, a 360° orbit) and a sparse initial cloud, like an outdoor
   capture's. Its test views are INRIA's llffhold split: every 8th image in name order.
2. The same capture in nerfstudio layout for the reference (`transforms.json` with
   OpenGL camera-to-world matrices, the initial cloud as a PLY) holding **only the
   training views**, so the reference never sees a test image.
3. The reference trains (`opensplat DATA -n ITERS --keep-crs`, its defaults otherwise,
   plus `--opensplat-args`); `transsplat train --data CAPTURE --iters ITERS` trains too
   (its own split holds the test views out).
4. Both results are rendered at the test cameras by `transsplat render --raw` (the two
   rasterizers agree to 2e-4 once OpenSplat's depth order is fixed, see below), each
   over the background it trained with, and scored here in numpy: PSNR and INRIA's SSIM
   (11×11 Gaussian window, σ = 1.5, zero padding, C1 = 0.01², C2 = 0.03²) over whole
   images, every view, the worst view and the spread. transsplat's own `train.json`
   figures are printed beside the numpy ones as a cross-check of both evaluators.
   `--score-ply LABEL=PLY` adds a scene trained elsewhere on the same capture, rendered
   and scored the same way (black background): `tools/gsplat_reference.py` trains
   gsplat on a GPU and writes one, so its own figures are checked by this evaluator and
   by transsplat's rasterizer.
5. Writes `OUT/anchor.json` and prints one table: test PSNR / SSIM, worst view, views
   more than 3 dB below the mean, Gaussian count, wall time.

The reference is not built or shipped by this repository: pass the path of an OpenSplat
binary built for the CPU (`GPU_RUNTIME=CPU`). OpenSplat's CPU rasterizer hands a
strided view of the depths to a raw-pointer sort; make that tensor contiguous before
its `data_ptr()` (in `rasterizer/gsplat-cpu/gsplat_cpu.cpp`), or its depth order, and
so its images, are wrong.

Needs numpy and Pillow.
"""

import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
import time

import numpy as np

LLFF_HOLD = 8
# OpenSplat's fixed background colour (nerfstudio's default, `model.hpp`).
OPENSPLAT_BACKGROUND = (0.6130, 0.0101, 0.3984)


def run(cmd, log):
    """Runs `cmd` with stdout and stderr into `log`; exits on failure. Returns its wall seconds."""
    print("+", " ".join(cmd), flush=True)
    t0 = time.time()
    with open(log, "w") as f:
        r = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT)
    if r.returncode != 0:
        sys.exit(f"{cmd[0]} failed (exit {r.returncode}); see {log}")
    return time.time() - t0


def qvec_to_rot(q):
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * y * y - 2 * z * z, 2 * x * y - 2 * w * z, 2 * x * z + 2 * w * y],
            [2 * x * y + 2 * w * z, 1 - 2 * x * x - 2 * z * z, 2 * y * z - 2 * w * x],
            [2 * x * z - 2 * w * y, 2 * y * z + 2 * w * x, 1 - 2 * x * x - 2 * y * y],
        ]
    )


def read_colmap_text(sparse):
    """COLMAP text model: {camera id: (w, h, fx, fy, cx, cy)}, [(name, R_wc, t_wc, cam)]."""
    cams = {}
    for line in open(os.path.join(sparse, "cameras.txt")):
        if line.startswith("#") or not line.strip():
            continue
        p = line.split()
        if p[1] != "PINHOLE":
            sys.exit(f"{sparse}/cameras.txt: camera model {p[1]} (only PINHOLE is converted)")
        cams[int(p[0])] = (int(p[2]), int(p[3])) + tuple(float(v) for v in p[4:8])
    images = []
    lines = [l for l in open(os.path.join(sparse, "images.txt")) if not l.startswith("#")]
    for i in range(0, len(lines), 2):
        p = lines[i].split()
        if not p:
            continue
        q = [float(v) for v in p[1:5]]
        t = np.array([float(v) for v in p[5:8]])
        images.append((p[9], qvec_to_rot(q), t, int(p[8])))
    return cams, images


def read_points(sparse):
    xyz, rgb = [], []
    for line in open(os.path.join(sparse, "points3D.txt")):
        if line.startswith("#") or not line.strip():
            continue
        p = line.split()
        xyz.append([float(v) for v in p[1:4]])
        rgb.append([int(v) for v in p[4:7]])
    return np.array(xyz, np.float32), np.array(rgb, np.uint8)


def test_names(names):
    """INRIA's llffhold: every 8th image in name order is a test view."""
    return {n for i, n in enumerate(sorted(names)) if i % LLFF_HOLD == 0}


def write_nerfstudio(capture, out):
    """The capture's training views in nerfstudio layout (OpenGL camera-to-world)."""
    sparse = os.path.join(capture, "sparse", "0")
    cams, images = read_colmap_text(sparse)
    test = test_names([n for n, *_ in images])
    tmp = out + ".partial"
    shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(os.path.join(tmp, "images"))
    frames = []
    for name, r_wc, t_wc, cid in images:
        if name in test:
            continue
        w, h, fx, fy, cx, cy = cams[cid]
        c2w = np.eye(4)
        c2w[:3, :3] = r_wc.T
        c2w[:3, 3] = -r_wc.T @ t_wc
        c2w[:3, 1:3] *= -1  # OpenCV (y down, z forward) -> OpenGL (y up, z back)
        shutil.copyfile(os.path.join(capture, "images", name), os.path.join(tmp, "images", name))
        frames.append(
            {
                "file_path": f"images/{name}",
                "w": w,
                "h": h,
                "fl_x": fx,
                "fl_y": fy,
                "cx": cx,
                "cy": cy,
                "k1": 0.0,
                "k2": 0.0,
                "p1": 0.0,
                "p2": 0.0,
                "k3": 0.0,
                "transform_matrix": c2w.tolist(),
            }
        )
    xyz, rgb = read_points(sparse)
    with open(os.path.join(tmp, "points.ply"), "w") as f:
        f.write("ply\nformat ascii 1.0\n")
        f.write(f"element vertex {len(xyz)}\n")
        f.write("property float x\nproperty float y\nproperty float z\n")
        f.write("property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
        for p, c in zip(xyz, rgb):
            f.write(f"{p[0]} {p[1]} {p[2]} {c[0]} {c[1]} {c[2]}\n")
    with open(os.path.join(tmp, "transforms.json"), "w") as f:
        json.dump({"camera_model": "OPENCV", "ply_file_path": "points.ply", "frames": frames}, f)
    os.rename(tmp, out)
    return len(frames), len(test)


def ply_count(path):
    with open(path, "rb") as f:
        for line in f:
            line = line.decode("ascii", "replace").strip()
            if line.startswith("element vertex"):
                return int(line.split()[2])
            if line == "end_header":
                break
    sys.exit(f"{path}: no vertex count in the PLY header")


def gaussian_window(size=11, sigma=1.5):
    x = np.arange(size) - size // 2
    g = np.exp(-(x**2) / (2 * sigma**2))
    return g / g.sum()


def conv_same(img, g):
    """Zero-padded separable 2D convolution with the same output size (H×W)."""
    r = len(g) // 2
    p = np.pad(img, r)
    h, w = img.shape
    rows = sum(g[k] * p[:, k : k + w] for k in range(len(g)))
    return sum(g[k] * rows[k : k + h, :] for k in range(len(g)))


def ssim(x, y):
    """INRIA's SSIM (utils/loss_utils.py): per channel, mean over pixels and channels."""
    g = gaussian_window()
    c1, c2 = 0.01**2, 0.03**2
    vals = []
    for c in range(3):
        a, b = x[..., c].astype(np.float64), y[..., c].astype(np.float64)
        mx, my = conv_same(a, g), conv_same(b, g)
        sxx = conv_same(a * a, g) - mx * mx
        syy = conv_same(b * b, g) - my * my
        sxy = conv_same(a * b, g) - mx * my
        m = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
        vals.append(m.mean())
    return float(np.mean(vals))


def psnr(x, y):
    mse = float(np.mean((x.astype(np.float64) - y.astype(np.float64)) ** 2))
    return 10 * math.log10(1.0 / max(mse, 1e-20))


def score(render_dir, capture, names):
    from PIL import Image

    views = []
    for n in sorted(names):
        stem = os.path.splitext(n)[0]
        pred = np.clip(np.load(os.path.join(render_dir, stem + ".npy")), 0, 1)
        gt = np.asarray(Image.open(os.path.join(capture, "images", n)).convert("RGB"), np.float32) / 255
        views.append({"name": stem, "psnr": psnr(pred, gt), "ssim": ssim(pred, gt)})
    mean = sum(v["psnr"] for v in views) / len(views)
    worst = min(views, key=lambda v: v["psnr"])
    return {
        "psnr": mean,
        "ssim": sum(v["ssim"] for v in views) / len(views),
        "worst": worst,
        "views_3db_below_mean": [v["name"] for v in views if v["psnr"] < mean - 3],
        "per_view": views,
    }


def render(ts, scene, capture, out, background, log):
    if os.path.exists(out):
        return
    bg = ",".join(str(c) for c in background)
    run([ts, "render", "--scene", scene, "--cameras", os.path.join(capture, "sparse", "0"),
         "--out", out, "--raw", "--background", bg], log)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--opensplat", help="an OpenSplat binary built for the CPU (unless --skip opensplat)")
    ap.add_argument("--transsplat", default=os.path.join(os.path.dirname(__file__), "..", "target", "release", "transsplat"))
    ap.add_argument("--out", required=True, help="work folder (reused: finished steps are skipped)")
    ap.add_argument("--scene", default="tabletop")
    ap.add_argument("--size", type=int, default=256, help="image width and height")
    ap.add_argument("--views", type=int, default=48)
    ap.add_argument("--points", type=int, default=6000)
    ap.add_argument("--iters", type=int, default=7000)
    ap.add_argument("--opensplat-args", default="", help="extra arguments for the reference, space-separated")
    ap.add_argument("--opensplat-label", default="opensplat",
                    help="name of the reference's run (its folders and table row), e.g. to keep runs with different --opensplat-args apart")
    ap.add_argument("--transsplat-args", default="", help="extra arguments for `transsplat train`")
    ap.add_argument("--transsplat-label", default="transsplat", help="name of transsplat's run (see --opensplat-label)")
    ap.add_argument("--skip", default="", help="comma-separated trainers not to run: opensplat, transsplat")
    ap.add_argument("--score-ply", action="append", default=[], metavar="LABEL=PLY",
                    help="also render and score a scene trained elsewhere on this capture (black "
                         "background), e.g. one that tools/gsplat_reference.py wrote on a GPU; repeatable")
    a = ap.parse_args()
    ts = os.path.abspath(a.transsplat)
    out = os.path.abspath(a.out)
    os.makedirs(out, exist_ok=True)
    skip = set(filter(None, a.skip.split(",")))
    if "opensplat" not in skip and not a.opensplat:
        ap.error("--opensplat is needed unless --skip opensplat")

    capture = os.path.join(out, "capture")
    if not os.path.exists(capture):
        run([ts, "scene", a.scene, "--open", "--views", str(a.views), "--width", str(a.size),
             "--height", str(a.size), "--points", str(a.points), "--out", capture],
            os.path.join(out, "scene.log"))
    names = os.listdir(os.path.join(capture, "images"))
    test = test_names(names)
    ns = os.path.join(out, "nerfstudio")
    if not os.path.exists(ns):
        n_train, n_test = write_nerfstudio(capture, ns)
        print(f"nerfstudio copy: {n_train} training views ({n_test} test views held out)")

    results = {}
    label = a.opensplat_label
    if "opensplat" not in skip:
        # The reference writes into a staging folder renamed when it finishes, so an
        # interrupted run leaves no PLY that a later run would score.
        os_dir = os.path.join(out, f"{label}_{a.iters}")
        ply = os.path.join(os_dir, "splat.ply")
        if not os.path.exists(os_dir):
            tmp = os_dir + ".partial"
            shutil.rmtree(tmp, ignore_errors=True)
            os.makedirs(tmp)
            cmd = [os.path.abspath(a.opensplat), ns, "-n", str(a.iters), "--keep-crs",
                   "--cpu", "-o", os.path.join(tmp, "splat.ply")] + a.opensplat_args.split()
            seconds = run(cmd, os.path.join(tmp, "train.log"))
            with open(os.path.join(tmp, "seconds.json"), "w") as f:
                json.dump(seconds, f)
            os.rename(tmp, os_dir)
        r_dir = os.path.join(out, f"{label}_{a.iters}_render")
        render(ts, ply, capture, r_dir, OPENSPLAT_BACKGROUND, os.path.join(out, f"render_{label}.log"))
        results[label] = score(r_dir, capture, test)
        results[label]["gaussians"] = ply_count(ply)
        results[label]["seconds"] = json.load(open(os.path.join(os_dir, "seconds.json")))

    tl = a.transsplat_label
    if "transsplat" not in skip:
        t_dir = os.path.join(out, f"{tl}_{a.iters}")
        if not os.path.exists(t_dir):
            cmd = [ts, "train", "--data", capture, "--iters", str(a.iters), "--out", t_dir,
                   "--checkpoint-every", "0"] + a.transsplat_args.split()
            run(cmd, os.path.join(out, f"train_{tl}.log"))
        ply = os.path.join(t_dir, "point_cloud", f"iteration_{a.iters}", "point_cloud.ply")
        r_dir = os.path.join(out, f"{tl}_{a.iters}_render")
        render(ts, ply, capture, r_dir, (0, 0, 0), os.path.join(out, f"render_{tl}.log"))
        results[tl] = score(r_dir, capture, test)
        results[tl]["gaussians"] = ply_count(ply)
        own = json.load(open(os.path.join(t_dir, "train.json")))
        results[tl]["seconds"] = own.get("seconds")
        results[tl]["train_json"] = own

    for spec in a.score_ply:
        name, sep, ply = spec.partition("=")
        if not sep or not re.fullmatch(r"[A-Za-z0-9.-]+", name) or name in (".", "..") or not os.path.isfile(ply):
            sys.exit(f"--score-ply {spec}: expected LABEL=PLY (LABEL of letters, digits, '.' and '-') "
                     "naming an existing file")
        r_dir = os.path.join(out, f"scored_{name}")
        # Renders of an earlier PLY under the same label are not reused for another.
        source = json.dumps([os.path.abspath(ply), os.path.getsize(ply), os.path.getmtime(ply)])
        stamp = r_dir + ".source"
        if os.path.exists(r_dir) and (not os.path.exists(stamp) or open(stamp).read() != source):
            shutil.rmtree(r_dir)
        render(ts, os.path.abspath(ply), capture, r_dir, (0, 0, 0), os.path.join(out, f"render_{name}.log"))
        with open(stamp, "w") as f:
            f.write(source)
        results[name] = score(r_dir, capture, test)
        results[name]["gaussians"] = ply_count(ply)

    with open(os.path.join(out, f"anchor_{label}_{tl}.json"), "w") as f:
        json.dump({"settings": vars(a), "results": results}, f, indent=2)
    print(f"\n{a.scene} --open, {a.views} views of {a.size}², {a.points} initial points, "
          f"{a.iters} steps; test views: {', '.join(sorted(os.path.splitext(n)[0] for n in test))}")
    print("| trainer | test PSNR | SSIM | worst view | views > 3 dB below mean | Gaussians | time |")
    print("|---|---|---|---|---|---|---|")
    for k, r in results.items():
        secs = f"{r['seconds']:.0f} s" if r.get("seconds") else "–"
        print(f"| {k} | {r['psnr']:.3f} | {r['ssim']:.4f} | {r['worst']['name']} {r['worst']['psnr']:.2f} "
              f"| {len(r['views_3db_below_mean'])} | {r['gaussians']:,} | {secs} |")
    if tl in results:
        own = results[tl]["train_json"]
        print(f"transsplat's own train.json (cross-check of the evaluators): {json.dumps(own.get('test', own))[:300]}")


if __name__ == "__main__":
    main()

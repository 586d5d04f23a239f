#!/usr/bin/env python3
"""gsplat's trainer as a reference anchor for `transsplat train` (issue #14), on a GPU.

    python3 tools/gsplat_reference.py --capture CAPTURE --out OUT.json \
        [--iters 7000] [--strategy default|mcmc] [--cap-max N] [--seed 0] [--ply OUT.ply]

CAPTURE is what `transsplat scene SCENE --open` writes (COLMAP text model in
`sparse/0`, images in `images/`), the same capture `tools/reference_trainer.py` gives
OpenSplat and transsplat, or a nerfstudio capture (`transforms.json` with its
`ply_file_path` points, as `tools/mesh_captures.py` writes). This script trains on it with gsplat's library the way gsplat's
`examples/simple_trainer.py` does with its defaults (that example is not in gsplat's
wheel and wants COLMAP binaries and a dozen packages, so its training loop is restated
here, setting for setting):

- the split: INRIA's llffhold, every 8th image in name order is a test view, never seen
  in training (simple_trainer's `test_every = 8` over sorted names);
- the init: the capture's sparse points, SH DC from their colours, SH degree 3 added one
  band per 1000 steps, log scale = log of the mean distance to the 3 nearest points,
  random quaternions, opacity 0.1 (MCMC: opacity 0.5, scale × 0.1);
- Adam per parameter group, eps 1e-15; learning rates means 1.6e-4 × scene scale
  (decayed exponentially to 1 % at the last step), scales 5e-3, quats 1e-3, opacities
  5e-2, SH DC 2.5e-3, SH rest 2.5e-3 / 20; scene scale = 1.1 × the largest camera
  distance from the cameras' mean (simple_trainer normalises the world first, which
  every one of these settings is invariant to, up to the near plane);
- the loss: 0.8 L1 + 0.2 (1 − SSIM) with an 11×11 Gaussian window (σ 1.5) and valid
  padding, as `fused_ssim(..., padding="valid")`; MCMC adds 0.01 mean opacity and 0.01
  mean scale;
- the strategy: `DefaultStrategy()` (refine 500–15000 every 100, opacity reset every
  3000, gradient threshold 2e-4) or `MCMCStrategy(cap_max=N)` (noise lr 5e5, refine
  500–25000 every 100), called where simple_trainer calls them;
- the render: `gsplat.rasterization`, classic mode, not packed, black background, near
  plane 0.01, one image per step.

Evaluation on the held-out views: the render clamped to [0, 1], PSNR over the whole
image and INRIA's SSIM (same window, zero padding, mean over pixels and channels), every
view, the worst and the views more than 3 dB below the mean: the figures and names that
`tools/reference_trainer.py` writes, so the rows compare. `--ply` writes the trained
scene in INRIA's layout; `reference_trainer.py --reference-ply` renders it with
transsplat at the same cameras, a cross-check of both rasterizers and both evaluators.

`--build-only` compiles gsplat's CUDA extension (`torch.utils.cpp_extension.load` over
the wheel's sources; set TORCH_CUDA_ARCH_LIST to the one GPU's architecture to cut the
time) and exits. Needs torch with CUDA, numpy, Pillow, gsplat (1.5.3 measured) and
`reference_trainer.py` beside it (its COLMAP reader and split).
"""

import argparse
import glob
import json
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from reference_trainer import LLFF_HOLD, read_colmap_text, read_points  # noqa: E402

SH_C0 = 0.28209479177387814


def build_extension():
    """Compiles gsplat's CUDA sources once and registers them as `gsplat.csrc`.

    gsplat's `_backend` imports `gsplat.csrc` before it tries its own JIT build, so a
    module registered under that name here is the one every gsplat call uses.
    """
    import importlib.util

    from torch.utils.cpp_extension import load

    spec = importlib.util.find_spec("gsplat")
    root = os.path.join(os.path.dirname(spec.origin), "cuda")
    sources = sorted(glob.glob(os.path.join(root, "csrc", "*.cu")))
    sources += sorted(glob.glob(os.path.join(root, "csrc", "*.cpp")))
    sources.append(os.path.join(root, "ext.cpp"))
    build = os.environ.get("GSPLAT_BUILD", "/tmp/gsplat_build")
    os.makedirs(build, exist_ok=True)
    t0 = time.time()
    mod = load(
        name="gsplat_cuda",
        sources=sources,
        extra_cflags=["-O3", "-Wno-attributes"],
        extra_cuda_cflags=["-O3", "-use_fast_math"],
        extra_include_paths=[os.path.join(root, "include"), os.path.join(root, "csrc", "third_party", "glm")],
        build_directory=build,
        verbose=False,
    )
    sys.modules["gsplat.csrc"] = mod
    print(f"gsplat CUDA extension ready in {time.time() - t0:.0f} s", flush=True)


def read_capture(capture):
    """Views sorted by name: (name, 4×4 world-to-camera (OpenCV), K, w, h), and the
    points (xyz, rgb in [0, 1]), read by `reference_trainer.py`'s COLMAP text reader or,
    where the capture has a `transforms.json`, by `read_transforms`."""
    if os.path.exists(os.path.join(capture, "transforms.json")):
        return read_transforms(capture)
    sparse = os.path.join(capture, "sparse", "0")
    cams, images = read_colmap_text(sparse)
    views = []
    for name, r_wc, t_wc, cid in images:
        w, h, fx, fy, cx, cy = cams[cid]
        vm = np.eye(4)
        vm[:3, :3] = r_wc
        vm[:3, 3] = t_wc
        views.append((name, vm, np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]), w, h))
    views.sort(key=lambda v: v[0])
    xyz, rgb = read_points(sparse)
    return views, xyz, rgb.astype(np.float32) / 255.0


def read_transforms(capture):
    """A nerfstudio capture: OpenGL camera-to-world matrices turned into OpenCV
    world-to-camera ones (y and z axes negated), focal lengths from `fl_x`/`fl_y` or
    `camera_angle_x`, principal point `cx`/`cy` or the image centre; the points from the
    binary PLY at `ply_file_path` (float x, y, z and uchar red, green, blue)."""
    meta = json.load(open(os.path.join(capture, "transforms.json")))
    views = []
    for frame in meta["frames"]:
        w = int(frame.get("w", meta.get("w")))
        h = int(frame.get("h", meta.get("h")))
        fx = frame.get("fl_x", meta.get("fl_x"))
        if fx is None:
            fx = 0.5 * w / math.tan(0.5 * meta["camera_angle_x"])
        fy = frame.get("fl_y", meta.get("fl_y", fx))
        cx = frame.get("cx", meta.get("cx", 0.5 * w))
        cy = frame.get("cy", meta.get("cy", 0.5 * h))
        c2w = np.array(frame["transform_matrix"], np.float64) @ np.diag([1.0, -1.0, -1.0, 1.0])
        vm = np.linalg.inv(c2w)
        name = os.path.relpath(frame["file_path"], "images")
        views.append((name, vm, np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]), w, h))
    views.sort(key=lambda v: v[0])
    xyz, rgb = read_binary_points(os.path.join(capture, meta["ply_file_path"]))
    return views, xyz, rgb.astype(np.float32) / 255.0


def read_binary_points(path):
    """Positions and colours of a little-endian binary PLY of float x, y, z and uchar
    red, green, blue vertices (any other float properties skipped)."""
    with open(path, "rb") as f:
        header = []
        while True:
            line = f.readline()
            if not line:
                sys.exit(f"{path}: no end_header")
            line = line.decode("ascii").strip()
            if line == "end_header":
                break
            header.append(line.split())
        count = next(int(p[2]) for p in header if p[:2] == ["element", "vertex"])
        types = {"float": "<f4", "uchar": "u1", "double": "<f8"}
        props = [(p[2], types[p[1]]) for p in header if p[0] == "property"]
        data = np.frombuffer(f.read(), dtype=np.dtype(props), count=count)
    xyz = np.stack([data[k] for k in ("x", "y", "z")], 1).astype(np.float32)
    rgb = np.stack([data[k] for k in ("red", "green", "blue")], 1).astype(np.uint8)
    return xyz, rgb


def load_image(capture, name):
    from PIL import Image

    return np.asarray(Image.open(os.path.join(capture, "images", name)).convert("RGB"), np.float32) / 255.0


def gaussian_window(torch, size=11, sigma=1.5):
    x = torch.arange(size, dtype=torch.float32) - size // 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    g = g / g.sum()
    return (g[:, None] * g[None, :]).expand(3, 1, size, size).contiguous()


def ssim(torch, x, y, window, padding):
    """SSIM of two [1, 3, H, W] images, mean over pixels and channels (C1 = 0.01², C2 = 0.03²)."""
    import torch.nn.functional as F

    c1, c2 = 0.01**2, 0.03**2
    conv = lambda t: F.conv2d(t, window, padding=padding, groups=3)  # noqa: E731
    mx, my = conv(x), conv(y)
    sxx = conv(x * x) - mx * mx
    syy = conv(y * y) - my * my
    sxy = conv(x * y) - mx * my
    m = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    return m.mean()


def write_ply(path, splats):
    """The trained `splats` (torch parameters, on any device) as an INRIA PLY."""
    import torch

    with torch.no_grad():
        sh = torch.cat([splats["sh0"], splats["shN"]], 1)
        arrays = [splats[k].detach().cpu().numpy() for k in ("means", "quats", "scales", "opacities")]
        write_inria_ply(path, *arrays, sh.cpu().numpy())


def write_inria_ply(path, means, quats, log_scales, opacity_logits, sh):
    """INRIA's layout: SH DC, then the rest channel-major (all of red's coefficients
    first), raw logit opacity, log scales, unit quaternions (w, x, y, z). Written to a
    temporary name and renamed. `sh` is (N, K, 3) with the DC term at k = 0."""
    n = len(means)
    q = quats / np.linalg.norm(quats, axis=-1, keepdims=True)
    rest = sh[:, 1:].transpose(0, 2, 1).reshape(n, -1)
    cols = [means, np.zeros_like(means), sh[:, 0], rest, opacity_logits.reshape(n, 1), log_scales, q]
    data = np.concatenate(cols, axis=1).astype("<f4")
    names = ["x", "y", "z", "nx", "ny", "nz"] + [f"f_dc_{i}" for i in range(3)]
    names += [f"f_rest_{i}" for i in range(rest.shape[1])] + ["opacity"]
    names += [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)]
    assert data.shape[1] == len(names)
    tmp = path + ".partial"
    with open(tmp, "wb") as f:
        f.write(f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\n".encode())
        f.write("".join(f"property float {c}\n" for c in names).encode())
        f.write(b"end_header\n")
        f.write(data.tobytes())
    os.rename(tmp, path)


def outside(folder, path):
    """Whether `path` lies outside `folder` (links resolved), so writing it cannot touch an input."""
    f, p = os.path.realpath(folder), os.path.realpath(path)
    return os.path.commonpath([f, p]) != f


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--capture", help="a capture written by `transsplat scene --open`")
    ap.add_argument("--out", help="where the results go (JSON)")
    ap.add_argument("--iters", type=int, default=7000)
    ap.add_argument("--strategy", choices=["default", "mcmc"], default="default")
    ap.add_argument("--cap-max", type=int, default=1_000_000, help="MCMC's Gaussian budget")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--ply", help="also write the trained scene here (INRIA layout)")
    ap.add_argument("--build-only", action="store_true", help="compile gsplat's CUDA extension and exit")
    a = ap.parse_args()
    for path in (a.out, a.ply):
        if path and a.capture and not outside(a.capture, path):
            ap.error(f"{path}: an output may not lie inside the capture {a.capture} (inputs are never written)")

    import torch
    import torch.nn.functional as F

    build_extension()
    if a.build_only:
        return
    if not (a.capture and a.out):
        ap.error("--capture and --out are needed unless --build-only")
    from gsplat import rasterization
    from gsplat.strategy import DefaultStrategy, MCMCStrategy

    torch.manual_seed(a.seed)
    np.random.seed(a.seed)
    dev = torch.device("cuda")
    views, xyz, rgb = read_capture(a.capture)
    test = [v for i, v in enumerate(views) if i % LLFF_HOLD == 0]
    train = [v for i, v in enumerate(views) if i % LLFF_HOLD != 0]

    def stack(vs):
        vm = torch.tensor(np.stack([v[1] for v in vs]), dtype=torch.float32, device=dev)
        ks = torch.tensor(np.stack([v[2] for v in vs]), dtype=torch.float32, device=dev)
        px = torch.tensor(np.stack([load_image(a.capture, v[0]) for v in vs]), device=dev)
        return vm, ks, px

    tr_vm, tr_k, tr_px = stack(train)
    width, height = train[0][3], train[0][4]
    centres = np.stack([-v[1][:3, :3].T @ v[1][:3, 3] for v in train])
    scene_scale = float(np.linalg.norm(centres - centres.mean(0), axis=1).max()) * 1.1

    mcmc = a.strategy == "mcmc"
    init_opa, init_scale = (0.5, 0.1) if mcmc else (0.1, 1.0)
    pts = torch.tensor(xyz)
    # gsplat clamps nothing here; a duplicate point would give log(0), so the floor.
    d2 = (torch.cdist(pts, pts).topk(4, largest=False).values[:, 1:] ** 2).clamp_min(1e-12)
    n = len(pts)
    sh = torch.zeros(n, 16, 3)
    sh[:, 0] = (torch.tensor(rgb) - 0.5) / SH_C0
    init = {
        "means": (pts, 1.6e-4 * scene_scale),
        "scales": (torch.log(d2.mean(-1).sqrt() * init_scale)[:, None].repeat(1, 3), 5e-3),
        "quats": (torch.rand(n, 4), 1e-3),
        "opacities": (torch.logit(torch.full((n,), init_opa)), 5e-2),
        "sh0": (sh[:, :1].clone(), 2.5e-3),
        "shN": (sh[:, 1:].clone(), 2.5e-3 / 20),
    }
    splats = torch.nn.ParameterDict({k: torch.nn.Parameter(v.to(dev)) for k, (v, _) in init.items()})
    opts = {k: torch.optim.Adam([{"params": splats[k], "lr": lr, "name": k}], eps=1e-15) for k, (_, lr) in init.items()}
    sched = torch.optim.lr_scheduler.ExponentialLR(opts["means"], gamma=0.01 ** (1.0 / a.iters))
    strategy = MCMCStrategy(cap_max=a.cap_max) if mcmc else DefaultStrategy()
    strategy.check_sanity(splats, opts)
    state = strategy.initialize_state() if mcmc else strategy.initialize_state(scene_scale=scene_scale)
    window = gaussian_window(torch).to(dev)

    def render(vm, k, sh_degree):
        return rasterization(
            means=splats["means"], quats=splats["quats"], scales=torch.exp(splats["scales"]),
            opacities=torch.sigmoid(splats["opacities"]),
            colors=torch.cat([splats["sh0"], splats["shN"]], 1), viewmats=vm, Ks=k,
            width=width, height=height, packed=False, absgrad=False, rasterize_mode="classic",
            sh_degree=sh_degree, near_plane=0.01, far_plane=1e10,
        )

    gen = torch.Generator().manual_seed(a.seed)
    order = []
    torch.cuda.synchronize()
    t0 = time.time()
    for step in range(a.iters):
        if not order:
            order = torch.randperm(len(train), generator=gen).tolist()
        i = order.pop()
        img, _, info = render(tr_vm[i : i + 1], tr_k[i : i + 1], min(step // 1000, 3))
        if not mcmc:
            strategy.step_pre_backward(splats, opts, state, step, info)
        gt = tr_px[i : i + 1]
        x, y = img.permute(0, 3, 1, 2), gt.permute(0, 3, 1, 2)
        loss = 0.8 * F.l1_loss(img, gt) + 0.2 * (1 - ssim(torch, x, y, window, 0))
        if mcmc:
            loss = loss + 0.01 * torch.sigmoid(splats["opacities"]).mean() + 0.01 * torch.exp(splats["scales"]).mean()
        loss.backward()
        for o in opts.values():
            o.step()
            o.zero_grad(set_to_none=True)
        sched.step()
        if mcmc:
            strategy.step_post_backward(splats, opts, state, step, info, lr=sched.get_last_lr()[0])
        else:
            strategy.step_post_backward(splats, opts, state, step, info, packed=False)
        if step % 1000 == 0 or step == a.iters - 1:
            print(f"step {step} loss {loss.item():.4f} gaussians {len(splats['means'])}", flush=True)
    torch.cuda.synchronize()
    seconds = time.time() - t0

    per_view = []
    with torch.no_grad():
        te_vm, te_k, te_px = stack(test)
        for j, v in enumerate(test):
            img = render(te_vm[j : j + 1], te_k[j : j + 1], 3)[0].clamp(0, 1)
            gt = te_px[j : j + 1]
            mse = float(((img.double() - gt.double()) ** 2).mean())
            s = float(ssim(torch, img.permute(0, 3, 1, 2), gt.permute(0, 3, 1, 2), window, 5))
            per_view.append({"name": os.path.splitext(v[0])[0], "psnr": 10 * math.log10(1 / max(mse, 1e-20)), "ssim": s})
    mean = sum(v["psnr"] for v in per_view) / len(per_view)
    result = {
        "trainer": f"gsplat {getattr(__import__('gsplat'), '__version__', '?')} {type(strategy).__name__}",
        "settings": vars(a),
        "device": torch.cuda.get_device_name(),
        "psnr": mean,
        "ssim": sum(v["ssim"] for v in per_view) / len(per_view),
        "worst": min(per_view, key=lambda v: v["psnr"]),
        "views_3db_below_mean": [v["name"] for v in per_view if v["psnr"] < mean - 3],
        "per_view": per_view,
        "gaussians": len(splats["means"]),
        "seconds": seconds,
        "scene_scale": scene_scale,
    }
    tmp = a.out + ".partial"
    with open(tmp, "w") as f:
        json.dump(result, f, indent=2)
    os.rename(tmp, a.out)
    if a.ply:
        write_ply(a.ply, splats)
    print(f"{result['trainer']}: test PSNR {mean:.3f} SSIM {result['ssim']:.4f} worst "
          f"{result['worst']['name']} {result['worst']['psnr']:.2f} gaussians {result['gaussians']:,} "
          f"{seconds:.0f} s", flush=True)


if __name__ == "__main__":
    main()

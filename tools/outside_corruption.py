#!/usr/bin/env python3
"""Edits of a mesh capture corrupted by a model that is *not* the simulated editor's.

The quality suite corrupts true edits with the simulated editor's model
(crates/builtin/src/simulated.rs). Hidden corruption models will be used, so this
script makes edits the way a latent-diffusion editor returns them and the suite never
tried, for the folder editor, and scores edited scenes on the held-out views:

  make   --capture caps/forward --renders R --out EDITS [--seed S] [--clean]
  score  --capture caps/forward --source S --edited E1 [E2 ...] [--evidence EDITS]
  run    --capture caps/forward --prompt "make the teddy blue" --work DIR [--seeds 0,1]

`run` does the whole comparison in DIR with the `transsplat` binary (`--transsplat`,
default target/release/transsplat): trains the capture (`train --iters 2000
--no-masks`, the suite's steps), renders it, edits it with `naive` fed the uncorrupted
edits (the ceiling) and with the default, `masklift` and `naive` fed the corrupted ones,
and scores them; every step is skipped when its folder exists.

`R` is `transsplat render --scene TRAINED --out R --raw` of the trained capture (the
folder editor is given the trained scene's renders, as `views export` gives them).
Per edit view v, with Δ_v = edited_mesh − image_mesh the true change of the view:

  1. edit strength: Δ scaled by a_v ~ U(0.75, 1.05) (under- and over-edits);
  2. misregistration: the change shifted by (dx, dy), each ~ U(-2, 2) px, whole pixels;
  3. bleed: outside the shifted target the change is a Gaussian blur of the change,
     σ ~ U(1.5, 4) px, at strength k ~ U(0.4, 0.9) (a soft halo, not the suite's ring);
  4. partial edits: with probability 1/5 only the image's upper half of the change;
  5. decoder round trip: the whole image blurred (σ = 0.6 px), plus N(0, 1.5/255)
     noise, then 8-bit quantised (every pixel changes a little, as through a VAE).

`--clean` writes the uncorrupted edit, render + Δ_v (what `naive` is fed for the ceiling).
No attention and no masks are written: the folder editor then takes the smoothed change
map as its attention (docs/cli.md, Editors). `score` prints per edited scene the target
PSNR against the true edit (target pixels: label share ≥ 1/2), the background PSNR
against the source scene's render where the target's label share is 0 (pooled, and in
the worst view), and the silhouette PSNR (within 1 % of the diagonal of the target
mask's outline, both sides), over the held-out views (every 8th), each capped at 60 dB:
the target mask and the band as the quality suite draws them (`eval::ground_truth`).
Needs numpy and pillow.
"""
import argparse, json, os, sys
import numpy as np
from PIL import Image

HOLD = 8


def load_png(p):
    return np.asarray(Image.open(p).convert("RGB"), dtype=np.float32) / 255.0


def blur(img, sigma):
    """Separable Gaussian blur over the first two axes, edges clamped."""
    if sigma <= 0:
        return img
    r = int(np.ceil(3 * sigma))
    x = np.arange(-r, r + 1, dtype=np.float32)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    k /= k.sum()
    out = img
    for axis in (0, 1):
        pad = [(0, 0)] * out.ndim
        pad[axis] = (r, r)
        p = np.pad(out, pad, mode="edge")
        acc = np.zeros_like(out)
        for i, w in enumerate(k):
            sl = [slice(None)] * out.ndim
            sl[axis] = slice(i, i + out.shape[axis])
            acc += w * p[tuple(sl)]
        out = acc
    return out


def shift(img, dx, dy):
    """Whole-pixel shift with edge clamping."""
    h, w = img.shape[:2]
    ys = np.clip(np.arange(h) - dy, 0, h - 1)
    xs = np.clip(np.arange(w) - dx, 0, w - 1)
    return img[ys][:, xs]


def frames(capture):
    """The views' stems in the order `transsplat` sorts cameras (by image name), which
    the held-out split counts in."""
    t = json.load(open(os.path.join(capture, "transforms.json")))
    names = sorted(os.path.basename(f["file_path"]) for f in t["frames"])
    return [os.path.splitext(n)[0] for n in names]


def target_labels(capture, stem):
    """The target label's share of each pixel's label samples, and the target mask: the
    pixels whose most frequent label (the lowest among equals) is the target's, as the
    suite's `LabelRender::from_samples` labels a pixel."""
    meta = json.load(open(os.path.join(capture, "capture.json")))
    label = next(o["label"] for o in meta["objects"] if o["name"] == meta["target"])
    s = meta["supersample"]
    lab = np.asarray(Image.open(os.path.join(capture, "labels", stem + ".png")))
    if lab.ndim == 3:
        lab = lab[..., 0]
    h, w = lab.shape[0] // s, lab.shape[1] // s
    blocks = lab[: h * s, : w * s].reshape(h, s, w, s).transpose(0, 2, 1, 3).reshape(h, w, s * s)
    counts = np.stack([(blocks == l).sum(axis=2) for l in range(int(lab.max()) + 1)], axis=2)
    return (blocks == label).mean(axis=2), counts.argmax(axis=2) == label


def refuse_inside(out, flag, *inputs):
    """Exits with 2 when the output `out` (given by `flag`) lies in or over an input
    folder: the tool never writes into what it reads."""
    o = os.path.realpath(out)
    for i in inputs:
        r = os.path.realpath(i)
        if o == r or o.startswith(r + os.sep) or r.startswith(o + os.sep):
            print(f"{flag} {out}: lies in or over the input {i}; choose a folder outside it", file=sys.stderr)
            sys.exit(2)


def make(a):
    """Writes the edits into a staging folder renamed to `a.out` when every view is done,
    so an interrupted run leaves no folder that `run` would take as finished."""
    refuse_inside(a.out, "--out", a.capture, a.renders)
    if os.path.exists(a.out):
        print(f"{a.out}: already exists; choose another --out", file=sys.stderr)
        sys.exit(2)
    stage = f"{a.out}.partial-{os.getpid()}"
    os.makedirs(stage)
    stems = frames(a.capture)
    for i, stem in enumerate(stems):
        if i % HOLD == 0:
            continue
        rng = np.random.default_rng([a.seed, i])
        render = np.load(os.path.join(a.renders, stem + ".npy")).astype(np.float32)
        change = load_png(os.path.join(a.capture, "edited", stem + ".png")) - load_png(
            os.path.join(a.capture, "images", stem + ".png"))
        inside = target_labels(a.capture, stem)[0] > 0
        strength = rng.uniform(0.75, 1.05)
        dx, dy = rng.integers(-2, 3, size=2)
        sigma, k = rng.uniform(1.5, 4.0), rng.uniform(0.4, 0.9)
        partial = rng.random() < 0.2
        if a.clean:
            strength, dx, dy, k, partial = 1.0, 0, 0, 1.0, False
        d = shift(change * strength, dx, dy)
        m = shift(inside[..., None].astype(np.float32), dx, dy) > 0.5
        d = np.where(m, d, k * blur(d, sigma)) if not a.clean else d
        if partial:
            d[d.shape[0] // 2:] = 0
        img = np.clip(render + d, 0, 1)
        if not a.clean:
            img = blur(img, 0.6) + rng.normal(0, 1.5 / 255, render.shape)
        img = np.round(np.clip(img, 0, 1) * 255).astype(np.uint8)
        Image.fromarray(img).save(os.path.join(stage, stem + ".png"))
    os.rename(stage, a.out)
    print(f"wrote {a.out}")


def psnr(se, n):
    return 60.0 if n == 0 or se <= 0 else min(60.0, 10 * np.log10(n / se))


def grow(mask, r):
    """The pixels within Euclidean distance r of the mask (pixel centres), as the suite's
    `builtin::masks::grow`."""
    out = np.zeros_like(mask)
    k = int(np.floor(r))
    for dy in range(-k, k + 1):
        for dx in range(-k, k + 1):
            if dx * dx + dy * dy <= r * r:
                out |= shift(mask, dx, dy)
    return out


def band(mask, r):
    """The silhouette band of the suite (`eval::ground_truth::silhouette_band`): within r
    of the mask's outline, on either side (grown by r, and not the mask shrunk by r)."""
    return grow(mask, r) & grow(~mask, r)


def score(a):
    stems = frames(a.capture)
    test = [s for i, s in enumerate(stems) if i % HOLD == 0]
    print("scene                          target  backgr  worst   silhouette")
    for e in a.edited:
        t = [0.0, 0]; b = [0.0, 0]; s = [0.0, 0]; worst = 60.0
        for stem in test:
            out = np.load(os.path.join(e, stem + ".npy"))
            src = np.load(os.path.join(a.source, stem + ".npy"))
            truth = load_png(os.path.join(a.capture, "edited", stem + ".png"))
            share, tm = target_labels(a.capture, stem)
            bm = share == 0
            r = max(1.0, 0.01 * np.hypot(*share.shape))
            sm = band(tm, r)
            err_t = ((np.clip(out, 0, 1) - truth) ** 2)
            err_b = ((np.clip(out, 0, 1) - np.clip(src, 0, 1)) ** 2)
            t[0] += err_t[tm].sum(); t[1] += tm.sum() * 3
            s[0] += err_t[sm].sum(); s[1] += sm.sum() * 3
            b[0] += err_b[bm].sum(); b[1] += bm.sum() * 3
            worst = min(worst, psnr(err_b[bm].sum(), bm.sum() * 3))
        name = os.path.normpath(e)
        name = os.path.basename(os.path.dirname(name)) if os.path.basename(name) == "renders" else os.path.basename(name)
        print(f"{name[:30]:30} {psnr(*t):6.2f}  {psnr(*b):6.2f}  {worst:6.2f}  {psnr(*s):6.2f}")
    if a.evidence:
        t = [0.0, 0]
        for i, stem in enumerate(stems):
            if i % HOLD == 0:
                continue
            img = load_png(os.path.join(a.evidence, stem + ".png"))
            truth = load_png(os.path.join(a.capture, "edited", stem + ".png"))
            tm = target_labels(a.capture, stem)[1]
            t[0] += ((img - truth) ** 2)[tm].sum(); t[1] += tm.sum() * 3
        print(f"2D evidence inside the target (edit views): {psnr(*t):6.2f}")


def run(a):
    import subprocess

    def sh(*args, log=None):
        with open(log or os.devnull, "w") as f:
            subprocess.run([a.transsplat, *map(str, args)], check=True, stdout=f, stderr=subprocess.STDOUT)

    w = lambda *p: os.path.join(a.work, *p)
    refuse_inside(a.work, "--work", a.capture)
    os.makedirs(a.work, exist_ok=True)
    if not os.path.isdir(w("trained")):
        sh("train", "--data", a.capture, "--out", w("trained"), "--iters", 2000, "--no-masks", log=w("train.log"))
    if not os.path.isdir(w("renders")):
        sh("render", "--scene", w("trained"), "--out", w("renders"), "--raw")

    def edit(edits, method, name):
        if not os.path.isdir(w(name, "renders")):
            sh("edit", "--scene", w("trained"), "--editor", "folder", "--edits", edits, "--prompt", a.prompt,
               "--method", method, "--out", w(name, "scene"), log=w(name + ".log"))
            sh("render", "--scene", w(name, "scene"), "--out", w(name, "renders"), "--raw")
        return w(name, "renders")

    def edits(name, seed, clean):
        if not os.path.isdir(w(name)):
            make(argparse.Namespace(capture=a.capture, renders=w("renders"), out=w(name), seed=seed, clean=clean))
        return w(name)

    ceiling = edit(edits("edits-clean", 0, True), "naive", "ceiling")
    for seed in map(int, a.seeds.split(",")):
        e = edits(f"edits-{seed}", seed, False)
        out = [edit(e, m, f"{m}-{seed}") for m in ("transsplat", "masklift", "naive")]
        print(f"seed {seed}")
        score(argparse.Namespace(capture=a.capture, source=w("renders"), edited=[ceiling, *out], evidence=e))


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    m = sub.add_parser("make")
    m.add_argument("--capture", required=True)
    m.add_argument("--renders", required=True)
    m.add_argument("--out", required=True)
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--clean", action="store_true", help="the uncorrupted edit, render + Δ (the ceiling's input)")
    s = sub.add_parser("score")
    s.add_argument("--capture", required=True)
    s.add_argument("--source", required=True)
    s.add_argument("--edited", nargs="+", required=True)
    s.add_argument("--evidence", help="an edit folder: also its own target PSNR over the edit views")
    r = sub.add_parser("run")
    r.add_argument("--capture", required=True)
    r.add_argument("--prompt", required=True)
    r.add_argument("--work", required=True)
    r.add_argument("--seeds", default="0")
    r.add_argument("--transsplat", default="target/release/transsplat")
    a = p.parse_args()
    {"make": make, "score": score, "run": run}[a.cmd](a)


if __name__ == "__main__":
    sys.exit(main())

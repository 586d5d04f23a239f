#!/usr/bin/env python3
"""Four built-in scene jobs on a local 2-CPU Ray cluster against the same jobs run one
after another by the command line tool (`transsplat edit --editor folder` on the same
edited images), in one session. The editor is a cheap deterministic recolour, so the
comparison measures what Ray adds or saves around the lifts.

    tools/bench_ray.py [--steps 300] [--quick]

Needs the `transsplat` package with Ray (tools/python_tests.sh installs both) and
target/release/transsplat. Prints the wall times, their ratio and Ray's start-up.
"""

import argparse
import json
import pathlib
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "crates/python/tests"))
import ray_editors  # noqa: E402
from ray_editors import write_png  # noqa: E402
import transsplat  # noqa: E402
from transsplat import ray as tray  # noqa: E402

BIN = ROOT / "target/release/transsplat"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--lift-cpus", type=float, default=2, help="CPUs a lift reserves (2: one lift at a time)")
    args = ap.parse_args()
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="bench-ray-"))
    jobs = []
    for name, seed in (("tabletop", 0), ("tabletop", 1), ("occluded", 0), ("occluded", 1)):
        scene = transsplat.builtin_scene(name, tmp / f"{name}{seed}", quick=args.quick, seed=seed)
        views = tmp / f"{name}{seed}-views"
        subprocess.run([BIN, "views", "export", "--scene", scene, "--out", views], check=True, capture_output=True)
        edits = tmp / f"{name}{seed}-edits"
        edits.mkdir()
        jobs.append((f"{name}{seed}", scene, views, edits))
    # The same edited images for both: the recolour of each edit view's render.
    for _, scene, views, edits in jobs:
        g = transsplat.load_ply(scene)
        cams = transsplat.load_cameras(scene)
        deg = int(round(np.sqrt(g["sh"].shape[1]))) - 1
        for i, n in enumerate(cams["names"]):
            if transsplat._core.is_test_view(i):
                continue
            img, _, _ = transsplat.rasterization(
                g["means"], g["quats"], np.exp(g["log_scales"]), 1 / (1 + np.exp(-g["opacity_logits"])), g["sh"],
                cams["viewmats"][i:i + 1], cams["Ks"][i:i + 1], int(cams["widths"][i]), int(cams["heights"][i]),
                sh_degree=deg)
            e = np.clip(np.round(ray_editors.recolour(img[0]) * 255), 0, 255).astype(np.uint8)
            write_png(edits / (pathlib.Path(n).stem + ".png"), e)
    t0 = time.monotonic()
    for name, scene, _, edits in jobs:
        subprocess.run([BIN, "edit", "--scene", scene, "--prompt", "make the ball blue", "--editor", "folder",
                        "--edits", edits, "--steps", str(args.steps), "--out", tmp / f"cli-{name}"],
                       check=True, capture_output=True)
    cli = time.monotonic() - t0
    import ray

    t0 = time.monotonic()
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False,
             runtime_env={"env_vars": {"PYTHONPATH": str(ROOT / "crates/python/tests")}})
    start = time.monotonic() - t0
    doc = {"cache": str(tmp / "cache"), "summary": str(tmp / "summary.json"), "editor_workers": 2,
           "lift_cpus": args.lift_cpus,
           "defaults": {"steps": args.steps, "editor": "ray_editors:Recolour", "prompt": "make the ball blue"},
           "job": [{"name": n, "scene": str(s), "out": str(tmp / f"ray-{n}")} for n, s, _, _ in jobs]}
    (tmp / "m.json").write_text(json.dumps(doc))
    t0 = time.monotonic()
    rows = tray.run(tmp / "m.json", progress=False)
    wall = time.monotonic() - t0
    ray.shutdown()
    assert all(r["status"] == "ok" for r in rows), rows
    lifts = sum(r["lift_s"] for r in rows)
    print(f"jobs {len(rows)}, steps {args.steps}, quick {args.quick}")
    print(f"CLI one after another: {cli:.1f} s")
    print(f"Ray, 2 CPUs: {wall:.1f} s (+ {start:.1f} s cluster start); ratio CLI/Ray {cli / wall:.2f}")
    print(f"lift_cpus {args.lift_cpus}; sum of the lifts inside Ray tasks {lifts:.1f} s; Ray's overhead per job "
          f"(Ray wall - CLI wall) / jobs = {(wall - cli) / len(rows):.2f} s")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Captures rendered from textured meshes by a real renderer (pybullet's TinyRenderer).

The built-in benchmark scenes are rendered by our own rasterizer, so a trainer tuned on
them meets nothing it did not itself make. This script renders datasets the way a user's
capture arrives: textured triangle meshes (pybullet_data's table, duck, soccer ball,
teddy, mug, cubes) on a checkerboard floor reaching the horizon, under a sky, shaded
with shadows by a software renderer that shares no code with transsplat. Three camera
paths, each a layout users shoot:

  orbit    one ring around the table (the classic 360 capture)
  rings    three rings at low, middle and high elevation
  forward  eyes on a plane in front of the table, all looking the same way (LLFF-like)
  room     an arc of 200° around the table inside a room whose papered walls rise above
           every view's frame (an indoor capture: no sky; not in the default set)

Each dataset is a nerfstudio `transforms.json` (OpenGL camera-to-world, `camera_angle_x`)
with `images/`, a sparse point cloud `points3d.ply` standing in for SfM (surface points
seen in at least two training views, unprojected from the renderer's depth, every held-out
view excluded: `transsplat train` holds out every 8th camera by name), and for the edit
studies `masks/<stem>.png` (the edit target's visibility, from the renderer's segmentation)
`edited/<stem>.png` (the same view with the target recoloured: the ground-truth edit) and
`labels/<stem>.png` (which object each sample of the supersampled render shows: 0 the
floor and sky, 1 the table, then the objects as `capture.json` lists them; at `supersample`
times the image size, so box-filtering a label's indicator gives its coverage of a pixel,
the way a blend weight does). `transsplat bench quality --captures DIR` edits these
captures with the simulated editor's corruption of the true edits.

The sky is an environment at infinity: each background pixel takes a colour from its
ray direction (a horizon-to-zenith gradient with soft cloud bands), so it is consistent
across views as a real sky is, and it is not a constant a trainer could fit with a
background colour.

Needs pybullet, numpy and Pillow (`pip install pybullet numpy pillow`); not a
dependency of the project or CI. Usage:

    python3 tools/mesh_captures.py --out DIR [--paths orbit,rings,forward] [--size 256]
        [--views 48] [--seed 0]

then, for example, `transsplat train --data DIR/orbit --out trained --iters 3000 --no-masks`.
The k-th path of `--paths` gets the k-th layout (objects, edit target, floor and wall colours),
so a reordered list (`--paths rings,forward,orbit`) with another `--seed` (camera jitter and
points) renders captures the defaults were not measured on.
"""

import argparse
import json
import math
import os
import shutil
import struct
import sys

import numpy as np
from PIL import Image

try:
    import pybullet as pb
    import pybullet_data
except ImportError:  # pragma: no cover
    sys.exit("mesh_captures.py: needs pybullet (pip install pybullet numpy pillow)")

FOV_DEG = 50.0
NEAR, FAR = 0.05, 200.0
TABLE_TOP = 0.625
SCRATCH = "/tmp/mesh_captures_assets"  # pybullet_data's table.urdf: a 1.5 x 1 top at z = 0.6 +- 0.025


def build_world(variant, room=False):
    """Loads the floor, the table and the objects; returns {name: body id}.

    `variant` picks the object arrangement, so the three captures do not share one
    layout; `room` stands walls round the table (the `room` path). The floor is plane100 (200 m square) with pybullet's checker texture
    tiled by its UVs; the table is the textured table.urdf."""
    data = pybullet_data.getDataPath()
    pb.setAdditionalSearchPath(data)
    bodies = {}
    bodies["floor"] = floor_body(variant)
    if room:
        bodies["walls"] = walls_body(variant)
    bodies["table"] = pb.loadURDF("table/table.urdf", [0, 0, 0], useFixedBase=True)
    top = TABLE_TOP
    quat = pb.getQuaternionFromEuler
    if variant == 0:
        bodies["duck"] = pb.loadURDF("duck_vhacd.urdf", [-0.35, 0.1, top], quat([math.pi / 2, 0, 0.6]),
                                     useFixedBase=True, globalScaling=2.5)
        bodies["ball"] = pb.loadURDF("soccerball.urdf", [0.3, -0.15, top + 0.12], useFixedBase=True,
                                     globalScaling=0.24)
        bodies["teddy"] = pb.loadURDF("teddy_large.urdf", [0.05, 0.25, top], quat([math.pi / 2, 0, -0.4]),
                                      useFixedBase=True, globalScaling=0.18)
        bodies["mug"] = pb.loadURDF("objects/mug.urdf", [0.5, 0.25, top], useFixedBase=True, globalScaling=1.2)
        bodies["cube"] = pb.loadURDF("cube_small.urdf", [-0.1, -0.3, top + 0.05], quat([0, 0, 0.5]),
                                     useFixedBase=True, globalScaling=2.0)
        target = "duck"
    elif variant == 1:
        bodies["mug"] = pb.loadURDF("objects/mug.urdf", [0.0, 0.0, top], quat([0, 0, 1.0]), useFixedBase=True,
                                    globalScaling=1.6)
        bodies["ball"] = pb.loadURDF("soccerball.urdf", [-0.45, -0.2, top + 0.1], useFixedBase=True,
                                     globalScaling=0.2)
        bodies["duck"] = pb.loadURDF("duck_vhacd.urdf", [0.4, 0.2, top], quat([math.pi / 2, 0, 2.2]),
                                     useFixedBase=True, globalScaling=2.2)
        bodies["cube"] = pb.loadURDF("cube_small.urdf", [0.35, -0.3, top + 0.06], quat([0, 0, 0.2]),
                                     useFixedBase=True, globalScaling=2.4)
        # A red distractor beside the target.
        bodies["cube2"] = pb.loadURDF("cube_small.urdf", [-0.2, 0.3, top + 0.04], quat([0, 0, 0.9]),
                                      useFixedBase=True, globalScaling=1.6)
        pb.changeVisualShape(bodies["cube2"], -1, rgbaColor=[0.85, 0.15, 0.1, 1])
        target = "mug"
    else:
        bodies["teddy"] = pb.loadURDF("teddy_large.urdf", [-0.1, 0.05, top], quat([math.pi / 2, 0, 0.3]),
                                      useFixedBase=True, globalScaling=0.2)
        bodies["duck"] = pb.loadURDF("duck_vhacd.urdf", [0.35, -0.1, top], quat([math.pi / 2, 0, -0.8]),
                                     useFixedBase=True, globalScaling=2.4)
        bodies["ball"] = pb.loadURDF("soccerball.urdf", [-0.45, -0.25, top + 0.11], useFixedBase=True,
                                     globalScaling=0.22)
        bodies["mug"] = pb.loadURDF("objects/mug.urdf", [0.45, 0.3, top], useFixedBase=True, globalScaling=1.2)
        target = "teddy"
    return bodies, target


def floor_body(variant):
    """A 120 m square floor: a generated OBJ whose texture (a two-tone checker with
    paving-like noise, 1 m squares, colours per capture) repeats every 2 m."""
    rng = np.random.default_rng(100 + variant)
    tones = [([0.62, 0.60, 0.55], [0.32, 0.30, 0.28]), ([0.45, 0.55, 0.35], [0.25, 0.35, 0.20]),
             ([0.70, 0.66, 0.62], [0.45, 0.30, 0.25])][variant % 3]
    n = 128
    yy, xx = np.mgrid[0:n, 0:n]
    checker = ((xx // (n // 2) + yy // (n // 2)) % 2)[..., None]
    tex = np.where(checker == 1, tones[0], tones[1]) * (1 + 0.12 * rng.standard_normal((n, n, 1)))
    folder = os.path.join(SCRATCH, f"floor{variant}")
    os.makedirs(folder, exist_ok=True)
    Image.fromarray(np.clip(tex * 255, 0, 255).astype(np.uint8)).save(os.path.join(folder, "floor.png"))
    half, reps = 60.0, 60.0
    with open(os.path.join(folder, "floor.obj"), "w") as fh:
        fh.write(f"v {-half} {-half} 0\nv {half} {-half} 0\nv {half} {half} 0\nv {-half} {half} 0\n")
        fh.write(f"vt 0 0\nvt {reps} 0\nvt {reps} {reps}\nvt 0 {reps}\nvn 0 0 1\n")
        fh.write("f 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n")
    shape = pb.createVisualShape(pb.GEOM_MESH, fileName=os.path.join(folder, "floor.obj"))
    body = pb.createMultiBody(baseMass=0, baseVisualShapeIndex=shape)
    pb.changeVisualShape(body, -1, textureUniqueId=pb.loadTexture(os.path.join(folder, "floor.png")))
    return body


def walls_body(variant, half=3.0, height=3.2):
    """Four walls facing inwards round the table, `half` m from its centre and `height`
    m high: a papered texture (vertical stripes with noise and a dado band, 0.5 m
    repeat) that a feature matcher would find points on, as on a real room's walls."""
    rng = np.random.default_rng(200 + variant)
    n = 128
    yy, xx = np.mgrid[0:n, 0:n]
    base = np.array([[0.80, 0.74, 0.62], [0.62, 0.70, 0.78], [0.78, 0.66, 0.66]][variant % 3])
    stripe = 0.85 + 0.15 * (((xx // 16) % 2) == 0)[..., None]
    tex = base * stripe * (1 + 0.10 * rng.standard_normal((n, n, 1)))
    folder = os.path.join(SCRATCH, f"walls{variant}")
    os.makedirs(folder, exist_ok=True)
    Image.fromarray(np.clip(tex * 255, 0, 255).astype(np.uint8)).save(os.path.join(folder, "walls.png"))
    reps_u, reps_v = 2 * half / 0.5, height / 0.5
    corners = [(-half, -half), (half, -half), (half, half), (-half, half)]
    with open(os.path.join(folder, "walls.obj"), "w") as fh:
        for k in range(4):
            (x0, y0), (x1, y1) = corners[k], corners[(k + 1) % 4]
            fh.write(f"v {x0} {y0} 0\nv {x1} {y1} 0\nv {x1} {y1} {height}\nv {x0} {y0} {height}\n")
            # Inward normal: the wall's direction turned towards the centre.
            nx, ny = -(y1 - y0) / (2 * half), (x1 - x0) / (2 * half)
            fh.write(f"vn {nx} {ny} 0\n")
        fh.write(f"vt 0 0\nvt {reps_u} 0\nvt {reps_u} {reps_v}\nvt 0 {reps_v}\n")
        for k in range(4):
            a = 4 * k
            # Wound clockwise seen from inside the room's outside, so the faces look in.
            fh.write(f"f {a + 1}/1/{k + 1} {a + 3}/3/{k + 1} {a + 2}/2/{k + 1}\n")
            fh.write(f"f {a + 1}/1/{k + 1} {a + 4}/4/{k + 1} {a + 3}/3/{k + 1}\n")
    shape = pb.createVisualShape(pb.GEOM_MESH, fileName=os.path.join(folder, "walls.obj"))
    body = pb.createMultiBody(baseMass=0, baseVisualShapeIndex=shape)
    pb.changeVisualShape(body, -1, textureUniqueId=pb.loadTexture(os.path.join(folder, "walls.png")))
    return body


def look_at(eye, target, up=(0.0, 0.0, 1.0)):
    """Camera-to-world (OpenGL: x right, y up, looking down -z) for an eye at `eye`."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    upv = np.cross(back, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, upv, back, eye
    return c2w


def camera_path(kind, views, rng):
    """The eyes and look-at points of one capture, in a fixed order (names sort the same)."""
    centre = np.array([0.0, 0.0, TABLE_TOP + 0.1])
    poses = []
    if kind == "orbit":
        for i in range(views):
            a = 2 * math.pi * i / views + rng.uniform(-0.03, 0.03)
            r, z = 1.75 + rng.uniform(-0.1, 0.1), 1.3 + rng.uniform(-0.08, 0.08)
            poses.append(look_at([r * math.cos(a), r * math.sin(a), z], centre))
    elif kind == "rings":
        rings = [(1.9, 0.95), (1.6, 1.5), (0.9, 2.2)]
        per = [views // 3 + (1 if k < views % 3 else 0) for k in range(3)]
        for (r, z), n in zip(rings, per):
            for i in range(n):
                a = 2 * math.pi * (i + 0.5 * (z > 2)) / n + rng.uniform(-0.03, 0.03)
                poses.append(look_at([r * math.cos(a), r * math.sin(a), z], centre))
    elif kind == "forward":
        # A 8 x 6 grid of eyes on a plane 2 m in front of the table, jittered, all
        # looking along the same axis at points behind the table.
        cols, rows = 8, max(1, views // 8)
        for j in range(rows):
            for i in range(cols):
                x = -0.35 + 0.9 * i / (cols - 1) + rng.uniform(-0.03, 0.03)
                z = 1.0 + 0.6 * j / max(rows - 1, 1) + rng.uniform(-0.03, 0.03)
                eye = np.array([x, -2.0, z])
                poses.append(look_at(eye, eye + np.array([0.0, 2.3, -0.45])))
        poses = poses[:views]
    elif kind == "room":
        # An arc of 200° in front of the back wall, every camera pitched down at the table.
        for i in range(views):
            a = math.radians(-100 + 200 * i / max(views - 1, 1)) + rng.uniform(-0.03, 0.03)
            r, z = 1.75 + rng.uniform(-0.1, 0.1), 1.4 + rng.uniform(-0.1, 0.1)
            poses.append(look_at([r * math.cos(a), r * math.sin(a), z], centre))
    else:
        raise ValueError(kind)
    return poses


def sky(dirs):
    """Colour of the environment at infinity along unit world directions (..., 3)."""
    elev = np.clip(dirs[..., 2], -1.0, 1.0)
    t = np.clip(elev / 0.6, 0.0, 1.0) ** 0.7
    horizon, zenith = np.array([0.86, 0.88, 0.92]), np.array([0.30, 0.50, 0.85])
    base = horizon * (1 - t[..., None]) + zenith * t[..., None]
    az = np.arctan2(dirs[..., 1], dirs[..., 0])
    cloud = 0.5 + 0.5 * np.sin(5 * az + 9 * elev) * np.sin(3 * az - 14 * elev + 1.3)
    cloud = np.clip((cloud - 0.55) * 2.5, 0.0, 1.0) * (elev > 0.03) * (1 - t)
    return base * (1 - cloud[..., None] * 0.6) + 0.97 * cloud[..., None] * 0.6


SUPERSAMPLE = 3


def render(c2w, size, supersample=SUPERSAMPLE):
    """RGB in [0, 1] (sky composited), world points (NaN on the sky), the centre
    sample's segmentation and the full-resolution segmentation.

    Rendered at `supersample` times the size and box-filtered down, as a camera's
    pixels integrate light (TinyRenderer has no antialiasing; the checker floor would
    alias differently in every view). Points and segmentation are the centre sample's."""
    big = size * supersample
    rgb, points, seg = render_once(c2w, big)
    k = supersample
    rgb = rgb.reshape(size, k, size, k, 3).mean(axis=(1, 3))
    return rgb, points[k // 2::k, k // 2::k], seg[k // 2::k, k // 2::k], seg


def render_once(c2w, size):
    """One TinyRenderer image with the sky composited."""
    view = np.linalg.inv(c2w)
    view_gl = view.T.reshape(-1).tolist()  # column-major, as OpenGL
    proj = pb.computeProjectionMatrixFOV(FOV_DEG, 1.0, NEAR, FAR)
    _, _, rgba, depth_buf, seg = pb.getCameraImage(
        size, size, view_gl, proj, renderer=pb.ER_TINY_RENDERER, shadow=1,
        lightDirection=[0.4, -0.6, 1.0], lightColor=[1, 1, 1], lightDistance=10,
        lightAmbientCoeff=0.55, lightDiffuseCoeff=0.5, lightSpecularCoeff=0.05)
    rgb = np.asarray(rgba, dtype=np.float64).reshape(size, size, 4)[..., :3] / 255.0
    zb = np.asarray(depth_buf, dtype=np.float64).reshape(size, size)
    depth = FAR * NEAR / (FAR - (FAR - NEAR) * zb)
    seg = np.asarray(seg).reshape(size, size)
    # Ray directions in world space for every pixel (pixel centres).
    f = 0.5 * size / math.tan(math.radians(FOV_DEG) / 2)
    u = (np.arange(size) + 0.5 - size / 2) / f
    xs, ys = np.meshgrid(u, -u)
    d_cam = np.stack([xs, ys, -np.ones_like(xs)], -1)
    d_world = d_cam @ c2w[:3, :3].T
    d_world /= np.linalg.norm(d_world, axis=-1, keepdims=True)
    sky_mask = seg < 0
    rgb[sky_mask] = sky(d_world[sky_mask])
    depth[sky_mask] = np.nan
    # Depth along the ray -> points.
    along = depth[..., None] * np.linalg.norm(d_cam, axis=-1, keepdims=True)
    points = c2w[:3, 3] + d_world * along
    return rgb, points, seg


def write_ply(path, xyz, rgb):
    with open(path, "wb") as fh:
        fh.write(("ply\nformat binary_little_endian 1.0\nelement vertex %d\n"
                  "property float x\nproperty float y\nproperty float z\n"
                  "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
                  % len(xyz)).encode())
        for p, c in zip(xyz.astype(np.float32), np.clip(rgb * 255 + 0.5, 0, 255).astype(np.uint8)):
            fh.write(struct.pack("<fffBBB", *p, *c))


def save_png(path, rgb):
    Image.fromarray(np.clip(rgb * 255 + 0.5, 0, 255).astype(np.uint8)).save(path)


def capture(kind, variant, out, size, views, seed, points_max):
    rng = np.random.default_rng(seed + 17 * variant)
    pb.resetSimulation()
    bodies, target = build_world(variant, room=kind == "room")
    poses = camera_path(kind, views, rng)
    if os.path.exists(out):
        shutil.rmtree(out)
    for sub in ("images", "masks", "edited", "labels"):
        os.makedirs(os.path.join(out, sub))
    frames, cloud_xyz, cloud_rgb = [], [], []
    # Edited appearance: the target recoloured (texture removed, a plain colour).
    edit_colour = [0.15, 0.35, 0.95, 1.0]
    # Object labels: 0 the floor, the walls and the sky, 1 the table, then the objects.
    objects = [n for n in bodies if n not in ("floor", "walls", "table")]
    label_of_body = {bodies["table"]: 1}
    label_of_body.update({bodies[n]: 2 + k for k, n in enumerate(objects)})
    for i, c2w in enumerate(poses):
        stem = f"view_{i:03d}"
        rgb, pts, seg, seg_full = render(c2w, size)
        save_png(os.path.join(out, "images", stem + ".png"), rgb)
        mask = (seg & ((1 << 24) - 1)) == bodies[target]
        Image.fromarray((mask * 255).astype(np.uint8)).save(os.path.join(out, "masks", stem + ".png"))
        body = np.where(seg_full < 0, -1, seg_full & ((1 << 24) - 1))
        labels = np.zeros(body.shape, dtype=np.uint8)
        for b, l in label_of_body.items():
            labels[body == b] = l
        Image.fromarray(labels).save(os.path.join(out, "labels", stem + ".png"))
        frames.append({"file_path": f"images/{stem}.png", "transform_matrix": c2w.tolist()})
        if i % 8 != 0:  # SfM sees only the training views
            ok = np.isfinite(pts[..., 0])  # not the sky
            idx = np.flatnonzero(ok.reshape(-1))
            take = rng.choice(idx, size=min(len(idx), 4 * points_max // max(views, 1)), replace=False)
            cloud_xyz.append(pts.reshape(-1, 3)[take])
            cloud_rgb.append(rgb.reshape(-1, 3)[take])
    # Ground-truth edit renders.
    pb.changeVisualShape(bodies[target], -1, textureUniqueId=-1, rgbaColor=edit_colour)
    for i, c2w in enumerate(poses):
        rgb, _, _, _ = render(c2w, size)
        save_png(os.path.join(out, "edited", f"view_{i:03d}.png"), rgb)
    xyz, col = np.concatenate(cloud_xyz), np.concatenate(cloud_rgb)
    # A real SfM cloud is sparse and noisy: keep at most points_max, jitter by 2 mm.
    keep = rng.choice(len(xyz), size=min(len(xyz), points_max), replace=False)
    xyz = xyz[keep] + rng.normal(scale=0.002, size=(len(keep), 3))
    write_ply(os.path.join(out, "points3d.ply"), xyz, col[keep])
    meta = {
        "camera_angle_x": math.radians(FOV_DEG),
        "w": size,
        "h": size,
        "ply_file_path": "points3d.ply",
        "frames": frames,
    }
    with open(os.path.join(out, "transforms.json"), "w") as fh:
        json.dump(meta, fh, indent=1)
    with open(os.path.join(out, "capture.json"), "w") as fh:
        json.dump({"path": kind, "variant": variant, "target": target, "edit_rgb": edit_colour[:3],
                   "objects": [{"name": n, "label": 2 + k} for k, n in enumerate(objects)],
                   "supersample": SUPERSAMPLE,
                   "views": len(poses), "size": size, "seed": seed, "renderer": "pybullet TinyRenderer"},
                  fh, indent=1)
    print(f"{kind}: {len(poses)} views, {len(keep)} points, target {target} -> {out}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--paths", default="orbit,rings,forward")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--views", type=int, default=48)
    ap.add_argument("--points", type=int, default=6000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    pb.connect(pb.DIRECT)
    for variant, kind in enumerate(args.paths.split(",")):
        capture(kind, variant, os.path.join(args.out, kind), args.size, args.views, args.seed, args.points)


if __name__ == "__main__":
    main()

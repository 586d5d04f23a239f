"""Checks our scene exports with a real reader: PlayCanvas splat-transform.

1. Our compressed PLY of a built-in scene has the same body, byte for byte, as the one
   splat-transform writes from the same PLY (same Morton order, chunk bounds and codes).
2. splat-transform reads our compressed PLY and our .spz with the same Gaussian count
   (its `-m` summary), and writes them back as plain PLYs.
3. Those PLYs, rendered by transsplat at the scene's cameras, match the original scene's
   renders within the format's quantisation (PSNR printed and bounded below).
4. glTF (KHR_gaussian_splatting): splat-transform 2.7.1 writes .glb but cannot read it
   (no glb input format), so its own .glb of the same PLY is compared with ours
   attribute by attribute (same count, same values after the documented differences:
   it stores the quaternion unnormalised and COLOR_0 in sRGB, we normalise and decode
   COLOR_0 to linear as the extension asks); our reader reads its file, and that
   scene renders at the original's PSNR. headless Chromium draws our file with the
   PlayCanvas engine (gltf_test.mjs).
5. SOG: splat-transform reads our .sog (count, its plain-PLY rewrite renders within the
   format's quantisation, as in 2-3); our reader reads splat-transform's own .sog of the
   same PLY, which renders at a stated PSNR too (the two writers' codebooks and palettes
   differ; the format fixes only how they are read). Sizes of both are printed.

Usage: python check_formats.py BIN SPLAT_TRANSFORM WORKDIR. Exits non-zero on failure.
"""

import glob
import os
import re
import subprocess
import sys

import json
import struct

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


def read_glb(path):
    """The splat primitive's attributes of a .glb, as float arrays (n, components)."""
    b = open(path, "rb").read()
    if b[:4] != b"glTF" or struct.unpack_from("<I", b, 8)[0] != len(b):
        sys.exit(f"{path}: not a GLB file of its own length")
    jl = struct.unpack_from("<I", b, 12)[0]
    doc = json.loads(b[20 : 20 + jl])
    binary = b[28 + jl :]
    prim = doc["meshes"][0]["primitives"][0]
    if prim.get("mode") != 0 or "KHR_gaussian_splatting" not in prim.get("extensions", {}):
        sys.exit(f"{path}: the primitive is not a POINTS primitive with KHR_gaussian_splatting")
    out = {}
    for name, i in prim["attributes"].items():
        a = doc["accessors"][i]
        v = doc["bufferViews"][a["bufferView"]]
        n = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[a["type"]]
        dtype = {5126: "<f4", 5121: "u1"}[a["componentType"]]
        start = v["byteOffset"] + a.get("byteOffset", 0)
        if start % 4 or v["byteOffset"] % 4:
            sys.exit(f"{path}: {name} is not 4-byte aligned")
        x = np.frombuffer(binary, dtype, a["count"] * n, start).reshape(-1, n).astype(np.float64)
        out[name] = x / 255.0 if a.get("normalized") else x
    pos = out["POSITION"]
    acc = doc["accessors"][prim["attributes"]["POSITION"]]
    if not (np.allclose(acc["min"], pos.min(0), rtol=0, atol=0) and np.allclose(acc["max"], pos.max(0), rtol=0, atol=0)):
        sys.exit(f"{path}: POSITION min/max do not match the data")
    return out


def srgb_to_linear(c):
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def compare_glb(ours, theirs):
    """Ours against splat-transform's .glb of the same PLY, attribute by attribute."""
    a, b = read_glb(ours), read_glb(theirs)
    problems = []
    if sorted(a) != sorted(b):
        problems.append(f"attributes differ: ours {sorted(a)}, theirs {sorted(b)}")
    worst = {}
    for name in sorted(set(a) & set(b)):
        x, y = a[name], b[name]
        if x.shape != y.shape:
            problems.append(f"{name}: shape {x.shape} against {y.shape}")
            continue
        if name.endswith("ROTATION"):
            y = y / np.linalg.norm(y, axis=1, keepdims=True)
        if name == "COLOR_0":
            y = np.concatenate([srgb_to_linear(y[:, :3]), y[:, 3:]], axis=1)
            # Theirs was rounded to 8 bits in sRGB, ours in linear: up to 2 steps apart.
            tol = 2.0 / 255 + 1e-9
        else:
            tol = 1e-6 * np.maximum(1.0, np.abs(y))
        err = np.abs(x - y)
        worst[name] = float(err.max())
        if np.any(err > tol):
            problems.append(f"{name}: differs by up to {err.max():.3g}")
    return worst, problems


def main():
    bin_, st, work = sys.argv[1:4]
    os.makedirs(work, exist_ok=True)
    ds = os.path.join(work, "ds")
    run(bin_, "scene", "tabletop", "--out", ds, "--force")
    src = os.path.join(ds, "point_cloud", "iteration_0", "point_cloud.ply")
    count = int(re.search(r"gaussians\s+([0-9]+)", run(bin_, "info", src)).group(1))
    ours_c = os.path.join(work, "ours.compressed.ply")
    ours_s = os.path.join(work, "ours.spz")
    ours_g = os.path.join(work, "ours.glb")
    ours_sog = os.path.join(work, "ours.sog")
    run(bin_, "convert", src, ours_sog)
    theirs_sog = os.path.join(work, "theirs.sog")
    # SH k-means on the CPU (-g cpu): no GPU here.
    run(st, "-w", "-g", "cpu", src, theirs_sog)
    for name, path in [("ours", ours_sog), ("splat-transform's", theirs_sog)]:
        print(f"SOG ({name}): {os.path.getsize(path) / count:.2f} bytes a Gaussian")
    run(bin_, "convert", src, ours_c)
    run(bin_, "convert", src, ours_s)
    run(bin_, "convert", src, ours_g)

    theirs_c = os.path.join(work, "theirs.compressed.ply")
    run(st, "-w", src, theirs_c)
    same = body(ours_c) == body(theirs_c)
    print(f"compressed PLY body identical to splat-transform's: {same}")
    if not same:
        sys.exit("our compressed PLY differs from splat-transform's")

    failures = []
    theirs_g = os.path.join(work, "theirs.glb")
    run(st, "-w", src, theirs_g)
    worst, problems = compare_glb(ours_g, theirs_g)
    print(f"glTF: our .glb against splat-transform's, largest difference per attribute: {worst}")
    failures += problems
    for name, path in [("ours", ours_g), ("theirs", theirs_g)]:
        n = len(read_glb(path)["POSITION"])
        if n != count:
            failures.append(f"glTF ({name}): {n} Gaussians, {count} in the PLY")
        print(f"glTF ({name}): {n} Gaussians, {os.path.getsize(path) / n:.1f} bytes a Gaussian")

    renders = {}
    for name, path, floor in [("compressed PLY", ours_c, 45.0), ("SPZ", ours_s, 42.0), ("SOG", ours_sog, 38.0)]:
        n = row_count(st, path)
        back = os.path.join(work, f"st_{os.path.basename(path)}.ply")
        run(st, "-w", path, back)
        out = os.path.join(work, f"r_{os.path.basename(path)}")
        run(bin_, "render", "--scene", back, "--cameras", os.path.join(ds, "cameras.json"), "--out", out, "--raw")
        renders[name] = (out, n, floor)
    # glTF: read back by our reader (splat-transform has no glb input), ours and theirs.
    # and splat-transform's SOG read by our reader.
    for name, path, floor in [
        ("glTF (ours, our reader)", ours_g, 90.0),
        ("glTF (splat-transform's, our reader)", theirs_g, 90.0),
        ("SOG (splat-transform's, our reader)", theirs_sog, 38.0),
    ]:
        back = os.path.join(work, f"back_{os.path.basename(path)}.ply")
        run(bin_, "convert", path, back)
        n = int(re.search(r"gaussians\s+([0-9]+)", run(bin_, "info", back)).group(1))
        out = os.path.join(work, f"r_{os.path.basename(path)}")
        run(bin_, "render", "--scene", back, "--cameras", os.path.join(ds, "cameras.json"), "--out", out, "--raw")
        renders[name] = (out, n, floor)
    ref = os.path.join(work, "r_src")
    run(bin_, "render", "--scene", src, "--cameras", os.path.join(ds, "cameras.json"), "--out", ref, "--raw")
    for name, (out, n, floor) in renders.items():
        ps = [psnr(np.load(f), np.load(os.path.join(out, os.path.basename(f)))) for f in sorted(glob.glob(f"{ref}/*.npy"))]
        print(
            f"{name}: {n} Gaussians read (of {count}); the plain-PLY rewrite renders at "
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

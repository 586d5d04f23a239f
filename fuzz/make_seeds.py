#!/usr/bin/env python3
"""Writes the small seed corpus under fuzz/corpus/<target>/ (plain Python 3, no packages).

Each target gets a few valid files and a few tricky ones (edge cases the parsers must
handle); the fuzzer grows its own corpus from these elsewhere (see README.md)."""
import os
import struct

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "corpus")


def put(target, name, data):
    d = os.path.join(ROOT, target)
    os.makedirs(d, exist_ok=True)
    if isinstance(data, str):
        data = data.encode()
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


# ---------------------------------------------------------------- PLY
BASE = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
TAIL = ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]


def ply_props(rest):
    return BASE + [f"f_rest_{i}" for i in range(rest)] + TAIL


def ply_header(fmt, n, props, ty="float", pre="", post=""):
    h = f"ply\nformat {fmt} 1.0\ncomment seed\n{pre}element vertex {n}\n"
    h += "".join(f"property {ty} {p}\n" for p in props)
    return h + post + "end_header\n"


def row(i, props):
    vals = []
    for p in props:
        if p == "rot_0":
            vals.append(1.0)
        elif p.startswith("scale"):
            vals.append(-3.0)
        else:
            vals.append(0.25 * i - 0.1 * len(vals))
    return vals


props0 = ply_props(0)
props1 = ply_props(9)
for fmt, end in [("binary_little_endian", "<"), ("binary_big_endian", ">")]:
    body = b"".join(struct.pack(end + "f" * len(props1), *row(i, props1)) for i in range(2))
    put("ply", f"{fmt}_sh1.ply", ply_header(fmt, 2, props1).encode() + body)
body = b"".join(struct.pack("<" + "d" * len(props0), *row(i, props0)) for i in range(2))
put("ply", "double_sh0.ply", ply_header("binary_little_endian", 2, props0, "double").encode() + body)
ascii_rows = "".join(" ".join(f"{v:g}" for v in row(i, props0)) + "\n" for i in range(3))
put("ply", "ascii_sh0.ply", ply_header("ascii", 3, props0) + ascii_rows)
# other elements before and after the vertices, a list property, an extra property
pre = "element camera 1\nproperty float k\nproperty list uchar int idx\n"
post = "property uchar red\nelement face 1\nproperty list uchar int vertex_indices\n"
vals = [row(i, props0) + [7] for i in range(2)]
text = "1.5 2 4 5\n" + "".join(" ".join(f"{v:g}" for v in r) + "\n" for r in vals) + "3 0 1 0\n"
put("ply", "ascii_elements.ply", ply_header("ascii", 2, props0, pre=pre, post=post) + text)
# NaN (read with drop_invalid), CRLF header, lying count
nan = struct.pack("<" + "f" * len(props0), *([float("nan")] + row(0, props0)[1:]))
ok = struct.pack("<" + "f" * len(props0), *row(1, props0))
put("ply", "nan_row.ply", ply_header("binary_little_endian", 2, props0).encode() + nan + ok)
put("ply", "crlf.ply", ply_header("binary_little_endian", 1, props0).replace("\n", "\r\n").encode() + ok)
put("ply", "lying_count.ply", ply_header("binary_little_endian", 4000000000, props0).encode() + ok)

# ---------------------------------------------------------------- COLMAP


def split3(a, b, c):
    return struct.pack("<HH", len(a), len(b)) + a + b + c


def cams_bin(cams):
    out = struct.pack("<Q", len(cams))
    for cid, model, w, h, params in cams:
        out += struct.pack("<IiQQ", cid, model, w, h) + struct.pack("<" + "d" * len(params), *params)
    return out


def images_bin(images):
    out = struct.pack("<Q", len(images))
    for iid, q, t, cid, name, npts in images:
        out += struct.pack("<I4d3dI", iid, *q, *t, cid) + name.encode() + b"\0"
        out += struct.pack("<Q", npts) + b"\0" * (24 * npts)
    return out


def points_bin(points):
    out = struct.pack("<Q", len(points))
    for pid, xyz, rgb, track in points:
        out += struct.pack("<Q3d3Bd", pid, *xyz, *rgb, 0.5) + struct.pack("<Q", track) + b"\0" * (8 * track)
    return out


cams = [(1, 1, 64, 48, [50.0, 50.0, 32.0, 24.0]), (2, 0, 32, 32, [30.0, 16.0, 16.0])]
imgs = [(1, (1, 0, 0, 0), (0, 0, 2), 1, "a.png", 2), (2, (0.9, 0.1, 0, 0), (0.1, 0, 2), 2, "b.png", 0)]
pts = [(1, (0.0, 0.1, 0.2), (255, 0, 10), 2), (2, (1.0, 1.0, 1.0), (1, 2, 3), 0)]
put("colmap_bin", "valid.bin", split3(cams_bin(cams), images_bin(imgs), points_bin(pts)))
put("colmap_bin", "no_points.bin", split3(cams_bin(cams), images_bin(imgs), b""))
put("colmap_bin", "opencv_zero_dist.bin",
    split3(cams_bin([(1, 4, 64, 48, [50, 50, 32, 24, 0, 0, 0, 0])]), images_bin(imgs[:1]), points_bin([])))
put("colmap_bin", "fisheye.bin",
    split3(cams_bin([(1, 5, 64, 48, [50, 50, 32, 24, 0, 0, 0, 0])]), images_bin(imgs[:1]), b""))
put("colmap_bin", "lying_counts.bin",
    split3(struct.pack("<Q", 1 << 62) + cams_bin(cams)[8:], struct.pack("<Q", 10**12), struct.pack("<Q", 1 << 63)))

cams_txt = "# Camera list\n1 PINHOLE 64 48 50 50 32 24\n2 SIMPLE_PINHOLE 32 32 30 16 16\n"
imgs_txt = ("# Image list\n1 1 0 0 0 0 0 2 1 a.png\n10 20 -1 30 40 2\n"
            "2 0.9 0.1 0 0 0.1 0 2 2 name with spaces.png\n\n")
pts_txt = "# 3D points\n1 0 0.1 0.2 255 0 10 0.5 1 0 2 1\n2 1 1 1 1 2 3 0.1\n"
put("colmap_txt", "valid.txt", split3(cams_txt.encode(), imgs_txt.encode(), pts_txt.encode()))
put("colmap_txt", "radial_dist.txt",
    split3(b"1 SIMPLE_RADIAL 64 48 50 32 24 0.01\n", b"1 1 0 0 0 0 0 2 1 a.png\n", b""))
put("colmap_txt", "bad_camera_ref.txt", split3(cams_txt.encode(), b"1 1 0 0 0 0 0 2 9 a.png\n\n", b""))
put("colmap_txt", "zero_size.txt", split3(b"1 PINHOLE 0 48 50 50 32 24\n", b"1 1 0 0 0 0 0 2 1 a.png\n", b""))

# ---------------------------------------------------------------- cameras.json
put("cameras_json", "valid.json", """[
 {"id": 0, "img_name": "a", "width": 64, "height": 48, "position": [0, 0, -2],
  "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "fy": 50.0, "fx": 50.0},
 {"id": 1, "img_name": 7, "width": 64.0, "height": 48, "position": [0.5, 0, -2],
  "rotation": [[0, 0, 1], [0, 1, 0], [-1, 0, 0]], "fy": 40, "fx": 41.5}
]""")
put("cameras_json", "zero_focal.json",
    '[{"id":0,"img_name":"a","width":4,"height":4,"position":[0,0,0],'
    '"rotation":[[1,0,0],[0,1,0],[0,0,1]],"fx":0,"fy":1}]')
put("cameras_json", "huge_numbers.json",
    '[{"id":0,"img_name":"a","width":1e300,"height":-4,"position":[1e39,0,0],'
    '"rotation":[[1,0,0],[0,1,0]],"fx":1e-320,"fy":1}]')
put("cameras_json", "transforms_like.json", '{"frames": [], "fl_x": 1}')

# ---------------------------------------------------------------- transforms.json
put("transforms_json", "nerfstudio.json", """{
 "camera_model": "OPENCV", "fl_x": 50, "fl_y": 50, "cx": 32, "cy": 24, "w": 64, "h": 48,
 "k1": 0, "k2": 0, "p1": 0, "p2": 0, "ply_file_path": "sparse_pc.ply",
 "frames": [
  {"file_path": "images/a.png",
   "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,2],[0,0,0,1]]},
  {"file_path": "images/b.png", "fl_x": 40,
   "transform_matrix": [[0,0,1,1],[0,1,0,0],[-1,0,0,2]]}
 ]}""")
put("transforms_json", "blender.json", """{"camera_angle_x": 0.69, "w": 800, "h": 800, "frames": [
 {"file_path": "./train/r_0", "rotation": 0.01,
  "transform_matrix": [[-1,0,0,0],[0,0.7,-0.7,-2.8],[0,-0.7,-0.7,2.8],[0,0,0,1]]}]}""")
put("transforms_json", "needs_image.json",
    '{"camera_angle_x": 0.7, "frames": [{"file_path": "r_0", '
    '"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]}')
put("transforms_json", "distorted.json",
    '{"fl_x": 5, "w": 4, "h": 4, "k1": 0.1, "frames": [{"file_path": "a", '
    '"transform_matrix": [[2,0,0,0],[0,1,0,0],[0,0,1,0]]}]}')

# ---------------------------------------------------------------- npy


def npy(descr, shape, payload, fortran=False, version=1):
    shape_s = "(" + "".join(f"{d}, " for d in shape).rstrip(" ") + ")"
    if len(shape) > 1:
        shape_s = "(" + ", ".join(str(d) for d in shape) + ")"
    header = f"{{'descr': '{descr}', 'fortran_order': {fortran}, 'shape': {shape_s}, }}"
    header += " " * ((64 - (len(header) + 11 + (2 if version > 1 else 0)) % 64) % 64) + "\n"
    if version == 1:
        return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode() + payload
    return b"\x93NUMPY" + bytes([version, 0]) + struct.pack("<I", len(header)) + header.encode() + payload


put("npy", "f4_2x3.npy", npy("<f4", [2, 3], struct.pack("<6f", 0, 1, 2, 3, 4, float("inf"))))
put("npy", "f8_fortran.npy", npy("<f8", [2, 3], struct.pack("<6d", 0, 3, 1, 4, 2, 5), fortran=True))
put("npy", "be_i2_v2.npy", npy(">i2", [4], struct.pack(">4h", -1, 2, -3, 4), version=2))
put("npy", "f2_scalar_v3.npy", npy("<f2", [], struct.pack("<e", 1.5), version=3))
put("npy", "u1_empty.npy", npy("|u1", [0, 5], b""))
put("npy", "huge_shape.npy", npy("<f4", [1 << 40, 1 << 30], b"\0" * 8))

# ---------------------------------------------------------------- edit config
put("edit_config", "full.toml", """method = "transsplat"
semantic_dim = 16
seed = 3
[prototypes]
count = 32
[transport]
eps = 0.05
top_k = 128
[fusion]
rho = 0.1
ema = 0.5
[loss]
leak = 0.2
[schedule]
steps = 100
transport_every = 50
[lr]
sh_dc = 0.01
""")
put("edit_config", "overrides.toml", "loss.leak=0.5\ntransport.top_k=64\nmethod=naive\n")
put("edit_config", "bad.toml", "[transport]\nepsilon = 1\neps = nan\n[loss]\nimg = inf\n")

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

# ---------------------------------------------------------------- image (PNG by hand, JPEG literals)


def png(w, h, color, depth, raw_rows, plte=None, trns=None, interlace=0, chunks=None):
    """A PNG from already-filtered scanlines (each row starts with its filter byte)."""
    import zlib

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    out = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, depth, color, 0, 0, interlace))
    if plte is not None:
        out += chunk(b"PLTE", plte)
    if trns is not None:
        out += chunk(b"tRNS", trns)
    for kind, body in chunks or []:
        out += chunk(kind, body)
    return out + chunk(b"IDAT", zlib.compress(b"".join(raw_rows))) + chunk(b"IEND", b"")


put("image", "rgb8.png", png(3, 2, 2, 8, [b"\0" + bytes(range(i * 9, i * 9 + 9)) for i in range(2)]))
put("image", "rgba8_filters.png",
    png(2, 4, 6, 8, [bytes([f]) + bytes([10 * f + k for k in range(8)]) for f in range(4)]))
put("image", "grey16.png", png(2, 2, 0, 16, [b"\0\xff\xff\x80\x00", b"\2\x00\x01\x00\x02"]))
put("image", "grey_alpha8.png", png(2, 1, 4, 8, [b"\0\x10\x80\xf0\x00"]))
put("image", "rgb16.png", png(1, 1, 2, 16, [b"\0\xff\xff\x80\x00\x00\x00"]))
put("image", "palette4_trns.png", png(4, 2, 3, 4, [b"\0\x01\x23", b"\0\x32\x10"],
                                       plte=bytes(range(12)), trns=b"\x00\x80"))
put("image", "grey1.png", png(9, 1, 0, 1, [b"\0\xa5\x80"]))
# Adam7 passes of a 3x3 RGB image: 1x1, 1x1, 2x1, 1x2 (two rows), 3x1 pixels
put("image", "interlaced.png", png(3, 3, 2, 8, [b"\0" + bytes(range(k, k + 3 * n)) for k, n in
                                                [(0, 1), (3, 1), (6, 2), (12, 1), (15, 1), (18, 3)]], interlace=1))
put("image", "huge_header.png", png(32768, 32768, 6, 16, [b"\0" * 16]))
put("image", "truncated.png", png(4, 4, 2, 8, [b"\0" + bytes(12)] * 4)[:-30])
JPEG_BASELINE = bytes.fromhex(  # 8x8 RGB, quality 50, written once with PIL
    "ffd8ffe000104a46494600010100000100010000ffdb004300100b0c0e0c0a100e0d0e1211101318281a181616183123"
    "251d283a333d3c3933383740485c4e404457453738506d51575f626768673e4d71797064785c656763ffdb0043011112"
    "121815182f1a1a2f63423842636363636363636363636363636363636363636363636363636363636363636363636363"
    "6363636363636363636363636363ffc00011080008000803012200021101031101ffc4001f0000010501010101010100"
    "000000000000000102030405060708090a0bffc400b5100002010303020403050504040000017d010203000411051221"
    "31410613516107227114328191a1082342b1c11552d1f02433627282090a161718191a25262728292a3435363738393a"
    "434445464748494a535455565758595a636465666768696a737475767778797a838485868788898a9293949596979899"
    "9aa2a3a4a5a6a7a8a9aab2b3b4b5b6b7b8b9bac2c3c4c5c6c7c8c9cad2d3d4d5d6d7d8d9dae1e2e3e4e5e6e7e8e9eaf1"
    "f2f3f4f5f6f7f8f9faffc4001f0100030101010101010101010000000000000102030405060708090a0bffc400b51100"
    "020102040403040705040400010277000102031104052131061241510761711322328108144291a1b1c109233352f015"
    "6272d10a162434e125f11718191a262728292a35363738393a434445464748494a535455565758595a63646566676869"
    "6a737475767778797a82838485868788898a92939495969798999aa2a3a4a5a6a7a8a9aab2b3b4b5b6b7b8b9bac2c3c4"
    "c5c6c7c8c9cad2d3d4d5d6d7d8d9dae2e3e4e5e6e7e8e9eaf2f3f4f5f6f7f8f9faffda000c03010002110311003f0083"
    "4fd0ba7c94514573d5c4d4e6dcbc062eafb15a9fffd9")
JPEG_PROGRESSIVE = bytes.fromhex(  # 4x4 grey, progressive, written once with PIL
    "ffd8ffe000104a46494600010100000100010000ffdb0043001b12141714111b1716171e1c1b2028422b28252528513a3d"
    "3042605565645f555d5b6a7899816a7190735b5d85b586909ea3abadab6780bcc9baa6c799a8aba4ffc2000b0800040004"
    "01011100ffc40014000100000000000000000000000000000003ffda00080101000000014fffc4001610010101000000000"
    "00000000000000000020111ffda00080101000105022267ffc40014100100000000000000000000000000000000ffda000"
    "8010100063f027fffc4001510010100000000000000000000000000000041ffda0008010100013f218cffda000801010000"
    "00107fffc4001510010100000000000000000000000000000011ffda0008010100013f1086ff00ffd9")
put("image", "baseline.jpg", JPEG_BASELINE)
put("image", "progressive_grey.jpg", JPEG_PROGRESSIVE)
put("image", "truncated.jpg", JPEG_BASELINE[:400])
sof = JPEG_BASELINE.index(b"\xff\xc0")  # SOF0: length(2) precision(1) height(2) width(2)
put("image", "huge_size.jpg", JPEG_BASELINE[:sof + 5] + b"\x7f\xff\x7f\xff" + JPEG_BASELINE[sof + 9:])
put("image", "zero_size.jpg", JPEG_BASELINE[:sof + 5] + b"\x00\x00\x00\x08" + JPEG_BASELINE[sof + 9:])

# ---------------------------------------------------------------- archive
# The first byte is the target's mode: 0 whole file, 1 body (the target appends the
# checksum), 2 and 3 bytes that drive archive::Writer (see fuzz_targets/archive.rs).


def archive_body(entries):
    """Header and entries of a checkpoint (crates/scene/src/archive.rs), no trailer."""
    out = b"TSPLCKPT" + struct.pack("<II", 1, len(entries))
    for name, code, payload, count in entries:
        out += struct.pack("<H", len(name.encode())) + name.encode() + bytes([code]) + struct.pack("<Q", count)
        out += payload
    return out


ENTRIES = [("means", 1, struct.pack("<4f", 0.5, -1.0, float("nan"), 3.0), 4),
           ("ids", 2, struct.pack("<2I", 7, 8), 2), ("step", 3, struct.pack("<Q", 42), 1),
           ("lr", 4, struct.pack("<d", 1e-3), 1), ("config", 5, "méthode = 1".encode(), len("méthode = 1".encode()))]
put("archive", "body_valid", b"\x01" + archive_body(ENTRIES))
put("archive", "body_empty", b"\x01" + archive_body([]))
put("archive", "body_duplicate_name", b"\x01" + archive_body(ENTRIES[:2] + [("ids", 5, b"x", 1)]))
put("archive", "body_lying_count", b"\x01" + archive_body(ENTRIES[:1])[:12] + struct.pack("<I", 1 << 31)
    + archive_body(ENTRIES[:1])[16:])
put("archive", "body_huge_len", b"\x01" + archive_body([("a", 4, b"", 1 << 61)]))
put("archive", "body_bad_type_utf8", b"\x01" + archive_body([("\xff", 9, b"", 0)]).replace(b"\xc3\xbf", b"\xff\xbf"))
put("archive", "body_version2", b"\x01" + archive_body(ENTRIES[:1]).replace(b"\x01\x00\x00\x00", b"\x02\x00\x00\x00", 1))
put("archive", "file_bad_checksum", b"\x00" + archive_body(ENTRIES) + b"\0" * 8 + b"TSPLEND\0")
put("archive", "file_truncated", b"\x00" + archive_body(ENTRIES)[:40])
# Writer-driven: type, name length, name, count, values (see build() in the target)
put("archive", "writer_f32_text", b"\x02" + b"\x00\x03abc\x02" + struct.pack("<2f", 1.5, -2) + b"\x04\x01t\x03hi!")
put("archive", "writer_mutated", b"\x03" + b"\x10\x00\x0b\x7f" + b"\x02\x01s\x01" + struct.pack("<Q", 9) + b"\x03\x00\x01")

# ---------------------------------------------------------------- model configs
# First byte: 0 DINOv2, 1 CLIP text, 2 CLIP vision, 3 CLIP, 4 UNet, 5 VAE, 6 DDIM.
import json

FIX = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "crates", "models", "tests", "fixtures")


def fixture(path):
    with open(os.path.join(FIX, path)) as f:
        return json.load(f)


clip_full = fixture("clip/full/config.json")
for kind, name, cfg in [(0, "dinov2", fixture("dinov2/config.json")), (1, "clip_text", fixture("clip/text/config.json")),
                        (2, "clip_vision", clip_full["vision_config"]), (3, "clip", clip_full),
                        (4, "unet", fixture("ip2p/unet/config.json")), (5, "vae", fixture("ip2p/vae/config.json")),
                        (6, "ddim", fixture("ip2p/scheduler/scheduler_config.json"))]:
    put("model_config", name, bytes([kind]) + json.dumps(cfg).encode())
put("model_config", "dinov2_zero_heads", b"\x00" + json.dumps(dict(fixture("dinov2/config.json"), num_attention_heads=0)).encode())
put("model_config", "unet_zero_groups", b"\x04" + json.dumps(dict(fixture("ip2p/unet/config.json"), norm_num_groups=0)).encode())
put("model_config", "vae_many_blocks", b"\x05" + json.dumps(dict(fixture("ip2p/vae/config.json"), block_out_channels=[8] * 70)).encode())

# ---------------------------------------------------------------- glTF (KHR_gaussian_splatting)
GS = "KHR_gaussian_splatting"


def glb(n, degree=1, opacity_u8=False, stride=False, count=None, ext=True, mode=0):
    """A .glb of n Gaussians: one tightly packed float view per attribute (or, with
    stride, POSITION and SCALE interleaved in one view), opacity as float or
    normalised bytes."""
    attrs = [("POSITION", "VEC3", 3), (f"{GS}:ROTATION", "VEC4", 4), (f"{GS}:SCALE", "VEC3", 3),
             (f"{GS}:OPACITY", "SCALAR", 1)]
    attrs += [(f"{GS}:SH_DEGREE_{l}_COEF_{c}", "VEC3", 3) for l in range(degree + 1) for c in range(2 * l + 1)]
    binary, views, accessors, names = b"", [], [], {}
    for k, (name, kind, comps) in enumerate(attrs):
        if name.endswith("ROTATION"):
            vals = [0.0, 0.0, 0.0, 1.0] * n
        elif name.endswith("SCALE"):
            vals = [0.01 * (i + 1) for i in range(n * 3)]
        elif name.endswith("OPACITY"):
            vals = [0.5] * n
        else:
            vals = [0.1 * i - 0.2 * k for i in range(n * comps)]
        if opacity_u8 and name.endswith("OPACITY"):
            data, ctype, norm = bytes(128 for _ in range(n)), 5121, True
        else:
            data, ctype, norm = struct.pack(f"<{len(vals)}f", *vals), 5126, False
        views.append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(data)})
        binary += data + b"\0" * (-len(data) % 4)
        acc = {"bufferView": k, "componentType": ctype, "count": n if count is None else count, "type": kind}
        if norm:
            acc["normalized"] = True
        if name == "POSITION":
            acc["min"], acc["max"] = [min(vals[a::3]) for a in range(3)], [max(vals[a::3]) for a in range(3)]
        accessors.append(acc)
        names[name] = k
    if stride:
        # POSITION and SCALE interleaved, 24 bytes an element.
        pos = struct.unpack(f"<{3 * n}f", binary[views[0]["byteOffset"]:][:12 * n])
        sc = [0.01] * (3 * n)
        inter = b"".join(struct.pack("<6f", *pos[3 * i:3 * i + 3], *sc[3 * i:3 * i + 3]) for i in range(n))
        views.append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(inter), "byteStride": 24})
        binary += inter
        accessors[0]["bufferView"] = len(views) - 1
        accessors[2] = {"bufferView": len(views) - 1, "byteOffset": 12, "componentType": 5126, "count": n, "type": "VEC3"}
    prim = {"attributes": names, "mode": mode}
    if ext:
        prim["extensions"] = {GS: {"kernel": "ellipse", "colorSpace": "srgb_rec709_display"}}
    doc = {"asset": {"version": "2.0"}, "extensionsUsed": [GS], "scene": 0, "scenes": [{"nodes": [0]}],
           "nodes": [{"mesh": 0}], "meshes": [{"primitives": [prim]}], "accessors": accessors,
           "bufferViews": views, "buffers": [{"byteLength": len(binary)}]}
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    total = 12 + 8 + len(js) + 8 + len(binary)
    return (b"glTF" + struct.pack("<III", 2, total, len(js)) + b"JSON" + js
            + struct.pack("<I", len(binary)) + b"BIN\0" + binary)


put("gltf", "sh1.glb", glb(3))
put("gltf", "sh3.glb", glb(2, degree=3))
put("gltf", "sh0_u8_opacity.glb", glb(4, degree=0, opacity_u8=True))
put("gltf", "interleaved.glb", glb(3, degree=0, stride=True))
put("gltf", "lying_count.glb", glb(2, degree=0, count=1 << 30))
put("gltf", "no_extension.glb", glb(2, degree=0, ext=False))
put("gltf", "triangles.glb", glb(2, degree=0, mode=4))
put("gltf", "truncated.glb", glb(3)[:-7])

# ---------------------------------------------------------------- SOG
# Mode bytes (fuzz_targets/sog.rs): 1 and 2 build a bundle from floats (degree = mode / 3
# % 4), 0 parses the rest as a file (the fuzzer finds zips from modes 1 and 2's paths).
def sog_floats(n, degree):
    per = 11 + 3 * (degree + 1) ** 2
    vals = []
    for i in range(n):
        r = [0.1 * i, -0.2 * i, 0.05 * i, -3.0, -3.5, -4.0, 1.0, 0.1 * i, 0.0, 0.0, 0.5 - 0.1 * i]
        vals += r + [0.01 * (j - i) for j in range(per - 11)]
    return struct.pack(f"<{len(vals)}f", *vals)


put("sog", "build_sh0", bytes([1]) + sog_floats(5, 0))
put("sog", "build_sh1", bytes([4]) + sog_floats(4, 1))
put("sog", "build_sh3_mutate", bytes([11]) + struct.pack("<IBBBB", 40, 6, 255, 0, 0) + sog_floats(3, 3))
put("sog", "zip_garbage", b"\0PK\x03\x04\x14\0\0\0\0\0")

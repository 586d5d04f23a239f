"""The reference-trainer scripts under tools/ read and write what transsplat reads and
writes: their COLMAP reader against the library's, their PLY writer against its PLY
reader, and both scripts' held-out split (the GPU side of them cannot run here)."""

import importlib.util
import subprocess
import sys

import numpy as np
import transsplat

from conftest import ROOT, run_cli


def tool(name):
    spec = importlib.util.spec_from_file_location(name, ROOT / "tools" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_gsplat_reference_reads_the_capture_as_transsplat_does(tmp_path):
    cap = tmp_path / "cap"
    run_cli("scene", "tabletop", "--open", "--views", "17", "--width", "40", "--height", "30",
            "--points", "300", "--out", cap)
    g = tool("gsplat_reference")
    views, xyz, rgb = g.read_capture(cap)
    cams = transsplat.load_cameras(cap / "sparse" / "0")
    order = np.argsort(cams["names"])
    assert [v[0] for v in views] == [cams["names"][i] for i in order]
    np.testing.assert_allclose(np.stack([v[1] for v in views]), cams["viewmats"][order], atol=1e-5)
    np.testing.assert_allclose(np.stack([v[2] for v in views]), cams["Ks"][order], atol=1e-4)
    assert {(v[3], v[4]) for v in views} == {(40, 30)}
    assert xyz.shape[1] == 3 and 0 < len(xyz) <= 300 and rgb.shape == xyz.shape
    assert 0.0 <= rgb.min() and rgb.max() <= 1.0
    # The held-out views are the ones reference_trainer.py scores: every 8th by name.
    held = {v[0] for i, v in enumerate(views) if i % g.LLFF_HOLD == 0}
    assert held == tool("reference_trainer").test_names([v[0] for v in views])
    assert len(held) == 3


def test_gsplat_reference_reads_a_nerfstudio_capture_as_transsplat_does(tmp_path):
    """A transforms.json capture (what tools/mesh_captures.py writes): the OpenGL-to-OpenCV
    flip, the focal length from camera_angle_x and the binary points, against the library."""
    import json
    import math

    rng = np.random.default_rng(3)
    frames = []
    for i in range(9):
        a, b = rng.normal(size=3), rng.normal(size=3)
        q, _ = np.linalg.qr(np.stack([a, b, rng.normal(size=3)], 1))
        c2w = np.eye(4)
        c2w[:3, :3] = q * np.sign(np.linalg.det(q))
        c2w[:3, 3] = rng.normal(size=3) * 3
        frames.append({"file_path": f"images/view_{8 - i:03d}.png", "transform_matrix": c2w.tolist()})
    meta = {"camera_angle_x": 0.9, "w": 40, "h": 30, "ply_file_path": "points3d.ply", "frames": frames}
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    xyz = rng.normal(size=(5, 3)).astype("<f4")
    rgb = rng.integers(0, 256, size=(5, 3)).astype("u1")
    rows = np.zeros(5, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for k, col in zip(("x", "y", "z"), xyz.T):
        rows[k] = col
    for k, col in zip(("red", "green", "blue"), rgb.T):
        rows[k] = col
    header = "ply\nformat binary_little_endian 1.0\nelement vertex 5\n"
    header += "".join(f"property float {k}\n" for k in "xyz")
    header += "".join(f"property uchar {k}\n" for k in ("red", "green", "blue")) + "end_header\n"
    (tmp_path / "points3d.ply").write_bytes(header.encode() + rows.tobytes())

    views, got_xyz, got_rgb = tool("gsplat_reference").read_capture(tmp_path)
    cams = transsplat.load_cameras(tmp_path / "transforms.json")
    order = np.argsort(cams["names"])
    assert [v[0] for v in views] == [f"view_{i:03d}.png" for i in range(9)]
    np.testing.assert_allclose(np.stack([v[1] for v in views]), cams["viewmats"][order], atol=1e-5)
    np.testing.assert_allclose(np.stack([v[2] for v in views]), cams["Ks"][order], atol=1e-3)
    assert abs(views[0][2][0, 0] - 20 / math.tan(0.45)) < 1e-9
    np.testing.assert_array_equal(got_xyz, xyz)
    np.testing.assert_allclose(got_rgb, rgb / 255.0, atol=1e-7)


def test_gsplat_reference_ply_round_trips_through_load_ply(tmp_path):
    g = tool("gsplat_reference")
    rng = np.random.default_rng(3)
    n = 7
    means = rng.normal(size=(n, 3)).astype(np.float32)
    quats = rng.normal(size=(n, 4)).astype(np.float32) * 3.0
    log_scales = rng.normal(size=(n, 3)).astype(np.float32)
    logits = rng.normal(size=n).astype(np.float32)
    # Every coefficient distinct, so a transposed SH rest cannot pass.
    sh = (np.arange(n * 16 * 3, dtype=np.float32).reshape(n, 16, 3) / 100.0).astype(np.float32)
    path = tmp_path / "g.ply"
    g.write_inria_ply(str(path), means, quats, log_scales, logits, sh)
    back = transsplat.load_ply(path)
    np.testing.assert_array_equal(back["means"], means)
    np.testing.assert_allclose(back["quats"], quats / np.linalg.norm(quats, axis=1, keepdims=True), atol=1e-6)
    np.testing.assert_array_equal(back["log_scales"], log_scales)
    np.testing.assert_array_equal(back["opacity_logits"], logits)
    np.testing.assert_array_equal(back["sh"], sh)
    assert not (tmp_path / "g.ply.partial").exists()


def test_reference_trainer_scores_a_scene_trained_elsewhere(tmp_path):
    """`reference_trainer.py --score-ply`: the capture's own ground-truth scene, rendered by
    transsplat at the held-out cameras and scored in numpy, matches its images (to 8-bit
    rounding); a file that is not there is refused."""
    import json

    from conftest import cli_binary

    script = str(ROOT / "tools" / "reference_trainer.py")
    base = [sys.executable, script, "--transsplat", str(cli_binary()), "--out", str(tmp_path / "a"),
            "--size", "48", "--views", "16", "--points", "300", "--skip", "opensplat,transsplat"]
    # The capture is written first; its ground-truth scene is then there to score.
    r = subprocess.run(base, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    gt = tmp_path / "a" / "capture" / "point_cloud" / "iteration_0" / "point_cloud.ply"
    r = subprocess.run(base + ["--score-ply", f"truth={gt}"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    res = json.loads((tmp_path / "a" / "anchor_opensplat_transsplat.json").read_text())["results"]["truth"]
    assert len(res["per_view"]) == 2 and res["psnr"] > 40.0, res
    assert res["gaussians"] > 0
    # Another scene under the same label is rendered afresh, not scored from the old renders.
    g = transsplat.load_ply(gt)
    g["sh"][:, 0] += 0.5
    other = tmp_path / "other.ply"
    transsplat.save_ply(other, g)
    r = subprocess.run(base + ["--score-ply", f"truth={other}"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    res2 = json.loads((tmp_path / "a" / "anchor_opensplat_transsplat.json").read_text())["results"]["truth"]
    assert res2["psnr"] < res["psnr"] - 10.0, (res["psnr"], res2["psnr"])
    for spec in [f"x={tmp_path / 'none.ply'}", f"../up={gt}", f"a/b={gt}"]:
        bad = subprocess.run(base + ["--score-ply", spec], capture_output=True, text=True)
        assert bad.returncode != 0 and "--score-ply" in bad.stderr, spec
    assert not (tmp_path / "up").exists() and not (tmp_path / "a" / "scored_..").exists()


def test_gsplat_reference_refuses_outputs_inside_the_capture(tmp_path):
    g = tool("gsplat_reference")
    cap = tmp_path / "cap"
    (cap / "images").mkdir(parents=True)
    assert g.outside(cap, tmp_path / "out.json")
    assert not g.outside(cap, cap / "out.json")
    assert not g.outside(cap, cap / "images" / "view_000.png")
    assert not g.outside(cap, cap)
    # Through a link to the capture, too.
    (tmp_path / "link").symlink_to(cap)
    assert not g.outside(cap, tmp_path / "link" / "out.json")
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "gsplat_reference.py"), "--capture", str(cap),
                        "--out", str(cap / "r.json")], capture_output=True, text=True)
    assert r.returncode == 2 and "inside the capture" in r.stderr, r.stderr

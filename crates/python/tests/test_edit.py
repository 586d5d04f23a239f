"""`edit` with a Python callable editor against the command line tool with the folder
editor on the same edited images: the same scene, byte for byte. And the editor
contract's bad inputs: exceptions naming the view, nothing written."""

import pathlib

import numpy as np
import pytest

import ray_editors
import transsplat
from conftest import run_cli
from ray_editors import write_png

STEPS = "40"
PROMPT = "make the ball blue"


def recolour(image):
    """A deterministic 'edit': the red-dominant pixels turn blue, as uint8."""
    return np.clip(np.round(ray_editors.recolour(image) * 255.0), 0, 255).astype(np.uint8)


def test_python_editor_gives_the_cli_folder_editors_scene(tabletop, tmp_path):
    views = tmp_path / "views"
    run_cli("views", "export", "--scene", tabletop, "--out", views)
    edits = tmp_path / "edits"
    edits.mkdir()
    seen = {}

    def editor(vs, prompt):
        assert prompt == PROMPT
        out = []
        for v in vs:
            assert v.image.shape == (v.height, v.width, 3) and v.image.dtype == np.float32
            assert v.viewmat.shape == (4, 4) and v.K.shape == (3, 3)
            e = recolour(v.image)
            write_png(edits / (pathlib.Path(v.name).stem + ".png"), e)
            seen[v.name] = v.index
            out.append(e)
        return out

    py_out = tmp_path / "py"
    steps_seen = []
    r = transsplat.edit(tabletop, None, PROMPT, editor, steps=int(STEPS), out=py_out,
                        progress=lambda kind, a, b, x: steps_seen.append((kind, a)))
    assert seen and all(not transsplat._core.is_test_view(i) for i in seen.values())
    assert ("step", int(STEPS)) in steps_seen
    cli_out = tmp_path / "cli"
    run_cli("edit", "--scene", tabletop, "--prompt", PROMPT, "--editor", "folder", "--edits", edits,
            "--steps", STEPS, "--out", cli_out)
    ply = f"point_cloud/iteration_{STEPS}/point_cloud.ply"
    assert (py_out / ply).read_bytes() == (cli_out / ply).read_bytes()
    # The returned scene is the written one.
    written = transsplat.load_ply(py_out)
    for k in ("means", "log_scales", "sh"):
        np.testing.assert_array_equal(written[k], r["gaussians"][k])
    assert sorted(written["extra"]) == sorted(r["gaussians"]["extra"]) and written["extra"]
    assert r["gate"].shape == (len(written["means"]),)
    assert r["rounds"] and {"objective", "mean_gate", "step"} <= set(r["rounds"][0])
    assert len(r["losses"]) == int(STEPS)
    assert (py_out / "report.html").is_file() and (py_out / "transport.json").is_file()


def test_arrays_in_arrays_out_and_methods(tabletop):
    g = transsplat.load_ply(tabletop)
    cams = transsplat.load_cameras(tabletop)

    def editor(vs, prompt):
        return [(recolour(v.image), None, None) if i % 2 == 0 else None for i, v in enumerate(vs)]

    r = transsplat.edit(g, cams, PROMPT, editor, method="naive", steps=5, progress=False)
    assert r["gate"] is None and r["out"] is None
    assert r["gaussians"]["means"].shape == g["means"].shape


def editor_returning(fn):
    return lambda vs, prompt: fn(vs)


@pytest.mark.parametrize("fn,exc,match", [
    (lambda vs: [v.image for v in vs][:-1], ValueError, r"returned \d+ views for \d+ inputs"),
    (lambda vs: [np.zeros((4, 4, 3)) for v in vs], ValueError, r"view '.*': edited image has shape \(4, 4, 3\)"),
    (lambda vs: [np.full(v.image.shape, np.nan) for v in vs], ValueError, r"view '.*': edited image: non-finite"),
    (lambda vs: [(v.image, np.zeros((3, 3))) for v in vs], ValueError, r"view '.*': attention has shape"),
    (lambda vs: [None for v in vs], ValueError, "no edited view"),
    (lambda vs: 7, ValueError, "must return a list"),
    (lambda vs: [{"img": v.image} for v in vs], ValueError, "unknown keys"),
])
def test_bad_editor_outputs_raise_naming_the_view_and_write_nothing(tabletop, tmp_path, fn, exc, match):
    out = tmp_path / "out"
    with pytest.raises(exc, match=match):
        transsplat.edit(tabletop, None, PROMPT, editor_returning(fn), steps=2, out=out, progress=False)
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]


def test_an_editor_that_raises_propagates_its_exception(tabletop, tmp_path):
    class Boom(RuntimeError):
        pass

    def editor(vs, prompt):
        raise Boom("the GPU fell over")

    with pytest.raises(Boom, match="the GPU fell over"):
        transsplat.edit(tabletop, None, PROMPT, editor, steps=2, out=tmp_path / "o", progress=False)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("at", [3, 20])
def test_keyboard_interrupt_from_progress_stops_between_steps(tabletop, tmp_path, at):
    """Raised in a step's report (the last step's too), it stops the edit: nothing is
    written and the exception comes through."""
    def progress(kind, a, b, x):
        if kind == "step" and a == at:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        transsplat.edit(tabletop, None, PROMPT, lambda vs, p: [recolour(v.image) for v in vs], steps=20,
                        out=tmp_path / "o", progress=progress)
    assert not (tmp_path / "o").exists()


def test_config_files_method_is_kept_unless_one_is_given(tabletop, tmp_path):
    cfg = tmp_path / "naive.toml"
    cfg.write_text('method = "naive"\n')
    edit = lambda **kw: transsplat.edit(tabletop, None, PROMPT, lambda vs, p: [recolour(v.image) for v in vs],  # noqa: E731
                                        config=cfg, steps=2, progress=False, **kw)
    assert edit()["gate"] is None  # naive has no gate
    assert edit(method="transsplat")["gate"] is not None


def test_bad_settings_and_files(tabletop, tmp_path):
    same = lambda vs, p: [v.image for v in vs]  # noqa: E731
    with pytest.raises(ValueError, match="unknown setting"):
        transsplat.edit(tabletop, None, PROMPT, same, config={"loss.nope": 1}, progress=False)
    with pytest.raises(ValueError, match="unknown method"):
        transsplat.edit(tabletop, None, PROMPT, same, method="best", progress=False)
    with pytest.raises(ValueError, match="prompt"):
        transsplat.edit(tabletop, None, " ", same, progress=False)
    with pytest.raises(FileNotFoundError, match="missing.ply"):
        transsplat.edit(tmp_path / "missing.ply", tabletop, PROMPT, same, progress=False)
    cams = transsplat.load_cameras(tabletop)
    cams["names"] = ["same.png"] * len(cams["names"])
    with pytest.raises(ValueError, match="cameras: two cameras share the image name 'same'|\"same\""):
        transsplat.edit(transsplat.load_ply(tabletop), cams, PROMPT, same, progress=False)
    with pytest.raises(ValueError, match="no view has attention"):
        transsplat.edit(tabletop, None, PROMPT, same, steps=2, progress=False)
    with pytest.raises(ValueError, match="the output lies inside the input folder"):
        transsplat.edit(tabletop, None, PROMPT, same, out=tabletop / "edited", progress=False)


def test_ply_round_trip_and_file_errors(tabletop, tmp_path):
    g = transsplat.load_ply(tabletop)
    g["extra"] = {"sem_0": np.arange(len(g["means"]), dtype=np.float32)}
    transsplat.save_ply(tmp_path / "a.ply", g)
    h = transsplat.load_ply(tmp_path / "a.ply")
    for k in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        np.testing.assert_array_equal(g[k], h[k])
    np.testing.assert_array_equal(h["extra"]["sem_0"], g["extra"]["sem_0"])
    with pytest.raises(FileNotFoundError, match="nope.ply"):
        transsplat.load_ply(tmp_path / "nope.ply")
    (tmp_path / "bad.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nend_header\n")
    with pytest.raises(ValueError, match="bad.ply"):
        transsplat.load_ply(tmp_path / "bad.ply")
    with pytest.raises(ValueError, match="quats"):
        transsplat.save_ply(tmp_path / "b.ply", dict(g, quats=g["quats"][:, :3]))
    assert not (tmp_path / "b.ply").exists()
    with pytest.raises(OSError):
        transsplat.save_ply(tmp_path / "no" / "dir" / "c.ply", g)


def test_cameras_match_a_render_of_the_cli(tabletop, tmp_path):
    """`load_cameras` + `rasterization` reproduce `transsplat render` of the same scene."""
    g = transsplat.load_ply(tabletop)
    cams = transsplat.load_cameras(tabletop)
    run_cli("render", "--scene", tabletop, "--out", tmp_path / "r", "--raw")
    i = 1
    name = pathlib.Path(cams["names"][i]).stem
    want = np.load(tmp_path / "r" / f"{name}.npy")
    deg = int(round(np.sqrt(g["sh"].shape[1]))) - 1
    out, _, _ = transsplat.rasterization(
        g["means"], g["quats"], np.exp(g["log_scales"]), 1 / (1 + np.exp(-g["opacity_logits"])), g["sh"],
        cams["viewmats"][i:i + 1], cams["Ks"][i:i + 1], int(cams["widths"][i]), int(cams["heights"][i]),
        sh_degree=deg,
    )
    np.testing.assert_allclose(out[0], want, atol=2e-4)


def test_views_edits_the_views_the_cli_chooses(tabletop, tmp_path):
    """`views=3` hands the editor 3 views, the ones `transsplat edit --views 3` edits
    (the same choice: the returned edit_views), and a bad choice is a ValueError."""
    seen = []

    def editor(vs, prompt):
        seen.extend(v.index for v in vs)
        return [recolour(v.image) for v in vs]

    r = transsplat.edit(tabletop, None, PROMPT, editor, steps=5, views=3, progress=False)
    assert len(seen) == 3 and sorted(seen) == sorted(r["edit_views"])
    half = transsplat.edit(tabletop, None, PROMPT, editor, steps=2, views="1/2", progress=False)
    edit_views = [i for i in range(len(transsplat.load_cameras(tabletop)["names"]))
                  if not transsplat._core.is_test_view(i)]
    assert len(half["edit_views"]) == -(-len(edit_views) // 2)
    for bad in ("0", "half", 10_000):
        with pytest.raises(ValueError, match="views"):
            transsplat.edit(tabletop, None, PROMPT, editor, steps=2, views=bad, progress=False)

"""`rasterization` and its vjp against the committed gsplat fixtures (gsplat 1.5's
projection and SH with a dense float64 compositor, gradients by autograd; written by
tools/raster_fixtures.py): the same oracle as the Rust tests, through the Python API
with gsplat's activated parameters."""

import json

import numpy as np
import pytest

import transsplat
from conftest import RASTER_FIXTURES

CASES = json.loads((RASTER_FIXTURES / "index.json").read_text())["cases"]


def load(case):
    d = RASTER_FIXTURES / case
    meta = json.loads((d / "meta.json").read_text())
    f = {p.stem: np.load(p) for p in d.glob("*.npy")}
    n = meta["num_gaussians"]
    k = (meta["sh_degree"] + 1) ** 2
    K = np.array([[meta["fx"], 0, meta["cx"]], [0, meta["fy"], meta["cy"]], [0, 0, 1]], np.float32)
    return meta, f, dict(
        means=f["means"].reshape(n, 3),
        quats=f["quats"].reshape(n, 4),
        scales=np.exp(f["log_scales"].reshape(n, 3)),
        opacities=1.0 / (1.0 + np.exp(-f["opacity_logits"].reshape(n))),
        colors=f["sh"].reshape(n, k, 3),
        viewmats=np.array(meta["viewmat"], np.float32)[None],
        Ks=K[None],
        width=meta["width"],
        height=meta["height"],
    )


def close(what, got, want, atol, rtol=0.0):
    got, want = np.asarray(got, np.float64).ravel(), np.asarray(want, np.float64).ravel()
    assert got.shape == want.shape, what
    err = np.abs(got - want)
    tol = atol + rtol * np.abs(want).max(initial=0.0)
    assert err.max(initial=0.0) <= tol, f"{what}: max error {err.max()} at {err.argmax()} > {tol}"


@pytest.mark.parametrize("case", CASES)
def test_forward_and_gradients_match_gsplat(case):
    meta, f, a = load(case)
    h, w = meta["height"], meta["width"]
    bg = np.array(meta["background"], np.float32)[None]
    out, alphas, m = transsplat.rasterization(
        **a, sh_degree=meta["sh_degree"], backgrounds=bg, render_mode="RGB+D"
    )
    assert out.shape == (1, h, w, 4) and alphas.shape == (1, h, w, 1)
    close(f"{case} rgb", out[0, ..., :3], f["rgb"], 1e-5)
    close(f"{case} alpha", alphas, f["alpha"], 1e-5)
    close(f"{case} depth", out[0, ..., 3], f["depth"], 1e-5, 2e-4)
    np.testing.assert_array_equal(m["radii"][0].ravel(), f["radii"].ravel().astype(np.int32))
    visible = (m["radii"][0] > 0).any(axis=1)
    close(f"{case} means2d", m["means2d"][0][visible], f["means2d"].reshape(-1, 2)[visible], 1e-3, 1e-5)

    v_colors = np.concatenate([f["v_rgb"].reshape(h, w, 3), f["v_depth"].reshape(h, w, 1)], axis=2)[None]
    g = m["vjp"](v_colors, f["v_alpha"].reshape(1, h, w, 1))
    # Gradients of the activated parameters from the oracle's: d/ds = d/dln s / s and
    # d/do = d/dlogit / (o (1 - o)); compared in the oracle's parameterisation.
    o = a["opacities"].astype(np.float64)
    close(f"{case} grad sh", g["colors"], f["grad_sh"], 1e-6, 1e-4)
    if meta["num_features"] == 0:  # the oracle's other gradients include its features' loss
        close(f"{case} grad means", g["means"], f["grad_means"], 1e-6, 1e-4)
        close(f"{case} grad quats", g["quats"], f["grad_quats"], 1e-6, 1e-4)
        close(f"{case} grad log_scales", g["scales"] * a["scales"], f["grad_log_scales"], 1e-6, 1e-4)
        close(f"{case} grad opacity", g["opacities"] * o * (1 - o), f["grad_opacity_logits"], 1e-6, 1e-4)
        close(f"{case} grad means2d", g["means2d"][0], f["grad_means2d"], 1e-6, 1e-4)


@pytest.mark.parametrize("case", [c for c in CASES if (RASTER_FIXTURES / c / "features.npy").exists()])
def test_features_match_gsplat(case):
    meta, f, a = load(case)
    h, w, nf = meta["height"], meta["width"], meta["num_features"]
    a["colors"] = f["features"].reshape(-1, nf)
    out, alphas, m = transsplat.rasterization(**a)
    close(f"{case} features", out, f["features_out"], 1e-5, 1e-5)
    g = m["vjp"](f["v_features"].reshape(1, h, w, nf))
    close(f"{case} grad features", g["colors"], f["grad_features"], 1e-6, 1e-4)


def finite_difference(fn, x, i, eps):
    x0 = x.copy()
    x0.flat[i] += eps
    up = fn(x0)
    x0.flat[i] -= 2 * eps
    return (up - fn(x0)) / (2 * eps)


def test_vjp_of_activated_opacity_scale_background_and_expected_depth_by_finite_differences():
    """The parts the fixtures do not reach: the background of features, ED's division
    by alpha, the chain rule to activated scales and opacities, several cameras.

    The scene is built so the images are smooth in every parameter (finite differences
    would otherwise see the rasterizer's steps): a few Gaussians wide enough that every
    pixel is above the 1/255 alpha cut-off, transmittance far from the early stop, and
    depths far apart (no reordering)."""
    rng = np.random.default_rng(3)
    n, w, h = 6, 24, 20
    a = dict(
        means=np.column_stack([rng.uniform(-0.3, 0.3, (n, 2)), np.linspace(-0.5, 0.5, n)]),
        quats=rng.normal(size=(n, 4)),
        scales=rng.uniform(0.8, 1.5, (n, 3)),
        opacities=rng.uniform(0.2, 0.6, n),
        colors=rng.uniform(0, 1, (n, 2)),
    )
    vm = np.stack([np.eye(4), np.eye(4)])
    vm[:, 2, 3] = [3.0, 3.5]
    K = np.array([[30.0, 0, 12], [0, 30, 10], [0, 0, 1]])[None].repeat(2, 0)
    bg = np.array([[0.3, 0.7], [0.1, 0.2]])
    wt = rng.normal(size=(2, h, w, 3)).astype(np.float32)
    settings = dict(viewmats=vm, Ks=K, width=w, height=h, backgrounds=bg, render_mode="RGB+ED")

    def loss(**kw):
        out, al, _ = transsplat.rasterization(**dict(a, **kw), **settings)
        return float((out.astype(np.float64) * wt).sum() + 0.5 * al.astype(np.float64).sum())

    out, al, m = transsplat.rasterization(**a, **settings)
    assert al.min() > 0.05 and al.max() < 0.999
    g = m["vjp"](wt, np.full((2, h, w, 1), 0.5, np.float32))
    for name in ("opacities", "scales", "colors", "means", "quats"):
        x = a[name]
        for i in range(x.size):
            fd = finite_difference(lambda v: loss(**{name: v}), x, i, 1e-3)
            got = g[name].flat[i]
            assert abs(got - fd) <= 2e-2 * max(1.0, abs(fd)), f"{name}[{i}]: vjp {got} vs fd {fd}"


def test_bad_arguments_raise_value_errors_naming_them():
    _, _, a = load(CASES[0])
    with pytest.raises(ValueError, match=r"quats: expected shape \(1, 4\), got \(1, 3\)"):
        transsplat.rasterization(**dict(a, quats=np.zeros((1, 3))), sh_degree=0)
    with pytest.raises(ValueError, match=r"means: non-finite value NaN at index \(0, 0\)"):
        transsplat.rasterization(**dict(a, means=np.full((1, 3), np.nan)), sh_degree=0)
    with pytest.raises(ValueError, match="opacities: value 1.5"):
        transsplat.rasterization(**dict(a, opacities=np.array([1.5])), sh_degree=0)
    with pytest.raises(ValueError, match="scales: negative"):
        transsplat.rasterization(**dict(a, scales=-np.ones((1, 3))), sh_degree=0)
    with pytest.raises(ValueError, match="sh_degree: 1 needs 4"):
        transsplat.rasterization(**a, sh_degree=1)
    with pytest.raises(ValueError, match="render_mode"):
        transsplat.rasterization(**a, sh_degree=0, render_mode="RGBA")
    with pytest.raises(ValueError, match="width"):
        transsplat.rasterization(**dict(a, width=0), sh_degree=0)
    with pytest.raises(ValueError, match="near_plane"):
        transsplat.rasterization(**a, sh_degree=0, near_plane=0.2)
    with pytest.raises(ValueError, match="expected a float array"):
        transsplat.rasterization(**dict(a, means=np.array([["a", "b", "c"]])), sh_degree=0)
    rot = np.array(a["viewmats"])
    rot[0, 0, 0] = 5.0
    with pytest.raises(ValueError, match='cameras: camera "00000"'):
        transsplat.rasterization(**dict(a, viewmats=rot), sh_degree=0)
    _, _, m = transsplat.rasterization(**a, sh_degree=0)
    with pytest.raises(ValueError, match="v_render_colors"):
        m["vjp"](np.zeros((1, 2, 2, 3)))


def test_zero_cameras_and_zero_gaussians():
    _, _, a = load("single")
    out, al, m = transsplat.rasterization(**dict(a, viewmats=np.zeros((0, 4, 4)), Ks=np.zeros((0, 3, 3))), sh_degree=0)
    assert out.shape == (0, a["height"], a["width"], 3) and al.shape == (0, a["height"], a["width"], 1)
    assert m["vjp"](np.zeros(out.shape))["means"].shape == (1, 3)
    empty = dict(a, means=np.zeros((0, 3)), quats=np.zeros((0, 4)), scales=np.zeros((0, 3)),
                 opacities=np.zeros(0), colors=np.zeros((0, 1, 3)))
    out, al, m = transsplat.rasterization(**empty, sh_degree=0, backgrounds=np.array([[0.2, 0.3, 0.4]]))
    assert (al == 0).all() and np.allclose(out[0], [0.2, 0.3, 0.4])
    assert m["vjp"](np.ones(out.shape))["colors"].shape == (0, 1, 3)


def test_non_contiguous_and_float64_inputs_give_the_same_images():
    _, _, a = load("rand50_d2")
    out, _, _ = transsplat.rasterization(**a, sh_degree=2)
    b = dict(a)
    b["means"] = np.asfortranarray(a["means"].astype(np.float64))
    b["colors"] = np.ascontiguousarray(a["colors"].transpose(0, 2, 1)).transpose(0, 2, 1)
    out2, _, _ = transsplat.rasterization(**b, sh_degree=2)
    np.testing.assert_array_equal(out, out2)


def test_torch_autograd_matches_the_vjp():
    torch = pytest.importorskip("torch")
    from transsplat.torch import rasterization as trast

    _, f, a = load("rand300_d3_bg")
    t = {k: torch.tensor(v, requires_grad=True) for k, v in a.items() if isinstance(v, np.ndarray)}
    out, alphas, meta = trast(t["means"], t["quats"], t["scales"], t["opacities"], t["colors"],
                              t["viewmats"], t["Ks"], a["width"], a["height"], sh_degree=3)
    (out.sum() + alphas.sum()).backward()
    _, _, m = transsplat.rasterization(**a, sh_degree=3)
    g = m["vjp"](np.ones(out.shape, np.float32), np.ones(alphas.shape, np.float32))
    for k in ("means", "quats", "scales", "opacities", "colors"):
        np.testing.assert_allclose(t[k].grad.numpy(), g[k], rtol=1e-6, atol=1e-7)
    assert tuple(meta["radii"].shape) == (1, 300, 2)

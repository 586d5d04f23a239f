"""transsplat: language-driven editing of 3D Gaussian Splatting scenes by unbalanced
semantic transport, on a CPU.

The package is a thin front over the same Rust library as the ``transsplat`` command
line tool:

- :func:`load_ply` / :func:`save_ply`: INRIA 3DGS PLY scenes as named numpy arrays;
  :func:`load_cameras`: cameras from cameras.json, transforms.json or COLMAP as gsplat's
  ``viewmats`` (world-to-camera, 4x4) and ``Ks`` (3x3).
- :func:`rasterization`: a differentiable CPU 3DGS rasterizer with the argument names,
  shapes and conventions of ``gsplat.rasterization``; the returned ``meta["vjp"]``
  gives the gradients of every input. ``transsplat.torch.rasterization`` wraps it in a
  ``torch.autograd.Function``.
- :func:`sinkhorn_unbalanced`: entropic unbalanced optimal transport with POT's
  conventions (``ot.unbalanced.sinkhorn_unbalanced``, ``reg_type="kl"``), dense or top-k.
- :func:`edit`: the TransSplat edit of a scene with any Python callable as the 2D editor
  (diffusers' InstructPix2Pix, your own function, ...).

Arrays go in as numpy arrays (float32 C-contiguous arrays are read in place; anything
else is converted first) and come out as numpy arrays that own the library's buffers.
Errors raise ``ValueError`` (bad shapes, values, settings), ``FileNotFoundError`` and
``OSError`` with the command line tool's messages.
"""

from __future__ import annotations

import math
import os
from typing import Any, Callable, Dict, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from . import _core
from ._edit import View, edit

__version__ = _core.__version__

__all__ = [
    "View",
    "builtin_scene",
    "edit",
    "load_cameras",
    "load_ply",
    "rasterization",
    "save_ply",
    "sinkhorn_unbalanced",
    "sinkhorn_unbalanced_topk",
]

PathLike = Union[str, "os.PathLike[str]"]


def _f32(name: str, x: Any) -> np.ndarray:
    """``x`` as a C-contiguous float32 array; no copy when it already is one."""
    if x is None:
        raise ValueError(f"{name}: expected an array, got None")
    try:
        a = np.asarray(x)
    except Exception as e:  # e.g. ragged lists
        raise ValueError(f"{name}: not an array ({e})") from None
    if a.dtype.kind not in "fiub":
        raise ValueError(f"{name}: expected a float array, got dtype {a.dtype}")
    return np.ascontiguousarray(a, dtype=np.float32)


def load_ply(path: PathLike) -> Dict[str, Any]:
    """Reads a 3DGS scene in the INRIA layout.

    ``path`` is a ``.ply`` file or an INRIA output folder (its newest
    ``point_cloud/iteration_*/point_cloud.ply``). Returns a dict of float32 arrays in
    the file's own parameterisation:

    - ``means`` (N, 3), ``quats`` (N, 4) as (w, x, y, z), not necessarily normalised,
    - ``log_scales`` (N, 3) (``scales = exp(log_scales)``),
    - ``opacity_logits`` (N,) (``opacities = sigmoid(opacity_logits)``),
    - ``sh`` (N, K, 3) SH coefficients, K = (degree + 1)^2, ``sh[:, 0]`` the DC term,
    - ``extra``: a dict of any other per-Gaussian properties (N,), e.g. the semantic
      latents ``sem_0 ...`` that ``transsplat edit`` writes.

    Raises ``FileNotFoundError`` for a missing file and ``ValueError`` for a bad one.
    """
    return _core.load_ply(os.fspath(path))


def builtin_scene(name: str, out: PathLike, quick: bool = False, seed: int = 0) -> str:
    """Writes a built-in benchmark scene (``"tabletop"``, ``"occluded"``, ``"garden"``) as a dataset
    folder, as ``transsplat scene NAME --out DIR [--quick]`` does: the scene in the
    INRIA layout with ``cameras.json``, its renders, label masks, ``labels.json`` and a
    COLMAP text model. Returns ``out``. The folder must not exist or be empty, or hold
    an earlier built-in scene."""
    return os.fspath(_core.builtin_scene(str(name), os.fspath(out), bool(quick), int(seed)))


def save_ply(path: PathLike, gaussians: Mapping[str, Any]) -> None:
    """Writes ``gaussians`` (the dict :func:`load_ply` returns) as an INRIA PLY.

    The file is written under a temporary name and renamed when complete, so a
    failure never leaves a half-written file at ``path``.
    """
    _core.save_ply(os.fspath(path), *_scene_arrays("gaussians", gaussians))


def _scene_arrays(what: str, g: Mapping[str, Any]) -> list:
    """The arguments of the core for a scene dict (:func:`load_ply`'s layout): the five
    parameter arrays as float32, the extra properties' names and their (N, E) values."""
    keys = ("means", "quats", "log_scales", "opacity_logits", "sh")
    for key in keys:
        if key not in g:
            raise ValueError(f"{what}: missing array {key!r}")
    extra = dict(g.get("extra") or {})
    names = list(extra)
    values = np.stack([_f32(f"extra[{k!r}]", extra[k]).reshape(-1) for k in names], axis=1) if names else None
    return [*(_f32(k, g[k]) for k in keys), names, values]


def load_cameras(path: PathLike) -> Dict[str, Any]:
    """Reads cameras from any source the command line tool reads.

    ``path`` is a cameras.json (INRIA) or transforms.json file, a COLMAP model folder
    (``cameras.bin``/``.txt``) or a dataset folder holding one of these (``sparse/0``),
    or an INRIA output folder. Returns ``names`` (list of image names), ``viewmats``
    (C, 4, 4) world-to-camera matrices in the OpenCV convention (x right, y down,
    z forward), ``Ks`` (C, 3, 3) intrinsics, and ``widths`` / ``heights`` (C,).
    """
    return _core.load_cameras(os.fspath(path))


def rasterization(
    means: Any,
    quats: Any,
    scales: Any,
    opacities: Any,
    colors: Any,
    viewmats: Any,
    Ks: Any,
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    radius_clip: float = 0.0,
    eps2d: float = 0.3,
    sh_degree: Optional[int] = None,
    packed: bool = False,
    backgrounds: Any = None,
    render_mode: str = "RGB",
    rasterize_mode: str = "classic",
    camera_model: str = "pinhole",
    **unsupported: Any,
) -> Tuple[np.ndarray, np.ndarray, Dict[str, Any]]:
    """Renders 3D Gaussians on the CPU, with gsplat's ``rasterization()`` conventions.

    Args:
        means: (N, 3) centres.
        quats: (N, 4) rotations as (w, x, y, z); normalised inside.
        scales: (N, 3) activated scales (standard deviations), >= 0.
        opacities: (N,) activated opacities in [0, 1].
        colors: (N, K, 3) SH coefficients when ``sh_degree`` is given (K = 1, 4, 9 or
            16; colour = SH(dir) + 0.5, clamped at 0), else (N, D) features blended as
            they are.
        viewmats: (C, 4, 4) world-to-camera matrices (OpenCV convention).
        Ks: (C, 3, 3) pinhole intrinsics.
        width, height: image size in pixels.
        sh_degree: SH degree to evaluate (<= the degree of ``colors``), or None for
            features.
        backgrounds: (C, D) colour behind the Gaussians (default black).
        render_mode: "RGB", "D" (accumulated depth), "ED" (expected depth),
            "RGB+D" or "RGB+ED"; the depth channel comes last.

    ``near_plane``, ``far_plane``, ``radius_clip``, ``eps2d``, ``rasterize_mode``,
    ``camera_model`` and ``packed`` are accepted for compatibility at gsplat's defaults
    (the rasterizer is built for them); another value raises ``ValueError``.
    Opacities are used within [1e-6, 1 - 1e-6] (the library stores logits).

    Returns:
        ``(render_colors, render_alphas, meta)``: colors (C, H, W, channels) float32,
        alphas (C, H, W, 1), and ``meta`` with per-Gaussian statistics ``radii``
        (C, N, 2) int32 (0 = culled), ``means2d`` (C, N, 2) pixels, ``depths`` (C, N)
        camera z, plus ``width``, ``height``, ``n_cameras``, ``tile_size``, and
        ``meta["vjp"](v_render_colors, v_render_alphas=None)``: the gradients of a
        loss with respect to ``means``, ``quats``, ``scales``, ``opacities``,
        ``colors`` (same shapes as the inputs) and ``means2d`` (C, N, 2), given the
        loss's gradients with respect to the two outputs.
    """
    if unsupported:
        raise ValueError(f"rasterization: unsupported arguments {sorted(unsupported)}")
    fixed = {
        "near_plane": (near_plane, 0.01),
        "far_plane": (far_plane, 1e10),
        "radius_clip": (radius_clip, 0.0),
        "eps2d": (eps2d, 0.3),
        "packed": (packed, False),
        "rasterize_mode": (rasterize_mode, "classic"),
        "camera_model": (camera_model, "pinhole"),
    }
    for name, (got, want) in fixed.items():
        if got != want:
            raise ValueError(f"{name}: only gsplat's default {want!r} is supported, got {got!r}")
    width, height = _size(width, height)
    if sh_degree is not None and (not isinstance(sh_degree, (int, np.integer)) or not 0 <= sh_degree <= 3):
        raise ValueError(f"sh_degree: expected None or 0 to 3, got {sh_degree!r}")
    args = [
        _f32("means", means),
        _f32("quats", quats),
        _f32("scales", scales),
        _f32("opacities", opacities),
        _f32("colors", colors),
    ]
    vm = _f32("viewmats", viewmats)
    ks = _f32("Ks", Ks)
    bg = None if backgrounds is None else _f32("backgrounds", backgrounds)
    deg = None if sh_degree is None else int(sh_degree)
    out, alphas, meta, state = _core.rasterize(*args, vm, ks, width, height, deg, bg, render_mode)
    shape = out.shape

    def vjp(v_render_colors: Any, v_render_alphas: Any = None) -> Dict[str, np.ndarray]:
        """Gradients of every input, given those of ``render_colors`` (and alphas)."""
        vc = _f32("v_render_colors", v_render_colors)
        if vc.shape != shape:
            raise ValueError(f"v_render_colors: expected shape {shape}, got {vc.shape}")
        va = None if v_render_alphas is None else _f32("v_render_alphas", v_render_alphas)
        return _core.rasterize_backward(state, *args, vc, va)

    meta["vjp"] = vjp
    return out, alphas, meta


def _size(width: Any, height: Any) -> Tuple[int, int]:
    for name, v in (("width", width), ("height", height)):
        if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or not 0 < v <= 32768:
            raise ValueError(f"{name}: expected a positive integer of at most 32768 pixels, got {v!r}")
    return int(width), int(height)


def _reg_m(reg_m: Any) -> Tuple[float, float]:
    if isinstance(reg_m, (tuple, list, np.ndarray)):
        if len(reg_m) != 2:
            raise ValueError(f"reg_m: expected a number or a pair, got {len(reg_m)} values")
        s, t = float(reg_m[0]), float(reg_m[1])
    else:
        s = t = float(reg_m)
    for v in (s, t):
        if math.isnan(v) or v <= 0:
            raise ValueError(f"reg_m: must be positive (or inf for a hard marginal), got {reg_m!r}")
    return s, t


def sinkhorn_unbalanced(
    a: Any,
    b: Any,
    M: Any,
    reg: float,
    reg_m: Union[float, Tuple[float, float]],
    method: str = "sinkhorn",
    reg_type: str = "kl",
    c: Any = None,
    warmstart: Any = None,
    numItermax: int = 1000,
    stopThr: float = 1e-6,
    verbose: bool = False,
    log: bool = False,
    top_k: Optional[int] = None,
    **kwargs: Any,
):
    """Entropic unbalanced optimal transport, as POT's
    ``ot.unbalanced.sinkhorn_unbalanced(a, b, M, reg, reg_m, reg_type="kl")``:

        T* = argmin_T <M, T> + reg KL(T | a b^T) + reg_m1 KL(T 1 | a) + reg_m2 KL(T^T 1 | b)

    with the generalised KL. ``a`` (n,) and ``b`` (m,) are the masses (an empty list
    means uniform, as in POT), ``M`` (n, m) the cost (+inf excludes an entry),
    ``reg_m`` a number or a pair (``inf`` makes that marginal hard). ``top_k`` keeps
    for each target only its k cheapest sources (the paper's sparse support; None
    or 0 is dense).

    The solver runs Gauss-Seidel log-domain sweeps on a float32 kernel: it matches
    POT's iterates; ``stopThr`` stops when the potentials (ln u, ln v) change by at
    most that much in a sweep (POT compares the scalings u, v), and ``stopThr=0``
    runs exactly ``numItermax`` sweeps.

    Returns the plan (n, m) in ``M``'s float dtype, and with ``log=True`` also a dict
    with POT's ``logu``, ``logv``, ``cost`` and ``err`` and the solver's
    ``objective``, ``dual``, ``transported_mass``, ``iterations``, ``converged``.
    """
    if kwargs:
        raise ValueError(f"sinkhorn_unbalanced: unsupported arguments {sorted(kwargs)}")
    if method not in ("sinkhorn", "sinkhorn_stabilized", "sinkhorn_reg_scaling"):
        raise ValueError(f"method: expected 'sinkhorn' (the iterates are the same for all), got {method!r}")
    if reg_type != "kl":
        raise ValueError(f"reg_type: only 'kl' is supported, got {reg_type!r}")
    if c is not None or warmstart is not None:
        raise ValueError("c and warmstart: only POT's defaults (None) are supported")
    Mf = _f32("M", M)
    if Mf.ndim != 2:
        raise ValueError(f"M: expected shape (n, m), got {Mf.shape}")
    n, m = Mf.shape
    a = np.full(n, 1.0 / max(n, 1), dtype=np.float32) if len(a) == 0 else _f32("a", a)
    b = np.full(m, 1.0 / max(m, 1), dtype=np.float32) if len(b) == 0 else _f32("b", b)
    if a.ndim != 1 or b.ndim != 1:
        raise ValueError(f"a and b: expected 1-D masses, got shapes {a.shape} and {b.shape}")
    if not (isinstance(numItermax, (int, np.integer)) and numItermax >= 0):
        raise ValueError(f"numItermax: expected a non-negative integer, got {numItermax!r}")
    stop = None if stopThr is None or stopThr == 0 else float(stopThr)
    if stop is not None and not (math.isfinite(stop) and stop > 0):
        raise ValueError(f"stopThr: expected a positive number or 0, got {stopThr!r}")
    k = int(top_k or 0)
    if k < 0:
        raise ValueError(f"top_k: expected a positive integer or None, got {top_k!r}")
    s, t = _reg_m(reg_m)
    plan, info = _core.sinkhorn_unbalanced(a, b, Mf, float(reg), s, t, int(numItermax), stop, k)
    dtype = np.asarray(M).dtype
    if dtype.kind == "f" and dtype != plan.dtype:
        plan = plan.astype(dtype)
    if verbose:
        print(f"sinkhorn_unbalanced: {info['iterations']} sweeps, change {info['err']:.3e}")
    return (plan, info) if log else plan


def sinkhorn_unbalanced_topk(a: Any, b: Any, M: Any, reg: float, reg_m: Any, k: int, **kwargs: Any):
    """:func:`sinkhorn_unbalanced` on the top-k support: each target keeps its ``k``
    cheapest sources (ties to the lower index; the paper's sparse view-wise transport)."""
    if not isinstance(k, (int, np.integer)) or k <= 0:
        raise ValueError(f"k: expected a positive integer, got {k!r}")
    return sinkhorn_unbalanced(a, b, M, reg, reg_m, top_k=int(k), **kwargs)

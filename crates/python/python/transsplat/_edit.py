"""The TransSplat edit with any Python callable as the 2D editor."""

from __future__ import annotations

import json
import math
import os
import sys
import time
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Union

import numpy as np

from . import _core


@dataclass(frozen=True)
class View:
    """One edit view as the editor receives it.

    Attributes:
        index: position of the view in the scene's camera list.
        name: the camera's image name (e.g. ``"00012.png"``).
        image: the current render, (H, W, 3) float32 in [0, 1].
        viewmat: (4, 4) world-to-camera matrix (OpenCV convention).
        K: (3, 3) intrinsics.
        width, height: image size in pixels.
    """

    index: int
    name: str
    image: np.ndarray
    viewmat: np.ndarray
    K: np.ndarray
    width: int
    height: int


def _plane(view: View, what: str, x: Any, channels: Optional[int]) -> Optional[np.ndarray]:
    """An editor's output plane as a C-contiguous float32 array; uint8 images become
    [0, 1]; (H, W, 1) planes become (H, W). Shapes are checked here, values in Rust."""
    if x is None:
        return None
    a = np.asarray(x)
    if a.dtype == np.uint8:
        a = a.astype(np.float32) / 255.0
    elif a.dtype.kind not in "fiub":
        raise ValueError(f"view {view.name!r}: {what} has dtype {a.dtype}, expected float or uint8")
    if channels is None and a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if channels == 3 and a.ndim == 3 and a.shape[2] == 4:
        raise ValueError(f"view {view.name!r}: {what} has 4 channels; composite it to RGB first")
    want = (view.height, view.width) if channels is None else (view.height, view.width, channels)
    if a.shape != want:
        raise ValueError(
            f"view {view.name!r}: {what} has shape {a.shape}, expected {want} (the view is "
            f"{view.width}x{view.height}; resize the editor's output to the view)"
        )
    return np.ascontiguousarray(a, dtype=np.float32)


def _output(view: View, item: Any):
    """``None``, or ``(image, attention, mask)`` from what the editor returned for a view:
    an image, a tuple ``(image[, attention[, mask]])`` or a dict with those keys."""
    if item is None:
        return None
    if isinstance(item, Mapping):
        unknown = set(item) - {"image", "attention", "mask"}
        if unknown:
            raise ValueError(f"view {view.name!r}: unknown keys {sorted(unknown)} (image, attention, mask)")
        image, attention, mask = item.get("image"), item.get("attention"), item.get("mask")
    elif isinstance(item, tuple):
        if not 1 <= len(item) <= 3:
            raise ValueError(f"view {view.name!r}: expected (image[, attention[, mask]]), got {len(item)} items")
        image, attention, mask = (list(item) + [None, None])[:3]
    else:
        image, attention, mask = item, None, None
    if image is None:
        raise ValueError(f"view {view.name!r}: no edited image")
    return (
        _plane(view, "edited image", image, 3),
        _plane(view, "attention", attention, None),
        _plane(view, "mask", mask, None),
    )


def call_editor(editor: Callable, raw: List[tuple], prompt: str) -> List[Any]:
    """Calls the user's editor on the views and checks what it returns (used by the
    compiled edit; exceptions raised by the editor propagate unchanged)."""
    views, out = _call_on_views(editor, raw, prompt, "editor", "entry")
    if len(out) != len(views):
        raise ValueError(f"the editor returned {len(out)} views for {len(views)} inputs")
    return [_output(v, item) for v, item in zip(views, out)]


def _call_on_views(fn: Callable, raw: List[tuple], text: str, role: str, item: str):
    """The views (read-only images) and `fn(views, text)` as a list; a result that is not
    a list of entries is a ValueError naming `role`."""
    views = [View(i, n, img, vm, k, w, h) for (i, n, img, vm, k, w, h) in raw]
    for v in views:
        v.image.setflags(write=False)
    out = fn(views, text)
    if out is None or isinstance(out, (str, bytes, np.ndarray)) or not hasattr(out, "__len__"):
        raise ValueError(f"the {role} must return a list with one {item} per view, got {type(out).__name__}")
    return views, list(out)


def call_segmenter(segmenter: Callable, raw: List[tuple], phrase: str) -> List[Optional[np.ndarray]]:
    """Calls the user's segmenter on the views and checks the shape and type of what it
    returns (used by the compiled edit; values are checked in Rust; exceptions raised by
    the segmenter propagate unchanged)."""
    views, out = _call_on_views(segmenter, raw, phrase, "segmenter", "mask")
    if len(out) != len(views):
        raise ValueError(f"the segmenter returned {len(out)} masks for {len(views)} views")
    masks = []
    for v, m in zip(views, out):
        if m is not None and np.ndim(m) == 0:
            raise ValueError(
                f"view {v.index} ({v.name!r}): the segmenter's mask is a {type(m).__name__}, expected an "
                f"(H, W) array in [0, 1] or None"
            )
        masks.append(_plane(v, "the segmenter's mask", m, None))
    return masks


class _Progress:
    """tqdm when it is installed (``tqdm.auto``: a widget in notebooks), else a line on
    stderr every few seconds."""

    def __init__(self) -> None:
        self.bar = None
        self.last = 0.0
        try:
            from tqdm.auto import tqdm

            self.tqdm = tqdm
        except ImportError:
            self.tqdm = None

    def __call__(self, kind: str, a: int, b: int, x: float) -> None:
        if kind == "edited":
            print(f"transsplat: the editor edited {a} views in {x:.1f} s", file=sys.stderr)
        elif kind == "step":
            if self.tqdm is not None:
                if self.bar is None:
                    self.bar = self.tqdm(total=b, desc="edit", unit="step")
                self.bar.update(a - self.bar.n)
                if a % 10 == 0:
                    self.bar.set_postfix(loss=f"{x:.4f}")
                if a == b:
                    self.bar.close()
            elif time.monotonic() - self.last > 2.0 or a == b:
                self.last = time.monotonic()
                print(f"transsplat: edit step {a}/{b}, loss {x:.4f}", file=sys.stderr)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _overrides(settings: Mapping[str, Any]) -> List[str]:
    out = []
    for k, v in settings.items():
        if isinstance(v, bool):
            text = "true" if v else "false"
        elif isinstance(v, (int, float, np.integer, np.floating)):
            if isinstance(v, (float, np.floating)) and not math.isfinite(v):
                raise ValueError(f"config: {k} = {v} is not a finite number")
            text = repr(v.item() if hasattr(v, "item") else v)
        elif isinstance(v, str):
            text = json.dumps(v)
        else:
            raise ValueError(f"config: {k} has a value of type {type(v).__name__}")
        out.append(f"{k}={text}")
    return out


def edit(
    scene: Union[str, "os.PathLike[str]", Mapping[str, Any]],
    cameras: Union[str, "os.PathLike[str]", Mapping[str, Any], None],
    prompt: str,
    editor: Callable[[List[View], str], Sequence[Any]],
    config: Union[str, "os.PathLike[str]", Mapping[str, Any], None] = None,
    method: Optional[str] = None,
    out: Union[str, "os.PathLike[str]", None] = None,
    steps: Optional[int] = None,
    background: Sequence[float] = (0.0, 0.0, 0.0),
    progress: Union[bool, Callable[[str, int, int, float], None]] = True,
    views: Union[str, int] = "all",
    segmenter: Optional[Callable[[List[View], str], Sequence[Any]]] = None,
    segment: Optional[str] = None,
) -> Dict[str, Any]:
    """Edits a scene with a 2D editor and lifts the edits onto the Gaussians by
    unbalanced semantic transport (the TransSplat method; the baselines and ablations
    by ``method``).

    Args:
        scene: a PLY file or INRIA output folder, or the dict :func:`load_ply` returns.
        cameras: a camera source :func:`load_cameras` reads, or its dict; None takes
            the cameras beside a scene given as a path. Every 8th camera is held out as
            a test view; the others are edited.
        prompt: the instruction, e.g. ``"make the ball blue"``.
        editor: ``editor(views, prompt)`` with ``views`` a list of :class:`View`;
            returns one entry per view: ``None`` (no edit for that view), the edited
            image (H, W, 3) float in [0, 1] or uint8, a tuple ``(image, attention,
            mask)`` or a dict with those keys. ``attention`` (H, W) >= 0 marks where
            the instruction applies; ``mask`` (H, W) in [0, 1] is the target. Without
            both, attention is the mask, or the change between render and edit (as the
            command line tool's folder editor does).
        config: a TOML file of settings (as ``transsplat edit --config``) or a dict of
            ``{"section.key": value}`` overrides (as ``--set``).
        method: ``transsplat``, ``naive``, ``masklift``, ``no_leaksup``,
            ``no_prototype`` or ``geometric``; None keeps the config's (``transsplat``
            unless the config file says otherwise), as the command line tool does.
        out: when given, the output folder of ``transsplat edit`` is written there
            (edited PLY, renders, gate maps, transport.json, report.html); it appears
            only when complete.
        steps: optimisation steps (overrides the config).
        background: colour behind the Gaussians.
        progress: True shows progress (tqdm if installed), False none, or a callable
            ``progress(kind, a, b, x)`` (kind "edited", "step" or "round").
        views: which edit views the editor edits: ``"all"``, ``"auto"``, a count ``K``
            or ``"1/N"``, chosen as ``transsplat edit --views`` chooses them.
        segmenter: ``segmenter(views, phrase)`` with ``views`` the :class:`View` list of
            the views the editor edited (their renders before the edit); returns one
            entry per view: an (H, W) mask in [0, 1] (float, bool or uint8; inside
            where > 0.5) or None where the target was not found (e.g. Grounded-SAM or
            LangSAM on your GPU). Each edited view's support becomes its attention
            inside the mask, replacing any mask the editor returned: the same door as
            ``transsplat edit --segment`` / ``--masks``. A view with no mask counts as
            a miss (its attention alone decides its support; a warning names it); a miss in every view
            raises ``ValueError``.
        segment: the phrase the segmenter is given (``"the ball"``); without it, the
            whole instruction ``prompt``.

    Returns:
        A dict: ``gaussians`` (the edited scene, as :func:`load_ply` returns it, with
        the semantic latents under ``extra``), ``gate`` (N,) or None, ``rounds`` (per
        transport round: step, objective, dual, gap, transported mass, mean gate),
        ``losses`` (per step), ``timing``, ``prototypes``, ``edit_views`` and ``out``.

    KeyboardInterrupt stops the loop between steps and is raised; nothing is written.
    """
    from . import _f32, _scene_arrays, load_cameras, load_ply

    inputs: List[str] = []
    if isinstance(scene, Mapping):
        g = scene
    else:
        inputs.append(os.fspath(scene))
        g = load_ply(scene)
    if cameras is None:
        if isinstance(scene, Mapping):
            raise ValueError("cameras: needed when the scene is given as arrays")
        cameras = scene
    if isinstance(cameras, Mapping):
        cams = cameras
    else:
        inputs.append(os.fspath(cameras))
        cams = load_cameras(cameras)
    for key in ("viewmats", "Ks", "widths", "heights", "names"):
        if key not in cams:
            raise ValueError(f"cameras: missing {key!r}")
    if not isinstance(prompt, str) or not prompt.strip():
        raise ValueError("prompt: the instruction is empty; give one such as \"make the ball blue\"")
    if not callable(editor):
        raise ValueError(f"editor: expected a callable, got {type(editor).__name__}")
    if segmenter is not None and not callable(segmenter):
        raise ValueError(f"segmenter: expected a callable, got {type(segmenter).__name__}")
    if segment is not None:
        if segmenter is None:
            raise ValueError("segment: needs segmenter=, a callable from views to masks")
        if not isinstance(segment, str) or not segment.strip():
            raise ValueError("segment: the phrase is empty; name the target, e.g. \"the ball\"")
    toml_text = None
    overrides: List[str] = []
    if isinstance(config, Mapping):
        overrides = _overrides(config)
    elif config is not None:
        path = os.fspath(config)
        inputs.append(path)
        with open(path, encoding="utf-8") as f:
            toml_text = f.read()
    from . import _size

    for w, h in zip(cams["widths"], cams["heights"]):
        _size(int(w), int(h))
    bg = [float(v) for v in background]
    if len(bg) != 3:
        raise ValueError(f"background: expected 3 values, got {len(bg)}")
    if steps is not None and (not isinstance(steps, (int, np.integer)) or steps < 0):
        raise ValueError(f"steps: expected a non-negative integer, got {steps!r}")
    if progress is True:
        bar = _Progress()
    elif progress is False or progress is None:
        bar = None
    elif callable(progress):
        bar = progress
    else:
        raise ValueError("progress: expected True, False or a callable")
    scene_args = _scene_arrays("scene", g)

    def adapter(raw, text):
        return call_editor(editor, raw, text)

    segmenter_adapter = None
    if segmenter is not None:

        def segmenter_adapter(raw, phrase):
            return call_segmenter(segmenter, raw, phrase)

    try:
        r = _core.edit(
            *scene_args,
            _f32("viewmats", cams["viewmats"]),
            _f32("Ks", cams["Ks"]),
            [int(w) for w in cams["widths"]],
            [int(h) for h in cams["heights"]],
            [str(n) for n in cams["names"]],
            prompt,
            adapter,
            toml_text,
            overrides,
            method,
            None if steps is None else int(steps),
            bg,
            None if out is None else os.fspath(out),
            inputs,
            bar,
            str(views),
            segmenter_adapter,
            segment,
        )
    finally:
        if isinstance(bar, _Progress):
            bar.close()
    return {
        "gaussians": r["gaussians"],
        "gate": r["gate"],
        "rounds": json.loads(r["rounds_json"]),
        "losses": json.loads(r["losses_json"]),
        "timing": json.loads(r["timing_json"]),
        "prototypes": r["prototypes"],
        "edit_views": r["edit_views"],
        "out": None if r["out"] is None else os.fspath(r["out"]),
    }

"""Type stubs of the compiled core (``transsplat._core``). Use the wrappers in
``transsplat``: they convert arguments and document the conventions."""

from os import PathLike
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

F32 = npt.NDArray[np.float32]
_Path = Union[str, PathLike]

__version__: str

class Frames:
    """State one rasterization call keeps for its backward."""

def load_ply(path: _Path) -> Dict[str, Any]: ...
def save_ply(
    path: _Path,
    means: F32,
    quats: F32,
    log_scales: F32,
    opacity_logits: F32,
    sh: F32,
    extra_names: List[str],
    extra: Optional[F32] = None,
) -> None: ...
def load_cameras(path: _Path) -> Dict[str, Any]: ...
def builtin_scene(name: str, out: _Path, quick: bool = False, seed: int = 0) -> str: ...
def rasterize(
    means: F32,
    quats: F32,
    scales: F32,
    opacities: F32,
    colors: F32,
    viewmats: F32,
    ks: F32,
    width: int,
    height: int,
    sh_degree: Optional[int],
    backgrounds: Optional[F32],
    render_mode: str,
) -> Tuple[F32, F32, Dict[str, Any], Frames]: ...
def rasterize_backward(
    state: Frames,
    means: F32,
    quats: F32,
    scales: F32,
    opacities: F32,
    colors: F32,
    v_colors: F32,
    v_alphas: Optional[F32] = None,
) -> Dict[str, np.ndarray]: ...
def sinkhorn_unbalanced(
    a: F32,
    b: F32,
    m: F32,
    reg: float,
    reg_m_s: float,
    reg_m_t: float,
    num_iter_max: int,
    stop_thr: Optional[float],
    top_k: int,
) -> Tuple[F32, Dict[str, Any]]: ...
def is_test_view(index: int) -> bool: ...
def edit(
    means: F32,
    quats: F32,
    log_scales: F32,
    opacity_logits: F32,
    sh: F32,
    extra_names: List[str],
    extra: Optional[F32],
    viewmats: F32,
    ks: F32,
    widths: Sequence[int],
    heights: Sequence[int],
    names: Sequence[str],
    prompt: str,
    adapter: Callable[[List[tuple], str], List[Any]],
    config_toml: Optional[str],
    overrides: List[str],
    method: Optional[str],
    steps: Optional[int],
    background: Sequence[float],
    out: Optional[str],
    inputs: List[str],
    progress: Optional[Callable[[str, int, int, float], None]],
    views: str,
    segmenter: Optional[Callable[[List[tuple], str], List[Any]]] = None,
    segment: Optional[str] = None,
) -> Dict[str, Any]: ...
def check_config(
    config_toml: Optional[str], overrides: List[str], method: Optional[str], steps: Optional[int]
) -> None: ...
def bench_scene(n: int, size: int) -> Tuple[Dict[str, Any], Dict[str, Any]]: ...
def check_output(out: _Path, inputs: List[_Path]) -> None: ...

"""PyTorch autograd for the CPU rasterizer: ``loss.backward()`` through
:func:`rasterization` on CPU tensors.

    from transsplat.torch import rasterization
    colors, alphas, meta = rasterization(means, quats, scales, opacities, sh,
                                         viewmats, Ks, W, H, sh_degree=3)
    loss = (colors - target).abs().mean()
    loss.backward()        # means.grad, quats.grad, scales.grad, ... are filled

Arguments are those of :func:`transsplat.rasterization` (gsplat's names and shapes);
tensors must live on the CPU. Gradients flow to ``means``, ``quats``, ``scales``,
``opacities`` and ``colors``; ``meta["means2d"]`` carries no gradient (the per-camera
2D-mean gradients of the last backward are in ``meta["means2d_grad"]`` once it ran).
"""

from __future__ import annotations

from typing import Any, Dict, Tuple

import numpy as np
import torch

import transsplat as _ts

_INPUTS = ("means", "quats", "scales", "opacities", "colors")


def _np(t: torch.Tensor, name: str) -> np.ndarray:
    if t.device.type != "cpu":
        raise ValueError(f"{name}: the rasterizer runs on the CPU; got a tensor on {t.device}")
    return t.detach().to(torch.float32).contiguous().numpy()


class _Rasterize(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, opacities, colors, viewmats, Ks, settings, holder):
        arrays = [_np(t, n) for t, n in zip((means, quats, scales, opacities, colors), _INPUTS)]
        out, alphas, meta = _ts.rasterization(
            *arrays, _np(viewmats, "viewmats"), _np(Ks, "Ks"), **settings
        )
        ctx.vjp = meta.pop("vjp")
        ctx.meta = holder
        holder.update(meta)
        ctx.dtypes = [t.dtype for t in (means, quats, scales, opacities, colors)]
        return torch.from_numpy(out), torch.from_numpy(alphas)

    @staticmethod
    def backward(ctx, v_colors, v_alphas):
        g = ctx.vjp(
            v_colors.detach().to(torch.float32).contiguous().numpy(),
            None if v_alphas is None else v_alphas.detach().to(torch.float32).contiguous().numpy(),
        )
        ctx.meta["means2d_grad"] = torch.from_numpy(g["means2d"])
        grads = [torch.from_numpy(g[n]).to(d) for n, d in zip(_INPUTS, ctx.dtypes)]
        return (*grads, None, None, None, None)


def rasterization(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    **settings: Any,
) -> Tuple[torch.Tensor, torch.Tensor, Dict[str, Any]]:
    """:func:`transsplat.rasterization` on CPU tensors, differentiable with respect to
    ``means``, ``quats``, ``scales``, ``opacities`` and ``colors``. Returns
    ``(render_colors, render_alphas, meta)`` with ``meta``'s arrays as tensors."""
    settings = dict(settings, width=width, height=height)
    holder: Dict[str, Any] = {}
    out, alphas = _Rasterize.apply(means, quats, scales, opacities, colors, viewmats, Ks, settings, holder)
    for k, v in list(holder.items()):
        if isinstance(v, np.ndarray):
            holder[k] = torch.from_numpy(v)
    return out, alphas, holder

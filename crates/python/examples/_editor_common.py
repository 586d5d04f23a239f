"""Shared plumbing of the diffusers editor examples (flux_kontext_editor.py,
qwen_image_edit_editor.py): loading a pipeline, the per-view seeds, and the resize of a
shard of views to the model's working size and back.

What every editor built on `ShardEditor` guarantees:

- one pipeline call per shard (the views transsplat or a Ray actor hands it), so a GPU
  edits the shard as one batch; views of different sizes are grouped by working size,
  one call per group, and `max_batch` caps a call's views (`transsplat.edit` hands the
  editor all its views at once: a whole scene at ~1024² can exceed a GPU's memory);
- each view gets its own `torch.Generator`, seeded from the editor's seed and the
  view's index, and the generators go to the pipeline as a list (one per batch entry):
  a view's edit does not depend on which shard it came in or where in it, which is
  what lets `transsplat.ray` cache results per view and retry shards;
- the edited images come back at the render's (H, W) as float32 in [0, 1].

Needs torch and diffusers (>= 0.35, the first with both FluxKontextPipeline and
QwenImageEditPipeline).
"""

import math
import re

import diffusers
import numpy as np
import torch
import torch.nn.functional as F

# The per-view seed is seed * SEED_STRIDE + view.index, as in ip2p_editor.py: distinct
# (seed, view) pairs get distinct streams while a scene has fewer than 100003 cameras.
SEED_STRIDE = 100003


def view_generator(seed, view):
    """The view's own generator. CPU generators: diffusers draws the noise on the CPU
    and moves it, so the noise of a view is the same on any GPU (or none)."""
    return torch.Generator(device="cpu").manual_seed(seed * SEED_STRIDE + int(view.index))


def working_size(height, width, size, multiple):
    """(h, w) of about size × size pixels with the render's aspect ratio, each a
    multiple of `multiple` (the pipeline's latent patch in pixels) and at least one."""
    scale = math.sqrt(size * size / (height * width))
    h = max(multiple, round(height * scale / multiple) * multiple)
    w = max(multiple, round(width * scale / multiple) * multiple)
    return h, w


def resize_views(views, size):
    """The views' renders as one (B, 3, h, w) float32 batch in [0, 1] on the CPU."""
    out = []
    for v in views:
        image = np.array(v.image, dtype=np.float32)  # a copy: transsplat's renders are read-only
        x = torch.from_numpy(image).permute(2, 0, 1)[None]
        out.append(F.interpolate(x, size=size, mode="bilinear", align_corners=False, antialias=True))
    return torch.cat(out).clamp(0, 1)


def resize_back(images, views):
    """A pipeline's (B, 3, h, w) output in [0, 1] as one (H, W, 3) float32 image per view,
    at each view's own size (antialiased: the working size is usually larger)."""
    images = images.detach().float().cpu()
    out = []
    for x, v in zip(images, views):
        x = F.interpolate(x[None], size=(v.height, v.width), mode="bilinear", align_corners=False, antialias=True)
        out.append(x[0].clamp(0, 1).permute(1, 2, 0).contiguous().numpy())
    return out


def load_pipeline(pipeline_class, weights, device=None, offload=None):
    """`pipeline_class.from_pretrained(weights)` in bfloat16 on a GPU (the dtype the model
    cards load in; float32 on the CPU), then placed by `offload`:

    - None: every component on the device (fastest; needs the most memory);
    - "model": `enable_model_cpu_offload()`, one component on the GPU at a time (the
      peak is about the largest component, the transformer);
    - "sequential": `enable_sequential_cpu_offload()`, layer by layer (least memory,
      much slower).
    """
    device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
    dtype = torch.bfloat16 if device.type == "cuda" else torch.float32
    # diffusers 0.40 renamed from_pretrained's `torch_dtype` to `dtype` (the old name warns;
    # before 0.40 the new one is ignored, which would load float32).
    version = tuple(int(x) for x in re.findall(r"\d+", diffusers.__version__)[:2])
    pipe = pipeline_class.from_pretrained(weights, **{"dtype" if version >= (0, 40) else "torch_dtype": dtype})
    if offload is None:
        pipe.to(device)
    elif offload == "model":
        pipe.enable_model_cpu_offload(device=device)
    elif offload == "sequential":
        pipe.enable_sequential_cpu_offload(device=device)
    else:
        raise ValueError(f"offload: expected None, 'model' or 'sequential', got {offload!r}")
    pipe.set_progress_bar_config(disable=True)
    return pipe


class ShardEditor:
    """A transsplat editor callable ``editor(views, prompt)`` around a diffusers pipeline.

    `max_batch` (None: no cap) is the most views one pipeline call gets.

    Subclasses implement ``edit_batch(images, prompt, generators, size)``: one pipeline
    call on `images` (B, 3, h, w) in [0, 1] at the working size `size` = (h, w), with one
    generator per image, returning (B, 3, h, w) in [0, 1].

    It returns the edited image per view and no attention: these DiT pipelines have no
    cheap cross-attention map to give, and transsplat then computes the change between
    render and edit itself (with the 8-bit quantisation floor and the smoothing of the
    command line tool's folder editor, so a Python run and `--editor folder` on the same
    edits agree).
    """

    def __init__(self, pipe, seed, size, multiple, max_batch=None):
        self.pipe, self.seed, self.size, self.multiple = pipe, seed, size, multiple
        self.max_batch = max_batch

    def edit_batch(self, images, prompt, generators, size):
        raise NotImplementedError

    def __call__(self, views, prompt):
        groups = {}
        for i, v in enumerate(views):
            groups.setdefault(working_size(v.height, v.width, self.size, self.multiple), []).append(i)
        out = [None] * len(views)
        for size, members in groups.items():
            step = self.max_batch or len(members)
            for start in range(0, len(members), step):
                batch = members[start:start + step]
                shard = [views[i] for i in batch]
                generators = [view_generator(self.seed, v) for v in shard]
                with torch.inference_mode():
                    edited = self.edit_batch(resize_views(shard, size), prompt, generators, size)
                for i, image in zip(batch, resize_back(edited, shard)):
                    out[i] = image
        return out


def command_line(doc, model, min_memory):
    """The arguments every DiT editor example takes (scene, weights, prompt, output, the
    lift's steps and views, working size, offload, batch, device, seed); the caller adds its
    model's own and parses. `model` names the diffusers folder, `min_memory` the GPU size
    below which offloading is needed."""
    import argparse

    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", required=True, help="PLY or INRIA output folder")
    ap.add_argument("--cameras", help="camera source (default: beside the scene)")
    ap.add_argument("--weights", required=True, help=f"diffusers {model} folder")
    ap.add_argument("--prompt", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--steps", type=int, help="optimisation steps of the lift")
    ap.add_argument("--views", default="all", help='views to edit: "all", "auto", a count or "1/N"')
    ap.add_argument("--size", type=int, default=1024, help="working size: about SIZE x SIZE pixels")
    ap.add_argument("--offload", choices=["model", "sequential"], help=f"CPU offload, for GPUs under ~{min_memory}")
    ap.add_argument("--max-batch", type=int, default=4,
                    help="views per pipeline call (transsplat.edit hands the editor all its views at once)")
    ap.add_argument("--device", help="default: cuda when available")
    ap.add_argument("--seed", type=int, default=0)
    return ap


def run_edit(args, editor):
    """`transsplat.edit` with `editor` as the command line asked; prints what it wrote."""
    import transsplat

    r = transsplat.edit(args.scene, args.cameras, args.prompt, editor, steps=args.steps, out=args.out,
                        views=args.views)
    print(f"edited {len(r['gaussians']['means'])} Gaussians; wrote {r['out']}")

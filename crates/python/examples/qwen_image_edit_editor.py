#!/usr/bin/env python3
"""Qwen-Image-Edit (diffusers' QwenImageEditPipeline) as the 2D editor of a TransSplat edit.

diffusers does the 2D edits on a GPU, transsplat lifts them onto the Gaussians on the
CPU. Each call edits its whole shard of views in one batch: every render is resized to
the working size (about 1024² pixels with the render's aspect, multiples of 32, the
size the pipeline itself gives its input image), denoised in 50 steps with true
classifier-free guidance 4.0 against the negative prompt " " (the model card's
settings) from noise seeded per view, and resized back to the render's size.

    python qwen_image_edit_editor.py --scene SCENE --weights DIR --prompt "make the ball blue" --out edited/

DIR is the diffusers folder of the model (`hf download Qwen/Qwen-Image-Edit --local-dir
DIR`). Needs torch, torchvision, diffusers >= 0.35 and transformers (`pip install torch
torchvision diffusers transformers`; transformers 5's Qwen2-VL processor needs
torchvision).

Memory: the model card builds Qwen-Image-Edit on "the 20B Qwen-Image model", about 41 GB
of weights in bfloat16; with its Qwen2.5-VL-7B text encoder (8.3B parameters) and the
VAE the pipeline's weights are about 58 GB (an 80 GB card), activations on top.
`--offload model` keeps one component on the GPU at a time (about the transformer's
41 GB plus activations), `--offload sequential` moves layer by layer (least memory,
much slower). Sizes: docs/python.md.
"""

import numpy as np
from diffusers import QwenImageEditPipeline
from PIL import Image

from _editor_common import ShardEditor, command_line, load_pipeline, run_edit


class QwenImageEditor(ShardEditor):
    """A transsplat editor callable: ``editor(views, prompt)`` returns one edited image
    per view (H, W, 3) in [0, 1], the whole shard in one QwenImageEditPipeline call.

    ``QwenImageEditor(weights, ...)`` loads the model (as a Ray manifest's
    ``editor_args`` do); ``QwenImageEditor.from_pipeline(pipe, ...)`` wraps a pipeline
    you built or loaded yourself.

    Args:
        weights: the diffusers folder (or hub id) of Qwen-Image-Edit.
        device: "cuda", "cpu", ...; default: CUDA when there is one.
        offload: None, "model" or "sequential" (see `_editor_common.load_pipeline`).
        seed: the edit's seed; view v's noise comes from seed and v.index only.
        steps: denoising steps (50 in the model card).
        true_cfg_scale: classifier-free guidance (4.0 in the model card; 1 turns it
            off and halves the transformer's work).
        negative_prompt: the unconditional prompt of the guidance (" " in the card).
        size: the output's working size, about size × size pixels at the render's
            aspect. The pipeline always gives the Qwen2.5-VL encoder and the VAE the
            input image at about 1024² whatever this is.
        max_batch: the most views one pipeline call gets (None: the whole shard).
    """

    def __init__(self, weights=None, device=None, offload=None, seed=0, steps=50, true_cfg_scale=4.0,
                 negative_prompt=" ", size=1024, max_batch=None, pipeline=None):
        if (weights is None) == (pipeline is None):
            raise ValueError("give either weights (a model folder) or pipeline (a QwenImageEditPipeline)")
        pipe = pipeline if pipeline is not None else load_pipeline(QwenImageEditPipeline, weights, device, offload)
        # The pipeline rounds its input image to multiples of 32 (and latents need 2 × 2
        # patches of the VAE's grid): with the same rounding our resize is the only one.
        super().__init__(pipe, seed=seed, size=size, multiple=max(32, pipe.vae_scale_factor * 2),
                         max_batch=max_batch)
        self.steps, self.true_cfg_scale, self.negative_prompt = steps, true_cfg_scale, negative_prompt

    @classmethod
    def from_pipeline(cls, pipe, **settings):
        """The editor around a ready QwenImageEditPipeline (already on its device)."""
        return cls(pipeline=pipe, **settings)

    def edit_batch(self, images, prompt, generators, size):
        h, w = size
        # QwenImageEditPipeline reads its input's size as PIL images do (`.size`), so the
        # batch goes in as a list of 8-bit images, as the model sees any photo.
        pil = [Image.fromarray(np.round(x.permute(1, 2, 0).numpy() * 255).astype(np.uint8)) for x in images]
        n = len(pil)
        return self.pipe(
            image=pil, prompt=[prompt] * n, negative_prompt=[self.negative_prompt] * n,
            true_cfg_scale=self.true_cfg_scale, height=h, width=w, num_inference_steps=self.steps,
            generator=generators, output_type="pt",
        ).images


def main():
    ap = command_line(__doc__, "Qwen-Image-Edit", "58 GB")
    ap.add_argument("--edit-steps", type=int, default=50, help="denoising steps of each 2D edit")
    ap.add_argument("--true-cfg-scale", type=float, default=4.0)
    args = ap.parse_args()
    editor = QwenImageEditor(args.weights, device=args.device, offload=args.offload, seed=args.seed,
                             steps=args.edit_steps, true_cfg_scale=args.true_cfg_scale, size=args.size,
                             max_batch=args.max_batch)
    run_edit(args, editor)


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""FLUX.1 Kontext [dev] (diffusers' FluxKontextPipeline) as the 2D editor of a TransSplat edit.

diffusers does the 2D edits on a GPU, transsplat lifts them onto the Gaussians on the
CPU. Each call edits its whole shard of views in one batch: every render is resized to
Kontext's working size (about 1024² pixels with the render's aspect; a 4:3 render
works at 1184 × 880, one of the resolutions Kontext was trained at), denoised from
noise seeded per view (the model card's example: guidance 2.5, the pipeline's default
28 steps), and resized back to the render's size.

    python flux_kontext_editor.py --scene SCENE --weights DIR --prompt "make the ball blue" --out edited/

DIR is the diffusers folder of the model (`hf download black-forest-labs/FLUX.1-Kontext-dev
--local-dir DIR`; the repository is gated: accept its licence on the model page and
`hf auth login` first). Needs torch, diffusers >= 0.35, transformers, sentencepiece and
protobuf (`pip install torch diffusers transformers sentencepiece protobuf`).

Memory: the model card calls Kontext [dev] "a 12 billion parameter rectified flow
transformer", about 24 GB of weights in bfloat16; with the T5-XXL and CLIP text
encoders and the VAE the pipeline's weights are about 34 GB, activations on top.
`--offload model` keeps one component on the GPU at a time (about the transformer's
24 GB plus activations), `--offload sequential` moves layer by layer (least memory,
much slower). Sizes: docs/python.md.
"""

from diffusers import FluxKontextPipeline

from _editor_common import ShardEditor, command_line, load_pipeline, run_edit


class FluxKontextEditor(ShardEditor):
    """A transsplat editor callable: ``editor(views, prompt)`` returns one edited image
    per view (H, W, 3) in [0, 1], the whole shard in one FluxKontextPipeline call.

    ``FluxKontextEditor(weights, ...)`` loads the model (as a Ray manifest's
    ``editor_args`` do); ``FluxKontextEditor.from_pipeline(pipe, ...)`` wraps a pipeline
    you built or loaded yourself.

    Args:
        weights: the diffusers folder (or hub id) of FLUX.1 Kontext [dev].
        device: "cuda", "cpu", ...; default: CUDA when there is one.
        offload: None, "model" or "sequential" (see `_editor_common.load_pipeline`).
        seed: the edit's seed; view v's noise comes from seed and v.index only.
        steps: denoising steps (the pipeline's default, 28).
        guidance: the distilled guidance scale (2.5 in the model card).
        size: the working size, about size × size pixels at the render's aspect.
        max_batch: the most views one pipeline call gets (None: the whole shard).
    """

    def __init__(self, weights=None, device=None, offload=None, seed=0, steps=28, guidance=2.5, size=1024,
                 max_batch=None, pipeline=None):
        if (weights is None) == (pipeline is None):
            raise ValueError("give either weights (a model folder) or pipeline (a FluxKontextPipeline)")
        pipe = pipeline if pipeline is not None else load_pipeline(FluxKontextPipeline, weights, device, offload)
        # Latents are 2 × 2 patches of the VAE's 8× downsampled image: sizes are multiples of 16.
        super().__init__(pipe, seed=seed, size=size, multiple=pipe.vae_scale_factor * 2, max_batch=max_batch)
        self.steps, self.guidance = steps, guidance

    @classmethod
    def from_pipeline(cls, pipe, **settings):
        """The editor around a ready FluxKontextPipeline (already on its device)."""
        return cls(pipeline=pipe, **settings)

    def edit_batch(self, images, prompt, generators, size):
        h, w = size
        # The working size is ours: `_auto_resize=False` keeps the pipeline from snapping
        # the input to its nearest training resolution (at size 1024 it is one already),
        # and max_area = h·w makes the output that size too.
        return self.pipe(
            image=images, prompt=[prompt] * len(images), height=h, width=w, max_area=h * w, _auto_resize=False,
            num_inference_steps=self.steps, guidance_scale=self.guidance, generator=generators, output_type="pt",
        ).images


def main():
    ap = command_line(__doc__, "FLUX.1 Kontext", "34 GB")
    ap.add_argument("--edit-steps", type=int, default=28, help="denoising steps of each 2D edit")
    ap.add_argument("--guidance", type=float, default=2.5)
    args = ap.parse_args()
    editor = FluxKontextEditor(args.weights, device=args.device, offload=args.offload, seed=args.seed,
                               steps=args.edit_steps, guidance=args.guidance, size=args.size,
                               max_batch=args.max_batch)
    run_edit(args, editor)


if __name__ == "__main__":
    main()

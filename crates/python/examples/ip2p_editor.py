#!/usr/bin/env python3
"""InstructPix2Pix (diffusers) as the 2D editor of a TransSplat edit.

diffusers does the 2D edits (on a GPU when there is one), transsplat lifts them onto the
Gaussians on the CPU. Each view is edited the way Instruct-NeRF2NeRF / Instruct-GS2GS
edit a render: encode it, add noise at a start step drawn from [0.02, 0.98] of the
diffusion schedule (seeded per view), denoise in 20 DDIM steps with three-way
classifier-free guidance (text 7.5, image 1.5) conditioned on the same render.

    python ip2p_editor.py --scene SCENE --weights DIR --prompt "make the ball blue" --out edited/

DIR is a diffusers InstructPix2Pix folder (`hf download timbrooks/instruct-pix2pix
--local-dir DIR`: unet/, vae/, text_encoder/, tokenizer/, scheduler/). Needs torch,
diffusers and transformers (`pip install torch diffusers transformers`).
"""

import argparse
import pathlib

import numpy as np
import torch
import torch.nn.functional as F
from diffusers import AutoencoderKL, DDIMScheduler, UNet2DConditionModel
from transformers import CLIPTextModel, CLIPTokenizer

import transsplat


class InstructPix2PixEditor:
    """A transsplat editor callable: ``editor(views, prompt)`` returns one edited image
    per view (H, W, 3) in [0, 1]."""

    def __init__(self, weights, tokenizer=None, device=None, seed=0, steps=20, guidance=7.5,
                 image_guidance=1.5, lower=0.02, upper=0.98, size=512):
        w = pathlib.Path(weights)
        self.device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
        self.dtype = torch.float16 if self.device.type == "cuda" else torch.float32
        variant = "fp16" if any((w / "unet").glob("*.fp16.safetensors")) else None
        self.unet = UNet2DConditionModel.from_pretrained(w / "unet", variant=variant).to(self.device, self.dtype)
        self.vae = AutoencoderKL.from_pretrained(w / "vae").to(self.device, self.dtype)
        self.text_encoder = CLIPTextModel.from_pretrained(w / "text_encoder").to(self.device, self.dtype)
        self.tokenizer = CLIPTokenizer.from_pretrained(tokenizer or (w / "tokenizer"))
        self.scheduler_config = DDIMScheduler.load_config(w / "scheduler")
        self.seed, self.steps = seed, steps
        self.guidance, self.image_guidance = guidance, image_guidance
        self.lower, self.upper, self.size = lower, upper, size

    @torch.no_grad()
    def embed(self, text):
        length = self.text_encoder.config.max_position_embeddings  # 77 for CLIP
        ids = self.tokenizer(text, padding="max_length", max_length=length, truncation=True,
                             return_tensors="pt").input_ids.to(self.device)
        return self.text_encoder(ids)[0]

    @torch.no_grad()
    def edit_one(self, image, text_embeddings, generator):
        """Instruct-NeRF2NeRF's edit of one render (image and condition are the render)."""
        h, w = image.shape[:2]
        scale = self.size / max(h, w)
        hh, ww = max(8, round(h * scale / 8) * 8), max(8, round(w * scale / 8) * 8)
        x = torch.from_numpy(np.array(image, dtype=np.float32)).permute(2, 0, 1)[None].to(self.device, self.dtype)
        x = F.interpolate(x, size=(hh, ww), mode="bilinear", align_corners=False)
        sf = self.vae.config.scaling_factor
        posterior = self.vae.encode(2 * x - 1).latent_dist
        latents = posterior.sample(generator=generator) * sf
        cond = posterior.mode()
        cond = torch.cat([cond, cond, torch.zeros_like(cond)])
        # The start noise: T ~ U{lower, ..., upper} of the 1000 training steps, then 20
        # DDIM steps from T down (the scheduler re-spaced over [0, T)).
        n_train = self.scheduler_config["num_train_timesteps"]
        lo, hi = int(n_train * self.lower), int(n_train * self.upper)
        T = int(torch.randint(lo, hi + 1, [1], generator=generator, device=self.device))
        # As Instruct-NeRF2NeRF: the betas stay those of the 1000-step schedule; only the
        # spacing of the inference steps is taken over [0, T).
        scheduler = DDIMScheduler.from_config(self.scheduler_config)
        scheduler.register_to_config(num_train_timesteps=T)
        scheduler.set_timesteps(self.steps)
        noise = torch.randn(latents.shape, generator=generator, device=self.device, dtype=self.dtype)
        latents = scheduler.add_noise(latents, noise, scheduler.timesteps[:1])
        for t in scheduler.timesteps:
            inp = torch.cat([torch.cat([latents] * 3), cond], dim=1)
            eps = self.unet(inp, t, encoder_hidden_states=text_embeddings).sample
            e_text, e_image, e_uncond = eps.chunk(3)
            eps = e_uncond + self.guidance * (e_text - e_image) + self.image_guidance * (e_image - e_uncond)
            latents = scheduler.step(eps, t, latents).prev_sample
        out = self.vae.decode(latents / sf).sample
        out = F.interpolate((out / 2 + 0.5).clamp(0, 1), size=(h, w), mode="bilinear", align_corners=False)
        return out[0].permute(1, 2, 0).float().cpu().numpy()

    def __call__(self, views, prompt):
        text = self.embed(prompt)
        uncond = self.embed("")
        emb = torch.cat([text, uncond, uncond])
        out = []
        for v in views:
            g = torch.Generator(device=self.device).manual_seed(self.seed * 100003 + v.index)
            out.append(self.edit_one(v.image, emb, g))
        return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", required=True, help="PLY or INRIA output folder")
    ap.add_argument("--cameras", help="camera source (default: beside the scene)")
    ap.add_argument("--weights", required=True, help="diffusers InstructPix2Pix folder")
    ap.add_argument("--tokenizer", help="CLIP tokenizer folder (default: WEIGHTS/tokenizer)")
    ap.add_argument("--prompt", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--steps", type=int, help="optimisation steps of the lift")
    ap.add_argument("--size", type=int, default=512, help="long side the editor works at")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    editor = InstructPix2PixEditor(args.weights, tokenizer=args.tokenizer, seed=args.seed, size=args.size)
    r = transsplat.edit(args.scene, args.cameras, args.prompt, editor, steps=args.steps, out=args.out)
    print(f"edited {len(r['gaussians']['means'])} Gaussians; wrote {r['out']}")


if __name__ == "__main__":
    main()

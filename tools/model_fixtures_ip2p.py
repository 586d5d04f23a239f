#!/usr/bin/env python3
"""Writes the InstructPix2Pix parity fixtures under crates/models/tests/fixtures/ip2p/.

Tiny randomly initialised diffusers / transformers components, saved in the diffusers
pipeline layout that `timbrooks/instruct-pix2pix` uses, plus inputs and reference
outputs computed here with diffusers and transformers:

  unet/          UNet2DConditionModel, 8 input channels; saved as the `.fp16` variant
  vae/           AutoencoderKL (4 levels: the real down-sampling factor 8); float32
  text_encoder/  CLIPTextModel (full CLIP vocabulary, hidden size 8); bfloat16
  scheduler/     the scheduler config of timbrooks/instruct-pix2pix
  reference.safetensors
                 unet.*   one UNet forward (batch 3, like three-way guidance)
                 vae.*    encoder posterior mode and decoder output
                 ddim.*   timesteps and steps of DDIMScheduler for the IN2N usage
                 edit.*   one whole 3-step edit from an explicit start and noise

Weights are rounded to the saved dtype *before* the reference outputs are computed, so
the Rust side (which converts every weight to f32) must match them to float32 accuracy.

Run with the oracle venv:  /work/.venv-oracle/bin/python tools/model_fixtures_ip2p.py
"""

import json
import os
import shutil

import torch
from diffusers import AutoencoderKL, DDIMScheduler, UNet2DConditionModel
from safetensors.torch import save_file
from transformers import CLIPTextConfig, CLIPTextModel

OUT = os.path.join(os.path.dirname(__file__), "..", "crates", "models", "tests", "fixtures", "ip2p")
TEXT_DIM = 8
# The scheduler config shipped with timbrooks/instruct-pix2pix (an Euler-ancestral config
# from which Instruct-NeRF2NeRF / Instruct-GS2GS build their DDIMScheduler).
SCHEDULER = {
    "_class_name": "EulerAncestralDiscreteScheduler",
    "beta_end": 0.012,
    "beta_schedule": "scaled_linear",
    "beta_start": 0.00085,
    "clip_sample": False,
    "num_train_timesteps": 1000,
    "prediction_type": "epsilon",
    "set_alpha_to_one": False,
    "skip_prk_steps": True,
    "steps_offset": 1,
    "trained_betas": None,
}


def perturb(module, gen, scale=0.05):
    """Adds noise to every parameter so norms' affine terms and zero-initialised layers matter."""
    with torch.no_grad():
        for p in module.parameters():
            p.add_(torch.randn(p.shape, generator=gen) * scale)


def round_to(module, dtype):
    with torch.no_grad():
        for p in module.parameters():
            p.copy_(p.to(dtype).to(torch.float32))


def save_component(module, folder, dtype, filename):
    os.makedirs(folder, exist_ok=True)
    module.save_config(folder) if hasattr(module, "save_config") else None
    state = {k: v.detach().to(dtype).contiguous() for k, v in module.state_dict().items()}
    save_file(state, os.path.join(folder, filename))


def ddim_for(train_span, steps):
    """DDIMScheduler as Instruct-NeRF2NeRF / Instruct-GS2GS use it: built from the pipeline's
    scheduler config, `num_train_timesteps` replaced by the start T before `set_timesteps`
    (alphas_cumprod keep the 1000-step schedule)."""
    s = DDIMScheduler.from_config(SCHEDULER)
    s.register_to_config(num_train_timesteps=int(train_span))
    s.set_timesteps(steps)
    return s


def main():
    torch.manual_seed(0)
    gen = torch.Generator().manual_seed(1234)
    if os.path.isdir(OUT):
        shutil.rmtree(OUT)
    os.makedirs(OUT)
    ref = {}

    # ---- UNet ----------------------------------------------------------------------
    unet = UNet2DConditionModel(
        sample_size=8,
        in_channels=8,
        out_channels=4,
        down_block_types=("CrossAttnDownBlock2D", "DownBlock2D"),
        up_block_types=("UpBlock2D", "CrossAttnUpBlock2D"),
        block_out_channels=(16, 32),
        layers_per_block=1,
        cross_attention_dim=TEXT_DIM,
        attention_head_dim=(2, 4),
        norm_num_groups=4,
    ).eval()
    perturb(unet, gen)
    with torch.no_grad():
        # Wider GEGLU gates, so the exact (erf) GELU is distinguishable from its tanh
        # approximation at this tolerance.
        for name, p in unet.named_parameters():
            if "ff.net.0.proj" in name:
                p.mul_(6.0)
    round_to(unet, torch.float16)
    unet_dir = os.path.join(OUT, "unet")
    unet.save_config(unet_dir)
    save_component(unet, unet_dir, torch.float16, "diffusion_pytorch_model.fp16.safetensors")

    sample = torch.randn(3, 8, 8, 12, generator=gen)
    ehs = torch.randn(3, 77, TEXT_DIM, generator=gen)
    with torch.no_grad():
        out = unet(sample, 601, encoder_hidden_states=ehs).sample
    ref["unet.sample"] = sample
    ref["unet.encoder_hidden_states"] = ehs
    ref["unet.timestep"] = torch.tensor([601.0])
    ref["unet.out"] = out

    # ---- VAE -----------------------------------------------------------------------
    vae = AutoencoderKL(
        in_channels=3,
        out_channels=3,
        down_block_types=("DownEncoderBlock2D",) * 4,
        up_block_types=("UpDecoderBlock2D",) * 4,
        block_out_channels=(8, 8, 16, 16),
        layers_per_block=1,
        latent_channels=4,
        norm_num_groups=4,
        sample_size=32,
        scaling_factor=0.18215,
    ).eval()
    perturb(vae, gen)
    vae_dir = os.path.join(OUT, "vae")
    vae.save_config(vae_dir)
    save_component(vae, vae_dir, torch.float32, "diffusion_pytorch_model.safetensors")

    image = torch.rand(1, 3, 32, 48, generator=gen)
    latent = torch.randn(1, 4, 4, 6, generator=gen)
    with torch.no_grad():
        mode = vae.encode(image * 2 - 1).latent_dist.mode()
        decoded = vae.decode(latent).sample
    ref["vae.image"] = image
    ref["vae.mode"] = mode
    ref["vae.latent"] = latent
    ref["vae.decoded"] = decoded

    # ---- text encoder --------------------------------------------------------------
    text = CLIPTextModel(
        CLIPTextConfig(
            vocab_size=49408,
            hidden_size=TEXT_DIM,
            intermediate_size=16,
            num_attention_heads=2,
            num_hidden_layers=1,
            max_position_embeddings=77,
            hidden_act="quick_gelu",
            bos_token_id=49406,
            eos_token_id=49407,
            pad_token_id=49407,
        )
    ).eval()
    perturb(text, gen, scale=0.2)
    round_to(text, torch.bfloat16)
    te_dir = os.path.join(OUT, "text_encoder")
    os.makedirs(te_dir)
    text.config.save_pretrained(te_dir)
    save_component(text, te_dir, torch.bfloat16, "model.safetensors")

    # Token ids of "turn the chair into bronze" and of "" by the CLIP tokenizer (BOS,
    # tokens, EOS, padded with EOS to 77 as the SD 1.5 tokenizer config does).
    from open_clip.tokenizer import SimpleTokenizer

    prompt_ids = [49406] + SimpleTokenizer().encode("turn the chair into bronze") + [49407]
    uncond_ids = [49406, 49407]
    ids = torch.tensor([p + [49407] * (77 - len(p)) for p in (prompt_ids, uncond_ids)])
    with torch.no_grad():
        emb = text(ids).last_hidden_state
    ref["edit.input_ids"] = ids.to(torch.float32)
    ref["edit.prompt_embeds"] = emb[0:1]
    ref["edit.uncond_embeds"] = emb[1:2]

    # ---- scheduler -----------------------------------------------------------------
    os.makedirs(os.path.join(OUT, "scheduler"))
    with open(os.path.join(OUT, "scheduler", "scheduler_config.json"), "w") as f:
        json.dump(SCHEDULER, f, indent=2)
    for span in (700, 853, 980):
        s = ddim_for(span, 20)
        ref[f"ddim.timesteps_{span}"] = s.timesteps.to(torch.float32)
    s = ddim_for(853, 20)
    x = torch.randn(2, 4, 3, 5, generator=gen)
    eps = torch.randn(2, 4, 3, 5, generator=gen)
    ref["ddim.sample"] = x
    ref["ddim.eps"] = eps
    for t in (int(s.timesteps[0]), int(s.timesteps[10]), int(s.timesteps[-1])):
        ref[f"ddim.step_853_{t}"] = s.step(eps, t, x).prev_sample
    ref["ddim.add_noise_853"] = s.add_noise(x, eps, s.timesteps[:1])

    # ---- one whole edit -------------------------------------------------------------
    # The Instruct-NeRF2NeRF / Instruct-GS2GS edit loop written with diffusers'
    # components: encode the render, noise it to the first timestep of the span, denoise
    # with three-way guidance (batch: text+image, image only, neither).
    span, steps, s_t, s_i = 800, 3, 7.5, 1.5
    sched = ddim_for(span, steps)
    edit_image = torch.rand(1, 3, 32, 48, generator=gen)
    noise = torch.randn(1, 4, 4, 6, generator=gen)
    sf = vae.config.scaling_factor
    with torch.no_grad():
        posterior = vae.encode(edit_image * 2 - 1).latent_dist
        latents = posterior.mode() * sf
        cond = posterior.mode()
        cond3 = torch.cat([cond, cond, torch.zeros_like(cond)])
        embeds = torch.cat([emb[0:1], emb[1:2], emb[1:2]])
        latents = sched.add_noise(latents, noise, sched.timesteps[:1])
        attention = torch.zeros(1, 1, 4, 6)
        for t in sched.timesteps:
            model_in = torch.cat([torch.cat([latents] * 3), cond3], dim=1)
            e = unet(model_in, t, encoder_hidden_states=embeds).sample
            e_text, e_img, e_u = e.chunk(3)
            guided = e_u + s_t * (e_text - e_img) + s_i * (e_img - e_u)
            attention += (e_text - e_img).abs().mean(dim=1, keepdim=True)
            latents = sched.step(guided, t, latents).prev_sample
        attention /= len(sched.timesteps)
        edited = (vae.decode(latents / sf).sample / 2 + 0.5).clamp(0, 1)
    ref["edit.image"] = edit_image
    ref["edit.noise"] = noise
    ref["edit.span"] = torch.tensor([float(span)])
    ref["edit.steps"] = torch.tensor([float(steps)])
    ref["edit.timesteps"] = sched.timesteps.to(torch.float32)
    ref["edit.latents"] = latents
    ref["edit.attention"] = attention
    ref["edit.edited"] = edited

    save_file({k: v.detach().to(torch.float32).contiguous() for k, v in ref.items()},
              os.path.join(OUT, "reference.safetensors"))
    total = 0
    for root, _, files in os.walk(OUT):
        for f in files:
            total += os.path.getsize(os.path.join(root, f))
    print(f"wrote {OUT} ({total / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()

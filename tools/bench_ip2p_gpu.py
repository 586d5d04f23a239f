"""Per-view cost of InstructPix2Pix on a GPU worker, for the sweep estimate in
docs/results.md ("Python, Ray and GPU editors"). Run by hand on a GPU machine with torch, diffusers
and transformers; no weights needed: the SD 1.5 InstructPix2Pix architecture (UNet
with 8 input channels, VAE, CLIP ViT-L/14 text encoder) with random weights does the
same arithmetic as the real model.

One edited view = VAE encode of the render + 20 DDIM steps of the UNet on a batch of 3
(three-way guidance: text, image, unconditional) + VAE decode; the prompt is encoded
once per job. Views are batched B at a time (B renders → a UNet batch of 3B).

    python3 tools/bench_ip2p_gpu.py [--sizes 256 512] [--batches 1 4 8] [--dtype fp16]
"""
import argparse
import json
import time

import torch
from diffusers import AutoencoderKL, UNet2DConditionModel
from transformers import CLIPTextConfig, CLIPTextModel

STEPS = 20


def models(dtype, device):
    unet = UNet2DConditionModel(in_channels=8, out_channels=4, cross_attention_dim=768,
                                attention_head_dim=8, sample_size=64)
    vae = AutoencoderKL(in_channels=3, out_channels=3, latent_channels=4,
                        block_out_channels=(128, 256, 512, 512),
                        down_block_types=("DownEncoderBlock2D",) * 4,
                        up_block_types=("UpDecoderBlock2D",) * 4, layers_per_block=2)
    text = CLIPTextModel(CLIPTextConfig(hidden_size=768, intermediate_size=3072, num_hidden_layers=12,
                                        num_attention_heads=12, max_position_embeddings=77))
    return [m.to(device=device, dtype=dtype).eval() for m in (unet, vae, text)]


@torch.no_grad()
def edit_batch(unet, vae, text_states, images):
    b = images.shape[0]
    image_latents = vae.encode(images).latent_dist.mode()
    latents = torch.randn_like(image_latents)
    cond = text_states.expand(3 * b, -1, -1)
    for t in torch.linspace(999, 0, STEPS, device=images.device).long():
        x = torch.cat([latents] * 3)
        x = torch.cat([x, torch.cat([image_latents, image_latents, torch.zeros_like(image_latents)])], dim=1)
        eps = unet(x, t, encoder_hidden_states=cond).sample
        e_text, e_img, e_u = eps.chunk(3)
        eps = e_u + 7.5 * (e_text - e_img) + 1.5 * (e_img - e_u)
        latents = latents - 0.05 * eps  # the DDIM update is a few elementwise ops
    return vae.decode(latents / 0.18215).sample


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", type=int, nargs="+", default=[256, 512])
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 4, 8])
    ap.add_argument("--dtype", choices=["fp16", "bf16", "fp32"], default="fp16")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    dtype = {"fp16": torch.float16, "bf16": torch.bfloat16, "fp32": torch.float32}[args.dtype]
    device = "cuda"
    torch.manual_seed(0)
    unet, vae, text = models(dtype, device)
    ids = torch.randint(0, 49408, (1, 77), device=device)
    rows = []
    with torch.no_grad():
        t0 = time.perf_counter()
        text_states = text(ids).last_hidden_state
        torch.cuda.synchronize()
        rows.append({"what": "text encoder (once per prompt)", "seconds": time.perf_counter() - t0})
        for size in args.sizes:
            for b in args.batches:
                images = torch.rand(b, 3, size, size, device=device, dtype=dtype) * 2 - 1
                edit_batch(unet, vae, text_states, images)  # warm-up (cudnn autotune, allocator)
                torch.cuda.synchronize()
                times = []
                for _ in range(args.repeats):
                    t0 = time.perf_counter()
                    edit_batch(unet, vae, text_states, images)
                    torch.cuda.synchronize()
                    times.append(time.perf_counter() - t0)
                best = min(times)
                rows.append({"what": f"{size}x{size}, {b} view(s) per call", "size": size, "batch": b,
                             "seconds_per_call": best, "seconds_per_view": best / b})
                print(json.dumps(rows[-1]), flush=True)
    print(json.dumps({"device": torch.cuda.get_device_name(), "dtype": args.dtype, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()

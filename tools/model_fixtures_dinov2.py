#!/usr/bin/env python3
"""Reference fixtures for DINOv2 patch features (crates/models/src/dinov2.rs).

Run with the oracle venv:  /work/.venv-oracle/bin/python tools/model_fixtures_dinov2.py

Writes crates/models/tests/fixtures/dinov2/: a tiny random Dinov2Model saved by
save_pretrained (the hub layout of facebook/dinov2-small / -base) and reference.safetensors
with two images and the reference features of the transsplat pipeline computed with torch:

  1. resize bicubic (F.interpolate, align_corners=False) to the nearest multiple of the
     patch size on each side (at least one patch),
  2. ImageNet mean / std,
  3. Dinov2Model -> last_hidden_state (after the final layernorm), patch tokens only,
     position embeddings interpolated by transformers itself,
  4. the patch grid upsampled bilinearly (align_corners=False) to the image size, H x W x C.
"""

import os

import numpy as np
import torch
from safetensors.torch import save_file
from transformers import Dinov2Config, Dinov2Model

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "crates", "models", "tests", "fixtures", "dinov2")
MEAN = torch.tensor((0.485, 0.456, 0.406)).view(1, 3, 1, 1)
STD = torch.tensor((0.229, 0.224, 0.225)).view(1, 3, 1, 1)


def features(model, img_hwc, patch):
    h, w, _ = img_hwc.shape
    gh, gw = max(1, round(h / patch)), max(1, round(w / patch))
    x = torch.from_numpy(img_hwc).permute(2, 0, 1)[None]
    x = torch.nn.functional.interpolate(x, size=(gh * patch, gw * patch), mode="bicubic", align_corners=False)
    x = (x - MEAN) / STD
    out = model(pixel_values=x).last_hidden_state
    grid = out[:, 1:].reshape(1, gh, gw, -1).permute(0, 3, 1, 2)
    up = torch.nn.functional.interpolate(grid, size=(h, w), mode="bilinear", align_corners=False)
    return out[0], up[0].permute(1, 2, 0).contiguous()


def main():
    torch.manual_seed(2)
    cfg = Dinov2Config(hidden_size=32, num_hidden_layers=2, num_attention_heads=4, mlp_ratio=2,
                       image_size=56, patch_size=14, layerscale_value=1.0)
    model = Dinov2Model(cfg).eval()
    with torch.no_grad():
        for layer in model.encoder.layer:  # make the layer scales non-trivial
            layer.layer_scale1.lambda1.uniform_(0.5, 1.5)
            layer.layer_scale2.lambda1.uniform_(0.5, 1.5)
    model.save_pretrained(ROOT)
    rng = np.random.default_rng(2)
    out = {}
    # 56x56: the native 4x4 grid (no interpolation); 45x75: a 3x5 grid (bicubic position grid).
    for i, (h, w) in enumerate([(56, 56), (45, 75)]):
        img = rng.random((h, w, 3)).astype(np.float32)
        with torch.no_grad():
            hidden, up = features(model, img, 14)
        out[f"image{i}"] = torch.from_numpy(img)
        out[f"hidden{i}"] = hidden
        out[f"features{i}.rows4"] = up[::4].contiguous()  # every 4th row keeps the fixture small
    save_file(out, os.path.join(ROOT, "reference.safetensors"))
    print("dinov2: written")


if __name__ == "__main__":
    main()

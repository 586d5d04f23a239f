#!/usr/bin/env python3
"""Reference fixtures for the CLIPSeg text-grounded segmenter (crates/models/src/clipseg.rs).

Run with a Python that has torch and transformers 5:

    python tools/model_fixtures_clipseg.py

Writes, under crates/models/tests/fixtures/clipseg/:
  simple/     a tiny random CLIPSegForImageSegmentation with the one-step transposed
              convolution (patch 8, 32 x 32 native input, legacy eos_token_id = 2 pooling,
              FiLM at decoder step 0, the last vision layer unused by the decoder)
  complex/    the same with use_complex_transposed_convolution (patch 16, 48 x 48 native
              input, eos_token_id pooling, FiLM at decoder step 1, three extracted layers)
  reference.safetensors  inputs and reference outputs of both, keys prefixed by the folder

Each folder holds config.json and model.safetensors (save_pretrained: the layout of
CIDAS/clipseg-rd64-refined, `clip.` and `decoder.` prefixes) and a preprocessor_config.json
whose square size differs from the config's image_size, as 352 differs from 224 in the
real checkpoint, so the processor path runs with interpolated position embeddings.

Per variant the reference holds:
  pixels, input_ids            a batch of two normalised inputs at the native size and two prompts
                               (inputs stored in f16, the reference run on the same rounded values)
  conditional_embeddings       the projected text features that condition the decoder (FiLM)
  decoder_features             the decoder output before the transposed convolution
  logits                       CLIPSegForImageSegmentation logits
  big.pixels, big.logits, big.decoder_features   one input (the first prompt) at another square
                                                 size (position embeddings interpolated)
  image, prompt_ids, probabilities               the segment() pipeline: an H x W x 3 image in
      [0, 1] resized to the processor size (bilinear with antialiasing, what torchvision's
      resize does for ViTImageProcessor), ImageNet mean / std, the model, sigmoid, the
      probabilities resized back to H x W the same way.
Token ids are given directly (vocabulary of 500): the tokenizer is proven by its own fixture.
"""

import os

import numpy as np
import torch
import torch.nn.functional as F
from safetensors.torch import save_file
from transformers import CLIPSegConfig, CLIPSegForImageSegmentation

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "crates", "models", "tests", "fixtures", "clipseg")
MEAN = (0.485, 0.456, 0.406)
STD = (0.229, 0.224, 0.225)

VARIANTS = {
    "simple": dict(
        complex=False, patch=8, image_size=32, big=48, processor=48, layers=3, extract=[0, 1],
        conditional_layer=0, eos_token_id=2, image_hw=(50, 70),
    ),
    "complex": dict(
        complex=True, patch=16, image_size=48, big=64, processor=80, layers=3, extract=[0, 1, 2],
        conditional_layer=1, eos_token_id=499, image_hw=(29, 37),
    ),
}


def config(v):
    return CLIPSegConfig(
        text_config=dict(vocab_size=500, hidden_size=16, intermediate_size=32, num_hidden_layers=2,
                         num_attention_heads=2, max_position_embeddings=16, eos_token_id=v["eos_token_id"],
                         bos_token_id=0, pad_token_id=1),
        vision_config=dict(hidden_size=24, intermediate_size=48, num_hidden_layers=v["layers"],
                           num_attention_heads=4, image_size=v["image_size"], patch_size=v["patch"]),
        projection_dim=24, extract_layers=v["extract"], reduce_dim=16, decoder_num_attention_heads=2,
        decoder_intermediate_size=32, conditional_layer=v["conditional_layer"],
        use_complex_transposed_convolution=v["complex"],
    )


def randomize_norms_and_biases(model):
    """Default init leaves layer norms at (1, 0) and many biases at 0; randomise them so a
    missing bias or a swapped norm cannot go unnoticed."""
    with torch.no_grad():
        for name, p in model.named_parameters():
            if name.endswith(".bias"):
                p.uniform_(-0.2, 0.2)
            elif "layer_norm" in name or "layrnorm" in name or "layernorm" in name:
                p.uniform_(0.7, 1.3)


def run(model, pixels, ids):
    """Logits, conditional embeddings and the decoder output before the transposed convolution."""
    captured = {}

    def keep_input(_module, inputs):
        captured["features"] = inputs[0].detach().clone()

    hook = model.decoder.transposed_convolution.register_forward_pre_hook(keep_input)
    with torch.no_grad():
        out = model(input_ids=ids, pixel_values=pixels)
    hook.remove()
    return out.logits, out.conditional_embeddings, captured["features"]


def check_hidden_state_indexing(model, pixels):
    """extract_layers index the vision hidden states after the embeddings: entry i + 1 is the
    output of encoder layer i (the Rust port takes layer outputs directly)."""
    outputs = []

    def keep_output(_module, _inputs, output):
        outputs.append(output[0] if isinstance(output, tuple) else output)

    hooks = [layer.register_forward_hook(keep_output) for layer in model.clip.vision_model.encoder.layers]
    with torch.no_grad():
        hs = model.clip.vision_model(pixel_values=pixels, output_hidden_states=True).hidden_states
    for h in hooks:
        h.remove()
    for i, o in enumerate(outputs):
        assert torch.equal(hs[i + 1], o), f"hidden_states[{i + 1}] is not the output of layer {i}"


def resize(x_nchw, h, w):
    """torchvision's tensor resize (bilinear, antialias=True), as ViTImageProcessor uses it."""
    return F.interpolate(x_nchw, size=(h, w), mode="bilinear", align_corners=False, antialias=True)


def segment(model, image_hwc, ids, size):
    h, w, _ = image_hwc.shape
    x = torch.from_numpy(image_hwc).permute(2, 0, 1)[None]
    x = resize(x, size, size)
    x = (x - torch.tensor(MEAN).view(1, 3, 1, 1)) / torch.tensor(STD).view(1, 3, 1, 1)
    logits, _, _ = run(model, x, ids)
    return resize(torch.sigmoid(logits)[:, None], h, w)[0, 0]


def save_processor(folder, size):
    import json

    with open(os.path.join(folder, "preprocessor_config.json"), "w") as f:
        json.dump({"do_normalize": True, "do_resize": True, "image_mean": list(MEAN), "image_std": list(STD),
                   "image_processor_type": "ViTImageProcessor", "processor_class": "CLIPSegProcessor",
                   "resample": 2, "size": size}, f, indent=2)


def prompts(eos, rng):
    """Two prompts of length 9, the end token at different places (padding after it)."""
    ids = torch.from_numpy(rng.integers(3, 499, (2, 9)))
    ids[:, 0] = 0
    ids[0, 5:] = eos if eos != 2 else 499  # legacy configs pool at the largest id
    ids[1, 8] = eos if eos != 2 else 499
    return ids


def variant(name, v, seed, out):
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = CLIPSegForImageSegmentation(config(v)).eval()
    randomize_norms_and_biases(model)
    folder = os.path.join(ROOT, name)
    model.save_pretrained(folder)
    save_processor(folder, v["processor"])
    ids = prompts(v["eos_token_id"], rng)
    out[f"{name}.input_ids"] = ids.to(torch.int32)
    # The native size with both prompts, then another size (interpolated positions) with the first.
    for key, batch, size in (("", 2, v["image_size"]), ("big.", 1, v["big"])):
        # Inputs are stored in f16 (half the bytes); the reference runs on the same rounded values.
        pixels = torch.from_numpy(rng.standard_normal((batch, 3, size, size)).astype(np.float16)).float()
        check_hidden_state_indexing(model, pixels)
        logits, cond, features = run(model, pixels, ids[:batch])
        out[f"{name}.{key}pixels"] = pixels.half()
        out[f"{name}.{key}logits"] = logits
        out[f"{name}.{key}decoder_features"] = features
        if not key:
            out[f"{name}.conditional_embeddings"] = cond
        print(f"{name}: {size}x{size} -> logits {tuple(logits.shape)}")
    h, w = v["image_hw"]
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    image = np.stack([np.sin(9 * xx) * 0.5 + 0.5, yy, rng.random((h, w))], -1).astype(np.float16).astype(np.float32)
    prompt = ids[1:2]
    out[f"{name}.image"] = torch.from_numpy(image).half()
    out[f"{name}.prompt_ids"] = prompt.to(torch.int32)
    out[f"{name}.probabilities"] = segment(model, image, prompt, v["processor"])


def main():
    torch.set_num_threads(2)
    out = {}
    for seed, (name, v) in enumerate(VARIANTS.items()):
        variant(name, v, 40 + seed, out)
    save_file({k: t.contiguous() for k, t in out.items()}, os.path.join(ROOT, "reference.safetensors"))
    print("clipseg: written")


if __name__ == "__main__":
    main()

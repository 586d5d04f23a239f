#!/usr/bin/env python3
"""Reference fixtures for SAM, the promptable segmenter that sharpens a text mask
(crates/models/src/sam.rs).

Run with a Python that has torch and transformers 5:

    python tools/model_fixtures_sam.py

Writes, under crates/models/tests/fixtures/sam/:
  tiny/                  a tiny random transformers `SamModel` (save_pretrained: the layout of
                         facebook/sam-vit-base and of SlimSAM): 64 x 64 input, patch 8, windows
                         of 3 on an 8 x 8 grid (so the windows are padded), one global layer,
                         relative and absolute positions, a two-layer two-way decoder
  reference.safetensors  inputs and outputs, keys:
    pixels                          a batch of two normalised 64 x 64 inputs (stored in f16, the
                                    reference run on the rounded values)
    image_embeddings                the vision encoder's output after the neck
    points, labels                  one positive and one negative point per image (input pixels)
    boxes                           one box per image (x1, y1, x2, y2, input pixels)
    points.masks, points.iou        multimask output (3 masks) for the points alone
    box.masks, box.iou              single-mask output for a box and one positive point
    image, box_xyxy, point_xy       the segment() pipeline on an H x W x 3 image in [0, 1]:
      probabilities                 resize the long side to 64 (bilinear, antialias), ImageNet
                                    mean / std, pad right and bottom with zeros, the box and
                                    the point scaled as SamProcessor scales them, single-mask
                                    output, logits resized bilinearly to the padded input,
                                    cropped, resized to H x W, sigmoid.
"""

import os

import numpy as np
import torch
import torch.nn.functional as F
from safetensors.torch import save_file
from transformers import SamConfig, SamModel

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "crates", "models", "tests", "fixtures", "sam")
MEAN = (0.485, 0.456, 0.406)
STD = (0.229, 0.224, 0.225)
SIZE = 64


def config():
    return SamConfig(
        vision_config=dict(hidden_size=24, output_channels=16, num_hidden_layers=3, num_attention_heads=2,
                           image_size=SIZE, patch_size=8, window_size=3, global_attn_indexes=[1],
                           num_pos_feats=8, mlp_dim=40),
        prompt_encoder_config=dict(hidden_size=16, image_size=SIZE, patch_size=8, mask_input_channels=8),
        mask_decoder_config=dict(hidden_size=16, mlp_dim=24, num_hidden_layers=2, num_attention_heads=2,
                                 attention_downsample_rate=2, iou_head_depth=3, iou_head_hidden_dim=12),
    )


def randomize(model):
    """Draw every parameter at a scale where each term shows in the output. transformers'
    init leaves the vision tower's weights at 1e-10 (its `initializer_range`), layer norms at
    (1, 0), biases and positions at 0: a missing term would go unnoticed."""
    embeddings = ("iou_token", "mask_tokens", "point_embed", "not_a_point_embed", "no_mask_embed",
                  "positional_embedding")
    with torch.no_grad():
        for name, p in model.named_parameters():
            if name.endswith(".bias"):
                p.uniform_(-0.2, 0.2)
            elif "layer_norm" in name:
                p.uniform_(0.7, 1.3)
            elif "rel_pos" in name or name.endswith("pos_embed"):
                p.normal_(0.0, 0.3)
            elif any(e in name for e in embeddings):
                p.normal_(0.0, 1.0)
            elif p.dim() >= 2:
                fan_in = p.shape[0] if "upscale_conv" in name else p[0].numel()  # transposed: [in, out, k, k]
                p.normal_(0.0, fan_in ** -0.5)


def preprocess(image_hwc):
    """SamImageProcessor on a float image: long side to SIZE, normalise, pad bottom / right."""
    h, w, _ = image_hwc.shape
    scale = SIZE / max(h, w)
    nh, nw = int(h * scale + 0.5), int(w * scale + 0.5)
    x = torch.from_numpy(image_hwc).permute(2, 0, 1)[None]
    x = F.interpolate(x, size=(nh, nw), mode="bilinear", align_corners=False, antialias=True)
    x = (x - torch.tensor(MEAN).view(1, 3, 1, 1)) / torch.tensor(STD).view(1, 3, 1, 1)
    return F.pad(x, (0, SIZE - nw, 0, SIZE - nh)), (nh, nw)


def segment(model, image_hwc, box_xyxy, point_xy):
    h, w, _ = image_hwc.shape
    pixels, (nh, nw) = preprocess(image_hwc)
    sx, sy = nw / w, nh / h  # SamProcessor's coordinate scaling
    box = torch.tensor([[[box_xyxy[0] * sx, box_xyxy[1] * sy, box_xyxy[2] * sx, box_xyxy[3] * sy]]])
    point = torch.tensor([[[[point_xy[0] * sx, point_xy[1] * sy]]]])
    with torch.no_grad():
        out = model(pixel_values=pixels, input_points=point, input_labels=torch.ones(1, 1, 1, dtype=torch.long),
                    input_boxes=box, multimask_output=False)
    logits = out.pred_masks[0, 0]  # (1, 16, 16)
    logits = F.interpolate(logits[None], size=(SIZE, SIZE), mode="bilinear", align_corners=False)
    logits = logits[..., :nh, :nw]
    logits = F.interpolate(logits, size=(h, w), mode="bilinear", align_corners=False)
    return torch.sigmoid(logits)[0, 0]


def main():
    torch.set_num_threads(2)
    torch.manual_seed(7)
    rng = np.random.default_rng(7)
    model = SamModel(config()).eval()
    randomize(model)
    os.makedirs(ROOT, exist_ok=True)
    model.save_pretrained(os.path.join(ROOT, "tiny"))
    out = {}
    pixels = torch.from_numpy(rng.standard_normal((2, 3, SIZE, SIZE)).astype(np.float16)).float()
    points = torch.tensor([[[[20.0, 30.0], [50.0, 10.0]]], [[[5.0, 60.0], [33.0, 33.0]]]])
    labels = torch.tensor([[[1, 0]], [[1, 0]]])
    boxes = torch.tensor([[[10.0, 12.0, 40.0, 50.0]], [[0.0, 3.0, 63.0, 30.0]]])
    with torch.no_grad():
        embeddings = model.get_image_embeddings(pixels)
        by_points = model(image_embeddings=embeddings, input_points=points, input_labels=labels,
                          multimask_output=True)
        by_box = model(image_embeddings=embeddings, input_points=points[:, :, :1], input_labels=labels[:, :, :1],
                       input_boxes=boxes, multimask_output=False)
    out["pixels"] = pixels.half()
    out["image_embeddings"] = embeddings
    out["points"], out["labels"], out["boxes"] = points, labels.to(torch.int32), boxes
    out["points.masks"], out["points.iou"] = by_points.pred_masks, by_points.iou_scores
    out["box.masks"], out["box.iou"] = by_box.pred_masks, by_box.iou_scores
    h, w = 37, 50
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    image = np.stack([np.sin(9 * xx) * 0.5 + 0.5, yy, rng.random((h, w))], -1).astype(np.float16).astype(np.float32)
    box_xyxy, point_xy = (8.0, 5.0, 30.0, 28.0), (19.0, 16.0)
    out["image"] = torch.from_numpy(image).half()
    out["box_xyxy"] = torch.tensor(box_xyxy)
    out["point_xy"] = torch.tensor(point_xy)
    out["probabilities"] = segment(model, image, box_xyxy, point_xy)
    save_file({k: t.contiguous() for k, t in out.items()}, os.path.join(ROOT, "reference.safetensors"))
    print("sam: masks", tuple(by_points.pred_masks.shape), tuple(by_box.pred_masks.shape), "written")


if __name__ == "__main__":
    main()

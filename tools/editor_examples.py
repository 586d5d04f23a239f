#!/usr/bin/env python3
"""The diffusers editor examples of crates/python/examples run end to end on tiny random
pipelines (issue #41): FluxKontextEditor, QwenImageEditor and InstructPix2PixEditor, each
around a pipeline of the real class (FluxKontextPipeline, QwenImageEditPipeline, and
ip2p_editor.py's own UNet / VAE / CLIP / DDIM loading) with a few layers of 8-64
channels and random weights (`torch.manual_seed`), so the plumbing runs through the
real library code without any download: no weights exist here, and the tokenizers are
written from a hand-made byte-level vocabulary.

For each example, on the built-in "tabletop" scene (quick) with 4 edit views:

- A: `transsplat.edit(..., editor, out=...)` writes the output folder with its PLY; the
  editor gets the 4 views in one call and (Flux, Qwen) makes one pipeline call with a
  batch of 4; every returned image is (H, W, 3) float32 in [0, 1] at the render's size;
- B: the same edit again gives the same images bit for bit and the same PLY byte for byte;
- C: the same edit with the views reversed and split in shards of 3 and 1 (as a Ray
  editor actor gets them) gives every view the image it had in A (float tolerance);
- another seed changes the edit; `max_batch=2` splits the 4 views into two pipeline
  calls without changing an image; the editor built from a weights folder (the tiny
  pipeline saved with `save_pretrained`) gives A's image; the example's own `main()`
  (its command line) runs and writes its PLY.

Not part of CI (it needs torch, diffusers and transformers; a few minutes on 2 cores):

    python3 -m venv /work/venv-editors
    /work/venv-editors/bin/pip install torch torchvision diffusers transformers accelerate \\
        sentencepiece tokenizers protobuf numpy pillow target/wheels/transsplat-*.whl  # the built wheel
    nice -n 10 /work/venv-editors/bin/python tools/editor_examples.py [--only flux,qwen,ip2p] [--keep DIR]

Prints one line per check, a summary table and "N passed, N failed"; exits 1 on any failure.
"""

import os

os.environ.setdefault("HF_HUB_OFFLINE", "1")  # everything is built here; nothing may be fetched
os.environ.setdefault("TRANSFORMERS_VERBOSITY", "error")
os.environ.setdefault("DIFFUSERS_VERBOSITY", "error")

import argparse
import glob
import json
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time

import diffusers
import numpy as np
import torch
import transformers

ROOT = pathlib.Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "crates" / "python" / "examples"
sys.path.insert(0, str(EXAMPLES))

import transsplat  # noqa: E402
from diffusers import (  # noqa: E402
    AutoencoderKL,
    AutoencoderKLQwenImage,
    DDIMScheduler,
    FlowMatchEulerDiscreteScheduler,
    FluxKontextPipeline,
    FluxTransformer2DModel,
    QwenImageEditPipeline,
    QwenImageTransformer2DModel,
    UNet2DConditionModel,
)
from tokenizers import Tokenizer, decoders, models, pre_tokenizers, processors  # noqa: E402
from transformers import (  # noqa: E402
    CLIPTextConfig,
    CLIPTextModel,
    CLIPTokenizer,
    Qwen2_5_VLConfig,
    Qwen2_5_VLForConditionalGeneration,
    Qwen2Tokenizer,
    Qwen2VLImageProcessor,
    Qwen2VLProcessor,
    Qwen2VLVideoProcessor,
    T5Config,
    T5EncoderModel,
    T5TokenizerFast,
)

from diffusers.utils import logging as diffusers_logging  # noqa: E402
from transformers.utils import logging as transformers_logging  # noqa: E402

from flux_kontext_editor import FluxKontextEditor  # noqa: E402
from ip2p_editor import InstructPix2PixEditor  # noqa: E402
from qwen_image_edit_editor import QwenImageEditor  # noqa: E402

diffusers_logging.disable_progress_bar()
transformers_logging.disable_progress_bar()

PROMPT = "make the ball blue"
VIEWS = 4          # edit views per run
LIFT_STEPS = 30    # optimisation steps of each lift
SHARD_TOL = 1e-4   # a view edited in another shard: same image up to float reordering

# ---------------------------------------------------------------------------------------
# Tiny tokenizers, written to files as a hub folder would hold them


def byte_alphabet():
    """The 256 characters that byte-level BPE (CLIP, Qwen2) writes bytes 0..255 as: the
    printable Latin-1 bytes stand for themselves, the others are moved to U+0100 on."""
    direct = [*range(33, 127), *range(161, 173), *range(174, 256)]
    return [chr(b) for b in direct] + [chr(256 + i) for i in range(256 - len(direct))]


def write_bpe(folder, specials, end_of_word=None):
    """vocab.json (the specials, then every byte character, and with `end_of_word` each
    one again as a word's last symbol, as CLIP's BPE needs) and an empty merges.txt:
    every byte is one token."""
    folder.mkdir(parents=True, exist_ok=True)
    vocab = {s: i for i, s in enumerate(specials)}
    for c in byte_alphabet():
        vocab.setdefault(c, len(vocab))
    if end_of_word:
        for c in byte_alphabet():
            vocab.setdefault(c + end_of_word, len(vocab))
    (folder / "vocab.json").write_text(json.dumps(vocab), encoding="utf-8")
    (folder / "merges.txt").write_text("#version: 0.2\n", encoding="utf-8")
    return folder


def clip_tokenizer(tmp):
    folder = write_bpe(tmp / "clip-tokenizer", ["<|startoftext|>", "<|endoftext|>"], end_of_word="</w>")
    return CLIPTokenizer.from_pretrained(folder, model_max_length=77)


def t5_tokenizer(tmp):
    """A unigram tokenizer over lower-case letters, digits and punctuation, each alone
    or opening a word (▁), with T5's pad / eos / unk ids 0 / 1 / 2."""
    pieces = [("<pad>", 0.0), ("</s>", 0.0), ("<unk>", 0.0), ("\u2581", -2.0)]
    for c in "abcdefghijklmnopqrstuvwxyz0123456789.,!?'-":
        pieces += [(c, -3.0), ("\u2581" + c, -3.5)]
    tok = Tokenizer(models.Unigram(pieces, unk_id=2))
    tok.pre_tokenizer = pre_tokenizers.Metaspace()
    tok.decoder = decoders.Metaspace()
    tok.post_processor = processors.TemplateProcessing(single="$A </s>", special_tokens=[("</s>", 1)])
    folder = tmp / "t5-tokenizer"
    folder.mkdir(parents=True, exist_ok=True)
    tok.save(str(folder / "tokenizer.json"))
    return T5TokenizerFast.from_pretrained(folder, extra_ids=0)


QWEN_SPECIALS = ["<|endoftext|>", "<|im_start|>", "<|im_end|>", "<|vision_start|>", "<|vision_end|>",
                 "<|image_pad|>", "<|video_pad|>"]


def qwen_tokenizer(tmp):
    folder = write_bpe(tmp / "qwen-tokenizer", QWEN_SPECIALS)
    return Qwen2Tokenizer.from_pretrained(folder, additional_special_tokens=QWEN_SPECIALS[1:])


def tiny_clip_text_encoder(tokenizer):
    return CLIPTextModel(CLIPTextConfig(
        vocab_size=len(tokenizer), hidden_size=32, intermediate_size=37, num_hidden_layers=2, num_attention_heads=4,
        max_position_embeddings=77, projection_dim=32, bos_token_id=tokenizer.bos_token_id,
        eos_token_id=tokenizer.eos_token_id, pad_token_id=tokenizer.pad_token_id))


def eval_mode(pipe):
    """from_pretrained returns modules in eval mode; modules built here start in training
    mode, where T5's dropout would make every call random."""
    for component in pipe.components.values():
        if isinstance(component, torch.nn.Module):
            component.eval()
    pipe.set_progress_bar_config(disable=True)
    return pipe


# ---------------------------------------------------------------------------------------
# Tiny pipelines


def tiny_flux_kontext(tmp):
    """FluxKontextPipeline with 1 double + 1 single block of 2 heads × 16, a 3-level VAE
    (4× down, 4 latent channels), a 2-layer CLIP and a 2-layer T5 of width 32."""
    torch.manual_seed(0)
    transformer = FluxTransformer2DModel(
        patch_size=1, in_channels=16, num_layers=1, num_single_layers=1, attention_head_dim=16,
        num_attention_heads=2, joint_attention_dim=32, pooled_projection_dim=32, guidance_embeds=True,
        axes_dims_rope=[4, 4, 8])
    vae = AutoencoderKL(
        in_channels=3, out_channels=3, down_block_types=["DownEncoderBlock2D"] * 3,
        up_block_types=["UpDecoderBlock2D"] * 3, block_out_channels=(8, 16, 16), layers_per_block=1,
        latent_channels=4, norm_num_groups=4, use_quant_conv=False, use_post_quant_conv=False,
        shift_factor=0.1, scaling_factor=1.0)
    tokenizer, tokenizer_2 = clip_tokenizer(tmp), t5_tokenizer(tmp)
    text_encoder = tiny_clip_text_encoder(tokenizer)
    text_encoder_2 = T5EncoderModel(T5Config(
        vocab_size=len(tokenizer_2), d_model=32, d_kv=8, d_ff=37, num_layers=2, num_heads=4,
        decoder_start_token_id=0, pad_token_id=tokenizer_2.pad_token_id, eos_token_id=tokenizer_2.eos_token_id))
    return eval_mode(FluxKontextPipeline(
        scheduler=FlowMatchEulerDiscreteScheduler(), vae=vae, text_encoder=text_encoder, tokenizer=tokenizer,
        text_encoder_2=text_encoder_2, tokenizer_2=tokenizer_2, transformer=transformer,
        image_encoder=None, feature_extractor=None))


def tiny_qwen_image_edit(tmp):
    """QwenImageEditPipeline with a 2-block transformer of 2 heads × 16, a 5-level causal
    VAE of width 8 (16× down, so the ~1024² input image the pipeline always encodes stays
    cheap), a 2-layer Qwen2.5-VL of width 16 whose image processor keeps at most 56²
    pixels."""
    torch.manual_seed(0)
    transformer = QwenImageTransformer2DModel(
        patch_size=2, in_channels=16, out_channels=4, num_layers=2, attention_head_dim=16, num_attention_heads=2,
        joint_attention_dim=16, guidance_embeds=False, axes_dims_rope=(8, 4, 4))
    vae = AutoencoderKLQwenImage(
        base_dim=8, z_dim=4, dim_mult=[1, 1, 1, 1, 1], num_res_blocks=1, temperal_downsample=[False, False, True, True],
        latents_mean=[0.0] * 4, latents_std=[1.0] * 4)
    tokenizer = qwen_tokenizer(tmp)
    ids = {name: tokenizer.convert_tokens_to_ids(tok) for name, tok in (
        ("image", "<|image_pad|>"), ("video", "<|video_pad|>"), ("start", "<|vision_start|>"),
        ("end", "<|vision_end|>"), ("eos", "<|endoftext|>"))}
    config = Qwen2_5_VLConfig(
        text_config={
            "vocab_size": len(tokenizer), "hidden_size": 16, "intermediate_size": 16, "num_hidden_layers": 2,
            "num_attention_heads": 2, "num_key_value_heads": 2, "rope_theta": 1e6,
            "rope_scaling": {"type": "default", "rope_type": "default", "mrope_section": [1, 1, 2]},
            "bos_token_id": ids["eos"], "eos_token_id": ids["eos"]},
        vision_config={"depth": 2, "hidden_size": 16, "intermediate_size": 16, "num_heads": 2, "out_hidden_size": 16},
        image_token_id=ids["image"], video_token_id=ids["video"], vision_start_token_id=ids["start"],
        vision_end_token_id=ids["end"])
    text_encoder = Qwen2_5_VLForConditionalGeneration(config)
    processor = Qwen2VLProcessor(
        image_processor=Qwen2VLImageProcessor(min_pixels=28 * 28, max_pixels=56 * 56), tokenizer=tokenizer,
        video_processor=Qwen2VLVideoProcessor())
    return eval_mode(QwenImageEditPipeline(
        scheduler=FlowMatchEulerDiscreteScheduler(), vae=vae, text_encoder=text_encoder, tokenizer=tokenizer,
        processor=processor, transformer=transformer))


def tiny_ip2p_folder(tmp):
    """The folder layout ip2p_editor.py loads (unet/, vae/, text_encoder/, tokenizer/,
    scheduler/) with an 8-channel-input UNet of 2 levels (16, 32), a 2-level VAE and
    the 2-layer CLIP."""
    folder = tmp / "ip2p-weights"
    torch.manual_seed(0)
    UNet2DConditionModel(
        sample_size=16, in_channels=8, out_channels=4, layers_per_block=1, block_out_channels=(16, 32),
        down_block_types=("CrossAttnDownBlock2D", "DownBlock2D"), up_block_types=("UpBlock2D", "CrossAttnUpBlock2D"),
        cross_attention_dim=32, norm_num_groups=8, attention_head_dim=4).save_pretrained(folder / "unet")
    AutoencoderKL(
        in_channels=3, out_channels=3, down_block_types=["DownEncoderBlock2D"] * 2,
        up_block_types=["UpDecoderBlock2D"] * 2, block_out_channels=(8, 16), layers_per_block=1, latent_channels=4,
        norm_num_groups=4, scaling_factor=0.18215).save_pretrained(folder / "vae")
    tokenizer = clip_tokenizer(tmp)
    tokenizer.save_pretrained(folder / "tokenizer")
    tiny_clip_text_encoder(tokenizer).save_pretrained(folder / "text_encoder")
    DDIMScheduler(beta_schedule="scaled_linear", beta_start=0.00085, beta_end=0.012, clip_sample=False,
                  set_alpha_to_one=False).save_pretrained(folder / "scheduler")
    return folder


# ---------------------------------------------------------------------------------------
# What the checks watch


class CountedPipeline:
    """The pipeline, recording the batch size of each call (the editors call it with
    keywords only)."""

    def __init__(self, pipe):
        self.pipe, self.batches = pipe, []

    def __call__(self, **kwargs):
        self.batches.append(len(kwargs["image"]))
        return self.pipe(**kwargs)

    def __getattr__(self, name):
        return getattr(self.pipe, name)


class Recorded:
    """The editor as transsplat sees it: records the view indices of each editor call and
    what came back per view. With `shard`, the views are reversed and split into shards
    of that many, one editor call each, as a Ray editor actor receives them."""

    def __init__(self, editor, shard=None):
        self.editor, self.shard = editor, shard
        self.calls, self.images, self.views, self.bad = [], {}, {}, []

    def __call__(self, views, prompt):
        order = list(reversed(views)) if self.shard else list(views)
        step = self.shard or len(order)
        for s in range(0, len(order), step):
            shard = order[s:s + step]
            self.calls.append([v.index for v in shard])
            for v, image in zip(shard, self.editor(shard, prompt)):
                self.views[v.index], self.images[v.index] = v, image
                a = np.asarray(image)
                if a.shape != (v.height, v.width, 3) or a.dtype != np.float32 or not np.isfinite(a).all() \
                        or a.min() < 0 or a.max() > 1:
                    self.bad.append(f"view {v.index}: {a.shape} {a.dtype} in [{a.min():.3g}, {a.max():.3g}]")
        return [self.images[v.index] for v in views]


class Checks:
    def __init__(self):
        self.passed, self.failed = 0, []

    def __call__(self, name, ok, detail=""):
        print(f"  {'ok  ' if ok else 'FAIL'} {name}{': ' + detail if detail else ''}", flush=True)
        if ok:
            self.passed += 1
        else:
            self.failed.append(name)
        return ok


def ply_of(out):
    found = sorted(glob.glob(os.path.join(out, "point_cloud", "iteration_*", "point_cloud.ply")))
    return found[-1] if found else None


def max_diff(a, b, keys):
    return max(float(np.abs(np.asarray(a[k], np.float64) - np.asarray(b[k], np.float64)).max()) for k in keys)


def exercise(name, editor, counted, scene, work, check, weights_editor=None, main_cmd=None):
    """The checks of one example (module docstring); returns its summary row."""
    print(f"{name}:", flush=True)
    row = {"example": name}
    t0 = time.perf_counter()

    def edit(recorder, out=None):
        if counted is not None:
            counted.batches.clear()
        r = transsplat.edit(scene, None, PROMPT, recorder, out=None if out is None else str(out),
                            steps=LIFT_STEPS, views=VIEWS, progress=False)
        return r, list(counted.batches) if counted is not None else None

    a = Recorded(editor)
    r, batches_a = edit(a, work / f"{name}-a")
    ply_a = ply_of(r["out"]) if r["out"] else None
    check(f"{name}: the output folder holds the PLY", ply_a is not None and os.path.getsize(ply_a) > 0, str(ply_a))
    check(f"{name}: one editor call with all {VIEWS} views", [len(c) for c in a.calls] == [VIEWS], str(a.calls))
    if counted is not None:
        check(f"{name}: one pipeline call, a batch of {VIEWS}", batches_a == [VIEWS], str(batches_a))
    check(f"{name}: images at the render's size, float32 in [0, 1]", not a.bad and len(a.images) == VIEWS,
          "; ".join(a.bad) or f"{len(a.images)} views, e.g. {next(iter(a.images.values())).shape}")
    row["pipeline calls (A)"] = str(batches_a) if counted is not None else "per view"

    b = Recorded(editor)
    r_b, _ = edit(b, work / f"{name}-b")
    same = a.images.keys() == b.images.keys() and all(np.array_equal(a.images[k], b.images[k]) for k in a.images)
    check(f"{name}: the same seed gives the same images", same)
    ply_b = ply_of(r_b["out"]) if r_b["out"] else None
    same_ply = ply_a is not None and ply_b is not None and \
        pathlib.Path(ply_a).read_bytes() == pathlib.Path(ply_b).read_bytes()
    check(f"{name}: ... and the same PLY byte for byte", same_ply)
    row["A = B"] = "bitwise" if same else "differs"

    c = Recorded(editor, shard=3)
    _, batches_c = edit(c)
    diff = max_diff(a.images, c.images, a.images) if a.images.keys() == c.images.keys() else float("inf")
    check(f"{name}: shards {c.calls} give each view its image of A", diff <= SHARD_TOL,
          f"max |A - C| = {diff:.2e}" + (f" (pipeline batches {batches_c})" if counted is not None else ""))
    if counted is not None:
        check(f"{name}: one pipeline call per shard", batches_c == [len(s) for s in c.calls], str(batches_c))
    row["max |A - C| (shards 3+1)"] = f"{diff:.1e}"

    first = min(a.views)
    view = a.views[first]
    editor.seed = 1
    other = editor([view], PROMPT)[0]
    editor.seed = 0
    moved = float(np.abs(other - a.images[first]).max())
    check(f"{name}: another seed gives another edit", moved > 1e-3, f"max change {moved:.3f}")

    if counted is not None:
        counted.batches.clear()
        editor.max_batch = 2
        chunked = editor([a.views[k] for k in sorted(a.views)], PROMPT)
        editor.max_batch = None
        d = max(float(np.abs(x - a.images[k]).max()) for k, x in zip(sorted(a.views), chunked))
        check(f"{name}: max_batch=2 makes calls of 2 and the same images", counted.batches == [2, 2] and d <= SHARD_TOL,
              f"pipeline batches {counted.batches}, max diff {d:.2e}")

    if weights_editor is not None:
        loaded = weights_editor()([view], PROMPT)[0]
        d = float(np.abs(loaded - a.images[first]).max())
        check(f"{name}: the editor loaded from a weights folder gives A's image", d <= SHARD_TOL, f"max diff {d:.2e}")
        row["weights folder"] = f"{d:.1e}"
    if main_cmd is not None:
        out = work / f"{name}-main"
        p = subprocess.run([sys.executable, *main_cmd, "--out", str(out)], cwd=EXAMPLES, capture_output=True,
                           text=True)
        ok = p.returncode == 0 and ply_of(str(out)) is not None
        check(f"{name}: the example's command line writes its PLY", ok,
              p.stdout.strip().splitlines()[-1] if ok and p.stdout.strip() else (p.stderr.strip()[-800:] or "no PLY"))
        row["main()"] = "ok" if ok else "FAIL"
    row["time"] = f"{time.perf_counter() - t0:.0f} s"
    return row


def guarded(name, check, run):
    """One example's checks; an exception is its failure, and the other examples still run."""
    try:
        return run()
    except Exception:  # noqa: BLE001 - reported, and the exit status says it
        import traceback

        traceback.print_exc()
        check(f"{name}: ran to the end", False, "raised (traceback above)")
        return {"example": name, "time": "raised"}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", default="flux,qwen,ip2p", help="comma-separated subset of flux, qwen, ip2p")
    ap.add_argument("--keep", help="work in this (new or empty) folder and keep it")
    args = ap.parse_args()
    only = set(args.only.split(","))
    work = pathlib.Path(args.keep or tempfile.mkdtemp(prefix="editor-examples-"))
    work.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    check = Checks()
    rows = []
    try:
        scene = transsplat.builtin_scene("tabletop", str(work / "scene"), quick=True)
        cli = ["--scene", scene, "--prompt", PROMPT, "--steps", "10"]

        def dit(name, editor_class, build, size):
            """A DiT example around its tiny pipeline, saved as a weights folder too."""
            weights = work / f"{name}-weights"
            pipe = build(work)
            pipe.save_pretrained(weights)
            counted, settings = CountedPipeline(pipe), dict(steps=2, size=size)
            return exercise(
                name, editor_class.from_pipeline(counted, **settings), counted, scene, work, check,
                weights_editor=lambda: editor_class(weights, device="cpu", **settings),
                main_cmd=[f"{name}_editor.py", *cli, "--weights", str(weights), "--device", "cpu",
                          "--views", "2", "--edit-steps", "2", "--size", str(size)])

        def flux():
            return dit("flux_kontext", FluxKontextEditor, tiny_flux_kontext, 32)

        def qwen():
            return dit("qwen_image_edit", QwenImageEditor, tiny_qwen_image_edit, 64)

        def ip2p():
            folder = tiny_ip2p_folder(work)
            editor = InstructPix2PixEditor(folder, device="cpu", steps=4, size=32)
            return exercise("ip2p", editor, None, scene, work, check,
                            main_cmd=["ip2p_editor.py", *cli, "--weights", str(folder), "--size", "32"])

        for name, run in (("flux", flux), ("qwen", qwen), ("ip2p", ip2p)):
            if name in only:
                rows.append(guarded(name, check, run))
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    total = time.perf_counter() - start
    if rows:
        keys = list(dict.fromkeys(k for r in rows for k in r))
        print("\n| " + " | ".join(keys) + " |\n|" + "---|" * len(keys))
        for r in rows:
            print("| " + " | ".join(str(r.get(k, "")) for k in keys) + " |")
    print(f"\ntorch {torch.__version__}, diffusers {diffusers.__version__}, transformers "
          f"{transformers.__version__}, {torch.get_num_threads()} threads, {total:.0f} s in all")
    print(f"{check.passed} passed, {len(check.failed)} failed")
    for name in check.failed:
        print(f"FAILED: {name}")
    return 1 if check.failed else 0


if __name__ == "__main__":
    sys.exit(main())

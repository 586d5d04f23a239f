#!/usr/bin/env python3
"""Reference fixtures for the CLIP tokenizer, the CLIP towers and the CLIP metrics.

Run with the oracle venv (torch, transformers 5, open_clip for the vocabulary file):

    /work/.venv-oracle/bin/python tools/model_fixtures_clip.py

Writes, under crates/models/tests/fixtures/:
  tokenizer/prompts.json   prompts with transformers' CLIPTokenizer ids (plain and padded to 77)
  clip/text/               a tiny random CLIPTextModel (config.json, model.safetensors)
  clip/full/               a tiny random CLIPModel (quick_gelu text, gelu vision)
  clip/reference.safetensors  inputs and reference outputs of both

The tokenizer is built offline from vocab.json / merges.txt derived from open_clip's
bpe_simple_vocab_16e6.txt.gz, the same file the Rust crate bundles.
"""

import gzip
import json
import os
import random
import sys
import tempfile

import open_clip
import torch
from safetensors.torch import save_file
from transformers import CLIPConfig, CLIPModel, CLIPTextConfig, CLIPTextModel, CLIPTokenizer

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "crates", "models", "tests", "fixtures")


def bytes_to_unicode():
    bs = list(range(ord("!"), ord("~") + 1)) + list(range(ord("¡"), ord("¬") + 1)) + list(range(ord("®"), ord("ÿ") + 1))
    cs = bs[:]
    n = 0
    for b in range(256):
        if b not in bs:
            bs.append(b)
            cs.append(256 + n)
            n += 1
    return dict(zip(bs, [chr(c) for c in cs]))


def reference_tokenizer():
    path = os.path.join(os.path.dirname(open_clip.__file__), "bpe_simple_vocab_16e6.txt.gz")
    lines = gzip.open(path).read().decode("utf-8").split("\n")
    merges = [tuple(l.split()) for l in lines[1 : 49152 - 256 - 2 + 1]]
    symbols = list(bytes_to_unicode().values())
    vocab = symbols + [s + "</w>" for s in symbols] + ["".join(m) for m in merges]
    vocab += ["<|startoftext|>", "<|endoftext|>"]
    d = tempfile.mkdtemp()
    with open(os.path.join(d, "vocab.json"), "w") as f:
        json.dump({t: i for i, t in enumerate(vocab)}, f)
    with open(os.path.join(d, "merges.txt"), "w") as f:
        f.write("#version: 0.2\n" + "\n".join(" ".join(m) for m in merges) + "\n")
    return CLIPTokenizer.from_pretrained(d)


def prompts():
    fixed = [
        "",
        " ",
        "a photo of a cat",
        "A Photo Of A CAT",
        "Turn him into a clown",
        "make it look like Van Gogh's 'Starry Night'",
        "what's up? we're here, they've gone, I'm fine, you'll see, he'd go",
        "WHAT'S UP? I'M FINE",
        "turn the bear into a panda!!!",
        "1234567890 3.14159 -42 1e10 100% $5.99",
        "café naïve résumé Ångström crème brûlée",
        "cafe\u0301 nai\u0308ve",  # decomposed accents (NFC composes them)
        "Straße ŒUVRE İstanbul ǅemal",
        "日本語のテキスト 中文 한국어",
        "Привет мир, ΚΑΛΗΜΈΡΑ κόσμε",
        "مرحبا بالعالم שלום",
        "emoji 😀🎉👍🏽 👨‍👩‍👧 ❤️",
        "tabs\tand\nnewlines\r\n  and   spaces",
        "\u00a0non-breaking\u2003em space\u3000ideographic",
        "x<|endoftext|>y",
        "<|startoftext|>hello<|endoftext|>",
        "<|ENDOFTEXT|> upper-case special",
        "<|endoftext|",
        "'s 't 're 've 'm 'll 'd",
        "''''s ''t",
        "e-mail: someone@example.com, url: https://example.org/a?b=c&d=e#f",
        "(parentheses) [brackets] {braces} <angles> \"quotes\" `ticks`",
        "~!@#$%^&*()_+-=|\\:;,./<>?",
        "..." * 30,
        "supercalifragilisticexpialidocious antidisestablishmentarianism",
        "a " * 100,
        "Make the statue bronze " * 20,
        "½ ² ³ ① Ⅻ ٣ ༣",
        "ﬁnance ﬂow Ⅷ",
        "fullwidth ＡＢＣ ａｂｃ １２３",
        "zero\u200bwidth\u200djoin",
        "control\x01chars\x7f",
        "mixedCASEwords andCamelCase and snake_case_words",
        "It's a 4k HDR photo, 35mm, f/1.8 --ar 16:9",
    ]
    rng = random.Random(6)
    words = (
        "a the of photo painting turn make him her it into clown bear panda statue bronze marble snow "
        "winter autumn night fire fireworks Van Gogh style cartoon anime 3D render person face hat "
        "glasses smiling old young beautiful tree flower garden desert city street".split()
    )
    alphabet = (
        list("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789")
        + list(" ,.;:!?'\"-()[]/&%$#@*+=_<>|~`^")
        + list("éèêëàâäôöûüçñßøåæœÉÀÇ")
        + ["😀", "🎉", "❤", "✨", "日", "本", "語", "д", "ж", "λ", "Ω", "\t", "\n", "\u00a0", "\u0301"]
    )
    out = list(fixed)
    for _ in range(150):
        n = rng.randint(1, 20)
        ws = []
        for _ in range(n):
            w = rng.choice(words)
            r = rng.random()
            if r < 0.15:
                w = w.upper()
            elif r < 0.3:
                w = w.capitalize()
            if rng.random() < 0.2:
                w += rng.choice([",", ".", "!", "?", "'s", "'ll", "...", ":", ";"])
            ws.append(w)
        out.append(rng.choice([" ", "  ", " "]).join(ws))
    for _ in range(150):
        n = rng.randint(1, 60)
        out.append("".join(rng.choice(alphabet) for _ in range(n)))
    return out


def tokenizer_fixture():
    tok = reference_tokenizer()
    ps = prompts()
    ids = [tok(p).input_ids for p in ps]
    padded = [tok(p, truncation=True, padding="max_length", max_length=77).input_ids for p in ps]
    os.makedirs(os.path.join(ROOT, "tokenizer"), exist_ok=True)
    with open(os.path.join(ROOT, "tokenizer", "prompts.json"), "w", encoding="utf-8") as f:
        json.dump({"prompts": ps, "ids": ids, "padded_77": padded}, f, ensure_ascii=True)
    print(f"tokenizer: {len(ps)} prompts")
    return tok


def save_model(model, folder, half=False):
    """HF layout; half=True stores model.fp16.safetensors and reloads the rounded weights."""
    os.makedirs(folder, exist_ok=True)
    model.config.to_json_file(os.path.join(folder, "config.json"))
    state = {k: v.contiguous() for k, v in model.state_dict().items()}
    if half:
        state = {k: v.half() for k, v in state.items()}
        save_file(state, os.path.join(folder, "model.fp16.safetensors"))
        model.load_state_dict({k: v.float() for k, v in state.items()}, strict=False)
    else:
        save_file(state, os.path.join(folder, "model.safetensors"))


MEAN = torch.tensor((0.48145466, 0.4578275, 0.40821073)).view(1, 3, 1, 1)
STD = torch.tensor((0.26862954, 0.26130258, 0.27577711)).view(1, 3, 1, 1)


def clip_similarity_encode_image(model, image_hwc):
    """Instruct-NeRF2NeRF ClipSimilarity.encode_image with the HF CLIPModel as the CLIP."""
    x = torch.from_numpy(image_hwc).permute(2, 0, 1)[None].float()
    x = torch.nn.functional.interpolate(x, size=224, mode="bicubic", align_corners=False)
    x = (x - MEAN) / STD
    f = model.get_image_features(pixel_values=x).pooler_output
    return x, f / f.norm(dim=1, keepdim=True)


def clip_fixture(tok):
    import numpy as np

    torch.manual_seed(6)
    out = {}
    # A CLIPTextModel as Stable Diffusion's text_encoder: gelu, legacy eos_token_id = 2
    # (pooling at the largest id), small vocabulary.
    tc = CLIPTextConfig(
        vocab_size=1000, hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=4,
        max_position_embeddings=77, hidden_act="gelu", eos_token_id=2, bos_token_id=0, pad_token_id=1,
    )
    text = CLIPTextModel(tc).eval()
    save_model(text, os.path.join(ROOT, "clip", "text"))
    ids = torch.randint(0, 998, (2, 77))
    ids[:, 0] = 0
    ids[0, 10] = 999
    ids[0, 11:] = 999
    ids[1, 76] = 999
    with torch.no_grad():
        o = text(input_ids=ids)
    out["text.input_ids"] = ids.to(torch.int32)
    out["text.last_hidden_state"] = o.last_hidden_state
    out["text.pooled"] = o.pooler_output

    # A whole CLIPModel: real vocabulary and tokenizer, quick_gelu text, gelu vision,
    # 224 input, fp16 weights on disk.
    cc = CLIPConfig(
        text_config=dict(vocab_size=49408, hidden_size=8, intermediate_size=20, num_hidden_layers=2,
                         num_attention_heads=2, max_position_embeddings=77, hidden_act="quick_gelu"),
        vision_config=dict(hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=4,
                           image_size=224, patch_size=32, hidden_act="gelu"),
        projection_dim=24,
    )
    full = CLIPModel(cc).eval()
    save_model(full, os.path.join(ROOT, "clip", "full"), half=True)
    rng = np.random.default_rng(6)
    sizes = [(60, 90), (150, 130), (40, 300)]  # (h, w): up, down, mixed
    prompts = ["a photo of a man", "Turn him into a clown, with a red nose!", "a bronze statue " * 12]
    with torch.no_grad():
        for i, (h, w) in enumerate(sizes):
            y, x = np.mgrid[0:h, 0:w] / max(h, w)
            img = np.stack([np.sin(7 * x + i) * 0.5 + 0.5, y, rng.random((h, w))], -1).astype(np.float32)
            pix, feat = clip_similarity_encode_image(full, img)
            out[f"full.image{i}"] = torch.from_numpy(img)
            if i < 2:  # every 7th row of the preprocessed pixels (keeps the fixture small)
                out[f"full.pixels{i}.rows7"] = pix[0, :, ::7, :]
            out[f"full.image_features{i}"] = full.get_image_features(pixel_values=pix).pooler_output[0]
        tids = torch.tensor([tok(p, truncation=True, padding="max_length", max_length=77).input_ids for p in prompts])
        out["full.text_ids"] = tids.to(torch.int32)
        out["full.text_features"] = full.get_text_features(input_ids=tids).pooler_output
    with open(os.path.join(ROOT, "clip", "prompts.json"), "w") as f:
        json.dump(prompts, f)

    # The metric: ClipSimilarity over three views (source, edited) and two prompts.
    src_prompt, tgt_prompt = "a photo of a man", "a photo of a clown"
    with torch.no_grad():
        t = full.get_text_features(
            input_ids=torch.tensor([tok(p, truncation=True, padding="max_length", max_length=77).input_ids
                                    for p in (src_prompt, tgt_prompt)])).pooler_output
        t = t / t.norm(dim=1, keepdim=True)
        sims, dirs = [], []
        for i in range(3):
            h, w = 24 + 8 * i, 32
            a = rng.random((h, w, 3)).astype(np.float32)
            b = np.clip(a * 0.6 + rng.random((h, w, 3)).astype(np.float32) * 0.4, 0, 1).astype(np.float32)
            _, fa = clip_similarity_encode_image(full, a)
            _, fb = clip_similarity_encode_image(full, b)
            sims.append(torch.nn.functional.cosine_similarity(fb, t[1:2]).item())
            dirs.append(torch.nn.functional.cosine_similarity(fb - fa, t[1:2] - t[0:1]).item())
            out[f"metric.source{i}"] = torch.from_numpy(a)
            out[f"metric.edited{i}"] = torch.from_numpy(b)
    out["metric.clip_sim"] = torch.tensor(sims)
    out["metric.clip_dir"] = torch.tensor(dirs)
    with open(os.path.join(ROOT, "clip", "metric.json"), "w") as f:
        json.dump({"source_prompt": src_prompt, "target_prompt": tgt_prompt, "clip_sim": sims, "clip_dir": dirs,
                   "mean_clip_sim": sum(sims) / 3, "mean_clip_dir": sum(dirs) / 3}, f, indent=1)
    save_file({k: v.contiguous() for k, v in out.items()}, os.path.join(ROOT, "clip", "reference.safetensors"))
    print("clip: written")


if __name__ == "__main__":
    what = sys.argv[1:] or ["tokenizer", "clip"]
    tok = tokenizer_fixture() if "tokenizer" in what else reference_tokenizer()
    if "clip" in what:
        clip_fixture(tok)

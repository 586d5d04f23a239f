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


if __name__ == "__main__":
    what = sys.argv[1:] or ["tokenizer"]
    if "tokenizer" in what:
        tokenizer_fixture()

"""Editors and helpers shared by the tests and tools/bench_ray.py, importable by Ray's
worker processes (the tests put this folder on PYTHONPATH before starting a cluster)."""

import os
import pathlib
import struct
import zlib

import numpy as np


def recolour(image):
    """A deterministic 'edit': the red-dominant pixels turn blue."""
    img = image.copy()
    red = (img[..., 0] > img[..., 2] + 0.1) & (img[..., 0] > img[..., 1] + 0.1)
    img[red] = img[red][:, [2, 1, 0]]
    return img


def write_png(path, rgb8):
    """A minimal 8-bit RGB PNG writer (standard library only)."""
    h, w, _ = rgb8.shape
    raw = b"".join(b"\x00" + rgb8[y].tobytes() for y in range(h))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    pathlib.Path(path).write_bytes(png + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


class Recolour:
    """Loads 'a model' once (counted in a file per process) and recolours."""

    def __init__(self, log_dir=None):
        self.log_dir = log_dir
        if log_dir:
            pathlib.Path(log_dir).mkdir(parents=True, exist_ok=True)
            (pathlib.Path(log_dir) / f"load-{os.getpid()}").write_text("loaded")

    def __call__(self, views, prompt):
        return [recolour(v.image) for v in views]


class KillOnce(Recolour):
    """Kills its own worker process the first time it is called (a marker file says
    it happened), like a GPU node lost in the middle of the 2D edits."""

    def __init__(self, marker):
        super().__init__()
        self.marker = pathlib.Path(marker)

    def __call__(self, views, prompt):
        if not self.marker.exists():
            self.marker.write_text(str(os.getpid()))
            os._exit(1)
        return super().__call__(views, prompt)


class Broken:
    def __init__(self):
        pass

    def __call__(self, views, prompt):
        raise RuntimeError("the model weights are corrupt")


class RedMask:
    """A deterministic 'segmenter': the red-dominant pixels of each view (the ball
    before the edit), None where there are none."""

    def __init__(self, margin=0.1):
        self.margin = margin

    def __call__(self, views, phrase):
        out = []
        for v in views:
            img = v.image
            m = ((img[..., 0] > img[..., 2] + self.margin) & (img[..., 0] > img[..., 1] + self.margin))
            out.append(m.astype(np.float32) if m.any() else None)
        return out

"""`edit(..., segmenter=callable, segment=phrase)`: the masks a Python segmenter returns
reach the engine exactly as masks handed to the command line tool with `--masks DIR`
(the same scene, byte for byte), and bad masks raise `ValueError` naming the view."""

import json
import pathlib

import numpy as np
import pytest

import transsplat
from conftest import run_cli
from ray_editors import write_png
from test_edit import PROMPT, recolour

STEPS = 30
PHRASE = "the ball"


def red_mask(image):
    """A deterministic 'segmentation': the red-dominant pixels (the ball)."""
    return ((image[..., 0] > image[..., 2] + 0.1) & (image[..., 0] > image[..., 1] + 0.1)).astype(np.float32)


def editor(vs, prompt):
    return [recolour(v.image) for v in vs]


def test_python_segmenter_gives_the_cli_masks_folders_scene(tabletop, tmp_path):
    edits, masks = tmp_path / "edits", tmp_path / "masks"
    edits.mkdir()
    masks.mkdir()
    asked = []

    def editor_writing(vs, prompt):
        out = editor(vs, prompt)
        for v, e in zip(vs, out):
            write_png(edits / (pathlib.Path(v.name).stem + ".png"), e)
        return out

    def segmenter(vs, phrase):
        assert phrase == PHRASE
        out = []
        for v in vs:
            # the renders before the edit, as the editor received them
            assert v.image.shape == (v.height, v.width, 3) and not v.image.flags.writeable
            asked.append(v.index)
            m = red_mask(v.image)
            write_png(masks / (pathlib.Path(v.name).stem + ".png"), (np.repeat(m[..., None], 3, 2) * 255).astype(np.uint8))
            out.append(m if m.any() else None)
        return out

    py_out = tmp_path / "py"
    transsplat.edit(tabletop, None, PROMPT, editor_writing, steps=STEPS, out=py_out, progress=False,
                    segmenter=segmenter, segment=PHRASE)
    assert asked
    summary = json.loads((py_out / "transport.json").read_text())
    assert summary["segmenter"] == {"name": "python", "phrase": PHRASE}
    assert "renders/mask_" in (py_out / "report.html").read_text()
    cli_out = tmp_path / "cli"
    run_cli("edit", "--scene", tabletop, "--prompt", PROMPT, "--editor", "folder", "--edits", edits,
            "--masks", masks, "--steps", STEPS, "--out", cli_out)
    ply = f"point_cloud/iteration_{STEPS}/point_cloud.ply"
    assert (py_out / ply).read_bytes() == (cli_out / ply).read_bytes()
    # without the masks the scene differs: they were used
    plain = tmp_path / "plain"
    transsplat.edit(tabletop, None, PROMPT, editor, steps=STEPS, out=plain, progress=False)
    assert (plain / ply).read_bytes() != (py_out / ply).read_bytes()


def segmenter_returning(fn):
    return lambda vs, phrase: fn(vs)


@pytest.mark.parametrize("fn,match", [
    (lambda vs: [np.ones((3, 3), np.float32) for v in vs], r"view '.*': the segmenter's mask has shape \(3, 3\)"),
    (lambda vs: ["ball" for v in vs], r"view \d+ \('.*'\): the segmenter's mask is a str"),
    (lambda vs: [np.full((v.height, v.width), 1.5, np.float32) for v in vs],
     r"view \d+ \(.*\): the segmenter \(python\) gave the value 1.5"),
    (lambda vs: [np.full((v.height, v.width), np.nan, np.float32) for v in vs], r"view \d+ \(.*\): mask: non-finite"),
    (lambda vs: [None for v in vs], r"the segmenter \(python\) found nothing for \"the ball\" in any view"),
    (lambda vs: [np.zeros((v.height, v.width)) for v in vs], r"found nothing for \"the ball\""),
    (lambda vs: [None for v in vs][:-1], r"the segmenter returned \d+ masks for \d+ views"),
    (lambda vs: 3, "must return a list"),
])
def test_bad_segmenter_outputs_raise_naming_the_view_and_write_nothing(tabletop, tmp_path, fn, match):
    out = tmp_path / "out"
    with pytest.raises(ValueError, match=match):
        transsplat.edit(tabletop, None, PROMPT, editor, steps=2, out=out, progress=False,
                        segmenter=segmenter_returning(fn), segment=PHRASE)
    assert not out.exists()


def test_segment_needs_a_segmenter_and_a_phrase(tabletop):
    with pytest.raises(ValueError, match="segment: needs segmenter="):
        transsplat.edit(tabletop, None, PROMPT, editor, steps=2, progress=False, segment=PHRASE)
    with pytest.raises(ValueError, match="segmenter: expected a callable"):
        transsplat.edit(tabletop, None, PROMPT, editor, steps=2, progress=False, segmenter="langsam")
    with pytest.raises(ValueError, match="the phrase is empty"):
        transsplat.edit(tabletop, None, PROMPT, editor, steps=2, progress=False,
                        segmenter=segmenter_returning(lambda vs: [None] * len(vs)), segment=" ")


def test_a_segmenter_that_raises_propagates_its_exception(tabletop, tmp_path):
    class Boom(RuntimeError):
        pass

    def segmenter(vs, phrase):
        raise Boom("out of GPU memory")

    with pytest.raises(Boom, match="out of GPU memory"):
        transsplat.edit(tabletop, None, PROMPT, editor, steps=2, out=tmp_path / "o", progress=False,
                        segmenter=segmenter)
    assert not (tmp_path / "o").exists()

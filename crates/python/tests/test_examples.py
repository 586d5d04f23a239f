"""The examples run: the walkthrough end to end (a built-in scene, the gsplat-style
render, an edit with a Python editor, before/after and the gate)."""

import pathlib
import runpy

import numpy as np
import pytest

import transsplat

EXAMPLES = pathlib.Path(__file__).resolve().parents[1] / "examples"


def test_walkthrough_runs_and_the_edit_lands(capsys):
    ns = runpy.run_path(str(EXAMPLES / "walkthrough.py"), run_name="__main__")
    before, after, gate = ns["before"], ns["after"], ns["gate"]
    changed = np.abs(after - before).max(axis=2) > 0.05
    assert 0.001 < changed.mean() < 0.5, "the edit changed nothing or everything"
    assert (gate > 0.5).any() and (gate < 0.5).any()
    assert (pathlib.Path(ns["result"]["out"]) / "report.html").is_file()


def test_builtin_scene_refuses_unknown_names_and_foreign_folders(tmp_path):
    with pytest.raises(ValueError, match="unknown scene"):
        transsplat.builtin_scene("nope", tmp_path / "x")
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "precious.txt").write_text("keep")
    with pytest.raises((ValueError, OSError)):
        transsplat.builtin_scene("tabletop", tmp_path / "foreign", quick=True)
    assert (tmp_path / "foreign" / "precious.txt").read_text() == "keep"

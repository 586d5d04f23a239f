"""The Ray driver (transsplat.ray) on a local cluster the test starts itself: every job
completes, a worker killed in the middle of the 2D edits changes nothing in the outputs,
a rerun reuses the content-named view results, a job whose editor fails for good is
reported and the others go on; and the manifest's bad inputs are refused before
anything starts."""

import json
import os
import pathlib
import subprocess
import sys

import pytest

import transsplat
from transsplat import ray as tray

HERE = pathlib.Path(__file__).resolve().parent


def manifest(tmp, scene, jobs, **top):
    doc = {"cache": str(tmp / "cache"), "summary": str(tmp / "summary.json"), "editor_workers": 2,
           "shard_size": 3, **top, "defaults": {"steps": 20, "editor": "ray_editors:Recolour"}, "job": jobs}
    p = tmp / "manifest.json"
    p.write_text(json.dumps(doc))
    return p


@pytest.fixture(scope="module")
def cluster():
    ray = pytest.importorskip("ray")
    os.environ["PYTHONPATH"] = os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")])
    sys.path.insert(0, str(HERE))
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


def ply(out):
    return (pathlib.Path(out) / "point_cloud/iteration_20/point_cloud.ply").read_bytes()


def test_jobs_survive_a_killed_worker_and_reruns_reuse_views(cluster, tabletop, tmp_path):
    jobs = [
        {"name": "ball", "scene": str(tabletop), "prompt": "make the ball blue", "out": str(tmp_path / "clean/ball")},
        {"name": "ball-naive", "scene": str(tabletop), "prompt": "make the ball blue", "method": "naive",
         "out": str(tmp_path / "clean/naive")},
    ]
    (tmp_path / "a").mkdir()
    clean = tray.run(manifest(tmp_path / "a", tabletop, jobs), progress=False)
    assert [r["status"] for r in clean] == ["ok", "ok"], clean
    # Both jobs edit the same views of the same scene for the same prompt: whichever
    # runs second may take some or all of them from the first's content-named results.
    seen = [r["views_edited"] + r["views_cached"] for r in clean]
    assert seen[0] == seen[1] > 0 and sum(r["views_edited"] for r in clean) >= seen[0], clean
    assert clean[0]["mean_gate"] is not None and clean[1]["mean_gate"] is None
    # The same jobs, the editor's worker killed on its first call, a fresh cache.
    killed = [dict(j, out=j["out"].replace("clean", "killed"),
                   editor="ray_editors:KillOnce", editor_args={"marker": str(tmp_path / "killed.marker")})
              for j in jobs]
    (tmp_path / "b").mkdir()
    rows = tray.run(manifest(tmp_path / "b", tabletop, killed), progress=False)
    assert (tmp_path / "killed.marker").exists(), "the worker was never killed"
    assert [r["status"] for r in rows] == ["ok", "ok"], rows
    for j, k in zip(jobs, killed):
        assert ply(j["out"]) == ply(k["out"])
    # A rerun into new outputs edits nothing: every view comes from the content-named cache.
    again = [dict(j, out=j["out"].replace("killed", "again")) for j in killed]
    (tmp_path / "c").mkdir()
    m = manifest(tmp_path / "c", tabletop, again, cache=str(tmp_path / "b" / "cache"))
    rows = tray.run(m, progress=False)
    assert all(r["views_edited"] == 0 and r["views_cached"] > 0 for r in rows), rows
    assert ply(again[0]["out"]) == ply(jobs[0]["out"])
    summary = json.loads((tmp_path / "c" / "summary.json").read_text())
    assert [r["job"] for r in summary["jobs"]] == ["ball", "ball-naive"]
    assert (tmp_path / "c" / "summary.md").read_text().count("| ok |") == 2


def test_a_job_whose_editor_fails_is_reported_and_the_others_finish(cluster, tabletop, tmp_path):
    jobs = [
        {"name": "broken", "scene": str(tabletop), "prompt": "make the ball blue", "out": str(tmp_path / "broken"),
         "editor": "ray_editors:Broken"},
        {"name": "fine", "scene": str(tabletop), "prompt": "make the ball blue", "out": str(tmp_path / "fine")},
    ]
    rows = tray.run(manifest(tmp_path, tabletop, jobs), progress=False)
    by = {r["job"]: r for r in rows}
    assert by["broken"]["status"] == "failed" and "the model weights are corrupt" in by["broken"]["error"]
    assert by["fine"]["status"] == "ok" and (tmp_path / "fine" / "report.html").is_file()
    assert not (tmp_path / "broken").exists()


def test_a_jobs_segmenter_runs_in_its_lift_as_in_edit(cluster, tabletop, tmp_path):
    jobs = [{"name": "masked", "scene": str(tabletop), "prompt": "make the ball blue", "out": str(tmp_path / "masked"),
             "segmenter": "ray_editors:RedMask", "segmenter_args": {"margin": 0.1}, "segment": "the ball"}]
    rows = tray.run(manifest(tmp_path, tabletop, jobs), progress=False)
    assert rows[0]["status"] == "ok", rows
    summary = json.loads((tmp_path / "masked" / "transport.json").read_text())
    assert summary["segmenter"] == {"name": "python", "phrase": "the ball"}
    # The same edit in this process, through edit(..., segmenter=...): the same scene.
    import ray_editors

    transsplat.edit(tabletop, None, "make the ball blue", ray_editors.Recolour(), steps=20, out=tmp_path / "direct",
                    progress=False, segmenter=ray_editors.RedMask(0.1), segment="the ball")
    assert ply(tmp_path / "masked") == ply(tmp_path / "direct")


@pytest.mark.parametrize("edit,match", [
    (lambda j: j.update(scene="/nonexistent/scene"), "job 'a': scene /nonexistent/scene does not exist"),
    (lambda j: j.update(editor="ray_editors:Nope"), "job 'a': editor 'ray_editors:Nope': 'ray_editors' has no attribute"),
    (lambda j: j.update(editor="no_such_module:X"), "job 'a': editor 'no_such_module:X': cannot import"),
    (lambda j: j.update(config={"loss.nope": 1}), "job 'a': .*unknown setting"),
    (lambda j: j.update(method="best"), "job 'a': .*unknown method"),
    (lambda j: j.update(colour="red"), r"job 'a': unknown settings \['colour'\]"),
    (lambda j: j.update(segmenter="ray_editors:Nope"), "job 'a': segmenter 'ray_editors:Nope': 'ray_editors' has no attribute"),
    (lambda j: j.update(segment="the ball"), "job 'a': segmenter_args and segment need a segmenter"),
    (lambda j: j.update(segmenter="ray_editors:RedMask", segment=""), "job 'a': segment must be a phrase"),
    (lambda j: j.update(name="b"), "job 'b': two jobs are named 'b'"),
    (lambda j: j.update(out="OUT_B"), "job 'b': output .* is shared with job 'a'"),
    (lambda j: j.update(out=j["scene"] + "/edited"), "job 'a': output: .* lies inside the input folder"),
])
def test_bad_manifests_are_refused_before_anything_starts_naming_the_job(tabletop, tmp_path, edit, match):
    sys.path.insert(0, str(HERE))
    a = {"name": "a", "scene": str(tabletop), "prompt": "p", "out": str(tmp_path / "out_a")}
    b = {"name": "b", "scene": str(tabletop), "prompt": "p", "out": str(tmp_path / "out_b")}
    edit(a)
    if a["out"] == "OUT_B":
        a["out"] = b["out"]
    p = manifest(tmp_path, tabletop, [a, b] if a["name"] != "b" else [b, a])
    with pytest.raises(tray.ManifestError, match=match):
        tray.load_manifest(p)
    assert not (tmp_path / "out_a").exists() and not (tmp_path / "cache").exists()


def test_without_ray_the_message_names_the_package(tmp_path):
    code = ("import sys; sys.modules['ray'] = None\n"
            "from transsplat import ray as r\n"
            "try:\n    r._ray()\nexcept ImportError as e:\n    print(e)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert 'pip install "ray[default]"' in out

"""Scale-out on Ray: the 2D edits of many views and many scenes across a cluster, each
scene's lift on one node.

A manifest (TOML or JSON) lists edit jobs. The driver checks all of it before anything
starts, starts one pool of editor actors per editor (each loads its model once and
keeps it: ``num_gpus`` / ``num_cpus`` per actor as the job asks), then runs each job's
lift as one Ray task. The lift is :func:`transsplat.edit` with a dispatching editor:
it splits the job's views into shards, sends them to the editor actors, and keeps every
view's result on disk under a name made of its content (scene, camera, prompt, editor
and its settings), so a rerun skips finished views and a retried task can never pick
up another scene's view. Actors are restarted and their calls retried when a worker
dies; a job whose editor fails for good is reported with its error and the others go
on. One summary table (JSON and Markdown) is written at the end.

Manifest (TOML)::

    cache = "cache"                 # per-view results, content-named (default: beside the manifest)
    summary = "summary.json"        # default: <manifest stem>.summary.json beside it
    editor_workers = 2              # editor actors per editor (default 2)
    shard_size = 4                  # views per editor call (default 4)
    lift_cpus = 1                   # CPUs a lift task reserves (default 1); a lift is
                                    # multi-threaded, so the node's core count runs one
                                    # lift per node at a time

    [defaults]                      # merged into every job
    steps = 600
    editor = "mypkg.editors:InstructPix2PixEditor"   # module:attribute, a class or a function
    editor_args = { weights = "/models/ip2p" }       # keyword arguments of the class
    num_gpus = 1

    [[job]]
    name = "bear-panda"
    scene = "scenes/bear"           # PLY or INRIA folder (relative to the manifest)
    cameras = "scenes/bear"         # optional: beside the scene
    prompt = "turn the bear into a panda"
    out = "out/bear-panda"
    config = { "loss.leak" = 0.2 }  # or a TOML file; method, steps, background as in edit()
    segmenter = "mypkg.seg:LangSAM"  # optional: module:attribute, views -> target masks,
    segmenter_args = { device = "cuda" }  # run in the job's lift task (once per job)
    segment = "the bear"            # its phrase (default: the whole instruction)

Run it with ``transsplat-ray MANIFEST`` (or ``python -m transsplat.ray``), optionally
``--address`` of a running cluster. The CLI never needs Ray; this module needs
``pip install "ray[default]"``.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import importlib
import json
import os
import pathlib
import sys
import time
import traceback
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

from . import _core
from ._edit import View, _output, _overrides

try:  # Python >= 3.11
    import tomllib as _toml
except ImportError:  # pragma: no cover
    _toml = None

JOB_KEYS = {
    "name", "scene", "cameras", "prompt", "out", "editor", "editor_args", "num_gpus", "num_cpus",
    "config", "method", "steps", "background", "segmenter", "segmenter_args", "segment",
}
TOP_KEYS = {"job", "jobs", "defaults", "cache", "summary", "editor_workers", "shard_size", "lift_cpus"}


def _ray():
    try:
        import ray
    except ImportError:
        raise ImportError(
            "transsplat.ray needs Ray, which is not installed: pip install \"ray[default]\" "
            "(the transsplat command line tool and the rest of the package do not need it)"
        ) from None
    return ray


class ManifestError(ValueError):
    """A manifest that cannot be run; the message names the file and the job."""


@dataclasses.dataclass
class Job:
    """One edit job of a manifest, its paths resolved."""

    name: str
    scene: str
    cameras: Optional[str]
    prompt: str
    out: str
    editor: str
    editor_args: Dict[str, Any]
    num_gpus: float = 0.0
    num_cpus: float = 0.0
    config: Any = None
    method: Optional[str] = None
    steps: Optional[int] = None
    background: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    segmenter: Optional[str] = None
    segmenter_args: Dict[str, Any] = dataclasses.field(default_factory=dict)
    segment: Optional[str] = None

    def editor_key(self) -> str:
        """Jobs with the same key share one pool of editor actors."""
        return json.dumps([self.editor, self.editor_args, self.num_gpus, self.num_cpus], sort_keys=True)


@dataclasses.dataclass
class Manifest:
    path: pathlib.Path
    jobs: List[Job]
    cache: pathlib.Path
    summary: pathlib.Path
    editor_workers: int = 2
    shard_size: int = 4
    lift_cpus: float = 1.0


def resolve_editor(spec: str, what: str = "editor"):
    """The object a ``module:attribute`` spec names (an editor's, or a segmenter's with
    ``what="segmenter"``)."""
    mod, _, attr = spec.partition(":")
    if not mod or not attr:
        raise ValueError(f"{what} {spec!r}: expected module:attribute, e.g. mypkg.{what}s:My{what.title()}")
    try:
        obj = importlib.import_module(mod)
    except ImportError as e:
        raise ValueError(f"{what} {spec!r}: cannot import {mod!r} ({e})") from None
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise ValueError(f"{what} {spec!r}: {mod!r} has no attribute {attr!r}")
        obj = getattr(obj, part)
    if not callable(obj):
        raise ValueError(f"{what} {spec!r}: {attr!r} is not callable")
    return obj


def instantiate(spec: str, kwargs: Dict[str, Any], what: str = "editor"):
    """The callable a spec and its arguments describe: a class is instantiated with the
    arguments, a function gets them bound."""
    obj = resolve_editor(spec, what)
    if isinstance(obj, type):
        return obj(**kwargs)
    if kwargs:
        import functools

        return functools.partial(obj, **kwargs)
    return obj


def load_manifest(path: "os.PathLike[str] | str") -> Manifest:
    """Reads and checks a manifest: every job's scene and cameras exist, its editor
    imports, its settings are valid, names are unique and no two jobs share an output
    folder. Raises :class:`ManifestError` naming the file and the job."""
    p = pathlib.Path(path)
    here = p.resolve().parent

    def fail(msg: str):
        raise ManifestError(f"{p}: {msg}")

    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileNotFoundError(f"{p}: no such manifest") from None
    try:
        if p.suffix.lower() == ".json":
            doc = json.loads(text)
        else:
            if _toml is None:  # pragma: no cover
                fail("TOML manifests need Python >= 3.11; use JSON")
            doc = _toml.loads(text)
    except Exception as e:
        fail(f"not valid {'JSON' if p.suffix.lower() == '.json' else 'TOML'}: {e}")
    if not isinstance(doc, dict):
        fail("expected a table of settings with a list of jobs")
    unknown = set(doc) - TOP_KEYS
    if unknown:
        fail(f"unknown settings {sorted(unknown)}; expected {sorted(TOP_KEYS)}")
    raw_jobs = doc.get("job", doc.get("jobs"))
    if not isinstance(raw_jobs, list) or not raw_jobs:
        fail("no jobs: add [[job]] tables (TOML) or a \"jobs\" list (JSON)")
    defaults = doc.get("defaults", {})
    if not isinstance(defaults, dict):
        fail("defaults: expected a table")
    workers, shard = doc.get("editor_workers", 2), doc.get("shard_size", 4)
    lift_cpus = doc.get("lift_cpus", 1)
    if not isinstance(lift_cpus, (int, float)) or isinstance(lift_cpus, bool) or not 0 < lift_cpus <= 1024:
        fail(f"lift_cpus: expected a number from 0 (exclusive) to 1024, got {lift_cpus!r}")
    for key, v in (("editor_workers", workers), ("shard_size", shard)):
        if not isinstance(v, int) or isinstance(v, bool) or not 1 <= v <= 4096:
            fail(f"{key}: expected an integer from 1 to 4096, got {v!r}")

    def rel(v: Any) -> str:
        return str((here / str(v)).resolve()) if not os.path.isabs(str(v)) else str(v)

    jobs: List[Job] = []
    names = set()
    outs: Dict[str, str] = {}
    for i, raw in enumerate(raw_jobs):
        if not isinstance(raw, dict):
            fail(f"job {i + 1}: expected a table")
        spec = {**defaults, **raw}
        name = spec.get("name")
        label = f"job {name!r}" if name else f"job {i + 1}"
        unknown = set(spec) - JOB_KEYS
        if unknown:
            fail(f"{label}: unknown settings {sorted(unknown)}; expected {sorted(JOB_KEYS)}")
        if not isinstance(name, str) or not name.strip():
            fail(f"{label}: needs a name")
        if name in names:
            fail(f"{label}: two jobs are named {name!r}")
        names.add(name)
        for key in ("scene", "prompt", "out", "editor"):
            if not isinstance(spec.get(key), str) or not spec[key].strip():
                fail(f"{label}: needs {key}")
        scene = rel(spec["scene"])
        if not os.path.exists(scene):
            fail(f"{label}: scene {scene} does not exist")
        cameras = rel(spec["cameras"]) if spec.get("cameras") else None
        if cameras is not None and not os.path.exists(cameras):
            fail(f"{label}: cameras {cameras} do not exist")
        out = rel(spec["out"])
        for other, o in outs.items():
            if out == o or out.startswith(o + os.sep) or o.startswith(out + os.sep):
                fail(f"{label}: output {out} is shared with job {other!r} ({o})")
        outs[name] = out
        try:
            resolve_editor(spec["editor"])
        except ValueError as e:
            fail(f"{label}: {e}")
        args = spec.get("editor_args", {})
        if not isinstance(args, dict):
            fail(f"{label}: editor_args must be a table")
        segmenter, segmenter_args, segment = spec.get("segmenter"), spec.get("segmenter_args", {}), spec.get("segment")
        if segmenter is not None:
            try:
                resolve_editor(segmenter if isinstance(segmenter, str) else repr(segmenter), "segmenter")
            except ValueError as e:
                fail(f"{label}: {e}")
        elif "segmenter_args" in spec or segment is not None:
            fail(f"{label}: segmenter_args and segment need a segmenter")
        if not isinstance(segmenter_args, dict):
            fail(f"{label}: segmenter_args must be a table")
        if segment is not None and (not isinstance(segment, str) or not segment.strip()):
            fail(f"{label}: segment must be a phrase naming the target, e.g. \"the ball\"")
        config = spec.get("config")
        toml_text, overrides = None, []
        if isinstance(config, dict):
            overrides = _overrides(config)
        elif isinstance(config, str):
            config = rel(config)
            try:
                toml_text = pathlib.Path(config).read_text(encoding="utf-8")
            except OSError as e:
                fail(f"{label}: config {config}: {e.strerror}")
        elif config is not None:
            fail(f"{label}: config must be a TOML file or a table of settings")
        steps = spec.get("steps")
        if steps is not None and (not isinstance(steps, int) or isinstance(steps, bool) or steps < 0):
            fail(f"{label}: steps must be a non-negative integer, got {steps!r}")
        try:
            _core.check_config(toml_text, overrides, spec.get("method"), steps)
        except ValueError as e:
            fail(f"{label}: {e}")
        bg = spec.get("background", (0.0, 0.0, 0.0))
        try:
            bg = tuple(float(v) for v in bg)
            assert len(bg) == 3 and all(np.isfinite(bg))
        except Exception:
            fail(f"{label}: background must be three finite numbers")
        res = {}
        for key in ("num_gpus", "num_cpus"):
            v = spec.get(key, 0)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not 0 <= v <= 1024:
                fail(f"{label}: {key} must be a number from 0 to 1024, got {v!r}")
            res[key] = float(v)
        jobs.append(Job(name, scene, cameras, spec["prompt"], out, spec["editor"], args, res["num_gpus"],
                        res["num_cpus"], config, spec.get("method"), steps, bg, segmenter, segmenter_args, segment))
    cache = pathlib.Path(rel(doc.get("cache", f".{p.stem}.cache")))
    summary = pathlib.Path(rel(doc.get("summary", f"{p.stem}.summary.json")))
    # The one output rule, before anything starts: no output may be, contain or lie
    # inside any job's input (scene, cameras, config file) or the manifest.
    inputs = [str(p.resolve())]
    for j in jobs:
        inputs += [j.scene] + [x for x in (j.cameras, j.config) if isinstance(x, str)]
    outputs = [(f"job {j.name!r}: output", j.out) for j in jobs]
    outputs += [("cache", str(cache)), ("summary", str(summary)), ("summary", str(summary.with_suffix(".md")))]
    for what, out in outputs:
        try:
            _core.check_output(out, inputs)
        except ValueError as e:
            fail(f"{what}: {e}")
    return Manifest(p, jobs, cache, summary, workers, shard, float(lift_cpus))


def scene_fingerprint(g: Dict[str, Any]) -> str:
    """A hash of a scene's parameters (not of its file name)."""
    h = hashlib.sha256()
    for key in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        a = np.ascontiguousarray(g[key], np.float32)
        h.update(key.encode())
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def view_key(scene_fp: str, view: View, prompt: str, editor_key: str) -> str:
    """The content name of one view's edit: the scene, the camera (pose, intrinsics,
    size, name), the rendered image, the instruction and the editor with its settings."""
    h = hashlib.sha256()
    for part in (scene_fp, view.name, str((view.width, view.height)), prompt, editor_key):
        h.update(part.encode())
        h.update(b"\0")
    for a in (view.viewmat, view.K, view.image):
        h.update(np.ascontiguousarray(a, np.float32).tobytes())
    return h.hexdigest()[:40]


class EditorHost:
    """Holds one editor (loaded once per worker) and edits shards of views with it.
    The outputs are checked and converted where they are made (errors name the view)."""

    def __init__(self, spec: str, kwargs: Dict[str, Any]):
        self.editor = instantiate(spec, kwargs)

    def edit(self, views: List[View], prompt: str) -> List[Any]:
        out = list(self.editor(views, prompt))
        if len(out) != len(views):
            raise ValueError(f"the editor returned {len(out)} views for {len(views)} inputs")
        return [_output(v, item) for v, item in zip(views, out)]


def _save(path: pathlib.Path, result) -> None:
    """One view's result, written under a temporary name and renamed when complete."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as f:
        if result is None:
            np.savez(f, none=np.zeros(0))
        else:
            img, att, mask = result
            arrays = {"image": img}
            if att is not None:
                arrays["attention"] = att
            if mask is not None:
                arrays["mask"] = mask
            np.savez(f, **arrays)
    os.replace(tmp, path)


def _load(path: pathlib.Path):
    with np.load(path) as z:
        if "none" in z:
            return None
        return (z["image"], z["attention"] if "attention" in z else None, z["mask"] if "mask" in z else None)


class Dispatcher:
    """The editor :func:`transsplat.edit` sees inside a lift task: views not yet in the
    cache go to the editor actors in shards; every result is stored under its content
    name as it arrives."""

    def __init__(self, actors: Sequence[Any], cache: pathlib.Path, scene_fp: str, editor_key: str,
                 shard_size: int):
        self.actors, self.cache = list(actors), cache
        self.scene_fp, self.editor_key, self.shard_size = scene_fp, editor_key, shard_size
        self.cached = 0
        self.edited = 0

    def __call__(self, views: List[View], prompt: str) -> List[Any]:
        ray = _ray()
        self.cache.mkdir(parents=True, exist_ok=True)
        keys = [view_key(self.scene_fp, v, prompt, self.editor_key) for v in views]
        results: List[Any] = [None] * len(views)
        todo = []
        for i, k in enumerate(keys):
            p = self.cache / f"{k}.npz"
            if p.is_file():
                results[i] = _load(p)
                self.cached += 1
            else:
                todo.append(i)
        shards = [todo[s:s + self.shard_size] for s in range(0, len(todo), self.shard_size)]
        refs = {}
        for n, shard in enumerate(shards):
            actor = self.actors[n % len(self.actors)]
            refs[actor.edit.remote([views[i] for i in shard], prompt)] = shard
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            shard = refs[done[0]]
            for i, r in zip(shard, ray.get(done[0])):
                _save(self.cache / f"{keys[i]}.npz", r)
                results[i] = r
                self.edited += 1
        return results


def _lift(job: Job, actors, cache: str, shard_size: int) -> Dict[str, Any]:
    """One job's lift: load, dispatch the 2D edits, transport and optimise, write."""
    from . import edit, load_ply

    t0 = time.monotonic()
    g = load_ply(job.scene)
    disp = Dispatcher(actors, pathlib.Path(cache), scene_fingerprint(g), job.editor_key(), shard_size)
    # The segmenter runs here, on the source renders of the edited views (the cached
    # editor results do not depend on it).
    segmenter = instantiate(job.segmenter, job.segmenter_args, "segmenter") if job.segmenter else None
    # Paths, not arrays, so the output rule sees the inputs (the scene is read twice).
    r = edit(job.scene, job.cameras, job.prompt, disp, config=job.config, method=job.method, steps=job.steps,
             out=job.out, background=job.background, progress=False, segmenter=segmenter, segment=job.segment)
    gate = r["gate"]
    return {
        "gaussians": int(len(r["gaussians"]["means"])),
        "views_edited": disp.edited,
        "views_cached": disp.cached,
        "editor_s": r["timing"].get("editor"),
        "lift_s": time.monotonic() - t0,
        "mean_gate": None if gate is None else float(np.mean(gate)),
        "out": r["out"],
    }


def run(manifest: "Manifest | str | os.PathLike[str]", address: Optional[str] = None,
        num_cpus: Optional[int] = None, progress: bool = True) -> List[Dict[str, Any]]:
    """Runs every job of a manifest on Ray (started here unless one is running or
    ``address`` names one); returns one summary row per job and writes the summary
    table. A failed job is reported with its error; the others go on."""
    ray = _ray()
    m = manifest if isinstance(manifest, Manifest) else load_manifest(manifest)
    if not ray.is_initialized():
        ray.init(address=address, num_cpus=num_cpus, include_dashboard=False, log_to_driver=True)
    host = ray.remote(EditorHost)
    pools: Dict[str, List[Any]] = {}
    for job in m.jobs:
        key = job.editor_key()
        if key not in pools:
            # num_cpus is always given (0 unless the job asks): an actor left at Ray's
            # default needs a free CPU to be placed, and the lift tasks waiting for
            # the actors' edits can hold every CPU of a small cluster.
            opts = dict(max_restarts=-1, max_task_retries=-1, num_gpus=job.num_gpus, num_cpus=job.num_cpus)
            pools[key] = [host.options(**opts).remote(job.editor, job.editor_args) for _ in range(m.editor_workers)]
    lift = ray.remote(num_cpus=m.lift_cpus)(_lift)
    started = time.monotonic()
    futures = {lift.remote(job, pools[job.editor_key()], str(m.cache), m.shard_size): job for job in m.jobs}
    rows: Dict[str, Dict[str, Any]] = {}
    pending = list(futures)
    while pending:
        done, pending = ray.wait(pending, num_returns=1)
        job = futures[done[0]]
        try:
            row = {"job": job.name, "status": "ok", **ray.get(done[0])}
        except Exception as e:  # a RayTaskError wrapping the job's own exception
            cause = getattr(e, "cause", None) or e
            row = {"job": job.name, "status": "failed", "error": f"{type(cause).__name__}: {cause}".splitlines()[0]}
        row["finished_s"] = round(time.monotonic() - started, 3)
        rows[job.name] = row
        if progress:
            what = f"wrote {row.get('out')}" if row["status"] == "ok" else row["error"]
            print(f"transsplat-ray: [{len(rows)}/{len(m.jobs)}] {job.name}: {row['status']}: {what}",
                  file=sys.stderr, flush=True)
    table = [rows[j.name] for j in m.jobs]
    write_summary(m.summary, table)
    return table


def write_summary(path: pathlib.Path, rows: List[Dict[str, Any]]) -> None:
    """The summary as JSON and as a Markdown table beside it (both written atomically)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    cols = ["job", "status", "gaussians", "views_edited", "views_cached", "lift_s", "mean_gate", "out", "error"]

    def cell(v):
        if v is None:
            return ""
        return f"{v:.3f}" if isinstance(v, float) else str(v).replace("|", "\\|")

    md = "| " + " | ".join(cols) + " |\n|" + "---|" * len(cols) + "\n"
    md += "".join("| " + " | ".join(cell(r.get(c)) for c in cols) + " |\n" for r in rows)
    for target, text in ((path, json.dumps({"jobs": rows}, indent=1) + "\n"), (path.with_suffix(".md"), md)):
        tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, target)


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog="transsplat-ray", description=__doc__.split("\n\n")[0])
    ap.add_argument("manifest", help="TOML or JSON manifest of edit jobs")
    ap.add_argument("--address", help="a running Ray cluster (default: start a local one)")
    ap.add_argument("--num-cpus", type=int, help="CPUs of the local cluster")
    args = ap.parse_args(argv)
    try:
        m = load_manifest(args.manifest)
        rows = run(m, address=args.address, num_cpus=args.num_cpus)
    except (ManifestError, FileNotFoundError, ImportError) as e:
        print(f"transsplat-ray: {e}", file=sys.stderr)
        return 2
    failed = [r["job"] for r in rows if r["status"] != "ok"]
    print(f"transsplat-ray: {len(rows) - len(failed)} of {len(rows)} jobs done; summary in {m.summary}",
          file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

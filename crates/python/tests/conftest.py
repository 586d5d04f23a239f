"""Shared helpers: the repository's paths and the command line tool for parity tests."""

import os
import pathlib
import shutil
import subprocess

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[3]
RASTER_FIXTURES = ROOT / "crates" / "raster" / "tests" / "fixtures"


def cli_binary():
    """The `transsplat` binary built by `cargo test --release` / `cargo build --release`
    (or TRANSSPLAT_BIN)."""
    env = os.environ.get("TRANSSPLAT_BIN")
    if env:
        return pathlib.Path(env)
    for profile in ("release", "debug"):
        p = ROOT / "target" / profile / "transsplat"
        if p.is_file():
            return p
    pytest.skip("the transsplat binary is not built (cargo build --release)")


def run_cli(*args):
    """Runs the command line tool; fails the test with its stderr when it fails."""
    r = subprocess.run([str(cli_binary()), *map(str, args)], capture_output=True, text=True)
    assert r.returncode == 0, f"transsplat {' '.join(map(str, args))} failed:\n{r.stderr}"
    return r


@pytest.fixture(scope="session")
def tabletop(tmp_path_factory):
    """A quick built-in tabletop scene written by `transsplat scene`."""
    d = tmp_path_factory.mktemp("scene") / "tabletop"
    run_cli("scene", "tabletop", "--quick", "--out", d)
    return d

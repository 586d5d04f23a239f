#!/usr/bin/env bash
# Builds the `transsplat` Python wheel (crates/python, maturin, abi3) in a virtual
# environment under target/, installs it with the test dependencies (pytest, POT, Pillow) and
# runs its pytest suite. The parity tests call the `transsplat` binary of the same
# build (target/release/transsplat; `cargo test --release` or `cargo build --release`
# makes it). Usage: tools/python_tests.sh [pytest arguments]
set -euo pipefail
cd "$(dirname "$0")/.."
venv=target/python-venv
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/python" -m pip install --quiet --upgrade pip
"$venv/bin/python" -m pip install --quiet "maturin>=1.5,<2" "pytest>=7" "pot>=0.9" numpy pillow "ray>=2.9"
[ -x target/release/transsplat ] || cargo build --release -p transsplat
rm -rf target/wheels
"$venv/bin/maturin" build --release -m crates/python/Cargo.toml -o target/wheels
"$venv/bin/python" -m pip install --quiet --force-reinstall target/wheels/transsplat-*.whl
cd crates/python
# A bound on the whole suite: a hung Ray cluster must fail CI, not stall it.
exec timeout 1200 ../../"$venv/bin/python" -m pytest -q tests "$@"

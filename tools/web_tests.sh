#!/usr/bin/env bash
# The checks that need web tools, run by .ci/run after the Python tests:
#  - tools/web/check_formats.py: PlayCanvas splat-transform (npm) reads our compressed
#    PLY and SPZ files as the same scene (count, renders), and writes the same
#    compressed PLY body as we do; its .glb matches ours attribute by attribute; it
#    reads our .sog and we read its .sog;
#  - tools/web/gltf_test.mjs: the PlayCanvas engine draws our .glb
#    (KHR_gaussian_splatting) in headless Chromium where transsplat renders the scene;
#  - tools/web/viewer_test.mjs: the 3D viewer of an edit's report.html in headless
#    Chromium (Debian's package) against transsplat's own renders, the before/after
#    toggle and split, frame times on a 500k-Gaussian page, the no-WebGL message.
# Installs Chromium with apt-get when missing (as root) and the pinned npm packages of
# tools/web (npm ci). Screenshots and measurements land in target/web-tests.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! command -v chromium >/dev/null 2>&1; then
    sudo=""
    if [ "$(id -u)" -ne 0 ]; then
        if sudo -n true 2>/dev/null; then
            sudo="sudo -n"
        else
            echo "tools/web_tests.sh: Chromium is missing; install Debian's 'chromium' package" >&2
            exit 1
        fi
    fi
    $sudo apt-get update -qq
    $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
fi
(cd tools/web && npm ci --no-audit --no-fund --silent)
bin=target/release/transsplat
[ -x "$bin" ] || cargo build --release -p transsplat
python=target/python-venv/bin/python
[ -x "$python" ] || { python3 -m venv target/python-venv && "$python" -m pip install --quiet numpy; }
work=target/web-tests
rm -rf "$work"
mkdir -p "$work"

echo "== scene formats against splat-transform"
"$python" tools/web/check_formats.py "$bin" tools/web/node_modules/.bin/splat-transform "$work/formats"

echo "== our glTF drawn by the PlayCanvas engine in headless Chromium"
node tools/web/gltf_test.mjs "$work/formats/ours.glb" "$work/formats/ds/cameras.json" \
    "$work/formats/r_src/view_000.png" "$work/shots"

echo "== the 3D viewer in headless Chromium"
"$bin" scene tabletop --quick --out "$work/ds" 2>/dev/null
"$bin" edit --scene "$work/ds" --editor simulated --prompt "make the ball blue" --steps 120 --out "$work/edit" 2>/dev/null
# About 500k Gaussians (tabletop detail 10.8), for the frame time at a real size.
"$bin" scene tabletop --detail 10.8 --views 8 --out "$work/big" 2>/dev/null
"$bin" view "$work/big" --out "$work/big.html" 2>/dev/null
ls -l "$work/edit/report.html" "$work/big.html"
node tools/web/viewer_test.mjs "$work/edit" "$work/shots" --fps-page "$work/big.html"

#!/bin/bash
# Builds `transsplat` with `--features cuda` on a machine without the CUDA toolkit or a
# GPU (how the GPU figures in docs/results.md, "InstructPix2Pix on a GPU", were made):
# CUDA 13.0's nvcc, headers and runtime come from NVIDIA's PyPI wheels, and the driver
# and library entry points that cudarc links against come from stub libraries built here
# with the real libraries' sonames. At run time the machine's driver (libcuda.so.1) and
# its CUDA 13 cuBLAS / cuRAND (e.g. a torch cu130 install's nvidia/cu13/lib) are found
# through LD_LIBRARY_PATH. With the toolkit installed, `cargo build --release -p
# transsplat --features cuda` is all it takes.
#
#   tools/build_cuda.sh [COMPUTE_CAP (default 90: H100/H200)]   → target-cuda/release/transsplat
#   (CARGO_TARGET_DIR and CUDA_WORK move the build and the downloaded toolkit)
set -euo pipefail
cap=${1:-90}
target=${CARGO_TARGET_DIR:-$PWD/target-cuda}
work=${CUDA_WORK:-$PWD/target-cuda/toolkit}
mkdir -p "$work/wheels" "$work/root" "$work/stubs"
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
  --platform manylinux2014_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux_2_12_x86_64 \
  -d "$work/wheels" "nvidia-cuda-nvcc==13.0.*" "nvidia-cuda-runtime==13.0.*" "nvidia-cuda-crt==13.0.*" \
  "nvidia-nvvm==13.0.*" "nvidia-cuda-cccl==13.0.*"
for w in "$work"/wheels/*.whl; do python3 -m zipfile -e "$w" "$work/root"; done
cuda=$work/root/nvidia/cu13
chmod +x "$cuda"/bin/* "$cuda"/nvvm/bin/*
# Stubs: every entry point cudarc declares, in a library named as the real one.
cargo fetch -q
src=$(ls -d "${CARGO_HOME:-$HOME/.cargo}"/registry/src/*/cudarc-0.19.* | tail -1)/src
stub() { # module, library, soname
  grep -hoE "^ +fn [A-Za-z0-9_]+\(" "$src/$1"/sys/*.rs | sed -E 's/ +fn ([A-Za-z0-9_]+)\(/void \1(void){}/' | sort -u > "$work/stubs/$2.c"
  gcc -shared -fPIC -o "$work/stubs/lib$2.so" -Wl,-soname,"$3" "$work/stubs/$2.c"
}
stub driver cuda libcuda.so.1
stub nvrtc nvrtc libnvrtc.so.13
stub curand curand libcurand.so.10
stub cublas cublas libcublas.so.13
stub cublaslt cublasLt libcublasLt.so.13
ln -sf "$cuda/lib/libcudart.so.13" "$work/stubs/libcudart.so"
PATH=$cuda/bin:$PATH CUDA_PATH=$cuda CUDA_COMPUTE_CAP=$cap CARGO_TARGET_DIR=$target \
  RUSTFLAGS="-L native=$work/stubs" cargo build --release -p transsplat --features cuda
cp "$cuda/lib/libcudart.so.13" "$target/release/"
echo "$target/release/transsplat (ship libcudart.so.13 beside it; needs libcuda.so.1 and CUDA 13 cuBLAS/cuRAND on LD_LIBRARY_PATH)"

#!/usr/bin/env python3
"""InstructPix2Pix on the CPU: transsplat's candle implementation beside diffusers on
PyTorch's CPU build, same architecture, same machine, same session, same threads
(issue #40's side-by-side table; figures in docs/results.md, "Models").

Both sides build the SD 1.5 InstructPix2Pix architecture (a UNet with 8 input channels,
the VAE) with random weights: real weights cannot be downloaded here, and the
arithmetic is the same. Rows, each the best of `--repeats` timed runs after one
untimed warm-up (the whole view: one run, its parts already warm):

- one UNet step on a batch of 3 (the three-way guidance) at 256² and 512², and at 256²
  on a batch of 3 × 2 and 3 × 4 (several views per call, `edit --ip2p-batch`);
- VAE encode and VAE decode at 256² and 512²;
- a whole view at 256²: encode, 20 UNet steps, decode (measured on PyTorch; for candle
  composed from its rows, as `transsplat bench models` times the stages, not the loop);
- peak resident memory of each side's process (the models' weights included).

The candle side is `transsplat bench models --only ip2p` run as a child process (its
own peak memory is read from the child's rusage); PyTorch runs in this process with
`torch.set_num_threads(--threads)`, and the child gets `RAYON_NUM_THREADS` and
`OMP_NUM_THREADS` set to the same number.

    python3 tools/bench_ip2p_cpu.py [--threads 2] [--repeats 2] [--rounds 1] [--sizes 256 512]
        [--transsplat target/release/transsplat] [--out bench_ip2p_cpu.json]

With `--device cuda` both sides run on the GPU instead (issue #40's item 6): PyTorch
on CUDA, and the candle side a binary built with `--features cuda`, which runs its
models on CUDA device 0 when one is present. Every timed call waits for the device;
the memory rows add PyTorch's peak GPU allocation.

Needs torch, diffusers (not dependencies of the project or CI).
"""
import argparse
import json
import os
import re
import resource
import subprocess
import sys
import time

STEPS = 20


def torch_models(torch, device):
    """The UNet and the VAE of `bench_ip2p_gpu.py` (the same SD 1.5 configuration), f32."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from bench_ip2p_gpu import models

    unet, vae, _ = models(torch.float32, device)
    return unet, vae


def best_of_synced(repeats, f, warm_up=True, sync=lambda: None):
    """Best seconds of `repeats` calls of `f`, each waited for with `sync`."""
    if warm_up:
        f()
        sync()
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        f()
        sync()
        best = min(best, time.perf_counter() - t)
    return best


def torch_rows(args, built={}):
    """PyTorch's rows; its models are built on the first call and kept for the next."""
    import torch

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    dev = args.device
    if not built:
        built["models"] = torch_models(torch, dev)
    unet, vae = built["models"]
    text = torch.randn(3, 77, 768, device=dev)
    sync = torch.cuda.synchronize if dev == "cuda" else (lambda: None)

    def best_of(repeats, f, warm_up=True):
        return best_of_synced(repeats, f, warm_up, sync)

    rows = {}
    with torch.no_grad():
        for size in args.sizes:
            lat = size // 8
            x = torch.randn(3, 8, lat, lat, device=dev)
            t = torch.tensor(500, device=dev)
            rows[f"unet step (batch 3) {size}"] = best_of(
                args.repeats, lambda: unet(x, t, encoder_hidden_states=text).sample)
            if size == 256:
                for views in (2, 4):
                    xv = torch.randn(3 * views, 8, lat, lat, device=dev)
                    tv = text.repeat(views, 1, 1)
                    rows[f"unet step (batch 3x{views}) {size}"] = best_of(
                        args.repeats, lambda: unet(xv, t, encoder_hidden_states=tv).sample)
            img = torch.rand(1, 3, size, size, device=dev) * 2 - 1
            rows[f"vae encode {size}"] = best_of(args.repeats, lambda: vae.encode(img).latent_dist.mode())
            z = torch.randn(1, 4, lat, lat, device=dev)
            rows[f"vae decode {size}"] = best_of(args.repeats, lambda: vae.decode(z).sample)

        def whole_view():
            img = torch.rand(1, 3, 256, 256, device=dev) * 2 - 1
            image_latents = vae.encode(img).latent_dist.mode()
            latents = torch.randn_like(image_latents)
            for step in torch.linspace(999, 0, STEPS, device=dev).long():
                x = torch.cat([torch.cat([latents] * 3),
                               torch.cat([image_latents, image_latents, torch.zeros_like(image_latents)])], dim=1)
                eps = unet(x, step, encoder_hidden_states=text).sample
                e_text, e_img, e_u = eps.chunk(3)
                latents = latents - 0.05 * (e_u + 7.5 * (e_text - e_img) + 1.5 * (e_img - e_u))
            return vae.decode(latents / 0.18215).sample

        if 256 in args.sizes:
            # Its parts are warm by now: one timed run.
            rows["whole view 256 (measured)"] = best_of(1, whole_view, warm_up=False)
    rows["peak memory GiB"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    if dev == "cuda":
        rows["peak GPU memory GiB (PyTorch's allocator)"] = torch.cuda.max_memory_allocated() / 2**30
    return rows


def candle_rows(args):
    env = dict(os.environ, RAYON_NUM_THREADS=str(args.threads), OMP_NUM_THREADS=str(args.threads))
    run = subprocess.run([args.transsplat, "bench", "models", "--only", "ip2p",
                          "--repeats", str(args.repeats)], env=env,
                         capture_output=True, text=True)
    if run.returncode != 0:
        sys.exit(f"{args.transsplat} bench models failed (exit {run.returncode}):\n{run.stderr[-4000:]}")
    out = run.stdout
    rows = {}
    for line in out.splitlines():
        m = re.match(r"ip2p (unet step \(batch 3(?:x\d+)?\)|vae encode|vae decode) (\d+)x\d+\s+([\d.]+)", line)
        if m and int(m.group(2)) in args.sizes:
            rows[f"{m.group(1)} {m.group(2)}"] = float(m.group(3))
    if all(f"{k} 256" in rows for k in ("unet step (batch 3)", "vae encode", "vae decode")):
        rows["whole view 256 (composed)"] = (rows["vae encode 256"] + STEPS * rows["unet step (batch 3) 256"]
                                             + rows["vae decode 256"])
    rows["peak memory GiB"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 2**20
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=os.cpu_count())
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=1,
                    help="alternate the two sides this many times and keep each row's fastest: on a shared "
                         "machine whose speed drifts over minutes, both sides then see the same spells")
    ap.add_argument("--sizes", type=int, nargs="+", default=[256, 512])
    ap.add_argument("--transsplat", default="target/release/transsplat")
    ap.add_argument("--out", help="also write the table as JSON here")
    ap.add_argument("--device", choices=["cpu", "cuda"], default="cpu",
                    help="where both sides run (cuda: the candle binary built with --features cuda)")
    args = ap.parse_args()
    if not os.access(args.transsplat, os.X_OK):
        sys.exit(f"{args.transsplat}: not an executable (build it: cargo build --release -p transsplat)")
    # candle first, in a child, so its peak memory is its own.
    candle, torch = {}, {}
    for _ in range(max(args.rounds, 1)):
        for side, rows in ((candle, candle_rows(args)), (torch, torch_rows(args))):
            for k, v in rows.items():
                side[k] = max(side.get(k, v), v) if "memory" in k else min(side.get(k, v), v)
    keys = [k for k in torch if "memory" not in k] + [k for k in torch if "memory" in k]
    print(f"{'row':<32} {'candle s':>10} {'PyTorch s':>10} {'PyTorch / candle':>17}")
    table = []
    for k in keys:
        ck = candle.get(k) if k in candle else candle.get(k.replace("(measured)", "(composed)"))
        tk = torch[k]
        ratio = tk / ck if ck else float("nan")
        print(f"{k:<32} {ck if ck is not None else float('nan'):>10.3f} {tk:>10.3f} {ratio:>17.2f}")
        table.append({"row": k, "candle": ck, "pytorch": tk})
    if args.out:
        with open(args.out + ".partial", "w") as f:
            json.dump({"device": args.device, "threads": args.threads, "repeats": args.repeats,
                       "rounds": args.rounds, "rows": table},
                      f, indent=1)
        os.rename(args.out + ".partial", args.out)


if __name__ == "__main__":
    main()

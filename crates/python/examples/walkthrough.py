# %% [markdown]
# # transsplat from Python: render, edit, look at the result
#
# A notebook-style walkthrough (cells marked `# %%`; run it as a script or open it in
# Jupyter / VS Code). It uses a built-in scene and a tiny Python "editor" so it runs
# anywhere in about a minute on a laptop CPU; swap in `ip2p_editor.py`'s
# `InstructPix2PixEditor` for real edits.

# %%
import pathlib
import tempfile

import numpy as np

import transsplat

work = pathlib.Path(tempfile.mkdtemp(prefix="transsplat-walkthrough-"))
scene = transsplat.builtin_scene("tabletop", work / "tabletop", quick=True)
g = transsplat.load_ply(scene)
cams = transsplat.load_cameras(scene)
print(f"{len(g['means'])} Gaussians, SH {g['sh'].shape}, {len(cams['names'])} cameras")

# %% Render one camera with the gsplat-style rasterizer.
def render(g, i):
    deg = int(round(np.sqrt(g["sh"].shape[1]))) - 1
    colors, alphas, meta = transsplat.rasterization(
        g["means"], g["quats"], np.exp(g["log_scales"]), 1 / (1 + np.exp(-g["opacity_logits"])), g["sh"],
        cams["viewmats"][i : i + 1], cams["Ks"][i : i + 1], int(cams["widths"][i]), int(cams["heights"][i]),
        sh_degree=deg,
    )
    return colors[0]

before = render(g, 0)
print("render", before.shape, before.dtype)

# %% A 2D editor is any callable: views in, edited images out. This one turns the
# reddish pixels blue (the ball of the tabletop scene) and says where it looked.
def editor(views, prompt):
    out = []
    for v in views:
        img = v.image.copy()
        red = (img[..., 0] > img[..., 2] + 0.1) & (img[..., 0] > img[..., 1] + 0.1)
        img[red] = img[red][:, ::-1]
        out.append((img, red.astype(np.float32), None))  # (image, attention, mask)
    return out

result = transsplat.edit(scene, None, "make the ball blue", editor, steps=200, out=work / "edited")
print("wrote", result["out"])
print("transport rounds:", [(r["step"], round(r["mean_gate"], 3)) for r in result["rounds"]])

# %% Before / after, and the gate: the per-Gaussian probability that the edit applies.
after = render(result["gaussians"], 0)
gate = result["gate"]
print(f"changed pixels: {(np.abs(after - before).max(axis=2) > 0.05).mean():.1%}")
print(f"gate: mean {gate.mean():.3f}, open (> 0.5) on {(gate > 0.5).mean():.1%} of the Gaussians")
# Colour the Gaussians by their gate (red = edited) and render that.
heat = dict(result["gaussians"])
sh = np.zeros((len(gate), 1, 3), np.float32)
sh[:, 0, 0] = (gate - 0.5) / 0.28209479177387814
sh[:, 0, 2] = (0.5 - gate) / 0.28209479177387814
heat["sh"] = sh
gate_view = render(heat, 0)

try:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(12, 3.5))
    for a, img, title in zip(ax, (before, after, gate_view), ("before", "after", "gate")):
        a.imshow(np.clip(img, 0, 1))
        a.set_title(title)
        a.axis("off")
    fig.savefig(work / "before_after_gate.png", bbox_inches="tight")
    print("saved", work / "before_after_gate.png")
except ImportError:
    np.save(work / "before_after_gate.npy", np.stack([before, after, gate_view]))
    print("matplotlib is not installed; saved the three images as", work / "before_after_gate.npy")

# %% The same output folder as `transsplat edit`: report.html has the test views before
# and after, the gate maps and the per-round transport statistics.
print(sorted(p.name for p in pathlib.Path(result["out"]).iterdir()))

#!/usr/bin/env python3
"""Independent oracle for the transsplat CPU rasterizer: writes test fixtures.

What it is
    Projection, covariance and spherical harmonics come from gsplat 1.5's own
    PyTorch reference code (``gsplat.cuda._torch_impl``: ``_quat_scale_to_covar_preci``,
    ``_fully_fused_projection`` -> ``_world_to_cam`` / ``_persp_proj``,
    ``_spherical_harmonics``), imported and called, never copied. The compositor
    below is a dense (every visible Gaussian x every pixel) PyTorch compositor
    written here with the classic 3DGS / gsplat 1.5 rules (see ``composite``).
    Everything runs in float64 on the float32-rounded inputs; gradients are
    PyTorch autograd.

What it needs
    Python 3.10+, ``pip install numpy torch "gsplat==1.5.*"`` (CPU is enough: only the
    pure-PyTorch reference functions of gsplat are used, nothing is compiled).
    A throwaway virtualenv outside the repository is the easy way:
        python3 -m venv /tmp/oracle && /tmp/oracle/bin/pip install numpy torch "gsplat==1.5.*"
        /tmp/oracle/bin/python tools/raster_fixtures.py

How to run
    python3 tools/raster_fixtures.py [--out DIR]      (from the repository root)
    Deterministic: fixed seeds per case (borderline draws are redrawn, see below).
    Takes about a minute on one core (the dense case redraws ~220 times).

What it writes (DIR defaults to crates/raster/tests/fixtures)
    DIR/index.json   {"gsplat": version, "torch": version, "cases": [names]}
    DIR/<case>/meta.json  width, height, fx, fy, cx, cy, viewmat (4x4 world-to-camera,
        row-major, OpenCV axes), background, sh_degree, num_gaussians, num_features,
        description.
    DIR/<case>/*.npy   float32, little endian, C order, npy format 1.0:
      inputs    means (N,3), log_scales (N,3), quats (N,4) wxyz unnormalised,
                opacity_logits (N,), sh (N,K,3) K=(d+1)^2 (coefficient 0 = DC),
                features (N,F) [only if F>0]
      forward   rgb (H,W,3), alpha (H,W), depth (H,W) (= sum w z, not divided by
                alpha), features_out (H,W,F) [only if F>0, no background]
      stats     means2d (N,2), depths (N,) (raw projection for every Gaussian, also
                culled ones; gsplat leaves them undefined when culled: compare where
                radii > 0), radii (N,2) (ceil(3.33 sqrt(diag(cov2d + 0.3 I))) as
                gsplat's _fully_fused_projection; 0,0 when culled),
                radii_opacity_aware (N,2) (extra: what gsplat 1.5's CUDA projection
                computes when rasterization() hands it opacities: extend =
                min(3.33, sqrt(2 ln(255 opacity))), culled if opacity < 1/255),
                weight_sum, alpha_sum, pixel_count, visibility (N,) over blended
                pairs only (visibility = weight_sum / alpha_sum, 0 if alpha_sum = 0)
      splat     splat_in (H,W,4), splat_out (N,4) = sum_p w G / sum_p w (0 if no weight)
      backward  v_rgb (H,W,3), v_alpha (H,W), v_depth (H,W), v_features (H,W,F)
                [F>0]; grad_means (N,3), grad_log_scales (N,3), grad_quats (N,4),
                grad_opacity_logits (N,), grad_sh (N,K,3), grad_features (N,F) [F>0],
                grad_means2d (N,2), all of
                L = sum v_rgb*rgb + sum v_alpha*alpha + sum v_depth*depth
                    + sum v_features*features_out.

Borderline cases (a hard decision within float32 noise of flipping) are detected
after computing and the case is redrawn with the next seed; the count is printed
and put in the case description. Windows: alpha within 1e-5 (relative) of 1/255 or
o exp(-sigma) within 1e-5 of 0.999 on an evaluated pair; next_T within 1e-3 (relative)
of 1e-4 on a pair that passed the alpha test; 3.33 sqrt(cov) (or the opacity-aware
extent) within 1e-4 relative of an integer for a Gaussian whose culling/radius
depends on it; a box edge within 1e-3 px of the image border; z within 1e-4 of the
near plane; x/z or y/z within 1e-4 relative of the Jacobian clamp limit; SH colour
within 1e-5 of the clamp at 0. Also every pair with alpha >= 1/255 must lie inside
the (opacity-aware) box, else the dense compositor would differ from gsplat's tiles.
"""

import argparse
import json
import math
import os
import sys

import numpy as np
import torch

import gsplat
import gsplat.cuda._torch_impl as gs_ref  # gsplat's own PyTorch reference code

torch.set_default_dtype(torch.float64)
torch.set_num_threads(1)

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.999
T_STOP = 1e-4
EPS2D = 0.3
NEAR = 0.01
FAR = 1e10

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEFAULT_OUT = os.path.join(REPO, "crates", "raster", "tests", "fixtures")


def f32(x):
    """Round to float32 and back to a float64 numpy array (inputs are float32)."""
    return np.asarray(x, dtype=np.float32).astype(np.float64)


def f32_scalar(x):
    return float(np.float32(x))


# ----------------------------------------------------------------------------
# Cameras and scenes
# ----------------------------------------------------------------------------


def quat_to_rot(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def make_camera(rng, W, H, fx, fy, cx, cy, rotated):
    """World-to-camera viewmat; rotated cameras get a random pose."""
    if rotated:
        R = quat_to_rot(rng.normal(size=4))
        t = rng.uniform(-1.0, 1.0, size=3)
    else:
        R = np.eye(3)
        t = np.zeros(3)
    V = np.eye(4)
    V[:3, :3] = R
    V[:3, 3] = t
    return dict(W=W, H=H, fx=f32_scalar(fx), fy=f32_scalar(fy), cx=f32_scalar(cx),
                cy=f32_scalar(cy), viewmat=f32(V))


def cam_to_world(cam, p_c):
    """Points given in camera space -> world space for this camera."""
    V = cam["viewmat"]
    R, t = V[:3, :3], V[:3, 3]
    return np.linalg.solve(R, (p_c - t).T).T


def pixels_to_cam(cam, u, v, z):
    x = (u - cam["cx"]) / cam["fx"] * z
    y = (v - cam["cy"]) / cam["fy"] * z
    return np.stack([x, y, z], axis=-1)


def random_gaussians(rng, cam, n, z_range=(2.0, 6.0), log_scale_range=(-4.0, -1.0),
                     scene_size=2.0, margin=0.1, opacity_range=(-2.0, 4.0)):
    W, H = cam["W"], cam["H"]
    z = rng.uniform(*z_range, size=n)
    u = rng.uniform(-margin * W, (1 + margin) * W, size=n)
    v = rng.uniform(-margin * H, (1 + margin) * H, size=n)
    means_c = pixels_to_cam(cam, u, v, z)
    log_scales = rng.uniform(*log_scale_range, size=(n, 3)) + math.log(scene_size)
    return dict(
        means=cam_to_world(cam, means_c),
        log_scales=log_scales,
        quats=rng.normal(size=(n, 4)),
        opacity_logits=rng.uniform(*opacity_range, size=n),
    )


def concat(*parts):
    return {k: np.concatenate([p[k] for p in parts], axis=0) for k in parts[0]}


def finish_scene(rng, g, sh_degree, F):
    n = g["means"].shape[0]
    K = (sh_degree + 1) ** 2
    g["sh"] = rng.normal(0.0, 0.3, size=(n, K, 3))
    g["features"] = rng.normal(size=(n, F))
    return {k: f32(v) for k, v in g.items()}


# Each case: name -> (description, builder(rng) -> (cam, gaussians, sh_degree, background))


def case_single(rng):
    cam = make_camera(rng, 50, 37, 40.0, 40.0, 25.0, 18.5, rotated=False)
    g = dict(
        means=np.array([[0.1, -0.05, 3.0]]) + rng.normal(0, 0.01, size=(1, 3)),
        log_scales=np.log([[0.3, 0.2, 0.25]]) + rng.normal(0, 0.05, size=(1, 3)),
        quats=rng.normal(size=(1, 4)),
        opacity_logits=np.array([2.0]) + rng.normal(0, 0.1, size=1),
    )
    return cam, finish_scene(rng, g, 0, 0), 0, [0.0, 0.0, 0.0]


def case_overlap5(rng):
    cam = make_camera(rng, 64, 48, 50.0, 50.0, 32.0, 24.0, rotated=True)
    g = random_gaussians(rng, cam, 5, z_range=(3.0, 5.0), log_scale_range=(-1.0, -0.3),
                         scene_size=1.0, margin=-0.25, opacity_range=(-1.0, 3.0))
    return cam, finish_scene(rng, g, 1, 3), 1, [0.0, 0.0, 0.0]


def case_rand50_d0(rng):
    cam = make_camera(rng, 50, 37, 40.0, 40.0, 25.0, 18.5, rotated=True)
    g = random_gaussians(rng, cam, 50)
    return cam, finish_scene(rng, g, 0, 16), 0, [0.0, 0.0, 0.0]


def case_rand50_d2(rng):
    cam = make_camera(rng, 33, 20, 26.0, 26.0, 16.5, 10.0, rotated=True)
    g = random_gaussians(rng, cam, 50)
    return cam, finish_scene(rng, g, 2, 0), 2, [0.0, 0.0, 0.0]


def case_rand300_d1(rng):
    cam = make_camera(rng, 64, 48, 50.0, 50.0, 32.0, 24.0, rotated=True)
    g = random_gaussians(rng, cam, 300)
    return cam, finish_scene(rng, g, 1, 3), 1, [0.0, 0.0, 0.0]


def case_rand300_d3_bg(rng):
    cam = make_camera(rng, 50, 37, 40.0, 40.0, 25.0, 18.5, rotated=True)
    g = random_gaussians(rng, cam, 300)
    return cam, finish_scene(rng, g, 3, 0), 3, [0.25, 0.5, 0.875]


def case_dense1500_stop(rng):
    cam = make_camera(rng, 33, 20, 26.0, 26.0, 16.5, 10.0, rotated=True)
    g = random_gaussians(rng, cam, 1500, z_range=(2.0, 6.0), log_scale_range=(-4.0, -2.5),
                         scene_size=2.0, margin=0.05, opacity_range=(-1.0, 4.0))
    return cam, finish_scene(rng, g, 1, 3), 1, [0.0, 0.0, 0.0]


def case_offcentre_aniso(rng):
    cam = make_camera(rng, 50, 37, 48.0, 36.0, 18.25, 22.75, rotated=True)
    g = random_gaussians(rng, cam, 100)
    return cam, finish_scene(rng, g, 2, 16), 2, [0.0, 0.0, 0.0]


def case_near_clamp(rng):
    W, H = 64, 48
    cam = make_camera(rng, W, H, 50.0, 50.0, 32.0, 24.0, rotated=True)
    parts = [random_gaussians(rng, cam, 20)]

    def at(u, v, z, log_scale_range, scene_size=1.0):
        n = len(z)
        p_c = pixels_to_cam(cam, np.asarray(u), np.asarray(v), np.asarray(z))
        return dict(
            means=cam_to_world(cam, p_c),
            log_scales=rng.uniform(*log_scale_range, size=(n, 3)) + math.log(scene_size),
            quats=rng.normal(size=(n, 4)),
            opacity_logits=rng.uniform(-2.0, 4.0, size=n),
        )

    # behind the camera
    n = 8
    parts.append(at(rng.uniform(0, W, n), rng.uniform(0, H, n), rng.uniform(-4.0, -0.3, n),
                    (-3.0, -1.0)))
    # between the camera and the near plane (culled), and just past it (huge on screen)
    n = 4
    parts.append(at(rng.uniform(0, W, n), rng.uniform(0, H, n), rng.uniform(0.002, 0.008, n),
                    (-7.0, -5.0)))
    parts.append(at(rng.uniform(0, W, n), rng.uniform(0, H, n), rng.uniform(0.05, 0.3, n),
                    (-5.0, -3.5)))
    # far off-screen, small (box misses the image)
    n = 8
    side = rng.integers(0, 2, n)
    u = np.where(side == 0, rng.uniform(-3 * W, -W, n), rng.uniform(2 * W, 4 * W, n))
    parts.append(at(u, rng.uniform(-H, 2 * H, n), rng.uniform(2.0, 6.0, n), (-4.0, -2.5)))
    # large, centre beyond the 1.3x tan-fov limit on each side, box reaching into the image
    n = 12
    z = rng.uniform(2.0, 5.0, n)
    k = np.arange(n) % 4
    u = np.where(k == 0, rng.uniform(W * 1.2, W * 1.45, n),
                 np.where(k == 1, rng.uniform(-W * 0.45, -W * 0.2, n), rng.uniform(0, W, n)))
    v = np.where(k == 2, rng.uniform(H * 1.2, H * 1.45, n),
                 np.where(k == 3, rng.uniform(-H * 0.45, -H * 0.2, n), rng.uniform(0, H, n)))
    parts.append(at(u, v, z, (-1.3, -0.6)))
    g = concat(*parts)
    return cam, finish_scene(rng, g, 3, 3), 3, [0.0, 0.0, 0.0]


CASES = [
    ("single", case_single, 1000,
     "one Gaussian in front of an identity camera, SH degree 0"),
    ("overlap5", case_overlap5, 2000,
     "5 large overlapping Gaussians, rotated camera, SH degree 1, 3 features"),
    ("rand50_d0", case_rand50_d0, 3000,
     "50 random Gaussians, SH degree 0, 16 features"),
    ("rand50_d2", case_rand50_d2, 4000,
     "50 random Gaussians on a 33x20 image, SH degree 2"),
    ("rand300_d1", case_rand300_d1, 5000,
     "300 random Gaussians, SH degree 1, 3 features"),
    ("rand300_d3_bg", case_rand300_d3_bg, 6000,
     "300 random Gaussians, SH degree 3, non-black background"),
    ("dense1500_stop", case_dense1500_stop, 7000,
     "1500 small Gaussians on 33x20: many pixels hit the T <= 1e-4 stop; SH 1, 3 features"),
    ("offcentre_aniso", case_offcentre_aniso, 8000,
     "off-centre principal point, fx != fy, SH degree 2, 16 features"),
    ("near_clamp", case_near_clamp, 9000,
     "Gaussians behind the camera, inside the near plane, far off-screen, and large ones "
     "centred beyond the 1.3x tan-fov limit (Jacobian clamp active); SH degree 3, 3 features"),
]


# ----------------------------------------------------------------------------
# Oracle: gsplat projection + SH, dense compositor
# ----------------------------------------------------------------------------


def composite(means2d, conics, depths, opacities, colors, feats, visible, W, H, background):
    """Dense front-to-back compositor with the classic 3DGS / gsplat 1.5 rules.

    Every visible Gaussian (radius > 0 from the projection) is evaluated at every
    pixel centre (x+0.5, y+0.5) in order of camera-space depth. gsplat evaluates a
    Gaussian at every pixel of the 16x16 tiles its box touches, so "every pixel" is
    the same thing as long as alpha < 1/255 outside the box: that is checked in
    ``run_case`` (pairs_outside_box must be 0).

        sigma = 0.5 (a dx^2 + c dy^2) + b dx dy,  alpha = min(0.999, o exp(-sigma))
        skip if sigma < 0 or alpha < 1/255
        next_T = T (1 - alpha); if next_T <= 1e-4 the pixel stops, this one is not blended
        else w = alpha T is blended, T = next_T

    The skip and stop decisions are hard (made without gradient); gradients flow
    through the alphas of blended pairs only.
    """
    P = H * W
    ys, xs = torch.meshgrid(torch.arange(H, dtype=torch.float64),
                            torch.arange(W, dtype=torch.float64), indexing="ij")
    px = (xs + 0.5).reshape(-1)
    py = (ys + 0.5).reshape(-1)

    vis_idx = torch.nonzero(visible).reshape(-1)
    order = vis_idx[torch.argsort(depths.detach()[vis_idx], stable=True)]
    n = len(order)

    m = means2d[order]
    c = conics[order]
    dx = px[None, :] - m[:, 0:1]
    dy = py[None, :] - m[:, 1:2]
    sigma = 0.5 * (c[:, 0:1] * dx * dx + c[:, 2:3] * dy * dy) + c[:, 1:2] * dx * dy
    raw = opacities[order][:, None] * torch.exp(-sigma)
    alpha = torch.clamp_max(raw, ALPHA_MAX)

    # --- hard decisions, sequential over Gaussians, vectorised over pixels ---
    a_np = alpha.detach().numpy()
    s_np = sigma.detach().numpy()
    r_np = raw.detach().numpy()
    blend = np.zeros((n, P), dtype=bool)
    T = np.ones(P)
    done = np.zeros(P, dtype=bool)
    diag = dict(border_alpha=0, border_T=0, border_clamp=0)
    for i in range(n):
        live = ~done
        ok = live & (s_np[i] >= 0.0) & (a_np[i] >= ALPHA_MIN)
        next_T = T * (1.0 - a_np[i])
        stop = ok & (next_T <= T_STOP)
        bl = ok & ~stop
        diag["border_alpha"] += int(np.sum(live & (np.abs(a_np[i] - ALPHA_MIN) <= 1e-5 * ALPHA_MIN)))
        diag["border_T"] += int(np.sum(ok & (np.abs(next_T - T_STOP) <= 1e-3 * T_STOP)))
        diag["border_clamp"] += int(np.sum(live & (np.abs(r_np[i] - ALPHA_MAX) <= 1e-5)))
        done |= stop
        T = np.where(bl, next_T, T)
        blend[i] = bl
    diag["stopped_pixels"] = int(done.sum())
    diag["blended_pairs"] = int(blend.sum())
    diag["max_blended_per_pixel"] = int(blend.sum(axis=0).max()) if n else 0
    diag["above_threshold_np"] = (a_np >= ALPHA_MIN)  # for the box check
    diag["order"] = order

    # --- differentiable blending with the decisions fixed ---
    B = torch.from_numpy(blend).to(torch.float64)
    a = alpha * B
    T_incl = torch.cumprod(1.0 - a, dim=0)  # transmittance after each Gaussian
    ones = torch.ones(1, P)
    T_excl = torch.cat([ones, T_incl[:-1]], dim=0)  # transmittance before it
    w = a * T_excl  # (n, P)
    T_final = T_incl[-1] if n else torch.ones(P)

    bg = torch.tensor(background, dtype=torch.float64)
    rgb = (w.T @ colors[order] + T_final[:, None] * bg[None, :]).reshape(H, W, 3)
    alpha_img = (1.0 - T_final).reshape(H, W)
    depth = (w.T @ depths[order]).reshape(H, W)
    feats_out = (w.T @ feats[order]).reshape(H, W, feats.shape[1])
    return dict(rgb=rgb, alpha=alpha_img, depth=depth, features_out=feats_out,
                w=w, a=a, blend=blend, order=order), diag


def run_case(cam, g, sh_degree, background, rng):
    W, H = cam["W"], cam["H"]
    N = g["means"].shape[0]
    F = g["features"].shape[1]

    leaf = {k: torch.tensor(v, requires_grad=True) for k, v in g.items()}
    viewmat = torch.tensor(cam["viewmat"])
    K = torch.tensor([[cam["fx"], 0.0, cam["cx"]], [0.0, cam["fy"], cam["cy"]], [0.0, 0.0, 1.0]])

    # --- gsplat projection (its PyTorch reference implementation) ---
    scales = torch.exp(leaf["log_scales"])
    covars, _ = gs_ref._quat_scale_to_covar_preci(
        leaf["quats"], scales, compute_covar=True, compute_preci=False, triu=False)
    radii, means2d, depths, conics, _ = gs_ref._fully_fused_projection(
        leaf["means"], covars, viewmat[None], K[None], W, H,
        eps2d=EPS2D, near_plane=NEAR, far_plane=FAR, calc_compensations=False,
        camera_model="pinhole")
    radii, means2d, depths, conics = radii[0], means2d[0], depths[0], conics[0]
    means2d.retain_grad()
    visible = (radii > 0).all(dim=-1)

    # --- colours as gsplat's rasterization(): SH(dirs = mean - camera centre) + 0.5, >= 0 ---
    campos = torch.inverse(viewmat)[:3, 3]
    dirs = leaf["means"] - campos[None, :]
    sh_colors = gs_ref._spherical_harmonics(sh_degree, dirs, leaf["sh"])
    colors = torch.clamp_min(sh_colors + 0.5, 0.0)

    opacities = torch.sigmoid(leaf["opacity_logits"])
    out, diag = composite(means2d, conics, depths, opacities, colors, leaf["features"],
                          visible, W, H, background)

    # --- diagnostics from gsplat's own pieces (no grad) ---
    with torch.no_grad():
        means_c, covars_c = gs_ref._world_to_cam(leaf["means"], covars, viewmat[None])
        _, cov2d = gs_ref._persp_proj(means_c, covars_c, K[None], W, H)
        means_c, cov2d = means_c[0].numpy(), cov2d[0].numpy()
    cov2d = cov2d + EPS2D * np.eye(2)
    z = means_c[:, 2]
    vis = visible.numpy()
    m2 = means2d.detach().numpy()
    op = opacities.detach().numpy()
    diag_xx = np.stack([cov2d[:, 0, 0], cov2d[:, 1, 1]], axis=-1)
    ext_sigma = 3.33 * np.sqrt(diag_xx)
    r_np = radii.numpy().astype(np.float64)
    assert np.array_equal(r_np[vis], np.ceil(ext_sigma[vis])), "radius rule differs"
    # opacity-aware box of gsplat 1.5's CUDA projection (when opacities are passed)
    extend = np.minimum(3.33, np.sqrt(2.0 * np.log(np.maximum(op, 1e-30) / ALPHA_MIN)))
    ext_op = extend[:, None] * np.sqrt(diag_xx)
    r_op = np.ceil(ext_op)
    inside_op = ((m2[:, 0] + r_op[:, 0] > 0) & (m2[:, 0] - r_op[:, 0] < W)
                 & (m2[:, 1] + r_op[:, 1] > 0) & (m2[:, 1] - r_op[:, 1] < H))
    vis_op = (z > NEAR) & (z < FAR) & (op >= ALPHA_MIN) & inside_op
    r_op[~vis_op] = 0.0

    # Jacobian clamp of _persp_proj: is tx/tz outside its limits?
    fx, fy, cx, cy = cam["fx"], cam["fy"], cam["cx"], cam["cy"]
    lims = dict(xp=(W - cx) / fx + 0.3 * 0.5 * W / fx, xn=cx / fx + 0.3 * 0.5 * W / fx,
                yp=(H - cy) / fy + 0.3 * 0.5 * H / fy, yn=cy / fy + 0.3 * 0.5 * H / fy)
    with np.errstate(divide="ignore", invalid="ignore"):
        rx, ry = means_c[:, 0] / z, means_c[:, 1] / z
    clamped = (rx > lims["xp"]) | (rx < -lims["xn"]) | (ry > lims["yp"]) | (ry < -lims["yn"])
    border_jac = ((np.abs(rx - lims["xp"]) < 1e-4 * lims["xp"]) | (np.abs(rx + lims["xn"]) < 1e-4 * lims["xn"])
                  | (np.abs(ry - lims["yp"]) < 1e-4 * lims["yp"]) | (np.abs(ry + lims["yn"]) < 1e-4 * lims["yn"]))

    def near_int(x):  # ceil() within float32 noise of flipping
        return np.abs(x - np.round(x)) < 1e-4 * np.maximum(1.0, x)

    def box_edges(r):
        return ((np.abs(m2[:, 0] + r[:, 0]) < 1e-3) | (np.abs(m2[:, 0] - r[:, 0] - W) < 1e-3)
                | (np.abs(m2[:, 1] + r[:, 1]) < 1e-3) | (np.abs(m2[:, 1] - r[:, 1] - H) < 1e-3))

    def inside(r):
        return ((m2[:, 0] + r[:, 0] > 0) & (m2[:, 0] - r[:, 0] < W)
                & (m2[:, 1] + r[:, 1] > 0) & (m2[:, 1] - r[:, 1] < H))

    zok = (z > NEAR) & (z < FAR)
    # a radius matters (stats, culling) only for Gaussians visible with it or with it + 1
    matters = zok & (inside(np.ceil(ext_sigma) + 1) | inside(np.ceil(ext_op) + 1))
    border = dict(
        near=int(np.sum(np.abs(z - NEAR) < 1e-4)),
        radius=int(np.sum(matters[:, None] & near_int(ext_sigma))),
        radius_op=int(np.sum((matters & (op >= ALPHA_MIN))[:, None] & near_int(ext_op))),
        box=int(np.sum(zok & (box_edges(np.ceil(ext_sigma)) | box_edges(np.ceil(ext_op))))),
        jacobian=int(np.sum(zok & border_jac)),
        color=int(np.sum(vis[:, None] & (np.abs(sh_colors.detach().numpy() + 0.5) < 1e-5))),
        alpha=diag["border_alpha"], T=diag["border_T"], clamp999=diag["border_clamp"],
    )

    # gsplat only evaluates pixels in tiles touched by the box; the dense compositor
    # evaluates all pixels. Equivalent iff alpha < 1/255 outside the (tighter,
    # opacity-aware) box. Check on every pair.
    order = diag["order"].numpy()
    px = np.tile(np.arange(W) + 0.5, H)
    py = np.repeat(np.arange(H) + 0.5, W)
    mo, ro = m2[order], r_op[order]
    out_box = ((np.abs(px[None, :] - mo[:, 0:1]) > ro[:, 0:1])
               | (np.abs(py[None, :] - mo[:, 1:2]) > ro[:, 1:2]))
    pairs_outside_box = int(np.sum(out_box & diag["above_threshold_np"]))

    # --- statistics and splat-back (blended pairs only) ---
    w = out["w"].detach().numpy()
    a = out["a"].detach().numpy()
    blend = out["blend"]
    weight_sum = np.zeros(N)
    alpha_sum = np.zeros(N)
    pixel_count = np.zeros(N)
    weight_sum[order] = w.sum(axis=1)
    alpha_sum[order] = a.sum(axis=1)
    pixel_count[order] = blend.sum(axis=1)
    visibility = np.where(alpha_sum > 0, weight_sum / np.where(alpha_sum > 0, alpha_sum, 1.0), 0.0)
    splat_in = f32(rng.normal(size=(H, W, 4)))
    splat_out = np.zeros((N, 4))
    sw = w @ splat_in.reshape(-1, 4)
    ws = w.sum(axis=1)
    splat_out[order] = np.where(ws[:, None] > 0, sw / np.where(ws > 0, ws, 1.0)[:, None], 0.0)

    # --- backward ---
    v = dict(v_rgb=f32(rng.normal(size=(H, W, 3))), v_alpha=f32(rng.normal(size=(H, W))),
             v_depth=f32(rng.normal(size=(H, W))), v_features=f32(rng.normal(size=(H, W, F))))
    L = ((torch.tensor(v["v_rgb"]) * out["rgb"]).sum()
         + (torch.tensor(v["v_alpha"]) * out["alpha"]).sum()
         + (torch.tensor(v["v_depth"]) * out["depth"]).sum()
         + (torch.tensor(v["v_features"]) * out["features_out"]).sum())
    L.backward()

    def grad(t):
        return t.grad.numpy() if t.grad is not None else np.zeros(tuple(t.shape))

    arrays = dict(g)
    arrays.update(
        rgb=out["rgb"].detach().numpy(), alpha=out["alpha"].detach().numpy(),
        depth=out["depth"].detach().numpy(), features_out=out["features_out"].detach().numpy(),
        means2d=m2, depths=depths.detach().numpy(), radii=r_np, radii_opacity_aware=r_op,
        weight_sum=weight_sum, alpha_sum=alpha_sum, pixel_count=pixel_count,
        visibility=visibility, splat_in=splat_in, splat_out=splat_out,
        grad_means=grad(leaf["means"]), grad_log_scales=grad(leaf["log_scales"]),
        grad_quats=grad(leaf["quats"]), grad_opacity_logits=grad(leaf["opacity_logits"]),
        grad_sh=grad(leaf["sh"]), grad_features=grad(leaf["features"]),
        grad_means2d=means2d.grad.numpy(),
    )
    arrays.update(v)
    summary = dict(
        N=N, visible=int(vis.sum()), visible_opacity_aware=int(vis_op.sum()),
        blended_pairs=diag["blended_pairs"], stopped_pixels=diag["stopped_pixels"],
        max_blended_per_pixel=diag["max_blended_per_pixel"],
        jacobian_clamped_visible=int(np.sum(clamped & vis)),
        jacobian_clamped_in_front=int(np.sum(clamped & zok)),
        radii_differ_from_opacity_aware=int(np.sum(np.any(r_np != r_op, axis=1))),
        pairs_outside_box=pairs_outside_box,
    )
    return arrays, summary, border


# ----------------------------------------------------------------------------
# Output
# ----------------------------------------------------------------------------


def save_npy(path, arr):
    arr = np.ascontiguousarray(np.asarray(arr, dtype="<f4"))
    assert np.all(np.isfinite(arr)), path
    np.lib.format.write_array(open(path, "wb"), arr, version=(1, 0))


OPTIONAL_F = {"features", "features_out", "v_features", "grad_features"}


def write_case(out_dir, name, cam, arrays, sh_degree, background, description):
    d = os.path.join(out_dir, name)
    os.makedirs(d, exist_ok=True)
    for f in os.listdir(d):  # drop stale files from earlier runs
        os.remove(os.path.join(d, f))
    N, F = arrays["means"].shape[0], arrays["features"].shape[1]
    meta = dict(width=cam["W"], height=cam["H"], fx=cam["fx"], fy=cam["fy"], cx=cam["cx"],
                cy=cam["cy"], viewmat=[[float(x) for x in row] for row in cam["viewmat"]],
                background=[f32_scalar(b) for b in background], sh_degree=sh_degree,
                num_gaussians=N, num_features=F, description=description)
    with open(os.path.join(d, "meta.json"), "w") as fh:
        json.dump(meta, fh, indent=1)
        fh.write("\n")
    for k, v in sorted(arrays.items()):
        if F == 0 and k in OPTIONAL_F:
            continue
        save_npy(os.path.join(d, k + ".npy"), v)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=DEFAULT_OUT)
    ap.add_argument("--only", nargs="*", help="run only these cases (index.json still lists all)")
    ap.add_argument("--max-resamples", type=int, default=1000)
    args = ap.parse_args()

    print(f"gsplat {gsplat.__version__} ({gs_ref.__file__}), torch {torch.__version__}")
    os.makedirs(args.out, exist_ok=True)
    names = [c[0] for c in CASES]
    for name, builder, seed0, desc in CASES:
        if args.only and name not in args.only:
            continue
        for resamples in range(args.max_resamples + 1):
            seed = seed0 + resamples
            rng = np.random.default_rng(seed)
            cam, g, sh_degree, background = builder(rng)
            background = list(f32(background))
            arrays, summary, border = run_case(cam, g, sh_degree, background, rng)
            if sum(border.values()) == 0 and summary["pairs_outside_box"] == 0:
                break
            print(f"  {name} seed {seed}: borderline {border} "
                  f"pairs_outside_box={summary['pairs_outside_box']}, resampling")
        else:
            sys.exit(f"{name}: no clean seed in {args.max_resamples} tries")
        description = (f"{desc}. Seed {seed} ({resamples} resamples). gsplat "
                       f"{gsplat.__version__} _torch_impl projection/SH + dense float64 compositor.")
        write_case(args.out, name, cam, arrays, sh_degree, background, description)
        W, H = cam["W"], cam["H"]
        print(f"{name:16s} {W}x{H} d={sh_degree} F={g['features'].shape[1]:2d} seed={seed} "
              f"resamples={resamples} " + " ".join(f"{k}={v}" for k, v in summary.items()))
    with open(os.path.join(args.out, "index.json"), "w") as fh:
        json.dump(dict(gsplat=gsplat.__version__, torch=torch.__version__, cases=names), fh, indent=1)
        fh.write("\n")


if __name__ == "__main__":
    main()

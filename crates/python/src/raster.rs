//! gsplat-style rasterization over the library's CPU rasterizer, and its backward.
//!
//! Conventions are gsplat's `rasterization()` (1.5): activated scales and opacities,
//! (w, x, y, z) quaternions (normalised inside), `viewmats` world-to-camera in the
//! OpenCV convention, colors either SH coefficients `(N, K, 3)` with `sh_degree`
//! (colour = SH + 0.5 clamped at 0) or features `(N, D)` blended as they are, and
//! `render_mode` RGB, D, ED, RGB+D, RGB+ED with ED = D / max(alpha, 1e-10).
//!
//! The library stores log-scales and opacity logits (the INRIA parameterisation); the
//! conversion is `ln s` and `ln o − ln(1 − o)` with opacities used within
//! [`OPACITY_EPS`, 1 − `OPACITY_EPS`] and zero scales as [`MIN_SCALE`]; gradients are
//! chained back exactly: dL/ds = dL/d(ln s) / s, dL/do = dL/dlogit / (σ(1 − σ)).

use crate::arrays::{rows, slice, to_numpy, value_error};
use crate::io::cameras_from_arrays;
use numpy::{PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rayon::prelude::*;
use transsplat_raster::{backward, render, ClampGrad, Frame, Grads, ImageGrads, RenderOptions, Splats};
use transsplat_scene::{sh_coeffs, sigmoid, Camera};

/// Opacities are used within [ε, 1 − ε] so that their logit is finite.
pub const OPACITY_EPS: f64 = 1e-6;
/// A zero scale is used as this (its logarithm must be finite).
pub const MIN_SCALE: f32 = 1e-30;
/// gsplat's floor on alpha when dividing accumulated depth into expected depth.
const ED_EPS: f32 = 1e-10;

/// What `render_mode` asks for.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Mode {
    color: bool,
    depth: Depth,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Depth {
    None,
    /// Σ wᵢ zᵢ.
    Accumulated,
    /// Σ wᵢ zᵢ / max(α, 1e-10).
    Expected,
}

impl Mode {
    fn parse(s: &str) -> PyResult<Mode> {
        let (color, depth) = match s {
            "RGB" => (true, Depth::None),
            "D" => (false, Depth::Accumulated),
            "ED" => (false, Depth::Expected),
            "RGB+D" => (true, Depth::Accumulated),
            "RGB+ED" => (true, Depth::Expected),
            _ => {
                return Err(value_error(format!(
                    "render_mode: expected one of RGB, D, ED, RGB+D, RGB+ED, got {s:?}"
                )))
            }
        };
        Ok(Mode { color, depth })
    }

    /// Output channels for `d` colour channels.
    fn channels(&self, d: usize) -> usize {
        (if self.color { d } else { 0 }) + usize::from(self.depth != Depth::None)
    }
}

/// The Gaussians of one call in the library's parameterisation, with what is needed to
/// chain gradients back to gsplat's.
struct Inputs<'a> {
    means: &'a [[f32; 3]],
    quats: &'a [[f32; 4]],
    log_scales: Vec<[f32; 3]>,
    /// The scales used (zero raised to [`MIN_SCALE`]).
    scales: Vec<[f32; 3]>,
    logits: Vec<f32>,
    /// SH `(N, K, 3)`, or zeros of degree 0 when colors are features.
    sh: std::borrow::Cow<'a, [f32]>,
    sh_layout: u32,
    sh_degree: u32,
    features: &'a [f32],
    /// Colour channels: 3 for SH, D for features.
    d: usize,
    sh_mode: bool,
}

impl Inputs<'_> {
    fn splats(&self) -> Splats<'_> {
        Splats {
            means: self.means,
            log_scales: &self.log_scales,
            rotations: self.quats,
            opacity_logits: &self.logits,
            sh: &self.sh,
            sh_degree: self.sh_layout,
            active_sh_degree: self.sh_degree,
            features: self.features,
            num_features: if self.sh_mode { 0 } else { self.d },
        }
    }
}

/// Checks and converts gsplat's arguments.
#[allow(clippy::too_many_arguments)]
fn inputs<'a>(
    means: &'a PyReadonlyArrayDyn<'_, f32>,
    quats: &'a PyReadonlyArrayDyn<'_, f32>,
    scales: &'a PyReadonlyArrayDyn<'_, f32>,
    opacities: &'a PyReadonlyArrayDyn<'_, f32>,
    colors: &'a PyReadonlyArrayDyn<'_, f32>,
    sh_degree: Option<u32>,
) -> PyResult<Inputs<'a>> {
    let m = slice("means", means, &[None, Some(3)])?;
    let n = m.len() / 3;
    let q = slice("quats", quats, &[Some(n), Some(4)])?;
    let s = slice("scales", scales, &[Some(n), Some(3)])?;
    let o = slice("opacities", opacities, &[Some(n)])?;
    if let Some(i) = s.iter().position(|&v| v < 0.0) {
        return Err(value_error(format!("scales: negative value {} at Gaussian {}", s[i], i / 3)));
    }
    if let Some(i) = o.iter().position(|&v| !(0.0..=1.0).contains(&v)) {
        return Err(value_error(format!("opacities: value {} at Gaussian {i} is outside [0, 1]", o[i])));
    }
    let scales_used: Vec<[f32; 3]> = rows::<3>(s).par_iter().map(|r| r.map(|v| v.max(MIN_SCALE))).collect();
    let log_scales = scales_used.par_iter().map(|r| r.map(f32::ln)).collect();
    let logits = o
        .par_iter()
        .map(|&v| {
            let v = (v as f64).clamp(OPACITY_EPS, 1.0 - OPACITY_EPS);
            (v.ln() - (-v).ln_1p()) as f32
        })
        .collect();
    let (sh, sh_layout, degree, features, d) = match sh_degree {
        Some(deg) => {
            let c = slice("colors", colors, &[Some(n), None, Some(3)])?;
            let k = colors.shape()[1];
            let layout = (0..4u32).find(|&l| sh_coeffs(l) == k).ok_or_else(|| {
                value_error(format!("colors: expected 1, 4, 9 or 16 SH coefficients (N, K, 3), got K = {k}"))
            })?;
            if deg > layout {
                return Err(value_error(format!(
                    "sh_degree: {deg} needs {} SH coefficients, colors has {k}",
                    sh_coeffs(deg)
                )));
            }
            (std::borrow::Cow::Borrowed(c), layout, deg, &[][..], 3)
        }
        None => {
            let c = slice("colors", colors, &[Some(n), None])?;
            let d = colors.shape()[1];
            if d == 0 {
                return Err(value_error("colors: features need at least one channel, got shape (N, 0)"));
            }
            (std::borrow::Cow::Owned(vec![0.0; n * 3]), 0, 0, c, d)
        }
    };
    Ok(Inputs {
        means: rows::<3>(m),
        quats: rows::<4>(q),
        log_scales,
        scales: scales_used,
        logits,
        sh,
        sh_layout,
        sh_degree: degree,
        features,
        d,
        sh_mode: sh_degree.is_some(),
    })
}

/// The state one rasterization call keeps for its backward: each camera's frame, its
/// alpha and accumulated depth (for ED), and the call's settings.
#[pyclass(module = "transsplat._core", frozen)]
pub struct Frames {
    frames: Vec<Frame>,
    cams: Vec<Camera>,
    alphas: Vec<Vec<f32>>,
    depths: Vec<Vec<f32>>,
    backgrounds: Vec<f32>,
    mode: Mode,
    n: usize,
    d: usize,
    sh_degree: Option<u32>,
    width: usize,
    height: usize,
}

#[pymethods]
impl Frames {
    fn __repr__(&self) -> String {
        format!("<transsplat rasterization state: {} cameras, {} Gaussians>", self.cams.len(), self.n)
    }
}

/// What [`rasterize`] returns: colors, alphas, statistics, the state for the backward.
type Rendered<'py> = (Bound<'py, PyAny>, Bound<'py, PyAny>, Bound<'py, PyDict>, Frames);

/// Renders every camera; returns colors `(C, H, W, channels)`, alphas `(C, H, W, 1)`,
/// the per-Gaussian statistics and the state for [`rasterize_backward`].
#[pyfunction]
#[pyo3(signature = (means, quats, scales, opacities, colors, viewmats, ks, width, height, sh_degree, backgrounds, render_mode))]
#[allow(clippy::too_many_arguments)]
pub fn rasterize<'py>(
    py: Python<'py>,
    means: PyReadonlyArrayDyn<'py, f32>,
    quats: PyReadonlyArrayDyn<'py, f32>,
    scales: PyReadonlyArrayDyn<'py, f32>,
    opacities: PyReadonlyArrayDyn<'py, f32>,
    colors: PyReadonlyArrayDyn<'py, f32>,
    viewmats: PyReadonlyArrayDyn<'py, f32>,
    ks: PyReadonlyArrayDyn<'py, f32>,
    width: u32,
    height: u32,
    sh_degree: Option<u32>,
    backgrounds: Option<PyReadonlyArrayDyn<'py, f32>>,
    render_mode: &str,
) -> PyResult<Rendered<'py>> {
    let mode = Mode::parse(render_mode)?;
    let inp = inputs(&means, &quats, &scales, &opacities, &colors, sh_degree)?;
    let c = viewmats.shape().first().copied().unwrap_or(0);
    let cams = cameras_from_arrays(&viewmats, &ks, &vec![(width, height); c], None)?;
    let d = inp.d;
    let bgs = match &backgrounds {
        Some(b) => slice("backgrounds", b, &[Some(c), Some(d)])?.to_vec(),
        None => vec![0.0; c * d],
    };
    let (n, w, h) = (inp.means.len(), width as usize, height as usize);
    let ch = mode.channels(d);
    let out = py.allow_threads(|| {
        let splats = inp.splats();
        let mut colors = vec![0.0f32; c * h * w * ch];
        let mut alphas = vec![0.0f32; c * h * w];
        let (mut radii, mut means2d, mut depths): (Vec<i32>, Vec<f32>, Vec<f32>) =
            (Vec::new(), Vec::new(), Vec::new());
        let mut frames = Vec::with_capacity(c);
        let (mut alpha_keep, mut depth_keep): (Vec<Vec<f32>>, Vec<Vec<f32>>) =
            (Vec::with_capacity(c), Vec::with_capacity(c));
        for (ci, cam) in cams.iter().enumerate() {
            let bg = &bgs[ci * d..(ci + 1) * d];
            let background = if inp.sh_mode { [bg[0], bg[1], bg[2]] } else { [0.0; 3] };
            let (img, frame) = render(&splats, cam, &RenderOptions { background });
            let out = &mut colors[ci * h * w * ch..(ci + 1) * h * w * ch];
            for p in 0..h * w {
                let px = &mut out[p * ch..(p + 1) * ch];
                let a = img.alpha[p];
                if mode.color {
                    if inp.sh_mode {
                        px[..3].copy_from_slice(&img.rgb[p * 3..p * 3 + 3]);
                    } else {
                        for k in 0..d {
                            px[k] = img.features[p * d + k] + (1.0 - a) * bg[k];
                        }
                    }
                }
                match mode.depth {
                    Depth::None => {}
                    Depth::Accumulated => px[ch - 1] = img.depth[p],
                    Depth::Expected => px[ch - 1] = img.depth[p] / a.max(ED_EPS),
                }
            }
            alphas[ci * h * w..(ci + 1) * h * w].copy_from_slice(&img.alpha);
            radii.extend(frame.radii().iter().flat_map(|r| r.map(|v| v as i32)));
            means2d.extend(frame.means2d().iter().flatten());
            depths.extend_from_slice(&frame.binned.depths);
            frames.push(frame);
            alpha_keep.push(img.alpha);
            depth_keep.push(if mode.depth == Depth::Expected { img.depth } else { Vec::new() });
        }
        (colors, alphas, radii, means2d, depths, frames, alpha_keep, depth_keep)
    });
    let (colors_out, alphas, radii, means2d, depths, frames, alpha_keep, depth_keep) = out;
    let meta = PyDict::new(py);
    meta.set_item("radii", to_numpy(py, radii, &[c, n, 2])?)?;
    meta.set_item("means2d", to_numpy(py, means2d, &[c, n, 2])?)?;
    meta.set_item("depths", to_numpy(py, depths, &[c, n])?)?;
    meta.set_item("width", width)?;
    meta.set_item("height", height)?;
    meta.set_item("n_cameras", c)?;
    meta.set_item("tile_size", 16)?;
    let state = Frames {
        frames,
        cams,
        alphas: alpha_keep,
        depths: depth_keep,
        backgrounds: bgs,
        mode,
        n,
        d,
        sh_degree,
        width: w,
        height: h,
    };
    Ok((to_numpy(py, colors_out, &[c, h, w, ch])?, to_numpy(py, alphas, &[c, h, w, 1])?, meta, state))
}

/// Gradients of a loss with respect to every input of [`rasterize`], given its
/// gradients with respect to the colors and (optionally) the alphas.
#[pyfunction]
#[pyo3(signature = (state, means, quats, scales, opacities, colors, v_colors, v_alphas=None))]
#[allow(clippy::too_many_arguments)]
pub fn rasterize_backward<'py>(
    py: Python<'py>,
    state: &Frames,
    means: PyReadonlyArrayDyn<'py, f32>,
    quats: PyReadonlyArrayDyn<'py, f32>,
    scales: PyReadonlyArrayDyn<'py, f32>,
    opacities: PyReadonlyArrayDyn<'py, f32>,
    colors: PyReadonlyArrayDyn<'py, f32>,
    v_colors: PyReadonlyArrayDyn<'py, f32>,
    v_alphas: Option<PyReadonlyArrayDyn<'py, f32>>,
) -> PyResult<Bound<'py, PyDict>> {
    let inp = inputs(&means, &quats, &scales, &opacities, &colors, state.sh_degree)?;
    if inp.means.len() != state.n || inp.d != state.d {
        return Err(value_error(format!(
            "the Gaussians ({} with {} colour channels) are not those of the forward call ({} with {})",
            inp.means.len(),
            inp.d,
            state.n,
            state.d
        )));
    }
    let c = state.cams.len();
    let (w, h) = (state.width, state.height);
    let ch = state.mode.channels(state.d);
    let vc = slice("v_render_colors", &v_colors, &[Some(c), Some(h), Some(w), Some(ch)])?;
    let va = match &v_alphas {
        Some(a) => Some(slice("v_render_alphas", a, &[Some(c), Some(h), Some(w), Some(1)])?),
        None => None,
    };
    let (n, d, mode, sh_mode) = (state.n, state.d, state.mode, inp.sh_mode);
    let (grads, means2d) = py.allow_threads(|| {
        let splats = inp.splats();
        let mut grads = Grads::zeros(n, inp.sh_layout, splats.num_features);
        let mut means2d = Vec::with_capacity(c * n * 2);
        for (ci, cam) in state.cams.iter().enumerate() {
            let hw = h * w;
            let vci = &vc[ci * hw * ch..(ci + 1) * hw * ch];
            let bg = &state.backgrounds[ci * d..(ci + 1) * d];
            let alpha = &state.alphas[ci];
            let mut g_color = vec![0.0f32; if mode.color { hw * d } else { 0 }];
            let mut g_alpha = match va {
                Some(a) => a[ci * hw..(ci + 1) * hw].to_vec(),
                None => vec![0.0f32; hw],
            };
            let mut g_depth = vec![0.0f32; if mode.depth == Depth::None { 0 } else { hw }];
            for p in 0..hw {
                let v = &vci[p * ch..(p + 1) * ch];
                if mode.color {
                    g_color[p * d..(p + 1) * d].copy_from_slice(&v[..d]);
                    if !sh_mode {
                        // out = F + (1 − α) bg.
                        g_alpha[p] -= (0..d).map(|k| v[k] * bg[k]).sum::<f32>();
                    }
                }
                match mode.depth {
                    Depth::None => {}
                    Depth::Accumulated => g_depth[p] = v[ch - 1],
                    Depth::Expected => {
                        let a = alpha[p];
                        g_depth[p] = v[ch - 1] / a.max(ED_EPS);
                        if a > ED_EPS {
                            g_alpha[p] -= v[ch - 1] * state.depths[ci][p] / (a * a);
                        }
                    }
                }
            }
            let (rgb, features) = if sh_mode { (&g_color[..], &[][..]) } else { (&[][..], &g_color[..]) };
            // An autograd function returns the derivative of what it rendered: the exact clamp.
            let ig = ImageGrads { rgb, alpha: &g_alpha, depth: &g_depth, features, clamp: ClampGrad::Exact };
            backward(&splats, cam, &state.frames[ci], &ig, &mut grads);
            let m2 = if ci + 1 < c {
                std::mem::replace(&mut grads.means2d, vec![[0.0; 2]; n])
            } else {
                std::mem::take(&mut grads.means2d)
            };
            means2d.extend(m2.into_iter().flatten());
        }
        // Back to gsplat's parameterisation.
        let mut g_scales = std::mem::take(&mut grads.log_scales);
        g_scales.par_iter_mut().zip(&inp.scales).for_each(|(g, s)| {
            for k in 0..3 {
                g[k] /= s[k];
            }
        });
        let g_opacities: Vec<f32> = grads
            .opacity_logits
            .par_iter()
            .zip(&inp.logits)
            .map(|(&g, &l)| {
                let o = sigmoid(l);
                g / (o * (1.0 - o))
            })
            .collect();
        ((grads, g_scales, g_opacities), means2d)
    });
    let ((grads, g_scales, g_opacities), means2d) = (grads, means2d);
    let out = PyDict::new(py);
    out.set_item("means", to_numpy(py, grads.means.into_flattened(), &[n, 3])?)?;
    out.set_item("quats", to_numpy(py, grads.rotations.into_flattened(), &[n, 4])?)?;
    out.set_item("scales", to_numpy(py, g_scales.into_flattened(), &[n, 3])?)?;
    out.set_item("opacities", to_numpy(py, g_opacities, &[n])?)?;
    let colors = if sh_mode {
        let k = sh_coeffs(inp.sh_layout);
        to_numpy(py, grads.sh, &[n, k, 3])?
    } else {
        to_numpy(py, grads.features, &[n, d])?
    };
    out.set_item("colors", colors)?;
    out.set_item("means2d", to_numpy(py, means2d, &[c, n, 2])?)?;
    Ok(out)
}

//! Mip-Splatting's 3D smoothing filter (Yu et al., "Mip-Splatting: Alias-free 3D
//! Gaussian Splatting", CVPR 2024, its section "3D Smoothing Filter"), as an option of the trainer
//! (`train --filter-3d`).
//!
//! A training camera at depth d with focal length f samples the world every d / f;
//! detail finer than that was never observed. Each Gaussian is low-passed in 3D by an
//! isotropic Gaussian of variance `s · (d̂ / f̂)²`, where d̂ is the smallest depth at which
//! a training camera sees its centre and f̂ the largest focal length
//! ([`variances`]). The convolution of two Gaussians is a Gaussian, so the filtered one
//! has scales `√(σ_j² + v)` along its own axes, and the filter keeps its integral, so its
//! opacity is multiplied by `√(Π σ_j² / Π (σ_j² + v))` ([`filtered`]): a Gaussian
//! far thinner than what the cameras resolve is drawn as a dim, resolvable one, and the
//! optimiser cannot keep sub-sample splats that only reproduce each training view's
//! pixels.
//!
//! The variance is a per-Gaussian property recomputed every [`UPDATE_INTERVAL`] steps and
//! after every densification (as Mip-Splatting does), kept in the model's carried extras
//! under [`EXTRA_NAME`] so that densification copies it, checkpoints hold it and a resumed
//! run continues bit-identically. The trainer renders the filtered parameters and pulls
//! the image gradients back to the raw ones ([`pull_back`]); the written scene has the
//! filter baked into its scales and opacities ([`bake`]), so any 3DGS renderer draws
//! what training saw. The 2D Mip filter of the same paper is not built: the
//! rasterizer keeps INRIA's 0.3-pixel dilation.

use transsplat_raster::Grads;
use transsplat_scene::{Camera, Extra, Gaussians};

/// Name of the carried per-Gaussian filter variance.
pub const EXTRA_NAME: &str = "filter_3d";
/// Steps between recomputations of the variances (Mip-Splatting's interval).
pub const UPDATE_INTERVAL: u64 = 100;
/// Mip-Splatting's variance factor `s`, in squared pixels.
pub const DEFAULT_VARIANCE: f32 = 0.2;
/// A centre nearer than this (camera-space z) is not sampled by that camera.
const NEAR: f32 = 0.2;
/// A centre counts as seen when it projects within the image widened by this share on
/// every side (Mip-Splatting's 15 % margin).
const MARGIN: f32 = 0.15;

/// The filter variance of every Gaussian (the sampling rate of the paper's 3D filter): `factor · (d̂ / f̂)²`, d̂ the nearest
/// depth (beyond [`NEAR`]) at which a camera sees the centre within its widened image,
/// f̂ the largest focal length. A centre no camera sees takes the largest d̂ of those
/// seen (Mip-Splatting's rule); with none seen at all, every variance is 0.
pub fn variances(means: &[[f32; 3]], cameras: &[Camera], factor: f32) -> Vec<f32> {
    use rayon::prelude::*;
    let focal = cameras.iter().map(|c| c.fx.max(c.fy)).fold(0.0f32, f32::max);
    let nearest: Vec<f32> = means
        .par_iter()
        .with_min_len(4096)
        .map(|p| {
            let mut best = f32::INFINITY;
            for c in cameras {
                let r = &c.rotation;
                let z = r[2][0] * p[0] + r[2][1] * p[1] + r[2][2] * p[2] + c.translation[2];
                if !(z > NEAR) || z >= best {
                    continue;
                }
                let x = r[0][0] * p[0] + r[0][1] * p[1] + r[0][2] * p[2] + c.translation[0];
                let y = r[1][0] * p[0] + r[1][1] * p[1] + r[1][2] * p[2] + c.translation[1];
                let (u, v) = (c.fx * x / z + c.cx, c.fy * y / z + c.cy);
                let (w, h) = (c.width as f32, c.height as f32);
                if u >= -MARGIN * w && u <= (1.0 + MARGIN) * w && v >= -MARGIN * h && v <= (1.0 + MARGIN) * h
                {
                    best = z;
                }
            }
            best
        })
        .collect();
    let farthest_seen = nearest.iter().copied().filter(|d| d.is_finite()).fold(f32::NAN, f32::max);
    if !(farthest_seen.is_finite() && focal > 0.0) {
        return vec![0.0; means.len()];
    }
    nearest
        .into_iter()
        .map(|d| {
            let d = if d.is_finite() { d } else { farthest_seen };
            factor * (d / focal) * (d / focal)
        })
        .collect()
}

/// The filtered log-scales and opacity logits of one Gaussian (the 3D filter's
/// convolution, normalised to keep the integral): scales
/// `√(σ_j² + v)`, opacity `sigmoid(o) · √(Π σ_j² / Π (σ_j² + v))`.
pub fn filtered(log_scales: [f32; 3], opacity_logit: f32, variance: f32) -> ([f32; 3], f32) {
    let mut out = [0.0; 3];
    let mut log_k = 0.0f32;
    for j in 0..3 {
        let s2 = (2.0 * log_scales[j]).exp();
        let t = s2 + variance;
        out[j] = 0.5 * t.ln();
        log_k += 0.5 * (2.0 * log_scales[j] - t.ln());
    }
    let alpha = (sigmoid(opacity_logit) * log_k.exp()).max(f32::MIN_POSITIVE);
    (out, alpha.ln() - (-alpha).ln_1p())
}

/// The filtered parameters of every Gaussian into `log_scales` and `opacity_logits`
/// (resized to the model, then written in place).
pub fn filter_all(
    g: &Gaussians,
    variance: &[f32],
    log_scales: &mut Vec<[f32; 3]>,
    opacity_logits: &mut Vec<f32>,
) {
    use rayon::prelude::*;
    log_scales.resize(g.len(), [0.0; 3]);
    opacity_logits.resize(g.len(), 0.0);
    log_scales
        .par_iter_mut()
        .zip(opacity_logits.par_iter_mut())
        .zip(g.log_scales.par_iter().zip(&g.opacity_logits).zip(variance))
        .with_min_len(4096)
        .for_each(|((ls, o), ((l, &raw), &v))| (*ls, *o) = filtered(*l, raw, v));
}

/// Pulls gradients with respect to the filtered log-scales l' and opacity logit o'
/// back to the raw ones (the chain rule of [`filtered`]). With ρ_j = σ_j² / (σ_j² + v)
/// and α' the filtered opacity: ∂l'_j/∂l_j = ρ_j, ∂o'/∂o = k σ(1 − σ) / (α'(1 − α'))
/// with k = √Π ρ_j, and ∂o'/∂l_j = (1 − ρ_j) / (1 − α'). `rows` limits the work to the
/// rows the backward pass wrote (`None`: every row).
pub fn pull_back(g: &Gaussians, variance: &[f32], grads: &mut Grads, rows: Option<&[u32]>) {
    let mut one = |i: usize| {
        let (dl, d_o) = (grads.log_scales[i], grads.opacity_logits[i]);
        let v = variance[i];
        let mut rho = [0.0f32; 3];
        let mut k = 1.0f32;
        for j in 0..3 {
            let s2 = (2.0 * g.log_scales[i][j]).exp();
            rho[j] = s2 / (s2 + v);
            k *= rho[j].sqrt();
        }
        let sigma = sigmoid(g.opacity_logits[i]);
        let alpha = sigma * k;
        let to_alpha = d_o / (alpha * (1.0 - alpha)).max(f32::MIN_POSITIVE);
        grads.opacity_logits[i] = to_alpha * k * sigma * (1.0 - sigma);
        for j in 0..3 {
            grads.log_scales[i][j] = dl[j] * rho[j] + to_alpha * alpha * (1.0 - rho[j]);
        }
    };
    match rows {
        Some(rows) => rows.iter().for_each(|&i| one(i as usize)),
        None => (0..g.len()).for_each(&mut one),
    }
}

/// The opacity reset in filtered terms (as Mip-Splatting resets): every allowed
/// Gaussian's *filtered* opacity is capped at `value`, its raw opacity set to what gives
/// that through the filter (at most just below 1). Capping the raw opacity instead would
/// leave a thin Gaussian at `value · k`, far below the reset value, and training after
/// the reset would start from a scene much dimmer than INRIA's reset leaves. Returns
/// the rows touched, as `densify::reset_opacity`.
pub fn reset_opacity(g: &mut Gaussians, variance: &[f32], value: f32, mask: Option<&[bool]>) -> Vec<bool> {
    let mut touched = vec![false; g.len()];
    for i in 0..g.len() {
        if mask.is_some_and(|m| !m[i]) {
            continue;
        }
        let k: f32 = (0..3)
            .map(|j| {
                let s2 = (2.0 * g.log_scales[i][j]).exp();
                (s2 / (s2 + variance[i])).sqrt()
            })
            .product();
        let filtered = (sigmoid(g.opacity_logits[i]) * k).min(value);
        let raw = (filtered / k.max(f32::MIN_POSITIVE)).clamp(f32::MIN_POSITIVE, 1.0 - 1e-6);
        g.opacity_logits[i] = raw.ln() - (-raw).ln_1p();
        touched[i] = true;
    }
    touched
}

/// The variances carried in `g`'s extras, if there are any.
pub fn carried(g: &Gaussians) -> Option<Vec<f32>> {
    g.extra.column(EXTRA_NAME)
}

/// Stores `variance` as the carried [`EXTRA_NAME`] column (added if absent).
pub fn carry(g: &mut Gaussians, variance: &[f32]) {
    let n = g.len();
    let extra = &mut g.extra;
    let k = match extra.names.iter().position(|name| name == EXTRA_NAME) {
        Some(k) => k,
        None => {
            let w = extra.width();
            let mut values = Vec::with_capacity(n * (w + 1));
            for i in 0..n {
                values.extend_from_slice(&extra.values[i * w..(i + 1) * w]);
                values.push(0.0);
            }
            extra.names.push(EXTRA_NAME.to_string());
            extra.values = values;
            w
        }
    };
    let w = extra.width();
    for (i, &v) in variance.iter().enumerate() {
        extra.values[i * w + k] = v;
    }
}

/// `g` with the filter baked into its scales and opacities and the carried column
/// removed: what a renderer without the filter draws as the trainer did.
pub fn bake(g: &Gaussians) -> Gaussians {
    let Some(variance) = carried(g) else {
        return g.clone();
    };
    let mut out = g.clone();
    filter_all(g, &variance, &mut out.log_scales, &mut out.opacity_logits);
    let k = g.extra.names.iter().position(|name| name == EXTRA_NAME).expect("carried column");
    let w = g.extra.width();
    out.extra = Extra {
        names: g.extra.names.iter().filter(|name| name.as_str() != EXTRA_NAME).cloned().collect(),
        values: g
            .extra
            .values
            .chunks_exact(w.max(1))
            .flat_map(|row| row.iter().enumerate().filter(|&(j, _)| j != k).map(|(_, &x)| x))
            .collect(),
    };
    out
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_variance_is_the_nearest_sampling_interval_squared_times_the_factor() {
        // A camera at the origin looking down +z, focal 100 px, 200 × 100 image.
        let near = Camera::pinhole("a", 200, 100, 100.0);
        let mut far = Camera::pinhole("b", 200, 100, 50.0);
        far.translation = [0.0, 0.0, 3.0]; // sees the world 3 further away
        let means = [[0.0, 0.0, 2.0], [0.0, 0.0, -2.5], [30.0, 0.0, 2.0], [0.0, 0.0, 0.1]];
        let v = variances(&means, &[near, far], 0.2);
        // Seen at depth 2 (first camera) and 5: nearest 2, focal max(100, 50) = 100.
        assert!((v[0] - 0.2 * (2.0f32 / 100.0).powi(2)).abs() < 1e-9, "{v:?}");
        // [1] is behind the first camera and at depth 0.5 in the second.
        assert!((v[1] - 0.2 * (0.5f32 / 100.0).powi(2)).abs() < 1e-12, "{v:?}");
        // [3] is nearer than NEAR to the first camera (not sampled there), 3.1 from the second.
        assert!((v[3] - 0.2 * (3.1f32 / 100.0).powi(2)).abs() < 1e-9, "{v:?}");
        // [2] projects far outside both images: unseen, it takes the largest seen depth, 3.1.
        assert!((v[2] - v[3]).abs() < 1e-12, "{v:?}");
    }

    #[test]
    fn filtering_widens_each_axis_and_keeps_the_integral() {
        // σ = (0.3, 0.4, 0.01), v = 0.0009 (σ_f = 0.03): σ' = √(σ² + v).
        let ls = [0.3f32.ln(), 0.4f32.ln(), 0.01f32.ln()];
        let (out, o) = filtered(ls, 0.0, 0.0009);
        let want = [0.0909f32.sqrt(), 0.1609f32.sqrt(), 0.001f32.sqrt()];
        for j in 0..3 {
            assert!((out[j].exp() - want[j]).abs() < 1e-6);
        }
        // α' = 0.5 · √(0.09 · 0.16 · 0.0001 / (0.0909 · 0.1609 · 0.001)).
        let k = (0.09f32 * 0.16 * 0.0001 / (0.0909 * 0.1609 * 0.001)).sqrt();
        assert!((sigmoid(o) - 0.5 * k).abs() < 1e-6, "{} {}", sigmoid(o), 0.5 * k);
        // No variance, no change.
        let (same, o2) = filtered(ls, 1.3, 0.0);
        assert!(same.iter().zip(&ls).all(|(a, b)| (a - b).abs() < 1e-6) && (o2 - 1.3).abs() < 1e-5);
    }

    #[test]
    fn the_pull_back_is_the_derivative_of_the_filter() {
        let g = Gaussians {
            means: vec![[0.0; 3]],
            log_scales: vec![[-2.0, -3.5, -5.0]],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]],
            opacity_logits: vec![0.7],
            sh_degree: 0,
            sh: vec![0.0; 3],
            extra: Extra::default(),
        };
        let v = [2e-4f32];
        // L = a · l' + b · o' for fixed a, b: its gradient to l' is a, to o' is b.
        let (a, b) = ([0.3f32, -1.1, 0.5], 0.8f32);
        let loss = |ls: [f32; 3], o: f32| {
            let (l2, o2) = filtered(ls, o, v[0]);
            (a[0] * l2[0] + a[1] * l2[1] + a[2] * l2[2] + b * o2) as f64
        };
        let mut grads = Grads {
            means: vec![[0.0; 3]],
            log_scales: vec![a],
            rotations: vec![[0.0; 4]],
            opacity_logits: vec![b],
            sh: vec![0.0; 3],
            features: vec![],
            means2d: vec![[0.0; 2]],
        };
        pull_back(&g, &v, &mut grads, None);
        let (ls, o, h) = (g.log_scales[0], g.opacity_logits[0], 1e-3f32);
        let numeric_o = (loss(ls, o + h) - loss(ls, o - h)) / (2.0 * h as f64);
        assert!(
            (grads.opacity_logits[0] as f64 - numeric_o).abs() < 1e-3,
            "{} {numeric_o}",
            grads.opacity_logits[0]
        );
        for j in 0..3 {
            let (mut up, mut down) = (ls, ls);
            up[j] += h;
            down[j] -= h;
            let numeric = (loss(up, o) - loss(down, o)) / (2.0 * h as f64);
            assert!(
                (grads.log_scales[0][j] as f64 - numeric).abs() < 1e-3,
                "axis {j}: {} {numeric}",
                grads.log_scales[0][j]
            );
        }
    }

    #[test]
    fn the_reset_caps_the_filtered_opacity() {
        let mut g = Gaussians {
            means: vec![[0.0; 3]; 3],
            log_scales: vec![[-4.0; 3], [-4.0; 3], [-1.0; 3]],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; 3],
            opacity_logits: vec![3.0, 3.0, -6.0],
            sh_degree: 0,
            sh: vec![0.0; 9],
            extra: Extra::default(),
        };
        let v = [4e-4f32, 4e-4, 4e-4];
        let before2 = g.opacity_logits[2];
        let touched = reset_opacity(&mut g, &v, 0.01, Some(&[true, false, true]));
        assert_eq!(touched, [true, false, true]);
        // Row 0: filtered opacity 0.01 after the reset, raw far above 0.01.
        let (_, o) = filtered(g.log_scales[0], g.opacity_logits[0], v[0]);
        assert!((sigmoid(o) - 0.01).abs() < 1e-5, "{}", sigmoid(o));
        assert!(sigmoid(g.opacity_logits[0]) > 0.02, "the raw opacity is 0.01 / k");
        // Row 1 is masked out; row 2 was already below 0.01 through the filter: unchanged.
        assert_eq!(g.opacity_logits[1], 3.0);
        assert!((g.opacity_logits[2] - before2).abs() < 1e-4);
    }

    #[test]
    fn baking_removes_the_column_and_applies_the_filter() {
        let mut g = Gaussians {
            means: vec![[0.0; 3]; 2],
            log_scales: vec![[-3.0; 3], [-1.0; 3]],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; 2],
            opacity_logits: vec![0.0, 2.0],
            sh_degree: 0,
            sh: vec![0.0; 6],
            extra: Extra { names: vec!["label".into()], values: vec![4.0, 7.0] },
        };
        carry(&mut g, &[1e-3, 0.0]);
        assert_eq!(g.extra.names, ["label", EXTRA_NAME]);
        assert_eq!(carried(&g).unwrap(), [1e-3, 0.0]);
        let baked = bake(&g);
        assert_eq!(baked.extra, Extra { names: vec!["label".into()], values: vec![4.0, 7.0] });
        let (ls, o) = filtered([-3.0; 3], 0.0, 1e-3);
        assert_eq!((baked.log_scales[0], baked.opacity_logits[0]), (ls, o));
        assert!((baked.log_scales[1][0] + 1.0).abs() < 1e-6 && (baked.opacity_logits[1] - 2.0).abs() < 1e-5);
    }
}

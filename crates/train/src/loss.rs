//! The 3DGS image loss `(1 − λ) L1 + λ (1 − SSIM)`, λ = 0.2, with its exact
//! gradient with respect to the rendered image, and PSNR.
//!
//! SSIM is INRIA's `ssim` (`utils/loss_utils.py`): per channel, local statistics from
//! an 11×11 Gaussian window (σ = 1.5, normalised) applied as a 2D convolution with
//! zero padding and same-size output, `C1 = 0.01²`, `C2 = 0.03²`, and the mean of the
//! SSIM map over pixels and channels. L1 is the mean absolute difference.
//!
//! Optional per-pixel weights `w` (a mask) turn both means into weighted means,
//! `Σ_p w_p (·) / (3 Σ_p w_p)`: with a 0/1 mask the loss only sees the masked pixels
//! (the SSIM windows still read the whole image). All-zero weights give loss 0.
//!
//! Gradient of SSIM: with raw local moments `μx = G∗x`, `Exx = G∗x²`, `Exy = G∗xy`
//! (and the same for y), `S = A₁A₂ / (B₁B₂)` where `A₁ = 2μxμy + C1`,
//! `A₂ = 2(Exy − μxμy) + C2`, `B₁ = μx² + μy² + C1`, `B₂ = Exx − μx² + Eyy − μy² + C2`.
//! Then `∂S/∂μx = 2μy(A₂ − A₁)/(B₁B₂) − 2μx S (1/B₁ − 1/B₂)`, `∂S/∂Exx = −S/B₂`,
//! `∂S/∂Exy = 2A₁/(B₁B₂)`, and since zero-padded convolution with a symmetric kernel
//! is self-adjoint, `∂L/∂x = G∗a + 2x (G∗b) + y (G∗c)` for the maps
//! `a, b, c = (∂L/∂S) · (∂S/∂μx, ∂S/∂Exx, ∂S/∂Exy)`.

use rayon::prelude::*;

/// Side of the SSIM window.
pub const SSIM_WINDOW: usize = 11;
/// Standard deviation of the SSIM window, in pixels.
pub const SSIM_SIGMA: f32 = 1.5;
const C1: f32 = 0.01 * 0.01;
const C2: f32 = 0.03 * 0.03;

/// The normalised 1D Gaussian window (the 2D window is its outer product).
pub fn ssim_kernel() -> [f32; SSIM_WINDOW] {
    let half = (SSIM_WINDOW / 2) as f32;
    let g: [f32; SSIM_WINDOW] =
        std::array::from_fn(|i| (-(i as f32 - half).powi(2) / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp());
    let s: f32 = g.iter().sum();
    g.map(|v| v / s)
}

/// A loss value, its parts, and its gradient with respect to the rendered image.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ImageLoss {
    /// `(1 − λ) l1 + λ (1 − ssim)`.
    pub loss: f32,
    pub l1: f32,
    /// Mean SSIM; NaN when λ = 0 (not measured: the loss does not need it, see [`ssim`]).
    pub ssim: f32,
    /// `H × W × 3`, ∂loss/∂render.
    pub grad: Vec<f32>,
}

/// `(1 − λ) L1 + λ D-SSIM` between `render` and `target` (`H × W × 3`), optionally
/// weighted per pixel (`H × W`), and its gradient with respect to `render`.
pub fn image_loss(
    render: &[f32],
    target: &[f32],
    width: usize,
    height: usize,
    weights: Option<&[f32]>,
    lambda_dssim: f32,
) -> ImageLoss {
    let px = width * height;
    assert!(render.len() == px * 3 && target.len() == px * 3, "image sizes differ from {width}x{height}");
    assert!(weights.is_none_or(|w| w.len() == px), "weight map is not {width}x{height}");
    let wsum: f64 = match weights {
        Some(w) => w.iter().map(|&v| v as f64).sum(),
        None => px as f64,
    };
    let mut grad = vec![0.0f32; px * 3];
    if !(wsum > 0.0) {
        return ImageLoss { loss: 0.0, l1: 0.0, ssim: 1.0, grad };
    }
    let norm = (1.0 / (3.0 * wsum)) as f32;
    let weight = |p: usize| weights.map_or(1.0, |w| w[p]);

    // L1.
    let mut l1 = 0.0f64;
    let wl1 = 1.0 - lambda_dssim;
    for (q, g) in grad.iter_mut().enumerate() {
        let d = render[q] - target[q];
        let w = weight(q / 3);
        l1 += (w * d.abs()) as f64;
        let s = if d > 0.0 {
            1.0
        } else if d < 0.0 {
            -1.0
        } else {
            0.0
        };
        *g = wl1 * s * w * norm;
    }
    let l1 = (l1 * norm as f64) as f32;

    // SSIM, channel by channel.
    let mut ssim_sum = 0.0f64;
    if lambda_dssim != 0.0 {
        let dl_ds: Vec<f32> = (0..px).map(|p| -lambda_dssim * weight(p) * norm).collect();
        for c in 0..3 {
            let x: Vec<f32> = (0..px).map(|p| render[p * 3 + c]).collect();
            let y: Vec<f32> = (0..px).map(|p| target[p * 3 + c]).collect();
            let (s, gx) = ssim_channel(&x, &y, width, height, Some(&dl_ds), weights);
            ssim_sum += s;
            for (p, v) in gx.into_iter().enumerate() {
                grad[p * 3 + c] += v;
            }
        }
    } else {
        return ImageLoss { loss: l1, l1, ssim: f32::NAN, grad };
    }
    let ssim = (ssim_sum * norm as f64) as f32;
    ImageLoss { loss: wl1 * l1 + lambda_dssim * (1.0 - ssim), l1, ssim, grad }
}

/// INRIA's `ssim(img1, img2)`: the mean SSIM over pixels and channels of two
/// `H × W × 3` images.
pub fn ssim(a: &[f32], b: &[f32], width: usize, height: usize) -> f32 {
    let px = width * height;
    assert!(a.len() == px * 3 && b.len() == px * 3, "image sizes differ from {width}x{height}");
    if px == 0 {
        return f32::NAN;
    }
    let sum: f64 = (0..3)
        .map(|c| {
            let x: Vec<f32> = (0..px).map(|p| a[p * 3 + c]).collect();
            let y: Vec<f32> = (0..px).map(|p| b[p * 3 + c]).collect();
            ssim_channel(&x, &y, width, height, None, None).0
        })
        .sum();
    let norm = (1.0 / (3.0 * px as f64)) as f32;
    (sum * norm as f64) as f32
}

/// Peak signal-to-noise ratio (peak 1) of `render` clamped to [0, 1] against
/// `target`, optionally weighted per pixel; capped at 100 dB.
pub fn psnr(render: &[f32], target: &[f32], weights: Option<&[f32]>) -> f32 {
    let mut se = 0.0f64;
    let mut wsum = 0.0f64;
    for (q, (&r, &t)) in render.iter().zip(target).enumerate() {
        let w = weights.map_or(1.0, |w| w[q / 3]) as f64;
        let d = r.clamp(0.0, 1.0) as f64 - t as f64;
        se += w * d * d;
        wsum += w;
    }
    if !(wsum > 0.0) {
        return 0.0;
    }
    let mse = se / wsum;
    if mse <= 1e-10 {
        100.0
    } else {
        (10.0 * (1.0 / mse).log10()) as f32
    }
}

/// Zero-padded same-size separable Gaussian blur of one plane.
fn blur(src: &[f32], w: usize, h: usize) -> Vec<f32> {
    let g = ssim_kernel();
    let half = SSIM_WINDOW / 2;
    let mut tmp = vec![0.0f32; w * h];
    tmp.par_chunks_mut(w).zip(src.par_chunks(w)).with_min_len(8).for_each(|(t, s)| {
        for (k, &gk) in g.iter().enumerate() {
            // t[x] += g[k] s[x + k − half] for 0 ≤ x + k − half < w
            let (x0, s0) = if k < half { (half - k, 0) } else { (0, k - half) };
            if x0 >= w || s0 >= w {
                continue;
            }
            let len = (w - x0).min(w - s0);
            for (tv, &sv) in t[x0..x0 + len].iter_mut().zip(&s[s0..s0 + len]) {
                *tv += gk * sv;
            }
        }
    });
    let mut out = vec![0.0f32; w * h];
    out.par_chunks_mut(w).enumerate().with_min_len(8).for_each(|(y, o)| {
        for (k, &gk) in g.iter().enumerate() {
            let yy = y as isize + k as isize - half as isize;
            if yy < 0 || yy >= h as isize {
                continue;
            }
            let row = &tmp[yy as usize * w..(yy as usize + 1) * w];
            for (ov, &rv) in o.iter_mut().zip(row) {
                *ov += gk * rv;
            }
        }
    });
    out
}

/// SSIM of one channel: the (weighted) sum of the SSIM map, and, when `dl_ds` (the
/// loss gradient per SSIM-map pixel) is given, the gradient with respect to `x`.
fn ssim_channel(
    x: &[f32],
    y: &[f32],
    w: usize,
    h: usize,
    dl_ds: Option<&[f32]>,
    weights: Option<&[f32]>,
) -> (f64, Vec<f32>) {
    let px = w * h;
    let sq = |a: &[f32], b: &[f32]| -> Vec<f32> { a.iter().zip(b).map(|(u, v)| u * v).collect() };
    let mx = blur(x, w, h);
    let my = blur(y, w, h);
    let exx = blur(&sq(x, x), w, h);
    let eyy = blur(&sq(y, y), w, h);
    let exy = blur(&sq(x, y), w, h);
    let mut sum = 0.0f64;
    let want_grad = dl_ds.is_some();
    let (mut a, mut b, mut c) =
        if want_grad { (vec![0.0f32; px], vec![0.0f32; px], vec![0.0f32; px]) } else { Default::default() };
    for p in 0..px {
        let (ux, uy) = (mx[p], my[p]);
        let a1 = 2.0 * ux * uy + C1;
        let a2 = 2.0 * (exy[p] - ux * uy) + C2;
        let b1 = ux * ux + uy * uy + C1;
        let b2 = (exx[p] - ux * ux) + (eyy[p] - uy * uy) + C2;
        let s = a1 * a2 / (b1 * b2);
        sum += (weights.map_or(1.0, |wt| wt[p]) * s) as f64;
        if let Some(d) = dl_ds {
            let d = d[p];
            let bb = b1 * b2;
            a[p] = d * (2.0 * uy * (a2 - a1) / bb - 2.0 * ux * s * (1.0 / b1 - 1.0 / b2));
            b[p] = d * (-s / b2);
            c[p] = d * (2.0 * a1 / bb);
        }
    }
    if !want_grad {
        return (sum, Vec::new());
    }
    let (ga, gb, gc) = (blur(&a, w, h), blur(&b, w, h), blur(&c, w, h));
    let grad = (0..px).map(|p| ga[p] + 2.0 * x[p] * gb[p] + y[p] * gc[p]).collect();
    (sum, grad)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn random_image(w: usize, h: usize, seed: u64) -> Vec<f32> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..w * h * 3).map(|_| rng.gen_range(0.0..1.0)).collect()
    }

    #[test]
    fn ssim_of_identical_images_is_one_and_loss_zero() {
        let a = random_image(17, 12, 1);
        assert!((ssim(&a, &a, 17, 12) - 1.0).abs() < 1e-5);
        let l = image_loss(&a, &a, 17, 12, None, 0.2);
        assert!(l.loss.abs() < 1e-5 && l.l1 == 0.0);
        assert!(l.grad.iter().all(|g| g.abs() < 1e-4), "identical images are a stationary point");
    }

    /// Constant images a and b: with zero padding the window mass inside the image at a
    /// pixel is s = sx(col) sy(row), so μx = a s, σx² = a² s(1 − s), σxy = a b s(1 − s).
    #[test]
    fn ssim_of_constant_images_has_the_closed_form() {
        let (w, h, a, b) = (30usize, 24usize, 0.7f64, 0.3f64);
        let img = |v: f64| vec![v as f32; w * h * 3];
        let got = ssim(&img(a), &img(b), w, h) as f64;
        let g = ssim_kernel();
        let mass = |i: usize, n: usize| -> f64 {
            (0..SSIM_WINDOW)
                .filter(|&k| {
                    let j = i as isize + k as isize - 5;
                    j >= 0 && j < n as isize
                })
                .map(|k| g[k] as f64)
                .sum()
        };
        let (c1, c2) = (1e-4, 9e-4);
        let mut want = 0.0;
        for y in 0..h {
            for x in 0..w {
                let s = mass(x, w) * mass(y, h);
                let v = s * (1.0 - s);
                want += (2.0 * a * b * s * s + c1) * (2.0 * a * b * v + c2)
                    / (((a * a + b * b) * s * s + c1) * ((a * a + b * b) * v + c2));
            }
        }
        want /= (w * h) as f64;
        assert!((got - want).abs() < 1e-5, "{got} vs {want}");
    }

    fn check_gradient(weights: Option<&[f32]>, lambda: f32, seed: u64) {
        let (w, h) = (8usize, 6usize);
        let x = random_image(w, h, seed);
        // Keep |x − y| ≥ 0.05 so L1 is smooth at the probe points.
        let y: Vec<f32> = random_image(w, h, seed + 1)
            .iter()
            .zip(&x)
            .map(|(&t, &r)| if (t - r).abs() < 0.05 { (r + 0.3) % 1.0 } else { t })
            .collect();
        let l = image_loss(&x, &y, w, h, weights, lambda);
        let eps = 2e-3f32;
        let mut worst = 0.0f32;
        for q in 0..x.len() {
            let mut xp = x.clone();
            xp[q] += eps;
            let mut xm = x.clone();
            xm[q] -= eps;
            let fd = (image_loss(&xp, &y, w, h, weights, lambda).loss
                - image_loss(&xm, &y, w, h, weights, lambda).loss)
                / (2.0 * eps);
            let err = (fd - l.grad[q]).abs() / (2e-4 + 0.02 * l.grad[q].abs().max(fd.abs()));
            worst = worst.max(err);
            assert!(err < 1.0, "pixel value {q}: analytic {} vs finite difference {fd}", l.grad[q]);
        }
        assert!(worst.is_finite());
    }

    #[test]
    fn ssim_and_l1_gradients_match_finite_differences() {
        check_gradient(None, 1.0, 10); // pure D-SSIM
        check_gradient(None, 0.0, 20); // pure L1
        check_gradient(None, 0.2, 30); // the 3DGS loss
        let mask: Vec<f32> =
            (0..48).map(|p| if p % 5 == 0 { 0.0 } else { 0.25 + (p % 3) as f32 * 0.3 }).collect();
        check_gradient(Some(&mask), 0.2, 40);
    }

    #[test]
    fn masked_loss_ignores_pixels_outside_the_mask() {
        let (w, h) = (12, 12);
        let x = random_image(w, h, 3);
        let mut y = x.clone();
        let mut mask = vec![1.0f32; w * h];
        for p in 0..w {
            mask[p] = 0.0;
            for c in 0..3 {
                y[p * 3 + c] = 1.0 - y[p * 3 + c];
            }
        }
        let l = image_loss(&x, &y, w, h, Some(&mask), 0.0);
        assert_eq!(l.l1, 0.0);
        assert!((psnr(&x, &y, Some(&mask)) - 100.0).abs() < 1e-3);
        assert!(psnr(&x, &y, None) < 30.0);
        let zero = image_loss(&x, &y, w, h, Some(&[0.0; 144]), 0.2);
        assert_eq!(zero.loss, 0.0);
    }

    #[test]
    fn psnr_of_known_error() {
        let a = vec![0.5f32; 300];
        let b = vec![0.6f32; 300];
        assert!((psnr(&a, &b, None) - 20.0).abs() < 1e-3);
    }
}

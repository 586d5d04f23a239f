//! Built-in per-pixel features of an image (`H × W × 3`, sRGB-encoded, in [0, 1]).
//!
//! **Appearance Φ_v** ([`appearance`], [`D_APP`] = 6 channels), local: what the
//! pixel looks like.
//!
//! | channel | meaning |
//! |---|---|
//! | 0 | CIELAB L / 100 |
//! | 1 | CIELAB a / 128 |
//! | 2 | CIELAB b / 128 |
//! | 3 | standard deviation of L / 100 in a 5×5 window (fine texture) |
//! | 4 | gradient magnitude of L / 100 (central differences) |
//! | 5 | chroma texture: √(var(a/128) + var(b/128)) in a 5×5 window |
//!
//! **Fallback semantic features E_v** ([`semantic_fallback`], [`D_SEM`] = 16 channels),
//! used when no feature model (DINOv2) is given: regional rather than local, so pixels
//! of one object region agree. Scales are relative to the image diagonal D so the
//! features do not depend on resolution: s₁ = 0.01 D, s₂ = 0.03 D, s₃ = 0.08 D
//! (each at least 1 px).
//!
//! | channels | meaning |
//! |---|---|
//! | 0–2 | (L/100, a/128, b/128) Gaussian-blurred at σ = s₁ |
//! | 3–5 | the same at σ = s₂ |
//! | 6–8 | the same at σ = s₃ |
//! | 9 | standard deviation of L/100 in a box of radius 1.5 s₁ |
//! | 10 | standard deviation of L/100 in a box of radius 1.5 s₂ |
//! | 11 | gradient energy: √(Gaussian blur at s₁ of \|∇L/100\|²) |
//! | 12–13 | hue as (cos h, sin h) weighted by √(chroma / 128), blurred at s₂ |
//! | 14 | chroma / 128 blurred at s₂ |
//! | 15 | centre–surround of L/100: blur at s₁ minus blur at s₃ |
//!
//! Every filter is separable and O(pixels) per channel whatever its size: box filters
//! use running sums (the window is clipped at the border and the mean is over the
//! pixels inside it, so a constant image stays constant), and a Gaussian of standard
//! deviation σ is three box passes whose widths match σ² (the "boxes for Gauss"
//! construction). Channels are computed in parallel with rayon.
//!
//! [`change_attention`] is the smoothed change map Σ_c |Î − I| (σ = 2 px) used as
//! attention when an editor gives neither attention nor mask.

use rayon::prelude::*;

/// Number of appearance channels of [`appearance`].
pub const D_APP: usize = 6;
/// Number of channels of [`semantic_fallback`].
pub const D_SEM: usize = 16;
/// Standard deviation (pixels) of the smoothing in [`change_attention`].
pub const CHANGE_SIGMA: f32 = 2.0;

/// sRGB transfer function inverse: encoded value in [0, 1] to linear.
fn srgb_to_linear(c: f32) -> f32 {
    let c = if c.is_nan() { 0.0 } else { c.clamp(0.0, 1.0) };
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// CIELAB (D65 white, 2° observer) of an sRGB-encoded colour in [0, 1]: returns
/// (L ∈ [0, 100], a, b). Values outside [0, 1] are clamped, NaN is read as 0.
pub fn srgb_to_lab(rgb: [f32; 3]) -> [f32; 3] {
    let [r, g, b] = rgb.map(srgb_to_linear);
    // linear sRGB -> XYZ (D65), divided by the reference white
    let x = (0.412_456_4 * r + 0.357_576_1 * g + 0.180_437_5 * b) / 0.950_47;
    let y = 0.212_672_9 * r + 0.715_152_2 * g + 0.072_175 * b;
    let z = (0.019_333_9 * r + 0.119_192 * g + 0.950_304_1 * b) / 1.088_83;
    const D: f32 = 6.0 / 29.0;
    let f = |t: f32| if t > D * D * D { t.cbrt() } else { t / (3.0 * D * D) + 4.0 / 29.0 };
    let (fx, fy, fz) = (f(x), f(y), f(z));
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

/// Normalised Lab planes (L/100, a/128, b/128) of an `H × W × 3` image.
fn lab_planes(image: &[f32], w: usize, h: usize) -> [Vec<f32>; 3] {
    let n = w * h;
    let lab: Vec<[f32; 3]> = image
        .par_chunks(3)
        .take(n)
        .map(|p| {
            let px = [p[0], p.get(1).copied().unwrap_or(0.0), p.get(2).copied().unwrap_or(0.0)];
            let [l, a, b] = srgb_to_lab(px);
            [l / 100.0, a / 128.0, b / 128.0]
        })
        .collect();
    let mut out = [vec![0.0f32; n], vec![0.0f32; n], vec![0.0f32; n]];
    for (i, v) in lab.iter().enumerate() {
        for c in 0..3 {
            out[c][i] = v[c];
        }
    }
    out
}

/// Mean over a `(2r+1) × (2r+1)` window clipped at the border, O(pixels).
pub fn box_blur(plane: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    assert_eq!(plane.len(), w * h, "plane does not match its size");
    if r == 0 || plane.is_empty() {
        return plane.to_vec();
    }
    // horizontal: prefix sums per row
    let mut tmp = vec![0.0f32; w * h];
    tmp.par_chunks_mut(w).zip(plane.par_chunks(w)).for_each(|(dst, src)| {
        let mut prefix = Vec::with_capacity(w + 1);
        let mut acc = 0.0f64;
        prefix.push(0.0);
        for &v in src {
            acc += v as f64;
            prefix.push(acc);
        }
        for (x, d) in dst.iter_mut().enumerate() {
            let lo = x.saturating_sub(r);
            let hi = (x + r).min(w - 1);
            *d = ((prefix[hi + 1] - prefix[lo]) / (hi + 1 - lo) as f64) as f32;
        }
    });
    // vertical: running column sums
    let mut out = vec![0.0f32; w * h];
    let mut acc = vec![0.0f64; w];
    let add = |acc: &mut [f64], row: &[f32], sign: f64| {
        for (a, &v) in acc.iter_mut().zip(row) {
            *a += sign * v as f64;
        }
    };
    for y in 0..r.min(h) {
        add(&mut acc, &tmp[y * w..(y + 1) * w], 1.0);
    }
    for y in 0..h {
        if y + r < h {
            add(&mut acc, &tmp[(y + r) * w..(y + r + 1) * w], 1.0);
        }
        if y > r {
            let k = y - r - 1;
            add(&mut acc, &tmp[k * w..(k + 1) * w], -1.0);
        }
        let count = ((y + r).min(h - 1) + 1 - y.saturating_sub(r)) as f64;
        for (o, &a) in out[y * w..(y + 1) * w].iter_mut().zip(&acc) {
            *o = (a / count) as f32;
        }
    }
    out
}

/// Radii of three box filters whose composition has variance close to σ²
/// (the box widths 2r+1 are the two odd integers around √(12σ²/3 + 1)).
pub fn gaussian_box_radii(sigma: f32) -> [usize; 3] {
    let s2 = (sigma.max(0.0) as f64).powi(2);
    let n = 3.0;
    let ideal = (12.0 * s2 / n + 1.0).sqrt();
    let mut wl = ideal.floor() as i64;
    if wl % 2 == 0 {
        wl -= 1;
    }
    let wl = wl.max(1);
    let wu = wl + 2;
    let wlf = wl as f64;
    let m_ideal = (12.0 * s2 - n * wlf * wlf - 4.0 * n * wlf - 3.0 * n) / (-4.0 * wlf - 4.0);
    let m = m_ideal.round().clamp(0.0, 3.0) as usize;
    std::array::from_fn(|i| if i < m { (wl as usize - 1) / 2 } else { (wu as usize - 1) / 2 })
}

/// Gaussian blur of standard deviation `sigma` pixels (three box passes, O(pixels)).
pub fn gaussian_blur(plane: &[f32], w: usize, h: usize, sigma: f32) -> Vec<f32> {
    let mut out = plane.to_vec();
    for r in gaussian_box_radii(sigma) {
        if r > 0 {
            out = box_blur(&out, w, h, r);
        }
    }
    out
}

/// Local standard deviation of `plane` in a box of radius `r`.
fn local_std(plane: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    let sq: Vec<f32> = plane.iter().map(|v| v * v).collect();
    let (m, m2) = rayon::join(|| box_blur(plane, w, h, r), || box_blur(&sq, w, h, r));
    m.iter().zip(&m2).map(|(&a, &b)| (b - a * a).max(0.0).sqrt()).collect()
}

/// Gradient magnitude by central differences (one-sided at the border).
fn gradient_magnitude(plane: &[f32], w: usize, h: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; w * h];
    out.par_chunks_mut(w.max(1)).enumerate().for_each(|(y, row)| {
        let (y0, y1) = (y.saturating_sub(1), (y + 1).min(h - 1));
        for (x, o) in row.iter_mut().enumerate() {
            let (x0, x1) = (x.saturating_sub(1), (x + 1).min(w - 1));
            let gx = if x1 > x0 { (plane[y * w + x1] - plane[y * w + x0]) / (x1 - x0) as f32 } else { 0.0 };
            let gy = if y1 > y0 { (plane[y1 * w + x] - plane[y0 * w + x]) / (y1 - y0) as f32 } else { 0.0 };
            *o = (gx * gx + gy * gy).sqrt();
        }
    });
    out
}

/// Interleaves `planes` (each `H × W`) into `H × W × planes.len()`.
fn interleave(planes: &[Vec<f32>], n: usize) -> Vec<f32> {
    let c = planes.len();
    let mut out = vec![0.0f32; n * c];
    out.par_chunks_mut(c.max(1)).enumerate().for_each(|(i, px)| {
        for (k, v) in px.iter_mut().enumerate() {
            *v = planes[k][i];
        }
    });
    out
}

fn check_image(image: &[f32], w: usize, h: usize) {
    assert!(image.len() >= w * h * 3, "image buffer is smaller than {w}x{h}x3");
}

/// Appearance features Φ (see the module doc): `(H × W × D_APP, D_APP)`.
pub fn appearance(image: &[f32], w: usize, h: usize) -> (Vec<f32>, usize) {
    check_image(image, w, h);
    if w * h == 0 {
        return (Vec::new(), D_APP);
    }
    let [l, a, b] = lab_planes(image, w, h);
    let extra: Vec<Vec<f32>> = (0..3)
        .into_par_iter()
        .map(|k| match k {
            0 => local_std(&l, w, h, 2),
            1 => gradient_magnitude(&l, w, h),
            _ => {
                let (sa, sb) = (local_std(&a, w, h, 2), local_std(&b, w, h, 2));
                sa.iter().zip(&sb).map(|(x, y)| (x * x + y * y).sqrt()).collect()
            }
        })
        .collect();
    let mut planes = vec![l, a, b];
    planes.extend(extra);
    (interleave(&planes, w * h), D_APP)
}

/// The three scales s₁, s₂, s₃ (pixels) of [`semantic_fallback`].
pub fn semantic_scales(w: usize, h: usize) -> [f32; 3] {
    let diag = ((w * w + h * h) as f32).sqrt();
    [0.01, 0.03, 0.08].map(|f| (f * diag).max(1.0))
}

/// Fallback semantic features E (see the module doc): `(H × W × D_SEM, D_SEM)`.
pub fn semantic_fallback(image: &[f32], w: usize, h: usize) -> (Vec<f32>, usize) {
    check_image(image, w, h);
    if w * h == 0 {
        return (Vec::new(), D_SEM);
    }
    let [s1, s2, s3] = semantic_scales(w, h);
    let lab = lab_planes(image, w, h);
    let n = w * h;
    let chroma: Vec<f32> = (0..n).map(|i| (lab[1][i] * lab[1][i] + lab[2][i] * lab[2][i]).sqrt()).collect();
    let blurred: Vec<Vec<f32>> =
        (0..9).into_par_iter().map(|k| gaussian_blur(&lab[k % 3], w, h, [s1, s2, s3][k / 3])).collect();
    let rest: Vec<Vec<f32>> = (0..6)
        .into_par_iter()
        .map(|k| match k {
            0 => local_std(&lab[0], w, h, (1.5 * s1).round().max(1.0) as usize),
            1 => local_std(&lab[0], w, h, (1.5 * s2).round().max(2.0) as usize),
            2 => {
                let g2: Vec<f32> = gradient_magnitude(&lab[0], w, h).iter().map(|g| g * g).collect();
                gaussian_blur(&g2, w, h, s1).iter().map(|v| v.max(0.0).sqrt()).collect()
            }
            3 | 4 => {
                // hue direction (a, b) / chroma, weighted by √chroma
                let hue: Vec<f32> = (0..n)
                    .map(|i| {
                        let c = chroma[i];
                        if c <= 1e-6 {
                            0.0
                        } else {
                            let comp = if k == 3 { lab[1][i] } else { lab[2][i] };
                            comp / c * c.min(1.0).sqrt()
                        }
                    })
                    .collect();
                gaussian_blur(&hue, w, h, s2)
            }
            _ => gaussian_blur(&chroma, w, h, s2),
        })
        .collect();
    let mut planes = blurred;
    let surround: Vec<f32> = planes[0].iter().zip(&planes[6]).map(|(a, b)| a - b).collect();
    planes.extend(rest);
    planes.push(surround);
    debug_assert_eq!(planes.len(), D_SEM);
    (interleave(&planes, n), D_SEM)
}

/// Per-channel change below which a difference is 8-bit quantisation, not an edit.
pub const CHANGE_FLOOR: f32 = 2.0 / 255.0;

/// Smoothed change map: Σ_c [|edited − source| − floor]_+ per pixel (the floor,
/// [`CHANGE_FLOOR`], removes 8-bit quantisation noise so an unedited image yields no
/// attention), Gaussian-smoothed with σ = [`CHANGE_SIGMA`] px; `H × W`, ≥ 0. NaN
/// differences count as 0.
pub fn change_attention(source: &[f32], edited: &[f32], w: usize, h: usize) -> Vec<f32> {
    let n = w * h;
    let mut diff = vec![0.0f32; n];
    for (i, d) in diff.iter_mut().enumerate() {
        let mut s = 0.0;
        for c in 0..3 {
            let (a, b) = (source.get(i * 3 + c), edited.get(i * 3 + c));
            if let (Some(a), Some(b)) = (a, b) {
                let v = ((a - b).abs() - CHANGE_FLOOR).max(0.0);
                if v.is_finite() {
                    s += v;
                }
            }
        }
        *d = s;
    }
    if n == 0 {
        return diff;
    }
    gaussian_blur(&diff, w, h, CHANGE_SIGMA).into_iter().map(|v| v.max(0.0)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f32, b: f32, tol: f32) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn lab_matches_hand_values() {
        let white = srgb_to_lab([1.0, 1.0, 1.0]);
        assert!(close(white[0], 100.0, 1e-3) && close(white[1], 0.0, 1e-3) && close(white[2], 0.0, 1e-3));
        let red = srgb_to_lab([1.0, 0.0, 0.0]);
        assert!(
            close(red[0], 53.24, 0.01) && close(red[1], 80.09, 0.01) && close(red[2], 67.20, 0.01),
            "{red:?}"
        );
        let black = srgb_to_lab([0.0, 0.0, 0.0]);
        assert!(black.iter().all(|v| v.abs() < 1e-4), "{black:?}");
        // mid grey (sRGB 0.5 → linear 0.214) has L ≈ 53.39 and no chroma
        let grey = srgb_to_lab([0.5, 0.5, 0.5]);
        assert!(close(grey[0], 53.39, 0.02) && grey[1].abs() < 1e-3 && grey[2].abs() < 1e-3, "{grey:?}");
        // pure blue: L ≈ 32.30, a ≈ 79.19, b ≈ −107.86
        let blue = srgb_to_lab([0.0, 0.0, 1.0]);
        assert!(close(blue[0], 32.30, 0.02) && close(blue[1], 79.19, 0.05) && close(blue[2], -107.86, 0.05));
        // NaN and out-of-range input are clamped, not propagated
        assert!(srgb_to_lab([f32::NAN, 2.0, -1.0]).iter().all(|v| v.is_finite()));
    }

    #[test]
    fn box_blur_by_hand() {
        // 3x1 row [0, 3, 6], radius 1: [1.5, 3, 4.5] (clipped window means)
        assert_eq!(box_blur(&[0.0, 3.0, 6.0], 3, 1, 1), vec![1.5, 3.0, 4.5]);
        // column works the same way
        assert_eq!(box_blur(&[0.0, 3.0, 6.0], 1, 3, 1), vec![1.5, 3.0, 4.5]);
        // 3x3 impulse, radius 1: centre sees 9 pixels, corner 4, edge 6
        let mut p = vec![0.0f32; 9];
        p[4] = 36.0;
        let b = box_blur(&p, 3, 3, 1);
        assert_eq!(b, vec![9.0, 6.0, 9.0, 6.0, 4.0, 6.0, 9.0, 6.0, 9.0]);
        // a constant image stays constant at any radius
        let c = vec![0.7f32; 5 * 4];
        assert!(box_blur(&c, 5, 4, 3).iter().all(|&v| close(v, 0.7, 1e-6)));
        // radius 0 is the identity
        assert_eq!(box_blur(&[1.0, 2.0], 2, 1, 0), vec![1.0, 2.0]);
    }

    #[test]
    fn gaussian_blur_has_the_requested_variance() {
        for sigma in [1.0f32, 2.0, 5.0] {
            let radii = gaussian_box_radii(sigma);
            let var: f32 = radii.iter().map(|&r| ((2 * r + 1).pow(2) - 1) as f32 / 12.0).sum();
            assert!((var.sqrt() - sigma).abs() < 0.35, "sigma {sigma}: radii {radii:?} give {}", var.sqrt());
            let (w, h) = (61, 61);
            let mut p = vec![0.0f32; w * h];
            p[30 * w + 30] = 1.0;
            let b = gaussian_blur(&p, w, h, sigma);
            let mass: f32 = b.iter().sum();
            assert!(close(mass, 1.0, 1e-4), "mass {mass}");
            let mut m2 = 0.0;
            for y in 0..h {
                for x in 0..w {
                    m2 += b[y * w + x] * ((x as f32 - 30.0).powi(2));
                }
            }
            assert!(close(m2, var, 1e-3 * var.max(1.0)), "second moment {m2} vs {var}");
        }
    }

    #[test]
    fn change_attention_by_hand() {
        let (w, h) = (21, 21);
        let src = vec![0.5f32; w * h * 3];
        assert!(change_attention(&src, &src, w, h).iter().all(|&v| v == 0.0));
        let mut ed = src.clone();
        ed[(10 * w + 10) * 3 + 1] = 0.8; // one pixel, one channel, change 0.3
        ed[(10 * w + 10) * 3 + 2] = 0.4; // and 0.1 in another: total 0.4 less two floors
        ed[(3 * w + 3) * 3] = 0.5 + 1.5 / 255.0; // below the quantisation floor: ignored
        let a = change_attention(&src, &ed, w, h);
        let mass: f32 = a.iter().sum();
        assert!(close(mass, 0.4 - 2.0 * CHANGE_FLOOR, 1e-4), "mass {mass}");
        let peak = a.iter().cloned().fold(0.0, f32::max);
        assert_eq!(a[10 * w + 10], peak);
        assert!(close(a[10 * w + 7], a[7 * w + 10], 1e-7) && close(a[10 * w + 7], a[10 * w + 13], 1e-7));
        assert!(a[0] < 1e-6 && a.iter().all(|&v| v >= 0.0));
    }

    #[test]
    fn features_have_the_documented_shape_and_values() {
        let (w, h) = (20, 10);
        // left half red, right half flat white
        let mut img = vec![1.0f32; w * h * 3];
        for y in 0..h {
            for x in 0..w / 2 {
                img[(y * w + x) * 3 + 1] = 0.0;
                img[(y * w + x) * 3 + 2] = 0.0;
            }
        }
        let (phi, d) = appearance(&img, w, h);
        assert_eq!((phi.len(), d), (w * h * D_APP, D_APP));
        let at = |x: usize, y: usize, c: usize| phi[(y * w + x) * d + c];
        assert!(close(at(2, 5, 0), 0.5324, 1e-3) && close(at(2, 5, 1), 80.09 / 128.0, 1e-3));
        assert!(close(at(17, 5, 0), 1.0, 1e-4) && at(17, 5, 1).abs() < 1e-4);
        // flat regions: no texture, no gradient; the edge has both
        assert!(at(2, 5, 3) < 1e-3 && at(2, 5, 4) < 1e-6 && at(17, 5, 5) < 1e-3);
        assert!(at(9, 5, 3) > 0.1 && at(9, 5, 4) > 0.1 && at(10, 5, 5) > 0.1);
        let (e, d) = semantic_fallback(&img, w, h);
        assert_eq!((e.len(), d), (w * h * D_SEM, D_SEM));
        assert!(e.iter().all(|v| v.is_finite()));
        // hue of red points along +a/+b; white has no hue
        let e_at = |x: usize, c: usize| e[(5 * w + x) * d + c];
        assert!(e_at(0, 12) > 0.3 && e_at(0, 13) > 0.3 && e_at(19, 12).abs() < 0.05);
    }
}

//! Image and grid resampling exactly as `torch.nn.functional.interpolate(..., size=...,
//! align_corners=False)` does it (no antialiasing), on planar `C × H × W` f32 data.
//!
//! The reference protocols resample with torch, so the same arithmetic is used here:
//! output pixel `i` samples the source at `(i + 0.5) · in/out − 0.5`; bicubic uses the
//! Keys kernel with `A = −0.75` on the 4 × 4 neighbourhood with indices clamped to the
//! border; bilinear clamps negative source coordinates to 0.

/// Cubic convolution weights of the four taps around a sample at fraction `t`.
fn cubic_weights(t: f32) -> [f32; 4] {
    const A: f32 = -0.75;
    let near = |x: f32| ((A + 2.0) * x - (A + 3.0)) * x * x + 1.0;
    let far = |x: f32| ((A * x - 5.0 * A) * x + 8.0 * A) * x - 4.0 * A;
    [far(t + 1.0), near(t), near(1.0 - t), far(2.0 - t)]
}

/// For each output index: the four clamped source indices and their weights.
fn cubic_taps(n_in: usize, n_out: usize) -> Vec<([usize; 4], [f32; 4])> {
    let scale = n_in as f32 / n_out as f32;
    (0..n_out)
        .map(|i| {
            let src = scale * (i as f32 + 0.5) - 0.5;
            let base = src.floor();
            let w = cubic_weights(src - base);
            let at = |k: i64| (base as i64 + k).clamp(0, n_in as i64 - 1) as usize;
            ([at(-1), at(0), at(1), at(2)], w)
        })
        .collect()
}

/// Bicubic resampling of `channels` planes of `h × w` to `oh × ow`.
pub fn bicubic(src: &[f32], channels: usize, h: usize, w: usize, oh: usize, ow: usize) -> Vec<f32> {
    let ys = cubic_taps(h, oh);
    let xs = cubic_taps(w, ow);
    let mut out = vec![0f32; channels * oh * ow];
    for c in 0..channels {
        let plane = &src[c * h * w..(c + 1) * h * w];
        let dst = &mut out[c * oh * ow..(c + 1) * oh * ow];
        for (oy, (yi, yw)) in ys.iter().enumerate() {
            for (ox, (xi, xw)) in xs.iter().enumerate() {
                let mut acc = 0f32;
                for k in 0..4 {
                    let row = &plane[yi[k] * w..(yi[k] + 1) * w];
                    let r = row[xi[0]] * xw[0] + row[xi[1]] * xw[1] + row[xi[2]] * xw[2] + row[xi[3]] * xw[3];
                    acc += r * yw[k];
                }
                dst[oy * ow + ox] = acc;
            }
        }
    }
    out
}

/// For each output index: the two source indices and the weight of the second.
fn linear_taps(n_in: usize, n_out: usize) -> Vec<(usize, usize, f32)> {
    let scale = n_in as f32 / n_out as f32;
    (0..n_out)
        .map(|i| {
            let src = (scale * (i as f32 + 0.5) - 0.5).max(0.0);
            let i0 = (src as usize).min(n_in - 1);
            let i1 = (i0 + 1).min(n_in - 1);
            (i0, i1, src - i0 as f32)
        })
        .collect()
}

/// Bilinear resampling of `channels` planes of `h × w` to `oh × ow`.
pub fn bilinear(src: &[f32], channels: usize, h: usize, w: usize, oh: usize, ow: usize) -> Vec<f32> {
    let ys = linear_taps(h, oh);
    let xs = linear_taps(w, ow);
    let mut out = vec![0f32; channels * oh * ow];
    for c in 0..channels {
        let plane = &src[c * h * w..(c + 1) * h * w];
        let dst = &mut out[c * oh * ow..(c + 1) * oh * ow];
        for (oy, &(y0, y1, ty)) in ys.iter().enumerate() {
            for (ox, &(x0, x1, tx)) in xs.iter().enumerate() {
                let top = plane[y0 * w + x0] * (1.0 - tx) + plane[y0 * w + x1] * tx;
                let bottom = plane[y1 * w + x0] * (1.0 - tx) + plane[y1 * w + x1] * tx;
                dst[oy * ow + ox] = top * (1.0 - ty) + bottom * ty;
            }
        }
    }
    out
}

/// Position embeddings `[1 + gh·gw, C]` of a ViT for a `gh × gw` patch grid, from its
/// embeddings `[1 + n², C]` for the native `n × n` grid (class position first): the patch
/// positions, as `C` planes of `n × n`, resized bicubically as transformers'
/// `interpolate_pos_encoding` does (DINOv2, CLIPSeg); the native grid is returned as is.
pub fn position_grid(
    position: &candle_core::Tensor,
    n: usize,
    gh: usize,
    gw: usize,
) -> candle_core::Result<candle_core::Tensor> {
    if gh == n && gw == n {
        return Ok(position.clone());
    }
    let c = position.dim(1)?;
    let cls = position.narrow(0, 0, 1)?;
    let grid = position.narrow(0, 1, n * n)?.t()?.contiguous()?.flatten_all()?.to_vec1::<f32>()?;
    let resized = bicubic(&grid, c, n, n, gh, gw);
    let patch = candle_core::Tensor::from_vec(resized, (c, gh * gw), position.device())?.t()?;
    candle_core::Tensor::cat(&[&cls, &patch], 0)
}

/// `H × W × 3` interleaved pixels to planar `3 × H × W`.
pub fn hwc_to_chw(hwc: &[f32], h: usize, w: usize, c: usize) -> Vec<f32> {
    let mut out = vec![0f32; c * h * w];
    for (p, px) in hwc.chunks_exact(c).enumerate() {
        for (k, &v) in px.iter().enumerate() {
            out[k * h * w + p] = v;
        }
    }
    out
}

/// Normalises planar channels in place, v ← (v − mean[c]) / std[c] (the image processors'
/// `do_normalize`; ImageNet's mean and std for DINOv2, CLIPSeg and SAM).
pub fn normalize_planes(planar: &mut [f32], mean: &[f32; 3], std: &[f32; 3]) {
    let plane = planar.len() / 3;
    for (c, values) in planar.chunks_exact_mut(plane.max(1)).enumerate().take(3) {
        for v in values {
            *v = (*v - mean[c]) / std[c];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn planes_are_normalised_by_their_own_channel() {
        let mut planar = vec![1.0, 3.0, 2.0, 2.0, 0.0, 6.0];
        normalize_planes(&mut planar, &[1.0, 2.0, 0.0], &[2.0, 1.0, 3.0]);
        assert_eq!(planar, vec![0.0, 1.0, 0.0, 0.0, 0.0, 2.0]);
    }

    #[test]
    fn weights_sum_to_one_and_identity_size_is_exact() {
        for t in [0.0, 0.25, 0.5, 0.9] {
            let s: f32 = cubic_weights(t).iter().sum();
            assert!((s - 1.0).abs() < 1e-6);
        }
        let src: Vec<f32> = (0..2 * 5 * 7).map(|i| (i as f32 * 0.37).sin()).collect();
        assert_eq!(bicubic(&src, 2, 5, 7, 5, 7), src);
        assert_eq!(bilinear(&src, 2, 5, 7, 5, 7), src);
    }
}

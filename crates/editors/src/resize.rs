//! Bilinear resizing of interleaved float images, for edited images and masks that do
//! not come back at the view's size.
//!
//! Pixel centres sit at (x + 0.5, y + 0.5) in both images. Upscaling is plain bilinear
//! interpolation (edge pixels extended). Downscaling widens the triangle filter by the
//! scale factor so every source pixel contributes (an antialiased bilinear, as image
//! libraries do), which keeps thin lines and noise from aliasing.

/// Taps `(source index, weight)` of a separable triangle filter from `n` to `m` samples.
fn taps(n: usize, m: usize) -> Vec<Vec<(usize, f32)>> {
    let scale = n as f64 / m as f64;
    let support = scale.max(1.0);
    (0..m)
        .map(|o| {
            let centre = (o as f64 + 0.5) * scale; // in source pixel units
            let lo = (centre - support).floor().max(0.0) as usize;
            let hi = ((centre + support).ceil() as usize).min(n);
            let mut t: Vec<(usize, f64)> = (lo..hi)
                .filter_map(|i| {
                    let d = ((i as f64 + 0.5) - centre).abs() / support;
                    (d < 1.0).then_some((i, 1.0 - d))
                })
                .collect();
            if t.is_empty() {
                // outside the source (only at the border when upscaling): nearest pixel
                t.push((((centre - 0.5).round().max(0.0) as usize).min(n - 1), 1.0));
            }
            // edge extension: weight that would fall outside [0, n) goes to the nearest pixel
            let sum: f64 = t.iter().map(|x| x.1).sum();
            t.into_iter().map(|(i, w)| (i, (w / sum) as f32)).collect()
        })
        .collect()
}

/// Resizes an interleaved `w × h × c` image to `nw × nh`. Returns a copy when the
/// size is unchanged and an empty image when either size is empty.
pub fn resize_bilinear(src: &[f32], w: usize, h: usize, c: usize, nw: usize, nh: usize) -> Vec<f32> {
    assert!(src.len() >= w * h * c, "image buffer is smaller than {w}x{h}x{c}");
    if (w, h) == (nw, nh) {
        return src[..w * h * c].to_vec();
    }
    if w == 0 || h == 0 || nw == 0 || nh == 0 || c == 0 {
        return vec![0.0; nw * nh * c];
    }
    transsplat_scene::resample::separable(src, w, h, c, &taps(w, nw), &taps(h, nh))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn upscaling_interpolates_and_keeps_edges() {
        // [0, 4] to 4 samples: centres at 0.25, 0.75, 1.25, 1.75 source px
        let out = resize_bilinear(&[0.0, 4.0], 2, 1, 1, 4, 1);
        assert_eq!(out, vec![0.0, 1.0, 3.0, 4.0]);
        // a constant image stays constant either way, channels kept apart
        let src: Vec<f32> = (0..6 * 4).flat_map(|_| [0.25f32, 0.5]).collect();
        for (nw, nh) in [(11, 7), (2, 3), (6, 4)] {
            let out = resize_bilinear(&src, 6, 4, 2, nw, nh);
            assert_eq!(out.len(), nw * nh * 2);
            for px in out.chunks_exact(2) {
                assert!((px[0] - 0.25).abs() < 1e-6 && (px[1] - 0.5).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn halving_averages_with_a_triangle() {
        // 4 -> 2: output centre 1.0 sees pixels 0 (d 0.25), 1 (d 0.25), 2 (d 0.75) -> weights .75 .75 .25
        let out = resize_bilinear(&[0.0, 4.0, 8.0, 12.0], 4, 1, 1, 2, 1);
        let want0 = (0.75 * 0.0 + 0.75 * 4.0 + 0.25 * 8.0) / 1.75;
        assert!((out[0] - want0).abs() < 1e-5, "{out:?}");
        assert!((out[0] + out[1] - 12.0).abs() < 1e-5, "symmetric: {out:?}");
        assert!(resize_bilinear(&[1.0], 1, 1, 1, 0, 3).is_empty());
    }
}

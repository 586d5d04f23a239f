//! Separable resampling of interleaved float images: each output pixel is a weighted
//! sum of source pixels along x, then along y. The callers' filters (area, triangle)
//! differ only in their taps.

/// The taps of one output sample along one axis: `(source index, weight)` pairs.
pub type Taps = Vec<(usize, f32)>;

/// Resamples an interleaved `w × h × c` image to `tx.len() × ty.len()`: every row with
/// the x taps, then every column of the result with the y taps, summing in `f32` in tap
/// order.
pub fn separable(src: &[f32], w: usize, h: usize, c: usize, tx: &[Taps], ty: &[Taps]) -> Vec<f32> {
    let (nw, nh) = (tx.len(), ty.len());
    let mut rows = vec![0.0f32; h * nw * c];
    for y in 0..h {
        for (ox, t) in tx.iter().enumerate() {
            for &(ix, wgt) in t {
                for k in 0..c {
                    rows[(y * nw + ox) * c + k] += wgt * src[(y * w + ix) * c + k];
                }
            }
        }
    }
    let mut out = vec![0.0f32; nh * nw * c];
    for (oy, t) in ty.iter().enumerate() {
        let dst = &mut out[oy * nw * c..(oy + 1) * nw * c];
        for &(iy, wgt) in t {
            for (d, v) in dst.iter_mut().zip(&rows[iy * nw * c..(iy + 1) * nw * c]) {
                *d += wgt * v;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_then_columns_with_channels_apart() {
        // 2 × 2 × 2 to 1 × 2: x averages the two columns, y keeps row 1 then row 0.
        let src = [1.0, 10.0, 3.0, 30.0, 5.0, 50.0, 7.0, 70.0];
        let tx = [vec![(0, 0.5), (1, 0.5)]];
        let ty = [vec![(1, 1.0)], vec![(0, 1.0)]];
        assert_eq!(separable(&src, 2, 2, 2, &tx, &ty), vec![6.0, 60.0, 2.0, 20.0]);
    }
}

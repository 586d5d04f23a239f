//! 3×3 convolutions with stride 1 by Winograd's minimal filtering F(2×2, 3×3) (Lavin and
//! Gray, "Fast Algorithms for Convolutional Neural Networks", CVPR 2016, section 4).
//!
//! The output of each channel is cut into tiles of 2×2 pixels. Output tile t of channel o is
//!
//!   Y = Aᵀ [ Σ_c U_oc ⊙ V_ct ] A,   U_oc = G g_oc Gᵀ,   V_ct = Bᵀ d_ct B,
//!
//! with g_oc the 3×3 weight from input channel c, d_ct the 4×4 input patch under the tile
//! (zero outside the image), ⊙ the element-wise product, and
//!
//!   Bᵀ = [1 0 −1 0; 0 1 1 0; 0 −1 1 0; 0 1 0 −1],   G = [1 0 0; ½ ½ ½; ½ −½ ½; 0 0 1],
//!   Aᵀ = [1 1 1 0; 0 1 −1 −1].
//!
//! For each of the 16 positions ξ of the 4×4, the sum over c is a matrix product,
//! M_ξ = U_ξ (O × C) · V_ξ (C × T) over the T tiles: 16 multiplications per tile and
//! channel pair where the direct convolution spends 36 on the same four outputs. The
//! transforms are additions (and the halves of G). U is computed on each call from the
//! layer's weight, 16 values per weight pair, which costs about as much as a product over
//! two dozen tiles, so [`MIN_TILES`] sends smaller inputs to the direct convolution. Tiles
//! of every batch item are the product's columns together, in chunks whose V and M fit a
//! budget of floats.

use rayon::prelude::*;

use crate::cpu::{gemm, Matrix, Product};

/// Fewest tiles (over the whole batch) for which the transform of the weight pays.
pub const MIN_TILES: usize = 32;

/// The layer a [`conv3x3`] call computes: `weight` `[O, C, 3, 3]` row-major, an optional
/// bias `[O]`, zero padding of `padding` pixels on every side, stride 1.
pub struct Layer<'a> {
    pub weight: &'a [f32],
    pub bias: Option<&'a [f32]>,
    pub out_channels: usize,
    pub in_channels: usize,
    pub padding: usize,
}

/// Tiles of a `[B, C, H, W]` input: `(tile rows, tile columns)` of one item's output
/// (oh, ow) = (H + 2p − 2, W + 2p − 2).
pub fn tiles((oh, ow): (usize, usize)) -> (usize, usize) {
    (oh.div_ceil(2), ow.div_ceil(2))
}

/// y `[B, O, oh, ow]` of the layer for x `[B, C, h, w]`, where (oh, ow) = (h + 2p − 2,
/// w + 2p − 2) (module doc); V and M of a chunk of tiles hold at most `budget` floats
/// each (at least one tile).
pub fn conv3x3(layer: &Layer, x: &[f32], b: usize, (h, w): (usize, usize), y: &mut [f32], budget: usize) {
    let (o_n, c_n, p) = (layer.out_channels, layer.in_channels, layer.padding);
    let (oh, ow) = (h + 2 * p - 2, w + 2 * p - 2);
    let (th, tw) = tiles((oh, ow));
    let per_item = th * tw;
    let total = b * per_item;
    let u = transform_weight(layer.weight, o_n, c_n);
    let chunk = (budget / (16 * c_n.max(o_n)).max(1)).clamp(1, total.max(1));
    let mut v = vec![0.0f32; 16 * c_n * chunk];
    let mut m = vec![0.0f32; 16 * o_n * chunk];
    for t0 in (0..total).step_by(chunk) {
        let n = chunk.min(total - t0);
        let v = &mut v[..16 * c_n * n];
        let m = &mut m[..16 * o_n * n];
        // V: [C][16][n]
        v.par_chunks_mut(16 * n).enumerate().for_each(|(c, vc)| {
            transform_input(x, (b, c_n, h, w), c, p, (th, tw), t0, vc);
        });
        // M_ξ = U_ξ · V_ξ, M: [O][16][n]
        for xi in 0..16 {
            let lhs = Matrix { data: &u[xi * c_n..], rows: 16 * c_n, cols: 1 };
            let rhs = Matrix { data: &v[xi * n..], rows: 16 * n, cols: 1 };
            let how = Product { accumulate: false, scale: 1.0, parallel: true };
            gemm(m, xi * n, 16 * n, lhs, rhs, (o_n, n, c_n), how);
        }
        // Y = Aᵀ M A into each (item, o) plane the chunk touches
        y.par_chunks_mut(oh * ow).enumerate().for_each(|(plane, out)| {
            let (item, o) = (plane / o_n, plane % o_n);
            let first = (item * per_item).max(t0);
            let last = ((item + 1) * per_item).min(t0 + n);
            if first >= last {
                return;
            }
            let bias = layer.bias.map_or(0.0, |bias| bias[o]);
            let mo = &m[o * 16 * n..(o + 1) * 16 * n];
            for t in first..last {
                let at = t - t0;
                let mut tile = [0.0f32; 16];
                for (xi, value) in tile.iter_mut().enumerate() {
                    *value = mo[xi * n + at];
                }
                let out_tile = transform_output(&tile);
                let r = t - item * per_item;
                let (ty, tx) = (r / tw, r % tw);
                for (i, row) in out_tile.iter().enumerate() {
                    let yy = 2 * ty + i;
                    if yy >= oh {
                        continue;
                    }
                    for (j, &value) in row.iter().enumerate() {
                        let xx = 2 * tx + j;
                        if xx < ow {
                            out[yy * ow + xx] = value + bias;
                        }
                    }
                }
            }
        });
    }
}

/// U `[O][16][C]`: U_oc = G g_oc Gᵀ (module doc) at `[o][ξ][c]`, ξ = 4·row + column.
fn transform_weight(weight: &[f32], o_n: usize, c_n: usize) -> Vec<f32> {
    let mut u = vec![0.0f32; o_n * 16 * c_n];
    u.par_chunks_mut(16 * c_n).enumerate().for_each(|(o, uo)| {
        for c in 0..c_n {
            let g = &weight[(o * c_n + c) * 9..(o * c_n + c + 1) * 9];
            // G g (4 × 3), then (G g) Gᵀ (4 × 4)
            let mut gg = [[0.0f32; 3]; 4];
            for j in 0..3 {
                let (g0, g1, g2) = (g[j], g[3 + j], g[6 + j]);
                gg[0][j] = g0;
                gg[1][j] = 0.5 * (g0 + g1 + g2);
                gg[2][j] = 0.5 * (g0 - g1 + g2);
                gg[3][j] = g2;
            }
            for (i, row) in gg.iter().enumerate() {
                let [r0, r1, r2] = *row;
                let values = [r0, 0.5 * (r0 + r1 + r2), 0.5 * (r0 - r1 + r2), r2];
                for (j, &value) in values.iter().enumerate() {
                    uo[(4 * i + j) * c_n + c] = value;
                }
            }
        }
    });
    u
}

/// V of input channel `c` for the global tiles `t0..t0 + n` into `vc` `[16][n]`:
/// V = Bᵀ d B (module doc) with d the 4×4 patch whose corner is input pixel
/// (2·ty − p, 2·tx − p). Bᵀ d is computed once per tile row over the padded columns.
fn transform_input(
    x: &[f32],
    (b, c_n, h, w): (usize, usize, usize, usize),
    c: usize,
    p: usize,
    (th, tw): (usize, usize),
    t0: usize,
    vc: &mut [f32],
) {
    let n = vc.len() / 16;
    let per_item = th * tw;
    let width = 2 * tw + 2;
    let mut rows = vec![[0.0f32; 4]; width];
    let mut t = t0;
    while t < t0 + n {
        let item = t / per_item;
        debug_assert!(item < b);
        let r = t % per_item;
        let (ty, tx0) = (r / tw, r % tw);
        let tx1 = tw.min(tx0 + (t0 + n - t));
        let plane = &x[(item * c_n + c) * h * w..(item * c_n + c + 1) * h * w];
        // patch row i is input row 2·ty − p + i, zero outside the image
        let row = |i: usize| -> Option<&[f32]> {
            let yy = (2 * ty + i).checked_sub(p).filter(|&yy| yy < h)?;
            Some(&plane[yy * w..(yy + 1) * w])
        };
        let input_rows = [row(0), row(1), row(2), row(3)];
        // Bᵀ d over the padded columns 2·tx0 .. 2·tx1 + 2
        for (col, bd) in rows.iter_mut().enumerate().take(2 * tx1 + 2).skip(2 * tx0) {
            let at = col.checked_sub(p).filter(|&xx| xx < w);
            let d = |i: usize| match (input_rows[i], at) {
                (Some(row), Some(xx)) => row[xx],
                _ => 0.0,
            };
            let (d0, d1, d2, d3) = (d(0), d(1), d(2), d(3));
            *bd = [d0 - d2, d1 + d2, d2 - d1, d1 - d3];
        }
        for tx in tx0..tx1 {
            let at = t + tx - tx0 - t0;
            let a = 2 * tx;
            let (k0, k1, k2, k3) = (rows[a], rows[a + 1], rows[a + 2], rows[a + 3]);
            for i in 0..4 {
                vc[(4 * i) * n + at] = k0[i] - k2[i];
                vc[(4 * i + 1) * n + at] = k1[i] + k2[i];
                vc[(4 * i + 2) * n + at] = k2[i] - k1[i];
                vc[(4 * i + 3) * n + at] = k1[i] - k3[i];
            }
        }
        t += tx1 - tx0;
    }
}

/// Y = Aᵀ m A (module doc) of one tile's 4×4 sums, ξ = 4·row + column.
fn transform_output(m: &[f32; 16]) -> [[f32; 2]; 2] {
    // Aᵀ m (2 × 4)
    let mut am = [[0.0f32; 4]; 2];
    for j in 0..4 {
        am[0][j] = m[j] + m[4 + j] + m[8 + j];
        am[1][j] = m[4 + j] - m[8 + j] - m[12 + j];
    }
    let mut y = [[0.0f32; 2]; 2];
    for (row, a) in y.iter_mut().zip(&am) {
        row[0] = a[0] + a[1] + a[2];
        row[1] = a[1] - a[2] - a[3];
    }
    y
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The direct formula y[n, o, i, j] = b[o] + Σ_{c,u,v} w[o, c, u, v] · x[n, c, i + u − p, j + v − p].
    #[allow(clippy::too_many_arguments)]
    fn direct(
        w: &[f32],
        bias: &[f32],
        x: &[f32],
        (b, c_n, h, wd): (usize, usize, usize, usize),
        o_n: usize,
        p: usize,
    ) -> Vec<f32> {
        let (oh, ow) = (h + 2 * p - 2, wd + 2 * p - 2);
        let mut y = vec![0.0f32; b * o_n * oh * ow];
        for n in 0..b {
            for o in 0..o_n {
                for i in 0..oh {
                    for j in 0..ow {
                        let mut s = bias[o] as f64;
                        for c in 0..c_n {
                            for u in 0..3 {
                                for v in 0..3 {
                                    let (yy, xx) =
                                        ((i + u) as isize - p as isize, (j + v) as isize - p as isize);
                                    if yy < 0 || xx < 0 || yy >= h as isize || xx >= wd as isize {
                                        continue;
                                    }
                                    let xv = x[((n * c_n + c) * h + yy as usize) * wd + xx as usize];
                                    s += (w[((o * c_n + c) * 3 + u) * 3 + v] * xv) as f64;
                                }
                            }
                        }
                        y[((n * o_n + o) * oh + i) * ow + j] = s as f32;
                    }
                }
            }
        }
        y
    }

    /// Against the direct formula: odd and even sizes (a last tile cut by the edge),
    /// padding 0, 1 and 2, several items, and chunks of one tile, a few tiles (chunks
    /// that start and end inside a tile row and cross items) and all tiles.
    #[test]
    fn matches_the_direct_formula() {
        // (batch, cin, cout, h, w, padding)
        for &(b, c_n, o_n, h, wd, p) in
            &[(2, 3, 4, 7, 6, 1), (1, 5, 2, 8, 8, 1), (3, 2, 3, 5, 9, 0), (1, 2, 2, 4, 3, 2)]
        {
            let w: Vec<f32> = (0..o_n * c_n * 9).map(|i| ((i * 29 % 17) as f32 - 8.0) / 7.0).collect();
            let bias: Vec<f32> = (0..o_n).map(|o| o as f32 * 0.25 - 0.3).collect();
            let x: Vec<f32> = (0..b * c_n * h * wd).map(|i| ((i * 13 % 23) as f32 - 11.0) / 5.0).collect();
            let want = direct(&w, &bias, &x, (b, c_n, h, wd), o_n, p);
            let layer =
                Layer { weight: &w, bias: Some(&bias), out_channels: o_n, in_channels: c_n, padding: p };
            let scale = want.iter().fold(1.0f32, |a, v| a.max(v.abs()));
            for budget in [1, 16 * c_n.max(o_n) * 5, usize::MAX] {
                let mut got = vec![f32::NAN; want.len()];
                conv3x3(&layer, &x, b, (h, wd), &mut got, budget);
                let diff = want.iter().zip(&got).map(|(a, g)| (a - g).abs()).fold(0.0f32, f32::max);
                assert!(diff <= 2e-6 * scale, "{b}x{c_n}x{h}x{wd} → {o_n}, p {p}, budget {budget}: {diff}");
            }
        }
    }

    /// G g Gᵀ of a weight that is one at its centre and zero elsewhere, by hand:
    /// G's middle column is (0, ½, −½, 0), so U = (0, ½, −½, 0)ᵀ (0, ½, −½, 0).
    #[test]
    fn the_weight_transform_of_a_centre_tap() {
        let mut g = [0.0f32; 9];
        g[4] = 1.0;
        let u = transform_weight(&g, 1, 1);
        let col = [0.0, 0.5, -0.5, 0.0];
        for i in 0..4 {
            for j in 0..4 {
                assert_eq!(u[4 * i + j], col[i] * col[j], "({i}, {j})");
            }
        }
    }
}

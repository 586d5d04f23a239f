//! 3×3 convolutions with stride 1 by Winograd's minimal filtering F(2×2, 3×3) (Lavin and
//! Gray, "Fast Algorithms for Convolutional Neural Networks", CVPR 2016, section 4).
//!
//! The output of each channel is cut into tiles of 2×2 pixels. Output tile t of channel o is
//!
//!   Y = Aᵀ [ Σ_c U_oc ⊙ V_ct ] A + b_o,   U_oc = G g_oc Gᵀ,   V_ct = Bᵀ d_ct B,
//!
//! with g_oc the 3×3 weight from input channel c, b_o the bias, d_ct the 4×4 input patch under the tile
//! (zero outside the image), ⊙ the element-wise product, and
//!
//!   Bᵀ = [1 0 −1 0; 0 1 1 0; 0 −1 1 0; 0 1 0 −1],   G = [1 0 0; ½ ½ ½; ½ −½ ½; 0 0 1],
//!   Aᵀ = [1 1 1 0; 0 1 −1 −1].
//!
//! For each of the 16 positions ξ of the 4×4, the sum over c is a matrix product,
//! M_ξ = U_ξ (O × C) · V_ξ (C × T) over the T tiles: 16 multiplications per tile and
//! channel pair where the direct convolution spends 36 on the same four outputs. The
//! transforms are additions (and the halves of G). U is computed on each call from the
//! layer's weight, 16 values per weight pair, and each chunk's products pack it again; below
//! [`MIN_TILES`] (measured) that costs more than the multiplications saved, and the input
//! goes to the direct convolution. Tiles
//! of every batch item are the product's columns together, in chunks whose V and M fit
//! [`CHUNK_BUDGET`]. Both transforms run over a row of tiles at a time as plain loops the
//! compiler vectorises.

use rayon::prelude::*;

use crate::cpu::{gemm, Matrix, Product};

/// Fewest tiles (over the whole batch) for which the transform of the weight pays. On the
/// 256² UNet step (batch 3) 8, 64 and 200 were each slower than 32, by 2–7 %.
pub const MIN_TILES: usize = 32;
/// Most floats of V (and of M) of one chunk of tiles (4 MiB, so they stay in the last-level
/// cache between the transforms and the products; on 2 cores with a 32 MiB cache, chunks
/// of 4 to 64 MiB measured alike within the machine's drift).
pub const CHUNK_BUDGET: usize = 1 << 20;
/// Fewest tiles per chunk, whatever the budget: each of a chunk's 16 products packs its
/// U_ξ (O × C) again, which a product over fewer tiles does not pay back.
const MIN_CHUNK: usize = 64;

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

impl Layer<'_> {
    /// Tiles per chunk: as many as keep V and M within [`CHUNK_BUDGET`] floats each, and at
    /// least [`MIN_CHUNK`].
    pub fn chunk(&self) -> usize {
        (CHUNK_BUDGET / (16 * self.in_channels.max(self.out_channels)).max(1)).max(MIN_CHUNK)
    }
}

/// y `[B, O, oh, ow]` of the layer for x `[B, C, h, w]`, where (oh, ow) = (h + 2p − 2,
/// w + 2p − 2) (module doc), `chunk` tiles at a time ([`Layer::chunk`]).
pub fn conv3x3(layer: &Layer, x: &[f32], b: usize, (h, w): (usize, usize), y: &mut [f32], chunk: usize) {
    let (o_n, c_n, p) = (layer.out_channels, layer.in_channels, layer.padding);
    assert!(h + 2 * p >= 3 && w + 2 * p >= 3, "winograd: a {h}x{w} input padded by {p} is smaller than 3x3");
    let (oh, ow) = (h + 2 * p - 2, w + 2 * p - 2);
    let (th, tw) = tiles((oh, ow));
    let per_item = th * tw;
    let total = b * per_item;
    let u = transform_weight(layer.weight, o_n, c_n);
    let chunk = chunk.clamp(1, total.max(1));
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
            let bias = layer.bias.map_or(0.0, |bias| bias[o]);
            let mo = &m[o * 16 * n..(o + 1) * 16 * n];
            let mut ys = [const { Vec::new() }; 4];
            for_each_run(item, per_item, tw, t0, n, |ty, tx0, tx1, at| {
                let len = tx1 - tx0;
                let m = |xi: usize| &mo[xi * n + at..xi * n + at + len];
                for y in ys.iter_mut() {
                    y.resize(len, 0.0);
                }
                transform_output(std::array::from_fn(m), &mut ys, bias);
                for (i, (y_left, y_right)) in [(&ys[0], &ys[1]), (&ys[2], &ys[3])].into_iter().enumerate() {
                    let yy = 2 * ty + i;
                    if yy >= oh {
                        continue;
                    }
                    let row = &mut out[yy * ow..(yy + 1) * ow];
                    for (k, (&left, &right)) in y_left.iter().zip(y_right).enumerate() {
                        let xx = 2 * (tx0 + k);
                        row[xx] = left;
                        if xx + 1 < ow {
                            row[xx + 1] = right;
                        }
                    }
                }
            });
        });
    }
}

/// Calls `f(ty, tx0, tx1, at)` for each tile row of batch item `item` that the chunk of
/// global tiles `t0..t0 + n` holds: tiles tx0..tx1 of tile row ty, the first of them at
/// column `at` of the chunk.
fn for_each_run(
    item: usize,
    per_item: usize,
    tw: usize,
    t0: usize,
    n: usize,
    mut f: impl FnMut(usize, usize, usize, usize),
) {
    let first = (item * per_item).max(t0);
    let last = ((item + 1) * per_item).min(t0 + n);
    let mut t = first;
    while t < last {
        let r = t - item * per_item;
        let (ty, tx0) = (r / tw, r % tw);
        let tx1 = tw.min(tx0 + (last - t));
        f(ty, tx0, tx1, t - t0);
        t += tx1 - tx0;
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
/// (2·ty − p, 2·tx − p). Bᵀ d is computed once per tile row over the padded columns, its
/// even and odd columns apart, so that d B is a plain loop over the row's tiles.
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
    let mut padded: [Vec<f32>; 4] = std::array::from_fn(|_| vec![0.0; width]);
    let mut even: [Vec<f32>; 4] = std::array::from_fn(|_| vec![0.0; tw + 1]);
    let mut odd = even.clone();
    let first_item = t0 / per_item;
    let last_item = (t0 + n - 1) / per_item;
    debug_assert!(last_item < b);
    for item in first_item..=last_item {
        let plane = &x[(item * c_n + c) * h * w..(item * c_n + c + 1) * h * w];
        for_each_run(item, per_item, tw, t0, n, |ty, tx0, tx1, at| {
            // patch row i is input row 2·ty − p + i, column col − p, zero outside the image
            for (i, dst) in padded.iter_mut().enumerate() {
                dst.fill(0.0);
                if let Some(yy) = (2 * ty + i).checked_sub(p).filter(|&yy| yy < h) {
                    let end = (p + w).min(width);
                    dst[p..end].copy_from_slice(&plane[yy * w..yy * w + end - p]);
                }
            }
            // Bᵀ d, row by row, even and odd columns apart
            let [d0, d1, d2, d3] = &padded;
            for k in tx0..=tx1 {
                for (col, parity) in [(2 * k, &mut even), (2 * k + 1, &mut odd)] {
                    let (a, b_, c_, e) = (d0[col], d1[col], d2[col], d3[col]);
                    parity[0][k] = a - c_;
                    parity[1][k] = b_ + c_;
                    parity[2][k] = c_ - b_;
                    parity[3][k] = b_ - e;
                }
            }
            // (Bᵀ d) B for tiles tx0..tx1: columns 2·tx .. 2·tx + 3 are even[tx], odd[tx],
            // even[tx + 1], odd[tx + 1]
            let len = tx1 - tx0;
            for i in 0..4 {
                let (e0, e1) = (&even[i][tx0..tx1], &even[i][tx0 + 1..tx1 + 1]);
                let (o0, o1) = (&odd[i][tx0..tx1], &odd[i][tx0 + 1..tx1 + 1]);
                let (v0, rest) = vc[(4 * i) * n + at..].split_at_mut(n);
                let (v1, rest) = rest.split_at_mut(n);
                let (v2, v3) = rest.split_at_mut(n);
                for k in 0..len {
                    v0[k] = e0[k] - e1[k];
                    v1[k] = o0[k] + e1[k];
                    v2[k] = e1[k] - o0[k];
                    v3[k] = o0[k] - o1[k];
                }
            }
        });
    }
}

/// Y = Aᵀ m A + bias (module doc) for a run of tiles: `m[ξ]` holds sum ξ (4·row + column)
/// of each tile, `y` gets the outputs (0, 0), (0, 1), (1, 0), (1, 1) of each tile.
fn transform_output(m: [&[f32]; 16], y: &mut [Vec<f32>; 4], bias: f32) {
    let [y00, y01, y10, y11] = y;
    for k in 0..y00.len() {
        let s = |xi: usize| m[xi][k];
        // Aᵀ m (2 × 4)
        let top = |j: usize| s(j) + s(4 + j) + s(8 + j);
        let bottom = |j: usize| s(4 + j) - s(8 + j) - s(12 + j);
        let (t0, t1, t2, t3) = (top(0), top(1), top(2), top(3));
        let (b0, b1, b2, b3) = (bottom(0), bottom(1), bottom(2), bottom(3));
        y00[k] = t0 + t1 + t2 + bias;
        y01[k] = t1 - t2 - t3 + bias;
        y10[k] = b0 + b1 + b2 + bias;
        y11[k] = b1 - b2 - b3 + bias;
    }
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

    /// Against the direct formula: odd and even sizes (a last tile cut by the edge, one
    /// row of tiles), padding 0, 1 and 2, several items, and chunks of one tile, of a few
    /// tiles (chunks that start and end inside a tile row and span two or more items) and
    /// of all tiles.
    #[test]
    fn matches_the_direct_formula() {
        // (batch, cin, cout, h, w, padding)
        for &(b, c_n, o_n, h, wd, p) in &[
            (2, 3, 4, 7, 6, 1),
            (1, 5, 2, 8, 8, 1),
            (3, 2, 3, 5, 9, 0),
            (1, 2, 2, 4, 3, 2),
            (4, 2, 2, 3, 7, 0),
        ] {
            let w: Vec<f32> = (0..o_n * c_n * 9).map(|i| ((i * 29 % 17) as f32 - 8.0) / 7.0).collect();
            let bias: Vec<f32> = (0..o_n).map(|o| o as f32 * 0.25 - 0.3).collect();
            let x: Vec<f32> = (0..b * c_n * h * wd).map(|i| ((i * 13 % 23) as f32 - 11.0) / 5.0).collect();
            let want = direct(&w, &bias, &x, (b, c_n, h, wd), o_n, p);
            let layer =
                Layer { weight: &w, bias: Some(&bias), out_channels: o_n, in_channels: c_n, padding: p };
            let scale = want.iter().fold(1.0f32, |a, v| a.max(v.abs()));
            for chunk in [1, 5, 17, usize::MAX] {
                let mut got = vec![f32::NAN; want.len()];
                conv3x3(&layer, &x, b, (h, wd), &mut got, chunk);
                assert!(got.iter().all(|v| v.is_finite()), "every output pixel is written");
                let diff = want.iter().zip(&got).map(|(a, g)| (a - g).abs()).fold(0.0f32, f32::max);
                assert!(diff <= 2e-6 * scale, "{b}x{c_n}x{h}x{wd} → {o_n}, p {p}, chunks of {chunk}: {diff}");
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

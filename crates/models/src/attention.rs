//! Multi-head scaled dot-product attention, softmax(q kᵀ · scale) v per head.
//!
//! q is `b × n × c`, k and v `b × m × c`; head h owns channels h·d .. (h+1)·d with
//! d = c / heads (diffusers' `Attention.head_to_batch_dim` split), and the output is
//! `b × n × c` in the same layout (`batch_to_head_dim`).
//!
//! On the CPU the heads are never split into their own tensors: each task takes a block
//! of query rows of one batch item and, head by head, multiplies the rows' q by kᵀ into a
//! block of weights (the scale as the product's factor), takes the exponentials of each
//! row less its largest value in place, multiplies the block by v straight into the
//! head's columns of the output and divides each output row by its row's sum (d values
//! rather than m weights), all read and written through strides. A block holds at most
//! [`BLOCK`] weights, so the n × m weights of a head are never written whole, and up to
//! [`MAX_ROWS`] rows, because each task packs the head's k and v again for its products
//! (a block of a few rows against thousands of keys spends its time packing); the
//! tasks run in parallel, each product on its own thread. This replaces three copies that
//! split the heads, one that joins them, the scaling of q, and products too small to
//! split well over the threads. Elsewhere (a GPU) the heads
//! are split and each slice of at most 2²⁰ weights takes candle's operations.

use crate::cpu::{f32_input, gemm, Matrix, Product};
use candle_core::{CpuStorage, CustomOp3, DType, Layout, Shape, Tensor};
use rayon::prelude::*;

/// Largest number of attention weights a CPU task holds at once (4 MiB of f32).
const BLOCK: usize = 1 << 20;
/// Most query rows per CPU task.
const MAX_ROWS: usize = 256;
/// Largest number of weights computed at once off the CPU (4 MiB of f32).
const SLICE_BUDGET: usize = 1 << 20;

/// softmax(q kᵀ · scale) v for each of `heads` heads (module doc).
pub fn multi_head_attention(
    q: &Tensor,
    k: &Tensor,
    v: &Tensor,
    heads: usize,
    scale: f64,
) -> candle_core::Result<Tensor> {
    let (b, n, c) = q.dims3()?;
    let (bk, m, ck) = k.dims3()?;
    if bk != b || ck != c || v.dims3()? != (b, m, c) || heads == 0 || !c.is_multiple_of(heads) {
        candle_core::bail!(
            "attention: q {:?}, k {:?}, v {:?} with {heads} heads",
            q.dims(),
            k.dims(),
            v.dims()
        );
    }
    let on_cpu = [q, k, v].iter().all(|t| t.device().is_cpu() && t.dtype() == DType::F32);
    if on_cpu {
        let (q, k, v) = (q.contiguous()?, k.contiguous()?, v.contiguous()?);
        return q.apply_op3_no_bwd(&k, &v, &Attention { heads, scale: scale as f32 });
    }
    let split = |t: &Tensor| -> candle_core::Result<Tensor> {
        let (b, len, c) = t.dims3()?;
        t.reshape((b, len, heads, c / heads))?.transpose(1, 2)?.contiguous()?.reshape((
            b * heads,
            len,
            c / heads,
        ))
    };
    let o = sliced_attention(&split(q)?, &split(k)?, &split(v)?, scale, SLICE_BUDGET)?;
    o.reshape((b, heads, n, c / heads))?.transpose(1, 2)?.reshape((b, n, c))
}

struct Attention {
    heads: usize,
    scale: f32,
}

impl CustomOp3 for Attention {
    fn name(&self) -> &'static str {
        "multi-head-attention"
    }

    fn cpu_fwd(
        &self,
        qs: &CpuStorage,
        ql: &Layout,
        ks: &CpuStorage,
        kl: &Layout,
        vs: &CpuStorage,
        vl: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let (q, k, v) = (
            f32_input(qs, ql, "attention")?,
            f32_input(ks, kl, "attention")?,
            f32_input(vs, vl, "attention")?,
        );
        let (b, n, c) = ql.shape().dims3()?;
        let m = kl.shape().dims3()?.1;
        let d = c / self.heads;
        // enough tasks to keep every thread busy to the end, as few as that allows: each
        // task packs the head's k and v again for its products
        let tasks = 4 * rayon::current_num_threads();
        let rows = (BLOCK / m.max(1)).clamp(1, MAX_ROWS).min((b * n).div_ceil(tasks)).max(1);
        let mut y = vec![0.0f32; b * n * c];
        if y.is_empty() || m == 0 {
            // no keys: softmax over nothing, as candle's operations give it (NaN)
            y.fill(if m == 0 { f32::NAN } else { 0.0 });
            return Ok((CpuStorage::F32(y), ql.shape().clone()));
        }
        y.par_chunks_mut(n * c).enumerate().for_each(|(item, y_item)| {
            let (k, v) = (&k[item * m * c..(item + 1) * m * c], &v[item * m * c..(item + 1) * m * c]);
            y_item.par_chunks_mut(rows * c).enumerate().for_each(|(block, out)| {
                let r0 = block * rows;
                let len = out.len() / c;
                let q = &q[(item * n + r0) * c..(item * n + r0 + len) * c];
                let mut weights = vec![0.0f32; len * m];
                let mut inv_sums = vec![0.0f32; len];
                let serial = |accumulate, scale| Product { accumulate, scale, parallel: false };
                for h in 0..self.heads {
                    // scores = scale · q_h kₕᵀ: q_h rows c apart; kₕᵀ (d × m) element (i, j) at j·c + i
                    let q_h = Matrix { data: &q[h * d..], rows: c, cols: 1 };
                    let k_t = Matrix { data: &k[h * d..], rows: 1, cols: c };
                    gemm(&mut weights, 0, m, q_h, k_t, (len, m, d), serial(false, self.scale));
                    for (w, inv) in weights.chunks_exact_mut(m).zip(&mut inv_sums) {
                        *inv = 1.0 / crate::softmax::exp_row_in_place(w);
                    }
                    // out[:, h·d..(h+1)·d] = weights vₕ, each row then divided by its sum
                    let w = Matrix { data: &weights, rows: m, cols: 1 };
                    let v_h = Matrix { data: &v[h * d..], rows: c, cols: 1 };
                    gemm(out, h * d, c, w, v_h, (len, d, m), serial(false, 1.0));
                    for (row, &inv) in out.chunks_exact_mut(c).zip(&inv_sums) {
                        row[h * d..(h + 1) * d].iter_mut().for_each(|o| *o *= inv);
                    }
                }
            });
        });
        Ok((CpuStorage::F32(y), ql.shape().clone()))
    }
}

/// softmax(q kᵀ · scale) v for `q`: `S × n × d`, `k`, `v`: `S × m × d`, in blocks of at
/// most `budget` weights: several of the S (batch × heads) slices at once when their
/// n × m weights fit, else blocks of query rows of one slice. The scale is applied to q
/// (n × d values) rather than to the weights (n × m), and each block is computed exactly
/// as the whole would be (a softmax row depends on its own weights only).
fn sliced_attention(
    q: &Tensor,
    k: &Tensor,
    v: &Tensor,
    scale: f64,
    budget: usize,
) -> candle_core::Result<Tensor> {
    let (s, n, _) = q.dims3()?;
    let m = k.dim(1)?;
    let q = (q * scale)?;
    let block =
        |q: &Tensor, k: &Tensor, v: &Tensor| crate::softmax::softmax_last_dim(&q.matmul(&k.t()?)?)?.matmul(v);
    if n * m <= budget {
        let per = (budget / (n * m).max(1)).clamp(1, s.max(1));
        let mut outs = Vec::with_capacity(s.div_ceil(per));
        for start in (0..s).step_by(per) {
            let len = per.min(s - start);
            outs.push(block(
                &q.narrow(0, start, len)?,
                &k.narrow(0, start, len)?,
                &v.narrow(0, start, len)?,
            )?);
        }
        return Tensor::cat(&outs, 0);
    }
    let rows = (budget / m.max(1)).clamp(1, n);
    let mut heads = Vec::with_capacity(s);
    for h in 0..s {
        let (qh, kh, vh) = (q.narrow(0, h, 1)?, k.narrow(0, h, 1)?, v.narrow(0, h, 1)?);
        let mut outs = Vec::with_capacity(n.div_ceil(rows));
        for r0 in (0..n).step_by(rows) {
            outs.push(block(&qh.narrow(1, r0, rows.min(n - r0))?, &kh, &vh)?);
        }
        heads.push(Tensor::cat(&outs, 1)?);
    }
    Tensor::cat(&heads, 0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    fn max_diff(a: &Tensor, b: &Tensor) -> f32 {
        (a - b).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f32>().unwrap()
    }

    /// The direct formula with candle's operations: heads split by reshape and transpose,
    /// the whole weight matrix, candle's softmax.
    fn direct(q: &Tensor, k: &Tensor, v: &Tensor, heads: usize, scale: f64) -> Tensor {
        let split = |t: &Tensor| {
            let (b, len, c) = t.dims3().unwrap();
            t.reshape((b, len, heads, c / heads)).unwrap().transpose(1, 2).unwrap().contiguous().unwrap()
        };
        let (qh, kh, vh) = (split(q), split(k), split(v));
        let w = candle_nn::ops::softmax_last_dim(&(qh.matmul(&kh.t().unwrap()).unwrap() * scale).unwrap())
            .unwrap();
        let o = w.matmul(&vh).unwrap();
        let (b, n, c) = q.dims3().unwrap();
        o.transpose(1, 2).unwrap().reshape((b, n, c)).unwrap()
    }

    /// Against the direct formula: one and several heads, self- and cross-attention, a
    /// query count that is not a multiple of a task's rows, more keys than fit a block
    /// in one row, and a transposed (non-contiguous) input.
    #[test]
    fn matches_the_direct_formula() {
        let dev = Device::Cpu;
        for &(b, n, m, c, heads) in &[
            (1, 5, 7, 4, 1),
            (2, 130, 130, 16, 2),
            (3, 67, 77, 40, 5),
            (1, 3, 70_000, 8, 2),
            (2, 200, 9, 12, 3),
        ] {
            let q = crate::testing::randn(0f32, 1.0, (b, n, c), &dev).unwrap();
            let k = crate::testing::randn(0f32, 1.0, (b, m, c), &dev).unwrap();
            let v = crate::testing::randn(0f32, 1.0, (b, m, c), &dev).unwrap();
            let scale = 1.0 / ((c / heads) as f64).sqrt();
            let want = direct(&q, &k, &v, heads, scale);
            let got = multi_head_attention(&q, &k, &v, heads, scale).unwrap();
            assert_eq!(got.dims(), &[b, n, c]);
            let d = max_diff(&got, &want);
            assert!(d < 2e-5, "{b}×{n}×{c}, {m} keys, {heads} heads: {d}");
        }
        let q = crate::testing::randn(0f32, 1.0, (2, 8, 6), &dev).unwrap().transpose(1, 2).unwrap();
        let k = crate::testing::randn(0f32, 1.0, (2, 5, 8), &dev).unwrap();
        let v = crate::testing::randn(0f32, 1.0, (2, 5, 8), &dev).unwrap();
        let d = max_diff(&multi_head_attention(&q, &k, &v, 2, 0.5).unwrap(), &direct(&q, &k, &v, 2, 0.5));
        assert!(d < 2e-5, "transposed q: {d}");
    }

    /// The sliced path (off the CPU) computes every block as the whole would be.
    #[test]
    fn sliced_attention_equals_whole() {
        let d = Device::Cpu;
        let q = crate::testing::randn(0f32, 1.0, (6, 10, 4), &d).unwrap();
        let k = crate::testing::randn(0f32, 1.0, (6, 7, 4), &d).unwrap();
        let v = crate::testing::randn(0f32, 1.0, (6, 7, 4), &d).unwrap();
        let whole = sliced_attention(&q, &k, &v, 0.5, usize::MAX).unwrap();
        for budget in [1, 7, 20, 70, 140, 300] {
            let sliced = sliced_attention(&q, &k, &v, 0.5, budget).unwrap();
            assert!(max_diff(&sliced, &whole) < 1e-6, "budget {budget}");
        }
        let w =
            candle_nn::ops::softmax_last_dim(&(q.matmul(&k.t().unwrap()).unwrap() * 0.5).unwrap()).unwrap();
        assert!(max_diff(&w.matmul(&v).unwrap(), &whole) < 1e-6);
    }

    #[test]
    fn refuses_mismatched_shapes() {
        let dev = Device::Cpu;
        let q = Tensor::zeros((1, 4, 6), DType::F32, &dev).unwrap();
        let k = Tensor::zeros((1, 5, 6), DType::F32, &dev).unwrap();
        let v = Tensor::zeros((1, 5, 4), DType::F32, &dev).unwrap();
        assert!(multi_head_attention(&q, &k, &v, 2, 1.0).is_err());
        assert!(multi_head_attention(&q, &k, &k, 4, 1.0).is_err(), "6 channels do not split into 4 heads");
    }
}

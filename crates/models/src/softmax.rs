//! Softmax over the last axis on the CPU with a vectorisable exponential.
//!
//! softmax(x)_j = exp(x_j − max x) / Σ_k exp(x_k − max x) per row. candle's
//! `softmax_last_dim` calls the scalar `expf` of the C library per weight; in the UNet's
//! attention at 512² (4096 × 4096 weights per head) that scalar call is a tenth of a step.
//! Here exp(t) for t ≤ 0 is computed as 2ⁿ · p(r) with n = round(t / ln 2),
//! r = t − n ln 2 (ln 2 split in two parts, Cody and Waite) and p the degree-6 Taylor
//! polynomial of eʳ on |r| ≤ ln 2 / 2 (relative error below 2·10⁻⁷, about one f32 unit in
//! the last place), written as plain arithmetic over slices so the compiler vectorises it;
//! the row loop is compiled for AVX-512, for AVX2 and for the baseline, and the CPU's
//! best is picked at run time. Rows run in parallel. Off the CPU, or in another dtype, candle's op runs.

use crate::cpu::lanes_fold;
use candle_core::{CpuStorage, CustomOp1, DType, Layout, Shape, Tensor};
use rayon::prelude::*;

/// softmax over the last axis of `x`.
pub fn softmax_last_dim(x: &Tensor) -> candle_core::Result<Tensor> {
    if x.device().is_cpu() && x.dtype() == DType::F32 && x.rank() >= 1 {
        x.contiguous()?.apply_op1_no_bwd(&Softmax)
    } else {
        candle_nn::ops::softmax_last_dim(x)
    }
}

struct Softmax;

impl CustomOp1 for Softmax {
    fn name(&self) -> &'static str {
        "softmax-last-dim"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let x = crate::cpu::f32_input(storage, layout, "softmax")?;
        let row = layout.shape().dims().last().copied().unwrap_or(1).max(1);
        let mut y = vec![0.0f32; x.len()];
        // rows in parallel, a few at a time so short rows do not drown in scheduling
        let per_task = (4096 / row).max(1) * row;
        y.par_chunks_mut(per_task).zip(x.par_chunks(per_task)).for_each(|(out, inp)| {
            for (o, i) in out.chunks_exact_mut(row).zip(inp.chunks_exact(row)) {
                softmax_row(i, o);
            }
        });
        Ok((CpuStorage::F32(y), layout.shape().clone()))
    }
}

crate::cpu::simd_versions! {
    /// One row (module doc), for the vector units the CPU has.
    fn softmax_row(x: &[f32], y: &mut [f32]) {
        y.copy_from_slice(x);
        let inv = 1.0 / exp_row_in_place(y);
        y.iter_mut().for_each(|o| *o *= inv);
    }
}

crate::cpu::simd_versions! {
    /// The unnormalised softmax of a row in place: yⱼ ← exp(yⱼ − max y); returns Σⱼ yⱼ,
    /// by which the caller divides (attention divides its output rows instead, which are
    /// shorter than the weight rows).
    pub(crate) fn exp_row_in_place(y: &mut [f32]) -> f32 {
        let max = lanes_fold(y, f32::NEG_INFINITY, f32::max, f32::max);
        if !max.is_finite() {
            // a row of −∞ (fully masked) or holding NaN or +∞: as the exact formula gives it
            y.iter_mut().for_each(|v| *v = (*v - max).exp());
            return y.iter().sum();
        }
        const LANES: usize = crate::cpu::LANES;
        let mut sums = [0.0f32; LANES];
        let mut chunks = y.chunks_exact_mut(LANES);
        for c in &mut chunks {
            for (s, v) in sums.iter_mut().zip(c) {
                *v = exp_nonpositive(*v - max);
                *s += *v;
            }
        }
        let mut tail = 0.0;
        for v in chunks.into_remainder() {
            *v = exp_nonpositive(*v - max);
            tail += *v;
        }
        sums.iter().fold(tail, |a, &s| a + s)
    }
}

/// eᵗ for t ≤ 0 (module doc); e⁻⁸⁷ (about 1.6 · 10⁻³⁸) below −87.
#[inline(always)]
pub(crate) fn exp_nonpositive(t: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    // round to the nearest integer by adding and taking away 1.5 · 2²³ (exact for
    // |x| < 2²²; one vector addition, where `round_ties_even` is a library call on SSE2)
    const ROUND: f32 = 12_582_912.0;
    let t = t.max(-87.0);
    let shifted = t * LOG2E + ROUND;
    let n = shifted - ROUND;
    let r = (t - n * LN2_HI) - n * LN2_LO;
    let p = 1.0
        + r * (1.0 + r * (0.5 + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0))))));
    // 2ⁿ for n in [−126, 0] by its exponent bits. The integer n is read from the bits of
    // `shifted`, whose unit in the last place is 1 (1.5 · 2²³ + n holds n in its mantissa):
    // `n as i32` is a saturating conversion, which the compiler does not vectorise.
    let n_int = (shifted.to_bits() as i32).wrapping_sub(ROUND.to_bits() as i32);
    let two_n = f32::from_bits((n_int.wrapping_add(127) as u32) << 23);
    p * two_n
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    #[test]
    fn exp_is_within_two_units_in_the_last_place() {
        let mut worst = 0.0f64;
        for i in 0..200_000 {
            let t = -87.0 * i as f32 / 200_000.0;
            let want = (t as f64).exp();
            let got = exp_nonpositive(t) as f64;
            worst = worst.max(((got - want) / want).abs());
        }
        assert!(worst < 3e-7, "relative error {worst}");
        assert_eq!(exp_nonpositive(0.0), 1.0);
        assert_eq!(exp_nonpositive(-200.0), exp_nonpositive(-87.0));
    }

    /// The exponentials less the row's largest value and their sum: divided, the softmax
    /// (a row longer than the lanes with a tail, a short row, a fully masked row).
    #[test]
    fn exp_row_in_place_divided_by_its_sum_is_the_softmax() {
        for row in [(0..37).map(|i| (i as f32 * 0.7).sin() * 9.0).collect::<Vec<_>>(), vec![1.0, -2.0, 0.5]] {
            let mut y = row.clone();
            let sum = exp_row_in_place(&mut y);
            let max = row.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            let want_sum: f64 = row.iter().map(|&v| ((v - max) as f64).exp()).sum();
            assert!(((sum as f64 - want_sum) / want_sum).abs() < 1e-6, "{sum} against {want_sum}");
            for (&got, &v) in y.iter().zip(&row) {
                let want = ((v - max) as f64).exp();
                assert!((got as f64 - want).abs() < 1e-6 * want.max(1e-30) + 1e-12, "{got} against {want}");
            }
        }
        let mut masked = vec![f32::NEG_INFINITY; 5];
        assert!(exp_row_in_place(&mut masked).is_nan(), "a fully masked row has no softmax");
    }

    #[test]
    fn matches_candle_softmax() {
        let dev = Device::Cpu;
        for shape in [vec![3, 5, 17], vec![2, 4096], vec![7, 1], vec![1, 3, 2, 33]] {
            let x = (crate::testing::randn(0f32, 4.0, shape.as_slice(), &dev).unwrap() + 1.5).unwrap();
            let want = candle_nn::ops::softmax_last_dim(&x).unwrap();
            let got = softmax_last_dim(&x).unwrap();
            let scale = want.max_all().unwrap().to_scalar::<f32>().unwrap();
            let d = (got - want).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
            // the sums run in another order (16 lanes), so compare relative to the largest weight
            assert!(d < 1e-5 * scale, "{shape:?}: {d} (largest weight {scale})");
        }
        // a transposed input is made contiguous first
        let x = crate::testing::randn(0f32, 1.0, (4, 6), &dev).unwrap().t().unwrap();
        let d = (softmax_last_dim(&x).unwrap()
            - candle_nn::ops::softmax_last_dim(&x.contiguous().unwrap()).unwrap())
        .unwrap()
        .abs()
        .unwrap()
        .max_all()
        .unwrap()
        .to_scalar::<f32>()
        .unwrap();
        assert!(d < 1e-6, "{d}");
    }
}

//! Group normalisation, optionally followed by SiLU, in one pass on the CPU.
//!
//! For x `[B, C, …]` split into G groups of C/G channels, each (batch item, group) has
//! mean μ and variance σ² over its channels and positions, and
//! y = γ_c (x − μ) / √(σ² + ε) + β_c, then y · sigmoid(y) when SiLU follows (diffusers'
//! `GroupNorm` then `SiLU`, as every resnet block runs them).
//!
//! candle's `GroupNorm` builds this from eight tensor operations (sum, broadcast
//! subtract, square, sum, add, square root, broadcast divide, then the affine map as two
//! broadcast operations) and SiLU is one more; each reads and writes the whole
//! activation. Here the statistics take one read (sums in f64) and the output one write,
//! (batch item, group) pairs in parallel. Off the CPU, or in another dtype, candle's layer
//! runs instead; the tests compare the two.

use candle_core::{CpuStorage, CustomOp1, DType, Layout, Module, Shape, Tensor};
use candle_nn::VarBuilder;
use rayon::prelude::*;

/// A group normalisation layer loaded like `candle_nn::group_norm` (`weight`, `bias`).
#[derive(Debug, Clone)]
pub struct GroupNorm {
    candle: candle_nn::GroupNorm,
    op: GroupNormOp,
}

/// The CPU operation; `silu` picks the fused activation.
#[derive(Debug, Clone)]
struct GroupNormOp {
    weight: Vec<f32>,
    bias: Vec<f32>,
    groups: usize,
    eps: f64,
    silu: bool,
}

/// Loads a group norm over `channels` channels in `groups` groups from `vb`.
pub fn group_norm(
    groups: usize,
    channels: usize,
    eps: f64,
    vb: VarBuilder,
) -> candle_core::Result<GroupNorm> {
    let candle = candle_nn::group_norm(groups, channels, eps, vb.clone())?;
    let weight = vb.get(channels, "weight")?;
    let bias = vb.get(channels, "bias")?;
    let op = GroupNormOp {
        weight: weight.to_dtype(DType::F32)?.to_vec1()?,
        bias: bias.to_dtype(DType::F32)?.to_vec1()?,
        groups,
        eps,
        silu: false,
    };
    Ok(GroupNorm { candle, op })
}

impl GroupNorm {
    fn cpu(&self, x: &Tensor) -> bool {
        x.device().is_cpu() && x.dtype() == DType::F32 && x.rank() >= 2
    }

    /// SiLU(GroupNorm(x)).
    pub fn forward_silu(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        if self.cpu(x) {
            x.contiguous()?.apply_op1_no_bwd(&GroupNormOp { silu: true, ..self.op.clone() })
        } else {
            candle_nn::ops::silu(&self.candle.forward(x)?)
        }
    }
}

impl Module for GroupNorm {
    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        if self.cpu(x) {
            x.contiguous()?.apply_op1_no_bwd(&self.op)
        } else {
            self.candle.forward(x)
        }
    }
}

impl CustomOp1 for GroupNormOp {
    fn name(&self) -> &'static str {
        "group-norm"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let x = crate::cpu::f32_input(storage, layout, "group-norm")?;
        let dims = layout.shape().dims();
        let c = dims[1];
        if c != self.weight.len() || self.groups == 0 || !c.is_multiple_of(self.groups) {
            candle_core::bail!(
                "group-norm: {c} channels, {} weights in {} groups",
                self.weight.len(),
                self.groups
            );
        }
        let positions: usize = dims[2..].iter().product();
        let per_group = c / self.groups * positions;
        let mut y = vec![0.0f32; x.len()];
        y.par_chunks_mut(per_group).zip(x.par_chunks(per_group)).enumerate().for_each(|(k, (out, inp))| {
            let first_channel = (k % self.groups) * (c / self.groups);
            let (mean, rstd) = moments(inp, self.eps);
            for (j, (o, i)) in out.chunks_mut(positions).zip(inp.chunks(positions)).enumerate() {
                let ch = first_channel + j;
                let scale = (self.weight[ch] as f64 * rstd) as f32;
                let shift = self.bias[ch] - (mean * self.weight[ch] as f64 * rstd) as f32;
                affine(i, o, scale, shift, self.silu);
            }
        });
        Ok((CpuStorage::F32(y), layout.shape().clone()))
    }
}

crate::cpu::simd_versions! {
    /// The mean of `x` and 1/√(variance + eps), summed in f64 over independent lanes.
    fn moments(x: &[f32], eps: f64) -> (f64, f64) {
        let n = x.len().max(1) as f64;
        let add = |a: f64, b: f64| a + b;
        let mean = crate::cpu::lanes_fold(x, 0.0, |a, v| a + v as f64, add) / n;
        let var = crate::cpu::lanes_fold(x, 0.0, |a, v| a + (v as f64 - mean) * (v as f64 - mean), add) / n;
        (mean, 1.0 / (var + eps).sqrt())
    }
}

crate::cpu::simd_versions! {
    /// o = x · scale + shift, then SiLU(t) = t / (1 + e⁻ᵗ) with `silu`: e⁻ᵗ from the
    /// vectorised exponential of −|t| (t ≥ 0: t / (1 + e); t < 0: t · e / (1 + e)).
    fn affine(x: &[f32], out: &mut [f32], scale: f32, shift: f32, silu: bool) {
        if silu {
            for (o, &v) in out.iter_mut().zip(x) {
                let t = v * scale + shift;
                let e = crate::softmax::exp_nonpositive(-t.abs());
                let num = if t >= 0.0 { t } else { t * e };
                *o = num / (1.0 + e);
            }
        } else {
            for (o, &v) in out.iter_mut().zip(x) {
                *o = v * scale + shift;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;
    use candle_nn::VarMap;

    /// Against candle's layer (and candle's SiLU) on inputs of rank 3 and 4, with a
    /// non-trivial affine map and an offset mean.
    #[test]
    fn matches_candle_group_norm_and_silu() {
        let dev = Device::Cpu;
        for (i, shape) in [vec![2, 8, 5, 3], vec![3, 6, 7], vec![1, 32, 4, 4]].into_iter().enumerate() {
            let varmap = VarMap::new();
            let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
            let channels = shape[1];
            let groups = if channels == 6 { 3 } else { 4 };
            let norm = group_norm(groups, channels, 1e-5, vb.pp(format!("n{i}"))).unwrap();
            // make γ and β non-trivial
            let w = crate::testing::randn(1f32, 0.5, channels, &dev).unwrap();
            let b = crate::testing::randn(0f32, 0.5, channels, &dev).unwrap();
            let norm = GroupNorm {
                candle: candle_nn::GroupNorm::new(w.clone(), b.clone(), channels, groups, 1e-5).unwrap(),
                op: GroupNormOp { weight: w.to_vec1().unwrap(), bias: b.to_vec1().unwrap(), ..norm.op },
            };
            let x = (crate::testing::randn(0f32, 2.0, shape.as_slice(), &dev).unwrap() + 3.0).unwrap();
            let close = |a: &Tensor, b: &Tensor, what: &str| {
                let d = (a - b).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
                assert!(d < 2e-5, "case {i} {what}: {d}");
            };
            close(&norm.forward(&x).unwrap(), &norm.candle.forward(&x).unwrap(), "norm");
            let want = candle_nn::ops::silu(&norm.candle.forward(&x).unwrap()).unwrap();
            close(&norm.forward_silu(&x).unwrap(), &want, "norm + silu");
        }
    }
}

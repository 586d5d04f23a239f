//! Linear layers and the GEGLU activation on the CPU.
//!
//! [`Linear`]: y = x Wᵀ + b as one GEMM over the rows of x, the bias as the GEMM's starting
//! value. candle's layer runs the product and then a broadcast add of b, whose row-by-row
//! iteration is one of the larger costs of a UNet step after the GEMM itself.
//!
//! [`geglu`]: for h = [value, gate] (the last axis split in halves), value · GELU(gate)
//! with GELU(g) = g/2 · (1 + erf(g/√2)) (diffusers' `GEGLU`, exact GELU), in one pass,
//! where candle takes a chunk, a strided GELU through the C library's scalar `erff` and
//! a strided product. erf is Abramowitz and Stegun 7.1.26 (absolute error below
//! 1.5·10⁻⁷ in exact arithmetic, below 10⁻⁶ in f32), written as plain arithmetic so the compiler vectorises it, and compiled a
//! second time for AVX-512, picked at run time.
//!
//! Off the CPU or in another dtype both fall back to candle; the tests compare the two.

use candle_core::{CpuStorage, CustomOp1, DType, Layout, Module, Shape, Tensor, D};
use candle_nn::VarBuilder;
use rayon::prelude::*;

use crate::cpu::{f32_input, gemm_accumulate, Matrix};
use crate::softmax::exp_nonpositive;

/// A linear layer loaded like `candle_nn::linear` (`weight` `[out, in]`, `bias` `[out]`);
/// the weights live in one place, plain memory on the CPU path.
#[derive(Debug, Clone)]
pub enum Linear {
    /// f32 on the CPU: the GEMM of the module doc.
    Cpu(LinearOp),
    /// Anything else: candle's layer.
    Candle(candle_nn::Linear),
}

/// The CPU layer's weights.
#[derive(Debug, Clone)]
pub struct LinearOp {
    /// `[out, in]` row-major.
    weight: Vec<f32>,
    bias: Option<Vec<f32>>,
    inputs: usize,
    outputs: usize,
}

/// With a bias.
pub fn linear(inputs: usize, outputs: usize, vb: VarBuilder) -> candle_core::Result<Linear> {
    from_candle(candle_nn::linear(inputs, outputs, vb)?)
}

/// Without a bias.
pub fn linear_no_bias(inputs: usize, outputs: usize, vb: VarBuilder) -> candle_core::Result<Linear> {
    from_candle(candle_nn::linear_no_bias(inputs, outputs, vb)?)
}

fn from_candle(candle: candle_nn::Linear) -> candle_core::Result<Linear> {
    let w = candle.weight();
    if !w.device().is_cpu() || w.dtype() != DType::F32 {
        return Ok(Linear::Candle(candle));
    }
    let (outputs, inputs) = w.dims2()?;
    Ok(Linear::Cpu(LinearOp {
        weight: w.flatten_all()?.to_vec1()?,
        bias: candle.bias().map(|b| b.to_vec1()).transpose()?,
        inputs,
        outputs,
    }))
}

impl LinearOp {
    /// The same layer as a candle layer on `device` (for an input the CPU path does not take).
    fn to_candle(&self, device: &candle_core::Device) -> candle_core::Result<candle_nn::Linear> {
        let w = Tensor::from_slice(&self.weight, (self.outputs, self.inputs), device)?;
        let b = self.bias.as_ref().map(|b| Tensor::from_slice(b, self.outputs, device)).transpose()?;
        Ok(candle_nn::Linear::new(w, b))
    }
}

impl Module for Linear {
    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        match self {
            Linear::Cpu(op) if x.device().is_cpu() && x.dtype() == DType::F32 => {
                x.contiguous()?.apply_op1_no_bwd(op)
            }
            Linear::Cpu(op) => op.to_candle(x.device())?.forward(x),
            Linear::Candle(c) => c.forward(x),
        }
    }
}

impl CustomOp1 for LinearOp {
    fn name(&self) -> &'static str {
        "linear"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let x = f32_input(storage, layout, "linear")?;
        let dims = layout.shape().dims();
        if dims.last() != Some(&self.inputs) {
            candle_core::bail!("linear: input {dims:?} does not end in {} features", self.inputs);
        }
        let rows = x.len() / self.inputs.max(1);
        let mut y = vec![0.0f32; rows * self.outputs];
        if let Some(b) = &self.bias {
            y.chunks_exact_mut(self.outputs).for_each(|row| row.copy_from_slice(b));
        }
        // the rhs is the weight read transposed: step 1 along k, `inputs` along n
        let lhs = Matrix { data: x, rows: self.inputs, cols: 1 };
        let rhs = Matrix { data: &self.weight, rows: 1, cols: self.inputs };
        gemm_accumulate(&mut y, 0, self.outputs, lhs, rhs, (rows, self.outputs, self.inputs));
        let mut out = dims.to_vec();
        *out.last_mut().expect("checked above") = self.outputs;
        Ok((CpuStorage::F32(y), Shape::from(out)))
    }
}

/// value · GELU(gate) for `h` = [value, gate] along the last axis (module doc).
pub fn geglu(h: &Tensor) -> candle_core::Result<Tensor> {
    if h.device().is_cpu() && h.dtype() == DType::F32 {
        h.contiguous()?.apply_op1_no_bwd(&Geglu)
    } else {
        let halves = h.chunk(2, D::Minus1)?;
        &halves[0] * halves[1].gelu_erf()?
    }
}

struct Geglu;

impl CustomOp1 for Geglu {
    fn name(&self) -> &'static str {
        "geglu"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let x = f32_input(storage, layout, "geglu")?;
        let mut dims = layout.shape().dims().to_vec();
        let width = dims.last().copied().unwrap_or(0);
        if width == 0 || width % 2 != 0 {
            candle_core::bail!("geglu: the last axis ({width}) must split in two halves");
        }
        let half = width / 2;
        let mut y = vec![0.0f32; x.len() / 2];
        let per_task = (8192 / half).max(1);
        y.par_chunks_mut(per_task * half).zip(x.par_chunks(per_task * width)).for_each(|(out, inp)| {
            for (o, i) in out.chunks_exact_mut(half).zip(inp.chunks_exact(width)) {
                geglu_row(&i[..half], &i[half..], o);
            }
        });
        *dims.last_mut().expect("checked above") = half;
        Ok((CpuStorage::F32(y), Shape::from(dims)))
    }
}

crate::cpu::simd_versions! {
    /// value · GELU(gate) (module doc), for the vector units the CPU has.
    fn geglu_row(value: &[f32], gate: &[f32], out: &mut [f32]) {
        for ((o, &v), &g) in out.iter_mut().zip(value).zip(gate) {
            *o = v * 0.5 * g * (1.0 + erf(g * std::f32::consts::FRAC_1_SQRT_2));
        }
    }
}

/// erf(x), Abramowitz and Stegun 7.1.26 (module doc).
#[inline(always)]
fn erf(x: f32) -> f32 {
    const P: f32 = 0.327_591_1;
    const A: [f32; 5] = [0.254_829_6, -0.284_496_74, 1.421_413_7, -1.453_152_1, 1.061_405_4];
    let z = x.abs();
    let t = 1.0 / (1.0 + P * z);
    let poly = t * (A[0] + t * (A[1] + t * (A[2] + t * (A[3] + t * A[4]))));
    let e = 1.0 - poly * exp_nonpositive(-z * z);
    e.copysign(x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;
    use candle_nn::VarMap;

    fn max_diff(a: &Tensor, b: &Tensor) -> f32 {
        (a - b).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap()
    }

    #[test]
    fn linear_matches_candle_with_and_without_bias() {
        let dev = Device::Cpu;
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
        for (i, bias) in [true, false].into_iter().enumerate() {
            let name = format!("l{i}");
            let ours = if bias {
                linear(7, 5, vb.pp(&name)).unwrap()
            } else {
                linear_no_bias(7, 5, vb.pp(&name)).unwrap()
            };
            let Linear::Cpu(op) = &ours else { panic!("the CPU path applies") };
            let candle = op.to_candle(&dev).unwrap();
            for shape in [vec![3, 7], vec![2, 4, 7], vec![1, 1, 2, 7]] {
                let x = crate::testing::randn(0f32, 1.0, shape.as_slice(), &dev).unwrap();
                let (got, want) = (ours.forward(&x).unwrap(), candle.forward(&x).unwrap());
                assert_eq!(got.dims(), want.dims());
                assert!(max_diff(&got, &want) < 1e-5, "bias {bias} {shape:?}");
            }
        }
    }

    #[test]
    fn geglu_matches_candle_and_erf_is_accurate() {
        let dev = Device::Cpu;
        let h = crate::testing::randn(0f32, 2.0, (3, 5, 2 * 37), &dev).unwrap();
        let halves = h.chunk(2, D::Minus1).unwrap();
        let want = (&halves[0] * halves[1].gelu_erf().unwrap()).unwrap();
        let got = geglu(&h).unwrap();
        assert_eq!(got.dims(), &[3, 5, 37]);
        assert!(max_diff(&got, &want) < 1e-5, "{}", max_diff(&got, &want));
        let mut worst = 0.0f64;
        for i in -3000..=3000 {
            let x = i as f32 / 1000.0;
            let want = libm_erf(x as f64);
            worst = worst.max((erf(x) as f64 - want).abs());
        }
        assert!(worst < 1e-6, "erf error {worst}");
        assert!(geglu(&Tensor::zeros((2, 3), DType::F32, &dev).unwrap()).is_err(), "odd width");
    }

    /// erf in f64 by its Taylor series (exact to about 1e-13 for |x| ≤ 3), the test's oracle.
    fn libm_erf(x: f64) -> f64 {
        let (mut term, mut sum) = (x, x);
        for n in 1..200 {
            term *= -x * x / n as f64;
            sum += term / (2 * n + 1) as f64;
        }
        sum * 2.0 / std::f64::consts::PI.sqrt()
    }
}

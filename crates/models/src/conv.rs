//! 2D convolution for the CPU: im2col by rows, then one GEMM per tile of output rows.
//!
//! For input x `[B, C, H, W]` and weight w `[O, C, kh, kw]` (bias b `[O]`), the output is
//! y[n, o, i, j] = b[o] + Σ_{c, u, v} w[o, c, u, v] · x[n, c, s·i + u − p, s·j + v − p]
//! (zero outside the image), `[B, O, H', W']` with H' = (H + 2p − kh) / s + 1. Written as a
//! product, y[n] = W · X_n with W `[O, C·kh·kw]` (the weight tensor's own memory, no
//! reordering) and the im2col matrix X_n `[C·kh·kw, H'·W']`, row (c, u, v) holding
//! x[n, c, s·i + u − p, s·j + v − p] over the output pixels (i, j).
//!
//! Why not candle's `conv2d`: candle 0.9 builds its im2col tile pixel by pixel into a
//! channel-last copy of the input (a gather with a stride of 512 floats per write) and
//! scatters the product back pixel by pixel; on InstructPix2Pix that gather was the
//! largest cost of a UNet step on 2 cores, above the GEMM itself. Here each im2col row is
//! built from contiguous runs of one input row (a copy when s = 1), rows in parallel; the
//! GEMM writes straight into the output `[O, H'·W']` of its batch item, with the bias as
//! its starting value; a 1×1 convolution with s = 1 and p = 0 is the GEMM on the input
//! itself. The im2col matrix is built for as many output rows at a time as fit
//! [`COL_BUDGET`] floats, so a VAE decoder at 512² does not allocate gigabytes. A 3×3
//! convolution with stride 1 over enough pixels goes to [`crate::winograd`] instead.
//!
//! The `gemm` crate is built with its `x86-v4` kernels (AVX-512, chosen at run time where
//! the CPU has it; AVX2 and FMA otherwise); the feature applies to candle's own matrix
//! products as well, since cargo builds one `gemm` for both.
//!
//! [`Conv2d`] uses this on CPU tensors in f32 and candle's own `conv2d` everywhere else
//! (CUDA, other dtypes, groups or dilation), so the two are interchangeable; the tests
//! compare them.

use candle_core::{CpuStorage, CustomOp1, DType, Layout, Module, Shape, Tensor};
use candle_nn::{Conv2dConfig, VarBuilder};
use rayon::prelude::*;

use crate::cpu::{f32_input, gemm_accumulate, Matrix};
use crate::winograd;

/// Most floats of one im2col matrix (64 MiB): tiles of output rows are sized to it.
pub const COL_BUDGET: usize = 16 << 20;

/// A 2D convolution layer loaded like `candle_nn::conv2d` (`weight`, `bias`).
#[derive(Debug)]
pub enum Conv2d {
    /// f32 on the CPU: [`RowConv`].
    Cpu(RowConv),
    /// Anything else: candle's layer.
    Candle(candle_nn::Conv2d),
}

impl Conv2d {
    /// The layer's output channels.
    pub fn out_channels(&self) -> usize {
        match self {
            Conv2d::Cpu(c) => c.out_channels,
            Conv2d::Candle(c) => c.weight().dim(0).unwrap_or(0),
        }
    }
}

/// Loads a `k × k` convolution from `vb` (`weight` `[cout, cin, k, k]`, `bias` `[cout]`),
/// as `candle_nn::conv2d` does.
pub fn conv2d(
    cin: usize,
    cout: usize,
    k: usize,
    cfg: Conv2dConfig,
    vb: VarBuilder,
) -> candle_core::Result<Conv2d> {
    let layer = candle_nn::conv2d(cin, cout, k, cfg, vb)?;
    from_candle(layer, cfg)
}

/// The CPU path for `layer` when it applies (f32 on the CPU, no groups or dilation).
pub fn from_candle(layer: candle_nn::Conv2d, cfg: Conv2dConfig) -> candle_core::Result<Conv2d> {
    let w = layer.weight();
    if !w.device().is_cpu() || w.dtype() != DType::F32 || cfg.groups != 1 || cfg.dilation != 1 {
        return Ok(Conv2d::Candle(layer));
    }
    let (out_channels, in_channels, kh, kw) = w.dims4()?;
    let weight = w.flatten_all()?.to_vec1::<f32>()?;
    let bias = layer.bias().map(|b| b.to_vec1::<f32>()).transpose()?;
    Ok(Conv2d::Cpu(RowConv {
        weight,
        bias,
        out_channels,
        in_channels,
        kernel: (kh, kw),
        stride: cfg.stride,
        padding: cfg.padding,
    }))
}

impl Module for Conv2d {
    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        match self {
            Conv2d::Cpu(c) if x.device().is_cpu() && x.dtype() == DType::F32 => {
                x.contiguous()?.apply_op1_no_bwd(c)
            }
            Conv2d::Cpu(c) => c.to_candle(x.device())?.forward(x),
            Conv2d::Candle(c) => c.forward(x),
        }
    }
}

/// The convolution of the module doc with its weight in plain memory.
#[derive(Clone, Debug)]
pub struct RowConv {
    /// `[O, C·kh·kw]`, the weight tensor's row-major memory.
    weight: Vec<f32>,
    bias: Option<Vec<f32>>,
    out_channels: usize,
    in_channels: usize,
    kernel: (usize, usize),
    stride: usize,
    padding: usize,
}

impl RowConv {
    /// The same layer as a candle layer on `device` (for an input off the CPU).
    fn to_candle(&self, device: &candle_core::Device) -> candle_core::Result<candle_nn::Conv2d> {
        let (kh, kw) = self.kernel;
        let w = Tensor::from_slice(&self.weight, (self.out_channels, self.in_channels, kh, kw), device)?;
        let b = self.bias.as_ref().map(|b| Tensor::from_slice(b, self.out_channels, device)).transpose()?;
        let cfg = Conv2dConfig { padding: self.padding, stride: self.stride, ..Default::default() };
        Ok(candle_nn::Conv2d::new(w, b, cfg))
    }

    /// Output size of an `h × w` input.
    fn out_size(&self, h: usize, w: usize) -> Option<(usize, usize)> {
        let (kh, kw) = self.kernel;
        let (hp, wp) = (h + 2 * self.padding, w + 2 * self.padding);
        if hp < kh || wp < kw || self.stride == 0 {
            return None;
        }
        Some(((hp - kh) / self.stride + 1, (wp - kw) / self.stride + 1))
    }

    /// y = W · X for one batch item: `x` `[C, H, W]`, `y` `[O, H'·W']`; im2col matrices of
    /// at most `budget` floats (at least one output row).
    fn item(
        &self,
        x: &[f32],
        (h, w): (usize, usize),
        y: &mut [f32],
        (oh, ow): (usize, usize),
        budget: usize,
    ) {
        let (kh, kw) = self.kernel;
        let k = self.in_channels * kh * kw;
        let pixels = oh * ow;
        // the bias is the GEMM's starting value
        match &self.bias {
            Some(b) => y.chunks_exact_mut(pixels).zip(b).for_each(|(row, &v)| row.fill(v)),
            None => y.fill(0.0),
        }
        if kh == 1 && kw == 1 && self.stride == 1 && self.padding == 0 {
            gemm_into(y, pixels, 0, pixels, &self.weight, x, self.out_channels, k);
            return;
        }
        let rows = (budget / (k * ow).max(1)).clamp(1, oh);
        let mut col = vec![0.0f32; k * rows * ow];
        for r0 in (0..oh).step_by(rows) {
            let n_rows = rows.min(oh - r0);
            let n = n_rows * ow;
            let col = &mut col[..k * n];
            self.im2col(x, h, w, r0, n_rows, ow, col);
            gemm_into(y, pixels, r0 * ow, n, &self.weight, col, self.out_channels, k);
        }
    }

    /// Rows (c, u, v) of X for output rows `r0..r0 + n_rows` into `col` `[C·kh·kw, n_rows·W']`.
    #[allow(clippy::too_many_arguments)]
    fn im2col(&self, x: &[f32], h: usize, w: usize, r0: usize, n_rows: usize, ow: usize, col: &mut [f32]) {
        let (kh, kw) = self.kernel;
        let (s, p) = (self.stride, self.padding as isize);
        col.par_chunks_mut(n_rows * ow).enumerate().for_each(|(row, out)| {
            let (c, u, v) = (row / (kh * kw), (row / kw) % kh, row % kw);
            let plane = &x[c * h * w..(c + 1) * h * w];
            // output columns j whose input column s·j + v − p lies inside the image
            let first = ((p - v as isize).max(0) as usize).div_ceil(s);
            let last = if (w as isize) + p - (v as isize) <= 0 {
                0
            } else {
                (((w as isize + p - v as isize - 1) as usize) / s + 1).min(ow)
            };
            for (i, dst) in out.chunks_exact_mut(ow).enumerate() {
                let iy = ((r0 + i) * s + u) as isize - p;
                if iy < 0 || iy >= h as isize || first >= last {
                    dst.fill(0.0);
                    continue;
                }
                let src = &plane[iy as usize * w..(iy as usize + 1) * w];
                dst[..first].fill(0.0);
                dst[last..].fill(0.0);
                let x0 = (first * s) as isize + v as isize - p;
                if s == 1 {
                    dst[first..last].copy_from_slice(&src[x0 as usize..x0 as usize + (last - first)]);
                } else {
                    for (j, d) in dst[first..last].iter_mut().enumerate() {
                        *d = src[x0 as usize + j * s];
                    }
                }
            }
        });
    }
}

/// y[:, offset..offset + n] += W · X: W `[m, k]` and X `[k, n]` row-major, y rows of
/// `y_stride` floats (the GEMM of the module doc).
#[allow(clippy::too_many_arguments)]
fn gemm_into(
    y: &mut [f32],
    y_stride: usize,
    offset: usize,
    n: usize,
    w: &[f32],
    x: &[f32],
    m: usize,
    k: usize,
) {
    let lhs = Matrix { data: w, rows: k, cols: 1 };
    let rhs = Matrix { data: x, rows: n, cols: 1 };
    gemm_accumulate(y, offset, y_stride, lhs, rhs, (m, n, k));
}

impl CustomOp1 for RowConv {
    fn name(&self) -> &'static str {
        "row-conv2d"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let x = f32_input(storage, layout, "row-conv2d")?;
        let (b, c, h, w) = layout.shape().dims4()?;
        if c != self.in_channels {
            candle_core::bail!("row-conv2d: input has {c} channels, the weight {}", self.in_channels);
        }
        let Some((oh, ow)) = self.out_size(h, w) else {
            candle_core::bail!("row-conv2d: a {h}x{w} input is smaller than the {:?} kernel", self.kernel)
        };
        let per_out = self.out_channels * oh * ow;
        let mut y = vec![0.0f32; b * per_out];
        let (th, tw) = winograd::tiles((oh, ow));
        if self.kernel == (3, 3) && self.stride == 1 && b * th * tw >= winograd::MIN_TILES {
            let layer = winograd::Layer {
                weight: &self.weight,
                bias: self.bias.as_deref(),
                out_channels: self.out_channels,
                in_channels: self.in_channels,
                padding: self.padding,
            };
            winograd::conv3x3(&layer, x, b, (h, w), &mut y, layer.chunk());
        } else {
            for (xb, yb) in x.chunks_exact(c * h * w).zip(y.chunks_exact_mut(per_out)) {
                self.item(xb, (h, w), yb, (oh, ow), COL_BUDGET);
            }
        }
        Ok((CpuStorage::F32(y), Shape::from((b, self.out_channels, oh, ow))))
    }
}

/// A transposed convolution whose kernel equals its stride (`k`): every input pixel
/// becomes its own `k × k` block of outputs, y[o, k·i + u, k·j + v] = b[o] +
/// Σ_c x[c, i, j] · w[c, o, u, v]. Computed as one matrix product per batch, the
/// pixels `[h·w, cin]` times the weight `[cin, cout·k·k]`, then the blocks laid out.
/// (CLIPSeg's decoder, SAM's mask upscaling.)
#[derive(Debug, Clone)]
pub struct PatchTransposedConv {
    /// `[cin, cout·k·k]` (the weight's own memory, `[cin, cout, k, k]`).
    weight: Tensor,
    bias: Tensor,
    out_channels: usize,
    kernel: usize,
}

impl PatchTransposedConv {
    pub fn new(vb: VarBuilder, cin: usize, cout: usize, kernel: usize) -> candle_core::Result<Self> {
        let weight = vb.get((cin, cout, kernel, kernel), "weight")?.reshape((cin, cout * kernel * kernel))?;
        Ok(Self { weight, bias: vb.get(cout, "bias")?, out_channels: cout, kernel })
    }

    pub fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let (b, cin, h, w) = x.dims4()?;
        let (cout, k) = (self.out_channels, self.kernel);
        let pixels = x.permute((0, 2, 3, 1))?.reshape((b * h * w, cin))?;
        let blocks = pixels.matmul(&self.weight)?; // [b·h·w, cout·k·k]
        blocks
            .reshape((b, h, w, cout, k, k))?
            .permute((0, 3, 1, 4, 2, 5))?
            .reshape((b, cout, h * k, w * k))?
            .broadcast_add(&self.bias.reshape((1, cout, 1, 1))?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;
    use candle_nn::VarMap;

    #[test]
    fn patch_transposed_convolution_matches_candle() {
        let device = Device::Cpu;
        let (cin, cout, k) = (3, 2, 4);
        let weight = Tensor::arange(0f32, (cin * cout * k * k) as f32, &device)
            .unwrap()
            .sin()
            .unwrap()
            .reshape((cin, cout, k, k))
            .unwrap();
        let bias = Tensor::new(&[0.5f32, -0.25], &device).unwrap();
        let x = Tensor::arange(0f32, (2 * cin * 3 * 5) as f32, &device)
            .unwrap()
            .cos()
            .unwrap()
            .reshape((2, cin, 3, 5))
            .unwrap();
        let vb = VarBuilder::from_tensors(
            [("weight".to_string(), weight.clone()), ("bias".to_string(), bias.clone())].into(),
            DType::F32,
            &device,
        );
        let got = PatchTransposedConv::new(vb, cin, cout, k).unwrap().forward(&x).unwrap();
        let want = x
            .conv_transpose2d(&weight, 0, 0, k, 1)
            .unwrap()
            .broadcast_add(&bias.reshape((1, cout, 1, 1)).unwrap())
            .unwrap();
        assert_eq!(got.dims(), [2, cout, 3 * k, 5 * k]);
        let err = (got - want).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
        assert!(err < 1e-5, "{err}");
    }

    /// Every case against candle's own `conv2d` (its direct and tiled paths are the
    /// oracle), including strides, padding, 1×1, odd sizes and inputs large enough for the
    /// Winograd path.
    #[test]
    fn matches_candle_conv2d() {
        let dev = Device::Cpu;
        // (cin, cout, k, stride, padding, h, w, batch, bias)
        let cases = [
            (3, 5, 3, 1, 1, 7, 9, 2, true),
            (4, 6, 3, 2, 1, 9, 8, 1, true),
            (4, 6, 3, 2, 0, 9, 9, 1, false),
            (8, 3, 1, 1, 0, 5, 6, 3, true),
            (5, 4, 1, 2, 0, 7, 7, 1, true),
            (2, 3, 3, 1, 0, 3, 3, 1, true),
            (2, 2, 5, 1, 2, 4, 6, 1, true),
            (3, 2, 3, 3, 2, 10, 11, 2, true),
            // too few tiles for Winograd: the im2col path with padding
            (3, 5, 3, 1, 1, 5, 6, 1, true),
            // enough tiles for Winograd's F(2×2, 3×3) (crate::winograd)
            (3, 5, 3, 1, 1, 16, 13, 2, true),
            (4, 4, 3, 1, 0, 18, 18, 1, false),
        ];
        for (i, &(cin, cout, k, stride, padding, h, w, b, bias)) in cases.iter().enumerate() {
            let varmap = VarMap::new();
            let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
            let cfg = Conv2dConfig { padding, stride, ..Default::default() };
            let layer = if bias {
                candle_nn::conv2d(cin, cout, k, cfg, vb.pp(format!("c{i}"))).unwrap()
            } else {
                candle_nn::conv2d_no_bias(cin, cout, k, cfg, vb.pp(format!("c{i}"))).unwrap()
            };
            if let Some(bias) = layer.bias() {
                // candle initialises the bias uniformly; make it clearly nonzero
                varmap
                    .data()
                    .lock()
                    .unwrap()
                    .get(&format!("c{i}.bias"))
                    .unwrap()
                    .set(&(bias + 0.5).unwrap())
                    .unwrap();
            }
            let x = crate::testing::randn(0f32, 1.0, (b, cin, h, w), &dev).unwrap();
            let want = layer.forward(&x).unwrap();
            let ours = from_candle(layer.clone(), cfg).unwrap();
            assert!(matches!(ours, Conv2d::Cpu(_)), "case {i}: the CPU path applies");
            let got = ours.forward(&x).unwrap();
            assert_eq!(got.dims(), want.dims(), "case {i}");
            let diff = (got - &want).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
            let scale = want.abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
            assert!(diff <= 1e-5 * scale.max(1.0), "case {i}: max difference {diff} (scale {scale})");
        }
    }

    /// A budget of one row per tile gives the same output as one tile.
    #[test]
    fn row_tiles_do_not_change_the_result() {
        let dev = Device::Cpu;
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
        let cfg = Conv2dConfig { padding: 1, stride: 2, ..Default::default() };
        let Conv2d::Cpu(conv) = conv2d(3, 4, 3, cfg, vb).unwrap() else { panic!("the CPU path") };
        let x: Vec<f32> = (0..3 * 9 * 7).map(|i| ((i * 37 % 11) as f32 - 5.0) / 3.0).collect();
        let out = conv.out_size(9, 7).unwrap();
        assert_eq!(out, (5, 4));
        let mut whole = vec![0.0; 4 * 5 * 4];
        let mut tiled = whole.clone();
        conv.item(&x, (9, 7), &mut whole, out, usize::MAX);
        conv.item(&x, (9, 7), &mut tiled, out, 1);
        assert_eq!(whole, tiled);
        assert!(whole.iter().any(|&v| v != 0.0));
    }

    #[test]
    fn a_transposed_input_is_made_contiguous_first() {
        let dev = Device::Cpu;
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
        let cfg = Conv2dConfig { padding: 1, ..Default::default() };
        let layer = candle_nn::conv2d(3, 4, 3, cfg, vb).unwrap();
        let x = crate::testing::randn(0f32, 1.0, (1, 3, 6, 5), &dev).unwrap().transpose(2, 3).unwrap();
        let want = layer.forward(&x).unwrap();
        let got = from_candle(layer, cfg).unwrap().forward(&x).unwrap();
        let diff = (got - want).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
        assert!(diff < 1e-5, "{diff}");
    }
}

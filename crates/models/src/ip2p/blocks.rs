//! The convolutional blocks of the UNet and the auto-encoder, as diffusers defines them
//! (`ResnetBlock2D`, `Downsample2D`, `Upsample2D`, the VAE's single-head `Attention`,
//! `UNetMidBlock2D`, `DownEncoderBlock2D`, `UpDecoderBlock2D`), over this crate's
//! convolution ([`crate::conv`]): most of an InstructPix2Pix step is in these
//! convolutions.
//!
//! Names follow diffusers' state dict (`norm1`, `conv1`, `time_emb_proj`, …); the VAE
//! attention reads both the current `to_q/to_k/to_v/to_out.0` and the older
//! `query/key/value/proj_attn` names.

use candle_core::{Module, Tensor, D};
use candle_nn::{self as nn, Conv2dConfig, VarBuilder};

use crate::conv::{conv2d, Conv2d};
use crate::linear::{linear, Linear};
use crate::norm::{group_norm, GroupNorm};

/// diffusers `ResnetBlock2D`: with h = conv1(silu(norm1(x))) (+ time_emb_proj(silu(t))
/// per channel), the output is (shortcut(x) + conv2(silu(norm2(h)))) / output_scale,
/// shortcut a 1×1 convolution when the channel count changes.
#[derive(Debug)]
pub struct ResnetBlock {
    norm1: GroupNorm,
    conv1: Conv2d,
    time_emb_proj: Option<Linear>,
    norm2: GroupNorm,
    conv2: Conv2d,
    conv_shortcut: Option<Conv2d>,
    output_scale: f64,
}

/// What a [`ResnetBlock`] is built from besides its channels.
#[derive(Clone, Copy, Debug)]
pub struct ResnetConfig {
    /// Channels of the time embedding (`None`: the block takes none, as in the VAE).
    pub temb_channels: Option<usize>,
    pub groups: usize,
    pub eps: f64,
    pub output_scale: f64,
}

impl ResnetBlock {
    pub fn new(vb: VarBuilder, cin: usize, cout: usize, cfg: ResnetConfig) -> candle_core::Result<Self> {
        let conv3 = Conv2dConfig { padding: 1, ..Default::default() };
        let norm1 = group_norm(cfg.groups, cin, cfg.eps, vb.pp("norm1"))?;
        let conv1 = conv2d(cin, cout, 3, conv3, vb.pp("conv1"))?;
        let time_emb_proj = cfg.temb_channels.map(|t| linear(t, cout, vb.pp("time_emb_proj"))).transpose()?;
        let norm2 = group_norm(cfg.groups, cout, cfg.eps, vb.pp("norm2"))?;
        let conv2 = conv2d(cout, cout, 3, conv3, vb.pp("conv2"))?;
        let conv_shortcut = (cin != cout)
            .then(|| conv2d(cin, cout, 1, Default::default(), vb.pp("conv_shortcut")))
            .transpose()?;
        Ok(ResnetBlock {
            norm1,
            conv1,
            time_emb_proj,
            norm2,
            conv2,
            conv_shortcut,
            output_scale: cfg.output_scale,
        })
    }

    /// `x` `[B, C, H, W]`, `temb` `[B, T]` when the block has a time projection.
    pub fn forward(&self, x: &Tensor, temb: Option<&Tensor>) -> candle_core::Result<Tensor> {
        let mut h = self.conv1.forward(&self.norm1.forward_silu(x)?)?;
        if let (Some(proj), Some(t)) = (&self.time_emb_proj, temb) {
            let t = proj.forward(&nn::ops::silu(t)?)?.unsqueeze(D::Minus1)?.unsqueeze(D::Minus1)?;
            h = h.broadcast_add(&t)?;
        }
        let h = self.conv2.forward(&self.norm2.forward_silu(&h)?)?;
        let shortcut = match &self.conv_shortcut {
            Some(c) => c.forward(x)?,
            None => x.clone(),
        };
        let out = (shortcut + h)?;
        if self.output_scale == 1.0 {
            Ok(out)
        } else {
            out / self.output_scale
        }
    }
}

/// diffusers `Downsample2D` with a convolution: a 3×3 stride-2 convolution with padding
/// `padding`; with padding 0 the input is first padded by one zero row and column at the
/// bottom and right (as diffusers does).
#[derive(Debug)]
pub struct Downsample {
    conv: Conv2d,
    padding: usize,
}

impl Downsample {
    pub fn new(vb: VarBuilder, channels: usize, padding: usize) -> candle_core::Result<Self> {
        let cfg = Conv2dConfig { padding, stride: 2, ..Default::default() };
        Ok(Downsample { conv: conv2d(channels, channels, 3, cfg, vb.pp("conv"))?, padding })
    }

    pub fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        if self.padding == 0 {
            let x = x.pad_with_zeros(D::Minus1, 0, 1)?.pad_with_zeros(D::Minus2, 0, 1)?;
            self.conv.forward(&x)
        } else {
            self.conv.forward(x)
        }
    }
}

/// diffusers `Upsample2D` with a convolution: nearest-neighbour ×2, then a 3×3 convolution.
#[derive(Debug)]
pub struct Upsample {
    conv: Conv2d,
}

impl Upsample {
    pub fn new(vb: VarBuilder, channels: usize) -> candle_core::Result<Self> {
        let cfg = Conv2dConfig { padding: 1, ..Default::default() };
        Ok(Upsample { conv: conv2d(channels, channels, 3, cfg, vb.pp("conv"))? })
    }

    pub fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let (_, _, h, w) = x.dims4()?;
        self.conv.forward(&x.upsample_nearest2d(2 * h, 2 * w)?)
    }
}

/// The VAE's attention (diffusers `Attention` with one head, a group norm, a residual and
/// rescale 1): tokens t = norm(x) over the pixels, x + out(softmax(q kᵀ / √C) v).
#[derive(Debug)]
pub struct VaeAttention {
    group_norm: GroupNorm,
    to_q: Linear,
    to_k: Linear,
    to_v: Linear,
    to_out: Linear,
    channels: usize,
}

impl VaeAttention {
    pub fn new(vb: VarBuilder, channels: usize, groups: usize, eps: f64) -> candle_core::Result<Self> {
        let group_norm = group_norm(groups, channels, eps, vb.pp("group_norm"))?;
        let linear = |name: &str| linear(channels, channels, vb.pp(name));
        let (to_q, to_k, to_v, to_out) = if vb.contains_tensor("to_q.weight") {
            (linear("to_q")?, linear("to_k")?, linear("to_v")?, linear("to_out.0")?)
        } else {
            (linear("query")?, linear("key")?, linear("value")?, linear("proj_attn")?)
        };
        Ok(VaeAttention { group_norm, to_q, to_k, to_v, to_out, channels })
    }

    pub fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let (b, c, h, w) = x.dims4()?;
        let t = self.group_norm.forward(x)?.reshape((b, c, h * w))?.transpose(1, 2)?.contiguous()?;
        let (q, k, v) = (self.to_q.forward(&t)?, self.to_k.forward(&t)?, self.to_v.forward(&t)?);
        let scale = 1.0 / (self.channels as f64).sqrt();
        let o = self.to_out.forward(&crate::attention::multi_head_attention(&q, &k, &v, 1, scale)?)?;
        o.transpose(1, 2)?.reshape((b, c, h, w))? + x
    }
}

/// diffusers `UNetMidBlock2D` as the VAE uses it: resnet, attention, resnet.
#[derive(Debug)]
pub struct VaeMidBlock {
    first: ResnetBlock,
    attention: VaeAttention,
    second: ResnetBlock,
}

impl VaeMidBlock {
    pub fn new(vb: VarBuilder, channels: usize, cfg: ResnetConfig) -> candle_core::Result<Self> {
        let r = vb.pp("resnets");
        Ok(VaeMidBlock {
            first: ResnetBlock::new(r.pp(0), channels, channels, cfg)?,
            attention: VaeAttention::new(vb.pp("attentions").pp(0), channels, cfg.groups, cfg.eps)?,
            second: ResnetBlock::new(r.pp(1), channels, channels, cfg)?,
        })
    }

    pub fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let h = self.first.forward(x, None)?;
        let h = self.attention.forward(&h)?;
        self.second.forward(&h, None)
    }
}

/// diffusers `DownEncoderBlock2D` ([`VaeBlock::down`]: resnets, then a [`Downsample`] with
/// padding 0 unless last) and `UpDecoderBlock2D` ([`VaeBlock::up`]: resnets, then an
/// [`Upsample`] unless last).
#[derive(Debug)]
pub struct VaeBlock {
    resnets: Vec<ResnetBlock>,
    resample: Option<Resample>,
}

/// What follows a [`VaeBlock`]'s resnets.
#[derive(Debug)]
enum Resample {
    Down(Downsample),
    Up(Upsample),
}

impl VaeBlock {
    /// `layers` resnets from `cin` to `cout` channels (`resnets.{i}`).
    fn resnets(
        vb: &VarBuilder,
        (cin, cout): (usize, usize),
        layers: usize,
        cfg: ResnetConfig,
    ) -> candle_core::Result<Vec<ResnetBlock>> {
        (0..layers)
            .map(|i| ResnetBlock::new(vb.pp("resnets").pp(i), if i == 0 { cin } else { cout }, cout, cfg))
            .collect()
    }

    /// An encoder block; `downsample` unless it is the last.
    pub fn down(
        vb: VarBuilder,
        channels: (usize, usize),
        layers: usize,
        downsample: bool,
        cfg: ResnetConfig,
    ) -> candle_core::Result<Self> {
        let resnets = Self::resnets(&vb, channels, layers, cfg)?;
        let resample = downsample
            .then(|| Downsample::new(vb.pp("downsamplers").pp(0), channels.1, 0).map(Resample::Down))
            .transpose()?;
        Ok(VaeBlock { resnets, resample })
    }

    /// A decoder block; `upsample` unless it is the last.
    pub fn up(
        vb: VarBuilder,
        channels: (usize, usize),
        layers: usize,
        upsample: bool,
        cfg: ResnetConfig,
    ) -> candle_core::Result<Self> {
        let resnets = Self::resnets(&vb, channels, layers, cfg)?;
        let resample = upsample
            .then(|| Upsample::new(vb.pp("upsamplers").pp(0), channels.1).map(Resample::Up))
            .transpose()?;
        Ok(VaeBlock { resnets, resample })
    }

    pub fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let mut h = x.clone();
        for r in &self.resnets {
            h = r.forward(&h, None)?;
        }
        match &self.resample {
            Some(Resample::Down(d)) => d.forward(&h),
            Some(Resample::Up(u)) => u.forward(&h),
            None => Ok(h),
        }
    }
}

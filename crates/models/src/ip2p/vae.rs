//! The Stable Diffusion auto-encoder (diffusers `AutoencoderKL`), built from a diffusers
//! `vae/config.json`, from the blocks of [`super::blocks`]; the encoder and decoder are
//! wired here so that the posterior's mode (its mean) is available, which
//! InstructPix2Pix uses as the image-conditioning latent.

use candle_core::{Module, Tensor};
use candle_nn::{Conv2dConfig, VarBuilder};

use super::blocks::{ResnetConfig, VaeBlock, VaeMidBlock};
use crate::conv::{conv2d, Conv2d};
use crate::norm::{group_norm, GroupNorm};
use serde::Deserialize;

use super::unet::MAX_BLOCKS;
use crate::check::{self, ModelConfig};

fn three() -> usize {
    3
}
fn four() -> usize {
    4
}
fn groups() -> usize {
    32
}
fn f_true() -> bool {
    true
}
fn sd_scale() -> f64 {
    0.18215
}

/// The fields of a diffusers `AutoencoderKL` config that this implementation reads.
#[derive(Debug, Clone, Deserialize)]
pub struct VaeConfig {
    #[serde(default = "three")]
    pub in_channels: usize,
    #[serde(default = "three")]
    pub out_channels: usize,
    pub block_out_channels: Vec<usize>,
    pub layers_per_block: usize,
    #[serde(default = "four")]
    pub latent_channels: usize,
    #[serde(default = "groups")]
    pub norm_num_groups: usize,
    /// Latents are multiplied by this before diffusion (0.18215 for SD 1.x).
    #[serde(default = "sd_scale")]
    pub scaling_factor: f64,
    #[serde(default = "f_true")]
    pub use_quant_conv: bool,
    #[serde(default = "f_true")]
    pub use_post_quant_conv: bool,
    #[serde(default = "f_true")]
    pub mid_block_add_attention: bool,
    #[serde(default)]
    pub shift_factor: Option<f64>,
}

impl ModelConfig for VaeConfig {
    /// Errors naming the first field that cannot describe an auto-encoder or that this
    /// implementation does not support.
    fn check(&self) -> Result<(), String> {
        let n = self.block_out_channels.len();
        if n == 0 || n > MAX_BLOCKS {
            return Err(format!("block_out_channels must list 1 to {MAX_BLOCKS} resolutions, not {n}"));
        }
        check::size("in_channels", self.in_channels)?;
        check::size("out_channels", self.out_channels)?;
        check::size("latent_channels", self.latent_channels)?;
        check::layers("layers_per_block", self.layers_per_block)?;
        check::positive("scaling_factor", self.scaling_factor)?;
        for (i, &c) in self.block_out_channels.iter().enumerate() {
            let channels = format!("block_out_channels[{i}]");
            check::size(&channels, c)?;
            check::divides(&channels, c, "norm_num_groups", self.norm_num_groups)?;
        }
        if !self.mid_block_add_attention {
            return Err("mid_block_add_attention = false is not supported".into());
        }
        if self.shift_factor.is_some_and(|s| s != 0.0) {
            return Err("shift_factor is not supported (SD 1.x VAEs have none)".into());
        }
        Ok(())
    }
}

impl VaeConfig {
    /// Image pixels per latent pixel along each axis (8 for SD).
    pub fn downscale(&self) -> usize {
        1 << (self.block_out_channels.len() - 1)
    }
}

/// diffusers `AutoencoderKL`.
#[derive(Debug)]
pub struct Vae {
    pub config: VaeConfig,
    enc_conv_in: Conv2d,
    enc_down: Vec<VaeBlock>,
    enc_mid: VaeMidBlock,
    enc_norm_out: GroupNorm,
    enc_conv_out: Conv2d,
    quant_conv: Option<Conv2d>,
    post_quant_conv: Option<Conv2d>,
    dec_conv_in: Conv2d,
    dec_mid: VaeMidBlock,
    dec_up: Vec<VaeBlock>,
    dec_norm_out: GroupNorm,
    dec_conv_out: Conv2d,
}

fn conv3(vb: VarBuilder, cin: usize, cout: usize) -> candle_core::Result<Conv2d> {
    conv2d(cin, cout, 3, Conv2dConfig { padding: 1, ..Default::default() }, vb)
}

impl Vae {
    /// Builds the auto-encoder from `config` and the weights in `vb` (diffusers names).
    pub fn new(vb: VarBuilder, config: VaeConfig) -> candle_core::Result<Self> {
        config.check().map_err(candle_core::Error::Msg)?;
        let c = &config;
        let chans = &c.block_out_channels;
        let n = chans.len();
        let last = chans[n - 1];
        let rc =
            ResnetConfig { temb_channels: None, groups: c.norm_num_groups, eps: 1e-6, output_scale: 1.0 };

        let enc = vb.pp("encoder");
        let enc_conv_in = conv3(enc.pp("conv_in"), c.in_channels, chans[0])?;
        let mut enc_down = Vec::with_capacity(n);
        for i in 0..n {
            let cin = if i == 0 { chans[0] } else { chans[i - 1] };
            let vb = enc.pp("down_blocks").pp(i);
            enc_down.push(VaeBlock::down(vb, (cin, chans[i]), c.layers_per_block, i + 1 < n, rc)?);
        }
        let enc_mid = VaeMidBlock::new(enc.pp("mid_block"), last, rc)?;
        let enc_norm_out = group_norm(c.norm_num_groups, last, 1e-6, enc.pp("conv_norm_out"))?;
        let enc_conv_out = conv3(enc.pp("conv_out"), last, 2 * c.latent_channels)?;
        let l2 = 2 * c.latent_channels;
        let quant_conv = if c.use_quant_conv {
            Some(conv2d(l2, l2, 1, Default::default(), vb.pp("quant_conv"))?)
        } else {
            None
        };
        let lc = c.latent_channels;
        let post_quant_conv = if c.use_post_quant_conv {
            Some(conv2d(lc, lc, 1, Default::default(), vb.pp("post_quant_conv"))?)
        } else {
            None
        };

        let dec = vb.pp("decoder");
        let dec_conv_in = conv3(dec.pp("conv_in"), lc, last)?;
        let dec_mid = VaeMidBlock::new(dec.pp("mid_block"), last, rc)?;
        let rev: Vec<usize> = chans.iter().rev().copied().collect();
        let mut dec_up = Vec::with_capacity(n);
        for i in 0..n {
            let cin = if i == 0 { rev[0] } else { rev[i - 1] };
            let vb = dec.pp("up_blocks").pp(i);
            dec_up.push(VaeBlock::up(vb, (cin, rev[i]), c.layers_per_block + 1, i + 1 < n, rc)?);
        }
        let dec_norm_out = group_norm(c.norm_num_groups, chans[0], 1e-6, dec.pp("conv_norm_out"))?;
        let dec_conv_out = conv3(dec.pp("conv_out"), chans[0], c.out_channels)?;
        Ok(Self {
            config,
            enc_conv_in,
            enc_down,
            enc_mid,
            enc_norm_out,
            enc_conv_out,
            quant_conv,
            post_quant_conv,
            dec_conv_in,
            dec_mid,
            dec_up,
            dec_norm_out,
            dec_conv_out,
        })
    }

    /// Mode (mean) of the latent posterior of `x` (`B × 3 × H × W` in [-1, 1]), unscaled.
    pub fn encode_mode(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let mut h = self.enc_conv_in.forward(x)?;
        for block in &self.enc_down {
            h = block.forward(&h)?;
        }
        h = self.enc_mid.forward(&h)?;
        h = self.enc_conv_out.forward(&self.enc_norm_out.forward_silu(&h)?)?;
        if let Some(q) = &self.quant_conv {
            h = q.forward(&h)?;
        }
        h.narrow(1, 0, self.config.latent_channels)
    }

    /// Decodes unscaled latents `z` (`B × latent_channels × h × w`) to images in about [-1, 1].
    pub fn decode(&self, z: &Tensor) -> candle_core::Result<Tensor> {
        let z = match &self.post_quant_conv {
            Some(p) => p.forward(z)?,
            None => z.clone(),
        };
        let mut h = self.dec_mid.forward(&self.dec_conv_in.forward(&z)?)?;
        for block in &self.dec_up {
            h = block.forward(&h)?;
        }
        self.dec_conv_out.forward(&self.dec_norm_out.forward_silu(&h)?)
    }
}

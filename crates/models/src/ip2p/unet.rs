//! The conditional UNet of Stable Diffusion (diffusers `UNet2DConditionModel`), built
//! from a diffusers `unet/config.json` — InstructPix2Pix's has 8 input channels (the
//! noisy latent and the image-conditioning latent, concatenated).
//!
//! ResNet blocks and the timestep embedding are candle-transformers' (they match
//! diffusers); the transformer blocks, down/up blocks and the wiring are written here
//! because candle's feed-forward uses the tanh approximation of GELU where diffusers
//! uses the exact (erf) one, and because block types, head counts and transformer
//! depths are read per block from the config.

use candle_core::{Module, Tensor};
use candle_nn::{self as nn, Conv2dConfig, VarBuilder};

use super::blocks::{ResnetBlock, ResnetConfig};
use crate::conv::{conv2d, Conv2d};
use crate::linear::{linear, linear_no_bias, Linear};
use crate::norm::{group_norm, GroupNorm};
use candle_transformers::models::stable_diffusion::embeddings::{TimestepEmbedding, Timesteps};
use serde::Deserialize;

use crate::check::{self, ModelConfig};

/// A config value diffusers writes either once for all blocks or once per block.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub enum PerBlock {
    One(usize),
    Each(Vec<usize>),
}

impl PerBlock {
    fn get(&self, i: usize) -> usize {
        match self {
            PerBlock::One(v) => *v,
            // `check` guarantees one entry per block.
            PerBlock::Each(v) => v[i],
        }
    }

    fn fits(&self, n: usize) -> bool {
        match self {
            PerBlock::One(_) => true,
            PerBlock::Each(v) => v.len() == n,
        }
    }
}

fn one() -> PerBlock {
    PerBlock::One(1)
}
fn f_true() -> bool {
    true
}
fn eps_default() -> f64 {
    1e-5
}
fn groups_default() -> usize {
    32
}
fn one_f() -> f64 {
    1.0
}

/// The fields of a diffusers `UNet2DConditionModel` config that this implementation reads.
#[derive(Debug, Clone, Deserialize)]
pub struct UNetConfig {
    pub in_channels: usize,
    pub out_channels: usize,
    pub block_out_channels: Vec<usize>,
    pub down_block_types: Vec<String>,
    pub up_block_types: Vec<String>,
    #[serde(default)]
    pub mid_block_type: Option<String>,
    pub layers_per_block: PerBlock,
    pub attention_head_dim: PerBlock,
    #[serde(default)]
    pub num_attention_heads: Option<PerBlock>,
    pub cross_attention_dim: usize,
    #[serde(default = "groups_default")]
    pub norm_num_groups: usize,
    #[serde(default = "eps_default")]
    pub norm_eps: f64,
    #[serde(default)]
    pub use_linear_projection: bool,
    #[serde(default = "f_true")]
    pub flip_sin_to_cos: bool,
    #[serde(default)]
    pub freq_shift: f64,
    #[serde(default = "one_usize")]
    pub downsample_padding: usize,
    #[serde(default = "one_f")]
    pub mid_block_scale_factor: f64,
    #[serde(default = "one")]
    pub transformer_layers_per_block: PerBlock,
    #[serde(default)]
    pub center_input_sample: bool,
    #[serde(default)]
    pub only_cross_attention: serde_json::Value,
    #[serde(default)]
    pub dual_cross_attention: bool,
    #[serde(default)]
    pub class_embed_type: Option<String>,
    #[serde(default)]
    pub addition_embed_type: Option<String>,
    #[serde(default)]
    pub time_embedding_type: Option<String>,
    #[serde(default)]
    pub resnet_time_scale_shift: Option<String>,
}

fn one_usize() -> usize {
    1
}

/// Most resolutions (blocks) a UNet or VAE config may list; SD has 4.
pub(crate) const MAX_BLOCKS: usize = 16;

impl ModelConfig for UNetConfig {
    /// Errors naming the first field that cannot describe a UNet or that this
    /// implementation does not support.
    fn check(&self) -> Result<(), String> {
        let n = self.block_out_channels.len();
        if n == 0 || n > MAX_BLOCKS || self.down_block_types.len() != n || self.up_block_types.len() != n {
            return Err(format!(
                "block_out_channels, down_block_types and up_block_types must have one \
                 entry per resolution (1 to {MAX_BLOCKS})"
            ));
        }
        check::size("in_channels", self.in_channels)?;
        check::size("out_channels", self.out_channels)?;
        check::size("cross_attention_dim", self.cross_attention_dim)?;
        check::positive("norm_eps", self.norm_eps)?;
        check::positive("mid_block_scale_factor", self.mid_block_scale_factor)?;
        if !self.freq_shift.is_finite() {
            return Err(format!("freq_shift is {}: must be finite", self.freq_shift));
        }
        if self.downsample_padding > 1 {
            return Err(format!("downsample_padding is {}: must be 0 or 1", self.downsample_padding));
        }
        let lists = [
            ("layers_per_block", Some(&self.layers_per_block)),
            ("attention_head_dim", Some(&self.attention_head_dim)),
            ("num_attention_heads", self.num_attention_heads.as_ref()),
            ("transformer_layers_per_block", Some(&self.transformer_layers_per_block)),
        ];
        for (name, list) in lists {
            if list.is_some_and(|l| !l.fits(n)) {
                return Err(format!("{name} must be one number or one per resolution ({n})"));
            }
        }
        for t in self.down_block_types.iter() {
            if t != "CrossAttnDownBlock2D" && t != "DownBlock2D" {
                return Err(format!("unsupported down block type {t}"));
            }
        }
        for t in self.up_block_types.iter() {
            if t != "CrossAttnUpBlock2D" && t != "UpBlock2D" {
                return Err(format!("unsupported up block type {t}"));
            }
        }
        if let Some(m) = &self.mid_block_type {
            if m != "UNetMidBlock2DCrossAttn" {
                return Err(format!("unsupported mid block type {m}"));
            }
        }
        let only_cross = match &self.only_cross_attention {
            serde_json::Value::Bool(b) => *b,
            serde_json::Value::Array(a) => a.iter().any(|v| v.as_bool() == Some(true)),
            _ => false,
        };
        if only_cross || self.dual_cross_attention {
            return Err("only_cross_attention / dual_cross_attention are not supported".into());
        }
        if self.class_embed_type.is_some() || self.addition_embed_type.is_some() {
            return Err("class or additional embeddings (SDXL-style) are not supported".into());
        }
        if self.time_embedding_type.as_deref().is_some_and(|t| t != "positional") {
            return Err("only positional time embeddings are supported".into());
        }
        if self.resnet_time_scale_shift.as_deref().is_some_and(|t| t != "default") {
            return Err("only resnet_time_scale_shift \"default\" is supported".into());
        }
        for (i, &c) in self.block_out_channels.iter().enumerate() {
            let channels = format!("block_out_channels[{i}]");
            check::size(&channels, c)?;
            check::divides(&channels, c, "norm_num_groups", self.norm_num_groups)?;
            check::divides(&channels, c, &format!("attention heads of block {i}"), self.heads(i))?;
            check::layers(&format!("layers_per_block of block {i}"), self.layers_per_block.get(i))?;
            check::layers(
                &format!("transformer_layers_per_block of block {i}"),
                self.transformer_layers_per_block.get(i),
            )?;
        }
        Ok(())
    }
}

impl UNetConfig {
    /// Attention heads of block `i`: diffusers reads the (misnamed) `attention_head_dim`
    /// as the number of heads when `num_attention_heads` is absent.
    fn heads(&self, i: usize) -> usize {
        self.num_attention_heads.as_ref().unwrap_or(&self.attention_head_dim).get(i)
    }
}

/// Multi-head attention with diffusers' weight names (`to_q`, `to_k`, `to_v`, `to_out.0`).
#[derive(Debug)]
struct Attention {
    to_q: Linear,
    to_k: Linear,
    to_v: Linear,
    to_out: Linear,
    heads: usize,
    scale: f64,
}

impl Attention {
    fn new(vb: VarBuilder, dim: usize, context_dim: usize, heads: usize) -> candle_core::Result<Self> {
        let d_head = dim / heads;
        Ok(Self {
            to_q: linear_no_bias(dim, dim, vb.pp("to_q"))?,
            to_k: linear_no_bias(context_dim, dim, vb.pp("to_k"))?,
            to_v: linear_no_bias(context_dim, dim, vb.pp("to_v"))?,
            to_out: linear(dim, dim, vb.pp("to_out.0"))?,
            heads,
            scale: 1.0 / (d_head as f64).sqrt(),
        })
    }

    fn forward(&self, x: &Tensor, context: Option<&Tensor>) -> candle_core::Result<Tensor> {
        let ctx = context.unwrap_or(x);
        let (q, k, v) = (self.to_q.forward(x)?, self.to_k.forward(ctx)?, self.to_v.forward(ctx)?);
        self.to_out.forward(&crate::attention::multi_head_attention(&q, &k, &v, self.heads, self.scale)?)
    }
}

/// GEGLU feed-forward: `proj` to twice the inner width, value × GELU(gate), back.
#[derive(Debug)]
struct FeedForward {
    proj_in: Linear,
    proj_out: Linear,
}

impl FeedForward {
    fn new(vb: VarBuilder, dim: usize) -> candle_core::Result<Self> {
        let inner = 4 * dim;
        Ok(Self {
            proj_in: linear(dim, 2 * inner, vb.pp("net.0.proj"))?,
            proj_out: linear(inner, dim, vb.pp("net.2"))?,
        })
    }

    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        self.proj_out.forward(&crate::linear::geglu(&self.proj_in.forward(x)?)?)
    }
}

#[derive(Debug)]
struct TransformerBlock {
    norm1: nn::LayerNorm,
    attn1: Attention,
    norm2: nn::LayerNorm,
    attn2: Attention,
    norm3: nn::LayerNorm,
    ff: FeedForward,
}

impl TransformerBlock {
    fn new(vb: VarBuilder, dim: usize, context_dim: usize, heads: usize) -> candle_core::Result<Self> {
        Ok(Self {
            norm1: nn::layer_norm(dim, 1e-5, vb.pp("norm1"))?,
            attn1: Attention::new(vb.pp("attn1"), dim, dim, heads)?,
            norm2: nn::layer_norm(dim, 1e-5, vb.pp("norm2"))?,
            attn2: Attention::new(vb.pp("attn2"), dim, context_dim, heads)?,
            norm3: nn::layer_norm(dim, 1e-5, vb.pp("norm3"))?,
            ff: FeedForward::new(vb.pp("ff"), dim)?,
        })
    }

    fn forward(&self, x: &Tensor, context: &Tensor) -> candle_core::Result<Tensor> {
        let x = (self.attn1.forward(&self.norm1.forward(x)?, None)? + x)?;
        let x = (self.attn2.forward(&self.norm2.forward(&x)?, Some(context))? + x)?;
        self.ff.forward(&self.norm3.forward(&x)?)? + x
    }
}

#[derive(Debug)]
enum Proj {
    Conv(Conv2d),
    Linear(Linear),
}

/// diffusers `Transformer2DModel` (continuous input): group norm, projection in,
/// transformer blocks over the H·W tokens, projection out, residual.
#[derive(Debug)]
struct Transformer2D {
    norm: GroupNorm,
    proj_in: Proj,
    blocks: Vec<TransformerBlock>,
    proj_out: Proj,
}

impl Transformer2D {
    /// The transformer of resolution `level` (its heads and depth come from the config).
    fn new(vb: VarBuilder, channels: usize, level: usize, cfg: &UNetConfig) -> candle_core::Result<Self> {
        let (heads, depth) = (cfg.heads(level), cfg.transformer_layers_per_block.get(level));
        let norm = group_norm(cfg.norm_num_groups, channels, 1e-6, vb.pp("norm"))?;
        let (proj_in, proj_out) = if cfg.use_linear_projection {
            (
                Proj::Linear(linear(channels, channels, vb.pp("proj_in"))?),
                Proj::Linear(linear(channels, channels, vb.pp("proj_out"))?),
            )
        } else {
            (
                Proj::Conv(conv2d(channels, channels, 1, Default::default(), vb.pp("proj_in"))?),
                Proj::Conv(conv2d(channels, channels, 1, Default::default(), vb.pp("proj_out"))?),
            )
        };
        let blocks = (0..depth)
            .map(|i| {
                TransformerBlock::new(
                    vb.pp("transformer_blocks").pp(i),
                    channels,
                    cfg.cross_attention_dim,
                    heads,
                )
            })
            .collect::<candle_core::Result<_>>()?;
        Ok(Self { norm, proj_in, blocks, proj_out })
    }

    fn forward(&self, x: &Tensor, context: &Tensor) -> candle_core::Result<Tensor> {
        let (b, c, h, w) = x.dims4()?;
        let tokens = |t: &Tensor| t.flatten_from(2)?.transpose(1, 2)?.contiguous();
        let normed = self.norm.forward(x)?;
        let mut t = match &self.proj_in {
            Proj::Conv(p) => tokens(&p.forward(&normed)?)?,
            Proj::Linear(p) => p.forward(&tokens(&normed)?)?,
        };
        for block in &self.blocks {
            t = block.forward(&t, context)?;
        }
        let image = |t: &Tensor| t.transpose(1, 2)?.reshape((b, c, h, w));
        let out = match &self.proj_out {
            Proj::Conv(p) => p.forward(&image(&t)?)?,
            Proj::Linear(p) => image(&p.forward(&t)?)?,
        };
        out + x
    }
}

fn conv3(
    vb: VarBuilder,
    cin: usize,
    cout: usize,
    stride: usize,
    padding: usize,
) -> candle_core::Result<Conv2d> {
    let cfg = Conv2dConfig { padding, stride, ..Default::default() };
    conv2d(cin, cout, 3, cfg, vb)
}

/// One resolution level on the way down (`CrossAttnDownBlock2D` or `DownBlock2D`).
#[derive(Debug)]
struct DownBlock {
    resnets: Vec<ResnetBlock>,
    attentions: Vec<Transformer2D>,
    downsample: Option<Conv2d>,
}

/// One resolution level on the way up (`CrossAttnUpBlock2D` or `UpBlock2D`).
#[derive(Debug)]
struct UpBlock {
    resnets: Vec<ResnetBlock>,
    attentions: Vec<Transformer2D>,
    upsample: Option<Conv2d>,
}

/// diffusers `UNet2DConditionModel` (Stable Diffusion 1.x layout).
#[derive(Debug)]
pub struct UNet {
    pub config: UNetConfig,
    conv_in: Conv2d,
    time_proj: Timesteps,
    time_embedding: TimestepEmbedding,
    down: Vec<DownBlock>,
    mid_resnets: Vec<ResnetBlock>,
    mid_attentions: Vec<Transformer2D>,
    up: Vec<UpBlock>,
    conv_norm_out: GroupNorm,
    conv_out: Conv2d,
}

impl UNet {
    /// Builds the UNet from `config` and the weights in `vb` (diffusers names).
    pub fn new(vb: VarBuilder, config: UNetConfig) -> candle_core::Result<Self> {
        config.check().map_err(candle_core::Error::Msg)?;
        let cfg = &config;
        let n = cfg.block_out_channels.len();
        let ch0 = cfg.block_out_channels[0];
        let temb = 4 * ch0;
        let resnet = |vb: VarBuilder, cin: usize, cout: usize, scale: f64| {
            let rc = ResnetConfig {
                temb_channels: Some(temb),
                groups: cfg.norm_num_groups,
                eps: cfg.norm_eps,
                output_scale: scale,
            };
            ResnetBlock::new(vb, cin, cout, rc)
        };
        let conv_in = conv3(vb.pp("conv_in"), cfg.in_channels, ch0, 1, 1)?;
        let time_proj = Timesteps::new(ch0, cfg.flip_sin_to_cos, cfg.freq_shift);
        let time_embedding = TimestepEmbedding::new(vb.pp("time_embedding"), ch0, temb)?;

        let mut down = Vec::with_capacity(n);
        let mut out_ch = ch0;
        for i in 0..n {
            let in_ch = out_ch;
            out_ch = cfg.block_out_channels[i];
            let vb_b = vb.pp("down_blocks").pp(i);
            let layers = cfg.layers_per_block.get(i);
            let cross = cfg.down_block_types[i] == "CrossAttnDownBlock2D";
            let mut resnets = Vec::new();
            let mut attentions = Vec::new();
            for j in 0..layers {
                let cin = if j == 0 { in_ch } else { out_ch };
                resnets.push(resnet(vb_b.pp("resnets").pp(j), cin, out_ch, 1.0)?);
                if cross {
                    attentions.push(Transformer2D::new(vb_b.pp("attentions").pp(j), out_ch, i, cfg)?);
                }
            }
            let downsample = if i + 1 < n {
                Some(conv3(vb_b.pp("downsamplers.0.conv"), out_ch, out_ch, 2, cfg.downsample_padding)?)
            } else {
                None
            };
            down.push(DownBlock { resnets, attentions, downsample });
        }

        let ch_last = cfg.block_out_channels[n - 1];
        let vb_m = vb.pp("mid_block");
        let mid_resnets = (0..2)
            .map(|j| resnet(vb_m.pp("resnets").pp(j), ch_last, ch_last, cfg.mid_block_scale_factor))
            .collect::<candle_core::Result<Vec<_>>>()?;
        let mid_attentions = vec![Transformer2D::new(vb_m.pp("attentions.0"), ch_last, n - 1, cfg)?];

        let mut up = Vec::with_capacity(n);
        let rev: Vec<usize> = cfg.block_out_channels.iter().rev().copied().collect();
        let mut out_ch = rev[0];
        for i in 0..n {
            let block = n - 1 - i; // the down block this level mirrors
            let prev_out = out_ch;
            out_ch = rev[i];
            let in_ch = rev[(i + 1).min(n - 1)];
            let vb_b = vb.pp("up_blocks").pp(i);
            let layers = cfg.layers_per_block.get(block) + 1;
            let cross = cfg.up_block_types[i] == "CrossAttnUpBlock2D";
            let mut resnets = Vec::new();
            let mut attentions = Vec::new();
            for j in 0..layers {
                let skip = if j == layers - 1 { in_ch } else { out_ch };
                let cin = if j == 0 { prev_out } else { out_ch };
                resnets.push(resnet(vb_b.pp("resnets").pp(j), cin + skip, out_ch, 1.0)?);
                if cross {
                    attentions.push(Transformer2D::new(vb_b.pp("attentions").pp(j), out_ch, block, cfg)?);
                }
            }
            let upsample = if i + 1 < n {
                Some(conv3(vb_b.pp("upsamplers.0.conv"), out_ch, out_ch, 1, 1)?)
            } else {
                None
            };
            up.push(UpBlock { resnets, attentions, upsample });
        }
        let conv_norm_out = group_norm(cfg.norm_num_groups, ch0, cfg.norm_eps, vb.pp("conv_norm_out"))?;
        let conv_out = conv3(vb.pp("conv_out"), ch0, cfg.out_channels, 1, 1)?;
        Ok(Self {
            config,
            conv_in,
            time_proj,
            time_embedding,
            down,
            mid_resnets,
            mid_attentions,
            up,
            conv_norm_out,
            conv_out,
        })
    }

    /// Predicted noise ε for `sample` (`B × in_channels × h × w`) at diffusion timestep
    /// `t`, conditioned on `context` (`B × tokens × cross_attention_dim`).
    pub fn forward(&self, sample: &Tensor, t: f64, context: &Tensor) -> candle_core::Result<Tensor> {
        self.forward_at(sample, &vec![t; sample.dim(0)?], context)
    }

    /// [`UNet::forward`] with a timestep per batch item.
    pub fn forward_at(
        &self,
        sample: &Tensor,
        timesteps: &[f64],
        context: &Tensor,
    ) -> candle_core::Result<Tensor> {
        let b = sample.dim(0)?;
        if timesteps.len() != b {
            candle_core::bail!("UNet: {} timesteps for a batch of {b}", timesteps.len());
        }
        let x = if self.config.center_input_sample { ((sample * 2.0)? - 1.0)? } else { sample.clone() };
        let t: Vec<f32> = timesteps.iter().map(|&t| t as f32).collect();
        let t = Tensor::from_vec(t, b, sample.device())?;
        let emb = self.time_embedding.forward(&self.time_proj.forward(&t)?.to_dtype(x.dtype())?)?;

        let mut x = self.conv_in.forward(&x)?;
        let mut skips = vec![x.clone()];
        for block in &self.down {
            for (j, resnet) in block.resnets.iter().enumerate() {
                x = resnet.forward(&x, Some(&emb))?;
                if let Some(attn) = block.attentions.get(j) {
                    x = attn.forward(&x, context)?;
                }
                skips.push(x.clone());
            }
            if let Some(down) = &block.downsample {
                x = down.forward(&x)?;
                skips.push(x.clone());
            }
        }

        x = self.mid_resnets[0].forward(&x, Some(&emb))?;
        for (attn, resnet) in self.mid_attentions.iter().zip(&self.mid_resnets[1..]) {
            x = resnet.forward(&attn.forward(&x, context)?, Some(&emb))?;
        }

        for block in &self.up {
            for (j, resnet) in block.resnets.iter().enumerate() {
                let skip =
                    skips.pop().ok_or_else(|| candle_core::Error::Msg("UNet skip underflow".into()))?;
                x = resnet.forward(&Tensor::cat(&[&x, &skip], 1)?, Some(&emb))?;
                if let Some(attn) = block.attentions.get(j) {
                    x = attn.forward(&x, context)?;
                }
            }
            if let Some(up) = &block.upsample {
                // Up to the size of the next skip, so odd latent sizes work as in diffusers.
                let (h, w) = match skips.last() {
                    Some(s) => (s.dim(2)?, s.dim(3)?),
                    None => (2 * x.dim(2)?, 2 * x.dim(3)?),
                };
                x = up.forward(&x.upsample_nearest2d(h, w)?)?;
            }
        }
        let x = self.conv_norm_out.forward_silu(&x)?;
        self.conv_out.forward(&x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn per_block_lists_must_match_the_block_count() {
        let text = include_str!("../../tests/fixtures/ip2p/unet/config.json");
        let good: UNetConfig = serde_json::from_str(text).unwrap();
        assert!(good.check().is_ok());
        let n = good.block_out_channels.len();
        let mut bad = good.clone();
        bad.layers_per_block = PerBlock::Each(vec![1; n + 1]);
        assert!(bad.check().unwrap_err().contains("layers_per_block"));
        let mut bad = good;
        bad.attention_head_dim = PerBlock::Each(vec![2; n - 1]);
        assert!(bad.check().unwrap_err().contains("attention_head_dim"));
    }
}

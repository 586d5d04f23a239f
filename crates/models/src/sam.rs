//! SAM, the promptable segmenter (Kirillov et al., "Segment Anything", ICCV 2023), in the
//! Hugging Face `SamModel` layout (`facebook/sam-vit-base`, `-large`, `-huge`, and the
//! pruned `Zigeng/SlimSAM-uniform-77`): transformers' `models/sam`, the reference this
//! port is proven against by `tests/sam_parity.rs`.
//!
//! What it is for: sharpening the target mask of the segmentation constraint (issue #43,
//! the paper's M_sam^v in Ω_v = {Ā_v ≥ δ_a} ∩ M_sam^v). A text-grounded mask (CLIPSeg's,
//! [`SamSharpened`]) is coarse at the object's boundary; SAM, prompted by that mask's box
//! and its most confident pixel, returns the object's mask at image resolution.
//!
//! The model, for an image and a prompt:
//! 1. **Vision encoder** (ViT with windowed attention). The image, its long side resized
//!    to `image_size` (1024) and the rest padded with zeros after ImageNet normalisation,
//!    is cut into `patch_size` patches (a convolution with kernel and stride `patch_size`),
//!    plus absolute positions `pos_embed`. Each layer is pre-norm:
//!    x ← x + Attn(LN₁(x)), x ← x + MLP(LN₂(x)) (`lin2(GELU(lin1))`). Attention runs within
//!    `window_size²` windows (the grid zero-padded to a multiple of the window), except in
//!    the layers of `global_attn_indexes`, over the whole grid. Scores carry MViTv2's
//!    decomposed relative positions: s(p, q) = q_p·k_q/√d + q_p·R_h[p_y − q_y] +
//!    q_p·R_w[p_x − q_x] ([`rel_pos_table`]). The neck maps the grid to `output_channels`
//!    (1 × 1 convolution, channel layer norm, 3 × 3 convolution, channel layer norm): the
//!    image embedding, `g × g` with g = `image_size / patch_size`.
//! 2. **Prompt encoder.** A point (x, y) in input pixels is encoded with random Fourier
//!    features, PE(p) = [sin 2π(2p̂ − 1)G, cos 2π(2p̂ − 1)G], p̂ = (p + ½)/`image_size`, G the
//!    `2 × num_pos_feats` matrix `shared_image_embedding.positional_embedding`, plus the
//!    learnt embedding of its label (`point_embed.0` negative, `.1` positive); a box is its
//!    two corners, PE plus `point_embed.2` and `.3`. Without a box the points are padded
//!    with one "not a point" token. The dense prompt is `no_mask_embed` at every cell (mask
//!    prompts are not used here). The image's own positions are PE of the cell centres.
//! 3. **Mask decoder.** Tokens [IoU token, `num_multimask_outputs + 1` mask tokens, prompt
//!    tokens] and the image embedding (plus the dense prompt) go through a two-way
//!    transformer: per layer, token self-attention, tokens → image cross-attention, MLP,
//!    image → tokens cross-attention, each followed by a layer norm, positions added to
//!    queries and keys (not values); a last tokens → image attention and layer norm. The
//!    image side is upscaled ×4 (two transposed 2 × 2 convolutions, channel layer norm and
//!    GELU), and each mask token through its own 3-layer MLP gives the weights of a
//!    per-pixel dot product: one logit map per mask at 4g × 4g. The IoU token's MLP
//!    predicts each mask's quality. Single-mask output takes mask 0; multimask the others.
//! 4. [`Sam::segment`] resizes the logits bilinearly to the padded input, crops the
//!    image's part, resizes to the image's size and applies the sigmoid (what
//!    `SamProcessor.post_process_masks` does before its threshold at 0).

use std::path::Path;

use candle_core::{DType, Device, IndexOp, Module, Tensor};
use candle_nn::{layer_norm, Conv2dConfig, LayerNorm, VarBuilder};
use serde::Deserialize;

use crate::check::{self, ModelConfig};
use crate::clip::{Activation, Attention};
use crate::conv::{self, Conv2d, PatchTransposedConv};
use crate::dinov2::{IMAGENET_MEAN, IMAGENET_STD};
use crate::linear::{linear, Linear};
use crate::resample;
use crate::softmax::softmax_last_dim;
use crate::{Error, ModelDir};
use transsplat_editors::{Error as EditorError, Segmenter, SourceView};

/// Download command for SAM weights (SlimSAM: the ViT-B layout pruned to a fifth of its
/// size; `facebook/sam-vit-base` loads the same way).
pub const SAM_HINT: &str = "hf download Zigeng/SlimSAM-uniform-77 --local-dir DIR";

/// [`SAM_HINT`] for the folder `dir`.
pub fn download_hint(dir: &Path) -> String {
    SAM_HINT.replace("DIR", &dir.display().to_string())
}

/// Heads of one attention computed together.
const HEADS_AT_ONCE: usize = 4;

/// Scores computed at once, in floats (4 MiB): the global layers' 4096 × 4096 scores a head
/// at 1024² are taken in blocks of query rows.
const SCORE_BUDGET: usize = 1 << 20;

/// `vision_config` of a `SamModel` (transformers' `SamVisionConfig` defaults: ViT-B).
#[derive(Debug, Clone, Deserialize)]
#[serde(default)]
pub struct SamVisionConfig {
    pub hidden_size: usize,
    pub output_channels: usize,
    pub num_hidden_layers: usize,
    pub num_attention_heads: usize,
    pub num_channels: usize,
    pub image_size: usize,
    pub patch_size: usize,
    pub hidden_act: String,
    pub layer_norm_eps: f64,
    pub qkv_bias: bool,
    pub mlp_ratio: f64,
    pub use_abs_pos: bool,
    pub use_rel_pos: bool,
    /// 0: every layer attends globally.
    pub window_size: usize,
    pub global_attn_indexes: Vec<usize>,
    pub num_pos_feats: usize,
    /// `hidden_size · mlp_ratio` when absent.
    pub mlp_dim: Option<usize>,
}

impl Default for SamVisionConfig {
    fn default() -> Self {
        Self {
            hidden_size: 768,
            output_channels: 256,
            num_hidden_layers: 12,
            num_attention_heads: 12,
            num_channels: 3,
            image_size: 1024,
            patch_size: 16,
            hidden_act: "gelu".into(),
            layer_norm_eps: 1e-6,
            qkv_bias: true,
            mlp_ratio: 4.0,
            use_abs_pos: true,
            use_rel_pos: true,
            window_size: 14,
            global_attn_indexes: vec![2, 5, 8, 11],
            num_pos_feats: 128,
            mlp_dim: None,
        }
    }
}

impl SamVisionConfig {
    pub fn mlp_dim(&self) -> usize {
        self.mlp_dim.unwrap_or((self.hidden_size as f64 * self.mlp_ratio) as usize)
    }

    /// The image embedding's side, `image_size / patch_size`.
    pub fn grid(&self) -> usize {
        self.image_size / self.patch_size.max(1)
    }
}

/// `prompt_encoder_config` (the fields this port reads).
#[derive(Debug, Clone, Deserialize)]
#[serde(default)]
pub struct SamPromptEncoderConfig {
    pub hidden_size: usize,
    pub image_size: usize,
    pub patch_size: usize,
}

impl Default for SamPromptEncoderConfig {
    fn default() -> Self {
        Self { hidden_size: 256, image_size: 1024, patch_size: 16 }
    }
}

/// `mask_decoder_config`.
#[derive(Debug, Clone, Deserialize)]
#[serde(default)]
pub struct SamMaskDecoderConfig {
    pub hidden_size: usize,
    pub hidden_act: String,
    pub mlp_dim: usize,
    pub num_hidden_layers: usize,
    pub num_attention_heads: usize,
    pub attention_downsample_rate: usize,
    pub num_multimask_outputs: usize,
    pub iou_head_depth: usize,
    pub iou_head_hidden_dim: usize,
    pub layer_norm_eps: f64,
}

impl Default for SamMaskDecoderConfig {
    fn default() -> Self {
        Self {
            hidden_size: 256,
            hidden_act: "relu".into(),
            mlp_dim: 2048,
            num_hidden_layers: 2,
            num_attention_heads: 8,
            attention_downsample_rate: 2,
            num_multimask_outputs: 3,
            iou_head_depth: 3,
            iou_head_hidden_dim: 256,
            layer_norm_eps: 1e-6,
        }
    }
}

/// `config.json` of a `SamModel`.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(default)]
pub struct SamConfig {
    pub vision_config: SamVisionConfig,
    pub prompt_encoder_config: SamPromptEncoderConfig,
    pub mask_decoder_config: SamMaskDecoderConfig,
}

impl ModelConfig for SamConfig {
    fn check(&self) -> Result<(), String> {
        let v = &self.vision_config;
        check::size("vision_config.hidden_size", v.hidden_size)?;
        check::divides(
            "vision_config.hidden_size",
            v.hidden_size,
            "vision_config.num_attention_heads",
            v.num_attention_heads,
        )?;
        check::layers("vision_config.num_hidden_layers", v.num_hidden_layers)?;
        check::size("vision_config.num_channels", v.num_channels)?;
        check::size("vision_config.mlp_dim", v.mlp_dim())?;
        check::size("vision_config.output_channels", v.output_channels)?;
        check::size("vision_config.num_pos_feats", v.num_pos_feats)?;
        check::positive("vision_config.layer_norm_eps", v.layer_norm_eps)?;
        check::divides("vision_config.image_size", v.image_size, "vision_config.patch_size", v.patch_size)?;
        if v.image_size > 4096 {
            return Err(format!("vision_config.image_size is {}: at most 4096 is supported", v.image_size));
        }
        if v.window_size > v.grid() {
            return Err(format!(
                "vision_config.window_size {} exceeds the patch grid {}",
                v.window_size,
                v.grid()
            ));
        }
        Activation::named(&v.hidden_act).map_err(|m| format!("vision_config: {m}"))?;
        let p = &self.prompt_encoder_config;
        let d = &self.mask_decoder_config;
        check::size("mask_decoder_config.hidden_size", d.hidden_size)?;
        for (field, width) in [
            ("vision_config.output_channels", v.output_channels),
            ("prompt_encoder_config.hidden_size", p.hidden_size),
            ("twice vision_config.num_pos_feats", 2 * v.num_pos_feats),
        ] {
            if width != d.hidden_size {
                return Err(format!(
                    "{field} is {width}: the mask decoder's hidden_size is {}; they must agree",
                    d.hidden_size
                ));
            }
        }
        if p.image_size != v.image_size || p.patch_size != v.patch_size {
            return Err(format!(
                "prompt_encoder_config's image_size / patch_size {} / {} differ from vision_config's {} / {}",
                p.image_size, p.patch_size, v.image_size, v.patch_size
            ));
        }
        check::divides("mask_decoder_config.hidden_size", d.hidden_size, "8 (the upscaled channels)", 8)?;
        check::divides(
            "mask_decoder_config.hidden_size",
            d.hidden_size,
            "mask_decoder_config.num_attention_heads",
            d.num_attention_heads,
        )?;
        check::size("mask_decoder_config.attention_downsample_rate", d.attention_downsample_rate)?;
        let internal = d.hidden_size / d.attention_downsample_rate;
        check::divides(
            "the cross-attention width",
            internal,
            "mask_decoder_config.num_attention_heads",
            d.num_attention_heads,
        )?;
        check::layers("mask_decoder_config.num_hidden_layers", d.num_hidden_layers)?;
        check::size("mask_decoder_config.mlp_dim", d.mlp_dim)?;
        check::size("mask_decoder_config.num_multimask_outputs", d.num_multimask_outputs)?;
        check::size("mask_decoder_config.iou_head_hidden_dim", d.iou_head_hidden_dim)?;
        if !(2..=check::MAX_LAYERS).contains(&d.iou_head_depth) {
            return Err(format!(
                "mask_decoder_config.iou_head_depth is {}: must be at least 2",
                d.iou_head_depth
            ));
        }
        check::positive("mask_decoder_config.layer_norm_eps", d.layer_norm_eps)?;
        Activation::named(&d.hidden_act).map_err(|m| format!("mask_decoder_config: {m}"))?;
        Ok(())
    }
}

/// A layer norm over the channels of an `[B, C, H, W]` tensor (transformers'
/// `SamLayerNorm(data_format="channels_first")`).
fn channel_norm(norm: &LayerNorm, x: &Tensor) -> candle_core::Result<Tensor> {
    norm.forward(&x.permute((0, 2, 3, 1))?)?.permute((0, 3, 1, 2))
}

/// The relative-position rows R[p − q + n − 1] for every query p and key q of an axis of
/// `n` cells: `[n, n, d]` from the learnt `[2n − 1, d]` table (query and key axes have the
/// same length in SAM, so transformers' resize of the table is the identity).
fn rel_pos_table(table: &Tensor, n: usize) -> candle_core::Result<Tensor> {
    let (rows, d) = table.dims2()?;
    if rows != 2 * n - 1 {
        candle_core::bail!(
            "SAM: relative position table of {rows} rows for an axis of {n} cells (need {})",
            2 * n - 1
        );
    }
    let index: Vec<u32> = (0..n).flat_map(|p| (0..n).map(move |q| (p + n - 1 - q) as u32)).collect();
    let index = Tensor::from_vec(index, n * n, table.device())?;
    table.index_select(&index, 0)?.reshape((n, n, d))
}

/// The vision encoder's attention with decomposed relative positions (module doc, 1).
#[derive(Debug)]
struct VisionAttention {
    qkv: Linear,
    proj: Linear,
    heads: usize,
    /// `(R_h, R_w)` tables, `[2n − 1, d]`.
    rel_pos: Option<(Tensor, Tensor)>,
    /// Scores computed at once, in floats ([`SCORE_BUDGET`]).
    budget: usize,
}

impl VisionAttention {
    fn new(vb: VarBuilder, config: &SamVisionConfig, side: usize) -> candle_core::Result<Self> {
        let c = config.hidden_size;
        let head_dim = c / config.num_attention_heads;
        let qkv = if config.qkv_bias {
            linear(c, 3 * c, vb.pp("qkv"))?
        } else {
            crate::linear::linear_no_bias(c, 3 * c, vb.pp("qkv"))?
        };
        let rel_pos = if config.use_rel_pos {
            Some((
                vb.get((2 * side - 1, head_dim), "rel_pos_h")?,
                vb.get((2 * side - 1, head_dim), "rel_pos_w")?,
            ))
        } else {
            None
        };
        Ok(Self {
            qkv,
            proj: linear(c, c, vb.pp("proj"))?,
            heads: config.num_attention_heads,
            rel_pos,
            budget: SCORE_BUDGET,
        })
    }

    /// `x`: `[B, h, w, C]` (a batch of windows or whole grids).
    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let (b, h, w, c) = x.dims4()?;
        let d = c / self.heads;
        let qkv = self.qkv.forward(x)?.reshape((b, h * w, 3, self.heads, d))?.permute((2, 0, 3, 1, 4))?;
        let qkv = qkv.reshape((3, b * self.heads, h * w, d))?;
        let (q, k, v) = (qkv.i(0)?, qkv.i(1)?, qkv.i(2)?);
        let tables = match &self.rel_pos {
            Some((rh, rw)) => Some((rel_pos_table(rh, h)?, rel_pos_table(rw, w)?)),
            None => None,
        };
        let scale = (d as f64).powf(-0.5);
        let (n, hw) = (b * self.heads, h * w);
        let rel = match &tables {
            Some((th, tw)) => Some(rel_products(&q.contiguous()?, th, tw, h, w)?),
            None => None,
        };
        let mut outputs = Vec::new();
        for start in (0..n).step_by(HEADS_AT_ONCE) {
            let len = HEADS_AT_ONCE.min(n - start);
            let q = q.narrow(0, start, len)?.contiguous()?;
            let k = k.narrow(0, start, len)?.contiguous()?.t()?;
            let v = v.narrow(0, start, len)?.contiguous()?;
            // Query rows in blocks whose scores stay within the budget (cache-sized).
            let rows = (self.budget / (len * hw)).clamp(1, hw);
            let mut blocks = Vec::new();
            for first in (0..hw).step_by(rows) {
                let count = rows.min(hw - first);
                let mut scores = (q.narrow(1, first, count)? * scale)?.matmul(&k)?;
                if let Some(rel) = &rel {
                    scores = rel.add_to(scores, start, first, h, w)?;
                }
                blocks.push(softmax_last_dim(&scores)?.matmul(&v)?);
            }
            outputs.push(Tensor::cat(&blocks, 1)?);
        }
        let out = Tensor::cat(&outputs, 0)?.reshape((b, self.heads, h, w, d))?.permute((0, 2, 3, 1, 4))?;
        self.proj.forward(&out.reshape((b, h, w, c))?)
    }
}

/// The two relative-position products of every query p of `[n, hw, d]`: q_p·R_h[p_y − k_y]
/// for each key row k_y (`[n, hw, h]`) and q_p·R_w[p_x − k_x] for each key column
/// (`[n, hw, w]`), from the tables `[h, h, d]`, `[w, w, d]` of [`rel_pos_table`].
fn rel_products(
    q: &Tensor,
    th: &Tensor,
    tw: &Tensor,
    h: usize,
    w: usize,
) -> candle_core::Result<RelProducts> {
    let (n, _, d) = q.dims3()?;
    let q = q.reshape((n, h, w, d))?;
    // rel_h[n, y, x, k] = Σ_c q[n, y, x, c] th[y, k, c]: one product per query row y.
    let by_row = q.permute((1, 0, 2, 3))?.reshape((h, n * w, d))?;
    let rel_h = by_row.matmul(&th.transpose(1, 2)?)?.reshape((h, n, w, h))?.permute((1, 0, 2, 3))?;
    // rel_w[n, y, x, k] = Σ_c q[n, y, x, c] tw[x, k, c]: one product per query column x.
    let by_column = q.permute((2, 0, 1, 3))?.reshape((w, n * h, d))?;
    let rel_w = by_column.matmul(&tw.transpose(1, 2)?)?.reshape((w, n, h, w))?.permute((1, 2, 0, 3))?;
    Ok(RelProducts { rows: rel_h.flatten_all()?.to_vec1()?, columns: rel_w.flatten_all()?.to_vec1()? })
}

/// [`rel_products`]' two tables, flat.
#[derive(Debug)]
struct RelProducts {
    rows: Vec<f32>,
    columns: Vec<f32>,
}

impl RelProducts {
    /// Adds the decomposed relative positions, s(p, k) += rows[p, k_y] + columns[p, k_x],
    /// to scores `[len, count, hw]` of the heads from `head` and the queries from `first`
    /// (a broadcast add over five axes would walk the scores one element at a time).
    fn add_to(
        &self,
        scores: Tensor,
        head: usize,
        first: usize,
        h: usize,
        w: usize,
    ) -> candle_core::Result<Tensor> {
        use rayon::prelude::*;
        let (len, count, hw) = scores.dims3()?;
        let device = scores.device().clone();
        let mut data = scores.flatten_all()?.to_vec1::<f32>()?;
        data.par_chunks_mut(hw).enumerate().for_each(|(i, keys)| {
            let query = (head + i / count) * hw + first + i % count;
            let (rh, rw) =
                (&self.rows[query * h..(query + 1) * h], &self.columns[query * w..(query + 1) * w]);
            for (ky, line) in keys.chunks_exact_mut(w).enumerate() {
                for (s, r) in line.iter_mut().zip(rw) {
                    *s += rh[ky] + r;
                }
            }
        });
        Tensor::from_vec(data, (len, count, hw), &device)
    }
}

#[derive(Debug)]
struct Mlp {
    lin1: Linear,
    lin2: Linear,
    act: Activation,
}

impl Mlp {
    fn new(vb: VarBuilder, width: usize, hidden: usize, act: Activation) -> candle_core::Result<Self> {
        Ok(Self {
            lin1: linear(width, hidden, vb.pp("lin1"))?,
            lin2: linear(hidden, width, vb.pp("lin2"))?,
            act,
        })
    }

    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        self.lin2.forward(&self.act.apply(&self.lin1.forward(x)?)?)
    }
}

#[derive(Debug)]
struct VisionLayer {
    norm1: LayerNorm,
    attn: VisionAttention,
    norm2: LayerNorm,
    mlp: Mlp,
    /// 0: global attention.
    window: usize,
}

impl VisionLayer {
    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let h = self.norm1.forward(x)?;
        let h = if self.window > 0 {
            let (_, height, width, _) = h.dims4()?;
            let (windows, padded) = window_partition(&h, self.window)?;
            window_unpartition(&self.attn.forward(&windows)?, self.window, padded, (height, width))?
        } else {
            self.attn.forward(&h)?
        };
        let x = (x + h)?;
        &x + self.mlp.forward(&self.norm2.forward(&x)?)?
    }
}

/// `[B, H, W, C]` → `[B · nh · nw, s, s, C]` windows of side `s`, the grid zero-padded at the
/// bottom and right to a multiple of `s`; returns the padded size too.
fn window_partition(x: &Tensor, s: usize) -> candle_core::Result<(Tensor, (usize, usize))> {
    let (b, h, w, c) = x.dims4()?;
    let (ph, pw) = (h.div_ceil(s) * s, w.div_ceil(s) * s);
    let x = x.pad_with_zeros(1, 0, ph - h)?.pad_with_zeros(2, 0, pw - w)?;
    let windows = x.reshape((b, ph / s, s, pw / s, s, c))?.permute((0, 1, 3, 2, 4, 5))?;
    Ok((windows.reshape((b * (ph / s) * (pw / s), s, s, c))?, (ph, pw)))
}

/// The inverse of [`window_partition`], the padding cropped.
fn window_unpartition(
    windows: &Tensor,
    s: usize,
    (ph, pw): (usize, usize),
    (h, w): (usize, usize),
) -> candle_core::Result<Tensor> {
    let c = windows.dim(3)?;
    let b = windows.dim(0)? / ((ph / s) * (pw / s));
    let x = windows
        .reshape((b, ph / s, pw / s, s, s, c))?
        .permute((0, 1, 3, 2, 4, 5))?
        .reshape((b, ph, pw, c))?;
    x.narrow(1, 0, h)?.narrow(2, 0, w)?.contiguous()
}

#[derive(Debug)]
struct VisionEncoder {
    patch_embed: Conv2d,
    pos_embed: Option<Tensor>,
    layers: Vec<VisionLayer>,
    neck_conv1: Conv2d,
    neck_norm1: LayerNorm,
    neck_conv2: Conv2d,
    neck_norm2: LayerNorm,
}

impl VisionEncoder {
    fn new(vb: VarBuilder, config: &SamVisionConfig) -> candle_core::Result<Self> {
        let (c, g, eps) = (config.hidden_size, config.grid(), config.layer_norm_eps);
        let act = Activation::named(&config.hidden_act).map_err(candle_core::Error::Msg)?;
        let patch = Conv2dConfig { stride: config.patch_size, ..Default::default() };
        let patch_embed =
            conv::conv2d(config.num_channels, c, config.patch_size, patch, vb.pp("patch_embed.projection"))?;
        let pos_embed = if config.use_abs_pos { Some(vb.get((1, g, g, c), "pos_embed")?) } else { None };
        let layers = (0..config.num_hidden_layers)
            .map(|i| {
                let vb = vb.pp(format!("layers.{i}"));
                let window = if config.global_attn_indexes.contains(&i) { 0 } else { config.window_size };
                Ok(VisionLayer {
                    norm1: layer_norm(c, eps, vb.pp("layer_norm1"))?,
                    attn: VisionAttention::new(vb.pp("attn"), config, if window == 0 { g } else { window })?,
                    norm2: layer_norm(c, eps, vb.pp("layer_norm2"))?,
                    mlp: Mlp::new(vb.pp("mlp"), c, config.mlp_dim(), act)?,
                    window,
                })
            })
            .collect::<candle_core::Result<_>>()?;
        let (out, neck) = (config.output_channels, vb.pp("neck"));
        let no_bias = |cin, k, padding, name: &str| {
            let cfg = Conv2dConfig { padding, ..Default::default() };
            conv::from_candle(candle_nn::conv2d_no_bias(cin, out, k, cfg, neck.pp(name))?, cfg)
        };
        Ok(Self {
            patch_embed,
            pos_embed,
            layers,
            neck_conv1: no_bias(c, 1, 0, "conv1")?,
            neck_norm1: layer_norm(out, 1e-6, neck.pp("layer_norm1"))?,
            neck_conv2: no_bias(out, 3, 1, "conv2")?,
            neck_norm2: layer_norm(out, 1e-6, neck.pp("layer_norm2"))?,
        })
    }

    /// `[B, 3, S, S]` normalised pixels → the image embedding `[B, output_channels, g, g]`.
    fn forward(&self, pixels: &Tensor) -> candle_core::Result<Tensor> {
        let mut x = self.patch_embed.forward(pixels)?.permute((0, 2, 3, 1))?;
        if let Some(pos) = &self.pos_embed {
            x = x.broadcast_add(pos)?;
        }
        for layer in &self.layers {
            x = layer.forward(&x)?;
        }
        let x = channel_norm(
            &self.neck_norm1,
            &self.neck_conv1.forward(&x.permute((0, 3, 1, 2))?.contiguous()?)?,
        )?;
        channel_norm(&self.neck_norm2, &self.neck_conv2.forward(&x.contiguous()?)?)
    }
}

/// A point prompt's label.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PointLabel {
    /// On the object (transformers' label 1).
    Positive,
    /// Off the object (label 0).
    Negative,
}

/// One prompt: points and at most one box, in the input's pixels (the resized, padded
/// image of side `image_size`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Prompt {
    pub points: Vec<([f32; 2], PointLabel)>,
    /// `[x1, y1, x2, y2]`.
    pub bbox: Option<[f32; 4]>,
}

/// The prompt encoder (module doc, 2): random Fourier features and learnt embeddings.
#[derive(Debug)]
struct PromptEncoder {
    /// `[2, F]` row-major.
    gaussian: Vec<f32>,
    features: usize,
    /// `point_embed.0..3`, `not_a_point_embed`, `no_mask_embed`: `[C]` each.
    point_embed: [Vec<f32>; 4],
    not_a_point: Vec<f32>,
    no_mask: Tensor,
    input_size: f32,
    width: usize,
}

impl PromptEncoder {
    fn new(vb: &VarBuilder, config: &SamConfig) -> candle_core::Result<Self> {
        let c = config.prompt_encoder_config.hidden_size;
        let features = config.vision_config.num_pos_feats;
        // Tied to `prompt_encoder.shared_embedding.positional_embedding`; files keep one name.
        let key = "shared_image_embedding.positional_embedding";
        let gaussian = if vb.contains_tensor(key) {
            vb.get((2, features), key)?
        } else {
            vb.get((2, features), "prompt_encoder.shared_embedding.positional_embedding")?
        };
        let pe = vb.pp("prompt_encoder");
        let row = |name: String| pe.get((1, c), &name)?.flatten_all()?.to_vec1::<f32>();
        Ok(Self {
            gaussian: gaussian.flatten_all()?.to_vec1()?,
            features,
            point_embed: [
                row("point_embed.0.weight".into())?,
                row("point_embed.1.weight".into())?,
                row("point_embed.2.weight".into())?,
                row("point_embed.3.weight".into())?,
            ],
            not_a_point: row("not_a_point_embed.weight".into())?,
            no_mask: pe.get((1, c), "no_mask_embed.weight")?,
            input_size: config.prompt_encoder_config.image_size as f32,
            width: c,
        })
    }

    /// PE of a point given in [0, 1]² (x, y): `[sin 2π(2p − 1)G, cos …]`.
    fn fourier(&self, p: [f32; 2]) -> Vec<f32> {
        let f = self.features;
        let (x, y) = (2.0 * p[0] - 1.0, 2.0 * p[1] - 1.0);
        let angles: Vec<f32> = (0..f)
            .map(|j| 2.0 * std::f32::consts::PI * (x * self.gaussian[j] + y * self.gaussian[f + j]))
            .collect();
        angles.iter().map(|a| a.sin()).chain(angles.iter().map(|a| a.cos())).collect()
    }

    /// PE of a point in input pixels, shifted to the pixel's centre.
    fn pixel(&self, p: [f32; 2]) -> Vec<f32> {
        self.fourier([(p[0] + 0.5) / self.input_size, (p[1] + 0.5) / self.input_size])
    }

    /// The sparse prompt tokens `[T, C]`, in transformers' order: the points (padded by a
    /// "not a point" token when there is no box), then the box's two corners.
    fn sparse(&self, prompt: &Prompt) -> Vec<Vec<f32>> {
        let add = |mut a: Vec<f32>, b: &[f32]| {
            a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
            a
        };
        let mut tokens: Vec<Vec<f32>> = prompt
            .points
            .iter()
            .map(|&(p, label)| {
                let which = if label == PointLabel::Positive { 1 } else { 0 };
                add(self.pixel(p), &self.point_embed[which])
            })
            .collect();
        match prompt.bbox {
            Some([x1, y1, x2, y2]) => {
                tokens.push(add(self.pixel([x1, y1]), &self.point_embed[2]));
                tokens.push(add(self.pixel([x2, y2]), &self.point_embed[3]));
            }
            None if !prompt.points.is_empty() => tokens.push(self.not_a_point.clone()),
            None => {}
        }
        tokens
    }

    /// PE of the `g × g` cell centres: `[g², C]`, row-major cells.
    fn image_positions(&self, g: usize, device: &Device) -> candle_core::Result<Tensor> {
        let cells: Vec<f32> = (0..g * g)
            .flat_map(|i| {
                self.fourier([((i % g) as f32 + 0.5) / g as f32, ((i / g) as f32 + 0.5) / g as f32])
            })
            .collect();
        Tensor::from_vec(cells, (g * g, self.width), device)
    }
}

#[derive(Debug)]
struct TwoWayBlock {
    self_attn: Attention,
    norm1: LayerNorm,
    token_to_image: Attention,
    norm2: LayerNorm,
    mlp: Mlp,
    norm3: LayerNorm,
    norm4: LayerNorm,
    image_to_token: Attention,
    skip_first_pe: bool,
}

impl TwoWayBlock {
    fn new(vb: VarBuilder, config: &SamMaskDecoderConfig, skip_first_pe: bool) -> candle_core::Result<Self> {
        let (c, eps, heads) = (config.hidden_size, config.layer_norm_eps, config.num_attention_heads);
        let down = config.attention_downsample_rate;
        let act = Activation::named(&config.hidden_act).map_err(candle_core::Error::Msg)?;
        Ok(Self {
            self_attn: Attention::with_width(vb.pp("self_attn"), c, c, heads)?,
            norm1: layer_norm(c, eps, vb.pp("layer_norm1"))?,
            token_to_image: Attention::with_width(vb.pp("cross_attn_token_to_image"), c, c / down, heads)?,
            norm2: layer_norm(c, eps, vb.pp("layer_norm2"))?,
            mlp: Mlp::new(vb.pp("mlp"), c, config.mlp_dim, act)?,
            norm3: layer_norm(c, eps, vb.pp("layer_norm3"))?,
            norm4: layer_norm(c, eps, vb.pp("layer_norm4"))?,
            image_to_token: Attention::with_width(vb.pp("cross_attn_image_to_token"), c, c / down, heads)?,
            skip_first_pe,
        })
    }

    /// Tokens `[B, T, C]` with their positions, image `[B, g², C]` with its positions.
    fn forward(
        &self,
        tokens: &Tensor,
        image: &Tensor,
        token_pe: &Tensor,
        image_pe: &Tensor,
    ) -> candle_core::Result<(Tensor, Tensor)> {
        let tokens = if self.skip_first_pe {
            self.self_attn.forward(tokens, None)?
        } else {
            let q = (tokens + token_pe)?;
            (tokens + self.self_attn.attend(&q, &q, tokens, None)?)?
        };
        let tokens = self.norm1.forward(&tokens)?;
        let keys = image.broadcast_add(image_pe)?;
        let tokens = (&tokens + self.token_to_image.attend(&(&tokens + token_pe)?, &keys, image, None)?)?;
        let tokens = self.norm2.forward(&tokens)?;
        let tokens = self.norm3.forward(&(&tokens + self.mlp.forward(&tokens)?)?)?;
        let image = (image + self.image_to_token.attend(&keys, &(&tokens + token_pe)?, &tokens, None)?)?;
        Ok((tokens, self.norm4.forward(&image)?))
    }
}

/// `proj_in`, ReLU, hidden layers with ReLU, `proj_out` (transformers' `SamFeedForward`).
#[derive(Debug)]
struct FeedForward {
    layers: Vec<Linear>,
}

impl FeedForward {
    fn new(
        vb: VarBuilder,
        input: usize,
        hidden: usize,
        output: usize,
        depth: usize,
    ) -> candle_core::Result<Self> {
        let mut layers = vec![linear(input, hidden, vb.pp("proj_in"))?];
        for i in 0..depth.saturating_sub(2) {
            layers.push(linear(hidden, hidden, vb.pp(format!("layers.{i}")))?);
        }
        layers.push(linear(hidden, output, vb.pp("proj_out"))?);
        Ok(Self { layers })
    }

    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let last = self.layers.len() - 1;
        let mut x = x.clone();
        for (i, layer) in self.layers.iter().enumerate() {
            x = layer.forward(&x)?;
            if i < last {
                x = x.relu()?;
            }
        }
        Ok(x)
    }
}

/// The mask decoder (module doc, 3).
#[derive(Debug)]
struct MaskDecoder {
    /// `[1 + M, C]`: the IoU token, then the mask tokens.
    output_tokens: Tensor,
    layers: Vec<TwoWayBlock>,
    final_attn: Attention,
    final_norm: LayerNorm,
    upscale1: PatchTransposedConv,
    upscale_norm: LayerNorm,
    upscale2: PatchTransposedConv,
    hypernetworks: Vec<FeedForward>,
    iou_head: FeedForward,
}

impl MaskDecoder {
    fn new(vb: VarBuilder, config: &SamMaskDecoderConfig) -> candle_core::Result<Self> {
        let c = config.hidden_size;
        let masks = config.num_multimask_outputs + 1;
        let output_tokens = Tensor::cat(
            &[vb.get((1, c), "iou_token.weight")?, vb.get((masks, c), "mask_tokens.weight")?],
            0,
        )?;
        let t = vb.pp("transformer");
        Ok(Self {
            output_tokens,
            layers: (0..config.num_hidden_layers)
                .map(|i| TwoWayBlock::new(t.pp(format!("layers.{i}")), config, i == 0))
                .collect::<candle_core::Result<_>>()?,
            final_attn: Attention::with_width(
                t.pp("final_attn_token_to_image"),
                c,
                c / config.attention_downsample_rate,
                config.num_attention_heads,
            )?,
            // nn.LayerNorm's own epsilon in the reference, not the config's.
            final_norm: layer_norm(c, 1e-5, t.pp("layer_norm_final_attn"))?,
            upscale1: PatchTransposedConv::new(vb.pp("upscale_conv1"), c, c / 4, 2)?,
            upscale_norm: layer_norm(c / 4, 1e-6, vb.pp("upscale_layer_norm"))?,
            upscale2: PatchTransposedConv::new(vb.pp("upscale_conv2"), c / 4, c / 8, 2)?,
            hypernetworks: (0..masks)
                .map(|i| FeedForward::new(vb.pp(format!("output_hypernetworks_mlps.{i}")), c, c, c / 8, 3))
                .collect::<candle_core::Result<_>>()?,
            iou_head: FeedForward::new(
                vb.pp("iou_prediction_head"),
                c,
                config.iou_head_hidden_dim,
                masks,
                config.iou_head_depth,
            )?,
        })
    }

    /// Image embedding plus dense prompt `[B, C, g, g]`, its positions `[g², C]`, sparse
    /// tokens `[B, T, C]` → logits `[B, 1 + M', 4g, 4g]` of every mask and IoU `[B, 1 + M']`.
    fn forward(
        &self,
        image: &Tensor,
        image_pe: &Tensor,
        sparse: &Tensor,
    ) -> candle_core::Result<(Tensor, Tensor)> {
        let (b, c, g, _) = image.dims4()?;
        let masks = self.output_tokens.dim(0)? - 1;
        let outputs = self.output_tokens.unsqueeze(0)?.broadcast_as((b, masks + 1, c))?;
        let token_pe = Tensor::cat(&[&outputs, sparse], 1)?.contiguous()?;
        let mut tokens = token_pe.clone();
        let mut keys = image.flatten_from(2)?.transpose(1, 2)?.contiguous()?;
        let image_pe = image_pe.unsqueeze(0)?;
        for layer in &self.layers {
            (tokens, keys) = layer.forward(&tokens, &keys, &token_pe, &image_pe)?;
        }
        let q = (&tokens + &token_pe)?;
        let k = keys.broadcast_add(&image_pe)?;
        let tokens = self.final_norm.forward(&(&tokens + self.final_attn.attend(&q, &k, &keys, None)?)?)?;
        let grid = keys.transpose(1, 2)?.reshape((b, c, g, g))?;
        let up = self.upscale1.forward(&grid)?;
        let up = channel_norm(&self.upscale_norm, &up)?.gelu_erf()?;
        let up = self.upscale2.forward(&up)?.gelu_erf()?; // [B, C/8, 4g, 4g]
        let hyper = self
            .hypernetworks
            .iter()
            .enumerate()
            .map(|(i, mlp)| mlp.forward(&tokens.i((.., 1 + i))?))
            .collect::<candle_core::Result<Vec<_>>>()?;
        let hyper = Tensor::stack(&hyper, 1)?; // [B, M, C/8]
        let side = 4 * g;
        let logits = hyper.matmul(&up.reshape((b, c / 8, side * side))?)?.reshape((b, masks, side, side))?;
        let iou = self.iou_head.forward(&tokens.i((.., 0))?)?;
        Ok((logits, iou))
    }
}

/// Masks from one decoder call: logits `[B, K, 4g, 4g]` and predicted IoU `[B, K]`.
#[derive(Debug, Clone)]
pub struct Masks {
    pub logits: Tensor,
    pub iou: Tensor,
}

/// SAM (module doc).
#[derive(Debug)]
pub struct Sam {
    vision: VisionEncoder,
    prompt: PromptEncoder,
    decoder: MaskDecoder,
    image_pe: Tensor,
    config: SamConfig,
    device: Device,
}

impl Sam {
    /// Loads `config.json` and `model.safetensors` from a Hugging Face `SamModel` folder.
    pub fn load(dir: &Path, device: &Device) -> Result<Self, Error> {
        let dir = ModelDir::open(dir, "SAM", &download_hint(dir))?;
        let config: SamConfig = dir.config("config.json")?;
        let vb = dir.var_builder("model", DType::F32, device)?;
        dir.build(|| Self::new(vb, config).map_err(Error::from))
    }

    /// The model from weights in `vb` (`config` checked).
    pub fn new(vb: VarBuilder, config: SamConfig) -> candle_core::Result<Self> {
        let prompt = PromptEncoder::new(&vb, &config)?;
        let image_pe = prompt.image_positions(config.vision_config.grid(), vb.device())?;
        Ok(Self {
            vision: VisionEncoder::new(vb.pp("vision_encoder"), &config.vision_config)?,
            decoder: MaskDecoder::new(vb.pp("mask_decoder"), &config.mask_decoder_config)?,
            prompt,
            image_pe,
            device: vb.device().clone(),
            config,
        })
    }

    pub fn config(&self) -> &SamConfig {
        &self.config
    }

    /// The input side, `image_size`.
    pub fn input_size(&self) -> usize {
        self.config.vision_config.image_size
    }

    /// Normalised pixels `[B, 3, S, S]` → image embeddings `[B, C, g, g]`.
    pub fn image_embeddings(&self, pixels: &Tensor) -> Result<Tensor, Error> {
        let s = self.input_size();
        let (_, channels, h, w) = pixels.dims4()?;
        if (channels, h, w) != (self.config.vision_config.num_channels, s, s) {
            return Err(candle_core::Error::Msg(format!(
                "SAM: pixels of shape {:?}; need [B, {}, {s}, {s}]",
                pixels.dims(),
                self.config.vision_config.num_channels
            ))
            .into());
        }
        Ok(self.vision.forward(pixels)?)
    }

    /// Masks for one prompt per image (`prompts.len()` = the batch). Every prompt must
    /// have the same number of tokens. `multimask`: the three masks 1..; else mask 0.
    pub fn decode(&self, embeddings: &Tensor, prompts: &[Prompt], multimask: bool) -> Result<Masks, Error> {
        let (b, c, _, _) = embeddings.dims4()?;
        if prompts.len() != b || prompts.is_empty() {
            return Err(
                candle_core::Error::Msg(format!("SAM: {} prompts for {b} images", prompts.len())).into()
            );
        }
        let tokens: Vec<Vec<Vec<f32>>> = prompts.iter().map(|p| self.prompt.sparse(p)).collect();
        let count = tokens[0].len();
        if count == 0 || tokens.iter().any(|t| t.len() != count) {
            return Err(candle_core::Error::Msg(
                "SAM: every prompt needs the same, non-zero number of points".into(),
            )
            .into());
        }
        let flat: Vec<f32> = tokens.into_iter().flatten().flatten().collect();
        let sparse = Tensor::from_vec(flat, (b, count, c), &self.device)?;
        let dense = self.prompt.no_mask.reshape((1, c, 1, 1))?;
        let image = embeddings.broadcast_add(&dense)?;
        let (logits, iou) = self.decoder.forward(&image, &self.image_pe, &sparse)?;
        let k = logits.dim(1)?;
        let (start, len) = if multimask { (1, k - 1) } else { (0, 1) };
        Ok(Masks { logits: logits.narrow(1, start, len)?, iou: iou.narrow(1, start, len)? })
    }

    /// SamImageProcessor on a float image: the long side to `image_size` (antialiased
    /// bilinear), ImageNet mean / std, zeros to the right and bottom. Returns the planar
    /// input `[3, S, S]` and the resized size (width, height).
    pub fn preprocess(
        &self,
        rgb: &[f32],
        width: usize,
        height: usize,
    ) -> Result<(Vec<f32>, (usize, usize)), Error> {
        if width == 0 || height == 0 || rgb.len() != width * height * 3 {
            return Err(candle_core::Error::Msg(format!(
                "SAM: image of {} values is not {width} x {height} x 3",
                rgb.len()
            ))
            .into());
        }
        let s = self.input_size();
        let (nw, nh) = resized_size(width, height, s);
        let resized = transsplat_editors::resize_bilinear(rgb, width, height, 3, nw, nh);
        let mut planar = resample::hwc_to_chw(&resized, nh, nw, 3);
        resample::normalize_planes(&mut planar, &IMAGENET_MEAN, &IMAGENET_STD);
        // Zeros (after normalisation) to the right and bottom.
        let mut input = vec![0f32; 3 * s * s];
        for (row, values) in planar.chunks_exact(nw).enumerate() {
            let (c, y) = (row / nh, row % nh);
            input[(c * s + y) * s..][..nw].copy_from_slice(values);
        }
        Ok((input, (nw, nh)))
    }

    /// The probability of the object `prompt` points at, per pixel of a `width × height`
    /// image (`prompt` in the image's own pixels); single-mask output.
    pub fn segment(
        &self,
        rgb: &[f32],
        width: usize,
        height: usize,
        prompt: &Prompt,
    ) -> Result<Vec<f32>, Error> {
        let s = self.input_size();
        let (input, (nw, nh)) = self.preprocess(rgb, width, height)?;
        let (sx, sy) = (nw as f32 / width as f32, nh as f32 / height as f32);
        let scaled = Prompt {
            points: prompt.points.iter().map(|&([x, y], l)| ([x * sx, y * sy], l)).collect(),
            bbox: prompt.bbox.map(|[x1, y1, x2, y2]| [x1 * sx, y1 * sy, x2 * sx, y2 * sy]),
        };
        let pixels = Tensor::from_vec(input, (1, 3, s, s), &self.device)?;
        let embeddings = self.image_embeddings(&pixels)?;
        let masks = self.decode(&embeddings, &[scaled], false)?;
        let (_, _, lh, lw) = masks.logits.dims4()?;
        let low = masks.logits.flatten_all()?.to_vec1::<f32>()?;
        let padded = resample::bilinear(&low, 1, lh, lw, s, s);
        let cropped: Vec<f32> = (0..nh).flat_map(|y| padded[y * s..y * s + nw].iter().copied()).collect();
        let logits = resample::bilinear(&cropped, 1, nh, nw, height, width);
        Ok(logits.into_iter().map(|l| 1.0 / (1.0 + (-l).exp())).collect())
    }
}

/// SamImageProcessor's resized size: the long side to `side`, the other rounded.
fn resized_size(width: usize, height: usize, side: usize) -> (usize, usize) {
    let scale = side as f64 / width.max(height) as f64;
    let round = |v: usize| ((v as f64 * scale + 0.5) as usize).clamp(1, side);
    (round(width), round(height))
}

/// SAM's prompt from a coarse mask of a `width × height` view: the box of the pixels above
/// ½ (inclusive pixel coordinates, as SAM's own mask-to-box) and one positive point at the
/// most confident pixel. `None` when no pixel is above ½.
pub fn prompt_from_mask(mask: &[f32], width: usize, height: usize) -> Option<Prompt> {
    let (mut x1, mut y1, mut x2, mut y2) = (usize::MAX, usize::MAX, 0, 0);
    let mut best = (f32::NEG_INFINITY, 0usize);
    for (i, &p) in mask.iter().enumerate().take(width * height) {
        if p > 0.5 {
            let (x, y) = (i % width, i / width);
            (x1, y1, x2, y2) = (x1.min(x), y1.min(y), x2.max(x), y2.max(y));
        }
        if p > best.0 {
            best = (p, i);
        }
    }
    (x1 != usize::MAX).then(|| Prompt {
        points: vec![([(best.1 % width) as f32, (best.1 / width) as f32], PointLabel::Positive)],
        bbox: Some([x1 as f32, y1 as f32, x2 as f32, y2 as f32]),
    })
}

/// A segmenter whose masks SAM sharpens: the coarse segmenter's mask of each view
/// (CLIPSeg's, from the phrase) prompts SAM with its box and most confident pixel
/// ([`prompt_from_mask`]); SAM's mask replaces it. A view the coarse segmenter missed
/// stays a miss.
#[derive(Debug)]
pub struct SamSharpened<S> {
    coarse: S,
    sam: Sam,
    name: String,
}

impl<S: Segmenter> SamSharpened<S> {
    pub fn new(coarse: S, sam: Sam) -> Self {
        let name = format!("{}+sam", coarse.name());
        Self { coarse, sam, name }
    }
}

impl<S: Segmenter> Segmenter for SamSharpened<S> {
    /// `<coarse>+sam`.
    fn name(&self) -> &str {
        &self.name
    }

    fn segment(&mut self, views: &[SourceView], phrase: &str) -> Result<Vec<Option<Vec<f32>>>, EditorError> {
        let coarse = self.coarse.segment(views, phrase)?;
        views
            .iter()
            .zip(coarse)
            .map(|(view, mask)| {
                let (w, h) = view.size();
                let Some(prompt) = mask.as_deref().and_then(|m| prompt_from_mask(m, w, h)) else {
                    return Ok(None);
                };
                let sharp = self
                    .sam
                    .segment(view.image, w, h, &prompt)
                    .map_err(|e| EditorError::Invalid(format!("SAM, view {}: {e}", view.index)))?;
                Ok(Some(sharp))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_prompt_of_a_mask_is_its_box_and_most_confident_pixel() {
        // 5 × 4 view; pixels above ½ at (1, 1), (3, 1), (2, 2); the most confident (2, 2).
        let mut mask = vec![0.1f32; 20];
        mask[5 + 1] = 0.6;
        mask[5 + 3] = 0.7;
        mask[10 + 2] = 0.9;
        let p = prompt_from_mask(&mask, 5, 4).unwrap();
        assert_eq!(p.bbox, Some([1.0, 1.0, 3.0, 2.0]));
        assert_eq!(p.points, vec![([2.0, 2.0], PointLabel::Positive)]);
        assert_eq!(prompt_from_mask(&[0.5; 20], 5, 4), None);
    }

    #[test]
    fn relative_positions_index_the_table_by_query_minus_key() {
        // n = 3: rows 0..5 of a one-channel table holding their own index.
        let table = Tensor::arange(0f32, 5.0, &Device::Cpu).unwrap().reshape((5, 1)).unwrap();
        let got = rel_pos_table(&table, 3).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        // R[p, q] = table[p − q + 2].
        assert_eq!(got, vec![2.0, 1.0, 0.0, 3.0, 2.0, 1.0, 4.0, 3.0, 2.0]);
        assert!(rel_pos_table(&table, 2).is_err());
    }

    #[test]
    fn windows_partition_and_unpartition_with_padding() {
        let x =
            Tensor::arange(0f32, 2.0 * 5.0 * 4.0 * 3.0, &Device::Cpu).unwrap().reshape((2, 5, 4, 3)).unwrap();
        let (windows, padded) = window_partition(&x, 3).unwrap();
        assert_eq!((windows.dims(), padded), ([2 * 2 * 2, 3, 3, 3].as_slice(), (6, 6)));
        // The second window of the first image holds columns 3.. of rows 0..3 (then padding).
        let w1 = windows.i(1).unwrap();
        assert_eq!(
            w1.i((0, 0)).unwrap().to_vec1::<f32>().unwrap(),
            x.i((0, 0, 3)).unwrap().to_vec1::<f32>().unwrap()
        );
        assert_eq!(w1.i((0, 1)).unwrap().to_vec1::<f32>().unwrap(), vec![0.0; 3]);
        let back = window_unpartition(&windows, 3, padded, (5, 4)).unwrap();
        let diff = (back - &x).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
        assert_eq!(diff, 0.0);
    }

    #[test]
    fn attention_in_blocks_of_query_rows_equals_attention_at_once() {
        let device = Device::Cpu;
        let config = SamVisionConfig { hidden_size: 8, num_attention_heads: 2, ..Default::default() };
        let (c, side, d) = (8, 5, 4);
        let values = |n: usize, f: f32| -> Tensor {
            Tensor::from_vec((0..n).map(|i| ((i as f32 + 1.0) * f).sin()).collect::<Vec<f32>>(), n, &device)
                .unwrap()
        };
        let tensors = [
            ("qkv.weight", values(3 * c * c, 0.37).reshape((3 * c, c)).unwrap()),
            ("qkv.bias", values(3 * c, 0.11)),
            ("proj.weight", values(c * c, 0.23).reshape((c, c)).unwrap()),
            ("proj.bias", values(c, 0.53)),
            ("rel_pos_h", values((2 * side - 1) * d, 0.71).reshape((2 * side - 1, d)).unwrap()),
            ("rel_pos_w", values((2 * side - 1) * d, 0.29).reshape((2 * side - 1, d)).unwrap()),
        ];
        let vb = VarBuilder::from_tensors(
            tensors.into_iter().map(|(k, v)| (k.to_string(), v)).collect(),
            DType::F32,
            &device,
        );
        let mut attention = VisionAttention::new(vb, &config, side).unwrap();
        let x = values(2 * side * side * c, 0.13).reshape((2, side, side, c)).unwrap();
        let at_once = attention.forward(&x).unwrap();
        // 2 windows × 2 heads at once, 25 keys a row: blocks of 3 query rows, the last short.
        attention.budget = 4 * 25 * 3;
        let blocked = attention.forward(&x).unwrap();
        let scale = at_once.abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
        let diff = (at_once - blocked).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
        assert!(diff <= 1e-5 * scale, "{diff} of {scale}");
    }

    #[test]
    fn the_processor_keeps_the_aspect_ratio() {
        assert_eq!(resized_size(50, 37, 64), (64, 47));
        assert_eq!(resized_size(256, 256, 1024), (1024, 1024));
        assert_eq!(resized_size(1000, 1, 64), (64, 1));
    }
}

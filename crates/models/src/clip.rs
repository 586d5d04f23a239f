//! CLIP text and vision towers in the Hugging Face `CLIPModel` / `CLIPTextModel` layout
//! (`openai/clip-vit-large-patch14`, `openai/clip-vit-base-patch32`, the `text_encoder/`
//! of Stable Diffusion and InstructPix2Pix), and the image preprocessing of the
//! Instruct-NeRF2NeRF `ClipSimilarity` protocol.
//!
//! Both towers are pre-norm transformers: `x + attn(ln1(x))`, then `x + mlp(ln2(x))`, the
//! MLP `fc2(act(fc1(x)))` with `act` from `hidden_act` (`quick_gelu`, `gelu`,
//! `gelu_new`). The text tower adds learned positions, masks attention causally, ends with
//! `final_layer_norm` and pools the hidden state at the first `<|endoftext|>` (or, for
//! configs with the legacy `eos_token_id = 2`, at the largest id). The vision tower embeds
//! `patch × patch` patches, prepends the class embedding, adds positions, applies
//! `pre_layrnorm`, the encoder, and `post_layernorm` to the class token. The projections
//! (`text_projection`, `visual_projection`) have no bias.

use candle_core::{DType, Device, Module, Tensor, D};
use candle_nn::{layer_norm, linear, linear_no_bias, Embedding, LayerNorm, Linear, VarBuilder};
use serde::Deserialize;

use crate::check::{self, ModelConfig};
use crate::resample;
use crate::tokenizer::{ClipTokenizer, CONTEXT_LENGTH, END_OF_TEXT};
use crate::{Error, ModelDir};

/// Download command for the CLIP the evaluation protocol uses.
pub const CLIP_HINT: &str = "hf download openai/clip-vit-large-patch14 --local-dir DIR";

/// CLIP's image normalisation (mean and standard deviation per RGB channel).
pub const CLIP_MEAN: [f32; 3] = [0.481_454_66, 0.457_827_5, 0.408_210_73];
/// See [`CLIP_MEAN`].
pub const CLIP_STD: [f32; 3] = [0.268_629_54, 0.261_302_6, 0.275_777_1];

fn default_act() -> String {
    "quick_gelu".to_string()
}
fn default_eps() -> f64 {
    1e-5
}
fn default_eos() -> u32 {
    END_OF_TEXT
}
fn default_projection() -> usize {
    512
}
fn default_channels() -> usize {
    3
}

/// `text_config` of a `CLIPModel`, or the whole config of a `CLIPTextModel`.
#[derive(Debug, Clone, Deserialize)]
pub struct ClipTextConfig {
    pub vocab_size: usize,
    pub hidden_size: usize,
    pub intermediate_size: usize,
    pub num_hidden_layers: usize,
    pub num_attention_heads: usize,
    pub max_position_embeddings: usize,
    #[serde(default = "default_act")]
    pub hidden_act: String,
    #[serde(default = "default_eps")]
    pub layer_norm_eps: f64,
    #[serde(default = "default_eos")]
    pub eos_token_id: u32,
    #[serde(default = "default_projection")]
    pub projection_dim: usize,
}

/// `vision_config` of a `CLIPModel`.
#[derive(Debug, Clone, Deserialize)]
pub struct ClipVisionConfig {
    pub hidden_size: usize,
    pub intermediate_size: usize,
    pub num_hidden_layers: usize,
    pub num_attention_heads: usize,
    pub image_size: usize,
    pub patch_size: usize,
    #[serde(default = "default_channels")]
    pub num_channels: usize,
    #[serde(default = "default_act")]
    pub hidden_act: String,
    #[serde(default = "default_eps")]
    pub layer_norm_eps: f64,
}

/// `config.json` of a `CLIPModel`.
#[derive(Debug, Clone, Deserialize)]
pub struct ClipConfig {
    pub text_config: ClipTextConfig,
    pub vision_config: ClipVisionConfig,
    #[serde(default = "default_projection")]
    pub projection_dim: usize,
}

/// The transformer sizes both towers share: width, heads dividing it, MLP width, depth.
fn check_tower(
    hidden: usize,
    heads: usize,
    intermediate: usize,
    layers: usize,
    eps: f64,
    act: &str,
) -> Result<(), String> {
    Activation::named(act)?;
    check::size("hidden_size", hidden)?;
    check::divides("hidden_size", hidden, "num_attention_heads", heads)?;
    check::size("intermediate_size", intermediate)?;
    check::layers("num_hidden_layers", layers)?;
    check::positive("layer_norm_eps", eps)
}

impl ModelConfig for ClipTextConfig {
    fn check(&self) -> Result<(), String> {
        check_tower(
            self.hidden_size,
            self.num_attention_heads,
            self.intermediate_size,
            self.num_hidden_layers,
            self.layer_norm_eps,
            &self.hidden_act,
        )?;
        check::size("vocab_size", self.vocab_size)?;
        check::size("max_position_embeddings", self.max_position_embeddings)?;
        check::size("projection_dim", self.projection_dim)?;
        if self.eos_token_id as usize >= self.vocab_size {
            return Err(format!(
                "eos_token_id {} is outside vocab_size {}",
                self.eos_token_id, self.vocab_size
            ));
        }
        Ok(())
    }
}

impl ModelConfig for ClipVisionConfig {
    fn check(&self) -> Result<(), String> {
        check_tower(
            self.hidden_size,
            self.num_attention_heads,
            self.intermediate_size,
            self.num_hidden_layers,
            self.layer_norm_eps,
            &self.hidden_act,
        )?;
        check::size("num_channels", self.num_channels)?;
        check::size("patch_size", self.patch_size)?;
        check::size("image_size", self.image_size)?;
        if self.image_size < self.patch_size {
            return Err(format!("image_size {} is below patch_size {}", self.image_size, self.patch_size));
        }
        Ok(())
    }
}

impl ModelConfig for ClipConfig {
    fn check(&self) -> Result<(), String> {
        self.text_config.check().map_err(|m| format!("text_config: {m}"))?;
        self.vision_config.check().map_err(|m| format!("vision_config: {m}"))?;
        check::size("projection_dim", self.projection_dim)
    }
}

#[derive(Debug, Clone, Copy)]
pub(crate) enum Activation {
    QuickGelu,
    GeluErf,
    GeluTanh,
    Relu,
}

impl Activation {
    fn parse(name: &str, path: &std::path::Path) -> Result<Self, Error> {
        Self::named(name).map_err(|msg| Error::Corrupt { path: path.to_path_buf(), msg })
    }

    pub(crate) fn named(name: &str) -> Result<Self, String> {
        match name {
            "quick_gelu" => Ok(Self::QuickGelu),
            "gelu" => Ok(Self::GeluErf),
            "gelu_new" | "gelu_pytorch_tanh" => Ok(Self::GeluTanh),
            "relu" => Ok(Self::Relu),
            other => Err(format!("unsupported hidden_act {other:?}")),
        }
    }

    pub(crate) fn apply(self, x: &Tensor) -> candle_core::Result<Tensor> {
        match self {
            // x · sigmoid(1.702 x)
            Self::QuickGelu => x * candle_nn::ops::sigmoid(&(x * 1.702)?)?,
            Self::GeluErf => x.gelu_erf(),
            Self::GeluTanh => x.gelu(),
            Self::Relu => x.relu(),
        }
    }
}

/// Multi-head attention with separate q/k/v/out projections (all with bias): CLIP's and
/// DINOv2's self-attention (same computation, other weight names), and SAM's mask-decoder
/// attention (queries, keys and values from different inputs, projected to a narrower
/// width).
#[derive(Debug, Clone)]
pub(crate) struct Attention {
    q: Linear,
    k: Linear,
    v: Linear,
    out: Linear,
    heads: usize,
}

impl Attention {
    pub(crate) fn new(vb: VarBuilder, dim: usize, heads: usize) -> candle_core::Result<Self> {
        Self::with_width(vb, dim, dim, heads)
    }

    /// Projections from `dim` to `inner` channels (q, k, v) and back (out).
    pub(crate) fn with_width(
        vb: VarBuilder,
        dim: usize,
        inner: usize,
        heads: usize,
    ) -> candle_core::Result<Self> {
        Ok(Self {
            q: linear(dim, inner, vb.pp("q_proj"))?,
            k: linear(dim, inner, vb.pp("k_proj"))?,
            v: linear(dim, inner, vb.pp("v_proj"))?,
            out: linear(inner, dim, vb.pp("out_proj"))?,
            heads,
        })
    }

    /// From its four projections.
    pub(crate) fn from_parts(q: Linear, k: Linear, v: Linear, out: Linear, heads: usize) -> Self {
        Self { q, k, v, out, heads }
    }

    /// Self-attention of `x` `[B, N, dim]`; `mask` is added to the attention logits
    /// (`[seq, seq]`, `-inf` where masked).
    pub(crate) fn forward(&self, x: &Tensor, mask: Option<&Tensor>) -> candle_core::Result<Tensor> {
        self.attend(x, x, x, mask)
    }

    /// Queries from `queries` `[B, N, dim]`, keys and values from `keys` and `values`
    /// `[B, M, dim]`: softmax(q kᵀ / √d) v per head, then the output projection.
    pub(crate) fn attend(
        &self,
        queries: &Tensor,
        keys: &Tensor,
        values: &Tensor,
        mask: Option<&Tensor>,
    ) -> candle_core::Result<Tensor> {
        let (b, n, _) = queries.dims3()?;
        let m = keys.dim(1)?;
        let q = self.q.forward(queries)?;
        let inner = q.dim(2)?;
        let hd = inner / self.heads;
        let split =
            |t: Tensor, len: usize| t.reshape((b, len, self.heads, hd))?.transpose(1, 2)?.contiguous();
        let q = split((q * (hd as f64).powf(-0.5))?, n)?;
        let k = split(self.k.forward(keys)?, m)?;
        let v = split(self.v.forward(values)?, m)?;
        let mut logits = q.matmul(&k.t()?.contiguous()?)?;
        if let Some(mask) = mask {
            logits = logits.broadcast_add(mask)?;
        }
        let probs = candle_nn::ops::softmax_last_dim(&logits)?;
        let y = probs.matmul(&v)?.transpose(1, 2)?.reshape((b, n, inner))?;
        self.out.forward(&y)
    }
}

/// One pre-norm transformer layer.
#[derive(Debug, Clone)]
struct EncoderLayer {
    ln1: LayerNorm,
    attn: Attention,
    ln2: LayerNorm,
    fc1: Linear,
    fc2: Linear,
    act: Activation,
}

/// The shape parameters shared by both towers.
struct Dims {
    hidden: usize,
    intermediate: usize,
    heads: usize,
    layers: usize,
    eps: f64,
    act: Activation,
}

fn encoder(vb: VarBuilder, d: &Dims) -> candle_core::Result<Vec<EncoderLayer>> {
    (0..d.layers)
        .map(|i| {
            let vb = vb.pp(format!("layers.{i}"));
            Ok(EncoderLayer {
                ln1: layer_norm(d.hidden, d.eps, vb.pp("layer_norm1"))?,
                attn: Attention::new(vb.pp("self_attn"), d.hidden, d.heads)?,
                ln2: layer_norm(d.hidden, d.eps, vb.pp("layer_norm2"))?,
                fc1: linear(d.hidden, d.intermediate, vb.pp("mlp.fc1"))?,
                fc2: linear(d.intermediate, d.hidden, vb.pp("mlp.fc2"))?,
                act: d.act,
            })
        })
        .collect()
}

fn run_encoder(layers: &[EncoderLayer], mut x: Tensor, mask: Option<&Tensor>) -> candle_core::Result<Tensor> {
    for l in layers {
        x = (&x + l.attn.forward(&l.ln1.forward(&x)?, mask)?)?;
        let h = l.fc2.forward(&l.act.apply(&l.fc1.forward(&l.ln2.forward(&x)?)?)?)?;
        x = (x + h)?;
    }
    Ok(x)
}

/// The CLIP text tower (`text_model.*`), optionally with its projection.
#[derive(Debug, Clone)]
pub struct ClipTextModel {
    token_embedding: Embedding,
    position_embedding: Tensor,
    layers: Vec<EncoderLayer>,
    final_ln: LayerNorm,
    projection: Option<Linear>,
    eos_token_id: u32,
    config: ClipTextConfig,
    device: Device,
}

/// Output of the text tower.
#[derive(Debug, Clone)]
pub struct TextOutput {
    /// `[batch, seq, hidden]` after `final_layer_norm` (what Stable Diffusion conditions on).
    pub last_hidden_state: Tensor,
    /// `[batch, hidden]`: the hidden state at each sequence's `<|endoftext|>`.
    pub pooled: Tensor,
}

/// The text config from a `CLIPModel` config (`text_config`) or a `CLIPTextModel` config.
fn text_config(dir: &ModelDir) -> Result<ClipTextConfig, Error> {
    let value = dir.json("config.json")?;
    let text = value.get("text_config").cloned().unwrap_or(value);
    dir.checked("config.json", text)
}

impl ClipTextModel {
    /// Loads the text tower from a folder holding `config.json` and `model.safetensors` of a
    /// `CLIPTextModel` (e.g. `text_encoder/`) or of a whole `CLIPModel`.
    pub fn load(dir: &ModelDir, device: &Device) -> Result<Self, Error> {
        let config = text_config(dir)?;
        let vb = dir.var_builder("model", DType::F32, device)?;
        dir.build(|| Self::new(vb, config, &dir.path.join("config.json")))
    }

    /// Builds the tower from weights under `text_model.*` (the hub checkpoints, e.g.
    /// Stable Diffusion's `text_encoder/`) or at the root (how transformers 5 saves a
    /// `CLIPTextModel`), and `text_projection` if present.
    pub fn new(vb: VarBuilder, config: ClipTextConfig, config_path: &std::path::Path) -> Result<Self, Error> {
        let act = Activation::parse(&config.hidden_act, config_path)?;
        let dims = Dims {
            hidden: config.hidden_size,
            intermediate: config.intermediate_size,
            heads: config.num_attention_heads,
            layers: config.num_hidden_layers,
            eps: config.layer_norm_eps,
            act,
        };
        let projection = if vb.contains_tensor("text_projection.weight") {
            Some(linear_no_bias(config.hidden_size, config.projection_dim, vb.pp("text_projection"))?)
        } else {
            None
        };
        let tm = if vb.contains_tensor("text_model.embeddings.token_embedding.weight") {
            vb.pp("text_model")
        } else {
            vb.clone()
        };
        let emb = tm.pp("embeddings");
        let token_embedding = Embedding::new(
            emb.get((config.vocab_size, config.hidden_size), "token_embedding.weight")?,
            config.hidden_size,
        );
        let position_embedding =
            emb.get((config.max_position_embeddings, config.hidden_size), "position_embedding.weight")?;
        let layers = encoder(tm.pp("encoder"), &dims)?;
        let final_ln = layer_norm(config.hidden_size, config.layer_norm_eps, tm.pp("final_layer_norm"))?;
        Ok(Self {
            token_embedding,
            position_embedding,
            layers,
            final_ln,
            projection,
            eos_token_id: config.eos_token_id,
            device: vb.device().clone(),
            config,
        })
    }

    /// The configuration read from `config.json`.
    pub fn config(&self) -> &ClipTextConfig {
        &self.config
    }

    /// Runs the tower on `ids` (`batch` rows of equal length, at most
    /// `max_position_embeddings`).
    pub fn forward(&self, ids: &[Vec<u32>]) -> Result<TextOutput, Error> {
        let b = ids.len();
        let n = ids.first().map_or(0, Vec::len);
        if b == 0 || n == 0 || n > self.config.max_position_embeddings || ids.iter().any(|r| r.len() != n) {
            return Err(candle_core::Error::Msg(format!(
                "CLIP text: {b} sequences of length {n}; need equal lengths in 1..={}",
                self.config.max_position_embeddings
            ))
            .into());
        }
        let flat: Vec<u32> = ids.concat();
        let input = Tensor::from_vec(flat, (b, n), &self.device)?;
        let x =
            self.token_embedding.forward(&input)?.broadcast_add(&self.position_embedding.narrow(0, 0, n)?)?;
        let mask: Vec<f32> =
            (0..n * n).map(|k| if k % n > k / n { f32::NEG_INFINITY } else { 0.0 }).collect();
        let mask = Tensor::from_vec(mask, (n, n), &self.device)?;
        let x = run_encoder(&self.layers, x, Some(&mask))?;
        let last_hidden_state = self.final_ln.forward(&x)?;
        let rows = ids
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let at = if self.eos_token_id == 2 {
                    // Legacy configs: the end token has the largest id (first maximum).
                    r.iter().enumerate().fold(0, |best, (k, &t)| if t > r[best] { k } else { best })
                } else {
                    r.iter().position(|&t| t == self.eos_token_id).unwrap_or(0)
                };
                last_hidden_state.get(i)?.get(at)
            })
            .collect::<candle_core::Result<Vec<_>>>()?;
        let pooled = Tensor::stack(&rows, 0)?;
        Ok(TextOutput { last_hidden_state, pooled })
    }

    /// Projected pooled output `[batch, projection_dim]` (needs `text_projection`).
    pub fn project(&self, pooled: &Tensor) -> Result<Tensor, Error> {
        match &self.projection {
            Some(p) => Ok(p.forward(pooled)?),
            None => Err(candle_core::Error::Msg("this CLIP text model has no text_projection".into()).into()),
        }
    }
}

/// The CLIP vision tower (`vision_model.*`); also CLIPSeg's backbone.
#[derive(Debug, Clone)]
pub(crate) struct ClipVisionModel {
    class_embedding: Tensor,
    patch_embedding: Tensor,
    /// `[1 + n², hidden]` position embeddings of the native `n × n` patch grid.
    position_embedding: Tensor,
    /// `n`: the side of the native patch grid (`image_size / patch_size`).
    native_grid: usize,
    pre_ln: LayerNorm,
    layers: Vec<EncoderLayer>,
    post_ln: LayerNorm,
    patch: usize,
}

impl ClipVisionModel {
    pub(crate) fn new(
        vb: VarBuilder,
        c: &ClipVisionConfig,
        config_path: &std::path::Path,
    ) -> Result<Self, Error> {
        let dims = Dims {
            hidden: c.hidden_size,
            intermediate: c.intermediate_size,
            heads: c.num_attention_heads,
            layers: c.num_hidden_layers,
            eps: c.layer_norm_eps,
            act: Activation::parse(&c.hidden_act, config_path)?,
        };
        let emb = vb.pp("embeddings");
        let grid = c.image_size / c.patch_size;
        Ok(Self {
            class_embedding: emb.get(c.hidden_size, "class_embedding")?,
            patch_embedding: emb
                .get((c.hidden_size, c.num_channels, c.patch_size, c.patch_size), "patch_embedding.weight")?,
            position_embedding: emb.get((grid * grid + 1, c.hidden_size), "position_embedding.weight")?,
            native_grid: grid,
            pre_ln: layer_norm(c.hidden_size, c.layer_norm_eps, vb.pp("pre_layrnorm"))?,
            layers: encoder(vb.pp("encoder"), &dims)?,
            post_ln: layer_norm(c.hidden_size, c.layer_norm_eps, vb.pp("post_layernorm"))?,
            patch: c.patch_size,
        })
    }

    /// The tokens entering the encoder, `[batch, 1 + gh·gw, hidden]`, of normalised
    /// `[batch, 3, gh·patch, gw·patch]` pixels: patch embeddings after the class embedding,
    /// plus positions, then `pre_layrnorm`. A grid other than the native square gets the
    /// native position grid resized bicubically (transformers' `interpolate_pos_encoding`).
    fn embed(&self, pixels: &Tensor) -> candle_core::Result<Tensor> {
        let b = pixels.dim(0)?;
        let patches = pixels.conv2d(&self.patch_embedding, 0, self.patch, 1, 1)?; // [b, d, gh, gw]
        let (_, d, gh, gw) = patches.dims4()?;
        let patches = patches.flatten_from(2)?.transpose(1, 2)?; // [b, gh·gw, d]
        let cls = self.class_embedding.reshape((1, 1, d))?.broadcast_as((b, 1, d))?;
        let positions = resample::position_grid(&self.position_embedding, self.native_grid, gh, gw)?;
        let x = Tensor::cat(&[&cls, &patches], 1)?.broadcast_add(&positions)?;
        self.pre_ln.forward(&x)
    }

    /// Pooled (class-token) output `[batch, hidden]` of normalised `[batch, 3, size, size]` pixels.
    fn forward(&self, pixels: &Tensor) -> candle_core::Result<Tensor> {
        let x = run_encoder(&self.layers, self.embed(pixels)?, None)?;
        self.post_ln.forward(&x.narrow(1, 0, 1)?.squeeze(1)?)
    }

    /// The outputs `[batch, 1 + gh·gw, hidden]` of the encoder layers numbered in `layers`
    /// (0 is the first layer; transformers' `hidden_states[i + 1]`), in that order. Layers
    /// after the deepest one asked for are not run.
    pub(crate) fn layer_outputs(
        &self,
        pixels: &Tensor,
        layers: &[usize],
    ) -> candle_core::Result<Vec<Tensor>> {
        let Some(&deepest) = layers.iter().max() else { return Ok(Vec::new()) };
        if deepest >= self.layers.len() {
            candle_core::bail!("vision layer {deepest} asked for; the tower has {}", self.layers.len());
        }
        let mut x = self.embed(pixels)?;
        let mut outputs = Vec::with_capacity(deepest + 1);
        for layer in &self.layers[..=deepest] {
            x = run_encoder(std::slice::from_ref(layer), x, None)?;
            outputs.push(x.clone());
        }
        Ok(layers.iter().map(|&i| outputs[i].clone()).collect())
    }
}

/// A whole CLIP model: both towers, their projections, the tokenizer and the
/// `ClipSimilarity` image preprocessing.
#[derive(Debug)]
pub struct Clip {
    text: ClipTextModel,
    vision: ClipVisionModel,
    visual_projection: Linear,
    tokenizer: ClipTokenizer,
    image_size: usize,
    device: Device,
}

impl Clip {
    /// Loads a `CLIPModel` folder (`config.json`, `model.safetensors`).
    pub fn load(dir: &ModelDir, device: &Device) -> Result<Self, Error> {
        let config: ClipConfig = dir.config("config.json")?;
        let vb = dir.var_builder("model", DType::F32, device)?;
        if !vb.contains_tensor("visual_projection.weight") {
            return Err(Error::Corrupt {
                path: dir.path.clone(),
                msg: "no visual_projection weights: this is not a full CLIPModel (text and vision)".into(),
            });
        }
        dir.build(|| Self::new(vb, &config, &dir.path.join("config.json")))
    }

    /// Builds the model from weights in the `CLIPModel` layout.
    pub fn new(vb: VarBuilder, config: &ClipConfig, config_path: &std::path::Path) -> Result<Self, Error> {
        let mut text_config = config.text_config.clone();
        text_config.projection_dim = config.projection_dim;
        let mut text = ClipTextModel::new(vb.clone(), text_config, config_path)?;
        // A whole CLIPModel always has its text projection.
        text.projection = Some(linear_no_bias(
            config.text_config.hidden_size,
            config.projection_dim,
            vb.pp("text_projection"),
        )?);
        let vc = &config.vision_config;
        let vision = ClipVisionModel::new(vb.pp("vision_model"), vc, config_path)?;
        let visual_projection =
            linear_no_bias(vc.hidden_size, config.projection_dim, vb.pp("visual_projection"))?;
        Ok(Self {
            text,
            vision,
            visual_projection,
            tokenizer: ClipTokenizer::bundled(),
            image_size: vc.image_size,
            device: vb.device().clone(),
        })
    }

    /// Side of the square input the vision tower takes (224 for ViT-L/14).
    pub fn image_size(&self) -> usize {
        self.image_size
    }

    /// The text tower.
    pub fn text_model(&self) -> &ClipTextModel {
        &self.text
    }

    /// `ClipSimilarity` preprocessing of one `H × W × 3` image in [0, 1]: bicubic resize
    /// to `size × size` without centre crop (torch `interpolate`, `align_corners=False`),
    /// then CLIP mean/std. Returns planar `3 × size × size`.
    pub fn preprocess(&self, rgb: &[f32], width: usize, height: usize) -> Vec<f32> {
        preprocess(rgb, width, height, self.image_size)
    }

    /// Projected image features `[n, projection_dim]` (not normalised) of preprocessed
    /// planar images, each `3 × size × size`.
    pub fn image_features_preprocessed(&self, planar: &[Vec<f32>]) -> Result<Tensor, Error> {
        let s = self.image_size;
        let flat: Vec<f32> = planar.concat();
        let pixels = Tensor::from_vec(flat, (planar.len(), 3, s, s), &self.device)?;
        Ok(self.visual_projection.forward(&self.vision.forward(&pixels)?)?)
    }

    /// Projected image features `[n, projection_dim]` (not normalised) of `H × W × 3`
    /// images in [0, 1], each given with its width and height.
    pub fn image_features(&self, images: &[(&[f32], usize, usize)]) -> Result<Tensor, Error> {
        let planar: Vec<Vec<f32>> = images.iter().map(|&(rgb, w, h)| self.preprocess(rgb, w, h)).collect();
        self.image_features_preprocessed(&planar)
    }

    /// Projected text features `[n, projection_dim]` (not normalised) of prompts, each
    /// tokenized to 77 tokens (truncated, padded with `<|endoftext|>`).
    pub fn text_features(&self, prompts: &[&str]) -> Result<Tensor, Error> {
        let ids: Vec<Vec<u32>> = prompts
            .iter()
            .map(|p| {
                self.tokenizer.encode_padded(
                    p,
                    CONTEXT_LENGTH.min(self.text.config.max_position_embeddings),
                    END_OF_TEXT,
                )
            })
            .collect();
        self.text_features_ids(&ids)
    }

    /// Projected text features of already tokenized prompts.
    pub fn text_features_ids(&self, ids: &[Vec<u32>]) -> Result<Tensor, Error> {
        let out = self.text.forward(ids)?;
        self.text.project(&out.pooled)
    }
}

/// See [`Clip::preprocess`].
pub fn preprocess(rgb: &[f32], width: usize, height: usize, size: usize) -> Vec<f32> {
    let planar = resample::hwc_to_chw(rgb, height, width, 3);
    let mut out = resample::bicubic(&planar, 3, height, width, size, size);
    for (c, plane) in out.chunks_exact_mut(size * size).enumerate() {
        for v in plane {
            *v = (*v - CLIP_MEAN[c]) / CLIP_STD[c];
        }
    }
    out
}

/// Rows of `x` divided by their L2 norms.
pub fn l2_normalize(x: &Tensor) -> candle_core::Result<Tensor> {
    x.broadcast_div(&x.sqr()?.sum_keepdim(D::Minus1)?.sqrt()?)
}

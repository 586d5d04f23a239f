//! CLIPSeg: a text-grounded segmenter (Lüddecke & Ecker, "Image Segmentation Using Text
//! and Image Prompts", CVPR 2022), in the Hugging Face `CLIPSegForImageSegmentation`
//! layout of `CIDAS/clipseg-rd64-refined` (transformers' `models/clipseg`, the reference
//! this port is proven against by `tests/clipseg_parity.rs`).
//!
//! What it is for: the segmentation constraint of the edit region (issue #43). The
//! paper restricts the edited Gaussians of view v to Ω_v = {Ā_v ≥ δ_a} ∩ M_sam^v, the
//! thresholded edit attention intersected with a mask of the object the prompt names;
//! [`ClipSeg::segment`] gives that mask's probabilities for a view and a prompt.
//!
//! The model, for a query image and a prompt:
//! 1. the prompt through the CLIP text tower ([`ClipTextModel`]), pooled at its end token
//!    and projected by `text_projection`: the conditional embedding c (`projection_dim`);
//! 2. the image (resized to the processor's square size, 352, and normalised with the
//!    ImageNet mean / std) through the CLIP vision tower; its position embeddings, learnt
//!    for `image_size` (224), are resized bicubically to the input's patch grid (22 × 22
//!    for 352 and patch 16), as transformers does for every input size. The decoder reads
//!    the hidden states a_k after the encoder layers listed in `extract_layers` (layer
//!    outputs, 0-based; layers after the deepest are not run);
//! 3. the decoder walks those activations from the deepest up, keeping one stream h of
//!    width `reduce_dim`: at step i, h ← R_i(a_{K−1−i}) + h (h = 0 at the first step; R_i
//!    the `reduces` linear layers); at step `conditional_layer` the stream is modulated
//!    by FiLM, h ← W_mul(c) ⊙ h + W_add(c) for every token (`film_mul`, `film_add`); then
//!    the decoder layer i, a post-norm transformer layer: h ← LN1(h + Attn(h)),
//!    h ← LN2(h + fc2(ReLU(fc1(h)))) (ReLU whatever `decoder_hidden_act` says, as in the
//!    reference; `decoder_num_attention_heads`, `decoder_intermediate_size`, the vision
//!    tower's layer-norm epsilon);
//! 4. the patch tokens of h (the class token dropped), as a `reduce_dim × g × g` map, are
//!    upsampled to one logit per pixel by `transposed_convolution`: a transposed
//!    convolution with kernel and stride `patch_size`, or with
//!    `use_complex_transposed_convolution` a 3 × 3 convolution, ReLU, a transposed
//!    convolution to `reduce_dim / 2` channels with kernel and stride `patch_size / 4`,
//!    ReLU, and another to one channel with the same kernel (×16 in all for patch 16);
//! 5. [`ClipSeg::segment`] applies the sigmoid and resizes the probabilities to the
//!    image's own size.
//!
//! Both resizes are bilinear with antialiasing (`transsplat_editors::resize_bilinear`),
//! which is what `ViTImageProcessor` does to a float image (torchvision's `resize`,
//! `antialias=True`); the fixture proves it equals torch's `interpolate(mode="bilinear",
//! antialias=True)` on both the way in and the way out.

use std::path::Path;

use candle_core::{DType, Device, Module, Tensor};
use candle_nn::{layer_norm, linear, linear_no_bias, Conv2dConfig, LayerNorm, Linear, VarBuilder};
use serde::Deserialize;
use serde_json::{json, Value};

use crate::check::{self, ModelConfig};
use crate::clip::{Attention, ClipTextConfig, ClipTextModel, ClipVisionConfig, ClipVisionModel};
use crate::conv::{self, Conv2d, PatchTransposedConv};
use crate::dinov2::{IMAGENET_MEAN, IMAGENET_STD};
use crate::resample;
use crate::tokenizer::{ClipTokenizer, END_OF_TEXT};
use crate::{Error, ModelDir};
use transsplat_editors::{Error as EditorError, Segmenter, SourceView};

/// Download command for the CLIPSeg weights.
pub const CLIPSEG_HINT: &str = "hf download CIDAS/clipseg-rd64-refined --local-dir DIR";

/// [`CLIPSEG_HINT`] for the folder `dir`.
pub fn download_hint(dir: &Path) -> String {
    CLIPSEG_HINT.replace("DIR", &dir.display().to_string())
}

/// Views segmented per forward pass by [`ClipSeg::segment_many`] (a batch of 352² inputs
/// through ViT-B/16 needs about 60 MB of activations per view).
pub const SEGMENT_BATCH: usize = 4;

/// The processor's square input side when the folder has no `preprocessor_config.json`
/// (352, as `CIDAS/clipseg-rd64-refined`'s).
pub const DEFAULT_INPUT_SIZE: usize = 352;

/// Largest processor input side accepted (the model's cost grows with its square).
pub const MAX_INPUT_SIZE: usize = 4096;

fn default_projection() -> usize {
    512
}
fn default_extract_layers() -> Vec<usize> {
    vec![3, 6, 9]
}
fn default_reduce_dim() -> usize {
    64
}
fn default_decoder_heads() -> usize {
    4
}
fn default_decoder_intermediate() -> usize {
    2048
}

/// `config.json` of a `CLIPSegForImageSegmentation`. Tower fields the file leaves out
/// take the defaults of transformers' `CLIPSegTextConfig` / `CLIPSegVisionConfig`, and
/// the legacy `text_config_dict` / `vision_config_dict` override them, as transformers
/// reads such files (see [`ClipSegConfig::resolve`]).
#[derive(Debug, Clone, Deserialize)]
pub struct ClipSegConfig {
    pub text_config: ClipTextConfig,
    pub vision_config: ClipVisionConfig,
    #[serde(default = "default_projection")]
    pub projection_dim: usize,
    /// Vision layers (0-based) whose outputs the decoder reads, shallow to deep.
    #[serde(default = "default_extract_layers")]
    pub extract_layers: Vec<usize>,
    #[serde(default = "default_reduce_dim")]
    pub reduce_dim: usize,
    #[serde(default = "default_decoder_heads")]
    pub decoder_num_attention_heads: usize,
    #[serde(default = "default_decoder_intermediate")]
    pub decoder_intermediate_size: usize,
    /// The decoder step (0 = the first, on the deepest activation) that applies FiLM.
    #[serde(default)]
    pub conditional_layer: usize,
    #[serde(default)]
    pub use_complex_transposed_convolution: bool,
}

impl ClipSegConfig {
    /// The raw `config.json` with each tower's config completed: transformers' defaults,
    /// then `text_config` / `vision_config`, then `text_config_dict` / `vision_config_dict`.
    pub fn resolve(mut value: Value) -> Value {
        let towers = [
            ("text_config", "text_config_dict", text_defaults()),
            ("vision_config", "vision_config_dict", vision_defaults()),
        ];
        if let Value::Object(root) = &mut value {
            for (key, legacy_key, mut tower) in towers {
                for source in [root.get(key), root.get(legacy_key)].into_iter().flatten() {
                    if let (Value::Object(tower), Value::Object(fields)) = (&mut tower, source) {
                        tower.extend(fields.iter().map(|(k, v)| (k.clone(), v.clone())));
                    }
                }
                root.insert(key.to_string(), tower);
            }
        }
        value
    }

    /// The number of decoder steps (one per extracted layer).
    pub fn depth(&self) -> usize {
        self.extract_layers.len()
    }
}

/// Defaults of transformers' `CLIPSegTextConfig`.
fn text_defaults() -> Value {
    json!({
        "vocab_size": 49408, "hidden_size": 512, "intermediate_size": 2048, "num_hidden_layers": 12,
        "num_attention_heads": 8, "max_position_embeddings": 77, "hidden_act": "quick_gelu",
        "layer_norm_eps": 1e-5, "eos_token_id": 49407
    })
}

/// Defaults of transformers' `CLIPSegVisionConfig`.
fn vision_defaults() -> Value {
    json!({
        "hidden_size": 768, "intermediate_size": 3072, "num_hidden_layers": 12, "num_attention_heads": 12,
        "num_channels": 3, "image_size": 224, "patch_size": 32, "hidden_act": "quick_gelu",
        "layer_norm_eps": 1e-5
    })
}

impl ModelConfig for ClipSegConfig {
    fn check(&self) -> Result<(), String> {
        self.text_config.check().map_err(|m| format!("text_config: {m}"))?;
        self.vision_config.check().map_err(|m| format!("vision_config: {m}"))?;
        check::size("projection_dim", self.projection_dim)?;
        check::size("reduce_dim", self.reduce_dim)?;
        check::divides(
            "reduce_dim",
            self.reduce_dim,
            "decoder_num_attention_heads",
            self.decoder_num_attention_heads,
        )?;
        check::size("decoder_intermediate_size", self.decoder_intermediate_size)?;
        self.check_extract_layers()?;
        if self.use_complex_transposed_convolution {
            let patch = self.vision_config.patch_size;
            if patch < 4 {
                return Err(format!(
                    "use_complex_transposed_convolution needs patch_size of at least 4 (kernels of \
                     patch_size / 4); patch_size is {patch}"
                ));
            }
            if self.reduce_dim < 2 {
                return Err("use_complex_transposed_convolution needs reduce_dim of at least 2".into());
            }
        }
        Ok(())
    }
}

impl ClipSegConfig {
    fn check_extract_layers(&self) -> Result<(), String> {
        let layers = self.vision_config.num_hidden_layers;
        if self.extract_layers.is_empty() || self.extract_layers.len() > check::MAX_LAYERS {
            return Err(format!(
                "extract_layers must list between 1 and {} vision layers",
                check::MAX_LAYERS
            ));
        }
        if let Some((i, l)) = self.extract_layers.iter().enumerate().find(|&(_, &l)| l >= layers) {
            return Err(format!(
                "extract_layers[{i}] is {l}: the vision tower has {layers} layers (0 to {})",
                layers.saturating_sub(1)
            ));
        }
        if self.conditional_layer >= self.depth() {
            return Err(format!(
                "conditional_layer {} is not a decoder step: extract_layers has {} entries",
                self.conditional_layer,
                self.depth()
            ));
        }
        Ok(())
    }
}

/// The processor's `size`: one side, or `{"height", "width"}`.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(untagged)]
pub enum ProcessorSize {
    Side(usize),
    HeightWidth { height: usize, width: usize },
}

fn default_size() -> ProcessorSize {
    ProcessorSize::Side(DEFAULT_INPUT_SIZE)
}
fn default_mean() -> [f32; 3] {
    IMAGENET_MEAN
}
fn default_std() -> [f32; 3] {
    IMAGENET_STD
}
fn default_true() -> bool {
    true
}
fn default_bilinear() -> u32 {
    PIL_BILINEAR
}

/// PIL's code for bilinear resampling, the only one supported.
const PIL_BILINEAR: u32 = 2;

/// `preprocessor_config.json` of `CLIPSegProcessor` (a `ViTImageProcessor`): a square
/// resize and the mean / std normalisation. Without the file: 352 and ImageNet's.
#[derive(Debug, Clone, Deserialize)]
pub struct ClipSegProcessorConfig {
    #[serde(default = "default_size")]
    pub size: ProcessorSize,
    #[serde(default = "default_mean")]
    pub image_mean: [f32; 3],
    #[serde(default = "default_std")]
    pub image_std: [f32; 3],
    #[serde(default = "default_true")]
    pub do_resize: bool,
    #[serde(default = "default_true")]
    pub do_normalize: bool,
    #[serde(default = "default_bilinear")]
    pub resample: u32,
}

impl Default for ClipSegProcessorConfig {
    fn default() -> Self {
        Self {
            size: default_size(),
            image_mean: IMAGENET_MEAN,
            image_std: IMAGENET_STD,
            do_resize: true,
            do_normalize: true,
            resample: PIL_BILINEAR,
        }
    }
}

impl ClipSegProcessorConfig {
    /// The side of the square the image is resized to (its height; [`Self::check`] makes
    /// sure the width is the same).
    pub fn side(&self) -> usize {
        match self.size {
            ProcessorSize::Side(s) => s,
            ProcessorSize::HeightWidth { height, .. } => height,
        }
    }
}

impl ModelConfig for ClipSegProcessorConfig {
    fn check(&self) -> Result<(), String> {
        if !(self.do_resize && self.do_normalize && self.resample == PIL_BILINEAR) {
            return Err(
                "only the processor that resizes bilinearly (resample 2) and normalises is supported".into(),
            );
        }
        if let ProcessorSize::HeightWidth { height, width } = self.size {
            if height != width {
                return Err(format!("size is {height} x {width}: the decoder needs a square input"));
            }
        }
        let side = self.side();
        if side == 0 || side > MAX_INPUT_SIZE {
            return Err(format!("size is {side}: must be between 1 and {MAX_INPUT_SIZE}"));
        }
        for c in 0..3 {
            check::positive(&format!("image_std[{c}]"), self.image_std[c] as f64)?;
            if !self.image_mean[c].is_finite() {
                return Err(format!("image_mean[{c}] is {}: must be finite", self.image_mean[c]));
            }
        }
        Ok(())
    }
}

/// The decoder's `transposed_convolution`, from `reduce_dim` channels to one logit per pixel.
#[derive(Debug)]
enum Upsampler {
    /// One transposed convolution, kernel and stride `patch_size`.
    Simple(PatchTransposedConv),
    /// 3 × 3 convolution, ReLU, transposed convolution to `reduce_dim / 2`, ReLU,
    /// transposed convolution to 1 (kernels and strides `patch_size / 4`).
    Complex { conv: Conv2d, first: PatchTransposedConv, second: PatchTransposedConv },
}

impl Upsampler {
    fn new(vb: VarBuilder, config: &ClipSegConfig) -> candle_core::Result<Self> {
        let (r, patch) = (config.reduce_dim, config.vision_config.patch_size);
        if !config.use_complex_transposed_convolution {
            return Ok(Self::Simple(PatchTransposedConv::new(vb, r, 1, patch)?));
        }
        let same = Conv2dConfig { padding: 1, ..Default::default() };
        Ok(Self::Complex {
            conv: conv::conv2d(r, r, 3, same, vb.pp("0"))?,
            first: PatchTransposedConv::new(vb.pp("2"), r, r / 2, patch / 4)?,
            second: PatchTransposedConv::new(vb.pp("4"), r / 2, 1, patch / 4)?,
        })
    }

    /// `[b, reduce_dim, g, g]` to `[b, 1, G, G]`.
    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        match self {
            Self::Simple(up) => up.forward(x),
            Self::Complex { conv, first, second } => {
                let x = conv.forward(x)?.relu()?;
                second.forward(&first.forward(&x)?.relu()?)
            }
        }
    }
}

/// One decoder layer: post-norm, ReLU MLP.
#[derive(Debug, Clone)]
struct DecoderLayer {
    attn: Attention,
    ln1: LayerNorm,
    fc1: Linear,
    fc2: Linear,
    ln2: LayerNorm,
}

impl DecoderLayer {
    fn new(vb: VarBuilder, config: &ClipSegConfig) -> candle_core::Result<Self> {
        let (width, mlp) = (config.reduce_dim, config.decoder_intermediate_size);
        let eps = config.vision_config.layer_norm_eps;
        Ok(Self {
            attn: Attention::new(vb.pp("self_attn"), width, config.decoder_num_attention_heads)?,
            ln1: layer_norm(width, eps, vb.pp("layer_norm1"))?,
            fc1: linear(width, mlp, vb.pp("mlp.fc1"))?,
            fc2: linear(mlp, width, vb.pp("mlp.fc2"))?,
            ln2: layer_norm(width, eps, vb.pp("layer_norm2"))?,
        })
    }

    /// h ← LN1(h + Attn(h)), then h ← LN2(h + fc2(ReLU(fc1(h)))).
    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let x = self.ln1.forward(&(x + self.attn.forward(x, None)?)?)?;
        let mlp = self.fc2.forward(&self.fc1.forward(&x)?.relu()?)?;
        self.ln2.forward(&(x + mlp)?)
    }
}

/// The CLIPSeg decoder (`decoder.*`).
#[derive(Debug)]
struct Decoder {
    film_mul: Linear,
    film_add: Linear,
    reduces: Vec<Linear>,
    layers: Vec<DecoderLayer>,
    upsampler: Upsampler,
    conditional_layer: usize,
}

impl Decoder {
    fn new(vb: VarBuilder, config: &ClipSegConfig) -> candle_core::Result<Self> {
        let (r, hidden) = (config.reduce_dim, config.vision_config.hidden_size);
        let steps = 0..config.depth();
        Ok(Self {
            film_mul: linear(config.projection_dim, r, vb.pp("film_mul"))?,
            film_add: linear(config.projection_dim, r, vb.pp("film_add"))?,
            reduces: steps
                .clone()
                .map(|i| linear(hidden, r, vb.pp(format!("reduces.{i}"))))
                .collect::<Result<_, _>>()?,
            layers: steps
                .map(|i| DecoderLayer::new(vb.pp(format!("layers.{i}")), config))
                .collect::<Result<_, _>>()?,
            upsampler: Upsampler::new(vb.pp("transposed_convolution"), config)?,
            conditional_layer: config.conditional_layer,
        })
    }

    /// The stream after the last decoder layer as a `[b, reduce_dim, g, g]` map of the
    /// patch tokens, from the extracted activations (shallow to deep, each
    /// `[b, 1 + g², hidden]`) and the conditional embeddings `[b, projection_dim]`.
    fn features(&self, activations: &[Tensor], conditional: &Tensor) -> candle_core::Result<Tensor> {
        let mut stream: Option<Tensor> = None;
        let deep_first = activations.iter().rev();
        for (step, ((activation, reduce), layer)) in
            deep_first.zip(&self.reduces).zip(&self.layers).enumerate()
        {
            let reduced = reduce.forward(activation)?;
            let mut h = match stream {
                Some(previous) => (reduced + previous)?,
                None => reduced,
            };
            if step == self.conditional_layer {
                h = self.film(&h, conditional)?;
            }
            stream = Some(layer.forward(&h)?);
        }
        let stream =
            stream.ok_or_else(|| candle_core::Error::Msg("CLIPSeg decoder without layers".into()))?;
        let (b, tokens, r) = stream.dims3()?;
        let g = (tokens - 1).isqrt();
        if g * g != tokens - 1 {
            candle_core::bail!("CLIPSeg decoder: {} patch tokens do not form a square grid", tokens - 1);
        }
        stream.narrow(1, 1, g * g)?.transpose(1, 2)?.reshape((b, r, g, g))
    }

    /// FiLM: h ⊙ W_mul(c) + W_add(c), the same modulation for every token of an item.
    fn film(&self, h: &Tensor, conditional: &Tensor) -> candle_core::Result<Tensor> {
        let scale = self.film_mul.forward(conditional)?.unsqueeze(1)?;
        let shift = self.film_add.forward(conditional)?.unsqueeze(1)?;
        h.broadcast_mul(&scale)?.broadcast_add(&shift)
    }
}

/// What [`ClipSeg::forward`] computes for a batch.
#[derive(Debug, Clone)]
pub struct Segmentation {
    /// `[b, reduce_dim, g, g]`: the decoder's output before the transposed convolution.
    pub decoder_features: Tensor,
    /// `[b, H, W]`: one logit per pixel of the input (H = W = its side for patch 16).
    pub logits: Tensor,
}

/// A CLIPSeg model (`CLIPSegForImageSegmentation`): text tower, vision tower, decoder,
/// the bundled tokenizer and the processor settings.
#[derive(Debug)]
pub struct ClipSeg {
    text: ClipTextModel,
    text_projection: Linear,
    vision: ClipVisionModel,
    decoder: Decoder,
    config: ClipSegConfig,
    processor: ClipSegProcessorConfig,
    tokenizer: ClipTokenizer,
    device: Device,
}

impl ClipSeg {
    /// Loads a `CIDAS/clipseg-rd64-refined` folder: `config.json`, `model.safetensors`
    /// and, if present, `preprocessor_config.json`.
    pub fn load(dir: &Path, device: &Device) -> Result<Self, Error> {
        let dir = ModelDir::open(dir, "CLIPSeg", &download_hint(dir))?;
        let config: ClipSegConfig =
            dir.checked("config.json", ClipSegConfig::resolve(dir.json("config.json")?))?;
        let processor = Self::processor_config(&dir, &config)?;
        let vb = dir.var_builder("model", DType::F32, device)?;
        dir.build(|| Self::new(vb, config, processor, &dir.path.join("config.json")))
    }

    /// `preprocessor_config.json` if the folder has one, else the defaults.
    fn processor_config(dir: &ModelDir, config: &ClipSegConfig) -> Result<ClipSegProcessorConfig, Error> {
        const NAME: &str = "preprocessor_config.json";
        if !dir.path.join(NAME).is_file() {
            return Ok(ClipSegProcessorConfig::default());
        }
        let processor: ClipSegProcessorConfig = dir.config(NAME)?;
        let patch = config.vision_config.patch_size;
        if processor.side() < patch {
            return Err(Error::Corrupt {
                path: dir.path.join(NAME),
                msg: format!("size {} is below the vision tower's patch_size {patch}", processor.side()),
            });
        }
        Ok(processor)
    }

    /// Builds the model from weights in the `CLIPSegForImageSegmentation` layout (`clip.`
    /// and `decoder.` prefixes); `config` is trusted (the loader checks it).
    pub fn new(
        vb: VarBuilder,
        config: ClipSegConfig,
        processor: ClipSegProcessorConfig,
        config_path: &Path,
    ) -> Result<Self, Error> {
        let clip = vb.pp("clip");
        let mut text_config = config.text_config.clone();
        text_config.projection_dim = config.projection_dim;
        let text_hidden = text_config.hidden_size;
        let text = ClipTextModel::new(clip.clone(), text_config, config_path)?;
        let text_projection = linear_no_bias(text_hidden, config.projection_dim, clip.pp("text_projection"))?;
        let vision = ClipVisionModel::new(clip.pp("vision_model"), &config.vision_config, config_path)?;
        let decoder = Decoder::new(vb.pp("decoder"), &config)?;
        Ok(Self {
            text,
            text_projection,
            vision,
            decoder,
            config,
            processor,
            tokenizer: ClipTokenizer::bundled(),
            device: vb.device().clone(),
        })
    }

    /// The configuration read from `config.json`.
    pub fn config(&self) -> &ClipSegConfig {
        &self.config
    }

    /// The side of the square the model runs at (the processor's size, 352).
    pub fn input_size(&self) -> usize {
        self.processor.side()
    }

    /// Token ids of a prompt: `<|startoftext|>`, the BPE tokens, `<|endoftext|>`, cut to
    /// the text tower's `max_position_embeddings` with the end token kept last (no
    /// padding: attention is causal and pooling reads the end token, so padding would
    /// change nothing).
    pub fn tokenize(&self, prompt: &str) -> Vec<u32> {
        let ids = self.tokenizer.encode(prompt);
        let max = self.text.config().max_position_embeddings;
        if ids.len() > max {
            self.tokenizer.encode_padded(prompt, max, END_OF_TEXT)
        } else {
            ids
        }
    }

    /// The conditional embeddings `[b, projection_dim]` of tokenized prompts (rows of
    /// equal length): the text tower's pooled output through `text_projection`.
    pub fn conditional_embeddings(&self, ids: &[Vec<u32>]) -> Result<Tensor, Error> {
        let vocab = self.text.config().vocab_size;
        if let Some(&bad) = ids.iter().flatten().find(|&&t| t as usize >= vocab) {
            return Err(candle_core::Error::Msg(format!(
                "CLIPSeg: token id {bad} is outside vocab_size {vocab}"
            ))
            .into());
        }
        let pooled = self.text.forward(ids)?.pooled;
        Ok(self.text_projection.forward(&pooled)?)
    }

    /// Logits and decoder features of normalised pixels `[b, 3, s, s]` (any square side
    /// of at least one patch; the position embeddings follow the grid) conditioned on
    /// `conditional` `[b, projection_dim]`.
    pub fn forward(&self, pixels: &Tensor, conditional: &Tensor) -> Result<Segmentation, Error> {
        let (b, channels, h, w) = pixels.dims4()?;
        let patch = self.config.vision_config.patch_size;
        if channels != self.config.vision_config.num_channels || h != w || h < patch {
            return Err(candle_core::Error::Msg(format!(
                "CLIPSeg: pixels of shape [{b}, {channels}, {h}, {w}]; need {} channels and a square of \
                 at least {patch}",
                self.config.vision_config.num_channels
            ))
            .into());
        }
        if conditional.dims() != [b, self.config.projection_dim] {
            return Err(candle_core::Error::Msg(format!(
                "CLIPSeg: conditional embeddings of shape {:?}; need [{b}, {}]",
                conditional.dims(),
                self.config.projection_dim
            ))
            .into());
        }
        let activations = self.vision.layer_outputs(pixels, &self.config.extract_layers)?;
        let decoder_features = self.decoder.features(&activations, conditional)?;
        let logits = self.decoder.upsampler.forward(&decoder_features)?.squeeze(1)?;
        Ok(Segmentation { decoder_features, logits })
    }

    /// The processor's input for an `H × W × 3` image in [0, 1]: resized to the model's
    /// square (bilinear, antialiased), normalised with the processor's mean / std;
    /// planar `3 × s × s`.
    pub fn preprocess(&self, rgb: &[f32], width: usize, height: usize) -> Result<Vec<f32>, Error> {
        if width == 0 || height == 0 || rgb.len() != width * height * 3 {
            return Err(candle_core::Error::Msg(format!(
                "CLIPSeg: image of {} values is not {width} x {height} x 3",
                rgb.len()
            ))
            .into());
        }
        let s = self.input_size();
        let resized = transsplat_editors::resize_bilinear(rgb, width, height, 3, s, s);
        let mut planar = resample::hwc_to_chw(&resized, s, s, 3);
        resample::normalize_planes(&mut planar, &self.processor.image_mean, &self.processor.image_std);
        Ok(planar)
    }

    /// Probability (sigmoid of the logit) that each pixel of an `H × W × 3` image in
    /// [0, 1] shows what `prompt` names, `H × W` row-major: the segmentation mask
    /// M_sam of the edit region.
    pub fn segment(&self, rgb: &[f32], width: usize, height: usize, prompt: &str) -> Result<Vec<f32>, Error> {
        self.segment_ids(rgb, width, height, &self.tokenize(prompt))
    }

    /// [`ClipSeg::segment`] with an already tokenized prompt.
    pub fn segment_ids(
        &self,
        rgb: &[f32],
        width: usize,
        height: usize,
        ids: &[u32],
    ) -> Result<Vec<f32>, Error> {
        let conditional = self.conditional_embeddings(&[ids.to_vec()])?;
        let mut out = self.segment_many(&[(rgb, width, height)], &conditional)?;
        Ok(out.pop().expect("one mask per image"))
    }

    /// [`ClipSeg::segment`] of several `(rgb, width, height)` images for one prompt's
    /// conditional embedding `[1, projection_dim]` ([`ClipSeg::conditional_embeddings`]),
    /// [`SEGMENT_BATCH`] images per forward pass: per image, the probabilities at its
    /// own size.
    pub fn segment_many(
        &self,
        images: &[(&[f32], usize, usize)],
        conditional: &Tensor,
    ) -> Result<Vec<Vec<f32>>, Error> {
        let s = self.input_size();
        let mut out = Vec::with_capacity(images.len());
        for batch in images.chunks(SEGMENT_BATCH) {
            let mut planar = Vec::with_capacity(batch.len() * 3 * s * s);
            for &(rgb, width, height) in batch {
                planar.extend(self.preprocess(rgb, width, height)?);
            }
            let b = batch.len();
            let pixels = Tensor::from_vec(planar, (b, 3, s, s), &self.device)?;
            let conditional = conditional.broadcast_as((b, self.config.projection_dim))?.contiguous()?;
            let logits = self.forward(&pixels, &conditional)?.logits;
            let (_, lh, lw) = logits.dims3()?;
            let probabilities = candle_nn::ops::sigmoid(&logits)?.flatten_all()?.to_vec1::<f32>()?;
            for (&(_, width, height), p) in batch.iter().zip(probabilities.chunks_exact(lh * lw)) {
                out.push(transsplat_editors::resize_bilinear(p, lw, lh, 1, width, height));
            }
        }
        Ok(out)
    }
}

/// CLIPSeg as a [`Segmenter`]: per view, the probability that each pixel shows what the
/// phrase names ([`ClipSeg::segment`]), [`SEGMENT_BATCH`] views per forward pass. The
/// phrase's conditional embedding is computed once ([`ClipSegSegmenter::prepare`]).
#[derive(Debug)]
pub struct ClipSegSegmenter {
    model: ClipSeg,
    /// The phrase last prepared and its conditional embedding `[1, projection_dim]`.
    prepared: Option<(String, Tensor)>,
}

impl ClipSegSegmenter {
    pub fn new(model: ClipSeg) -> Self {
        ClipSegSegmenter { model, prepared: None }
    }

    /// Loads a `CIDAS/clipseg-rd64-refined` folder ([`ClipSeg::load`]).
    pub fn load(dir: &Path, device: &Device) -> Result<Self, Error> {
        ClipSeg::load(dir, device).map(Self::new)
    }

    /// Encodes `phrase` (cheap: the text tower only), so a phrase the model cannot take
    /// is refused before any view is segmented.
    pub fn prepare(&mut self, phrase: &str) -> Result<(), Error> {
        if self.prepared.as_ref().is_some_and(|(p, _)| p == phrase) {
            return Ok(());
        }
        let embedding = self.model.conditional_embeddings(&[self.model.tokenize(phrase)])?;
        self.prepared = Some((phrase.to_string(), embedding));
        Ok(())
    }

    pub fn model(&self) -> &ClipSeg {
        &self.model
    }
}

impl Segmenter for ClipSegSegmenter {
    fn name(&self) -> &str {
        "clipseg"
    }

    fn segment(&mut self, views: &[SourceView], phrase: &str) -> Result<Vec<Option<Vec<f32>>>, EditorError> {
        let fail = |e: Error| EditorError::Invalid(format!("CLIPSeg, {phrase:?}: {e}"));
        self.prepare(phrase).map_err(fail)?;
        let (_, conditional) = self.prepared.as_ref().expect("prepared above");
        for v in views {
            v.check()?;
        }
        let images: Vec<(&[f32], usize, usize)> = views
            .iter()
            .map(|v| {
                let (w, h) = v.size();
                (v.image, w, h)
            })
            .collect();
        let masks = self.model.segment_many(&images, conditional).map_err(fail)?;
        // The antialiased resize may overshoot [0, 1] by a rounding error.
        Ok(masks.into_iter().map(|m| Some(m.into_iter().map(|p| p.clamp(0.0, 1.0)).collect())).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tower_configs_take_defaults_then_the_file_then_the_legacy_dicts() {
        let raw = json!({
            "text_config": {"hidden_size": 64, "eos_token_id": 2},
            "vision_config": {"patch_size": 32},
            "vision_config_dict": {"patch_size": 16},
            "text_config_dict": null,
            "use_complex_transposed_convolution": true
        });
        let config: ClipSegConfig = serde_json::from_value(ClipSegConfig::resolve(raw)).unwrap();
        assert_eq!((config.text_config.hidden_size, config.text_config.eos_token_id), (64, 2));
        assert_eq!(config.text_config.vocab_size, 49408);
        assert_eq!((config.vision_config.patch_size, config.vision_config.hidden_size), (16, 768));
        assert_eq!((config.extract_layers.as_slice(), config.reduce_dim), ([3, 6, 9].as_slice(), 64));
        assert!(config.check().is_ok());
        // Not an object: left for serde to refuse.
        assert_eq!(ClipSegConfig::resolve(json!([1])), json!([1]));
    }
}

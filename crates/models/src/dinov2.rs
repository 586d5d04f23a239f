//! DINOv2 patch features (Hugging Face `Dinov2Model` layout: `facebook/dinov2-small`,
//! `facebook/dinov2-base`), upsampled to the image: the semantic features E_v of the edit
//! (docs/method.md#e5-semantic-and-appearance-features).
//!
//! Pipeline of [`Dinov2::features`], proven against torch + transformers by
//! `tests/dinov2_parity.rs`:
//! 1. the image is resized bicubically (torch `interpolate`, `align_corners=False`) so each
//!    side is the nearest multiple of the patch size (14), at least one patch. Decision:
//!    nearest multiple rather than a fixed 224/518 square, so the patch grid keeps the
//!    image's aspect ratio and roughly one patch per 14 pixels of the render;
//! 2. ImageNet mean / std;
//! 3. the ViT: patch embedding (14 × 14 conv with bias), class token, position embeddings
//!    (the 37 × 37 grid of the checkpoints resized bicubically to the patch grid, as
//!    transformers does it, skipped when the grid is the native square), pre-norm layers
//!    `x + λ₁·attn(norm1(x))`, `x + λ₂·mlp(norm2(x))` (layer scales λ, gelu MLP), final
//!    `layernorm`;
//! 4. the patch tokens, as a `C × gh × gw` grid, upsampled bilinearly
//!    (`align_corners=False`) to `H × W`, returned interleaved `H × W × C`.

use candle_core::{DType, Device, Module, Tensor};
use candle_nn::{layer_norm, linear, LayerNorm, Linear, VarBuilder};
use serde::Deserialize;

use crate::check::{self, ModelConfig};
use crate::clip::Attention;
use crate::resample;
use crate::{Error, ModelDir};

/// Download command for the DINOv2 weights.
pub const DINOV2_HINT: &str = "hf download facebook/dinov2-small --local-dir DIR";

/// ImageNet normalisation used by DINOv2.
pub const IMAGENET_MEAN: [f32; 3] = [0.485, 0.456, 0.406];
/// See [`IMAGENET_MEAN`].
pub const IMAGENET_STD: [f32; 3] = [0.229, 0.224, 0.225];

fn default_act() -> String {
    "gelu".to_string()
}
fn default_eps() -> f64 {
    1e-6
}
fn default_mlp_ratio() -> f64 {
    4.0
}
fn default_true() -> bool {
    true
}

/// `config.json` of a `Dinov2Model`.
#[derive(Debug, Clone, Deserialize)]
pub struct Dinov2Config {
    pub hidden_size: usize,
    pub num_hidden_layers: usize,
    pub num_attention_heads: usize,
    #[serde(default = "default_mlp_ratio")]
    pub mlp_ratio: f64,
    pub image_size: usize,
    pub patch_size: usize,
    #[serde(default = "default_act")]
    pub hidden_act: String,
    #[serde(default = "default_eps")]
    pub layer_norm_eps: f64,
    #[serde(default = "default_true")]
    pub qkv_bias: bool,
    #[serde(default)]
    pub use_swiglu_ffn: bool,
}

impl ModelConfig for Dinov2Config {
    fn check(&self) -> Result<(), String> {
        if self.hidden_act != "gelu" || self.use_swiglu_ffn || !self.qkv_bias {
            return Err(
                "only the gelu-MLP DINOv2 models with qkv bias (dinov2-small/-base/-large) are supported"
                    .into(),
            );
        }
        check::size("hidden_size", self.hidden_size)?;
        check::layers("num_hidden_layers", self.num_hidden_layers)?;
        check::divides("hidden_size", self.hidden_size, "num_attention_heads", self.num_attention_heads)?;
        check::size("patch_size", self.patch_size)?;
        check::size("image_size", self.image_size)?;
        if self.image_size < self.patch_size {
            return Err(format!("image_size {} is below patch_size {}", self.image_size, self.patch_size));
        }
        check::positive("mlp_ratio", self.mlp_ratio)?;
        check::size("hidden_size × mlp_ratio", (self.hidden_size as f64 * self.mlp_ratio) as usize)?;
        check::positive("layer_norm_eps", self.layer_norm_eps)
    }
}

#[derive(Debug, Clone)]
struct Layer {
    norm1: LayerNorm,
    attn: Attention,
    scale1: Tensor,
    norm2: LayerNorm,
    fc1: Linear,
    fc2: Linear,
    scale2: Tensor,
}

/// A DINOv2 ViT.
#[derive(Debug, Clone)]
pub struct Dinov2 {
    cls_token: Tensor,
    patch_weight: Tensor,
    patch_bias: Tensor,
    /// `[1 + n², C]` position embeddings of the native `n × n` grid.
    position: Tensor,
    layers: Vec<Layer>,
    layernorm: LayerNorm,
    config: Dinov2Config,
    device: Device,
}

impl Dinov2 {
    /// Loads a `Dinov2Model` folder (`config.json`, `model.safetensors`).
    pub fn load(dir: &ModelDir, device: &Device) -> Result<Self, Error> {
        let config: Dinov2Config = dir.config("config.json")?;
        let vb = dir.var_builder("model", DType::F32, device)?;
        dir.build(|| Self::new(vb, config))
    }

    /// Builds the model from weights in the hub layout.
    pub fn new(vb: VarBuilder, config: Dinov2Config) -> Result<Self, Error> {
        let c = config.hidden_size;
        let p = config.patch_size;
        let grid = config.image_size / p;
        let emb = vb.pp("embeddings");
        let mlp = (c as f64 * config.mlp_ratio) as usize;
        let layers = (0..config.num_hidden_layers)
            .map(|i| {
                let l = vb.pp(format!("encoder.layer.{i}"));
                let a = l.pp("attention.attention");
                Ok(Layer {
                    norm1: layer_norm(c, config.layer_norm_eps, l.pp("norm1"))?,
                    attn: Attention::from_parts(
                        linear(c, c, a.pp("query"))?,
                        linear(c, c, a.pp("key"))?,
                        linear(c, c, a.pp("value"))?,
                        linear(c, c, l.pp("attention.output.dense"))?,
                        config.num_attention_heads,
                    ),
                    scale1: l.get(c, "layer_scale1.lambda1")?,
                    norm2: layer_norm(c, config.layer_norm_eps, l.pp("norm2"))?,
                    fc1: linear(c, mlp, l.pp("mlp.fc1"))?,
                    fc2: linear(mlp, c, l.pp("mlp.fc2"))?,
                    scale2: l.get(c, "layer_scale2.lambda1")?,
                })
            })
            .collect::<candle_core::Result<Vec<_>>>()?;
        Ok(Self {
            cls_token: emb.get((1, 1, c), "cls_token")?.reshape((1, c))?,
            patch_weight: emb.get((c, 3, p, p), "patch_embeddings.projection.weight")?,
            patch_bias: emb.get(c, "patch_embeddings.projection.bias")?,
            position: emb.get((1, grid * grid + 1, c), "position_embeddings")?.squeeze(0)?,
            layers,
            layernorm: layer_norm(c, config.layer_norm_eps, vb.pp("layernorm"))?,
            device: vb.device().clone(),
            config,
        })
    }

    /// Feature channels (384 for dinov2-small, 768 for -base).
    pub fn channels(&self) -> usize {
        self.config.hidden_size
    }

    /// Patch grid `(gh, gw)` used for an `h × w` image.
    pub fn grid(&self, width: usize, height: usize) -> (usize, usize) {
        let p = self.config.patch_size as f64;
        let side = |n: usize| ((n as f64 / p).round() as usize).max(1);
        (side(height), side(width))
    }

    /// `last_hidden_state` `[1 + gh·gw, C]` (class token first, after the final layernorm)
    /// of one normalised planar image `3 × (gh·14) × (gw·14)`.
    pub fn forward(&self, planar: Vec<f32>, gh: usize, gw: usize) -> Result<Tensor, Error> {
        let p = self.config.patch_size;
        let c = self.config.hidden_size;
        let x = Tensor::from_vec(planar, (1, 3, gh * p, gw * p), &self.device)?;
        let patches = x
            .conv2d(&self.patch_weight, 0, p, 1, 1)?
            .broadcast_add(&self.patch_bias.reshape((1, c, 1, 1))?)?;
        let patches = patches.flatten_from(2)?.squeeze(0)?.t()?; // [gh·gw, C]
        let positions = resample::position_grid(&self.position, self.config.image_size / p, gh, gw)?;
        let mut h = Tensor::cat(&[&self.cls_token, &patches], 0)?.add(&positions)?.unsqueeze(0)?;
        for l in &self.layers {
            let y = l.attn.forward(&l.norm1.forward(&h)?, None)?;
            h = (h + y.broadcast_mul(&l.scale1)?)?;
            let y = l.fc2.forward(&l.fc1.forward(&l.norm2.forward(&h)?)?.gelu_erf()?)?;
            h = (h + y.broadcast_mul(&l.scale2)?)?;
        }
        Ok(self.layernorm.forward(&h)?.squeeze(0)?)
    }

    /// Dense features of an `H × W × 3` image in [0, 1]: `H × W × C` interleaved, and `C`.
    pub fn features(&self, image: &[f32], width: usize, height: usize) -> Result<(Vec<f32>, usize), Error> {
        self.features_with(image, width, height, None)
    }

    /// [`Dinov2::features`] with the channels reduced to `dim` by a fixed random
    /// projection (seeded Gaussian, `C × dim`, the same for every image) applied to the
    /// patch tokens before upsampling; projection and bilinear upsampling are both linear,
    /// so this equals projecting the upsampled features. Pairwise feature distances are
    /// kept up to a small relative error (Johnson–Lindenstrauss), which is all the edit
    /// engine's PCA to d = 16 needs, while one 512 × 512 view takes 64 rather than 384
    /// or 768 channels (67 MB instead of 400 MB to 800 MB).
    pub fn features_projected(
        &self,
        image: &[f32],
        width: usize,
        height: usize,
        dim: usize,
    ) -> Result<(Vec<f32>, usize), Error> {
        self.features_with(image, width, height, Some(dim))
    }

    fn features_with(
        &self,
        image: &[f32],
        width: usize,
        height: usize,
        dim: Option<usize>,
    ) -> Result<(Vec<f32>, usize), Error> {
        if width == 0 || height == 0 || image.len() != width * height * 3 {
            return Err(candle_core::Error::Msg(format!(
                "DINOv2: image of {} values is not {width} x {height} x 3",
                image.len()
            ))
            .into());
        }
        let p = self.config.patch_size;
        let c = self.config.hidden_size;
        let (gh, gw) = self.grid(width, height);
        let planar = resample::hwc_to_chw(image, height, width, 3);
        let mut x = resample::bicubic(&planar, 3, height, width, gh * p, gw * p);
        resample::normalize_planes(&mut x, &IMAGENET_MEAN, &IMAGENET_STD);
        let hidden = self.forward(x, gh, gw)?;
        // Patch tokens as planar [C, gh, gw], upsampled to the image.
        let mut grid = hidden.narrow(0, 1, gh * gw)?.t()?.contiguous()?.flatten_all()?.to_vec1::<f32>()?;
        let mut c = c;
        if let Some(d) = dim.filter(|&d| d > 0 && d < c) {
            grid = project_planes(&grid, c, gh * gw, d);
            c = d;
        }
        let up = resample::bilinear(&grid, c, gh, gw, height, width);
        let mut out = vec![0f32; height * width * c];
        for (k, plane) in up.chunks_exact(height * width).enumerate() {
            for (px, &v) in plane.iter().enumerate() {
                out[px * c + k] = v;
            }
        }
        Ok((out, c))
    }
}

/// The fixed `C × d` projection of [`Dinov2::features_projected`] (row-major): seeded
/// Gaussian entries scaled by `1/√d`.
pub fn projection(c: usize, d: usize) -> Vec<f32> {
    let mut rng = transsplat_scene::rng::SplitMix64::new(0x0D1A_0002);
    let scale = 1.0 / (d as f32).sqrt();
    (0..c * d).map(|_| rng.normal() * scale).collect()
}

/// Projects `c` planes of `n` values onto `d` planes with [`projection`].
fn project_planes(planes: &[f32], c: usize, n: usize, d: usize) -> Vec<f32> {
    let m = projection(c, d);
    let mut out = vec![0f32; d * n];
    for (k, row) in out.chunks_exact_mut(n).enumerate() {
        for ch in 0..c {
            let w = m[ch * d + k];
            for (o, &v) in row.iter_mut().zip(&planes[ch * n..(ch + 1) * n]) {
                *o += w * v;
            }
        }
    }
    out
}

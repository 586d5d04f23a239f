//! Benchmark cases for InstructPix2Pix at the real Stable Diffusion 1.5 sizes, with
//! random weights (the real ones are not needed to time the arithmetic): one UNet step
//! as the guidance runs it (batch 3, 8 input channels, 77 tokens of 768), VAE encode
//! (posterior mode) and VAE decode, each at a given image size.
//!
//! The models are built once per size (`sd15_models`, a few GB of f32 weights) and
//! every case times one call; the caller (`transsplat bench models`) repeats and reports.

use candle_core::{Device, Tensor};

use transsplat_models::clip::ClipTextModel;
use transsplat_models::ip2p::unet::{UNet, UNetConfig};
use transsplat_models::ip2p::vae::{Vae, VaeConfig};
use transsplat_models::ip2p::{Ddim, DdimConfig, Ip2p, Ip2pEditor, Settings};

/// The `unet/config.json` of `timbrooks/instruct-pix2pix` (SD 1.5 with 8 input channels).
pub const SD15_UNET: &str = r#"{
  "in_channels": 8, "out_channels": 4,
  "block_out_channels": [320, 640, 1280, 1280],
  "down_block_types": ["CrossAttnDownBlock2D", "CrossAttnDownBlock2D", "CrossAttnDownBlock2D", "DownBlock2D"],
  "up_block_types": ["UpBlock2D", "CrossAttnUpBlock2D", "CrossAttnUpBlock2D", "CrossAttnUpBlock2D"],
  "layers_per_block": 2, "attention_head_dim": 8, "cross_attention_dim": 768,
  "norm_num_groups": 32, "norm_eps": 1e-05, "use_linear_projection": false,
  "flip_sin_to_cos": true, "freq_shift": 0, "downsample_padding": 1, "mid_block_scale_factor": 1
}"#;

/// The `vae/config.json` of Stable Diffusion 1.5.
pub const SD15_VAE: &str = r#"{
  "in_channels": 3, "out_channels": 3, "latent_channels": 4,
  "block_out_channels": [128, 256, 512, 512], "layers_per_block": 2,
  "norm_num_groups": 32, "scaling_factor": 0.18215
}"#;

/// SD 1.5 UNet and VAE with random weights.
pub struct Sd15 {
    pub unet: UNet,
    pub vae: Vae,
}

/// Builds the SD 1.5 UNet (≈ 860 M parameters) and VAE (≈ 84 M) with random weights.
pub fn sd15_models(device: &Device) -> candle_core::Result<Sd15> {
    let parse = |e: serde_json::Error| candle_core::Error::Msg(e.to_string());
    let unet_cfg = serde_json::from_str::<UNetConfig>(SD15_UNET).map_err(parse)?;
    let vae_cfg = serde_json::from_str::<VaeConfig>(SD15_VAE).map_err(parse)?;
    let to_candle = |e: transsplat_models::Error| candle_core::Error::Msg(e.to_string());
    let vb = transsplat_models::weights::random_weights(device, |vb| {
        UNet::new(vb.pp("unet"), unet_cfg.clone())?;
        Vae::new(vb.pp("vae"), vae_cfg.clone())?;
        Ok(())
    })
    .map_err(to_candle)?;
    let unet = UNet::new(vb.pp("unet"), unet_cfg)?;
    let vae = Vae::new(vb.pp("vae"), vae_cfg)?;
    Ok(Sd15 { unet, vae })
}

/// What a case times.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Case {
    /// One UNet evaluation on a batch of 3 (text, image, unconditional).
    UnetStep,
    /// One UNet evaluation on a batch of 3 × this many views (the editor's batch).
    UnetStepViews(usize),
    /// VAE encoder to the posterior mode, one image.
    VaeEncode,
    /// VAE decoder, one image.
    VaeDecode,
}

impl Case {
    pub const ALL: [Case; 3] = [Case::UnetStep, Case::VaeEncode, Case::VaeDecode];

    /// Views per case (the time per view is the case's time over this).
    pub fn views(self) -> usize {
        match self {
            Case::UnetStepViews(n) => n,
            _ => 1,
        }
    }

    /// Name as reported, e.g. `ip2p unet step (batch 3) 512x512`.
    pub fn name(self, size: usize) -> String {
        let what = match self {
            Case::UnetStep => "ip2p unet step (batch 3)".to_string(),
            Case::UnetStepViews(n) => format!("ip2p unet step (batch 3x{n})"),
            Case::VaeEncode => "ip2p vae encode".to_string(),
            Case::VaeDecode => "ip2p vae decode".to_string(),
        };
        format!("{what} {size}x{size}")
    }

    /// Runs the case once on `size × size` images (random inputs), waiting for the
    /// device to finish (a GPU runs the kernels asynchronously).
    pub fn run(self, m: &Sd15, size: usize, device: &Device) -> candle_core::Result<()> {
        let l = size / m.vae.config.downscale();
        match self {
            Case::UnetStep | Case::UnetStepViews(_) => {
                let b = 3 * self.views();
                let x = Tensor::randn(0f32, 1.0, (b, 8, l, l), device)?;
                let ctx = Tensor::randn(0f32, 1.0, (b, 77, 768), device)?;
                m.unet.forward(&x, 500.0, &ctx)?;
            }
            Case::VaeEncode => {
                let x = Tensor::rand(-1f32, 1.0, (1, 3, size, size), device)?;
                m.vae.encode_mode(&x)?;
            }
            Case::VaeDecode => {
                let z = Tensor::randn(0f32, 1.0, (1, 4, l, l), device)?;
                m.vae.decode(&z)?;
            }
        }
        device.synchronize()
    }
}

/// The InstructPix2Pix editor with random weights at the real sizes (SD 1.5 UNet and VAE,
/// CLIP ViT-L/14's text tower, the InstructPix2Pix DDIM schedule and the default
/// settings): it edits views with the arithmetic of the real model, for timing whole
/// edits (`transsplat bench edit --editor ip2p`). Its images are noise-like.
pub fn random_editor<'c>(device: &Device, seed: u64) -> Result<Ip2pEditor<'c>, String> {
    let err = |e: &dyn std::fmt::Display| format!("random InstructPix2Pix: {e}");
    let Sd15 { unet, vae } = sd15_models(device).map_err(|e| err(&e))?;
    let ddim = Ddim::new(DdimConfig::instruct_pix2pix()).map_err(|e| err(&e))?;
    let pipeline = Ip2p { unet, vae, ddim, device: device.clone() };
    let config = crate::configs::vit_l14().text_config;
    let path = std::path::Path::new("(benchmark config)");
    let vb = transsplat_models::weights::random_weights(device, |vb| {
        ClipTextModel::new(vb, config.clone(), path).map(|_| ())
    })
    .map_err(|e| err(&e))?;
    let text = ClipTextModel::new(vb, config, path).map_err(|e| err(&e))?;
    Ip2pEditor::from_parts(pipeline, text, Settings::default(), seed)
}

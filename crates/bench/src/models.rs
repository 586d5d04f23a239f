//! Model benchmarks for `transsplat bench models`: a list of named cases, each building a
//! model with the real architecture sizes and random weights (real weights cannot be
//! downloaded here; the arithmetic is the same) and timing one forward pass.

use crate::timing::try_best_of;
use candle_core::Device;

use crate::configs::vit_l14;
use crate::ip2p::{sd15_models, Case as Ip2pCase, Sd15};
use transsplat_models::clip::{Clip, ClipTextConfig, ClipVisionConfig};
use transsplat_models::clipseg::{ClipSeg, ClipSegConfig, ClipSegProcessorConfig};
use transsplat_models::dinov2::{Dinov2, Dinov2Config};
use transsplat_models::sam::{PointLabel, Prompt, Sam, SamConfig};
use transsplat_models::weights::random_weights;
use transsplat_models::Error;

/// One benchmark: a name and a function that builds its model and returns the seconds
/// of the fastest of `repeats` timed runs (after one untimed warm-up run).
pub struct Case {
    pub name: &'static str,
    pub run: fn(&Device, Repeats) -> Result<f64, Error>,
}

/// How many timed runs a case takes the fastest of (at least one).
#[derive(Clone, Copy, Debug)]
pub struct Repeats(pub usize);

/// Every model case (CLIP, CLIPSeg, SAM and DINOv2; the InstructPix2Pix cases join this list).
pub fn cases() -> Vec<Case> {
    vec![
        Case { name: "clip-vit-l14 image 224", run: clip_image },
        Case { name: "clip-vit-l14 text 77", run: clip_text },
        Case { name: "clipseg-rd64-refined segment 256x256", run: |d, n| clipseg(d, n, 256) },
        Case { name: "clipseg-rd64-refined segment 512x512", run: |d, n| clipseg(d, n, 512) },
        Case { name: "slimsam-uniform-77 segment 256x256", run: |d, n| sam(d, n, Some((168, 696)), 256) },
        Case { name: "slimsam-uniform-77 segment 512x512", run: |d, n| sam(d, n, Some((168, 696)), 512) },
        Case { name: "sam-vit-base segment 256x256", run: |d, n| sam(d, n, None, 256) },
        Case { name: "sam-vit-base segment 512x512", run: |d, n| sam(d, n, None, 512) },
        Case { name: "dinov2-small 256x256", run: |d, n| dinov2(d, n, 384, 6, 256) },
        Case { name: "dinov2-small 512x512", run: |d, n| dinov2(d, n, 384, 6, 512) },
        Case { name: "dinov2-base 256x256", run: |d, n| dinov2(d, n, 768, 12, 256) },
        Case { name: "dinov2-base 512x512", run: |d, n| dinov2(d, n, 768, 12, 512) },
        Case { name: "ip2p unet step (batch 3) 256x256", run: |d, n| ip2p(d, n, Ip2pCase::UnetStep, 256) },
        Case {
            name: "ip2p unet step (batch 3x2) 256x256",
            run: |d, n| ip2p(d, n, Ip2pCase::UnetStepViews(2), 256),
        },
        Case {
            name: "ip2p unet step (batch 3x4) 256x256",
            run: |d, n| ip2p(d, n, Ip2pCase::UnetStepViews(4), 256),
        },
        Case { name: "ip2p vae encode 256x256", run: |d, n| ip2p(d, n, Ip2pCase::VaeEncode, 256) },
        Case { name: "ip2p vae decode 256x256", run: |d, n| ip2p(d, n, Ip2pCase::VaeDecode, 256) },
        Case { name: "ip2p unet step (batch 3) 512x512", run: |d, n| ip2p(d, n, Ip2pCase::UnetStep, 512) },
        Case { name: "ip2p vae encode 512x512", run: |d, n| ip2p(d, n, Ip2pCase::VaeEncode, 512) },
        Case { name: "ip2p vae decode 512x512", run: |d, n| ip2p(d, n, Ip2pCase::VaeDecode, 512) },
        Case {
            name: "ip2p self-attention 512x512 (3x8 heads, 4096 tokens)",
            run: |d, n| attention(d, n, 4096),
        },
        Case {
            name: "ip2p self-attention 256x256 (3x8 heads, 1024 tokens)",
            run: |d, n| attention(d, n, 1024),
        },
    ]
}

/// The SD 1.5 models are built once per process (about 4 GB of random f32 weights).
fn ip2p(device: &Device, repeats: Repeats, case: Ip2pCase, size: usize) -> Result<f64, Error> {
    static MODELS: std::sync::Mutex<Option<std::sync::Arc<Sd15>>> = std::sync::Mutex::new(None);
    let models = {
        let mut slot = MODELS.lock().map_err(|_| candle_core::Error::Msg("poisoned".into()))?;
        if slot.is_none() {
            *slot = Some(std::sync::Arc::new(sd15_models(device)?));
        }
        slot.clone().expect("just built")
    };
    time(repeats, || Ok(case.run(&models, size, device)?))
}

/// One self-attention of the InstructPix2Pix UNet's finest level: a batch of 3 (the
/// three-way guidance), `tokens` latent pixels, 320 channels in 8 heads of 40.
fn attention(device: &Device, repeats: Repeats, tokens: usize) -> Result<f64, Error> {
    let x = candle_core::Tensor::randn(0f32, 1.0, (3, tokens, 320), device)?;
    let scale = 1.0 / 40f64.sqrt();
    time(repeats, || Ok(transsplat_models::attention::multi_head_attention(&x, &x, &x, 8, scale)?))
}

/// Seconds of the fastest of `repeats` runs of `f` after one untimed warm-up run.
fn time<T>(repeats: Repeats, f: impl FnMut() -> Result<T, Error>) -> Result<f64, Error> {
    try_best_of(1, repeats.0, f).map(|(secs, _)| secs)
}

fn clip(device: &Device) -> Result<Clip, Error> {
    let path = std::path::Path::new("(benchmark config)");
    let vb = random_weights(device, |vb| Clip::new(vb, &vit_l14(), path).map(|_| ()))?;
    Clip::new(vb, &vit_l14(), path)
}

fn clip_image(device: &Device, repeats: Repeats) -> Result<f64, Error> {
    let clip = clip(device)?;
    let (w, h) = (512, 512);
    let img: Vec<f32> = (0..w * h * 3).map(|i| (i % 255) as f32 / 255.0).collect();
    time(repeats, || clip.image_features(&[(&img, w, h)]))
}

fn clip_text(device: &Device, repeats: Repeats) -> Result<f64, Error> {
    let clip = clip(device)?;
    time(repeats, || clip.text_features(&["a photo of a man turned into a clown"]))
}

fn dinov2(device: &Device, repeats: Repeats, hidden: usize, heads: usize, size: usize) -> Result<f64, Error> {
    let config = Dinov2Config {
        hidden_size: hidden,
        num_hidden_layers: 12,
        num_attention_heads: heads,
        mlp_ratio: 4.0,
        image_size: 518,
        patch_size: 14,
        hidden_act: "gelu".into(),
        layer_norm_eps: 1e-6,
        qkv_bias: true,
        use_swiglu_ffn: false,
    };
    let vb = random_weights(device, |vb| Dinov2::new(vb, config.clone()).map(|_| ()))?;
    let model = Dinov2::new(vb, config)?;
    let img: Vec<f32> = (0..size * size * 3).map(|i| (i % 251) as f32 / 251.0).collect();
    time(repeats, || model.features(&img, size, size))
}

/// `CIDAS/clipseg-rd64-refined`: CLIP ViT-B/16 towers (text 512 wide, 8 heads, vision 768
/// wide, 12 heads, patch 16, 224 native), projection 512, decoder reading vision layers
/// 3, 6 and 9 at width 64 (4 heads, MLP 2048), FiLM at the first step, the complex
/// transposed convolution; the processor resizes to 352.
fn clipseg_rd64_refined() -> ClipSegConfig {
    ClipSegConfig {
        text_config: ClipTextConfig {
            vocab_size: 49408,
            hidden_size: 512,
            intermediate_size: 2048,
            num_hidden_layers: 12,
            num_attention_heads: 8,
            max_position_embeddings: 77,
            hidden_act: "quick_gelu".into(),
            layer_norm_eps: 1e-5,
            eos_token_id: 49407,
            projection_dim: 512,
        },
        vision_config: ClipVisionConfig {
            hidden_size: 768,
            intermediate_size: 3072,
            num_hidden_layers: 12,
            num_attention_heads: 12,
            image_size: 224,
            patch_size: 16,
            num_channels: 3,
            hidden_act: "quick_gelu".into(),
            layer_norm_eps: 1e-5,
        },
        projection_dim: 512,
        extract_layers: vec![3, 6, 9],
        reduce_dim: 64,
        decoder_num_attention_heads: 4,
        decoder_intermediate_size: 2048,
        conditional_layer: 0,
        use_complex_transposed_convolution: true,
    }
}

/// One `segment` call on a `size`² view (resize to 352², both towers, the decoder, the
/// probabilities resized back).
fn clipseg(device: &Device, repeats: Repeats, size: usize) -> Result<f64, Error> {
    let path = std::path::Path::new("(benchmark config)");
    let (config, processor) = (clipseg_rd64_refined(), ClipSegProcessorConfig::default());
    let vb =
        random_weights(device, |vb| ClipSeg::new(vb, config.clone(), processor.clone(), path).map(|_| ()))?;
    let model = ClipSeg::new(vb, config, processor, path)?;
    let img: Vec<f32> = (0..size * size * 3).map(|i| (i % 253) as f32 / 253.0).collect();
    time(repeats, || model.segment(&img, size, size, "the bear statue"))
}

/// One SAM `segment` call on a `size`² view with a box and a point (resize to 1024², the
/// ViT encoder, the decoder, the mask resized back): `facebook/sam-vit-base`'s config
/// (transformers' defaults), or SlimSAM's pruned vision widths `(hidden_size, mlp_dim)`
/// (`Zigeng/SlimSAM-uniform-77`: 168, 696).
fn sam(device: &Device, repeats: Repeats, slim: Option<(usize, usize)>, size: usize) -> Result<f64, Error> {
    let mut config = SamConfig::default();
    if let Some((hidden, mlp)) = slim {
        config.vision_config.hidden_size = hidden;
        config.vision_config.mlp_dim = Some(mlp);
    }
    let vb = random_weights(device, |vb| Sam::new(vb, config.clone()).map(|_| ()).map_err(Error::from))?;
    let model = Sam::new(vb, config)?;
    let img: Vec<f32> = (0..size * size * 3).map(|i| (i % 253) as f32 / 253.0).collect();
    let q = size as f32 / 4.0;
    let prompt = Prompt {
        points: vec![([2.0 * q, 2.0 * q], PointLabel::Positive)],
        bbox: Some([q, q, 3.0 * q, 3.0 * q]),
    };
    time(repeats, || model.segment(&img, size, size, &prompt))
}

//! Model configs (`config.json` of DINOv2, CLIP, the UNet and VAE, the DDIM scheduler):
//! parsing and `ModelConfig::check` never panic, and a config that passes the check
//! describes a model (no zero sizes, heads and groups divide their widths, the DDIM
//! schedule builds). The first byte picks the config type; the rest is the JSON text.
#![no_main]

use libfuzzer_sys::fuzz_target;
use transsplat_models::clip::{ClipConfig, ClipTextConfig, ClipVisionConfig};
use transsplat_models::dinov2::Dinov2Config;
use transsplat_models::ip2p::ddim::{Ddim, DdimConfig};
use transsplat_models::ip2p::unet::UNetConfig;
use transsplat_models::ip2p::vae::VaeConfig;
use transsplat_models::ModelConfig;

fn checked<T: ModelConfig>(json: &[u8]) -> Option<T> {
    let c: T = serde_json::from_slice(json).ok()?;
    c.check().ok().map(|_| c)
}

fn tower(hidden: usize, heads: usize) {
    assert!(hidden > 0 && heads > 0 && hidden % heads == 0);
}

fuzz_target!(|data: &[u8]| {
    let Some((&kind, json)) = data.split_first() else { return };
    match kind % 7 {
        0 => {
            if let Some(c) = checked::<Dinov2Config>(json) {
                tower(c.hidden_size, c.num_attention_heads);
                assert!(c.patch_size > 0 && c.image_size >= c.patch_size);
            }
        }
        1 => {
            if let Some(c) = checked::<ClipTextConfig>(json) {
                tower(c.hidden_size, c.num_attention_heads);
                assert!((c.eos_token_id as usize) < c.vocab_size);
            }
        }
        2 => {
            if let Some(c) = checked::<ClipVisionConfig>(json) {
                tower(c.hidden_size, c.num_attention_heads);
                assert!(c.patch_size > 0 && c.image_size >= c.patch_size);
            }
        }
        3 => {
            if let Some(c) = checked::<ClipConfig>(json) {
                tower(c.text_config.hidden_size, c.text_config.num_attention_heads);
                tower(c.vision_config.hidden_size, c.vision_config.num_attention_heads);
            }
        }
        4 => {
            if let Some(c) = checked::<UNetConfig>(json) {
                assert!(c.norm_num_groups > 0);
                assert!(c.block_out_channels.iter().all(|&ch| ch > 0 && ch % c.norm_num_groups == 0));
            }
        }
        5 => {
            if let Some(c) = checked::<VaeConfig>(json) {
                assert!(c.norm_num_groups > 0 && c.downscale() >= 1);
                assert!(c.block_out_channels.iter().all(|&ch| ch > 0 && ch % c.norm_num_groups == 0));
            }
        }
        _ => {
            if let Some(c) = checked::<DdimConfig>(json) {
                // Unsupported settings may still be refused, never with a panic.
                if let Ok(d) = Ddim::new(c) {
                    assert!(d.train_steps() >= 2);
                }
            }
        }
    }
});

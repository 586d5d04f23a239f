//! The configurations of real models the benchmarks build with random weights.

use transsplat_models::clip::{ClipConfig, ClipTextConfig, ClipVisionConfig};

/// `openai/clip-vit-large-patch14`.
pub fn vit_l14() -> ClipConfig {
    ClipConfig {
        text_config: ClipTextConfig {
            vocab_size: 49408,
            hidden_size: 768,
            intermediate_size: 3072,
            num_hidden_layers: 12,
            num_attention_heads: 12,
            max_position_embeddings: 77,
            hidden_act: "quick_gelu".into(),
            layer_norm_eps: 1e-5,
            eos_token_id: 49407,
            projection_dim: 768,
        },
        vision_config: ClipVisionConfig {
            hidden_size: 1024,
            intermediate_size: 4096,
            num_hidden_layers: 24,
            num_attention_heads: 16,
            image_size: 224,
            patch_size: 14,
            num_channels: 3,
            hidden_act: "quick_gelu".into(),
            layer_norm_eps: 1e-5,
        },
        projection_dim: 768,
    }
}

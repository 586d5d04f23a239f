//! Field-by-field checks of model configs, run before any model is built.
//!
//! A config that cannot describe a model (zero sizes, heads that do not divide the width,
//! norm groups that do not divide the channels, non-finite epsilons, sizes beyond any
//! released checkpoint) is refused with a message naming the field, instead of a panic
//! (a division by zero) or an allocation sized by a typo deep inside the build. Every
//! config type implements [`ModelConfig`]; [`crate::ModelDir::config`] parses and checks
//! in one step, so no model can be built from an unchecked config read from a file.

use serde::de::DeserializeOwned;

/// Largest width, channel count, vocabulary or position count accepted from a config
/// (2^20). Released checkpoints are far below it (CLIP's vocabulary is 49408, the largest
/// ViT widths are a few thousand); the weights themselves are bounded by their file.
pub const MAX_SIZE: usize = 1 << 20;

/// Largest layer count or diffusion timestep count accepted from a config.
pub const MAX_LAYERS: usize = 1 << 12;

/// A config read from a model folder: parsed with serde, then checked by [`Self::check`].
pub trait ModelConfig: DeserializeOwned {
    /// The first problem found, naming its field; `Ok` when a model can be built.
    fn check(&self) -> Result<(), String>;
}

/// `value` is in `1..=MAX_SIZE`.
pub fn size(field: &str, value: usize) -> Result<(), String> {
    if value == 0 || value > MAX_SIZE {
        return Err(format!("{field} is {value}: must be between 1 and {MAX_SIZE}"));
    }
    Ok(())
}

/// `value` is in `0..=MAX_LAYERS` (zero layers is a degenerate but well-defined model).
pub fn layers(field: &str, value: usize) -> Result<(), String> {
    if value > MAX_LAYERS {
        return Err(format!("{field} is {value}: at most {MAX_LAYERS} are supported"));
    }
    Ok(())
}

/// `parts` is a valid size that divides `total` (attention heads into a width, norm
/// groups into channels).
pub fn divides(total_field: &str, total: usize, parts_field: &str, parts: usize) -> Result<(), String> {
    size(parts_field, parts)?;
    if !total.is_multiple_of(parts) {
        return Err(format!("{total_field} {total} does not divide into {parts_field} {parts}"));
    }
    Ok(())
}

/// `value` is finite and strictly positive (epsilons, ratios, scaling factors).
pub fn positive(field: &str, value: f64) -> Result<(), String> {
    if !(value.is_finite() && value > 0.0) {
        return Err(format!("{field} is {value}: must be a finite number above 0"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_check_names_the_field_and_accepts_the_boundary() {
        assert!(size("hidden_size", 1).is_ok() && size("hidden_size", MAX_SIZE).is_ok());
        assert!(size("hidden_size", 0).unwrap_err().starts_with("hidden_size is 0"));
        assert!(size("hidden_size", MAX_SIZE + 1).is_err());
        assert!(layers("num_hidden_layers", 0).is_ok());
        assert!(layers("num_hidden_layers", MAX_LAYERS + 1).unwrap_err().contains("num_hidden_layers"));
        assert!(divides("hidden_size", 32, "num_attention_heads", 4).is_ok());
        assert_eq!(
            divides("hidden_size", 32, "num_attention_heads", 5).unwrap_err(),
            "hidden_size 32 does not divide into num_attention_heads 5"
        );
        assert!(divides("hidden_size", 32, "num_attention_heads", 0).unwrap_err().contains("is 0"));
        for bad in [0.0, -1e-6, f64::NAN, f64::INFINITY] {
            assert!(positive("layer_norm_eps", bad).unwrap_err().contains("layer_norm_eps"), "{bad}");
        }
        assert!(positive("layer_norm_eps", 1e-12).is_ok());
    }
}

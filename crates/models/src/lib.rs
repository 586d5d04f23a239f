//! Foundation models for transsplat, written with candle and loaded from local
//! Hugging Face / diffusers folders (nothing is downloaded at run time).
//!
//! - [`ip2p`]: the InstructPix2Pix 2D editor (UNet with 8 input channels, VAE, CLIP text
//!   encoder, DDIM with three-way guidance), with a DiffEdit-style edit-attention map.
//! - [`dinov2`]: DINOv2 patch features, upsampled to the image: the semantic features E_v.
//! - [`clip`]: CLIP image and text features for the CLIP-sim / CLIP-dir metrics.
//! - [`clipseg`]: CLIPSeg, the text-grounded segmenter behind the mask M_sam of the edit region.
//! - [`tokenizer`]: the CLIP byte-pair tokenizer with its vocabulary bundled.
//! - [`resample`]: torch-exact bicubic / bilinear resizing for the models' preprocessing.
//! - [`check`]: field-by-field checks of model configs before building.
//! - [`weights`]: locating, validating and memory-mapping weight folders.
//!
//! Every model is proven against the reference Python implementation (diffusers,
//! transformers) on tiny randomly initialised configurations; the fixtures are written by
//! `tools/model_fixtures_*.py` and committed under `tests/fixtures`.

pub mod attention;
pub mod check;
#[macro_use]
mod cpu;
pub mod clip;
pub mod clipseg;
pub mod conv;
pub mod dinov2;
pub mod ip2p;
pub mod linear;
pub mod norm;
pub mod resample;
pub mod sam;
pub mod softmax;
#[cfg(test)]
mod testing;
pub mod tokenizer;
pub mod weights;
mod winograd;

pub use check::ModelConfig;
pub use weights::{default_device, Error, ModelDir};

//! InstructPix2Pix, the paper's 2D editor, from a diffusers pipeline folder as
//! published in `timbrooks/instruct-pix2pix` (`unet/`, `vae/`, `text_encoder/`,
//! `tokenizer/`, `scheduler/`).
//!
//! - [`blocks`]: diffusers' resnet, up/down-sampling and VAE attention blocks.
//! - [`unet`]: the conditional UNet (8 input channels: noisy latent + image latent).
//! - [`vae`]: the auto-encoder; the image-conditioning latent is its posterior mode.
//! - [`ddim`]: DDIM (η = 0) with the start-span usage of Instruct-NeRF2NeRF.
//! - [`pipeline`]: one edit with three-way guidance and the DiffEdit-style attention.
//! - [`editor`]: [`Ip2pEditor`], the pipeline with its CLIP text encoder as an `Editor`.

pub mod blocks;
pub mod ddim;
pub mod editor;
pub mod pipeline;
pub mod unet;
pub mod vae;

pub use ddim::{Ddim, DdimConfig};
pub use editor::{download_hint, Ip2pEditor};
pub use pipeline::{Edit, Ip2p, PromptEmbeds, Settings, DOWNLOAD_HINT};
pub use unet::{UNet, UNetConfig};
pub use vae::{Vae, VaeConfig};

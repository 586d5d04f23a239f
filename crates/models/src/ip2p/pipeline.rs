//! One InstructPix2Pix edit in the Instruct-NeRF2NeRF / Instruct-GS2GS manner: the
//! render is encoded, noised to the first timestep of a span T drawn in [0.70, 0.98] of
//! the schedule, and denoised by DDIM with three-way classifier-free guidance
//! (docs/method.md#e2-instructpix2pix; paper §"Implementation details": DDIM, 20 steps, t ∈ [0.70, 0.98]).

use candle_core::{DType, Device, Tensor};

use super::ddim::{Ddim, DdimConfig};
use super::unet::{UNet, UNetConfig};
use super::vae::{Vae, VaeConfig};
use crate::weights::{Error, ModelDir};

/// The command that downloads the InstructPix2Pix weights into `DIR`.
pub const DOWNLOAD_HINT: &str = "hf download timbrooks/instruct-pix2pix --local-dir DIR";

/// Sampling settings (defaults: the paper's).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    /// DDIM steps over the start span.
    pub steps: usize,
    /// Text guidance s_T.
    pub text_guidance: f64,
    /// Image guidance s_I.
    pub image_guidance: f64,
    /// The start span T is drawn uniformly in [t_min, t_max] × the training steps.
    pub t_min: f64,
    pub t_max: f64,
}

impl Default for Settings {
    fn default() -> Self {
        Self { steps: 20, text_guidance: 7.5, image_guidance: 1.5, t_min: 0.70, t_max: 0.98 }
    }
}

impl Settings {
    /// Errors unless the settings make sense.
    pub fn check(&self) -> Result<(), String> {
        if self.steps == 0 {
            return Err("ip2p: steps must be at least 1".into());
        }
        if !(0.0 < self.t_min && self.t_min <= self.t_max && self.t_max <= 1.0) {
            return Err(format!("ip2p: need 0 < t_min <= t_max <= 1, got [{}, {}]", self.t_min, self.t_max));
        }
        if !(self.text_guidance.is_finite() && self.image_guidance.is_finite()) {
            return Err("ip2p: guidance scales must be finite".into());
        }
        Ok(())
    }
}

/// The prompt and the empty prompt through the text encoder, `1 × tokens × dim` each.
#[derive(Debug, Clone)]
pub struct PromptEmbeds {
    pub cond: Tensor,
    pub uncond: Tensor,
}

/// The result of one edit of B images.
#[derive(Debug, Clone)]
pub struct Edit {
    /// Edited images, `B × 3 × H × W` in [0, 1].
    pub image: Tensor,
    /// Text-guidance magnitude at latent resolution, `B × 1 × h × w` (see [`Ip2p::edit`]).
    pub attention: Tensor,
}

/// The UNet, the VAE and the DDIM schedule of an InstructPix2Pix pipeline folder.
#[derive(Debug)]
pub struct Ip2p {
    pub unet: UNet,
    pub vae: Vae,
    pub ddim: Ddim,
    pub device: Device,
}

fn corrupt(dir: &ModelDir, file: &str, msg: String) -> Error {
    Error::Corrupt { path: dir.path.join(file), msg }
}

impl Ip2p {
    /// Loads `unet/` and `vae/` (fp32, fp16 or bf16 safetensors, converted to f32) and the
    /// DDIM schedule from `scheduler/scheduler_config.json` (SD 1.x values if absent).
    pub fn load(pipeline: &ModelDir, device: &Device) -> Result<Self, Error> {
        let unet_dir = pipeline.component("unet", "InstructPix2Pix UNet")?;
        let config: UNetConfig = unet_dir.config("config.json")?;
        if config.in_channels != 2 * config.out_channels {
            return Err(corrupt(
                &unet_dir,
                "config.json",
                format!(
                    "in_channels {} is not twice out_channels {}: not an InstructPix2Pix UNet",
                    config.in_channels, config.out_channels
                ),
            ));
        }
        let vb = unet_dir.var_builder("diffusion_pytorch_model", DType::F32, device)?;
        let unet = unet_dir.build(|| Ok(UNet::new(vb, config)?))?;

        let vae_dir = pipeline.component("vae", "InstructPix2Pix VAE")?;
        let config: VaeConfig = vae_dir.config("config.json")?;
        if config.latent_channels != unet.config.out_channels {
            return Err(corrupt(
                &vae_dir,
                "config.json",
                format!(
                    "latent_channels {} does not match the UNet's {} output channels",
                    config.latent_channels, unet.config.out_channels
                ),
            ));
        }
        let vb = vae_dir.var_builder("diffusion_pytorch_model", DType::F32, device)?;
        let vae = vae_dir.build(|| Ok(Vae::new(vb, config)?))?;

        let sched = pipeline.path.join("scheduler").join("scheduler_config.json");
        let config = if sched.is_file() {
            let dir = ModelDir { path: pipeline.path.join("scheduler"), ..pipeline.clone() };
            dir.config::<DdimConfig>("scheduler_config.json")?
        } else {
            DdimConfig::instruct_pix2pix()
        };
        let ddim = Ddim::new(config).map_err(|m| Error::Corrupt { path: sched, msg: m })?;
        Ok(Self { unet, vae, ddim, device: device.clone() })
    }

    /// Unscaled posterior mode of images `B × 3 × H × W` in [0, 1].
    pub fn encode(&self, image: &Tensor) -> candle_core::Result<Tensor> {
        self.vae.encode_mode(&((image * 2.0)? - 1.0)?)
    }

    /// Images in [0, 1] from diffusion latents (scaled by the VAE scaling factor).
    pub fn decode(&self, latents: &Tensor) -> candle_core::Result<Tensor> {
        let z = (latents / self.vae.config.scaling_factor)?;
        ((self.vae.decode(&z)? / 2.0)? + 0.5)?.clamp(0f32, 1f32)
    }

    /// Edits a batch of B images (`B × 3 × H × W` in [0, 1], H and W multiples of the VAE's
    /// down-scaling) for `prompt`, image b starting from its latent noised with `noise[b]`
    /// (`noise` is `B × 4 × h × w`) to the first of `settings.steps` DDIM timesteps over a
    /// span of `spans[b]` training steps. `on_step(i, n)` is called after each step;
    /// returning false stops the edit with an error.
    ///
    /// Each step runs the UNet once on a batch of 3B — (text, image), (∅, image), (∅, ∅)
    /// for every image, each at its own timestep — and combines per image
    /// ε = ε_u + s_T(ε_text − ε_img) + s_I(ε_img − ε_u) (docs/method.md#e2-instructpix2pix).
    /// The images do not interact: every layer works per batch item, so an image edited in
    /// a batch is the image edited alone up to the order of floating-point sums.
    /// The image-conditioning latent is the unscaled posterior mode; the edited latent is
    /// the mode × the scaling factor. The attention A_v (the paper's text-relevant map,
    /// §3.2) is DiffEdit-style: the channel mean of |ε_text − ε_img| averaged over steps.
    pub fn edit(
        &self,
        images: &Tensor,
        prompt: &PromptEmbeds,
        noise: &Tensor,
        spans: &[usize],
        settings: &Settings,
        on_step: &mut dyn FnMut(usize, usize) -> bool,
    ) -> candle_core::Result<Edit> {
        let b = images.dim(0)?;
        if spans.len() != b || noise.dim(0)? != b {
            candle_core::bail!("ip2p: {b} images, {} spans and {} noise maps", spans.len(), noise.dim(0)?);
        }
        let schedules = spans
            .iter()
            .map(|&span| Ok((self.ddim.timesteps(span, settings.steps)?, span / settings.steps)))
            .collect::<Result<Vec<_>, String>>()
            .map_err(candle_core::Error::Msg)?;
        let cond = self.encode(images)?;
        let scaled = (&cond * self.vae.config.scaling_factor)?;
        let per_image = |f: &dyn Fn(usize) -> candle_core::Result<Tensor>| -> candle_core::Result<Tensor> {
            Tensor::cat(&(0..b).map(f).collect::<candle_core::Result<Vec<_>>>()?, 0)
        };
        let mut latents = per_image(&|i| {
            self.ddim.add_noise(&scaled.narrow(0, i, 1)?, &noise.narrow(0, i, 1)?, schedules[i].0[0])
        })?;
        let image_cond = Tensor::cat(&[&cond, &cond, &cond.zeros_like()?], 0)?;
        let repeat = |t: &Tensor| Tensor::cat(&vec![t; b], 0);
        let context =
            Tensor::cat(&[repeat(&prompt.cond)?, repeat(&prompt.uncond)?, repeat(&prompt.uncond)?], 0)?;
        let mut attention = Tensor::zeros((b, 1, cond.dim(2)?, cond.dim(3)?), DType::F32, cond.device())?;
        for i in 0..settings.steps {
            let t: Vec<f64> = schedules.iter().map(|(ts, _)| ts[i] as f64).collect();
            let x = Tensor::cat(&[&latents, &latents, &latents], 0)?;
            let timesteps = [t.as_slice(), t.as_slice(), t.as_slice()].concat();
            let eps = self.unet.forward_at(&Tensor::cat(&[&x, &image_cond], 1)?, &timesteps, &context)?;
            let (e_text, e_img, e_u) = (eps.narrow(0, 0, b)?, eps.narrow(0, b, b)?, eps.narrow(0, 2 * b, b)?);
            let text_dir = (&e_text - &e_img)?;
            let guided = ((&e_u + (&text_dir * settings.text_guidance)?)?
                + ((&e_img - &e_u)? * settings.image_guidance)?)?;
            attention = (attention + text_dir.abs()?.mean_keepdim(1)?)?;
            latents = per_image(&|k| {
                let (ts, ratio) = &schedules[k];
                self.ddim.step(&guided.narrow(0, k, 1)?, ts[i], *ratio, &latents.narrow(0, k, 1)?)
            })?;
            if !on_step(i + 1, settings.steps) {
                return Err(candle_core::Error::Msg("interrupted".into()));
            }
        }
        let attention = (attention / settings.steps as f64)?;
        Ok(Edit { image: self.decode(&latents)?, attention })
    }
}

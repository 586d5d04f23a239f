//! [`Ip2pEditor`]: InstructPix2Pix as a transsplat [`Editor`].
//!
//! Every view is edited on its own (the UNet already runs a batch of three per step for
//! the guidance; views differ in size and start timestep), with a progress bar per
//! view. Per view, a SplitMix64 generator seeded from the editor's seed and the view
//! index draws the start span T ∈ [t_min, t_max] × 1000 and the initial noise, so an
//! edit is reproducible. The render is resized to a multiple of the VAE's down-scaling
//! (8) for the model and the edited image and attention are resized back to the view.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use candle_core::{Device, Tensor};
use transsplat_editors::{resize_bilinear, EditedView, Editor, Error as EditError, SourceView};
use transsplat_scene::rng::{mix, SplitMix64};

use super::pipeline::{Ip2p, PromptEmbeds, Settings, DOWNLOAD_HINT};
use crate::clip::ClipTextModel;
use crate::tokenizer::{ClipTokenizer, CONTEXT_LENGTH, END_OF_TEXT};
use crate::weights::{Error, ModelDir};

/// InstructPix2Pix over the views of an edit.
pub struct Ip2pEditor<'c> {
    pipeline: Ip2p,
    text: ClipTextModel,
    tokenizer: ClipTokenizer,
    settings: Settings,
    seed: u64,
    progress: bool,
    cancel: Option<&'c AtomicBool>,
}

/// The download command with the user's folder in place of `DIR`.
pub fn download_hint(dir: &Path) -> String {
    DOWNLOAD_HINT.replace("DIR", &dir.display().to_string())
}

impl<'c> Ip2pEditor<'c> {
    /// Loads the pipeline folder `dir` (`unet/`, `vae/`, `text_encoder/`, optional
    /// `scheduler/`; the CLIP vocabulary is bundled). Missing folders or files are
    /// errors naming them and the `hf download` command.
    pub fn load(dir: &Path, settings: Settings, seed: u64, device: &Device) -> Result<Self, Error> {
        settings.check().map_err(|msg| Error::Corrupt { path: dir.to_path_buf(), msg })?;
        let root = ModelDir::open(dir, "InstructPix2Pix", &download_hint(dir))?;
        let text_dir = root.component("text_encoder", "InstructPix2Pix text encoder")?;
        let text = ClipTextModel::load(&text_dir, device)?;
        let pipeline = Ip2p::load(&root, device)?;
        if text.config().hidden_size != pipeline.unet.config.cross_attention_dim {
            return Err(Error::Corrupt {
                path: text_dir.path.join("config.json"),
                msg: format!(
                    "hidden_size {} does not match the UNet's cross_attention_dim {}",
                    text.config().hidden_size,
                    pipeline.unet.config.cross_attention_dim
                ),
            });
        }
        Ok(Self {
            pipeline,
            text,
            tokenizer: ClipTokenizer::bundled(),
            settings,
            seed,
            progress: true,
            cancel: None,
        })
    }

    /// Shows (default) or hides the per-view progress bars.
    pub fn with_progress(mut self, show: bool) -> Self {
        self.progress = show;
        self
    }

    /// Stops between denoising steps once `flag` is set (the edit then errors).
    pub fn with_cancel(mut self, flag: &'c AtomicBool) -> Self {
        self.cancel = Some(flag);
        self
    }

    /// The loaded pipeline.
    pub fn pipeline(&self) -> &Ip2p {
        &self.pipeline
    }

    /// Text-encoder states of `prompt` and of the empty prompt, padded to 77 tokens with
    /// `<|endoftext|>` as the Stable Diffusion tokenizer does.
    pub fn encode_prompt(&self, prompt: &str) -> Result<PromptEmbeds, Error> {
        let ids = |t: &str| self.tokenizer.encode_padded(t, CONTEXT_LENGTH, END_OF_TEXT);
        let out = self.text.forward(&[ids(prompt), ids("")])?;
        let h = out.last_hidden_state;
        Ok(PromptEmbeds { cond: h.narrow(0, 0, 1)?, uncond: h.narrow(0, 1, 1)? })
    }

    /// The start span and initial noise of view `index` for latents of `h × w`.
    fn draw(&self, index: usize, h: usize, w: usize) -> (usize, Vec<f32>) {
        let mut rng = SplitMix64::new(mix(self.seed ^ mix(index as u64 + 1)));
        let n = self.pipeline.ddim.train_steps() as f64;
        let lo = (self.settings.t_min * n).floor() as usize;
        let hi = ((self.settings.t_max * n).floor() as usize).min(self.pipeline.ddim.train_steps());
        let span = (lo + (rng.next_u64() % (hi - lo + 1) as u64) as usize).max(self.settings.steps);
        let c = self.pipeline.unet.config.out_channels;
        let noise = (0..c * h * w).map(|_| rng.normal()).collect();
        (span, noise)
    }

    /// Edits one view: the edited image and A_v at the view's size.
    pub fn edit_view(&self, view: &SourceView, prompt: &PromptEmbeds) -> Result<EditedView, EditError> {
        view.check()?;
        let (w, h) = view.size();
        let f = self.pipeline.vae.config.downscale();
        let round = |v: usize| ((v + f / 2) / f).max(1) * f;
        let (mw, mh) = (round(w), round(h));
        let fail = |e: &dyn std::fmt::Display| {
            EditError::Invalid(format!("ip2p: view {} ({}): {e}", view.index, view.camera.name))
        };
        let pixels = resize_bilinear(view.image, w, h, 3, mw, mh);
        let device = &self.pipeline.device;
        let image = Tensor::from_vec(pixels, (1, mh, mw, 3), device)
            .and_then(|t| t.permute((0, 3, 1, 2)))
            .map_err(|e| fail(&e))?;
        let (span, noise) = self.draw(view.index, mh / f, mw / f);
        let c = self.pipeline.unet.config.out_channels;
        let noise = Tensor::from_vec(noise, (1, c, mh / f, mw / f), device).map_err(|e| fail(&e))?;

        let bar = if self.progress {
            let bar = indicatif::ProgressBar::new(self.settings.steps as u64);
            bar.set_style(
                indicatif::ProgressStyle::with_template(
                    "{msg} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta}",
                )
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            bar.set_message(format!("ip2p view {} ({})", view.index, view.camera.name));
            bar
        } else {
            indicatif::ProgressBar::hidden()
        };
        let cancel = self.cancel;
        let mut cancelled = false;
        let result = self.pipeline.edit(&image, prompt, &noise, span, &self.settings, &mut |i, _| {
            bar.set_position(i as u64);
            cancelled = cancel.is_some_and(|c| c.load(Ordering::SeqCst));
            !cancelled
        });
        bar.finish_and_clear();
        if cancelled {
            return Err(EditError::Invalid("ip2p: interrupted".into()));
        }
        let edit = result.map_err(|e| fail(&e))?;
        let to_vec = |t: &Tensor| -> candle_core::Result<Vec<f32>> {
            t.squeeze(0)?.permute((1, 2, 0))?.contiguous()?.flatten_all()?.to_vec1::<f32>()
        };
        let edited = to_vec(&edit.image).map_err(|e| fail(&e))?;
        let attention = to_vec(&edit.attention).map_err(|e| fail(&e))?;
        let image = resize_bilinear(&edited, mw, mh, 3, w, h);
        let attention = resize_bilinear(&attention, mw / f, mh / f, 1, w, h);
        tracing::debug!("ip2p view {}: span {span}, {}x{} at {mw}x{mh}", view.index, w, h);
        Ok(EditedView::new(image, w, h, attention, None))
    }
}

impl Editor for Ip2pEditor<'_> {
    fn name(&self) -> &str {
        "ip2p"
    }

    fn edit(&mut self, views: &[SourceView], prompt: &str) -> Result<Vec<Option<EditedView>>, EditError> {
        if prompt.trim().is_empty() {
            return Err(EditError::Instruction("ip2p: the edit instruction is empty".into()));
        }
        let embeds = self.encode_prompt(prompt).map_err(|e| EditError::Invalid(format!("ip2p: {e}")))?;
        views.iter().map(|v| self.edit_view(v, &embeds).map(Some)).collect()
    }
}

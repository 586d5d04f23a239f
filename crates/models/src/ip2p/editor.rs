//! [`Ip2pEditor`]: InstructPix2Pix as a transsplat [`Editor`].
//!
//! Views are edited in batches of up to [`Ip2pEditor::with_batch`] views of the same
//! model size: the UNet then runs 3 × views per step (the guidance's three branches for
//! each view, each view at its own timestep), on one progress bar over every view's DDIM
//! steps (views done, the step, the editor stage's ETA). Per view, a
//! SplitMix64 generator seeded from the editor's seed and the view index draws the start
//! span T ∈ [t_min, t_max] × 1000 and the initial noise, so an edit is reproducible and
//! does not depend on the batch a view falls in (the pipeline keeps the images apart:
//! [`Ip2p::edit`]). The render is resized to a multiple of the VAE's down-scaling (8) for
//! the model and the edited image and attention are resized back to the view.

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
    batch: usize,
    /// The bar of the views announced by [`Editor::expect_views`] and how many of them
    /// are done, kept across calls.
    stage: Option<(indicatif::ProgressBar, usize)>,
}

/// Views per UNet call unless [`Ip2pEditor::with_batch`] says otherwise.
pub const DEFAULT_BATCH: usize = 1;

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
        Self::from_parts(pipeline, text, settings, seed)
            .map_err(|msg| Error::Corrupt { path: text_dir.path.join("config.json"), msg })
    }

    /// The editor over a pipeline and text encoder built elsewhere (random weights in
    /// `transsplat bench edit --editor ip2p`); errors when the text encoder's width is not
    /// the UNet's cross-attention width.
    pub fn from_parts(
        pipeline: Ip2p,
        text: ClipTextModel,
        settings: Settings,
        seed: u64,
    ) -> Result<Self, String> {
        settings.check()?;
        if text.config().hidden_size != pipeline.unet.config.cross_attention_dim {
            return Err(format!(
                "hidden_size {} does not match the UNet's cross_attention_dim {}",
                text.config().hidden_size,
                pipeline.unet.config.cross_attention_dim
            ));
        }
        Ok(Self {
            pipeline,
            text,
            tokenizer: ClipTokenizer::bundled(),
            settings,
            seed,
            progress: true,
            cancel: None,
            batch: DEFAULT_BATCH,
            stage: None,
        })
    }

    /// Shows (default) or hides the progress bar.
    pub fn with_progress(mut self, show: bool) -> Self {
        self.progress = show;
        self
    }

    /// Stops between denoising steps once `flag` is set (the edit then errors).
    pub fn with_cancel(mut self, flag: &'c AtomicBool) -> Self {
        self.cancel = Some(flag);
        self
    }

    /// Edits up to `views` views (of the same size) per pipeline call (at least 1).
    pub fn with_batch(mut self, views: usize) -> Self {
        self.batch = views.max(1);
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

    /// The model's size for a `w × h` view: each side rounded to a multiple of the VAE's
    /// down-scaling.
    fn model_size(&self, w: usize, h: usize) -> (usize, usize) {
        let f = self.pipeline.vae.config.downscale();
        let round = |v: usize| ((v + f / 2) / f).max(1) * f;
        (round(w), round(h))
    }

    /// Edits `views` (of the same model size) in one pipeline call: the edited images and
    /// A_v at each view's size.
    pub fn edit_views(
        &self,
        views: &[&SourceView],
        prompt: &PromptEmbeds,
    ) -> Result<Vec<EditedView>, EditError> {
        let bar = self.bar(views.len());
        let out = self.edit_batch(views, prompt, &bar, 0);
        bar.finish_and_clear();
        out
    }

    /// A bar over the DDIM steps of `views` views (hidden without progress): its ETA is
    /// the editor stage's, its message the views done.
    fn bar(&self, views: usize) -> indicatif::ProgressBar {
        if !self.progress {
            return indicatif::ProgressBar::hidden();
        }
        let bar = indicatif::ProgressBar::new((self.settings.steps * views) as u64);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{msg} [{bar:30}] DDIM step {pos}/{len} {elapsed_precise} eta {eta}",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar.set_message(format!("ip2p: 0/{views} views done"));
        bar
    }

    /// [`Self::edit_views`] on `bar`, whose first `done` views are finished.
    fn edit_batch(
        &self,
        views: &[&SourceView],
        prompt: &PromptEmbeds,
        bar: &indicatif::ProgressBar,
        done: usize,
    ) -> Result<Vec<EditedView>, EditError> {
        let Some(first) = views.first() else { return Ok(Vec::new()) };
        for v in views {
            v.check()?;
        }
        let (w0, h0) = first.size();
        let (mw, mh) = self.model_size(w0, h0);
        let f = self.pipeline.vae.config.downscale();
        let names: Vec<String> = views.iter().map(|v| format!("{} ({})", v.index, v.camera.name)).collect();
        let fail = |e: &dyn std::fmt::Display| {
            let which = if views.len() == 1 { "view" } else { "views" };
            EditError::Invalid(format!("ip2p: {which} {}: {e}", names.join(", ")))
        };
        let device = &self.pipeline.device;
        let c = self.pipeline.unet.config.out_channels;
        let (mut pixels, mut noise, mut spans) = (Vec::new(), Vec::new(), Vec::new());
        for v in views {
            let (w, h) = v.size();
            if self.model_size(w, h) != (mw, mh) {
                return Err(fail(&"a batch must share one model size"));
            }
            pixels.extend(resize_bilinear(v.image, w, h, 3, mw, mh));
            let (span, n) = self.draw(v.index, mh / f, mw / f);
            noise.extend(n);
            spans.push(span);
        }
        let b = views.len();
        let image = Tensor::from_vec(pixels, (b, mh, mw, 3), device)
            .and_then(|t| t.permute((0, 3, 1, 2)))
            .map_err(|e| fail(&e))?;
        let noise = Tensor::from_vec(noise, (b, c, mh / f, mw / f), device).map_err(|e| fail(&e))?;

        let total = bar.length().unwrap_or(0) / self.settings.steps.max(1) as u64;
        bar.set_message(format!("ip2p: {done}/{total} views done, editing {}", names.join(", ")));
        let start = (done * self.settings.steps) as u64;
        let cancel = self.cancel;
        let mut cancelled = false;
        let result = self.pipeline.edit(&image, prompt, &noise, &spans, &self.settings, &mut |i, _| {
            bar.set_position(start + i as u64);
            cancelled = cancel.is_some_and(|c| c.load(Ordering::SeqCst));
            !cancelled
        });
        if cancelled {
            return Err(EditError::Invalid("ip2p: interrupted".into()));
        }
        let edit = result.map_err(|e| fail(&e))?;
        bar.set_position(start + self.settings.steps as u64);
        bar.set_message(format!("ip2p: {}/{total} views done", done + b));
        let to_vec = |t: &Tensor, k: usize| -> candle_core::Result<Vec<f32>> {
            t.narrow(0, k, 1)?.squeeze(0)?.permute((1, 2, 0))?.contiguous()?.flatten_all()?.to_vec1::<f32>()
        };
        let mut out = Vec::with_capacity(b);
        for (k, v) in views.iter().enumerate() {
            let (w, h) = v.size();
            let edited = to_vec(&edit.image, k).map_err(|e| fail(&e))?;
            let attention = to_vec(&edit.attention, k).map_err(|e| fail(&e))?;
            let image = resize_bilinear(&edited, mw, mh, 3, w, h);
            let attention = resize_bilinear(&attention, mw / f, mh / f, 1, w, h);
            tracing::debug!("ip2p view {}: span {}, {w}x{h} at {mw}x{mh}", v.index, spans[k]);
            out.push(EditedView::new(image, w, h, attention, None));
        }
        Ok(out)
    }

    /// Edits one view: the edited image and A_v at the view's size.
    pub fn edit_view(&self, view: &SourceView, prompt: &PromptEmbeds) -> Result<EditedView, EditError> {
        Ok(self.edit_views(&[view], prompt)?.remove(0))
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
        // consecutive views of one model size, up to `batch` at a time, on one bar: the
        // announced stage's if these views fit in what is left of it
        let (bar, first) = match self.stage.take() {
            Some((bar, done))
                if done + views.len() <= bar.length().unwrap_or(0) as usize / self.settings.steps.max(1) =>
            {
                (bar, done)
            }
            Some((bar, _)) => {
                bar.finish_and_clear();
                (self.bar(views.len()), 0)
            }
            None => (self.bar(views.len()), 0),
        };
        let mut out = Vec::with_capacity(views.len());
        let mut batch: Vec<&SourceView> = Vec::new();
        for v in views {
            let size = |v: &SourceView| {
                let (w, h) = v.size();
                self.model_size(w, h)
            };
            if batch.len() == self.batch || batch.first().is_some_and(|f| size(f) != size(v)) {
                let edited = self.edit_batch(&batch, &embeds, &bar, first + out.len());
                out.extend(edited.inspect_err(|_| bar.abandon())?.into_iter().map(Some));
                batch.clear();
            }
            batch.push(v);
        }
        let edited = self.edit_batch(&batch, &embeds, &bar, first + out.len());
        out.extend(edited.inspect_err(|_| bar.abandon())?.into_iter().map(Some));
        let done = first + out.len();
        if done * self.settings.steps < bar.length().unwrap_or(0) as usize {
            self.stage = Some((bar, done));
        } else {
            bar.finish_and_clear();
        }
        Ok(out)
    }

    fn expect_views(&mut self, views: usize) {
        if let Some((bar, _)) = self.stage.take() {
            bar.finish_and_clear();
        }
        self.stage = Some((self.bar(views), 0));
    }
}

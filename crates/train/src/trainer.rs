//! One optimisation step, usable by other crates.
//!
//! [`Trainer::step`] does what one INRIA `train.py` iteration does: raise the SH
//! degree on schedule, render, loss, backward, Adam, densification statistics,
//! densify/prune, opacity reset. Callers that add their own loss terms (the edit
//! engine) split it up:
//!
//! ```text
//! let step = trainer.begin_step();                    // schedule: SH degree, learning rates
//! let mut pass = trainer.forward_backward(&cam, &target, weights);  // image loss + grads
//! // ... add their own terms into pass.grads (sh, features, ...), or render and
//! // call trainer.backward(...) with their own image gradients ...
//! let report = trainer.finish_step(&pass.grads, Some(&pass.rows), Some(&pass.frame), densify_mask)?;
//! // report.reindex: apply it to any per-Gaussian array kept outside the model
//! ```
//!
//! Order within a step: INRIA densifies after the backward pass and before the
//! optimiser step (so the Adam update of that iteration is lost for the tensors it
//! replaces); we take the Adam step first, then densify. Gaussians added or removed
//! are applied to the model, the Adam moments and the statistics by
//! [`apply_reindex`].

use crate::adam::{Adam, AdamRule, Group, LearningRates, NonFinite, Update};
use crate::densify::{self, Bounds, DensifyConfig, DensifyCounts, DensifyStats};
use crate::filter3d;
use crate::loss::{image_loss, ImageLoss};
use crate::mcmc::{self, McmcConfig};
use crate::model::{Model, Reindex};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use transsplat_raster::{
    backward, render, ClampGrad, Frame, Grads, Image, ImageGrads, RenderOptions, Splats,
};
use transsplat_scene::Camera;

/// Everything that shapes a training run.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainConfig {
    /// Length of the run (sets the position learning-rate decay unless
    /// `lr.position_max_steps` is given).
    pub iterations: u64,
    pub lr: LearningRates,
    pub densify: DensifyConfig,
    /// Weight λ of D-SSIM in `(1 − λ) L1 + λ D-SSIM`.
    pub lambda_dssim: f32,
    /// Background colour behind the Gaussians.
    pub background: [f32; 3],
    /// Seed of every random choice (split samples, view order).
    pub seed: u64,
    /// Adam's update rule (dense as INRIA, or selective: only the rows a step reached).
    pub adam: AdamRule,
    /// Coarse-to-fine training resolution (off by default, as INRIA).
    pub downscale: Downscale,
    /// How the colour clamp at 0 passes gradients to the SH coefficients
    /// (docs/method.md#m11-colour-clamp): `Exact` by default (INRIA's and gsplat's; in
    /// training, `Revive` lets floaters survive as haze); the edit uses `Revive`.
    pub clamp_grad: ClampGrad,
    /// How the Gaussians grow: INRIA's adaptive density control (default) or MCMC.
    pub strategy: Strategy,
    /// Mip-Splatting's 3D smoothing filter ([`crate::filter3d`]): the variance factor s
    /// in squared pixels (Mip-Splatting: 0.2); 0 = off (default, as INRIA; docs/method.md
    /// T3, T5). Needs the training cameras ([`Trainer::for_cameras`]).
    pub filter_3d: f32,
}

/// The densification strategy: one pluggable part of the step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Strategy {
    /// INRIA's clone / split / prune / opacity reset on the mean positional gradient
    /// ([`crate::densify`]).
    #[default]
    Adaptive,
    /// Relocation of dead Gaussians and growth up to
    /// [`DensifyConfig::max_gaussians`] (default [`crate::mcmc::DEFAULT_CAP`]), position
    /// noise and opacity / scale regularisers ([`crate::mcmc`]). Uses the densification
    /// window and interval of [`DensifyConfig`] and its `min_opacity` as the dead
    /// threshold; no gradient statistics, no opacity reset, no size pruning.
    Mcmc(McmcConfig),
}

impl Strategy {
    /// Every strategy, with default settings.
    pub fn all() -> [Strategy; 2] {
        [Strategy::Adaptive, Strategy::Mcmc(McmcConfig::default())]
    }

    /// The strategy called `name`, with default settings.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::all().into_iter().find(|s| s.name() == name)
    }

    /// Its name.
    pub fn name(&self) -> &'static str {
        match self {
            Strategy::Adaptive => "adaptive",
            Strategy::Mcmc(_) => "mcmc",
        }
    }
}

/// Coarse-to-fine training as nerfstudio's splatfacto and OpenSplat do it
/// (`num_downscales`, `resolution_schedule`): the first `every` steps train on images
/// divided by 2^`levels`, the next `every` by 2^(`levels` − 1), and so on to full
/// resolution. Densification statistics are in NDC units, so the gradient threshold
/// means the same at every level.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Downscale {
    /// Halvings at the start (0 = full resolution throughout).
    pub levels: u32,
    /// Steps per level.
    pub every: u64,
}

impl Downscale {
    /// The image divisor for the step after `step` steps: 2^(levels − step / every),
    /// at least 1.
    pub fn factor(&self, step: u64) -> u32 {
        if self.levels == 0 || self.every == 0 {
            return 1;
        }
        let done = (step / self.every).min(self.levels as u64) as u32;
        1 << (self.levels - done).min(16)
    }
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            iterations: 30_000,
            lr: LearningRates::default(),
            densify: DensifyConfig::default(),
            lambda_dssim: 0.2,
            background: [0.0; 3],
            seed: 0,
            adam: AdamRule::Dense,
            downscale: Downscale::default(),
            clamp_grad: ClampGrad::Exact,
            strategy: Strategy::Adaptive,
            filter_3d: 0.0,
        }
    }
}

/// Errors of an optimisation step or run.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// A loss, gradient or parameter became NaN or infinite; `what` names it and its
    /// parameter group, e.g. "the gradient of the scales".
    #[error("step {step}: {what} became NaN or infinite; lower the learning rates or check the inputs")]
    NonFinite { step: u64, what: String },
    /// Inputs that do not fit together (sizes, lengths).
    #[error("{0}")]
    Mismatch(String),
    /// Stopped by the caller (Ctrl-C or a requested stop) with `step` steps done.
    #[error("interrupted after step {step}")]
    Interrupted { step: u64 },
    /// A checkpoint that cannot be used to resume this run.
    #[error("{0}")]
    Resume(String),
    /// Reading or writing a checkpoint failed (the message names the file).
    #[error(transparent)]
    Checkpoint(#[from] transsplat_scene::Error),
    /// A setting out of its range ([`TrainConfig::validate`]).
    #[error(transparent)]
    Setting(#[from] InvalidSetting),
}

/// A training setting out of its range: `key` names it as the config does
/// (`densify.min_opacity`), so each front can name it its own way (a flag, a keyword).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{key} {problem}")]
pub struct InvalidSetting {
    pub key: &'static str,
    /// What is wrong, e.g. "must be in [0, 1), got 1.5".
    pub problem: String,
}

/// The largest [`TrainConfig::filter_3d`]: a filter of 10 squared pixels blurs every
/// Gaussian to about three pixels in the nearest camera.
pub const MAX_FILTER_3D: f32 = 10.0;

/// The most halvings [`Downscale::levels`] may ask for (1/64 of the size).
pub const MAX_DOWNSCALES: u32 = 6;

impl TrainConfig {
    /// Checks every setting against its range, naming the first one out of it (as
    /// `EditConfig::validate` does for the edit).
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        let bad = |key: &'static str, problem: String| Err(InvalidSetting { key, problem });
        let d = &self.densify;
        if self.iterations == 0 {
            return bad("iterations", "must be at least 1".into());
        }
        if !(self.lr.opacity.is_finite() && self.lr.opacity >= 0.0) {
            return bad("lr.opacity", format!("must be a non-negative number, got {}", self.lr.opacity));
        }
        if !(d.grad_threshold.is_finite() && d.grad_threshold > 0.0) {
            return bad("densify.grad_threshold", format!("must be positive, got {}", d.grad_threshold));
        }
        if !(0.0..1.0).contains(&d.min_opacity) {
            return bad("densify.min_opacity", format!("must be in [0, 1), got {}", d.min_opacity));
        }
        if let Some(k) = d.camera_reach.filter(|k| !(k.is_finite() && *k > 0.0)) {
            return bad("densify.camera_reach", format!("must be positive (or off), got {k}"));
        }
        if let Some(r) = d.max_screen_radius.filter(|r| !(r.is_finite() && *r > 0.0)) {
            return bad("densify.max_screen_radius", format!("must be positive (or off), got {r}"));
        }
        if self.downscale.levels > MAX_DOWNSCALES {
            return bad(
                "downscale.levels",
                format!("must be at most {MAX_DOWNSCALES}, got {}", self.downscale.levels),
            );
        }
        if self.downscale.levels > 0 && self.downscale.every == 0 {
            return bad(
                "downscale.every",
                format!("must be at least 1 with {} levels", self.downscale.levels),
            );
        }
        if !(0.0..=1.0).contains(&self.lambda_dssim) {
            return bad("lambda_dssim", format!("must be in [0, 1], got {}", self.lambda_dssim));
        }
        if !(self.filter_3d.is_finite() && (0.0..=MAX_FILTER_3D).contains(&self.filter_3d)) {
            return bad("filter_3d", format!("must be in [0, {MAX_FILTER_3D}], got {}", self.filter_3d));
        }
        if !self.background.iter().all(|c| c.is_finite()) {
            return bad("background", format!("must be finite, got {:?}", self.background));
        }
        Ok(())
    }
}

/// Rendering, loss and gradients of one view.
#[derive(Clone, Debug)]
pub struct ViewPass {
    pub image: Image,
    pub frame: Frame,
    pub loss: ImageLoss,
    /// Gradients of the image loss with respect to every parameter.
    pub grads: Grads,
    /// The rows of `grads` the backward pass wrote (ascending; see
    /// [`transsplat_raster::backward`]).
    pub rows: Vec<u32>,
}

/// What a step did.
#[derive(Clone, Debug, Default)]
pub struct StepReport {
    /// The step number (1-based, as INRIA's iteration).
    pub step: u64,
    /// Image loss of the step (0 when the caller computed its own loss).
    pub loss: f32,
    /// Set when Gaussians were added or removed: apply it to outside arrays.
    pub reindex: Option<Reindex>,
    pub densified: Option<DensifyCounts>,
    pub opacity_reset: bool,
    /// Number of Gaussians after the step.
    pub gaussians: usize,
}

/// The model with its optimiser state and schedule.
#[derive(Clone, Debug)]
pub struct Trainer {
    pub model: Model,
    pub adam: Adam,
    pub stats: DensifyStats,
    pub config: TrainConfig,
    /// Scene extent (INRIA `cameras_extent`): scales position learning rates and
    /// the clone/split and prune thresholds.
    pub extent: f32,
    /// Steps begun so far (the current step number once [`Trainer::begin_step`] ran).
    pub step: u64,
    pub active_sh_degree: u32,
    pub rng: ChaCha8Rng,
    /// Mean of the camera centres, when the trainer was made from cameras
    /// ([`Trainer::for_cameras`]): scales the world-size prune rule with distance
    /// (`densify` module doc).
    pub centre: Option<[f32; 3]>,
    /// The training cameras' centres, when made from cameras: the camera-reach prune
    /// rule (`densify` module doc).
    pub cameras: Vec<[f32; 3]>,
    /// Gradient buffer reused by [`Trainer::step`], all zero between steps (only the
    /// rows a step wrote are cleared after it, so a step's cost does not grow with
    /// the Gaussians its view did not reach). Empty until the first step.
    scratch: Grads,
    /// The 3D filter's cameras and the filtered parameters the rasterizer sees, when
    /// `config.filter_3d > 0` and the cameras are known.
    filter: Option<Filter>,
}

/// The state of [`crate::filter3d`] in a trainer: the training cameras (the variances
/// are recomputed from them), the variances (a copy of the model's carried column, which
/// checkpoints and rearrangements keep), and the filtered log-scales and opacity logits,
/// refreshed whenever the raw ones change.
#[derive(Clone, Debug)]
struct Filter {
    cameras: Vec<Camera>,
    variance: Vec<f32>,
    log_scales: Vec<[f32; 3]>,
    opacity_logits: Vec<f32>,
}

/// Where [`Trainer::refresh_filter`] takes the variances from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Variances {
    /// Computed again from the means and the cameras (and carried).
    Recompute,
    /// Read back from the carried column, after a rearrangement of the rows.
    Carried,
    /// Unchanged since the last refresh: only the raw parameters moved.
    Kept,
}

/// Applies `r` to every per-Gaussian array: the model's ([`Model::reindex`]), the
/// Adam moments ([`Adam::reindex`]) and the densification statistics
/// ([`DensifyStats::reindex`]). The one place where Gaussians are added or removed.
pub fn apply_reindex(model: &mut Model, adam: &mut Adam, stats: &mut DensifyStats, r: &Reindex) {
    model.reindex(r);
    adam.reindex(r);
    stats.reindex(r);
}

/// The mean of the camera centres (None without cameras).
pub fn camera_centre(cameras: &[Camera]) -> Option<[f32; 3]> {
    let n = cameras.len() as f32;
    (!cameras.is_empty())
        .then(|| std::array::from_fn(|k| cameras.iter().map(|c| c.centre()[k]).sum::<f32>() / n))
}

/// INRIA's `getNerfppNorm` radius: 1.1 × the largest distance of a camera centre
/// from their mean (1 when degenerate).
pub fn scene_extent(cameras: &[Camera]) -> f32 {
    let Some(mean) = camera_centre(cameras) else {
        return 1.0;
    };
    let centres: Vec<[f32; 3]> = cameras.iter().map(Camera::centre).collect();
    let diag = centres
        .iter()
        .map(|c| ((c[0] - mean[0]).powi(2) + (c[1] - mean[1]).powi(2) + (c[2] - mean[2]).powi(2)).sqrt())
        .fold(0.0f32, f32::max);
    let r = 1.1 * diag;
    if r.is_finite() && r > 1e-6 {
        r
    } else {
        1.0
    }
}

impl Trainer {
    /// Starts training `model` in a scene of size `extent`.
    pub fn new(model: Model, extent: f32, config: TrainConfig) -> Result<Self, TrainError> {
        config.validate()?;
        model.validate().map_err(TrainError::Mismatch)?;
        if !(extent.is_finite() && extent > 0.0) {
            return Err(TrainError::Mismatch(format!("scene extent {extent} is not positive")));
        }
        let adam = Adam::new(&model);
        let stats = DensifyStats::new(model.len());
        let active_sh_degree =
            if config.densify.sh_degree_interval == 0 { model.gaussians.sh_degree } else { 0 };
        let rng = ChaCha8Rng::seed_from_u64(config.seed);
        let scratch = Grads::default();
        let (centre, cameras) = (None, Vec::new());
        Ok(Trainer {
            model,
            adam,
            stats,
            config,
            extent,
            step: 0,
            active_sh_degree,
            rng,
            centre,
            cameras,
            scratch,
            filter: None,
        })
    }

    /// Starts training `model` for a scene seen by `cameras`: the extent is INRIA's
    /// ([`scene_extent`]) and the cameras' centre scales the world-size prune rule.
    pub fn for_cameras(model: Model, cameras: &[Camera], config: TrainConfig) -> Result<Self, TrainError> {
        let mut t = Trainer::new(model, scene_extent(cameras), config)?;
        t.centre = camera_centre(cameras);
        t.cameras = cameras.iter().map(Camera::centre).collect();
        t.attach_filter(cameras);
        Ok(t)
    }

    /// Turns the 3D filter on with `cameras` when the config asks for it: the carried
    /// variances are kept when the model has them (a resumed run), computed otherwise.
    pub fn attach_filter(&mut self, cameras: &[Camera]) {
        if self.config.filter_3d <= 0.0 || cameras.is_empty() {
            return;
        }
        self.filter = Some(Filter {
            cameras: cameras.to_vec(),
            variance: Vec::new(),
            log_scales: Vec::new(),
            opacity_logits: Vec::new(),
        });
        let carried = filter3d::carried(&self.model.gaussians).is_some_and(|v| v.len() == self.model.len());
        self.refresh_filter(if carried { Variances::Carried } else { Variances::Recompute });
    }

    /// Brings the filter's variances (from `source`) and filtered parameters up to date
    /// with the model.
    fn refresh_filter(&mut self, source: Variances) {
        let Some(f) = self.filter.as_mut() else { return };
        let g = &mut self.model.gaussians;
        match source {
            Variances::Recompute => {
                f.variance = filter3d::variances(&g.means, &f.cameras, self.config.filter_3d);
                filter3d::carry(g, &f.variance);
            }
            Variances::Carried => f.variance = filter3d::carried(g).unwrap_or_else(|| vec![0.0; g.len()]),
            Variances::Kept => {}
        }
        filter3d::filter_all(g, &f.variance, &mut f.log_scales, &mut f.opacity_logits);
    }

    /// Turns gradients with respect to what the rasterizer saw into gradients with
    /// respect to the raw parameters: the identity without the 3D filter,
    /// [`filter3d::pull_back`] with it. [`Trainer::step`] does this; a caller of
    /// [`Trainer::finish_step`] with its own backward passes must too.
    pub fn pull_back(&self, grads: &mut Grads, rows: Option<&[u32]>) {
        if let Some(f) = &self.filter {
            filter3d::pull_back(&self.model.gaussians, &f.variance, grads, rows);
        }
    }

    /// The model as a renderer without the 3D filter should draw it: the filter baked in
    /// ([`filter3d::bake`]); the model itself without it.
    pub fn exported(&self) -> std::borrow::Cow<'_, transsplat_scene::Gaussians> {
        match self.filter {
            Some(_) => std::borrow::Cow::Owned(filter3d::bake(&self.model.gaussians)),
            None => std::borrow::Cow::Borrowed(&self.model.gaussians),
        }
    }

    /// The scene's size for densification.
    pub fn bounds(&self) -> Bounds {
        Bounds { extent: self.extent, centre: self.centre, cameras: self.cameras.clone() }
    }

    /// The rasterizer's view of the model at the active SH degree.
    pub fn splats(&self) -> Splats<'_> {
        let s = self.model.splats(self.active_sh_degree);
        match &self.filter {
            Some(f) => Splats { log_scales: &f.log_scales, opacity_logits: &f.opacity_logits, ..s },
            None => s,
        }
    }

    /// Render options (the configured background).
    pub fn render_options(&self) -> RenderOptions {
        RenderOptions { background: self.config.background }
    }

    /// Renders a view with the current model.
    pub fn render(&self, cam: &Camera) -> (Image, Frame) {
        render(&self.splats(), cam, &self.render_options())
    }

    /// All-zero gradients shaped like the model.
    pub fn zero_grads(&self) -> Grads {
        Grads::zeros(self.model.len(), self.model.gaussians.sh_degree, self.model.num_features)
    }

    /// Learning rate of each group at the current step ([`Group::index`] order).
    pub fn learning_rates(&self) -> [f32; 7] {
        self.config.lr.at(self.step, self.config.iterations, self.extent)
    }

    /// Begins a step: advances the counter and raises the SH degree every
    /// `sh_degree_interval` steps (INRIA `oneupSHdegree`). Returns the step number.
    pub fn begin_step(&mut self) -> u64 {
        self.step += 1;
        let every = self.config.densify.sh_degree_interval;
        if every > 0 && self.step.is_multiple_of(every) {
            self.active_sh_degree = (self.active_sh_degree + 1).min(self.model.gaussians.sh_degree);
        }
        self.step
    }

    /// Renders `cam`, computes the image loss against `target` (`H × W × 3`, optional
    /// per-pixel `weights`) and backpropagates it to every parameter.
    pub fn forward_backward(
        &self,
        cam: &Camera,
        target: &[f32],
        weights: Option<&[f32]>,
    ) -> Result<ViewPass, TrainError> {
        let mut grads = self.zero_grads();
        let (image, frame, loss, rows) = self.pass_into(cam, target, weights, &mut grads)?;
        Ok(ViewPass { image, frame, loss, grads, rows })
    }

    /// [`Trainer::forward_backward`] adding into `grads`; returns the rows written.
    fn pass_into(
        &self,
        cam: &Camera,
        target: &[f32],
        weights: Option<&[f32]>,
        grads: &mut Grads,
    ) -> Result<(Image, Frame, ImageLoss, Vec<u32>), TrainError> {
        let px = cam.width as usize * cam.height as usize;
        if target.len() != px * 3 || weights.is_some_and(|w| w.len() != px) {
            return Err(TrainError::Mismatch(format!(
                "target image for camera {:?} does not match its size {}x{}",
                cam.name, cam.width, cam.height
            )));
        }
        let (image, frame) = self.render(cam);
        let loss =
            image_loss(&image.rgb, target, image.width, image.height, weights, self.config.lambda_dssim);
        let rows = self.backward(cam, &frame, &ImageGrads { rgb: &loss.grad, ..Default::default() }, grads);
        Ok((image, frame, loss, rows))
    }

    /// Backward pass of a render of `cam` with caller-supplied image gradients
    /// (RGB, alpha, depth, features), accumulated into `grads`, through the colour
    /// clamp by the trainer's rule (`config.clamp_grad`, whatever `image_grads.clamp`
    /// says); returns the rows it wrote (ascending).
    pub fn backward(
        &self,
        cam: &Camera,
        frame: &Frame,
        image_grads: &ImageGrads,
        grads: &mut Grads,
    ) -> Vec<u32> {
        let image_grads = ImageGrads { clamp: self.config.clamp_grad, ..*image_grads };
        backward(&self.splats(), cam, frame, &image_grads, grads)
    }

    /// Finishes a step begun with [`Trainer::begin_step`]: records densification
    /// statistics from `grads.means2d` and `frame` (the step's render; `None` only
    /// when no statistics are due, e.g. a step rendered by blend weights with frozen
    /// geometry), takes the Adam step, then
    /// densifies / prunes / resets opacity on schedule. `densify_mask` restricts
    /// which Gaussians may be cloned, split, pruned or reset. A NaN or infinite
    /// gradient or parameter (both found in the Adam step's own pass, after the update:
    /// the model is then not fit to continue from) is a [`TrainError::NonFinite`] naming
    /// the step and the parameter group.
    ///
    /// `rows`, when known, lists (ascending) every row where `grads` may be non-zero (what
    /// the backward passes returned): Adam then visits only those (selective) or those
    /// and the rows whose moments are live (dense, where few rows are; otherwise it
    /// reads every row in order, which is faster there and gives the same bits).
    pub fn finish_step(
        &mut self,
        grads: &Grads,
        rows: Option<&[u32]>,
        frame: Option<&Frame>,
        densify_mask: Option<&[bool]>,
    ) -> Result<StepReport, TrainError> {
        let n = self.model.len();
        if grads.means.len() != n || grads.means2d.len() != n || frame.is_some_and(|f| f.radii().len() != n) {
            return Err(TrainError::Mismatch(format!(
                "gradients or frame were made for a different number of Gaussians than the model's {n}"
            )));
        }
        if densify_mask.is_some_and(|m| m.len() != n) {
            return Err(TrainError::Mismatch(format!("densification mask does not have {n} entries")));
        }
        let step = self.step;
        let lr = self.learning_rates();
        let d = self.config.densify.clone();
        let adaptive = self.config.strategy == Strategy::Adaptive;
        if adaptive && d.records(step) {
            let frame = frame.ok_or_else(|| {
                TrainError::Mismatch("densification statistics need the step's frame".into())
            })?;
            self.stats.record(
                &grads.means2d,
                frame.radii(),
                frame.binned.width as u32,
                frame.binned.height as u32,
            );
        }
        // Densification and the opacity reset copy or set finite values, so the update is
        // the only place a finite model can turn NaN or infinite.
        let update = match self.config.adam {
            AdamRule::Dense => Update::Dense(rows),
            AdamRule::Selective => Update::Selective(rows),
        };
        if let Some(bad) = self.adam.step(&mut self.model, grads, &lr, update) {
            let what = match bad {
                NonFinite::Gradient(g) => format!("the gradient of the {}", g.name()),
                NonFinite::Parameter(g) => format!("the {}", g.name()),
            };
            return Err(TrainError::NonFinite { step, what });
        }
        let mut report = StepReport { step, ..Default::default() };
        if d.densifies(step) {
            let (r, counts) = match self.config.strategy {
                Strategy::Adaptive => self.densify_and_prune(densify_mask),
                Strategy::Mcmc(_) => self.relocate_and_grow(densify_mask),
            };
            report.reindex = Some(r);
            report.densified = Some(counts);
        }
        if let Strategy::Mcmc(m) = self.config.strategy {
            mcmc::inject_noise(
                &mut self.model.gaussians,
                m.noise_lr * lr[Group::Position.index()],
                &mut self.rng,
            );
        }
        if adaptive && d.resets_opacity(step, self.config.iterations) {
            // The mask refers to the rows before densification.
            let mask = match (&report.reindex, densify_mask) {
                (Some(r), Some(m)) => Some(r.src.iter().map(|&s| m[s as usize]).collect::<Vec<bool>>()),
                (_, m) => m.map(<[bool]>::to_vec),
            };
            self.reset_opacity(mask.as_deref());
            report.opacity_reset = true;
        }
        let recompute = report.reindex.is_some() || step.is_multiple_of(filter3d::UPDATE_INTERVAL);
        self.refresh_filter(if recompute { Variances::Recompute } else { Variances::Kept });
        report.gaussians = self.model.len();
        Ok(report)
    }

    /// One full training step on one view: returns the report with the loss.
    pub fn step(
        &mut self,
        cam: &Camera,
        target: &[f32],
        weights: Option<&[f32]>,
    ) -> Result<StepReport, TrainError> {
        self.begin_step();
        let mut grads = std::mem::take(&mut self.scratch);
        if grads.means.len() != self.model.len() {
            grads = self.zero_grads(); // first step, or the model was densified or pruned
        }
        let (_, frame, loss, rows) = self.pass_into(cam, target, weights, &mut grads)?;
        if !loss.loss.is_finite() {
            return Err(TrainError::NonFinite { step: self.step, what: "the image loss".into() });
        }
        self.pull_back(&mut grads, Some(&rows));
        // MCMC's regularisers reach every row: then the step visits every row.
        let regularised = self.add_regularisers(&mut grads);
        let report = self.finish_step(&grads, (!regularised).then_some(&rows[..]), Some(&frame), None);
        grads.clear_rows(&rows);
        if regularised {
            grads.opacity_logits.fill(0.0);
            grads.log_scales.fill([0.0; 3]);
        }
        self.scratch = grads;
        Ok(StepReport { loss: loss.loss, ..report? })
    }

    /// Applies a rearrangement to the model, Adam moments and statistics.
    pub fn apply(&mut self, r: &Reindex) {
        apply_reindex(&mut self.model, &mut self.adam, &mut self.stats, r);
        // The carried variances were rearranged with the rows; new rows carry their
        // source's until the next recomputation (after every densification).
        self.refresh_filter(Variances::Carried);
    }

    /// INRIA `densify_and_prune` now (clone, split, prune), then clears the
    /// statistics. Returns the rearrangement and the counts.
    pub fn densify_and_prune(&mut self, mask: Option<&[bool]>) -> (Reindex, DensifyCounts) {
        let plan = densify::plan_densify(
            &self.model.gaussians,
            &self.stats,
            &self.config.densify,
            &self.bounds(),
            self.step,
            mask,
            &mut self.rng,
        );
        self.apply(&plan.reindex);
        let g = &mut self.model.gaussians;
        for (k, (m, s)) in plan.split_means.iter().zip(&plan.split_log_scales).enumerate() {
            g.means[plan.first_split + k] = *m;
            g.log_scales[plan.first_split + k] = *s;
        }
        self.stats.clear();
        let [by_opacity, by_world, by_screen, by_reach] = plan.counts.pruned_by;
        tracing::debug!(
            "step {}: cloned {}, split {} ({} held back by the budget), pruned {} (opacity {by_opacity}, world size {by_world}, screen size {by_screen}, camera reach {by_reach}) -> {} Gaussians",
            self.step,
            plan.counts.cloned,
            plan.counts.split,
            plan.counts.deferred,
            plan.counts.pruned(),
            self.model.len()
        );
        (plan.reindex, plan.counts)
    }

    /// Adds the strategy's regularisers' gradients to every row of `grads` (MCMC's mean
    /// opacity and scale, [`mcmc::add_regularisers`]); returns whether it added any.
    pub fn add_regularisers(&self, grads: &mut Grads) -> bool {
        match self.config.strategy {
            Strategy::Adaptive => false,
            Strategy::Mcmc(m) => {
                mcmc::add_regularisers(&self.model.gaussians, &m, grads);
                true
            }
        }
    }

    /// MCMC's relocation of dead Gaussians, then its growth toward the budget
    /// ([`crate::mcmc`]); the moments of every row involved restart at zero. Returns the
    /// rearrangement (relocation then growth) and the counts.
    pub fn relocate_and_grow(&mut self, mask: Option<&[bool]>) -> (Reindex, DensifyCounts) {
        let Strategy::Mcmc(cfg) = self.config.strategy else {
            return (Reindex::identity(self.model.len()), DensifyCounts::default());
        };
        let (min_opacity, cap) =
            (self.config.densify.min_opacity, self.config.densify.max_gaussians.unwrap_or(mcmc::DEFAULT_CAP));
        let moved = mcmc::plan_relocate(&mut self.model.gaussians, min_opacity, mask, &mut self.rng);
        self.apply(&moved.reindex);
        self.zero_moments(&moved.restart);
        // Relocation works in place, so the mask still names the same rows.
        let grown = mcmc::plan_grow(&mut self.model.gaussians, &cfg, min_opacity, cap, mask, &mut self.rng);
        self.apply(&grown.reindex);
        self.zero_moments(&grown.restart);
        self.stats.clear();
        let counts = DensifyCounts {
            relocated: moved.reindex.src.iter().enumerate().filter(|&(j, &s)| s as usize != j).count(),
            added: grown.reindex.len() - grown.reindex.old_len,
            ..Default::default()
        };
        tracing::debug!(
            "step {}: relocated {} dead Gaussians, added {} -> {} Gaussians",
            self.step,
            counts.relocated,
            counts.added,
            self.model.len()
        );
        (moved.reindex.then(&grown.reindex), counts)
    }

    /// Restarts the Adam moments of the rows where `rows[i]` is true, in every group.
    fn zero_moments(&mut self, rows: &[bool]) {
        for g in Group::ALL {
            self.adam.zero_moments(g, Some(rows));
        }
    }

    /// Prunes (low opacity; size after the first reset) among the allowed Gaussians.
    pub fn prune(&mut self, mask: Option<&[bool]>) -> Reindex {
        let r = densify::plan_prune(
            &self.model.gaussians,
            &self.stats,
            &self.config.densify,
            &self.bounds(),
            self.step,
            mask,
        );
        self.apply(&r);
        r
    }

    /// Removes the Gaussians where `keep[i]` is false.
    pub fn remove(&mut self, keep: &[bool]) -> Result<Reindex, TrainError> {
        if keep.len() != self.model.len() {
            return Err(TrainError::Mismatch(format!(
                "keep mask has {} entries, model {}",
                keep.len(),
                self.model.len()
            )));
        }
        let r = Reindex::keep(keep);
        self.apply(&r);
        Ok(r)
    }

    /// INRIA `reset_opacity` among the allowed Gaussians (of the filtered opacity with the
    /// 3D filter, [`filter3d::reset_opacity`]); zeroes their opacity moments.
    pub fn reset_opacity(&mut self, mask: Option<&[bool]>) {
        let value = self.config.densify.opacity_reset_value;
        let g = &mut self.model.gaussians;
        let touched = match &self.filter {
            Some(f) => filter3d::reset_opacity(g, &f.variance, value, mask),
            None => densify::reset_opacity(g, value, mask),
        };
        self.adam.zero_moments(Group::Opacity, Some(&touched));
        self.refresh_filter(Variances::Kept);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_downscale_schedule_halves_the_divisor_every_interval() {
        let d = Downscale { levels: 2, every: 3000 };
        let f: Vec<u32> = [0, 2999, 3000, 5999, 6000, 7000, u64::MAX].iter().map(|&s| d.factor(s)).collect();
        assert_eq!(f, vec![4, 4, 2, 2, 1, 1, 1]);
        assert_eq!(Downscale::default().factor(0), 1);
        assert_eq!(Downscale { levels: 3, every: 0 }.factor(5), 1);
    }
}

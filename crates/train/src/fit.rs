//! A whole training run on a [`Dataset`]: initialisation, the INRIA loop (one
//! random training view per step, drawn without replacement per epoch), periodic
//! test PSNR, the INRIA output folder, and the run's checkpoints (its identity
//! [`train_run_id`], [`Checkpointer::save_train`] and [`Checkpointer::load_train`]).

use crate::checkpoint::{get_rng, get_trainer, non_finite_parameters, put_rng, put_trainer};
use crate::checkpoint::{Checkpointer, Control, RunId};
use crate::dataset::{Dataset, LoadOptions, View};
use crate::init::{gaussians_from_points, random_points};
use crate::loss::{psnr, ssim};
use crate::model::Model;
use crate::trainer::{scene_extent, StepReport, Strategy, TrainConfig, TrainError, Trainer};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use transsplat_scene::archive::{Hasher, Writer};
use transsplat_scene::{cameras::inria, ply, Camera, Error};

/// The sky dome's default spacing in pixels: 4 px at the largest focal length, a
/// point per 16 squared pixels of sky, which the trainer's densification refines where
/// the sky has detail (docs/method.md T4).
pub const DEFAULT_SKY_SPACING: f32 = 4.0;

/// Options of a run beyond the optimiser's [`TrainConfig`].
#[derive(Clone, Debug, PartialEq)]
pub struct FitOptions {
    pub config: TrainConfig,
    /// Highest SH degree (INRIA `sh_degree`, 3).
    pub max_sh_degree: u32,
    /// Number of random points when the dataset has no point cloud (INRIA uses
    /// 100k for synthetic scenes).
    pub random_points: usize,
    /// Evaluate the test PSNR every this many steps (0 = only at the end).
    pub eval_every: u64,
    /// Spacing in pixels of the sky dome's points ([`crate::init::sky_points`]); 0: no
    /// dome, as INRIA. The default, [`DEFAULT_SKY_SPACING`], is the measured one
    /// (docs/method.md T4, T5).
    pub sky_spacing: f32,
    /// Start each Gaussian whose cloud neighbourhood is a surface flat on that surface
    /// ([`crate::init::flatten_on_surfaces`]); false: INRIA's balls. On by default
    /// (docs/method.md T6).
    pub surface_init: bool,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            config: TrainConfig::default(),
            max_sh_degree: 3,
            random_points: 100_000,
            eval_every: 1000,
            sky_spacing: DEFAULT_SKY_SPACING,
            surface_init: true,
        }
    }
}

/// Where the initial Gaussians came from.
#[derive(Clone, Debug, PartialEq)]
pub enum InitSource {
    Points { count: usize },
    Random { count: usize },
}

/// The initial model for a dataset (see [`crate::init`]).
pub fn initial_model(ds: &Dataset, opts: &FitOptions) -> (Model, InitSource) {
    let extent = scene_extent(&ds.cameras);
    let (mut cloud, source) = match &ds.points {
        Some(p) if !p.is_empty() => (p.clone(), InitSource::Points { count: p.len() }),
        _ => {
            let mut rng = ChaCha8Rng::seed_from_u64(opts.config.seed ^ 0x1417);
            let cams: Vec<Camera> = ds.train.iter().chain(&ds.test).map(|v| v.camera.clone()).collect();
            let p = random_points(&cams, opts.random_points, &mut rng);
            let n = p.len();
            (p, InitSource::Random { count: n })
        }
    };
    // The dome completes a cloud; alone it is no initialisation (an empty cloud stays
    // the error it is).
    if opts.sky_spacing > 0.0 && !cloud.is_empty() {
        let sky = crate::init::sky_points(&ds.train, &cloud, opts.sky_spacing, opts.config.background);
        tracing::info!("sky dome: {} points", sky.len());
        cloud.positions.extend(sky.positions);
        cloud.colors.extend(sky.colors);
    }
    let mut g = gaussians_from_points(&cloud, opts.max_sh_degree, 0.01 * extent);
    if opts.surface_init {
        let n = crate::init::flatten_on_surfaces(&mut g, &cloud.positions);
        tracing::info!("{n} of {} initial Gaussians start flat on their surfaces", g.len());
    }
    if let Strategy::Mcmc(m) = opts.config.strategy {
        // gsplat's MCMC preset: more opaque, smaller initial Gaussians.
        g.opacity_logits.fill(crate::init::logit(m.init_opacity));
        let shift = m.init_scale.ln();
        g.log_scales.iter_mut().flatten().for_each(|s| *s += shift);
    }
    (Model::new(g, 0), source)
}

/// A trainer for a fresh run on `ds`: the initial model ([`initial_model`]) and the
/// scene's bounds from its cameras ([`Trainer::for_cameras`]).
pub fn start(ds: &Dataset, opts: &FitOptions) -> Result<(Trainer, InitSource), TrainError> {
    let (model, source) = initial_model(ds, opts);
    Ok((Trainer::for_cameras(model, &ds.cameras, opts.config.clone())?, source))
}

/// Test metrics of one view.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ViewScore {
    /// The camera's image name.
    pub name: String,
    /// PSNR and SSIM over the whole image.
    pub psnr: f32,
    pub ssim: f32,
}

/// Mean test metrics, and each view's.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Eval {
    /// Mean PSNR over whole images.
    pub psnr: f32,
    /// Mean SSIM over whole images.
    pub ssim: f32,
    /// Mean PSNR inside the views' masks, when the test views have masks.
    pub masked_psnr: Option<f32>,
    pub views: usize,
    /// Every view's scores, in the order given.
    pub per_view: Vec<ViewScore>,
}

impl Eval {
    /// The view with the lowest PSNR (a view far below the mean is the floater
    /// symptom: haze in front of that camera).
    pub fn worst(&self) -> Option<&ViewScore> {
        self.worst_index().map(|k| &self.per_view[k])
    }

    /// The position of [`Self::worst`] in `per_view` (the order of the views evaluated).
    pub fn worst_index(&self) -> Option<usize> {
        (0..self.per_view.len()).min_by(|&a, &b| self.per_view[a].psnr.total_cmp(&self.per_view[b].psnr))
    }
}

/// PSNR and SSIM of the current model over `views`: over whole images, and the PSNR
/// inside the masks where the views have them (a number that alone would hide an
/// unfitted background).
pub fn evaluate(trainer: &Trainer, views: &[View]) -> Eval {
    if views.is_empty() {
        return Eval::default();
    }
    let (mut masked, mut with_masks) = (0.0f32, 0usize);
    let mut per_view = Vec::with_capacity(views.len());
    for v in views {
        let (img, _) = trainer.render(&v.camera);
        let (w, h) = (v.camera.width as usize, v.camera.height as usize);
        per_view.push(ViewScore {
            name: v.camera.name.clone(),
            psnr: psnr(&img.rgb, &v.image, None),
            ssim: ssim(&img.rgb, &v.image, w, h),
        });
        if let Some(wt) = v.weights.as_deref() {
            masked += psnr(&img.rgb, &v.image, Some(wt));
            with_masks += 1;
        }
    }
    let n = views.len() as f32;
    Eval {
        psnr: per_view.iter().map(|v| v.psnr).sum::<f32>() / n,
        ssim: per_view.iter().map(|v| v.ssim).sum::<f32>() / n,
        masked_psnr: (with_masks > 0).then(|| masked / with_masks as f32),
        views: views.len(),
        per_view,
    }
}

/// Progress of a run, for a progress bar.
#[derive(Clone, Debug, Default)]
pub struct Progress {
    pub step: u64,
    pub iterations: u64,
    /// Exponential moving average of the loss (INRIA's `ema_loss_for_log`).
    pub ema_loss: f32,
    /// Latest test evaluation, if any.
    pub test: Option<Eval>,
    pub gaussians: usize,
    pub last: StepReport,
}

/// The training loop's own state: the view order (drawn without replacement per
/// epoch) and the loss average. Part of a checkpoint.
#[derive(Clone, Debug)]
pub struct FitState {
    pub order_rng: ChaCha8Rng,
    /// Views left in this epoch (taken from the end).
    pub stack: Vec<usize>,
    pub ema_loss: f32,
}

impl FitState {
    /// The state at step 0 of a run with `seed`.
    pub fn new(seed: u64) -> Self {
        FitState { order_rng: ChaCha8Rng::seed_from_u64(seed ^ 0x0DE5), stack: Vec::new(), ema_loss: 0.0 }
    }
}

/// File name of a training checkpoint inside the checkpoint folder.
pub const TRAIN_FILE: &str = "train.ckpt";

/// The identity of a training run: the optimiser and loading settings, and a hash of
/// the dataset (cameras, images, masks, points).
pub fn train_run_id(ds: &Dataset, opts: &FitOptions, load: &LoadOptions) -> RunId {
    let settings = format!(
        "{:#?}\nmax_sh_degree: {}\nrandom_points: {}\nsky_spacing: {}\n{load:#?}",
        opts.config, opts.max_sh_degree, opts.random_points, opts.sky_spacing
    );
    let view_hash = |v: &View| {
        let mut h = Hasher::default();
        h.str(&format!("{:?}", v.camera)).f32s(&v.image);
        if let Some(w) = &v.weights {
            h.f32s(w);
        }
        h.finish()
    };
    let train: Vec<u64> = ds.train.par_iter().map(view_hash).collect();
    let test: Vec<u64> = ds.test.par_iter().map(view_hash).collect();
    let mut h = Hasher::default();
    h.str(&format!("{:?}\n{:?}", ds.kind, ds.cameras));
    train.iter().chain(&[u64::MAX]).chain(&test).for_each(|&x| {
        h.u64(x);
    });
    if let Some(p) = &ds.points {
        h.f32s(p.positions.as_flattened()).f32s(p.colors.as_flattened());
    }
    RunId { settings, inputs: h.finish() }
}

/// Training checkpoints: the trainer and the loop's [`FitState`], in [`TRAIN_FILE`].
impl Checkpointer {
    /// Writes a training checkpoint.
    pub fn save_train(&mut self, trainer: &Trainer, state: &FitState) -> Result<(), TrainError> {
        let id = self.id.clone();
        let mut w = Writer::new();
        id.put(&mut w);
        put_trainer(&mut w, "tr", trainer);
        put_rng(&mut w, "fit.order_rng", &state.order_rng);
        w.u64("fit.stack", state.stack.iter().map(|&i| i as u64).collect::<Vec<_>>());
        w.f32("fit.ema_loss", vec![state.ema_loss]);
        self.write(TRAIN_FILE, &w, trainer.step).map(|_| ())
    }

    /// Restores a training run from its checkpoint; `config` must be the run's.
    pub fn load_train(&mut self, config: TrainConfig) -> Result<(Trainer, FitState), TrainError> {
        let a = self.read(TRAIN_FILE)?;
        let trainer = get_trainer(&a, "tr", config)?;
        let order_rng = get_rng(&a, "fit.order_rng")?;
        let stack: Vec<usize> = a.u64("fit.stack")?.iter().map(|&i| i as usize).collect();
        if let Some(&bad) = stack.iter().find(|&&i| i >= u32::MAX as usize) {
            return Err(a.err(format!("view index {bad} out of range")).into());
        }
        let ema_loss = a.f32_len("fit.ema_loss", 1)?[0];
        self.last = Some(trainer.step);
        Ok((trainer, FitState { order_rng, stack, ema_loss }))
    }
}

/// Trains `trainer` on `ds` for `config.iterations` steps from its current step,
/// calling `on_progress` after every step. Returns the final test evaluation.
pub fn fit(
    ds: &Dataset,
    trainer: &mut Trainer,
    eval_every: u64,
    on_progress: impl FnMut(&Progress),
) -> Result<Eval, TrainError> {
    let mut state = FitState::new(trainer.config.seed);
    fit_with(ds, trainer, &mut state, eval_every, &mut Control::default(), on_progress)
}

/// [`fit`] from a loop state (fresh or restored from a checkpoint), steered by
/// `control`: a checkpoint at the top of every `every`-th step, and on a stop (Ctrl-C
/// or `stop_after`) a final checkpoint and [`TrainError::Interrupted`].
pub fn fit_with(
    ds: &Dataset,
    trainer: &mut Trainer,
    state: &mut FitState,
    eval_every: u64,
    control: &mut Control,
    mut on_progress: impl FnMut(&Progress),
) -> Result<Eval, TrainError> {
    if ds.train.is_empty() {
        return Err(TrainError::Mismatch("the dataset has no training views".into()));
    }
    if let Some(&bad) = state.stack.iter().find(|&&i| i >= ds.train.len()) {
        return Err(TrainError::Mismatch(format!("view {bad} of the saved order is not in the dataset")));
    }
    let start = trainer.step;
    let mut progress =
        Progress { iterations: trainer.config.iterations, ema_loss: state.ema_loss, ..Default::default() };
    let mut coarse = CoarseViews::default();
    while trainer.step < trainer.config.iterations {
        let step = trainer.step;
        if let Some(ck) = control.checkpoint.as_mut().filter(|ck| ck.due(step, start)) {
            ck.save_train(trainer, state)?;
        }
        if control.should_stop(step) {
            if let Some(ck) = control.checkpoint.as_mut().filter(|ck| ck.last != Some(step)) {
                ck.save_train(trainer, state)?;
            }
            return Err(TrainError::Interrupted { step });
        }
        if state.stack.is_empty() {
            state.stack = (0..ds.train.len()).collect();
            state.stack.shuffle(&mut state.order_rng);
        }
        let views = coarse.at(&ds.train, trainer.config.downscale.factor(step));
        let v = &views[state.stack.pop().expect("refilled")];
        let report = trainer.step(&v.camera, &v.image, v.weights.as_deref())?;
        state.ema_loss =
            if report.step == 1 { report.loss } else { 0.4 * report.loss + 0.6 * state.ema_loss };
        progress.ema_loss = state.ema_loss;
        progress.step = report.step;
        progress.gaussians = report.gaussians;
        if eval_every > 0 && report.step % eval_every == 0 && !ds.test.is_empty() {
            progress.test = Some(evaluate(trainer, &ds.test));
        }
        progress.last = report;
        on_progress(&progress);
    }
    Ok(evaluate(trainer, &ds.test))
}

/// The training views at the coarse-to-fine schedule's current divisor
/// ([`crate::trainer::Downscale`]), made once per level and dropped at full resolution.
#[derive(Default)]
struct CoarseViews {
    factor: u32,
    views: Vec<View>,
}

impl CoarseViews {
    /// `train` itself at divisor 1, else its views divided by `factor`.
    fn at<'a>(&'a mut self, train: &'a [View], factor: u32) -> &'a [View] {
        if factor <= 1 {
            *self = CoarseViews::default(); // the last coarse level is not kept
            return train;
        }
        if factor != self.factor {
            tracing::debug!("training at 1/{factor} resolution");
            self.views = train.par_iter().map(|v| v.downscaled(factor)).collect();
            self.factor = factor;
        }
        &self.views
    }
}

/// The run summary `train.json` in a training output folder (steps, Gaussians, test
/// PSNR); it also marks the folder as `train`'s own, which a rerun may replace.
pub const SUMMARY_FILE: &str = "train.json";

/// `train.json`: what a training run did and how its test views score. Written by
/// [`TrainSummary::write`] and read back by [`TrainSummary::read`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TrainSummary {
    pub steps: u64,
    pub gaussians: usize,
    /// Mean test PSNR and SSIM over whole images (none without test views).
    pub test_psnr: Option<f32>,
    pub test_ssim: Option<f32>,
    /// Mean test PSNR inside the test views' masks, when they have masks.
    pub test_psnr_masked: Option<f32>,
    pub test_views: usize,
    pub worst_test_view: Option<WorstView>,
    /// Mean PSNR of every 8th training view.
    pub train_psnr_sample: Option<f32>,
    pub per_test_view: Vec<TestView>,
    pub seconds: f64,
    /// The written scene.
    pub scene: PathBuf,
    /// The settings that name the run's rules (`adam`, `clamp_grad`, `strategy` by name).
    pub adam: String,
    pub clamp_grad: String,
    pub camera_reach: Option<f32>,
    pub strategy: String,
    /// The 3D filter's variance factor (`filter3d`), absent when off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub filter_3d: Option<f32>,
    /// True when the initial Gaussians were INRIA's balls rather than flat on their
    /// surfaces ([`FitOptions::surface_init`] off).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub isotropic_init: bool,
    /// The sky dome's spacing in pixels ([`crate::init::sky_points`]), absent when off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sky_spacing: Option<f32>,
}

/// The lowest-scoring test view.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct WorstView {
    pub name: String,
    pub psnr: f32,
}

/// One test view's scores and, for a view far below the mean (or the worst view when the
/// test PSNR is far below the training views'), its diagnosis.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TestView {
    pub name: String,
    pub psnr: f32,
    pub ssim: f32,
    /// `floaters` or `extrapolation` ([`crate::diagnose`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cause: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub near_share: Option<f32>,
}

impl TrainSummary {
    /// Writes `dir/train.json` atomically.
    pub fn write(&self, dir: &Path) -> transsplat_scene::Result<()> {
        let text = serde_json::to_string_pretty(self).expect("a summary serialises");
        transsplat_scene::atomic::write_bytes(&dir.join(SUMMARY_FILE), format!("{text}\n").as_bytes())
    }

    /// Reads `dir/train.json`, naming the file in an error.
    pub fn read(dir: &Path) -> transsplat_scene::Result<Self> {
        let path = dir.join(SUMMARY_FILE);
        let bytes = transsplat_scene::atomic::read(&path)?;
        serde_json::from_slice(&bytes).map_err(|e| Error::format(&path, format!("not a train.json: {e}")))
    }
}

/// Writes the INRIA output layout: `out/point_cloud/iteration_N/point_cloud.ply`
/// and `out/cameras.json`, each file atomically. Returns the PLY path.
/// Refuses (naming the parameter group) to write a model holding NaN or infinite values.
pub fn write_output(out: &Path, trainer: &Trainer, cameras: &[Camera]) -> transsplat_scene::Result<PathBuf> {
    if let Some(group) = non_finite_parameters(&trainer.model) {
        return Err(Error::format(
            out,
            format!("not written: the trained {group} hold NaN or infinite values"),
        ));
    }
    let dir = out.join("point_cloud").join(format!("iteration_{}", trainer.step));
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let ply_path = dir.join("point_cloud.ply");
    // With the 3D filter on, the written scene has it baked in (`filter3d` module doc).
    ply::write(&ply_path, &trainer.exported())?;
    inria::write(&out.join("cameras.json"), cameras)?;
    Ok(ply_path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_worst_view_is_the_lowest_psnr_and_its_position() {
        let score = |name: &str, psnr| ViewScore { name: name.into(), psnr, ssim: 0.5 };
        let eval = Eval {
            per_view: vec![score("a", 30.0), score("b", 21.0), score("c", 25.0)],
            views: 3,
            ..Default::default()
        };
        assert_eq!(eval.worst_index(), Some(1));
        assert_eq!(eval.worst().map(|v| v.name.as_str()), Some("b"));
        assert_eq!(Eval::default().worst_index(), None);
    }
}

//! A training job: a dataset (COLMAP, transforms.json or INRIA layout) into an INRIA
//! output folder with the test views' renders and `train.json`
//! ([`transsplat_train::fit::TrainSummary`]), committed only when complete.
//!
//! The settings are checked ([`TrainConfig::validate`]) and the dataset read before
//! anything is written, so a bad setting or dataset leaves nothing behind. A test view
//! more than [`FLOATER_WARN_DB`] below the mean is named in a warning with its
//! diagnosis (`transsplat_train::diagnose`: floaters or extrapolation), also recorded
//! in `train.json`; so is the worst test view when the test PSNR lies that far below the
//! training views' (a gap every test view shares need not be floaters).

use crate::checkpoints::{self, Checkpoints};
use crate::output::Output;
use crate::SessionError;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use transsplat_train::diagnose::{diagnose, Cause, Diagnosis};
use transsplat_train::fit::{train_run_id, TestView, TrainSummary, WorstView, SUMMARY_FILE, TRAIN_FILE};
use transsplat_train::{
    dataset, fit_with, start, write_output, Eval, FitOptions, FitState, InitSource, LoadOptions, Progress,
    Strategy, TrainConfig, TrainError, Trainer,
};

/// Folder of the test views' renders in a training output.
pub const TEST_RENDERS: &str = "test_renders";

/// A test view this far (dB) below the mean test PSNR, or a mean test PSNR this far
/// below the training views', is warned about with a diagnosis (floaters or
/// extrapolation, `transsplat_train::diagnose`).
pub const FLOATER_WARN_DB: f32 = 3.0;

/// Training checkpoints are written every this many steps unless asked otherwise.
const CHECKPOINT_EVERY: u64 = 500;

/// A training job.
#[derive(Clone, Debug)]
pub struct TrainRequest {
    /// The dataset folder.
    pub data: PathBuf,
    /// The output folder.
    pub out: PathBuf,
    /// Other inputs the output may not overwrite (a masks folder).
    pub other_inputs: Vec<PathBuf>,
    pub fit: FitOptions,
    pub load: LoadOptions,
    pub checkpoints: Checkpoints,
}

/// What a training job produced.
#[derive(Clone, Debug)]
pub struct TrainOutcome {
    /// The committed output folder.
    pub out: PathBuf,
    /// What `train.json` holds.
    pub summary: TrainSummary,
}

/// Runs a training job; `cancel` stops it between steps (with a checkpoint when they
/// are on), `progress` hears every step.
pub fn run(
    request: &TrainRequest,
    cancel: Option<&AtomicBool>,
    progress: &mut dyn FnMut(&Progress),
) -> Result<TrainOutcome, SessionError> {
    let TrainRequest { data, out, other_inputs, fit: opts, load, checkpoints } = request;
    opts.config.validate().map_err(TrainError::from)?;
    // The dataset is checked before anything is written: a bad dataset leaves nothing behind.
    let ds = dataset::load(data, load)?;
    if ds.train.is_empty() {
        return Err(SessionError::Input(format!("{}: no training views", data.display())));
    }
    let mut inputs: Vec<&Path> = vec![data];
    inputs.extend(other_inputs.iter().map(PathBuf::as_path));
    let staged = Output::begin(out, &inputs, SUMMARY_FILE)?;
    let out = std::path::absolute(out).unwrap_or_else(|_| out.clone());
    let (w, h) = (ds.train[0].camera.width, ds.train[0].camera.height);
    tracing::info!(
        "{}: {:?} dataset, {} training and {} test views at {w}x{h}",
        data.display(),
        ds.kind,
        ds.train.len(),
        ds.test.len()
    );
    let mut control = checkpoints.control(&out, CHECKPOINT_EVERY, TRAIN_FILE, cancel)?;
    if let Some(ck) = control.checkpoint.as_mut() {
        ck.id = train_run_id(&ds, opts, load);
    }
    let (mut trainer, mut state) = match control.checkpoint.as_mut().filter(|_| control.resume) {
        Some(ck) => {
            let (mut t, s) = ck.load_train(opts.config.clone())?;
            t.attach_filter(&ds.cameras);
            tracing::info!("resuming at step {} from {}", t.step, ck.dir.display());
            (t, s)
        }
        None => (fresh_trainer(&ds, opts, data)?, FitState::new(opts.config.seed)),
    };
    let started = std::time::Instant::now();
    let eval = match fit_with(&ds, &mut trainer, &mut state, opts.eval_every, &mut control, progress) {
        Ok(e) => e,
        Err(TrainError::Interrupted { step }) => return Err(checkpoints::interrupted(step, &control, &out)),
        Err(e) => return Err(checkpoints::failed(format!("training stopped: {e}"), &control, &out)),
    };
    let (train_psnr, diagnosed) = warn_on_low_test_views(&trainer, &ds, &eval);
    let summary = staged.write(|dir| {
        let ply = write_output(dir, &trainer, &ds.cameras)?;
        let ply = out.join(ply.strip_prefix(dir).unwrap_or(&ply));
        write_test_renders(&dir.join(TEST_RENDERS), &trainer, &ds.test)?;
        let mut summary =
            summary(&trainer, &eval, train_psnr, &diagnosed, started.elapsed().as_secs_f64(), ply);
        summary.sky_spacing = (opts.sky_spacing > 0.0).then_some(opts.sky_spacing);
        summary.isotropic_init = !opts.surface_init;
        summary.write(dir)?;
        Ok(summary)
    })?;
    staged.commit()?;
    if let Some(ck) = &control.checkpoint {
        ck.remove();
    }
    let masked = eval.masked_psnr.map_or(String::new(), |m| format!(" ({m:.2} dB inside the masks)"));
    let worst = eval.worst().map_or(String::new(), |v| format!(", worst {} {:.2} dB", v.name, v.psnr));
    tracing::info!(
        "{} steps in {:.1} s: {} Gaussians, test PSNR {:.2} dB, SSIM {:.4} over {} whole views{masked}{worst}; wrote {}",
        trainer.step,
        summary.seconds,
        trainer.model.len(),
        eval.psnr,
        eval.ssim,
        eval.views,
        summary.scene.display()
    );
    Ok(TrainOutcome { out, summary })
}

/// A trainer initialised from the dataset's points (or at random in the cameras'
/// view), with the warnings a user needs about that start.
fn fresh_trainer(ds: &dataset::Dataset, opts: &FitOptions, data: &Path) -> Result<Trainer, SessionError> {
    let (trainer, source) = start(ds, opts)?;
    match source {
        InitSource::Points { count } => tracing::info!("initialised {count} Gaussians from the point cloud"),
        InitSource::Random { count } => tracing::warn!(
            "no point cloud in the dataset: initialised {count} Gaussians at random in the cameras' view"
        ),
    }
    if let (Strategy::Mcmc(_), Some(cap)) = (trainer.config.strategy, trainer.config.densify.max_gaussians) {
        if trainer.model.len() > cap {
            tracing::warn!(
                "the initial cloud has {} Gaussians, more than --max-gaussians {cap}: MCMC only relocates, it does not prune down to the budget",
                trainer.model.len()
            );
        }
    }
    if trainer.model.is_empty() {
        return Err(SessionError::Input(format!(
            "{}: no initial Gaussians (empty point cloud and --random-points 0)",
            data.display()
        )));
    }
    Ok(trainer)
}

/// `train.json`'s contents.
fn summary(
    trainer: &Trainer,
    eval: &Eval,
    train_psnr: Option<f32>,
    diagnosed: &[(String, Diagnosis)],
    seconds: f64,
    scene: PathBuf,
) -> TrainSummary {
    let per_test_view = eval
        .per_view
        .iter()
        .map(|v| {
            let diagnosis = diagnosed.iter().find(|(name, _)| *name == v.name).map(|(_, d)| d);
            TestView {
                name: v.name.clone(),
                psnr: v.psnr,
                ssim: v.ssim,
                cause: diagnosis.map(|d| d.cause.name().to_string()),
                near_share: diagnosis.map(|d| d.near_share),
            }
        })
        .collect();
    let config: &TrainConfig = &trainer.config;
    TrainSummary {
        steps: trainer.step,
        gaussians: trainer.model.len(),
        test_psnr: (eval.views > 0).then_some(eval.psnr),
        test_ssim: (eval.views > 0).then_some(eval.ssim),
        test_psnr_masked: eval.masked_psnr,
        test_views: eval.views,
        worst_test_view: eval.worst().map(|v| WorstView { name: v.name.clone(), psnr: v.psnr }),
        train_psnr_sample: train_psnr,
        per_test_view,
        seconds,
        scene,
        adam: config.adam.name().into(),
        clamp_grad: config.clamp_grad.name().into(),
        camera_reach: config.densify.camera_reach,
        strategy: config.strategy.name().into(),
        filter_3d: (config.filter_3d > 0.0).then_some(config.filter_3d),
        sky_spacing: None,
        isotropic_init: false,
    }
}

/// Renders of the test views (`test_renders/<stem>.png`), to look at the views the
/// warnings name.
fn write_test_renders(
    dir: &Path,
    trainer: &Trainer,
    test: &[transsplat_train::View],
) -> Result<(), transsplat_scene::Error> {
    if test.is_empty() {
        return Ok(());
    }
    std::fs::create_dir_all(dir).map_err(|e| transsplat_scene::Error::io(dir, e))?;
    for v in test {
        let (img, _) = trainer.render(&v.camera);
        let path = dir.join(format!("{}.png", v.camera.stem()));
        transsplat_scene::image::write_png(&path, img.width, img.height, &img.rgb)?;
    }
    Ok(())
}

/// Warns about test views more than [`FLOATER_WARN_DB`] below the mean, each with its
/// diagnosis, and about a test PSNR that far below the training views', with the
/// low views' floaters if any, else the diagnosis of the worst test view (a gap every
/// test view shares is not floaters when even the worst sees nothing in front of the
/// training views' depths). Returns the
/// PSNR of every 8th training view and the diagnosed views.
fn warn_on_low_test_views(
    trainer: &Trainer,
    ds: &dataset::Dataset,
    eval: &Eval,
) -> (Option<f32>, Vec<(String, Diagnosis)>) {
    if eval.views == 0 {
        return (None, Vec::new());
    }
    let train_cameras: Vec<_> = ds.train.iter().map(|v| v.camera.clone()).collect();
    let mut diagnosed = Vec::new();
    for (view, score) in ds.test.iter().zip(&eval.per_view) {
        if score.psnr >= eval.psnr - FLOATER_WARN_DB {
            continue;
        }
        let d = diagnose(trainer, &view.camera, &train_cameras);
        tracing::warn!(
            "test view {} is at {:.2} dB, {:.1} dB below the mean test PSNR: {} ({TEST_RENDERS}/)",
            score.name,
            score.psnr,
            eval.psnr - score.psnr,
            verdict(&d)
        );
        diagnosed.push((score.name.clone(), d));
    }
    let sample: Vec<_> = ds.train.iter().step_by(8).cloned().collect();
    let train = transsplat_train::evaluate(trainer, &sample);
    if train.psnr - eval.psnr > FLOATER_WARN_DB {
        let floaters: Vec<&str> =
            diagnosed.iter().filter(|(_, d)| d.cause == Cause::Floaters).map(|(n, _)| n.as_str()).collect();
        let worst = eval.worst_index().and_then(|k| Some((ds.test.get(k)?, &eval.per_view[k])));
        let why = match worst {
            Some((view, score)) if floaters.is_empty() => {
                // The worst test view, diagnosed once (it may be among the low views above).
                let d = match diagnosed.iter().find(|(name, _)| *name == score.name) {
                    Some((_, d)) => *d,
                    None => {
                        let d = diagnose(trainer, &view.camera, &train_cameras);
                        diagnosed.push((score.name.clone(), d));
                        d
                    }
                };
                let gap = match d.cause {
                    Cause::Floaters => "",
                    Cause::Extrapolation => {
                        ", so not floaters: the scene fits its training views more closely than it is \
                         constrained between them"
                    }
                };
                format!("the worst test view, {}, {}{gap}", score.name, verdict(&d))
            }
            _ => format!("floaters in {}", floaters.join(", ")),
        };
        tracing::warn!(
            "test PSNR {:.2} dB is {:.1} dB below the training views' {:.2} dB: {why} ({TEST_RENDERS}/)",
            eval.psnr,
            train.psnr - eval.psnr,
            train.psnr
        );
    }
    (Some(train.psnr), diagnosed)
}

/// A diagnosis in words, for the warnings.
fn verdict(d: &Diagnosis) -> String {
    match d.cause {
        Cause::Floaters => format!(
            "floaters: {:.0} % of what it sees lies nearer than a quarter of the depth at which any \
             training view sees those splats",
            100.0 * d.near_share
        ),
        Cause::Extrapolation => format!(
            "extrapolation: it sees what the training views saw, at their depths, from an angle they \
             did not constrain; only {:.0} % of what it sees lies in front of where they see it",
            100.0 * d.near_share
        ),
    }
}

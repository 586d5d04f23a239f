//! `transsplat train`: 3DGS training from a COLMAP, transforms.json or INRIA-layout
//! dataset into an INRIA output folder; and `transsplat bench train`.

use super::common::{parse_rgb, progress, staged_output, CheckpointArgs};
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use transsplat_raster::ClampGrad;
use transsplat_train::dataset::Masks;
use transsplat_train::diagnose::{diagnose, Cause, Diagnosis};
use transsplat_train::fit::{train_run_id, TestView, TrainSummary, WorstView, SUMMARY_FILE, TRAIN_FILE};
use transsplat_train::init::MAX_RANDOM_POINTS;
use transsplat_train::{
    dataset, fit_with, start, write_output, AdamRule, DensifyConfig, Downscale, FitOptions, FitState,
    InitSource, LearningRates, LoadOptions, Strategy, TrainConfig, TrainError, Trainer,
};

/// Arguments of `transsplat train`.
#[derive(clap::Args, Debug)]
pub struct TrainArgs {
    /// Dataset folder: COLMAP (sparse/0 + images/), transforms.json, or cameras.json + images/.
    #[arg(long)]
    pub data: PathBuf,
    /// Output folder (INRIA layout: point_cloud/iteration_N/point_cloud.ply, cameras.json,
    /// and train.json with the run's summary). It appears only when training is complete;
    /// an existing one must be empty or an earlier train output, which is replaced.
    #[arg(long)]
    pub out: PathBuf,
    /// Training steps (INRIA: 30000).
    #[arg(long, default_value_t = 30_000)]
    pub iters: u64,
    /// Divide image sizes by this (1, 2, 4, 8; as INRIA -r).
    #[arg(long, default_value_t = 1)]
    pub resolution: u32,
    /// Random seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Evaluate the test PSNR every this many steps (0 = only at the end).
    #[arg(long, default_value_t = 1000)]
    pub eval_every: u64,
    /// Background colour R,G,B in [0, 1] (RGBA images are composited over it).
    #[arg(long, value_parser = parse_rgb, default_value = "0,0,0")]
    pub background: [f32; 3],
    /// Highest SH degree (0-3).
    #[arg(long, default_value_t = 3)]
    pub sh_degree: u32,
    /// Random points when the dataset has no point cloud (at most 10 million).
    #[arg(long, default_value_t = 100_000)]
    pub random_points: usize,
    /// Train only inside these masks: DIR/<image stem>.png (or .jpg) for every view, grey
    /// in [0, 1], a per-pixel loss weight. Without it, only masks the dataset declares per
    /// frame (transforms.json mask_path) are used; a masks/ folder alone is not.
    #[arg(long, value_name = "DIR", conflicts_with = "no_masks")]
    pub masks: Option<PathBuf>,
    /// Ignore the masks the dataset declares (transforms.json mask_path).
    #[arg(long)]
    pub no_masks: bool,
    /// Opacity learning rate (INRIA: 0.025; up to 0.05).
    #[arg(long, value_parser = super::common::finite_f32, default_value_t = 0.025)]
    pub opacity_lr: f32,
    /// Densify until this step (INRIA: 15000).
    #[arg(long, default_value_t = DensifyConfig::default().until_step)]
    pub densify_until: u64,
    /// Clone or split a Gaussian whose mean screen-space positional gradient (NDC units,
    /// as INRIA's `--densify_grad_threshold`) reaches this (INRIA: 0.0002).
    #[arg(long, value_parser = super::common::finite_f32, default_value_t = DensifyConfig::default().grad_threshold)]
    pub densify_grad_threshold: f32,
    /// Prune Gaussians whose opacity falls below this at each densification (INRIA: 0.005;
    /// nerfstudio's splatfacto and OpenSplat cull below 0.1).
    #[arg(long, value_parser = super::common::finite_f32, default_value_t = DensifyConfig::default().min_opacity)]
    pub min_opacity: f32,
    /// After the first opacity reset, prune Gaussians whose screen radius exceeded this
    /// many pixels since the last densification (the paper states 20). Default 0 = off,
    /// as in INRIA's code and gsplat: on a 48-view 256² open capture the 20 px rule cost
    /// 8 dB of test PSNR and 57 % more Gaussians (docs/results.md, "Against reference trainers").
    #[arg(long, value_parser = super::common::finite_f32, default_value_t = DensifyConfig::default().max_screen_radius.unwrap_or(0.0))]
    pub max_screen_radius: f32,
    /// At every densification, prune a Gaussian whose sphere of this many times its
    /// largest scale contains a training camera (default 3.33, the rasterizer's support;
    /// 0 = off, as INRIA). Far sky and floor Gaussians otherwise grow to tens of metres,
    /// and a held-out camera whose image plane passes near one sees it as a veil over
    /// the whole frame (docs/method.md T2).
    #[arg(long, value_parser = super::common::finite_f32, default_value_t = DensifyConfig::default().camera_reach.unwrap_or(0.0))]
    pub camera_reach: f32,
    /// Never grow past this many Gaussians. With `--strategy adaptive` densification
    /// takes the largest gradients first while they fit (default 0 = no cap, as INRIA);
    /// with `--strategy mcmc` it is the budget the run grows to (default 0 = gsplat's
    /// 1,000,000). For a fixed memory, or to compare with another trainer at equal size.
    #[arg(long, default_value_t = 0)]
    pub max_gaussians: usize,
    /// How the Gaussians grow: `adaptive` is INRIA's clone / split / prune on the
    /// positional gradient with opacity resets (default); `mcmc` is 3DGS-MCMC as gsplat
    /// runs it: dead Gaussians relocated onto live ones, growth of 5 % per densification
    /// up to --max-gaussians, position noise, opacity and scale regularisers, starting
    /// from opacity 0.5 and a tenth of the initial scale (docs/method.md T1).
    #[arg(long, value_parser = parse_strategy, default_value = "adaptive")]
    pub strategy: Strategy,
    /// Coarse to fine: the first --downscale-every steps train at 1/2^N resolution, the
    /// next at 1/2^(N-1), and so on (splatfacto's and OpenSplat's num_downscales; they use
    /// 2). Default 0 = full resolution throughout, as INRIA.
    #[arg(long, default_value_t = 0)]
    pub downscales: u32,
    /// Steps per level of --downscales (splatfacto and OpenSplat: 3000).
    #[arg(long, default_value_t = 3000)]
    pub downscale_every: u64,
    /// Adam's update rule: `dense` updates every Gaussian every step (INRIA); `selective`
    /// only those the step's view reached, so a step costs what the view sees, not the
    /// whole model (docs/method.md M10).
    #[arg(long, value_parser = parse_adam, default_value = "dense")]
    pub adam: AdamRule,
    /// How the colour clamp at 0 passes gradients to the SH: `exact` is the clamp's
    /// derivative, as INRIA and gsplat (default; a channel below 0 gets none); `revive`
    /// lets a channel that fell below 0 rise again: dark objects come out better, but
    /// floaters survive as haze (docs/method.md M11).
    #[arg(long, value_parser = parse_clamp_grad, default_value = "exact")]
    pub clamp_grad: ClampGrad,
    #[command(flatten)]
    pub checkpoints: CheckpointArgs,
}

/// A colour-clamp gradient rule by name (`exact`, `revive`).
fn parse_clamp_grad(s: &str) -> Result<ClampGrad, String> {
    let names: Vec<&str> = ClampGrad::ALL.iter().map(|r| r.name()).collect();
    ClampGrad::from_name(s).ok_or_else(|| format!("unknown clamp rule {s:?}; one of: {}", names.join(", ")))
}

/// A densification strategy by name (`adaptive`, `mcmc`).
fn parse_strategy(s: &str) -> Result<Strategy, String> {
    let names: Vec<&str> = Strategy::all().iter().map(|r| r.name()).collect();
    Strategy::from_name(s).ok_or_else(|| format!("unknown strategy {s:?}; one of: {}", names.join(", ")))
}

/// An Adam rule by name (`dense`, `selective`).
fn parse_adam(s: &str) -> Result<AdamRule, String> {
    let names: Vec<&str> = AdamRule::ALL.iter().map(|r| r.name()).collect();
    AdamRule::from_name(s).ok_or_else(|| format!("unknown Adam rule {s:?}; one of: {}", names.join(", ")))
}

/// Runs `transsplat train`.
pub fn run(args: &TrainArgs, cancel: &AtomicBool) -> Result<()> {
    if !matches!(args.resolution, 1..=64) {
        bail!("--resolution must be between 1 and 64, got {}", args.resolution);
    }
    if args.sh_degree > 3 {
        bail!("--sh-degree must be 0 to 3, got {}", args.sh_degree);
    }
    if args.camera_reach < 0.0 {
        bail!("--camera-reach must be at least 0, got {}", args.camera_reach);
    }
    if args.max_screen_radius < 0.0 {
        bail!("--max-screen-radius must be at least 0, got {}", args.max_screen_radius);
    }
    if args.downscales > 0 && args.downscale_every == 0 {
        bail!("--downscale-every must be at least 1 with --downscales {}", args.downscales);
    }
    if args.random_points > MAX_RANDOM_POINTS {
        bail!("--random-points must be at most {MAX_RANDOM_POINTS}, got {}", args.random_points);
    }
    let opts = FitOptions {
        config: TrainConfig {
            iterations: args.iters,
            lr: LearningRates { opacity: args.opacity_lr, ..Default::default() },
            densify: DensifyConfig {
                until_step: args.densify_until,
                grad_threshold: args.densify_grad_threshold,
                min_opacity: args.min_opacity,
                max_screen_radius: (args.max_screen_radius > 0.0).then_some(args.max_screen_radius),
                camera_reach: (args.camera_reach > 0.0).then_some(args.camera_reach),
                max_gaussians: (args.max_gaussians > 0).then_some(args.max_gaussians),
                ..Default::default()
            },
            background: args.background,
            seed: args.seed,
            adam: args.adam,
            clamp_grad: args.clamp_grad,
            strategy: args.strategy,
            downscale: Downscale { levels: args.downscales, every: args.downscale_every },
            ..Default::default()
        },
        max_sh_degree: args.sh_degree,
        random_points: args.random_points,
        eval_every: args.eval_every,
    };
    // The settings are checked before anything is read or written, each named by its flag.
    opts.config.validate().map_err(|e| anyhow::anyhow!("{} {}", flag_of(e.key), e.problem))?;
    let masks = match (&args.masks, args.no_masks) {
        (Some(dir), _) => Masks::Folder(dir.clone()),
        (None, true) => Masks::Off,
        (None, false) => Masks::Declared,
    };
    let load =
        LoadOptions { resolution: args.resolution, background: args.background, masks, ..Default::default() };
    // The dataset is checked before anything is written: a bad dataset leaves nothing behind.
    let ds = dataset::load(&args.data, &load)?;
    if ds.train.is_empty() {
        bail!("{}: no training views", args.data.display());
    }
    // The output is written into a hidden staging folder beside it and appears only when
    // complete: any failure or signal leaves no output folder and no partial files.
    let mut inputs: Vec<&Path> = vec![&args.data];
    inputs.extend(args.masks.as_deref());
    let staged = staged_output(&args.out, &inputs, SUMMARY_FILE)?;
    let out = std::path::absolute(&args.out).unwrap_or_else(|_| args.out.clone());
    let (w, h) = (ds.train[0].camera.width, ds.train[0].camera.height);
    tracing::info!(
        "{}: {:?} dataset, {} training and {} test views at {w}x{h}",
        args.data.display(),
        ds.kind,
        ds.train.len(),
        ds.test.len()
    );
    let mut control = args.checkpoints.control(&out, 500, TRAIN_FILE, cancel)?;
    if let Some(ck) = control.checkpoint.as_mut() {
        ck.id = train_run_id(&ds, &opts, &load);
    }
    let (mut trainer, mut state) = match control.checkpoint.as_mut().filter(|_| control.resume) {
        Some(ck) => {
            let (t, s) = ck.load_train(opts.config.clone())?;
            tracing::info!("resuming at step {} from {}", t.step, ck.dir.display());
            (t, s)
        }
        None => {
            let (t, source) = start(&ds, &opts).context("cannot start training")?;
            match source {
                InitSource::Points { count } => {
                    tracing::info!("initialised {count} Gaussians from the point cloud")
                }
                InitSource::Random { count } => tracing::warn!(
                    "no point cloud in the dataset: initialised {count} Gaussians at random in the cameras' view"
                ),
            }
            if let (Strategy::Mcmc(_), Some(cap)) = (t.config.strategy, t.config.densify.max_gaussians) {
                if t.model.len() > cap {
                    tracing::warn!(
                        "the initial cloud has {} Gaussians, more than --max-gaussians {cap}: MCMC only relocates, it does not prune down to the budget",
                        t.model.len()
                    );
                }
            }
            if t.model.is_empty() {
                bail!(
                    "{}: no initial Gaussians (empty point cloud and --random-points 0)",
                    args.data.display()
                );
            }
            (t, FitState::new(opts.config.seed))
        }
    };
    let pb = progress(args.iters, "train");
    pb.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    pb.set_position(trainer.step);
    let started = std::time::Instant::now();
    let eval = fit_with(&ds, &mut trainer, &mut state, args.eval_every, &mut control, |p| {
        if p.step % 10 == 0 || p.step == p.iterations {
            let test = p.test.as_ref().map_or(String::from("-"), |e| format!("{:.2}", e.psnr));
            pb.set_message(format!("loss {:.4} test PSNR {test} Gaussians {}", p.ema_loss, p.gaussians));
            pb.set_position(p.step);
        }
    });
    pb.finish_and_clear();
    let eval = match eval {
        Ok(e) => e,
        Err(TrainError::Interrupted { step }) => bail!(args.checkpoints.interrupted(step, &control, &out)),
        Err(e) => {
            bail!("training stopped: {e}; no scene was written to {}; {}", out.display(), control.note())
        }
    };
    pb.finish_and_clear();
    let ply = write_output(staged.path(), &trainer, &ds.cameras)?;
    let ply = out.join(ply.strip_prefix(staged.path()).unwrap_or(&ply));
    write_test_renders(&staged.path().join(TEST_RENDERS), &trainer, &ds.test)?;
    let (train_psnr, low_views) = warn_on_floaters(&trainer, &ds, &eval);
    let per_test_view = eval
        .per_view
        .iter()
        .map(|v| {
            let diagnosis = low_views.iter().find(|(name, _)| *name == v.name).map(|(_, d)| d);
            TestView {
                name: v.name.clone(),
                psnr: v.psnr,
                ssim: v.ssim,
                cause: diagnosis.map(|d| d.cause.name().to_string()),
                near_share: diagnosis.map(|d| d.near_share),
            }
        })
        .collect();
    let summary = TrainSummary {
        steps: trainer.step,
        gaussians: trainer.model.len(),
        test_psnr: (eval.views > 0).then_some(eval.psnr),
        test_ssim: (eval.views > 0).then_some(eval.ssim),
        test_psnr_masked: eval.masked_psnr,
        test_views: eval.views,
        worst_test_view: eval.worst().map(|v| WorstView { name: v.name.clone(), psnr: v.psnr }),
        train_psnr_sample: train_psnr,
        per_test_view,
        seconds: started.elapsed().as_secs_f64(),
        scene: ply.clone(),
        adam: trainer.config.adam.name().into(),
        clamp_grad: trainer.config.clamp_grad.name().into(),
        camera_reach: trainer.config.densify.camera_reach,
        strategy: trainer.config.strategy.name().into(),
    };
    summary.write(staged.path())?;
    staged.commit()?;
    if let Some(ck) = &control.checkpoint {
        ck.remove();
    }
    let masked = eval.masked_psnr.map_or(String::new(), |m| format!(" ({m:.2} dB inside the masks)"));
    let worst = eval.worst().map_or(String::new(), |v| format!(", worst {} {:.2} dB", v.name, v.psnr));
    tracing::info!(
        "{} steps in {:.1} s: {} Gaussians, test PSNR {:.2} dB, SSIM {:.4} over {} whole views{masked}{worst}; wrote {}",
        trainer.step,
        started.elapsed().as_secs_f64(),
        trainer.model.len(),
        eval.psnr,
        eval.ssim,
        eval.views,
        ply.display()
    );
    println!("{}", serde_json::to_string(&summary).expect("a summary serialises"));
    Ok(())
}

/// The `train` flag that sets a `TrainConfig` setting (`TrainConfig::validate`'s keys).
fn flag_of(key: &str) -> &'static str {
    match key {
        "iterations" => "--iters",
        "lr.opacity" => "--opacity-lr",
        "densify.grad_threshold" => "--densify-grad-threshold",
        "densify.min_opacity" => "--min-opacity",
        "densify.camera_reach" => "--camera-reach",
        "densify.max_screen_radius" => "--max-screen-radius",
        "downscale.levels" => "--downscales",
        "downscale.every" => "--downscale-every",
        "background" => "--background",
        _ => "a setting",
    }
}

/// Folder of the test views' renders in a training output.
pub const TEST_RENDERS: &str = "test_renders";

/// A test view this far (dB) below the mean test PSNR, or a mean test PSNR this far
/// below the training views', is warned about: the floater symptom (haze in front of
/// cameras the training views do not constrain).
const FLOATER_WARN_DB: f32 = 3.0;

/// Renders every test view to `dir/<image stem>.png`.
fn write_test_renders(dir: &Path, trainer: &Trainer, test: &[transsplat_train::View]) -> Result<()> {
    if test.is_empty() {
        return Ok(());
    }
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
    for v in test {
        let (img, _) = trainer.render(&v.camera);
        let path = dir.join(format!("{}.png", v.camera.stem()));
        transsplat_scene::image::write_png(&path, img.width, img.height, &img.rgb)?;
    }
    Ok(())
}

/// Warns when a test view lies far below the mean test PSNR, naming the cause
/// (floaters or extrapolation, [`diagnose`]), or the test PSNR far below the training
/// views' (every 8th training view is scored). Returns that training PSNR and each low
/// view's diagnosis.
fn warn_on_floaters(
    trainer: &Trainer,
    ds: &dataset::Dataset,
    eval: &transsplat_train::Eval,
) -> (Option<f32>, Vec<(String, Diagnosis)>) {
    if eval.views == 0 {
        return (None, Vec::new());
    }
    let train_cameras: Vec<_> = ds.train.iter().map(|v| v.camera.clone()).collect();
    let mut low = Vec::new();
    for (view, score) in ds.test.iter().zip(&eval.per_view) {
        if score.psnr >= eval.psnr - FLOATER_WARN_DB {
            continue;
        }
        let d = diagnose(trainer, &view.camera, &train_cameras);
        let why = match d.cause {
            Cause::Floaters => format!(
                "floaters: {:.0} % of what it sees lies nearer than a quarter of the depth at which any \
                 training view sees those splats",
                100.0 * d.near_share
            ),
            Cause::Extrapolation => format!(
                "extrapolation: it sees what the training views saw, from outside them; only {:.0} % of \
                 what it sees lies in front of where they see it",
                100.0 * d.near_share
            ),
        };
        tracing::warn!(
            "test view {} is at {:.2} dB, {:.1} dB below the mean test PSNR: {why} (test_renders/)",
            score.name,
            score.psnr,
            eval.psnr - score.psnr
        );
        low.push((score.name.clone(), d));
    }
    let sample: Vec<_> = ds.train.iter().step_by(8).cloned().collect();
    let train = transsplat_train::evaluate(trainer, &sample);
    if train.psnr - eval.psnr > FLOATER_WARN_DB {
        tracing::warn!(
            "test PSNR {:.2} dB is {:.1} dB below the training views' {:.2} dB: the test views may see floaters",
            eval.psnr,
            train.psnr - eval.psnr,
            train.psnr
        );
    }
    (Some(train.psnr), low)
}

/// Arguments of `transsplat bench train`.
#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    /// Gaussian counts (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "100000,500000")]
    pub gaussians: Vec<usize>,
    /// Square image sizes (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "256,512")]
    pub sizes: Vec<u32>,
    /// Repetitions per measurement (the best is reported).
    #[arg(long, default_value_t = 5)]
    pub reps: usize,
}

/// Runs `transsplat bench train`: time per training step against forward + backward.
pub fn bench(args: &BenchArgs) -> Result<()> {
    if args.sizes.contains(&0) || args.gaussians.contains(&0) {
        bail!("--sizes and --gaussians must be positive");
    }
    println!(
        "{:>10} {:>9} {:>12} {:>10} {:>7} {:>11} {:>9} {:>9} {:>9} {:>10} {:>10}",
        "gaussians",
        "size",
        "fwd+bwd s",
        "step s",
        "ratio",
        "selective s",
        "mcmc s",
        "loss s",
        "adam s",
        "densify s",
        "relocate s"
    );
    for &n in &args.gaussians {
        for &s in &args.sizes {
            let r = transsplat_train::bench::run(n, s, s, args.reps);
            println!(
                "{:>10} {:>9} {:>12.4} {:>10.4} {:>7.2} {:>11.4} {:>9.4} {:>9.4} {:>9.4} {:>10.4} {:>10.4}",
                n,
                format!("{s}x{s}"),
                r.forward_backward,
                r.step,
                r.step / r.forward_backward,
                r.step_selective,
                r.step_mcmc,
                r.loss,
                r.adam,
                r.densify,
                r.relocate
            );
            println!(
                "{}",
                serde_json::json!({
                    "gaussians": n, "width": s, "height": s,
                    "forward_backward_s": r.forward_backward, "step_s": r.step,
                    "step_over_forward_backward": r.step / r.forward_backward,
                    "step_selective_s": r.step_selective, "step_mcmc_s": r.step_mcmc,
                    "loss_s": r.loss, "adam_s": r.adam, "densify_s": r.densify, "relocate_s": r.relocate,
                    "threads": rayon::current_num_threads(),
                })
            );
        }
    }
    Ok(())
}

//! `transsplat train`: 3DGS training from a COLMAP, transforms.json or INRIA-layout
//! dataset into an INRIA output folder; and `transsplat bench train`.

use super::common::{parse_rgb, progress, CheckpointArgs};
use anyhow::{bail, Result};
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use transsplat_raster::ClampGrad;
use transsplat_session::train::TrainRequest;
use transsplat_train::dataset::Masks;
use transsplat_train::init::MAX_RANDOM_POINTS;
use transsplat_train::{
    AdamRule, DensifyConfig, Downscale, FitOptions, LearningRates, LoadOptions, Strategy, TrainConfig,
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
    /// Divide image sizes by this (1, 2, 4, 8; as INRIA -r; at most 64).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=64))]
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
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(0..=3))]
    pub sh_degree: u32,
    /// Random points when the dataset has no point cloud (at most 10 million).
    #[arg(long, default_value_t = 100_000)]
    pub random_points: usize,
    /// A sky dome: points on a far sphere above the cameras' horizon where the
    /// training views see a sky the point cloud does not reach, this many pixels apart
    /// (0: none, as INRIA). SfM finds no points at infinity; without the dome an open
    /// sky grows from the nearest surfaces and sits too near (docs/method.md T4). Below
    /// the horizon and behind walls the cloud samples densely it adds nothing; a room
    /// sampled sparsely keeps some behind its walls, so pass 0 for an indoor capture (T5).
    #[arg(long, value_parser = super::common::finite_f32, default_value_t = FitOptions::default().sky_spacing)]
    pub sky_spacing: f32,
    /// Start every Gaussian as a ball, as INRIA does. By default a Gaussian whose point
    /// lies on a surface of the cloud (its 8 nearest points spread little off their best
    /// plane) starts flat on that surface: a sparse far floor's balls, as tall as the
    /// points are far apart, otherwise scatter their splits above and below the floor,
    /// a fog that views at grazing angles cannot place (docs/method.md T6).
    #[arg(long)]
    pub isotropic_init: bool,
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
    /// Mip-Splatting's 3D smoothing filter: every Gaussian is low-passed by the finest
    /// sampling interval of the training cameras that see it, this factor times its
    /// square (Mip-Splatting: 0.2; default 0 = off, as INRIA). The written scene has the
    /// filter baked in, so any renderer draws what training saw (docs/method.md T3).
    #[arg(long, value_parser = super::common::finite_f32, default_value_t = TrainConfig::default().filter_3d)]
    pub filter_3d: f32,
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
    let request = train_request(args)?;
    let bar = progress(args.iters, "train");
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let outcome = transsplat_session::train::run(&request, Some(cancel), &mut |p| {
        if p.step % 10 == 0 || p.step == p.iterations {
            let test = p.test.as_ref().map_or(String::from("-"), |e| format!("{:.2}", e.psnr));
            bar.set_message(format!("loss {:.4} test PSNR {test} Gaussians {}", p.ema_loss, p.gaussians));
            bar.set_position(p.step);
        }
    });
    bar.finish_and_clear();
    println!("{}", serde_json::to_string(&outcome?.summary).expect("a summary serialises"));
    Ok(())
}

/// The training job the flags describe; the settings are checked before anything is
/// read or written, each named by its flag.
fn train_request(args: &TrainArgs) -> Result<TrainRequest> {
    if args.camera_reach < 0.0 {
        bail!("--camera-reach must be at least 0, got {}", args.camera_reach);
    }
    if args.max_screen_radius < 0.0 {
        bail!("--max-screen-radius must be at least 0, got {}", args.max_screen_radius);
    }
    if args.downscales > 0 && args.downscale_every == 0 {
        bail!("--downscale-every must be at least 1 with --downscales {}", args.downscales);
    }
    if args.sky_spacing < 0.0 {
        bail!("--sky-spacing must be at least 0 (0: no sky dome), got {}", args.sky_spacing);
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
            filter_3d: args.filter_3d,
            downscale: Downscale { levels: args.downscales, every: args.downscale_every },
            ..Default::default()
        },
        max_sh_degree: args.sh_degree,
        random_points: args.random_points,
        eval_every: args.eval_every,
        sky_spacing: args.sky_spacing,
        surface_init: !args.isotropic_init,
    };
    opts.config.validate().map_err(|e| anyhow::anyhow!("{} {}", flag_of(e.key), e.problem))?;
    let masks = match (&args.masks, args.no_masks) {
        (Some(dir), _) => Masks::Folder(dir.clone()),
        (None, true) => Masks::Off,
        (None, false) => Masks::Declared,
    };
    Ok(TrainRequest {
        data: args.data.clone(),
        out: args.out.clone(),
        other_inputs: args.masks.iter().cloned().collect(),
        fit: opts,
        load: LoadOptions {
            resolution: args.resolution,
            background: args.background,
            masks,
            ..Default::default()
        },
        checkpoints: args.checkpoints.spec(),
    })
}

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
        "filter_3d" => "--filter-3d",
        _ => "a setting",
    }
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
            let r = transsplat_bench::train::run(n, s, s, args.reps);
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

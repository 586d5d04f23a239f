//! `transsplat bench raster`: forward, backward and splat-back timings on the
//! reproducible synthetic scene of `transsplat_raster::synthetic`; `transsplat bench
//! edit`: a whole edit at a stated real size (`transsplat_bench::edit`).

use super::common::{load_cameras, load_scene, progress, show_steps, steps_bar, SceneArgs};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use transsplat_bench::edit as bench_edit;
use transsplat_bench::raster as bench;
use transsplat_edit::{EditConfig, Progress};
use transsplat_scene::{Camera, Gaussians};

/// Arguments of `transsplat bench raster`.
#[derive(clap::Args, Debug)]
pub struct RasterArgs {
    /// Time this scene (a PLY or an output folder) instead of the synthetic one, seen by
    /// one of its cameras (`--cameras`, `--camera`).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Cameras of `--scene`: cameras.json, transforms.json or a COLMAP folder (default:
    /// beside the scene).
    #[arg(long, requires = "scene")]
    pub cameras: Option<PathBuf>,
    /// The camera of `--scene` to render, by image name or stem (default: the first).
    #[arg(long, requires = "scene")]
    pub camera: Option<String>,
    /// Gaussian counts to run (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "100000,1000000")]
    pub gaussians: Vec<usize>,
    /// Image size (square).
    #[arg(long, default_value_t = 512)]
    pub size: u32,
    /// Repetitions per measurement (the best is reported).
    #[arg(long, default_value_t = 3)]
    pub reps: usize,
}

/// The scene and camera of `bench raster --scene`.
fn given_scene(args: &RasterArgs, path: &Path) -> anyhow::Result<(Gaussians, Camera)> {
    let scene = SceneArgs { scene: path.to_path_buf(), drop_invalid: false, spz_axes: Default::default() };
    let (g, _) = load_scene(&scene)?;
    let (cams, cam_path) = load_cameras(args.cameras.as_deref(), path)?;
    let cam = match &args.camera {
        None => cams.first(),
        Some(name) => cams.iter().find(|c| &c.name == name || &c.stem() == name),
    };
    let cam = cam.cloned().ok_or_else(|| {
        let names: Vec<String> = cams.iter().take(5).map(|c| c.stem()).collect();
        anyhow::anyhow!(
            "{}: no camera {:?} (there are {}, e.g. {})",
            cam_path.display(),
            args.camera.as_deref().unwrap_or(""),
            cams.len(),
            names.join(", ")
        )
    })?;
    Ok((g, cam))
}

/// Runs `transsplat bench raster` and prints a table and one JSON line per configuration.
pub fn raster(args: &RasterArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.size > 0, "--size must be positive");
    let given = args.scene.as_deref().map(|p| given_scene(args, p)).transpose()?;
    println!(
        "{:>10} {:>9} {:>10} {:>10} {:>10} {:>10} {:>10} {:>12} {:>10} {:>9}",
        "gaussians",
        "size",
        "forward s",
        "(binning)",
        "backward s",
        "(reused)",
        "splat s",
        "Mpairs/s fwd",
        "saturated",
        "traversed"
    );
    let runs: Vec<usize> = if given.is_some() { vec![0] } else { args.gaussians.clone() };
    for n in runs {
        let r = match &given {
            Some((g, cam)) => bench::run_on(g, cam, args.reps),
            None => bench::run(n, args.size, args.size, args.reps),
        };
        let n = r.gaussians;
        println!(
            "{:>10} {:>9} {:>10.4} {:>10.4} {:>10.4} {:>10.4} {:>10.4} {:>12.1} {:>9.1}% {:>9}",
            n,
            format!("{}x{}", r.width, r.height),
            r.forward,
            r.binning,
            r.backward,
            r.backward_reused,
            r.splat_back,
            r.blended_pairs as f64 / r.forward / 1e6,
            100.0 * r.saturated_fraction,
            r.median_traversed
        );
        println!(
            "{}",
            serde_json::json!({
                "gaussians": n, "width": r.width, "height": r.height,
                "forward_s": r.forward, "binning_s": r.binning, "backward_s": r.backward,
                "backward_reused_s": r.backward_reused, "splat_back_s": r.splat_back,
                "blended_pairs": r.blended_pairs, "intersections": r.intersections,
                "saturated_fraction": r.saturated_fraction, "median_traversed": r.median_traversed,
                "backward_over_forward": r.backward / r.forward,
                "threads": rayon::current_num_threads(),
            })
        );
    }
    Ok(())
}

/// Arguments of `transsplat bench models`.
#[derive(clap::Args, Debug)]
pub struct ModelsArgs {
    /// Only the cases whose name contains this text.
    #[arg(long)]
    pub only: Option<String>,
    /// Timed runs per case, the fastest reported (1 to 100).
    #[arg(long, default_value_t = 1)]
    pub repeats: usize,
}

/// `transsplat bench models`: the fastest of `--repeats` forward passes per model case
/// (real architecture sizes, random weights), after one warm-up.
pub fn models(args: &ModelsArgs) -> anyhow::Result<()> {
    if !(1..=100).contains(&args.repeats) {
        anyhow::bail!("--repeats must be between 1 and 100, got {}", args.repeats);
    }
    let device = transsplat_models::default_device();
    println!("{:<28} {:>10}", "case", "seconds");
    for case in transsplat_bench::models::cases() {
        if args.only.as_deref().is_some_and(|o| !case.name.contains(o)) {
            continue;
        }
        let s = (case.run)(&device, transsplat_bench::models::Repeats(args.repeats))?;
        println!("{:<28} {:>10.3}", case.name, s);
    }
    Ok(())
}

/// Arguments of `transsplat bench edit`.
#[derive(clap::Args, Debug)]
pub struct EditArgs {
    /// Sizes to run: a (~700k Gaussians, 42 views of 256x256), b (~1M, 40 views of
    /// 800x600), c (a's scene at 512x512), quick (~5k, 14 views of 128x96); comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "a")]
    pub size: Vec<String>,
    /// The 2D editor: simulated (scored against the ground truth) or ip2p
    /// (InstructPix2Pix at random weights: the real model's arithmetic, timed).
    #[arg(long, value_parser = ["simulated", "ip2p"], default_value = "simulated")]
    pub editor: String,
    /// Views per InstructPix2Pix UNet call (as `edit --ip2p-batch`).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=64))]
    pub ip2p_batch: u64,
    /// Which views the editor edits: all, auto, K or 1/N (as `edit --views`).
    #[arg(long, value_parser = transsplat_session::views::ViewChoice::parse, default_value = "all")]
    pub views: transsplat_session::views::ViewChoice,
    /// Optimisation steps (the default edit's 600 unless given).
    #[arg(long)]
    pub steps: Option<usize>,
    /// Method (default transsplat).
    #[arg(long)]
    pub method: Option<String>,
    /// Simulated editor severity.
    #[arg(long, value_parser = super::common::finite_f32, default_value_t = 1.0)]
    pub severity: f32,
    /// Override any edit setting, as in `edit --set`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
}

/// Runs `transsplat bench edit`: per size, the stage table and one JSON line.
pub fn edit(args: &EditArgs, cancel: &AtomicBool) -> anyhow::Result<()> {
    let sizes: Vec<bench_edit::BenchSize> = args
        .size
        .iter()
        .map(|s| bench_edit::size(s.trim()))
        .collect::<Result<_, _>>()
        .map_err(anyhow::Error::msg)?;
    let config = EditConfig::default()
        .assemble(args.method.as_deref(), &args.set, args.steps)
        .map_err(anyhow::Error::msg)?;
    let work = tempfile::tempdir()?;
    let editor = match args.editor.as_str() {
        "ip2p" => bench_edit::BenchEditor::Ip2p { batch: args.ip2p_batch as usize },
        _ => bench_edit::BenchEditor::Simulated { severity: args.severity },
    };
    for size in &sizes {
        let opts = bench_edit::EditBenchOptions {
            size: *size,
            config: config.clone(),
            prompt: "make the ball blue",
            editor,
            views: args.views,
        };
        let pb = steps_bar(config.schedule.steps as u64);
        let r = bench_edit::run(&opts, work.path(), Some(cancel), &mut |p| match p {
            Progress::Edited { .. } => show_steps(&pb),
            Progress::Step { step, .. } => pb.set_position(step as u64),
            _ => {}
        })?;
        pb.finish_and_clear();
        let t = &r.timing;
        let st = &t.stages;
        println!(
            "size {}: {} Gaussians, {} editor on {} of {} edit views of {}x{}, {} steps, {} threads",
            r.size,
            r.gaussians,
            r.editor,
            r.edit_views,
            r.candidate_views,
            r.width,
            r.height,
            r.steps,
            rayon::current_num_threads()
        );
        let rows = [
            ("edit (total)", t.total),
            ("  editor + source renders", t.editor),
            ("  the lift (all but the editor)", t.total - t.editor),
            ("  transport rounds", t.transport),
            ("  optimisation", t.optimise),
            ("    binning", st.binning),
            ("    tile pass", st.tiles),
            ("    image loss", st.image_loss),
            ("    backward", st.backward),
            ("    method terms", st.method_terms),
            ("    optimiser + densification", st.optimiser),
            ("    checkpoints", st.checkpoint),
            ("    blend weights", st.weights),
            ("    colour lift", st.lift),
            ("write PLY", r.write_s),
        ];
        for (name, s) in rows {
            println!("{name:<32} {s:>9.2} s");
        }
        println!("{:<32} {:>9.4} s", "per step", r.per_step_s);
        println!(
            "target PSNR {:.2} dB, background PSNR {:.2} dB",
            r.metrics.target_psnr, r.metrics.background_psnr
        );
        println!("{}", serde_json::to_string(&r)?);
    }
    Ok(())
}

/// Arguments of `transsplat bench quality`.
#[derive(clap::Args, Debug)]
pub struct QualityArgs {
    /// Output folder (replaced if it holds an earlier suite's output).
    #[arg(long, default_value = "quality")]
    pub out: PathBuf,
    /// Full-size scenes and the default 600-step schedule (an hour or more on 2 cores).
    /// Without it the suite runs the small scenes and the quick schedule of `demo --quick`
    /// (about a quarter of an hour on 2 cores; docs/results.md has the current time).
    #[arg(long, conflicts_with = "quick")]
    pub full: bool,
    /// The default small suite, spelled out (what `--full` is not; kept so that earlier
    /// commands still run).
    #[arg(long)]
    pub quick: bool,
    /// Run only these cases (comma-separated names; an unknown name lists them all).
    #[arg(long, value_delimiter = ',')]
    pub cases: Vec<String>,
    /// Training steps of the trained variants (0: built scenes only).
    #[arg(long, default_value_t = 2000)]
    pub trained: u64,
    /// Also edit these captures rendered from meshes (comma-separated folders written by
    /// tools/mesh_captures.py), each trained for `--trained` steps, at the trained
    /// variants' severities.
    #[arg(long, value_delimiter = ',')]
    pub captures: Vec<PathBuf>,
    /// Hand every built-in case's edits masks from the simulated segmenter at this
    /// severity (0: the true target mask; failure modes in crates/builtin/src/segmenter.rs).
    /// Without it the simulated editor gives no mask.
    #[arg(long, value_parser = super::common::finite_f32)]
    pub segmenter: Option<f32>,
    /// Methods to run (comma-separated; default all).
    #[arg(long, value_delimiter = ',')]
    pub methods: Option<Vec<String>>,
    /// Override any edit setting, as in `edit --set`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Which training views the simulated editor edits in every case: all, auto, K or
    /// 1/N (as `edit --views`).
    #[arg(long, value_parser = transsplat_session::views::ViewChoice::parse, default_value = "all")]
    pub views: transsplat_session::views::ViewChoice,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// Runs `transsplat bench quality`: the ground-truth suite, its table on stdout.
pub fn quality(args: &QualityArgs, cancel: &AtomicBool) -> anyhow::Result<()> {
    use transsplat_bench::quality;
    let opts = suite_options(args)?;
    // One bar over the cases, with an ETA; each case's methods in the log.
    let bar = progress(opts.cases.len() as u64, "cases");
    let mut current = String::new();
    let outcome = quality::run(&opts, Some(cancel), &mut |case, method, p| {
        if case != current {
            if !current.is_empty() {
                bar.inc(1);
            }
            current = case.to_string();
            bar.set_message(case.to_string());
            tracing::info!("case {}/{}: {case}", bar.position() + 1, bar.length().unwrap_or(0));
        }
        if let Progress::Step { step, steps, .. } = p {
            tracing::debug!("{case} {method}: step {step}/{steps}");
        }
    });
    bar.finish_and_clear();
    let (out, results) = outcome.map_err(|e| match e {
        transsplat_bench::demo::DemoError::Edit(transsplat_edit::EditError::Interrupted(_)) => {
            anyhow::anyhow!("interrupted; nothing was written to {}", args.out.display())
        }
        e => e.into(),
    })?;
    print!("{}", quality::table(&results, &quality::averages(&results)));
    println!("wrote {}/quality.json, quality.md and report.html", out.display());
    Ok(())
}

/// The suite's settings from its flags: the captures (loaded and checked), the cases,
/// the edit settings (the quick schedule unless `--full`, then `--set`).
fn suite_options(args: &QualityArgs) -> anyhow::Result<transsplat_bench::quality::SuiteOptions> {
    use transsplat_bench::quality;
    if !args.captures.is_empty() && args.trained == 0 {
        anyhow::bail!("--captures needs trained variants (--trained above 0)");
    }
    let captures = args
        .captures
        .iter()
        .map(|dir| {
            transsplat_bench::capture::Capture::load(dir).map_err(|e| anyhow::anyhow!("--captures: {e}"))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let cases =
        quality::select(quality::cases(args.trained, &captures), &args.cases).map_err(anyhow::Error::msg)?;
    let quick = !args.full;
    let mut config = EditConfig::default();
    if quick {
        transsplat_bench::demo::quick_schedule(&mut config);
    }
    let config = config.with_overrides(&args.set).map_err(anyhow::Error::msg)?;
    Ok(quality::SuiteOptions {
        out: args.out.clone(),
        cases,
        quick,
        methods: super::demo::parse_methods(args.methods.as_deref())?,
        config,
        seed: args.seed,
        views: args.views,
        captures,
        segmenter: args.segmenter,
    })
}

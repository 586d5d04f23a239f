//! `transsplat eval`: CLIP-sim and CLIP-dir of edited renders against source renders
//! (Instruct-NeRF2NeRF `ClipSimilarity` protocol, docs/method.md#v1-clip-metrics), for the output of any
//! method. Prints a table and writes per-view and mean values as JSON (atomically).

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{bail, Context, Result};
use clap::Args;
use transsplat_eval::clip_metrics::{pair_views, score, Error as ClipError};
use transsplat_models::clip::Clip;
use transsplat_models::ModelDir;
use transsplat_scene::{atomic, cameras::LLFF_HOLD, image};

use super::common::{load_cameras, load_scene, progress, SceneArgs};

/// Arguments of `transsplat eval`.
#[derive(Args, Debug)]
pub struct EvalArgs {
    /// CLIP folder (Hugging Face `CLIPModel` layout), e.g. from
    /// `hf download openai/clip-vit-large-patch14 --local-dir DIR`.
    #[arg(long, value_name = "DIR")]
    pub clip: PathBuf,
    /// Folder of source renders (PNG/JPEG), paired with the edits by file stem; with
    /// `--cameras`, the source scene (PLY or INRIA output folder) to render first.
    #[arg(long, value_name = "PATH")]
    pub source: PathBuf,
    /// Folder of edited renders; with `--cameras`, the edited scene to render first.
    #[arg(long, value_name = "PATH")]
    pub edited: PathBuf,
    /// Cameras (cameras.json, transforms.json or a COLMAP folder): `--source` and
    /// `--edited` are then scenes, rendered from every camera into a temporary folder.
    #[arg(long, value_name = "PATH")]
    pub cameras: Option<PathBuf>,
    /// Background colour R,G,B in [0, 1] when rendering scenes.
    #[arg(long, value_parser = super::common::parse_rgb, default_value = "0,0,0")]
    pub background: [f32; 3],
    /// Caption of the source scene.
    #[arg(long)]
    pub source_prompt: String,
    /// Caption of the edited scene.
    #[arg(long)]
    pub target_prompt: String,
    /// Score every n-th view (sorted by name; 8 = the llffhold test views).
    #[arg(long, default_value_t = LLFF_HOLD)]
    pub every: usize,
    /// Where to write the scores.
    #[arg(long, default_value = "metrics.json")]
    pub out: PathBuf,
}

/// Runs `transsplat eval`.
pub fn run(args: &EvalArgs, cancel: &AtomicBool) -> Result<()> {
    let hint = format!("hf download openai/clip-vit-large-patch14 --local-dir {}", args.clip.display());
    let dir = ModelDir::open(&args.clip, "CLIP", &hint)?;
    let mut inputs = vec![args.clip.as_path(), args.source.as_path(), args.edited.as_path()];
    inputs.extend(args.cameras.as_deref());
    super::common::check_output(&args.out, &inputs)?;
    // With --cameras the inputs are scenes: render them first (kept until scoring ends).
    let rendered = match &args.cameras {
        Some(cams) => {
            let tmp = tempfile::tempdir().context("creating a temporary folder for the renders")?;
            for (scene, name) in [(&args.source, "source"), (&args.edited, "edited")] {
                render_all(scene, cams, &tmp.path().join(name), args.background, args.every, cancel)?;
            }
            Some(tmp)
        }
        None => None,
    };
    let (source, edited) = match &rendered {
        Some(tmp) => (tmp.path().join("source"), tmp.path().join("edited")),
        None => (args.source.clone(), args.edited.clone()),
    };
    // Rendered folders hold only the scored views already.
    let pairs = pair_views(&source, &edited, if rendered.is_some() { 1 } else { args.every })?;
    let clip = Clip::load(&dir, &transsplat_models::default_device())?;
    let mut images = Vec::with_capacity(pairs.len());
    for (stem, src, edit) in &pairs {
        let s = image::read(src).with_context(|| format!("source view {stem}"))?;
        let e = image::read(edit).with_context(|| format!("edited view {stem}"))?;
        images.push((stem.clone(), s, e));
    }
    let views: Vec<_> = images
        .iter()
        .map(|(stem, s, e)| {
            (stem.clone(), (s.data.as_slice(), s.width, s.height), (e.data.as_slice(), e.width, e.height))
        })
        .collect();
    let bar = progress(views.len() as u64, "CLIP");
    let scores = score(&clip, &views, &args.source_prompt, &args.target_prompt, args.every, &mut |n| {
        bar.set_position(n as u64);
        if cancel.load(Ordering::SeqCst) {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    });
    bar.finish_and_clear();
    let scores = match scores {
        Err(ClipError::Interrupted) => bail!("interrupted: nothing written"),
        other => other?,
    };
    println!("{:<24} {:>9} {:>9}", "view", "CLIP-sim", "CLIP-dir");
    for v in &scores.views {
        println!("{:<24} {:>9.4} {:>9.4}", v.view, v.clip_sim, v.clip_dir);
    }
    println!("{:<24} {:>9.4} {:>9.4}", "mean", scores.mean_clip_sim, scores.mean_clip_dir);
    let json = serde_json::to_string_pretty(&scores)?;
    atomic::write_bytes(&args.out, json.as_bytes())?;
    tracing::info!("wrote {}", args.out.display());
    Ok(())
}

/// Renders `scene` to `out/<image name>.png` from the cameras that are scored: every
/// `every`-th by image name, the order `pair_views` uses for folders.
fn render_all(
    scene: &Path,
    cameras: &Path,
    out: &Path,
    background: [f32; 3],
    every: usize,
    cancel: &AtomicBool,
) -> Result<()> {
    if every == 0 {
        bail!("--every must be at least 1");
    }
    let (g, _) = load_scene(&SceneArgs {
        scene: scene.to_path_buf(),
        drop_invalid: false,
        spz_axes: Default::default(),
    })?;
    let (mut cams, _) = load_cameras(Some(cameras), scene)?;
    cams.sort_by_key(|c| c.stem());
    let cams: Vec<_> = cams.into_iter().step_by(every).collect();
    std::fs::create_dir_all(out).with_context(|| format!("{}: cannot create", out.display()))?;
    super::render::render_views(&g, &cams, out, background, false, cancel)
}

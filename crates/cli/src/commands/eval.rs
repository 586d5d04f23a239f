//! `transsplat eval`: CLIP-sim and CLIP-dir of edited renders against source renders
//! (Instruct-NeRF2NeRF `ClipSimilarity` protocol, SPEC Evaluation), for the output of any
//! method. Prints a table and writes per-view and mean values as JSON (atomically).

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{bail, Context, Result};
use clap::Args;
use transsplat_eval::clip_metrics::{pair_views, score};
use transsplat_models::clip::Clip;
use transsplat_models::ModelDir;
use transsplat_scene::{atomic, image};

use super::common::progress;

/// Arguments of `transsplat eval`.
#[derive(Args, Debug)]
pub struct EvalArgs {
    /// CLIP folder (Hugging Face `CLIPModel` layout), e.g. from
    /// `hf download openai/clip-vit-large-patch14 --local-dir DIR`.
    #[arg(long, value_name = "DIR")]
    pub clip: PathBuf,
    /// Folder of source renders (PNG/JPEG), paired with the edits by file stem.
    #[arg(long, value_name = "DIR")]
    pub source: PathBuf,
    /// Folder of edited renders.
    #[arg(long, value_name = "DIR")]
    pub edited: PathBuf,
    /// Caption of the source scene.
    #[arg(long)]
    pub source_prompt: String,
    /// Caption of the edited scene.
    #[arg(long)]
    pub target_prompt: String,
    /// Score every n-th view (sorted by name; 8 = the llffhold test views).
    #[arg(long, default_value_t = 8)]
    pub every: usize,
    /// Where to write the scores.
    #[arg(long, default_value = "metrics.json")]
    pub out: PathBuf,
}

/// Runs `transsplat eval`.
pub fn run(args: &EvalArgs, cancel: &AtomicBool) -> Result<()> {
    let hint = format!("hf download openai/clip-vit-large-patch14 --local-dir {}", args.clip.display());
    let dir = ModelDir::open(&args.clip, "CLIP", &hint)?;
    let pairs = pair_views(&args.source, &args.edited, args.every)?;
    if [&args.source, &args.edited].iter().any(|d| args.out.starts_with(d)) {
        bail!("{}: the output must not be inside an input folder", args.out.display());
    }
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
    let mut cancelled = false;
    let scores = score(&clip, &views, &args.source_prompt, &args.target_prompt, args.every, &mut |n| {
        bar.set_position(n as u64);
        cancelled |= cancel.load(Ordering::SeqCst);
    })?;
    bar.finish_and_clear();
    if cancelled {
        bail!("interrupted: nothing written");
    }
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

//! `transsplat scene NAME --out DIR`: writes a built-in benchmark scene as a dataset
//! (INRIA output layout, renders, label masks, labels.json; see `transsplat_builtin::dataset`).

use super::common::progress;
use anyhow::Result;
use std::path::PathBuf;
use transsplat_builtin::{build, write_dataset, SceneConfig, WriteOptions};

/// Arguments of `transsplat scene`.
#[derive(clap::Args, Debug)]
pub struct BuiltinSceneArgs {
    /// Scene name: tabletop, occluded or garden.
    pub name: String,
    /// Output folder: missing, empty or an earlier scene dataset (replaced), unless --force;
    /// it appears only when the whole dataset is written.
    #[arg(long)]
    pub out: PathBuf,
    /// Image width in pixels (default 256; 128 with --quick).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height in pixels (default 192; 96 with --quick).
    #[arg(long)]
    pub height: Option<u32>,
    /// Number of cameras (default 32; 16 with --quick). Every 8th is a test view.
    #[arg(long)]
    pub views: Option<usize>,
    /// Gaussian density multiplier (default 1, about 40k Gaussians; 0.12 with --quick).
    #[arg(long, value_parser = super::common::finite_f32)]
    pub detail: Option<f32>,
    /// Seed of the procedural generation.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Small variant for tests: ~5k Gaussians, 16 views of 128x96.
    #[arg(long)]
    pub quick: bool,
    /// Open surroundings (tabletop, occluded): a checkerboard floor reaching 20 m under a
    /// sky dome instead of the floor and walls around the table, and a 360° orbit; a
    /// large, far background like an outdoor capture's.
    #[arg(long)]
    pub open: bool,
    /// Points in the initial cloud (sparse/0/points3D.txt; default 5000, at most 1,000,000).
    #[arg(long)]
    pub points: Option<usize>,
    /// Write into an existing non-empty folder (overwrites the dataset's files, deletes nothing).
    #[arg(long)]
    pub force: bool,
}

/// Runs `transsplat scene`.
pub fn run(args: &BuiltinSceneArgs) -> Result<()> {
    let mut cfg = if args.quick { SceneConfig::quick() } else { SceneConfig::default() };
    cfg.seed = args.seed;
    if let Some(w) = args.width {
        cfg.width = w;
    }
    if let Some(h) = args.height {
        cfg.height = h;
    }
    if let Some(v) = args.views {
        cfg.views = v;
    }
    if let Some(d) = args.detail {
        cfg.detail = d;
    }
    cfg.open = args.open;
    if args.points.is_some_and(|p| !(1..=1_000_000).contains(&p)) {
        anyhow::bail!("--points must be between 1 and 1000000");
    }
    let scene = build(&args.name, &cfg)?;
    tracing::info!(
        "scene {}: {} Gaussians, {} objects ({}), {} views of {}x{}",
        scene.name,
        scene.gaussians.len(),
        scene.objects.len(),
        scene.objects.iter().map(|o| o.name.as_str()).collect::<Vec<_>>().join(", "),
        scene.cameras.len(),
        cfg.width,
        cfg.height
    );
    let pb = progress(scene.cameras.len() as u64, "scene");
    let summary = write_dataset(
        &scene,
        &args.out,
        &WriteOptions { force: args.force, points: args.points },
        &mut |done, _| pb.set_position(done as u64),
    )?;
    pb.finish_and_clear();
    for (o, &n) in scene.objects.iter().zip(&summary.views_visible) {
        if n * 2 < summary.views {
            tracing::warn!("object {:?} is visible in only {n} of {} views", o.name, summary.views);
        }
    }
    tracing::info!(
        "wrote {} ({} views, {} test views)",
        args.out.display(),
        summary.views,
        summary.test_views
    );
    Ok(())
}

//! `transsplat views export`: renders the edit views (the training views, index % 8 != 0)
//! for editing with any 2D tool, all of them or one shard; the edited folder (or the
//! shards' folders gathered under one) goes back in with `--editor folder`.

use super::common::{load_cameras, load_scene, parse_rgb, progress, staged_output, SceneArgs};
use anyhow::Result;
use std::path::PathBuf;
use transsplat_editors::{export_views, exported_shard, ExportSpec, Shard};
use transsplat_raster::{render, RenderOptions, Splats};
use transsplat_scene::{fingerprint, Camera};

/// Subcommands of `transsplat views`.
#[derive(clap::Subcommand, Debug)]
pub enum ViewsCommand {
    /// Render the edit views (every camera but each 8th) to DIR/<stem>.<content key>.png
    /// plus views.json, for editing elsewhere; edited images with the same names go back
    /// in with `--editor folder`.
    Export(ExportArgs),
}

/// Arguments of `transsplat views export`.
#[derive(clap::Args, Debug)]
pub struct ExportArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Cameras: cameras.json, transforms.json, a COLMAP folder (sparse/0); default: beside the scene.
    #[arg(long)]
    pub cameras: Option<PathBuf>,
    /// Output folder: `<stem>.<key>.png` per edit view (`<key>`: a fingerprint of the
    /// scene and the camera) and `views.json`. A rerun into it copies the views it
    /// already holds instead of rendering them again.
    #[arg(long)]
    pub out: PathBuf,
    /// Export only shard I of N (0 <= I < N): the edit views at positions I, I+N, I+2N,
    /// ...; each shard needs its own output folder. The edited shards' folders gathered
    /// under one folder (or copied into one) go to `edit --editor folder --edits`.
    #[arg(long, value_name = "I/N", value_parser = Shard::parse)]
    pub shard: Option<Shard>,
    /// Background colour R,G,B in [0, 1].
    #[arg(long, value_parser = parse_rgb, default_value = "0,0,0")]
    pub background: [f32; 3],
}

/// Runs a `transsplat views` subcommand.
pub fn run(cmd: &ViewsCommand) -> Result<()> {
    match cmd {
        ViewsCommand::Export(a) => export(a),
    }
}

/// Runs `transsplat views export`.
pub fn export(args: &ExportArgs) -> Result<()> {
    let (g, scene_path) = load_scene(&args.scene)?;
    let (cams, cam_path) = load_cameras(args.cameras.as_deref(), &args.scene.scene)?;
    let edit: Vec<usize> = (0..cams.len()).filter(|&i| !transsplat_builtin::is_test(i)).collect();
    if edit.is_empty() {
        anyhow::bail!(
            "{}: only {} camera(s), all held out as test views; nothing to export",
            cam_path.display(),
            cams.len()
        );
    }
    let mut views: Vec<(usize, &Camera)> = edit.iter().map(|&i| (i, &cams[i])).collect();
    if let Some(shard) = args.shard {
        views = views.into_iter().enumerate().filter(|(p, _)| shard.holds(*p)).map(|(_, v)| v).collect();
        if views.is_empty() {
            anyhow::bail!(
                "{}: shard {shard} holds no view: there are only {} edit views; use at most {} shards",
                cam_path.display(),
                edit.len(),
                edit.len()
            );
        }
    }
    // Shards never replace each other: an earlier export in `out` must be of this shard.
    if let Some(earlier) = exported_shard(&args.out) {
        if args.shard.map(|s| s.to_string()).as_deref() != Some(earlier.as_str()) {
            let this = args.shard.map_or("all views".to_string(), |s| format!("shard {s}"));
            anyhow::bail!(
                "{}: holds shard {earlier} of an export, this is {this}; give each shard its own folder (e.g. --out views/I)",
                args.out.display()
            );
        }
    }
    // Never overwrites what this command did not write (e.g. a dataset's own images):
    // an existing folder must be empty or an earlier export (with views.json).
    let staged = staged_output(&args.out, &[&args.scene.scene, &scene_path, &cam_path], "views.json")?;
    let scene_fp = fingerprint::scene(&g);
    let splats = Splats::new(&g);
    let opts = RenderOptions { background: args.background };
    let pb = progress(views.len() as u64, "render");
    let spec = ExportSpec {
        scene: Some(&scene_fp),
        shard: args.shard,
        reuse: Some(&args.out),
        background: args.background,
    };
    let done = export_views(&views, staged.dir(), spec, |_, _, cam| {
        let (img, _) = render(&splats, cam, &opts);
        pb.inc(1);
        Ok(img.rgb)
    })?;
    pb.finish_and_clear();
    let out = staged.commit()?;
    let shard = args.shard.map_or(String::new(), |s| format!(" (shard {s})"));
    tracing::info!(
        "exported {} edit views{shard} to {} ({} reused from the earlier export)",
        views.len(),
        out.display(),
        done.reused
    );
    Ok(())
}

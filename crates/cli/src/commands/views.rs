//! `transsplat views export`: renders the edit views (the training views, index % 8 != 0)
//! for editing with any 2D tool; the edited folder goes back in with `--editor folder`.

use super::common::{load_cameras, load_scene, parse_rgb, progress, staged_output, SceneArgs};
use anyhow::Result;
use std::path::PathBuf;
use transsplat_editors::export_views_with;
use transsplat_raster::{render, RenderOptions, Splats};
use transsplat_scene::Camera;

/// Subcommands of `transsplat views`.
#[derive(clap::Subcommand, Debug)]
pub enum ViewsCommand {
    /// Render the edit views (every camera but each 8th) to DIR/<image name>.png plus
    /// views.json, for editing elsewhere; edited images with the same names go back in
    /// with `--editor folder`.
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
    /// Output folder: `<image name>.png` per edit view and `views.json`.
    #[arg(long)]
    pub out: PathBuf,
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
    let edit: Vec<usize> = (0..cams.len()).filter(|&i| !transsplat_scenes::is_test(i)).collect();
    if edit.is_empty() {
        anyhow::bail!(
            "{}: only {} camera(s), all held out as test views; nothing to export",
            cam_path.display(),
            cams.len()
        );
    }
    // Never overwrites what this command did not write (e.g. a dataset's own images):
    // an existing folder must be empty or an earlier export (with views.json).
    let staged = staged_output(&args.out, &[&args.scene.scene, &scene_path, &cam_path], "views.json")?;
    let splats = Splats::new(&g);
    let opts = RenderOptions { background: args.background };
    let pb = progress(edit.len() as u64, "render");
    let views: Vec<(usize, &Camera)> = edit.iter().map(|&i| (i, &cams[i])).collect();
    export_views_with(&views, staged.path(), |_, _, cam| {
        let (img, _) = render(&splats, cam, &opts);
        pb.inc(1);
        Ok(img.rgb)
    })?;
    pb.finish_and_clear();
    let out = staged.commit()?;
    tracing::info!("exported {} edit views to {}", views.len(), out.display());
    Ok(())
}

//! `transsplat render`: renders every camera of a scene to PNG (and raw `.npy`).

use super::common::{load_cameras, load_scene, parse_rgb, prepare_out_dir, progress, SceneArgs};
use anyhow::Result;
use std::path::{Path, PathBuf};
use transsplat_raster::{render, RenderOptions, Splats};
use transsplat_scene::{image, npy, Camera, Gaussians};

/// Arguments of `transsplat render`.
#[derive(clap::Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Cameras: cameras.json, transforms.json, a COLMAP folder (sparse/0); default: beside the scene.
    #[arg(long)]
    pub cameras: Option<PathBuf>,
    /// Output folder: `<image name>.png` per camera.
    #[arg(long)]
    pub out: PathBuf,
    /// Also write float32 H×W×3 RGB as `<image name>.npy`.
    #[arg(long)]
    pub raw: bool,
    /// Background colour R,G,B in [0, 1].
    #[arg(long, value_parser = parse_rgb, default_value = "0,0,0")]
    pub background: [f32; 3],
}

/// Runs `transsplat render`.
pub fn run(args: &RenderArgs) -> Result<()> {
    let (g, scene_path) = load_scene(&args.scene)?;
    let (cams, cam_path) = load_cameras(args.cameras.as_deref(), &args.scene.scene)?;
    let out = prepare_out_dir(&args.out, &[&scene_path, &cam_path])?;
    render_views(&g, &cams, &out, args.background, args.raw)?;
    tracing::info!("rendered {} views to {}", cams.len(), out.display());
    Ok(())
}

/// Renders `g` from every camera to `out/<image name>.png` (and `.npy` with `raw`).
pub fn render_views(
    g: &Gaussians,
    cams: &[Camera],
    out: &Path,
    background: [f32; 3],
    raw: bool,
) -> Result<()> {
    let splats = Splats::new(g);
    let opts = RenderOptions { background };
    let pb = progress(cams.len() as u64, "render");
    for cam in cams {
        let (img, _) = render(&splats, cam, &opts);
        let stem = cam.stem();
        image::write_png(&out.join(format!("{stem}.png")), img.width, img.height, &img.rgb)?;
        if raw {
            npy::write(&out.join(format!("{stem}.npy")), &[img.height, img.width, 3], &img.rgb)?;
        }
        pb.inc(1);
    }
    pb.finish_and_clear();
    Ok(())
}

//! `transsplat render`: renders every camera of a scene to PNG (and raw `.npy`).

use super::common::{load_cameras, load_scene, parse_rgb, progress, staged_output, SceneArgs};
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use transsplat_raster::{render, RenderOptions, Splats};
use transsplat_scene::{atomic, image, npy, Camera, Gaussians};

/// Arguments of `transsplat render`.
#[derive(clap::Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Cameras: cameras.json, transforms.json, a COLMAP folder (sparse/0); default: beside the scene.
    #[arg(long)]
    pub cameras: Option<PathBuf>,
    /// Output folder: `<image name>.png` per camera and render.json; it appears only when
    /// every view is written (an existing one must be empty or an earlier render output).
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
pub fn run(args: &RenderArgs, cancel: &AtomicBool) -> Result<()> {
    let (g, scene_path) = load_scene(&args.scene)?;
    let (cams, cam_path) = load_cameras(args.cameras.as_deref(), &args.scene.scene)?;
    let staged = staged_output(&args.out, &[&args.scene.scene, &scene_path, &cam_path], MARKER)?;
    render_views(&g, &cams, staged.dir(), args.background, args.raw, cancel)
        .with_context(|| format!("nothing was written to {}", args.out.display()))?;
    let summary = RenderSummary {
        scene: std::path::absolute(&scene_path)?,
        cameras: std::path::absolute(&cam_path)?,
        views: cams.len(),
        background: args.background,
        raw: args.raw,
    };
    let text = serde_json::to_string_pretty(&summary).expect("plain data serialises") + "\n";
    atomic::write_bytes(&staged.dir().join(MARKER), text.as_bytes())?;
    let out = staged.commit()?;
    tracing::info!("rendered {} views to {}", cams.len(), out.display());
    Ok(())
}

/// What `render` writes beside the images (the scene, cameras and settings); it marks a
/// folder as `render`'s own, which a rerun may replace.
pub const MARKER: &str = "render.json";

/// `render.json`.
#[derive(Debug, serde::Serialize)]
struct RenderSummary {
    /// The scene file rendered (absolute).
    scene: PathBuf,
    /// The cameras' file (absolute).
    cameras: PathBuf,
    views: usize,
    background: [f32; 3],
    /// Whether the float renders were written too (`.npy`).
    raw: bool,
}

/// Renders `g` from every camera to `out/<image name>.png` (and `.npy` with `raw`).
/// Stops between views when `cancel` is set; every file written is complete (each is
/// written to a temporary name and renamed).
pub fn render_views(
    g: &Gaussians,
    cams: &[Camera],
    out: &Path,
    background: [f32; 3],
    raw: bool,
    cancel: &AtomicBool,
) -> Result<()> {
    let splats = Splats::new(g);
    let opts = RenderOptions { background };
    let pb = progress(cams.len() as u64, "render");
    for (i, cam) in cams.iter().enumerate() {
        if cancel.load(Ordering::SeqCst) {
            pb.finish_and_clear();
            bail!("interrupted after {i} of {} views", cams.len());
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stop_request_ends_rendering_between_views() {
        let config = transsplat_builtin::SceneConfig { views: 3, ..transsplat_builtin::SceneConfig::quick() };
        let scene = transsplat_builtin::build("tabletop", &config).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let stop = AtomicBool::new(true);
        let err =
            render_views(&scene.gaussians, &scene.cameras, dir.path(), [0.0; 3], false, &stop).unwrap_err();
        assert!(err.to_string().starts_with("interrupted after 0 of 3 views"), "{err}");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
        stop.store(false, Ordering::SeqCst);
        render_views(&scene.gaussians, &scene.cameras, dir.path(), [0.0; 3], false, &stop).unwrap();
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 3);
    }
}

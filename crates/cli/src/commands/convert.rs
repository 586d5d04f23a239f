//! `transsplat convert`: a scene from one file format to another (INRIA PLY,
//! PlayCanvas compressed PLY, SPZ, glTF binary, SOG), and optionally its cameras to INRIA cameras.json.

use super::common::{check_output, load_cameras, load_scene, SceneArgs, SpzWriteArgs};
use anyhow::{bail, Result};
use std::path::PathBuf;
use transsplat_scene::formats::{self, SceneFormat};
use transsplat_scene::spz;

/// Arguments of `transsplat convert`.
#[derive(clap::Args, Debug)]
pub struct ConvertArgs {
    /// Input scene: a PLY (INRIA or compressed), an .spz, .glb or .sog file or an INRIA
    /// output folder.
    pub input: PathBuf,
    /// Output scene file; its format follows from the name (.spz, .compressed.ply, .ply,
    /// .glb, .sog) unless --format is given.
    pub output: PathBuf,
    /// Output format: ply, compressed-ply, spz, glb or sog.
    #[arg(long, value_parser = SceneFormat::parse)]
    pub format: Option<SceneFormat>,
    /// Drop Gaussians with NaN or infinite parameters instead of refusing the file.
    #[arg(long)]
    pub drop_invalid: bool,
    /// Axes of an .spz read or written: rub (Niantic's documented convention,
    /// splat-transform 2.x; the default) or rdf (the PLY's axes unconverted:
    /// splat-transform 3.x, Niantic's ply_to_spz).
    #[arg(long, value_parser = spz::Axes::parse, default_value = "rub")]
    pub spz_axes: spz::Axes,
    #[command(flatten)]
    pub spz: SpzWriteArgs,
    /// Also convert these cameras (any format `render` reads) ...
    #[arg(long, requires = "cameras_out")]
    pub cameras: Option<PathBuf>,
    /// ... to this INRIA cameras.json (the camera list of a 3DGS output folder).
    #[arg(long, requires = "cameras")]
    pub cameras_out: Option<PathBuf>,
}

/// Runs `transsplat convert`.
pub fn run(a: &ConvertArgs) -> Result<()> {
    let format = match a.format.or_else(|| SceneFormat::of_path(&a.output)) {
        Some(f) => f,
        None => bail!(
            "{}: cannot tell the output format from the name; use {}, or --format",
            a.output.display(),
            SceneFormat::ALL.map(SceneFormat::extension).join(", ")
        ),
    };
    let (g, scene_path) = load_scene(&SceneArgs {
        scene: a.input.clone(),
        drop_invalid: a.drop_invalid,
        spz_axes: a.spz_axes,
    })?;
    let mut inputs = vec![a.input.as_path(), scene_path.as_path()];
    if let Some(c) = &a.cameras {
        inputs.push(c);
    }
    check_output(&a.output, &inputs)?;
    if let (Some(src), Some(out)) = (&a.cameras, &a.cameras_out) {
        let (cams, cam_path) = load_cameras(Some(src), &a.input)?;
        let mut cam_inputs = inputs.clone();
        cam_inputs.push(&cam_path);
        cam_inputs.push(&a.output);
        check_output(out, &cam_inputs)?;
        transsplat_scene::cameras::inria::write(out, &cams)?;
        tracing::info!("wrote {} cameras to {}", cams.len(), out.display());
    }
    let options =
        formats::WriteOptions { spz: spz::Options { version: a.spz.spz_version, axes: a.spz_axes } };
    formats::write_with(&a.output, &g, format, &options)?;
    let size = std::fs::metadata(&a.output).map(|m| m.len()).unwrap_or(0);
    tracing::info!(
        "wrote {} Gaussians as {} to {} ({:.1} MB, {:.1} bytes a Gaussian)",
        g.len(),
        format.name(),
        a.output.display(),
        size as f64 / 1e6,
        size as f64 / g.len() as f64
    );
    Ok(())
}

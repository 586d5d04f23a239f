//! Loading inputs and preparing outputs, shared by the commands.

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use transsplat_scene::{cameras, ply, scene_paths, Camera, Gaussians};

/// Options shared by every command that reads a scene.
#[derive(clap::Args, Debug, Clone)]
pub struct SceneArgs {
    /// Scene: an INRIA 3DGS PLY, or an INRIA output folder (newest iteration is used).
    #[arg(long)]
    pub scene: PathBuf,
    /// Drop Gaussians with NaN or infinite parameters instead of refusing the file.
    #[arg(long)]
    pub drop_invalid: bool,
}

/// Reads and checks the scene; returns it with the PLY path it came from.
pub fn load_scene(args: &SceneArgs) -> Result<(Gaussians, PathBuf)> {
    let path = scene_paths::resolve_scene(&args.scene)?;
    let (g, dropped) = ply::read_with(&path, &ply::ReadOptions { drop_invalid: args.drop_invalid })?;
    if dropped > 0 {
        tracing::warn!("{}: dropped {dropped} Gaussians with NaN or infinite parameters", path.display());
    }
    if g.is_empty() {
        bail!("{}: the scene has no Gaussians", path.display());
    }
    tracing::info!("{}: {} Gaussians, SH degree {}", path.display(), g.len(), g.sh_degree);
    Ok((g, path))
}

/// Loads cameras from `--cameras`, or from beside the scene when it is an INRIA folder.
pub fn load_cameras(cameras_arg: Option<&Path>, scene: &Path) -> Result<(Vec<Camera>, PathBuf)> {
    let path = match cameras_arg {
        Some(p) => p.to_path_buf(),
        None => scene_paths::resolve_cameras_for(scene)
            .context("no --cameras given and none found beside the scene")?,
    };
    let cams = cameras::load(&path)?;
    if cams.is_empty() {
        bail!("{}: no cameras", path.display());
    }
    let mut stems = std::collections::HashSet::new();
    for c in &cams {
        if !stems.insert(c.stem()) {
            bail!(
                "{}: two cameras share the image name {:?}; outputs would overwrite each other",
                path.display(),
                c.stem()
            );
        }
    }
    Ok((cams, path))
}

/// Creates the output folder, refusing one that is an input file or holds the inputs
/// in a way outputs could overwrite.
pub fn prepare_out_dir(out: &Path, inputs: &[&Path]) -> Result<PathBuf> {
    if out.exists() && !out.is_dir() {
        bail!("{}: output path exists and is not a folder", out.display());
    }
    std::fs::create_dir_all(out)
        .with_context(|| format!("{}: cannot create output folder", out.display()))?;
    let out =
        out.canonicalize().with_context(|| format!("{}: cannot resolve output folder", out.display()))?;
    for input in inputs {
        if let Ok(inp) = input.canonicalize() {
            let dir = if inp.is_dir() {
                inp.clone()
            } else {
                inp.parent().map(Path::to_path_buf).unwrap_or_default()
            };
            if out == dir {
                bail!(
                    "{}: output folder is the folder of the input {}; choose another so no input can be overwritten",
                    out.display(),
                    input.display()
                );
            }
        }
    }
    let probe = out.join(".transsplat-write-test");
    std::fs::write(&probe, b"")
        .with_context(|| format!("{}: output folder is not writable", out.display()))?;
    let _ = std::fs::remove_file(probe);
    Ok(out)
}

/// Parses `R,G,B` with components in [0, 1].
pub fn parse_rgb(s: &str) -> Result<[f32; 3], String> {
    let v: Vec<f32> =
        s.split(',').map(|c| c.trim().parse::<f32>()).collect::<Result<_, _>>().map_err(|e| e.to_string())?;
    match v[..] {
        [r, g, b] if v.iter().all(|c| c.is_finite() && (0.0..=1.0).contains(c)) => Ok([r, g, b]),
        _ => Err(format!("expected R,G,B with three numbers in [0, 1], got {s:?}")),
    }
}

/// A progress bar on stderr (hidden when stderr is not a terminal).
pub fn progress(len: u64, what: &str) -> indicatif::ProgressBar {
    let pb = indicatif::ProgressBar::new(len);
    pb.set_style(
        indicatif::ProgressStyle::with_template(
            "{msg:>10} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    pb.set_message(what.to_string());
    pb
}

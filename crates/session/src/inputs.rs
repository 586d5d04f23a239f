//! A job's scene and cameras, read and checked the same way whichever front asks.
//!
//! - The scene: any format [`transsplat_scene::formats`] reads (INRIA PLY, compressed
//!   PLY, SPZ), or an INRIA output folder (its newest iteration); never empty.
//! - The cameras: a file or model folder ([`transsplat_scene::cameras::load`]), or the
//!   ones beside an INRIA scene folder; never empty, every camera valid, and each image
//!   name used once, since a job's outputs (renders, edited views) are named after it.
//!
//! Every error names the file it is about.

use crate::SessionError;
use std::path::{Path, PathBuf};
use transsplat_scene::{cameras, formats, scene_paths, Camera, Gaussians};

/// Reads and checks the scene at `path` (a file or an INRIA output folder); returns it
/// with the file it came from.
pub fn load_scene(path: &Path, options: &formats::ReadOptions) -> Result<(Gaussians, PathBuf), SessionError> {
    let file = scene_paths::resolve_scene(path)?;
    let (gaussians, dropped) = formats::read_with(&file, options)?;
    if dropped > 0 {
        tracing::warn!("{}: dropped {dropped} Gaussians with NaN or infinite parameters", file.display());
    }
    if gaussians.is_empty() {
        return Err(SessionError::Input(format!("{}: the scene has no Gaussians", file.display())));
    }
    tracing::info!("{}: {} Gaussians, SH degree {}", file.display(), gaussians.len(), gaussians.sh_degree);
    Ok((gaussians, file))
}

/// Reads and checks the cameras at `path`, or, without one, those beside `scene` (an
/// INRIA output folder's `cameras.json`); returns them with the file they came from.
pub fn load_cameras(path: Option<&Path>, scene: &Path) -> Result<(Vec<Camera>, PathBuf), SessionError> {
    let file = match path {
        Some(p) => p.to_path_buf(),
        None => scene_paths::resolve_cameras_for(scene).map_err(|e| {
            SessionError::Input(format!("no --cameras given and none found beside the scene: {e}"))
        })?,
    };
    // The loaders check every camera and that no two share an image name
    // (`cameras::validated`).
    let list = cameras::load(&file)?;
    if list.is_empty() {
        return Err(SessionError::Input(format!("{}: no cameras", file.display())));
    }
    Ok((list, file))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cameras_that_share_an_image_name_are_refused_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cameras.json");
        let entry = |id: u32| {
            format!(
                r#"{{"id": {id}, "img_name": "same", "width": 40, "height": 30, "position": [0, 0, -3],
                "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "fx": 50, "fy": 50}}"#
            )
        };
        std::fs::write(&path, format!("[{}, {}]", entry(0), entry(1))).unwrap();
        let message = load_cameras(Some(&path), dir.path()).unwrap_err().to_string();
        assert!(message.contains("cameras.json") && message.contains("\"same\""), "{message}");
        std::fs::write(&path, format!("[{}]", entry(0))).unwrap();
        assert_eq!(load_cameras(Some(&path), dir.path()).unwrap().0.len(), 1);
    }

    #[test]
    fn a_folder_without_cameras_says_which_flag_to_give() {
        let dir = tempfile::tempdir().unwrap();
        let message = load_cameras(None, dir.path()).unwrap_err().to_string();
        assert!(message.starts_with("no --cameras given"), "{message}");
    }
}

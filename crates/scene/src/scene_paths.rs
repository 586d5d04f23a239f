//! Finding the scene and camera files from what the user points at: a `.ply` file or
//! an INRIA 3DGS output folder (`point_cloud/iteration_*/point_cloud.ply` and
//! `cameras.json`).

use crate::{Error, Result};
use std::path::{Path, PathBuf};

/// The PLY file for `path`: a file as is; for an INRIA output folder the
/// `point_cloud.ply` of the highest `iteration_N` (numeric order); for a folder
/// holding a `point_cloud.ply` directly, that file.
pub fn resolve_scene(path: &Path) -> Result<PathBuf> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if meta.is_file() {
        return Ok(path.to_path_buf());
    }
    let pc = path.join("point_cloud");
    if pc.is_dir() {
        let entries = std::fs::read_dir(&pc).map_err(|e| Error::io(&pc, e))?;
        let mut best: Option<(u64, PathBuf)> = None;
        for entry in entries {
            let entry = entry.map_err(|e| Error::io(&pc, e))?;
            let name = entry.file_name();
            let Some(iter) =
                name.to_str().and_then(|n| n.strip_prefix("iteration_")).and_then(|n| n.parse::<u64>().ok())
            else {
                continue;
            };
            let ply = entry.path().join("point_cloud.ply");
            if ply.is_file() && !matches!(best, Some((b, _)) if b >= iter) {
                best = Some((iter, ply));
            }
        }
        return best.map(|(_, p)| p).ok_or_else(|| {
            Error::format(
                &pc,
                "no iteration_*/point_cloud.ply inside (an INRIA 3DGS output folder was expected)",
            )
        });
    }
    let direct = path.join("point_cloud.ply");
    if direct.is_file() {
        return Ok(direct);
    }
    Err(Error::format(
        path,
        "no scene found: expected a .ply file or an INRIA 3DGS output folder with point_cloud/iteration_*/point_cloud.ply",
    ))
}

/// The cameras belonging to a scene path: for an INRIA output folder (or a
/// `point_cloud.ply` inside one) its `cameras.json`; otherwise any camera source
/// [`crate::cameras::load`] recognises in the folder or beside the file.
pub fn resolve_cameras_for(scene: &Path) -> Result<PathBuf> {
    let meta = std::fs::metadata(scene).map_err(|e| Error::io(scene, e))?;
    let mut candidates: Vec<PathBuf> = Vec::new();
    if meta.is_dir() {
        candidates.push(scene.to_path_buf());
    } else if let Some(dir) = scene.parent() {
        candidates.push(dir.to_path_buf());
        // .../point_cloud/iteration_N/point_cloud.ply -> the output folder
        let up = dir.parent().filter(|p| p.file_name().is_some_and(|n| n == "point_cloud"));
        if let Some(root) = up.and_then(Path::parent) {
            candidates.push(root.to_path_buf());
        }
    }
    for dir in &candidates {
        let json = dir.join("cameras.json");
        if json.is_file() {
            return Ok(json);
        }
    }
    for dir in &candidates {
        if let Some(p) = crate::cameras::find_cameras_in(dir) {
            return Ok(p);
        }
    }
    Err(Error::format(
        scene,
        "no cameras found beside this scene (looked for cameras.json, transforms.json, COLMAP sparse/0); \
         give the cameras explicitly",
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inria_output_folder_finds_the_newest_iteration_and_cameras() {
        let d = tempfile::tempdir().unwrap();
        let root = d.path();
        for it in ["iteration_900", "iteration_30000", "iteration_7000", "iteration_40000", "iteration_x"] {
            std::fs::create_dir_all(root.join("point_cloud").join(it)).unwrap();
        }
        for it in ["iteration_900", "iteration_30000", "iteration_7000", "iteration_x"] {
            std::fs::write(root.join("point_cloud").join(it).join("point_cloud.ply"), b"ply\n").unwrap();
        }
        // iteration_40000 has no point_cloud.ply; 900 wins lexically but 30000 numerically.
        let want = root.join("point_cloud/iteration_30000/point_cloud.ply");
        assert_eq!(resolve_scene(root).unwrap(), want);
        assert_eq!(resolve_scene(&want).unwrap(), want);
        std::fs::write(root.join("cameras.json"), b"[]").unwrap();
        assert_eq!(resolve_cameras_for(root).unwrap(), root.join("cameras.json"));
        assert_eq!(resolve_cameras_for(&want).unwrap(), root.join("cameras.json"));
    }

    #[test]
    fn plain_files_and_failures() {
        let d = tempfile::tempdir().unwrap();
        let root = d.path();
        let e = resolve_scene(root).unwrap_err().to_string();
        assert!(e.starts_with(&format!("{}: no scene found", root.display())), "{e}");
        std::fs::create_dir(root.join("point_cloud")).unwrap();
        let e = resolve_scene(root).unwrap_err().to_string();
        assert!(e.contains("point_cloud: no iteration_*"), "{e}");
        let ply = root.join("scene.ply");
        std::fs::write(&ply, b"ply\n").unwrap();
        let e = resolve_cameras_for(&ply).unwrap_err().to_string();
        assert!(e.starts_with(&format!("{}: no cameras found", ply.display())), "{e}");
        std::fs::create_dir_all(root.join("sparse/0")).unwrap();
        std::fs::write(root.join("sparse/0/cameras.txt"), b"").unwrap();
        assert_eq!(resolve_cameras_for(&ply).unwrap(), root.join("sparse/0"));
        std::fs::write(root.join("transforms.json"), b"{}").unwrap();
        assert_eq!(resolve_cameras_for(&ply).unwrap(), root.join("transforms.json"));
        assert!(resolve_scene(&root.join("missing.ply")).is_err());
    }
}

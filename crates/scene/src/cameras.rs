//! Cameras from the formats 3DGS tools use, all converted to [`Camera`] (OpenCV
//! convention, world-to-camera, pinhole):
//!
//! - [`inria`]: the INRIA 3DGS `cameras.json` (read and write);
//! - [`colmap`]: COLMAP `sparse/0` in `.bin` or `.txt` (cameras, images, points3D);
//! - [`transforms`]: nerfstudio / Blender `transforms.json` (OpenGL camera-to-world).
//!
//! [`load`] picks the format from a path. Every returned camera passes
//! [`Camera::validate`] (a non-empty image name, a size within the one cap for images
//! and cameras [`crate::camera::check_image_size`], positive focal lengths, a rotation
//! that is orthonormal within [`crate::camera::ROTATION_TOLERANCE`]), and no two
//! cameras of a file share an image name; distortion that is not exactly zero is
//! refused, never ignored; fields of view must lie in (0, π).
//! [`is_held_out`] is the train/test split of a camera list ([`LLFF_HOLD`]).

use crate::{Camera, Error, Result};
use std::path::{Path, PathBuf};

pub mod colmap;
pub mod image_size;
pub mod inria;
pub mod transforms;

pub use colmap::{ColmapModel, Point3D};
pub use transforms::Transforms;

/// INRIA's `llffhold`: every 8th camera, in image-name order, is a test view.
pub const LLFF_HOLD: usize = 8;

/// Whether camera `index` is held out for testing when every `every`-th one is
/// (`index % every == 0`; none when `every` is 0).
pub fn is_held_out(index: usize, every: usize) -> bool {
    every > 0 && index.is_multiple_of(every)
}

/// The held-out test views and the edit views of `n` cameras in name order (every
/// [`LLFF_HOLD`]-th one held out); when every camera is held out (a single camera), all
/// of them are edited.
pub fn split_views(n: usize) -> (Vec<usize>, Vec<usize>) {
    let (test, edit): (Vec<usize>, Vec<usize>) = (0..n).partition(|&i| is_held_out(i, LLFF_HOLD));
    let edit = if edit.is_empty() { (0..n).collect() } else { edit };
    (test, edit)
}

/// Loads cameras from `path`, detecting the format:
///
/// - a `.json` file: an INRIA `cameras.json` (a list) or a `transforms.json` (an object
///   with `frames`);
/// - a COLMAP model folder (containing `cameras.bin` or `cameras.txt`), or a dataset
///   folder containing `sparse/0` (or `sparse`);
/// - an INRIA output folder (containing `cameras.json`);
/// - a dataset folder containing `transforms.json`.
pub fn load(path: &Path) -> Result<Vec<Camera>> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if meta.is_file() {
        return load_json(path);
    }
    match find_in_dir(path) {
        Some(Found::Json(p)) => load_json(&p),
        Some(Found::Colmap(d)) => Ok(colmap::read_sparse(&d)?.cameras),
        None => Err(Error::format(
            path,
            "no cameras found: expected cameras.json, transforms.json, a COLMAP model \
             (cameras.bin/.txt) or sparse/0 inside this folder",
        )),
    }
}

enum Found {
    Json(PathBuf),
    Colmap(PathBuf),
}

fn is_colmap_dir(d: &Path) -> bool {
    d.join("cameras.bin").is_file() || d.join("cameras.txt").is_file()
}

fn find_in_dir(dir: &Path) -> Option<Found> {
    for name in ["cameras.json", "transforms.json"] {
        let p = dir.join(name);
        if p.is_file() {
            return Some(Found::Json(p));
        }
    }
    [dir.to_path_buf(), dir.join("sparse").join("0"), dir.join("sparse")]
        .into_iter()
        .find(|d| is_colmap_dir(d))
        .map(Found::Colmap)
}

/// The COLMAP or JSON camera source inside a folder, if there is one (see [`load`]).
pub fn find_cameras_in(dir: &Path) -> Option<PathBuf> {
    find_in_dir(dir).map(|f| match f {
        Found::Json(p) | Found::Colmap(p) => p,
    })
}

fn load_json(path: &Path) -> Result<Vec<Camera>> {
    parse_json(&crate::atomic::read(path)?, path)
}

/// Parses camera JSON bytes, an INRIA `cameras.json` or a `transforms.json` (as [`load`]
/// does for a `.json` file); `path` names the file in errors and is the folder
/// `transforms.json` image paths are relative to.
pub fn parse_json(bytes: &[u8], path: &Path) -> Result<Vec<Camera>> {
    let value: serde_json::Value =
        serde_json::from_slice(bytes).map_err(|e| Error::format(path, format!("not valid JSON: {e}")))?;
    match &value {
        serde_json::Value::Array(_) => inria::from_value(&value, path),
        serde_json::Value::Object(m) if m.contains_key("frames") => {
            Ok(transforms::from_value(&value, path)?.cameras)
        }
        _ => Err(Error::format(
            path,
            "unrecognised camera JSON: expected an INRIA cameras.json list or a transforms.json \
             object with \"frames\"",
        )),
    }
}

/// Checks every camera ([`Camera::validate`]) and that no two share an image name
/// (compared by [`Camera::stem`], which names their outputs), naming `path` in the error.
/// Cameras are counted from 0 in the order given.
pub fn validated(cameras: Vec<Camera>, path: &Path) -> Result<Vec<Camera>> {
    let mut seen = std::collections::HashMap::with_capacity(cameras.len());
    for (i, c) in cameras.iter().enumerate() {
        c.validate().map_err(|m| {
            if c.name.trim().is_empty() {
                Error::format(path, format!("camera {i}: {m}"))
            } else {
                Error::format(path, m)
            }
        })?;
        if let Some(first) = seen.insert(c.stem(), &c.name) {
            let also =
                if *first == c.name { String::new() } else { format!(" ({first:?} and {:?})", c.name) };
            return Err(Error::format(
                path,
                format!(
                    "two cameras share the image name {:?}{also}; their outputs would overwrite each other",
                    c.stem()
                ),
            ));
        }
    }
    Ok(cameras)
}

/// A positive image dimension from a JSON number (integral floats like `800.0` allowed).
pub(crate) fn json_dim(v: &serde_json::Value) -> Option<u32> {
    let f = v.as_f64()?;
    (f.fract() == 0.0 && f >= 0.0 && f <= u32::MAX as f64).then_some(f as u32)
}

/// Rotation matrix of a (w, x, y, z) quaternion, normalised first (COLMAP does the
/// same). None for a zero or non-finite quaternion.
pub(crate) fn quat_to_matrix(q: [f64; 4]) -> Option<[[f32; 3]; 3]> {
    // Scaled by the largest component first so that squaring neither overflows nor
    // underflows: any finite non-zero quaternion has a direction.
    let big = q.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    if !(big.is_finite() && big > 0.0) || q.iter().any(|v| v.is_nan()) {
        return None;
    }
    let q = q.map(|v| v / big);
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let [w, x, y, z] = q.map(|v| v / n);
    let m = [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ];
    Some(m.map(|r| r.map(|v| v as f32)))
}

#[cfg(test)]
mod tests;

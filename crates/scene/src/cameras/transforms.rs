//! nerfstudio / Blender (NeRF synthetic) `transforms.json`.
//!
//! Each frame has a `file_path` and a 4x4 `transform_matrix`: camera-to-world in the
//! OpenGL convention (x right, y up, looking down -z). We flip the camera's y and z
//! axes to get OpenCV. Intrinsics come from the frame or the top level:
//! `fl_x fl_y cx cy w h`, or Blender's `camera_angle_x` (fx = fy = w / (2 tan(a/2)),
//! principal point at the centre, `w h` from the image header when not given); an
//! angle must be a field of view in radians, in (0, π).
//! Distortion `k1..k4 p1 p2` must be zero and `camera_model` a pinhole one. A frame's
//! optional `mask_path` names its training mask (nerfstudio's convention).

use crate::{Camera, Error, Result};
use serde_json::Value;
use std::path::{Path, PathBuf};

/// Cameras and the optional point cloud named by a `transforms.json`.
#[derive(Clone, Debug, PartialEq)]
pub struct Transforms {
    /// One camera per frame, in file order; named by the frame's `file_path`.
    pub cameras: Vec<Camera>,
    /// `ply_file_path` resolved relative to the JSON file's folder.
    pub ply_file_path: Option<PathBuf>,
    /// Each frame's `mask_path` (nerfstudio's per-frame training mask), resolved
    /// relative to the JSON file's folder; one entry per camera.
    pub mask_paths: Vec<Option<PathBuf>>,
}

/// Reads a `transforms.json`.
pub fn read(path: &Path) -> Result<Transforms> {
    parse(&crate::atomic::read(path)?, path)
}

/// Parses the bytes of a file at `path` (named in errors).
pub fn parse(bytes: &[u8], path: &Path) -> Result<Transforms> {
    let value: Value =
        serde_json::from_slice(bytes).map_err(|e| Error::format(path, format!("not valid JSON: {e}")))?;
    from_value(&value, path)
}

const DISTORTION: [&str; 6] = ["k1", "k2", "k3", "k4", "p1", "p2"];
const PINHOLE_MODELS: [&str; 3] = ["OPENCV", "PINHOLE", "SIMPLE_PINHOLE"];

pub(crate) fn from_value(value: &Value, path: &Path) -> Result<Transforms> {
    let err = |m: String| Error::format(path, m);
    let top = value.as_object().ok_or_else(|| err("expected a JSON object with \"frames\"".into()))?;
    let frames =
        top.get("frames").and_then(Value::as_array).ok_or_else(|| err("missing \"frames\" list".into()))?;
    let base = path.parent().unwrap_or(Path::new(""));
    let mut cameras = Vec::with_capacity(frames.len());
    let mut mask_paths = Vec::with_capacity(frames.len());
    for (i, frame) in frames.iter().enumerate() {
        let fobj = frame.as_object().ok_or_else(|| err(format!("frame {i} is not an object")))?;
        let name = fobj
            .get("file_path")
            .and_then(Value::as_str)
            .ok_or_else(|| err(format!("frame {i}: missing \"file_path\"")))?
            .to_string();
        let what = format!("frame {i} ({name:?})");
        mask_paths.push(match fobj.get("mask_path") {
            None | Some(Value::Null) => None,
            Some(Value::String(s)) if !s.trim().is_empty() => Some(base.join(s)),
            Some(_) => return Err(err(format!("{what}: \"mask_path\" is not a file name"))),
        });
        let get = |k: &str| fobj.get(k).or_else(|| top.get(k)).filter(|v| !v.is_null());
        let number = |k: &str| -> Result<Option<f64>> {
            match get(k) {
                None => Ok(None),
                Some(v) => {
                    v.as_f64().map(Some).ok_or_else(|| err(format!("{what}: \"{k}\" is not a number")))
                }
            }
        };
        if let Some(m) = get("camera_model") {
            let m = m.as_str().unwrap_or("");
            if !PINHOLE_MODELS.contains(&m) {
                return Err(err(format!(
                    "{what}: camera_model {m:?} is not supported (only OPENCV with zero distortion, PINHOLE, \
                     SIMPLE_PINHOLE); undistort the images first"
                )));
            }
        }
        for k in DISTORTION {
            if let Some(d) = number(k)? {
                if d != 0.0 {
                    return Err(err(format!(
                        "{what}: distortion {k} = {d} is not supported (pinhole cameras only); undistort the \
                         images first"
                    )));
                }
            }
        }
        let dim = |k: &str| -> Result<Option<u32>> {
            match get(k) {
                None => Ok(None),
                Some(v) => super::json_dim(v)
                    .map(Some)
                    .ok_or_else(|| err(format!("{what}: \"{k}\" is not a non-negative integer"))),
            }
        };
        let (width, height) = match (dim("w")?, dim("h")?) {
            (Some(w), Some(h)) => (w, h),
            _ => {
                let image = find_image(base, &name).ok_or_else(|| {
                    err(format!(
                        "{what}: no \"w\"/\"h\" given and the image {} was not found to read its size",
                        base.join(&name).display()
                    ))
                })?;
                super::image_size::read(&image)?
            }
        };
        let angle = |k: &str| -> Result<Option<f64>> {
            match number(k)? {
                Some(a) if !(a > 0.0 && a < std::f64::consts::PI) => Err(err(format!(
                    "{what}: \"{k}\" = {a} is not a field of view in radians between 0 and pi (3.14159)"
                ))),
                a => Ok(a),
            }
        };
        let fx = match (number("fl_x")?, angle("camera_angle_x")?) {
            (Some(f), _) => f,
            (None, Some(a)) => 0.5 * width as f64 / (0.5 * a).tan(),
            (None, None) => {
                return Err(err(format!("{what}: no focal length (\"fl_x\" or \"camera_angle_x\")")))
            }
        };
        let fy = match (number("fl_y")?, angle("camera_angle_y")?) {
            (Some(f), _) => f,
            (None, Some(a)) => 0.5 * height as f64 / (0.5 * a).tan(),
            (None, None) => fx,
        };
        let cx = number("cx")?.unwrap_or(width as f64 / 2.0);
        let cy = number("cy")?.unwrap_or(height as f64 / 2.0);
        let m = fobj.get("transform_matrix").and_then(matrix).ok_or_else(|| {
            err(format!("{what}: \"transform_matrix\" is not a 4x4 (or 3x4) matrix of numbers"))
        })?;
        // Whether the rotation part is a rotation is checked with every other camera
        // format's, in `Camera::validate` (through `validated` below).
        // OpenGL -> OpenCV: negate the camera's y and z axes (columns 1 and 2).
        let mut r = [[0.0f32; 3]; 3];
        for (row, src) in r.iter_mut().zip(&m) {
            *row = [src[0] as f32, -src[1] as f32, -src[2] as f32];
        }
        let centre = [m[0][3] as f32, m[1][3] as f32, m[2][3] as f32];
        cameras.push(Camera::from_c2w(
            name, width, height, fx as f32, fy as f32, cx as f32, cy as f32, r, centre,
        ));
    }
    let cameras = super::validated(cameras, path)?;
    let ply_file_path = match top.get("ply_file_path") {
        None | Some(Value::Null) => None,
        Some(Value::String(s)) => Some(base.join(s)),
        Some(_) => return Err(err("\"ply_file_path\" is not a string".into())),
    };
    Ok(Transforms { cameras, ply_file_path, mask_paths })
}

/// The first three rows of a 4x4 or 3x4 matrix.
fn matrix(v: &Value) -> Option<[[f64; 4]; 3]> {
    let rows = v.as_array().filter(|r| r.len() == 3 || r.len() == 4)?;
    let mut m = [[0.0; 4]; 3];
    for (dst, row) in m.iter_mut().zip(rows) {
        let row = row.as_array().filter(|r| r.len() == 4)?;
        for (d, x) in dst.iter_mut().zip(row) {
            *d = x.as_f64().filter(|f| f.is_finite())?;
        }
    }
    Some(m)
}

/// The image for a frame: `file_path` as is, or with a common extension added
/// (Blender paths often omit it).
fn find_image(base: &Path, file_path: &str) -> Option<PathBuf> {
    let p = base.join(file_path);
    if p.is_file() {
        return Some(p);
    }
    crate::image::find_with_extension(&p)
}

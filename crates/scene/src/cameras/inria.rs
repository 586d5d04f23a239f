//! INRIA 3DGS `cameras.json`: a list of
//! `{id, img_name, width, height, position, rotation, fx, fy}` where `position` is the
//! camera centre and `rotation` the camera-to-world 3x3 matrix (rows); the principal
//! point is the image centre.

use crate::{atomic, Camera, Error, Result};
use serde_json::Value;
use std::path::Path;

/// Reads an INRIA `cameras.json`.
pub fn read(path: &Path) -> Result<Vec<Camera>> {
    parse(&atomic::read(path)?, path)
}

/// Parses the bytes of a file at `path` (named in errors).
pub fn parse(bytes: &[u8], path: &Path) -> Result<Vec<Camera>> {
    let value: Value =
        serde_json::from_slice(bytes).map_err(|e| Error::format(path, format!("not valid JSON: {e}")))?;
    from_value(&value, path)
}

/// One camera of a `cameras.json` as INRIA's code writes it (the reader below is more
/// tolerant: numeric names, extra fields).
#[derive(serde::Serialize)]
struct Entry<'a> {
    id: usize,
    img_name: &'a str,
    width: u32,
    height: u32,
    /// The camera centre.
    position: [f32; 3],
    /// Camera-to-world rotation, rows.
    rotation: [[f32; 3]; 3],
    fy: f32,
    fx: f32,
}

/// Writes an INRIA `cameras.json` atomically. The principal point is not stored (the
/// format assumes the image centre).
pub fn write(path: &Path, cameras: &[Camera]) -> Result<()> {
    let off_centre = cameras
        .iter()
        .filter(|c| (c.cx - c.width as f32 / 2.0).abs() > 0.5 || (c.cy - c.height as f32 / 2.0).abs() > 0.5)
        .count();
    if off_centre > 0 {
        tracing::warn!(
            "{}: {off_centre} camera(s) have a principal point away from the image centre; cameras.json \
             cannot store it and readers will assume the centre",
            path.display()
        );
    }
    let list: Vec<Entry> = cameras
        .iter()
        .enumerate()
        .map(|(id, c)| Entry {
            id,
            img_name: &c.name,
            width: c.width,
            height: c.height,
            position: c.centre(),
            rotation: c.c2w_rotation(),
            fy: c.fy,
            fx: c.fx,
        })
        .collect();
    let text = serde_json::to_string_pretty(&list)
        .map_err(|e| Error::format(path, format!("cannot serialise cameras: {e}")))?;
    atomic::write_bytes(path, text.as_bytes())
}

/// Cameras from an already parsed `cameras.json` value.
pub(crate) fn from_value(value: &Value, path: &Path) -> Result<Vec<Camera>> {
    let err = |m: String| Error::format(path, m);
    let list = value.as_array().ok_or_else(|| err("expected a JSON list of cameras".into()))?;
    let mut out = Vec::with_capacity(list.len());
    for (i, v) in list.iter().enumerate() {
        let field = |k: &str| v.get(k).ok_or_else(|| err(format!("camera {i}: missing \"{k}\"")));
        let num = |k: &str| -> Result<f32> {
            field(k)?
                .as_f64()
                .map(|x| x as f32)
                .ok_or_else(|| err(format!("camera {i}: \"{k}\" is not a number")))
        };
        let dim = |k: &str| -> Result<u32> {
            super::json_dim(field(k)?)
                .ok_or_else(|| err(format!("camera {i}: \"{k}\" is not a non-negative integer")))
        };
        let vec3 = |v: &Value| -> Option<[f32; 3]> {
            let a = v.as_array().filter(|a| a.len() == 3)?;
            Some([a[0].as_f64()? as f32, a[1].as_f64()? as f32, a[2].as_f64()? as f32])
        };
        let name = match v.get("img_name") {
            Some(Value::String(s)) => s.clone(),
            Some(Value::Number(n)) => n.to_string(),
            _ => return Err(err(format!("camera {i}: missing or non-string \"img_name\""))),
        };
        let (width, height) = (dim("width")?, dim("height")?);
        let (fx, fy) = (num("fx")?, num("fy")?);
        let position = vec3(field("position")?)
            .ok_or_else(|| err(format!("camera {i}: \"position\" is not 3 numbers")))?;
        let rows = field("rotation")?.as_array().filter(|a| a.len() == 3);
        let rotation = rows
            .and_then(|r| Some([vec3(&r[0])?, vec3(&r[1])?, vec3(&r[2])?]))
            .ok_or_else(|| err(format!("camera {i}: \"rotation\" is not a 3x3 matrix")))?;
        out.push(Camera::from_c2w(
            name,
            width,
            height,
            fx,
            fy,
            width as f32 / 2.0,
            height as f32 / 2.0,
            rotation,
            position,
        ));
    }
    super::validated(out, path)
}

//! COLMAP sparse models (`sparse/0`): `cameras`, `images` and `points3D`, each as
//! `.bin` or `.txt` (the binary file wins when both exist).
//!
//! Images store the world-to-camera rotation as a quaternion (qw, qx, qy, qz) and the
//! translation t, already in the OpenCV convention. Pinhole models are accepted;
//! distortion models only when every distortion coefficient is exactly zero; fisheye
//! models never (their projection is not a pinhole even with zero coefficients).

use crate::{Camera, Error, Result};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// A sparse COLMAP reconstruction.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ColmapModel {
    /// One camera per registered image, sorted by image name.
    pub cameras: Vec<Camera>,
    /// The sparse points (empty when `points3D` is absent).
    pub points: Vec<Point3D>,
}

/// A sparse point with its colour.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Point3D {
    pub xyz: [f32; 3],
    pub rgb: [u8; 3],
}

/// Intrinsics of one COLMAP camera (after the pinhole check).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Intrinsics {
    width: u32,
    height: u32,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
}

/// COLMAP camera models: (id, name, parameter count, is fisheye).
const MODELS: &[(i32, &str, usize, bool)] = &[
    (0, "SIMPLE_PINHOLE", 3, false),
    (1, "PINHOLE", 4, false),
    (2, "SIMPLE_RADIAL", 4, false),
    (3, "RADIAL", 5, false),
    (4, "OPENCV", 8, false),
    (5, "OPENCV_FISHEYE", 8, true),
    (6, "FULL_OPENCV", 12, false),
    (7, "FOV", 5, false),
    (8, "SIMPLE_RADIAL_FISHEYE", 4, true),
    (9, "RADIAL_FISHEYE", 5, true),
    (10, "THIN_PRISM_FISHEYE", 12, true),
    (11, "RAD_TAN_THIN_PRISM_FISHEYE", 16, true),
];

/// Reads `dir/{cameras,images,points3D}.{bin,txt}`. A missing `points3D` gives no
/// points (with a warning); missing cameras or images is an error.
pub fn read_sparse(dir: &Path) -> Result<ColmapModel> {
    let pick = |stem: &str| -> Option<PathBuf> {
        [format!("{stem}.bin"), format!("{stem}.txt")].into_iter().map(|n| dir.join(n)).find(|p| p.is_file())
    };
    let missing =
        |stem: &str| Error::format(dir, format!("not a COLMAP model folder: no {stem}.bin or {stem}.txt"));
    let cam_path = pick("cameras").ok_or_else(|| missing("cameras"))?;
    let img_path = pick("images").ok_or_else(|| missing("images"))?;
    let cam_bytes = crate::atomic::read(&cam_path)?;
    let img_bytes = crate::atomic::read(&img_path)?;
    let points = match pick("points3D") {
        Some(p) => {
            let b = crate::atomic::read(&p)?;
            Some((p, b))
        }
        None => {
            tracing::warn!(
                "{}: no points3D.bin or points3D.txt; continuing without sparse points",
                dir.display()
            );
            None
        }
    };
    parse_model(
        (&cam_path, &cam_bytes),
        (&img_path, &img_bytes),
        points.as_ref().map(|(p, b)| (p.as_path(), b.as_slice())),
    )
}

/// Parses a COLMAP model from the bytes of its files, each given with its path: the
/// extension (`.bin` or anything else for text) picks the encoding, and errors name
/// the path. `points` is `None` when there is no `points3D` file.
pub fn parse_model(
    cameras: (&Path, &[u8]),
    images: (&Path, &[u8]),
    points: Option<(&Path, &[u8])>,
) -> Result<ColmapModel> {
    let (cam_path, img_path) = (cameras.0, images.0);
    let intrinsics = parse_cameras_file(cam_path, cameras.1)?;
    let images = parse_images_file(img_path, images.1)?;
    let cam_name = cam_path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();

    let mut cameras = Vec::with_capacity(images.len());
    for im in images {
        let k = intrinsics.get(&im.camera_id).ok_or_else(|| {
            Error::format(
                img_path,
                format!(
                    "{}image {:?} (id {}) refers to camera id {}, which is not in {cam_name}",
                    im.at(),
                    im.name,
                    im.image_id,
                    im.camera_id
                ),
            )
        })?;
        let rotation = super::quat_to_matrix(im.q).ok_or_else(|| {
            Error::format(
                img_path,
                format!(
                    "{}image {:?} has an invalid quaternion {:?} (zero or not finite, so not a rotation)",
                    im.at(),
                    im.name,
                    im.q
                ),
            )
        })?;
        cameras.push(Camera {
            name: im.name,
            width: k.width,
            height: k.height,
            fx: k.fx as f32,
            fy: k.fy as f32,
            cx: k.cx as f32,
            cy: k.cy as f32,
            rotation,
            translation: im.t.map(|v| v as f32),
        });
    }
    // Checked in file order (messages count cameras as the images file lists them).
    let mut cameras = super::validated(cameras, img_path)?;
    cameras.sort_by(|a, b| a.name.cmp(&b.name));
    let points = match points {
        Some((p, b)) => parse_points_file(p, b)?,
        None => Vec::new(),
    };
    Ok(ColmapModel { cameras, points })
}

fn is_bin(path: &Path) -> bool {
    path.extension().is_some_and(|e| e == "bin")
}

fn parse_cameras_file(path: &Path, bytes: &[u8]) -> Result<HashMap<u32, Intrinsics>> {
    let raw = if is_bin(path) { parse_cameras_bin(bytes) } else { parse_cameras_txt(bytes) };
    let raw = raw.map_err(|m| Error::format(path, m))?;
    let mut out = HashMap::with_capacity(raw.len());
    for (id, model, width, height, params) in raw {
        let k = to_pinhole(id, model, width, height, &params).map_err(|m| Error::format(path, m))?;
        if out.insert(id, k).is_some() {
            return Err(Error::format(path, format!("camera id {id} appears twice")));
        }
    }
    Ok(out)
}

pub(crate) type RawCamera = (u32, &'static (i32, &'static str, usize, bool), u64, u64, Vec<f64>);

fn to_pinhole(
    id: u32,
    model: &(i32, &str, usize, bool),
    width: u64,
    height: u64,
    p: &[f64],
) -> std::result::Result<Intrinsics, String> {
    let &(_, name, n, fisheye) = model;
    if p.len() != n {
        return Err(format!("camera {id}: model {name} needs {n} parameters, got {}", p.len()));
    }
    if fisheye {
        return Err(format!(
            "camera {id}: model {name} is a fisheye model, not a pinhole; undistort the images first \
             (COLMAP image_undistorter)"
        ));
    }
    let (fx, fy, cx, cy, dist) = match name {
        "SIMPLE_PINHOLE" | "SIMPLE_RADIAL" | "RADIAL" => (p[0], p[0], p[1], p[2], &p[3..]),
        _ => (p[0], p[1], p[2], p[3], &p[4..]),
    };
    if dist.iter().any(|&d| d != 0.0) {
        return Err(format!(
            "camera {id}: model {name} has non-zero distortion {dist:?}; only pinhole cameras are \
             supported, undistort the images first (COLMAP image_undistorter)"
        ));
    }
    // The size cap is checked here, where the size is, so the message names this file;
    // it also guarantees both sides fit in u32.
    crate::camera::check_image_size(width, height).map_err(|m| format!("camera {id}: {m}"))?;
    Ok(Intrinsics { width: width as u32, height: height as u32, fx, fy, cx, cy })
}

fn model_by_id(id: i32) -> Option<&'static (i32, &'static str, usize, bool)> {
    MODELS.iter().find(|m| m.0 == id)
}

fn model_by_name(name: &str) -> Option<&'static (i32, &'static str, usize, bool)> {
    MODELS.iter().find(|m| m.1 == name)
}

pub(crate) struct Image {
    image_id: u32,
    q: [f64; 4],
    t: [f64; 3],
    camera_id: u32,
    name: String,
    /// The 1-based line of the image in `images.txt`; None in `images.bin`.
    line: Option<usize>,
}

impl Image {
    /// `"line N: "` for an image from a text file, else nothing (a message prefix).
    fn at(&self) -> String {
        self.line.map(|l| format!("line {l}: ")).unwrap_or_default()
    }
}

fn parse_images_file(path: &Path, bytes: &[u8]) -> Result<Vec<Image>> {
    let images = if is_bin(path) { parse_images_bin(bytes) } else { parse_images_txt(bytes) };
    let images = images.map_err(|m| Error::format(path, m))?;
    let mut seen = std::collections::HashSet::with_capacity(images.len());
    for im in &images {
        if !seen.insert(im.image_id) {
            return Err(Error::format(path, format!("{}image id {} appears twice", im.at(), im.image_id)));
        }
    }
    Ok(images)
}

/// The points of a `points3D` file; points with a NaN or infinite coordinate are
/// dropped with a warning (as the PLY point cloud reader does).
fn parse_points_file(path: &Path, bytes: &[u8]) -> Result<Vec<Point3D>> {
    let points = if is_bin(path) { parse_points_bin(bytes) } else { parse_points_txt(bytes) };
    let mut points = points.map_err(|m| Error::format(path, m))?;
    let n = points.len();
    points.retain(|p| p.xyz.iter().all(|v| v.is_finite()));
    if points.len() < n {
        tracing::warn!(
            "{}: dropped {} points with NaN or infinite coordinates",
            path.display(),
            n - points.len()
        );
    }
    Ok(points)
}

// ---------------------------------------------------------------------------------
// Binary

struct Cursor<'a> {
    b: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    fn take<const N: usize>(&mut self) -> Option<[u8; N]> {
        let end = self.pos.checked_add(N)?;
        let a = self.b.get(self.pos..end)?.try_into().ok()?;
        self.pos = end;
        Some(a)
    }
    fn u64(&mut self) -> Option<u64> {
        self.take().map(u64::from_le_bytes)
    }
    fn i32(&mut self) -> Option<i32> {
        self.take().map(i32::from_le_bytes)
    }
    fn u32(&mut self) -> Option<u32> {
        self.take().map(u32::from_le_bytes)
    }
    fn f64(&mut self) -> Option<f64> {
        self.take().map(f64::from_le_bytes)
    }
    fn skip(&mut self, n: u64) -> Option<()> {
        let end = self.pos.checked_add(usize::try_from(n).ok()?).filter(|&e| e <= self.b.len())?;
        self.pos = end;
        Some(())
    }
    fn cstr(&mut self) -> Option<&'a [u8]> {
        let rest = self.b.get(self.pos..)?;
        let n = rest.iter().position(|&c| c == 0)?;
        self.pos += n + 1;
        Some(&rest[..n])
    }
    fn remaining(&self) -> usize {
        self.b.len().saturating_sub(self.pos)
    }
    /// A record count from the file, with the capacity it may reserve given the
    /// smallest record size.
    fn count(&mut self, min_record: usize) -> Option<(u64, usize)> {
        let n = self.u64()?;
        let cap = (self.remaining() / min_record).min(usize::try_from(n).unwrap_or(usize::MAX));
        Some((n, cap))
    }
}

fn truncated(what: &str, i: u64, n: u64) -> String {
    format!("truncated: {what} {i} of {n} ends past the end of the file (wrong count or cut-off file)")
}

pub(crate) fn parse_cameras_bin(b: &[u8]) -> std::result::Result<Vec<RawCamera>, String> {
    let mut c = Cursor { b, pos: 0 };
    let (n, cap) = c.count(48).ok_or("truncated: no camera count")?;
    let mut out = Vec::with_capacity(cap);
    for i in 0..n {
        let id = c.u32().ok_or_else(|| truncated("camera", i, n))?;
        let model_id = c.i32().ok_or_else(|| truncated("camera", i, n))?;
        let model = model_by_id(model_id)
            .ok_or_else(|| format!("camera {id}: unknown camera model id {model_id}"))?;
        let w = c.u64().ok_or_else(|| truncated("camera", i, n))?;
        let h = c.u64().ok_or_else(|| truncated("camera", i, n))?;
        let params = (0..model.2).map(|_| c.f64()).collect::<Option<Vec<f64>>>();
        let params = params.ok_or_else(|| truncated("camera", i, n))?;
        out.push((id, model, w, h, params));
    }
    Ok(out)
}

pub(crate) fn parse_images_bin(b: &[u8]) -> std::result::Result<Vec<Image>, String> {
    let mut c = Cursor { b, pos: 0 };
    let (n, cap) = c.count(4 + 56 + 4 + 1 + 8).ok_or("truncated: no image count")?;
    let mut out = Vec::with_capacity(cap);
    for i in 0..n {
        let t = || truncated("image", i, n);
        let image_id = c.u32().ok_or_else(t)?;
        let mut q = [0.0; 4];
        for v in &mut q {
            *v = c.f64().ok_or_else(t)?;
        }
        let mut tr = [0.0; 3];
        for v in &mut tr {
            *v = c.f64().ok_or_else(t)?;
        }
        let camera_id = c.u32().ok_or_else(t)?;
        let name = c.cstr().ok_or_else(t)?;
        let name = String::from_utf8_lossy(name).into_owned();
        let np = c.u64().ok_or_else(t)?;
        c.skip(np.checked_mul(24).ok_or_else(t)?).ok_or_else(t)?;
        out.push(Image { image_id, q, t: tr, camera_id, name, line: None });
    }
    Ok(out)
}

pub(crate) fn parse_points_bin(b: &[u8]) -> std::result::Result<Vec<Point3D>, String> {
    let mut c = Cursor { b, pos: 0 };
    let (n, cap) = c.count(8 + 24 + 3 + 8 + 8).ok_or("truncated: no point count")?;
    let mut out = Vec::with_capacity(cap);
    for i in 0..n {
        let t = || truncated("point", i, n);
        c.u64().ok_or_else(t)?;
        let mut xyz = [0.0f32; 3];
        for v in &mut xyz {
            *v = c.f64().ok_or_else(t)? as f32;
        }
        let rgb: [u8; 3] = c.take().ok_or_else(t)?;
        c.f64().ok_or_else(t)?;
        let track = c.u64().ok_or_else(t)?;
        c.skip(track.checked_mul(8).ok_or_else(t)?).ok_or_else(t)?;
        out.push(Point3D { xyz, rgb });
    }
    Ok(out)
}

// ---------------------------------------------------------------------------------
// Text

/// Lines with their 1-based numbers, trimmed; comments and blank lines kept so the
/// caller decides (images.txt has a possibly empty second line per image).
fn text_lines(b: &[u8]) -> std::result::Result<Vec<(usize, &str)>, String> {
    let s = std::str::from_utf8(b).map_err(|e| format!("not UTF-8 text (byte {})", e.valid_up_to()))?;
    Ok(s.lines().enumerate().map(|(i, l)| (i + 1, l.trim())).collect())
}

fn is_skip(l: &str) -> bool {
    l.is_empty() || l.starts_with('#')
}

fn num<T: std::str::FromStr>(tok: Option<&str>, line: usize, what: &str) -> std::result::Result<T, String> {
    let tok = tok.ok_or_else(|| format!("line {line}: missing {what}"))?;
    tok.parse::<T>().map_err(|_| format!("line {line}: {what} {tok:?} is not a valid number"))
}

pub(crate) fn parse_cameras_txt(b: &[u8]) -> std::result::Result<Vec<RawCamera>, String> {
    let mut out = Vec::new();
    for (ln, l) in text_lines(b)? {
        if is_skip(l) {
            continue;
        }
        let mut tok = l.split_whitespace();
        let id: u32 = num(tok.next(), ln, "camera id")?;
        let model_name = tok.next().ok_or_else(|| format!("line {ln}: missing camera model"))?;
        let model = model_by_name(model_name)
            .ok_or_else(|| format!("line {ln}: camera {id}: unknown camera model {model_name:?}"))?;
        let w: u64 = num(tok.next(), ln, "width")?;
        let h: u64 = num(tok.next(), ln, "height")?;
        let params =
            tok.map(|t| num::<f64>(Some(t), ln, "parameter")).collect::<std::result::Result<Vec<_>, _>>()?;
        out.push((id, model, w, h, params));
    }
    Ok(out)
}

pub(crate) fn parse_images_txt(b: &[u8]) -> std::result::Result<Vec<Image>, String> {
    let lines = text_lines(b)?;
    let mut out = Vec::new();
    let mut it = lines.into_iter();
    while let Some((ln, l)) = it.next() {
        if is_skip(l) {
            continue;
        }
        let mut rest = l;
        let mut tok = || {
            let (t, r) = split_token(rest);
            rest = r;
            (!t.is_empty()).then_some(t)
        };
        let image_id: u32 = num(tok(), ln, "image id")?;
        let mut q = [0.0; 4];
        for (v, w) in q.iter_mut().zip(["QW", "QX", "QY", "QZ"]) {
            *v = num(tok(), ln, w)?;
        }
        let mut t = [0.0; 3];
        for (v, w) in t.iter_mut().zip(["TX", "TY", "TZ"]) {
            *v = num(tok(), ln, w)?;
        }
        let camera_id: u32 = num(tok(), ln, "camera id")?;
        // The name is the rest of the line (it may contain spaces).
        let name = rest.trim();
        if name.is_empty() {
            return Err(format!("line {ln}: missing image name"));
        }
        let name = name.to_string();
        // The next line lists the 2D points (possibly empty); not needed, but checked
        // so that a missing line is an error rather than the next image read as points
        // and dropped. A last image may end the file without one (nothing is lost).
        if let Some((pln, points)) = it.next() {
            check_points2d_line(points).map_err(|m| {
                format!(
                    "line {pln}: expected the 2D points of image {image_id} (line {ln}) as X Y POINT3D_ID \
                     triples, {m}; each image takes two lines, the second possibly empty (is a line \
                     missing?)"
                )
            })?;
        }
        out.push(Image { image_id, q, t, camera_id, name, line: Some(ln) });
    }
    Ok(out)
}

/// Checks an `images.txt` 2D-point line: `X Y POINT3D_ID` triples (POINT3D_ID a whole
/// number, -1 for none), or nothing.
fn check_points2d_line(l: &str) -> std::result::Result<(), String> {
    let tok: Vec<&str> = l.split_whitespace().collect();
    if !tok.len().is_multiple_of(3) {
        return Err(format!("found {} values (not a multiple of 3)", tok.len()));
    }
    for t in tok.chunks_exact(3) {
        let id = t[2].parse::<f64>().ok().filter(|v| v.fract() == 0.0);
        if t[0].parse::<f64>().is_err() || t[1].parse::<f64>().is_err() || id.is_none() {
            return Err(format!("found {:?}", t.join(" ")));
        }
    }
    Ok(())
}

/// The first whitespace-separated token of `s` and what follows it.
fn split_token(s: &str) -> (&str, &str) {
    let s = s.trim_start();
    let end = s.find(char::is_whitespace).unwrap_or(s.len());
    s.split_at(end)
}

pub(crate) fn parse_points_txt(b: &[u8]) -> std::result::Result<Vec<Point3D>, String> {
    let mut out = Vec::new();
    for (ln, l) in text_lines(b)? {
        if is_skip(l) {
            continue;
        }
        let mut tok = l.split_whitespace();
        let _id: u64 = num(tok.next(), ln, "point id")?;
        let mut xyz = [0.0f32; 3];
        for (v, w) in xyz.iter_mut().zip(["X", "Y", "Z"]) {
            *v = num::<f64>(tok.next(), ln, w)? as f32;
        }
        let mut rgb = [0u8; 3];
        for (v, w) in rgb.iter_mut().zip(["R", "G", "B"]) {
            *v = num(tok.next(), ln, w)?;
        }
        out.push(Point3D { xyz, rgb });
    }
    Ok(out)
}

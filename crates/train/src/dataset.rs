//! Training datasets: cameras, images (and masks) at a chosen downscale, the
//! initial point cloud, and the train / test split.
//!
//! Recognised folders, first match wins:
//!
//! 1. COLMAP: `sparse/0` (or `sparse`) with `cameras`, `images`, `points3D`
//!    (`.bin` or `.txt`) and the images in `images/`; points from `points3D`.
//! 2. nerfstudio / Blender: `transforms.json`, image paths relative to it; points
//!    from `ply_file_path` (a plain xyz/rgb PLY, [`crate::points`]) when given.
//! 3. INRIA output layout as written by `transsplat scene`: `cameras.json` with the
//!    images in `images/<img_name>[.png|.jpg]`; points from `input.ply` when present
//!    (a scene PLY in `point_cloud/` is never used: it is what training should find).
//!
//! Without points (or with an empty cloud, which is warned about) the caller
//! initialises randomly ([`crate::init::random_points`]).
//!
//! Images: PNG or JPEG, 8 or 16 bit, grey or colour, converted by
//! `transsplat_scene::image`; an alpha channel is composited over the background
//! colour. An image whose size differs from its camera's is accepted when it has the
//! same aspect ratio (within a pixel) — a pre-downscaled copy — and the camera's
//! intrinsics are rescaled to it (with a warning); otherwise it is an error naming
//! the file. `resolution = R` then divides the size by R (rounded, as INRIA `-r`),
//! averaging pixels (area resampling) and scaling fx, fy, cx, cy by the same ratio.
//!
//! Masks ([`Masks`]): only when asked for (a folder of `<image stem>.png` / `.jpg` or the
//! image's file name) or declared by the dataset per frame (transforms.json
//! `mask_path`). A `masks/` folder alone is not a request: datasets prepared for editing
//! often carry one holding the edit target, and training only inside it would leave the
//! rest of the scene unfitted. Masks are greyscale in [0, 1], resized with the image; a
//! mask is a per-pixel loss weight: the loss (and the masked test PSNR) only see pixels
//! where it is non-zero.
//!
//! Split: cameras sorted by image name; every `test_every`-th (index % 8 == 0, INRIA
//! `llffhold`) is a test view. With fewer than two cameras nothing is held out.

use crate::points::{self, PointCloud};
use std::path::{Path, PathBuf};
use transsplat_scene::cameras::{colmap, inria, is_held_out, transforms, LLFF_HOLD};
use transsplat_scene::resample::{separable, Taps};
use transsplat_scene::{image, Camera, Error, Result};

/// How to load a dataset.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadOptions {
    /// Divide image sizes by this (1 = full resolution).
    pub resolution: u32,
    /// Colour RGBA images are composited over (and the render background).
    pub background: [f32; 3],
    /// Where training masks come from.
    pub masks: Masks,
    /// Every this-many-th camera is a test view (0 = none).
    pub test_every: usize,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions { resolution: 1, background: [0.0; 3], masks: Masks::Declared, test_every: LLFF_HOLD }
    }
}

/// Where training masks come from.
#[derive(Clone, Debug, PartialEq, Default)]
pub enum Masks {
    /// The masks the dataset declares per frame (transforms.json `mask_path`); none
    /// for frames (and formats) that declare none.
    #[default]
    Declared,
    /// `DIR/<image stem>.png` (or `.jpg`, or the image's file name) for every view; a
    /// view without one is an error naming the camera.
    Folder(PathBuf),
    /// No masks, not even declared ones.
    Off,
}

/// One training or test view at the loaded resolution.
#[derive(Clone, Debug, PartialEq)]
pub struct View {
    /// The camera, intrinsics scaled to the loaded image.
    pub camera: Camera,
    /// `H × W × 3` RGB in [0, 1].
    pub image: Vec<f32>,
    /// `H × W` loss weights from the mask, if any.
    pub weights: Option<Vec<f32>>,
    pub path: PathBuf,
}

impl View {
    /// The view with its image (and weights) divided by `factor`, area-resampled as at
    /// load time, and its intrinsics scaled to match.
    pub fn downscaled(&self, factor: u32) -> View {
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let (nw, nh) = scaled_size(w, h, factor);
        View {
            camera: scale_camera(&self.camera, nw, nh),
            image: resample(&self.image, w, h, 3, nw, nh),
            weights: self.weights.as_ref().map(|m| resample(m, w, h, 1, nw, nh)),
            path: self.path.clone(),
        }
    }
}

/// Which kind of folder was loaded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DatasetKind {
    Colmap,
    Transforms,
    Inria,
}

/// A loaded dataset.
#[derive(Clone, Debug, PartialEq)]
pub struct Dataset {
    pub kind: DatasetKind,
    /// Every camera at its original resolution, sorted by name (written to the
    /// output's `cameras.json`).
    pub cameras: Vec<Camera>,
    pub train: Vec<View>,
    pub test: Vec<View>,
    /// The initial point cloud, when the dataset has a non-empty one.
    pub points: Option<PointCloud>,
    /// Where the points came from (or would have).
    pub points_path: Option<PathBuf>,
}

/// Loads the dataset in `dir` (see the module docs).
pub fn load(dir: &Path, opts: &LoadOptions) -> Result<Dataset> {
    if !dir.is_dir() {
        return Err(Error::format(
            dir,
            "not a folder (expected a COLMAP, transforms.json or INRIA dataset folder)",
        ));
    }
    if opts.resolution == 0 {
        return Err(Error::format(dir, "resolution divisor must be at least 1"));
    }
    let sparse = [dir.join("sparse").join("0"), dir.join("sparse")]
        .into_iter()
        .find(|d| d.join("cameras.bin").is_file() || d.join("cameras.txt").is_file());
    let mut declared: Vec<Option<PathBuf>> = Vec::new();
    let (kind, mut cams, images, points_path, points): (_, _, Vec<PathBuf>, _, _) = if let Some(sp) = sparse {
        let model = colmap::read_sparse(&sp)?;
        let imgs = model.cameras.iter().map(|c| find_image(&dir.join("images"), &c.name)).collect();
        let pts = PointCloud {
            positions: model.points.iter().map(|p| p.xyz).collect(),
            colors: model.points.iter().map(|p| p.rgb.map(|v| v as f32 / 255.0)).collect(),
        };
        (DatasetKind::Colmap, model.cameras, imgs, Some(sp.clone()), Some(pts))
    } else if dir.join("transforms.json").is_file() {
        let tpath = dir.join("transforms.json");
        let t = transforms::read(&tpath)?;
        declared = t.mask_paths.clone();
        let imgs = t.cameras.iter().map(|c| find_image(dir, &c.name)).collect();
        let pts = match &t.ply_file_path {
            Some(p) => Some(points::read(p)?),
            None => None,
        };
        (DatasetKind::Transforms, t.cameras, imgs, t.ply_file_path.clone(), pts)
    } else if dir.join("cameras.json").is_file() {
        let cams = inria::read(&dir.join("cameras.json"))?;
        let imgs = cams.iter().map(|c| find_image(&dir.join("images"), &c.name)).collect();
        let input = dir.join("input.ply");
        let pts = if input.is_file() { Some(points::read(&input)?) } else { None };
        (DatasetKind::Inria, cams, imgs, input.is_file().then_some(input), pts)
    } else {
        return Err(Error::format(
            dir,
            "no dataset found: expected sparse/0 (COLMAP) with images/, transforms.json, or cameras.json with images/",
        ));
    };
    if cams.is_empty() {
        return Err(Error::format(dir, "the dataset has no cameras"));
    }
    let mut order: Vec<usize> = (0..cams.len()).collect();
    order.sort_by(|&a, &b| cams[a].name.cmp(&cams[b].name));
    declared.resize(cams.len(), None);
    let mut pairs: Vec<(Camera, PathBuf, Option<PathBuf>)> = order
        .iter()
        .map(|&i| (std::mem::replace(&mut cams[i], placeholder()), images[i].clone(), declared[i].take()))
        .collect();
    let mut resized = 0usize;
    let mut train = Vec::new();
    let mut test = Vec::new();
    let n = pairs.len();
    let cameras: Vec<Camera> = pairs.iter().map(|p| p.0.clone()).collect();
    for (k, (cam, path, declared)) in pairs.drain(..).enumerate() {
        if !path.is_file() {
            return Err(Error::format(&path, format!("image for camera {:?} is missing", cam.name)));
        }
        let img = image::read(&path)?.composite(opts.background);
        let (cam, was_resized) = fit_camera(cam, img.width, img.height, &path)?;
        resized += was_resized as usize;
        let (w, h) = scaled_size(img.width, img.height, opts.resolution);
        let data = resample(&img.data, img.width, img.height, 3, w, h);
        let mask = match &opts.masks {
            Masks::Off => None,
            Masks::Declared => declared,
            Masks::Folder(d) => Some(find_mask(d, &cam.name).ok_or_else(|| {
                Error::format(d, format!("no mask for camera {:?} (expected {}.png)", cam.name, cam.stem()))
            })?),
        };
        let weights = match mask {
            Some(mp) => {
                let m = image::read(&mp)?;
                if (m.width, m.height) != (img.width, img.height) {
                    return Err(Error::format(
                        &mp,
                        format!(
                            "mask is {}x{} but its image is {}x{}",
                            m.width, m.height, img.width, img.height
                        ),
                    ));
                }
                let grey: Vec<f32> = m.data.chunks_exact(3).map(|p| p[0]).collect();
                Some(resample(&grey, m.width, m.height, 1, w, h))
            }
            None => None,
        };
        let view = View { camera: scale_camera(&cam, w, h), image: data, weights, path };
        if n > 1 && is_held_out(k, opts.test_every) {
            test.push(view);
        } else {
            train.push(view);
        }
    }
    if resized > 0 {
        tracing::warn!(
            "{}: {resized} image(s) have another size than their camera with the same aspect ratio; the \
             intrinsics were rescaled to the images",
            dir.display()
        );
    }
    log_masks(dir, opts, &train, &test);
    let points = match points {
        Some(p) if p.is_empty() => {
            tracing::warn!(
                "{}: the point cloud is empty; initialising from random points",
                points_path.as_deref().unwrap_or(dir).display()
            );
            None
        }
        p => p,
    };
    Ok(Dataset { kind, cameras, train, test, points, points_path })
}

/// Says which masks training uses, and that an unrequested `masks/` folder is not used.
fn log_masks(dir: &Path, opts: &LoadOptions, train: &[View], test: &[View]) {
    let masked = train.iter().chain(test).filter(|v| v.weights.is_some()).count();
    let total = train.len() + test.len();
    let source = match &opts.masks {
        Masks::Folder(d) => format!("from {}", d.display()),
        Masks::Declared => "declared by the dataset (mask_path)".into(),
        Masks::Off => String::new(),
    };
    if masked > 0 {
        tracing::info!(
            "training masks {source} on {masked} of {total} views: the loss and the masked test PSNR see only \
             the pixels inside them"
        );
    } else if opts.masks != Masks::Off && dir.join("masks").is_dir() {
        tracing::info!(
            "{}: not used as training masks (pass --masks {} to train only inside them)",
            dir.join("masks").display(),
            dir.join("masks").display()
        );
    }
}

fn placeholder() -> Camera {
    Camera {
        name: String::new(),
        width: 1,
        height: 1,
        fx: 1.0,
        fy: 1.0,
        cx: 0.0,
        cy: 0.0,
        rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        translation: [0.0; 3],
    }
}

/// `base/name`, or with an image extension added, or with its extension replaced.
fn find_image(base: &Path, name: &str) -> PathBuf {
    let p = base.join(name);
    if p.is_file() {
        return p;
    }
    let stem_path = match Path::new(name).extension() {
        Some(_) => base.join(Path::new(name).with_extension("")),
        None => base.join(name),
    };
    image::find_with_extension(&p).or_else(|| image::find_with_extension(&stem_path)).unwrap_or(p)
}

fn find_mask(masks: &Path, name: &str) -> Option<PathBuf> {
    let file = Path::new(name).file_name()?;
    let stem = Path::new(file).file_stem()?.to_string_lossy().into_owned();
    let exact = masks.join(file);
    if exact.is_file() {
        return Some(exact);
    }
    image::find_with_extension(&masks.join(stem)).or_else(|| {
        let png = masks.join(format!("{}.png", file.to_string_lossy()));
        png.is_file().then_some(png)
    })
}

/// The camera for an image of `w × h`: unchanged when the sizes agree, rescaled when
/// the aspect ratio agrees within a pixel, else an error naming the image.
fn fit_camera(cam: Camera, w: usize, h: usize, path: &Path) -> Result<(Camera, bool)> {
    if (cam.width as usize, cam.height as usize) == (w, h) {
        return Ok((cam, false));
    }
    let s = w as f64 / cam.width as f64;
    let expect_h = cam.height as f64 * s;
    if (expect_h - h as f64).abs() <= 1.0 + 1e-6 {
        let scaled = scale_camera(&cam, w, h);
        return Ok((scaled, true));
    }
    Err(Error::format(
        path,
        format!(
            "image is {w}x{h} but camera {:?} is {}x{} (not a uniform downscale); fix the image or the camera model",
            cam.name, cam.width, cam.height
        ),
    ))
}

/// `(w / r, h / r)` rounded, at least 1 (INRIA `-r`).
pub fn scaled_size(w: usize, h: usize, r: u32) -> (usize, usize) {
    let r = r.max(1) as f64;
    (((w as f64 / r).round() as usize).max(1), ((h as f64 / r).round() as usize).max(1))
}

/// The camera with intrinsics scaled to an image of `w × h`.
pub fn scale_camera(cam: &Camera, w: usize, h: usize) -> Camera {
    let sx = w as f32 / cam.width as f32;
    let sy = h as f32 / cam.height as f32;
    Camera {
        width: w as u32,
        height: h as u32,
        fx: cam.fx * sx,
        fy: cam.fy * sy,
        cx: cam.cx * sx,
        cy: cam.cy * sy,
        ..cam.clone()
    }
}

/// Area (box-filter) resampling of an interleaved `w × h × c` image to `nw × nh`.
pub fn resample(src: &[f32], w: usize, h: usize, c: usize, nw: usize, nh: usize) -> Vec<f32> {
    if (w, h) == (nw, nh) {
        return src.to_vec();
    }
    let taps = |n: usize, m: usize| -> Vec<Taps> {
        let s = n as f64 / m as f64;
        (0..m)
            .map(|o| {
                let (a, b) = (o as f64 * s, (o + 1) as f64 * s);
                let mut t = Vec::new();
                let mut i = a.floor() as usize;
                while (i as f64) < b && i < n {
                    let wgt = (b.min(i as f64 + 1.0) - a.max(i as f64)) / s;
                    if wgt > 0.0 {
                        t.push((i, wgt as f32));
                    }
                    i += 1;
                }
                t
            })
            .collect()
    };
    separable(src, w, h, c, &taps(w, nw), &taps(h, nh))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn area_resampling_averages_blocks() {
        let src: Vec<f32> = (0..16).map(|v| v as f32).collect();
        let out = resample(&src, 4, 4, 1, 2, 2);
        assert_eq!(out, vec![2.5, 4.5, 10.5, 12.5]);
        let out = resample(&[0.0, 3.0, 6.0], 3, 1, 1, 2, 1);
        assert!((out[0] - 1.0).abs() < 1e-6 && (out[1] - 5.0).abs() < 1e-6, "{out:?}");
        assert_eq!(scaled_size(1001, 750, 4), (250, 188));
    }
}

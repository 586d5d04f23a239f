//! Writing a built-in scene as a dataset that 3DGS tools can train on.
//!
//! Layout of `DIR`:
//!
//! ```text
//! point_cloud/iteration_0/point_cloud.ply  the scene: INRIA 3DGS PLY (binary float32,
//!                                          SH degree 1) plus the extra float property
//!                                          `label` (per-Gaussian label id)
//! cameras.json                             INRIA cameras (img_name = view_NNN)
//! images/view_NNN.png                      8-bit RGB renders of every camera
//! masks/view_NNN.png                       8-bit greyscale: pixel value = label id
//!                                          (0 = background / nothing), see masks module
//! sparse/0/{cameras,images,points3D}.txt   the same cameras as a COLMAP text model
//!                                          (PINHOLE), points3D = every k-th Gaussian
//!                                          centre (≤ 5000, or `points`) with its colour
//! labels.json                              objects, label ids, test views, metadata
//! ```
//!
//! Every 8th view (index % 8 == 0) is a test view (`labels.json`: `"test"`).
//!
//! Atomicity: the dataset is written into a hidden temporary folder beside `DIR`
//! (`.NAME.partial-PID`) and renamed onto `DIR` when complete, so an interrupted run
//! leaves no half-written dataset. `DIR` may be missing or an empty folder; a
//! non-empty `DIR` is refused unless `force`, in which case the files are written into
//! it in place (each file atomically; nothing else in it is touched or deleted).

use crate::catalog::{Scene, LABEL_PROPERTY};
use crate::edit::dc_colour;
use crate::rig::{is_test, LLFF_HOLD};
use crate::Error;
use std::path::{Path, PathBuf};
use transsplat_raster::project::quat_from_matrix;
use transsplat_scene::{atomic, cameras, image, ply};

/// Options of [`write_dataset`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct WriteOptions {
    /// Write into a non-empty existing folder (overwriting the dataset's files).
    pub force: bool,
    /// Most points in `sparse/0/points3D.txt` (None: 5000): a sparser initial cloud
    /// for a trainer.
    pub points: Option<usize>,
}

/// What [`write_dataset`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetSummary {
    pub dir: PathBuf,
    pub gaussians: usize,
    pub views: usize,
    pub test_views: usize,
    /// Per object (label order): number of views where it covers at least one pixel.
    pub views_visible: Vec<usize>,
}

/// Relative path of the scene PLY inside a dataset.
pub const PLY_PATH: &str = "point_cloud/iteration_0/point_cloud.ply";

/// Points written to `sparse/0/points3D.txt` unless [`WriteOptions::points`] says.
const MAX_SPARSE_POINTS: usize = 5000;

fn out_err(path: &Path, msg: impl std::fmt::Display) -> Error {
    Error::Output { path: path.to_path_buf(), msg: msg.to_string() }
}

/// Writes `scene` to `dir` (layout in the module docs). `progress(done, total)` is
/// called after each view.
pub fn write_dataset(
    scene: &Scene,
    dir: &Path,
    opts: &WriteOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<DatasetSummary, Error> {
    if scene.labels.iter().any(|&l| l > 255) {
        return Err(Error::Invalid("labels above 255 do not fit 8-bit masks".into()));
    }
    let exists = dir.exists();
    if exists && !dir.is_dir() {
        return Err(out_err(dir, "exists and is not a folder"));
    }
    let non_empty = exists && std::fs::read_dir(dir).map_err(|e| out_err(dir, e))?.next().is_some();
    if non_empty && opts.force {
        return write_into(scene, dir, opts, progress);
    }
    if non_empty && !dir.join("labels.json").is_file() {
        return Err(out_err(dir, "output folder exists and is not empty (use --force to write into it)"));
    }
    // Staged beside `dir` and moved into place when complete (an earlier dataset, marked
    // by its labels.json, is replaced): an interrupted run leaves `dir` as it was.
    let staged = atomic::StagedDir::begin(dir, "labels.json")?;
    let mut summary = write_into(scene, staged.path(), opts, progress)?;
    summary.dir = staged.commit()?;
    Ok(summary)
}

fn mkdir(p: &Path) -> Result<(), Error> {
    std::fs::create_dir_all(p).map_err(|e| out_err(p, format!("cannot create folder: {e}")))
}

/// Writes an 8-bit greyscale PNG atomically.
pub fn write_grey_png(path: &Path, width: usize, height: usize, values: &[u8]) -> Result<(), Error> {
    if values.len() != width * height {
        return Err(Error::Invalid(format!(
            "{}: mask has {} values for {width}x{height}",
            path.display(),
            values.len()
        )));
    }
    atomic::write_with(path, |w| {
        let mut enc = png::Encoder::new(w, width as u32, height as u32);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Eight);
        let mut writer = enc.write_header().map_err(std::io::Error::other)?;
        writer.write_image_data(values).map_err(std::io::Error::other)?;
        writer.finish().map_err(std::io::Error::other)
    })?;
    Ok(())
}

/// `labels.json`'s mask encoding.
const MASK_ENCODING: &str = "8-bit greyscale PNG; pixel value = label id (0 = background or nothing); \
                             a pixel is labelled where the rendered alpha > 0.5, by the label with the \
                             largest blend weight";

/// `labels.json`: the scene's objects and label ids, its test views, and what rebuilds
/// it ([`Labels::scene_config`]). Written by [`write_dataset`], read by [`Labels::read`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Labels {
    pub scene: String,
    pub description: String,
    pub target: String,
    pub seed: u64,
    pub detail: f32,
    pub open: bool,
    pub width: u32,
    pub height: u32,
    pub num_gaussians: usize,
    pub sh_degree: u32,
    pub background: [f32; 3],
    pub ply: String,
    pub label_property: String,
    pub mask_encoding: String,
    pub llffhold: usize,
    pub labels: Vec<Label>,
    pub objects: Vec<LabelledObject>,
    pub test_views: Vec<String>,
    pub train_views: Vec<String>,
    pub views: Vec<LabelledView>,
}

/// One label id of `labels.json`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Label {
    pub id: usize,
    pub name: String,
    pub gaussians: usize,
}

/// One object of `labels.json`: the scene's object and its Gaussian count.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LabelledObject {
    #[serde(flatten)]
    pub object: crate::SceneObject,
    pub gaussians: usize,
}

/// One view of `labels.json`: its image and mask and the pixels of each object in it.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LabelledView {
    pub index: usize,
    pub name: String,
    pub image: String,
    pub mask: String,
    pub test: bool,
    pub object_pixels: std::collections::BTreeMap<String, usize>,
}

impl Labels {
    /// Reads `labels.json`; the error names the file.
    pub fn read(path: &Path) -> Result<Labels, Error> {
        let bytes = atomic::read(path)?;
        serde_json::from_slice(&bytes).map_err(|e| {
            Error::Io(transsplat_scene::Error::format(
                path,
                format!("not a labels.json of `transsplat scene`: {e}"),
            ))
        })
    }

    /// The settings that rebuild the scene bit for bit with [`crate::build`].
    pub fn scene_config(&self) -> crate::SceneConfig {
        crate::SceneConfig {
            seed: self.seed,
            detail: self.detail,
            width: self.width,
            height: self.height,
            views: self.views.len(),
            open: self.open,
        }
    }
}

fn write_into(
    scene: &Scene,
    dir: &Path,
    opts: &WriteOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<DatasetSummary, Error> {
    let ply_path = dir.join(PLY_PATH);
    mkdir(ply_path.parent().unwrap_or(dir))?;
    mkdir(&dir.join("images"))?;
    mkdir(&dir.join("masks"))?;
    mkdir(&dir.join("sparse/0"))?;
    ply::write(&ply_path, &scene.gaussians_with_labels())?;
    cameras::inria::write(&dir.join("cameras.json"), &scene.cameras)?;
    write_colmap(scene, &dir.join("sparse/0"), opts.points.unwrap_or(MAX_SPARSE_POINTS).max(1))?;

    let names = scene.label_names();
    let mut views_visible = vec![0usize; scene.objects.len()];
    let mut views = Vec::with_capacity(scene.cameras.len());
    let total = scene.cameras.len();
    for (i, cam) in scene.cameras.iter().enumerate() {
        let r = scene.render_view(i).ok_or_else(|| Error::Invalid(format!("no camera {i}")))?;
        let stem = cam.stem();
        image::write_png(&dir.join("images").join(format!("{stem}.png")), r.width, r.height, &r.rgb)?;
        let grey: Vec<u8> = r.labels.iter().map(|&l| l.min(255) as u8).collect();
        write_grey_png(&dir.join("masks").join(format!("{stem}.png")), r.width, r.height, &grey)?;
        let mut object_pixels = std::collections::BTreeMap::new();
        for (k, o) in scene.objects.iter().enumerate() {
            let a = r.area(o.label);
            if a > 0 {
                views_visible[k] += 1;
            }
            object_pixels.insert(o.name.clone(), a);
        }
        views.push(LabelledView {
            index: i,
            name: stem.clone(),
            image: format!("images/{stem}.png"),
            mask: format!("masks/{stem}.png"),
            test: is_test(i),
            object_pixels,
        });
        progress(i + 1, total);
    }

    let counts = scene.label_counts();
    let gaussians_of = |label: usize| counts.get(label).copied().unwrap_or(0);
    let labels =
        names.iter().enumerate().map(|(id, n)| Label { id, name: n.clone(), gaussians: gaussians_of(id) });
    let objects = scene
        .objects
        .iter()
        .map(|o| LabelledObject { object: o.clone(), gaussians: gaussians_of(o.label as usize) });
    let stems: Vec<String> = scene.cameras.iter().map(|c| c.stem()).collect();
    let doc = Labels {
        scene: scene.name.clone(),
        description: scene.description.clone(),
        target: scene.target.clone(),
        seed: scene.config.seed,
        detail: scene.config.detail,
        open: scene.config.open,
        width: scene.config.width,
        height: scene.config.height,
        num_gaussians: scene.gaussians.len(),
        sh_degree: scene.gaussians.sh_degree,
        background: scene.background,
        ply: PLY_PATH.into(),
        label_property: LABEL_PROPERTY.into(),
        mask_encoding: MASK_ENCODING.into(),
        llffhold: LLFF_HOLD,
        labels: labels.collect(),
        objects: objects.collect(),
        test_views: stems.iter().enumerate().filter(|(i, _)| is_test(*i)).map(|(_, s)| s.clone()).collect(),
        train_views: stems.iter().enumerate().filter(|(i, _)| !is_test(*i)).map(|(_, s)| s.clone()).collect(),
        views,
    };
    let text = serde_json::to_string_pretty(&doc).map_err(|e| out_err(&dir.join("labels.json"), e))?;
    atomic::write_bytes(&dir.join("labels.json"), text.as_bytes())?;
    Ok(DatasetSummary {
        dir: dir.to_path_buf(),
        gaussians: scene.gaussians.len(),
        views: total,
        test_views: scene.test_views().len(),
        views_visible,
    })
}

/// The cameras as a COLMAP text model (one PINHOLE camera per view; image names
/// `view_NNN.png` inside `images/`) and a subsample of the Gaussian centres as points.
fn write_colmap(scene: &Scene, dir: &Path, points: usize) -> Result<(), Error> {
    let mut cams = String::from(
        "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n",
    );
    let mut imgs = String::from(
        "# Image list with two lines of data per image:\n#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n",
    );
    for (i, c) in scene.cameras.iter().enumerate() {
        let id = i + 1;
        cams.push_str(&format!(
            "{id} PINHOLE {} {} {} {} {} {}\n",
            c.width, c.height, c.fx, c.fy, c.cx, c.cy
        ));
        let q = quat_from_matrix(c.rotation);
        let t = c.translation;
        imgs.push_str(&format!(
            "{id} {} {} {} {} {} {} {} {id} {}.png\n\n",
            q[0],
            q[1],
            q[2],
            q[3],
            t[0],
            t[1],
            t[2],
            c.stem()
        ));
    }
    let g = &scene.gaussians;
    let step = g.len().div_ceil(points).max(1);
    let mut pts = String::from("# 3D point list with one line of data per point:\n#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n");
    for (k, i) in (0..g.len()).step_by(step).enumerate() {
        let p = g.means[i];
        let c = dc_colour(g, i).map(image::to_u8);
        pts.push_str(&format!("{} {} {} {} {} {} {} 0\n", k + 1, p[0], p[1], p[2], c[0], c[1], c[2]));
    }
    atomic::write_bytes(&dir.join("cameras.txt"), cams.as_bytes())?;
    atomic::write_bytes(&dir.join("images.txt"), imgs.as_bytes())?;
    atomic::write_bytes(&dir.join("points3D.txt"), pts.as_bytes())?;
    Ok(())
}

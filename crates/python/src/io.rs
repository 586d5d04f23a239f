//! Scenes and cameras in and out: the INRIA PLY as named numpy arrays, and cameras
//! from every format the CLI reads as gsplat's `viewmats` and `Ks`.

use crate::arrays::{rows, scene_error, slice, to_numpy, value_error};
use numpy::{PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::path::PathBuf;
use transsplat_scene::{cameras, ply, scene_paths, sh_coeffs, Camera, Gaussians};

/// Reads a scene (a PLY file, or an INRIA output folder: its newest iteration) into a
/// dict of arrays in the file's parameterisation (see `transsplat.load_ply`).
#[pyfunction]
pub fn load_ply<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    let g = py.allow_threads(|| {
        let file = scene_paths::resolve_scene(&path)?;
        ply::read(&file)
    });
    gaussians_to_dict(py, g.map_err(scene_error)?)
}

/// The arrays of `g` as a dict; the buffers move into numpy.
pub fn gaussians_to_dict(py: Python<'_>, g: Gaussians) -> PyResult<Bound<'_, PyDict>> {
    let n = g.len();
    let k = sh_coeffs(g.sh_degree);
    let d = PyDict::new(py);
    d.set_item("means", to_numpy(py, g.means.into_flattened(), &[n, 3])?)?;
    d.set_item("quats", to_numpy(py, g.rotations.into_flattened(), &[n, 4])?)?;
    d.set_item("log_scales", to_numpy(py, g.log_scales.into_flattened(), &[n, 3])?)?;
    d.set_item("opacity_logits", to_numpy(py, g.opacity_logits, &[n])?)?;
    d.set_item("sh", to_numpy(py, g.sh, &[n, k, 3])?)?;
    let extra = PyDict::new(py);
    let w = g.extra.width();
    for (j, name) in g.extra.names.iter().enumerate() {
        let column: Vec<f32> = (0..n).map(|i| g.extra.values[i * w + j]).collect();
        extra.set_item(name, to_numpy(py, column, &[n])?)?;
    }
    d.set_item("extra", extra)?;
    Ok(d)
}

/// Scene arrays as the library's [`Gaussians`] (checked: shapes, finite values, an SH
/// layout of 1, 4, 9 or 16 coefficients).
#[allow(clippy::too_many_arguments)]
pub fn gaussians_from_arrays(
    means: &PyReadonlyArrayDyn<'_, f32>,
    quats: &PyReadonlyArrayDyn<'_, f32>,
    log_scales: &PyReadonlyArrayDyn<'_, f32>,
    opacity_logits: &PyReadonlyArrayDyn<'_, f32>,
    sh: &PyReadonlyArrayDyn<'_, f32>,
    extra_names: Vec<String>,
    extra: Option<&PyReadonlyArrayDyn<'_, f32>>,
) -> PyResult<Gaussians> {
    let m = slice("means", means, &[None, Some(3)])?;
    let n = m.len() / 3;
    let q = slice("quats", quats, &[Some(n), Some(4)])?;
    let s = slice("log_scales", log_scales, &[Some(n), Some(3)])?;
    let o = slice("opacity_logits", opacity_logits, &[Some(n)])?;
    let c = slice("sh", sh, &[Some(n), None, Some(3)])?;
    let k = sh.shape()[1];
    let degree = (0..4u32).find(|&d| sh_coeffs(d) == k).ok_or_else(|| {
        value_error(format!(
            "sh: expected 1, 4, 9 or 16 coefficients per channel (SH degree 0 to 3), got {k}"
        ))
    })?;
    let values = match extra {
        Some(e) => slice("extra", e, &[Some(n), Some(extra_names.len())])?.to_vec(),
        None if extra_names.is_empty() => Vec::new(),
        None => return Err(value_error("extra: names given without values")),
    };
    let g = Gaussians {
        means: rows::<3>(m).to_vec(),
        log_scales: rows::<3>(s).to_vec(),
        rotations: rows::<4>(q).to_vec(),
        opacity_logits: o.to_vec(),
        sh_degree: degree,
        sh: c.to_vec(),
        extra: transsplat_scene::gaussians::Extra { names: extra_names, values },
    };
    g.validate().map_err(value_error)?;
    Ok(g)
}

/// Writes a scene as an INRIA PLY, atomically (a temporary file renamed when complete).
#[pyfunction]
#[pyo3(signature = (path, means, quats, log_scales, opacity_logits, sh, extra_names, extra=None))]
#[allow(clippy::too_many_arguments)]
pub fn save_ply(
    py: Python<'_>,
    path: PathBuf,
    means: PyReadonlyArrayDyn<'_, f32>,
    quats: PyReadonlyArrayDyn<'_, f32>,
    log_scales: PyReadonlyArrayDyn<'_, f32>,
    opacity_logits: PyReadonlyArrayDyn<'_, f32>,
    sh: PyReadonlyArrayDyn<'_, f32>,
    extra_names: Vec<String>,
    extra: Option<PyReadonlyArrayDyn<'_, f32>>,
) -> PyResult<()> {
    let g = gaussians_from_arrays(
        &means,
        &quats,
        &log_scales,
        &opacity_logits,
        &sh,
        extra_names,
        extra.as_ref(),
    )?;
    py.allow_threads(|| ply::write(&path, &g)).map_err(scene_error)
}

/// Loads cameras (cameras.json, transforms.json, a COLMAP model or a folder holding
/// one, or the cameras beside an INRIA scene) as gsplat's arrays.
#[pyfunction]
pub fn load_cameras<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    let cams = py.allow_threads(|| -> transsplat_scene::Result<Vec<Camera>> {
        let file = if path.is_dir() && cameras::find_cameras_in(&path).is_none() {
            scene_paths::resolve_cameras_for(&path)?
        } else {
            path.clone()
        };
        cameras::load(&file)
    });
    cameras_to_dict(py, &cams.map_err(scene_error)?)
}

/// gsplat's world-to-camera matrix of a camera, row-major 4 × 4.
pub fn viewmat(cam: &Camera) -> [f32; 16] {
    let (r, t) = (&cam.rotation, &cam.translation);
    [
        r[0][0], r[0][1], r[0][2], t[0], r[1][0], r[1][1], r[1][2], t[1], r[2][0], r[2][1], r[2][2], t[2],
        0.0, 0.0, 0.0, 1.0,
    ]
}

/// The pinhole intrinsics `K` of a camera, row-major 3 × 3.
pub fn intrinsics(cam: &Camera) -> [f32; 9] {
    [cam.fx, 0.0, cam.cx, 0.0, cam.fy, cam.cy, 0.0, 0.0, 1.0]
}

/// `names`, `viewmats` (C, 4, 4) world-to-camera, `Ks` (C, 3, 3), `widths`, `heights`.
pub fn cameras_to_dict<'py>(py: Python<'py>, cams: &[Camera]) -> PyResult<Bound<'py, PyDict>> {
    let c = cams.len();
    let viewmats: Vec<f32> = cams.iter().flat_map(viewmat).collect();
    let ks: Vec<f32> = cams.iter().flat_map(intrinsics).collect();
    let d = PyDict::new(py);
    d.set_item("names", PyList::new(py, cams.iter().map(|c| c.name.clone()))?)?;
    d.set_item("viewmats", to_numpy(py, viewmats, &[c, 4, 4])?)?;
    d.set_item("Ks", to_numpy(py, ks, &[c, 3, 3])?)?;
    d.set_item("widths", to_numpy(py, cams.iter().map(|c| c.width as i64).collect(), &[c])?)?;
    d.set_item("heights", to_numpy(py, cams.iter().map(|c| c.height as i64).collect(), &[c])?)?;
    Ok(d)
}

/// [`cameras_from_arrays`] with the image sizes as two lists (widths, heights) of the
/// same length, and the image names.
pub fn cameras_from_lists(
    viewmats: &PyReadonlyArrayDyn<'_, f32>,
    ks: &PyReadonlyArrayDyn<'_, f32>,
    widths: Vec<u32>,
    heights: Vec<u32>,
    names: Vec<String>,
) -> PyResult<Vec<Camera>> {
    if widths.len() != heights.len() {
        return Err(value_error("cameras: widths and heights differ in length"));
    }
    let sizes: Vec<(u32, u32)> = widths.into_iter().zip(heights).collect();
    cameras_from_arrays(viewmats, ks, &sizes, Some(names))
}

/// Cameras from gsplat's arrays: `viewmats` (C, 4, 4) world-to-camera, `Ks` (C, 3, 3),
/// image sizes, optional names (default `00000` ...). They are checked as a camera
/// file is ([`cameras::validated`]: a proper rotation, positive focal lengths, the
/// size cap, unique image names).
pub fn cameras_from_arrays(
    viewmats: &PyReadonlyArrayDyn<'_, f32>,
    ks: &PyReadonlyArrayDyn<'_, f32>,
    sizes: &[(u32, u32)],
    names: Option<Vec<String>>,
) -> PyResult<Vec<Camera>> {
    let v = slice("viewmats", viewmats, &[None, Some(4), Some(4)])?;
    let c = v.len() / 16;
    let k = slice("Ks", ks, &[Some(c), Some(3), Some(3)])?;
    if sizes.len() != c {
        return Err(value_error(format!("{} image sizes for {c} cameras", sizes.len())));
    }
    let names = names.unwrap_or_else(|| (0..c).map(|i| format!("{i:05}")).collect());
    if names.len() != c {
        return Err(value_error(format!("names: {} names for {c} cameras", names.len())));
    }
    let mut out = Vec::with_capacity(c);
    for (i, name) in names.into_iter().enumerate() {
        let m = &v[i * 16..(i + 1) * 16];
        let kk = &k[i * 9..(i + 1) * 9];
        if kk[1] != 0.0 || kk[3] != 0.0 || kk[6] != 0.0 || kk[7] != 0.0 || kk[8] != 1.0 {
            return Err(value_error(format!(
                "Ks[{i}]: expected a pinhole matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]"
            )));
        }
        if m[12] != 0.0 || m[13] != 0.0 || m[14] != 0.0 || m[15] != 1.0 {
            return Err(value_error(format!("viewmats[{i}]: the last row must be [0, 0, 0, 1]")));
        }
        out.push(Camera {
            name,
            width: sizes[i].0,
            height: sizes[i].1,
            fx: kk[0],
            fy: kk[4],
            cx: kk[2],
            cy: kk[5],
            rotation: std::array::from_fn(|r| std::array::from_fn(|j| m[r * 4 + j])),
            translation: std::array::from_fn(|r| m[r * 4 + 3]),
        });
    }
    cameras::validated(out, std::path::Path::new("cameras")).map_err(scene_error)
}

/// Writes a built-in benchmark scene (`tabletop`, `occluded`, `garden`) as a dataset folder, as
/// `transsplat scene NAME --out DIR [--quick]` does; returns the folder.
#[pyfunction]
#[pyo3(signature = (name, out, quick=false, seed=0))]
pub fn builtin_scene(py: Python<'_>, name: &str, out: PathBuf, quick: bool, seed: u64) -> PyResult<PathBuf> {
    use transsplat_builtin::{build, write_dataset, SceneConfig, WriteOptions};
    let mut cfg = if quick { SceneConfig::quick() } else { SceneConfig::default() };
    cfg.seed = seed;
    let scene = build(name, &cfg).map_err(|e| value_error(e.to_string()))?;
    py.allow_threads(|| write_dataset(&scene, &out, &WriteOptions::default(), &mut |_, _| {})).map_err(
        |e| match e {
            transsplat_builtin::Error::Io(e) => scene_error(e),
            e => value_error(e.to_string()),
        },
    )?;
    Ok(out)
}

/// The rasterizer benchmark's synthetic scene and camera (`transsplat bench raster`:
/// `n` Gaussians filling the frustum, SH degree 3), so a call from Python can be timed
/// against the binary on identical input (`tools/bench_python.py`).
#[pyfunction]
pub fn bench_scene(py: Python<'_>, n: usize, size: u32) -> PyResult<(Bound<'_, PyDict>, Bound<'_, PyDict>)> {
    if n > 50_000_000 || size == 0 || size > 1 << 15 {
        return Err(value_error(format!("bench_scene: n = {n} or size = {size} out of range")));
    }
    let g = py.allow_threads(|| transsplat_raster::synthetic::bench_scene(n, 7));
    let cam = transsplat_raster::synthetic::bench_camera(size, size);
    Ok((gaussians_to_dict(py, g)?, cameras_to_dict(py, &[cam])?))
}

/// The one output rule (`transsplat_scene::atomic::check_output`): refused with
/// `ValueError` when `out` is an input, contains one, or lies inside an input folder or
/// a dataset's images folder.
#[pyfunction]
pub fn check_output(out: PathBuf, inputs: Vec<PathBuf>) -> PyResult<()> {
    let refs: Vec<&std::path::Path> = inputs.iter().map(PathBuf::as_path).collect();
    transsplat_scene::atomic::check_output(&out, &refs).map_err(scene_error)
}

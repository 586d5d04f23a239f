//! `transsplat view`: the interactive 3D viewer page for any scene, alone or against a
//! second one (before/after toggle and split slider), with its cameras.

use super::common::{check_output, finite_f64, load_cameras, load_scene, parse_rgb, SceneArgs};
use anyhow::{bail, Result};
use std::path::PathBuf;
use transsplat_scene::{atomic, scene_paths, Camera, Gaussians};
use transsplat_viewer::{Layer, LayerKind, Role, Viewer};

/// Arguments of `transsplat view`.
#[derive(clap::Args, Debug)]
pub struct ViewArgs {
    /// Scene: a PLY (INRIA or compressed), an .spz, .glb or .sog file, or an INRIA output folder.
    pub scene: PathBuf,
    /// A second scene shown as "after" (e.g. the edited one), in the same formats.
    #[arg(long)]
    pub compare: Option<PathBuf>,
    /// Cameras to draw and jump to (any format `render` reads); default: beside the
    /// scene, if any there.
    #[arg(long)]
    pub cameras: Option<PathBuf>,
    /// Extra per-Gaussian PLY properties to offer as colour modes (comma-separated;
    /// values in [0, 1] are shown as a heat map, whole numbers as labels).
    #[arg(long, value_delimiter = ',')]
    pub layer: Vec<String>,
    /// Background colour R,G,B in [0, 1].
    #[arg(long, value_parser = parse_rgb, default_value = "0,0,0")]
    pub background: [f32; 3],
    /// Size budget of the page in MB; beyond it the least opaque and smallest Gaussians
    /// are left out (the page says how many).
    #[arg(long, value_parser = finite_f64, default_value_t = 38.0)]
    pub max_mb: f64,
    /// Drop Gaussians with NaN or infinite parameters instead of refusing the file.
    #[arg(long)]
    pub drop_invalid: bool,
    /// Output HTML file (self-contained; works offline).
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `transsplat view`.
pub fn run(a: &ViewArgs) -> Result<()> {
    if !(0.5..=2000.0).contains(&a.max_mb) {
        bail!("--max-mb {} is outside 0.5..=2000", a.max_mb);
    }
    let load = |p: &PathBuf| {
        load_scene(&SceneArgs {
            scene: p.clone(),
            drop_invalid: a.drop_invalid,
            spz_axes: Default::default(),
        })
    };
    let (g, scene_path) = load(&a.scene)?;
    let other = a.compare.as_ref().map(load).transpose()?;
    let cams = match &a.cameras {
        Some(c) => Some(load_cameras(Some(c), &a.scene)?),
        None => scene_paths::resolve_cameras_for(&a.scene)
            .ok()
            .map(|_| load_cameras(None, &a.scene))
            .transpose()?,
    };
    let mut inputs = vec![a.scene.as_path(), scene_path.as_path()];
    if let Some((_, p)) = &other {
        inputs.push(p);
    }
    if let Some(c) = &a.compare {
        inputs.push(c);
    }
    if let Some((_, p)) = &cams {
        inputs.push(p);
    }
    check_output(&a.out, &inputs)?;

    let title = a.scene.display().to_string();
    let mut scenes: Vec<(String, &Gaussians)> =
        vec![(if other.is_some() { "before" } else { "scene" }.into(), &g)];
    if let Some((o, _)) = &other {
        scenes.push(("after".into(), o));
    }
    let mut v = Viewer::new(&title, a.background, scenes);
    v.max_bytes = (a.max_mb * 1e6) as usize;
    for name in &a.layer {
        let mut found = false;
        for (s, (_, sg)) in v.scenes.iter().enumerate() {
            if let Some(values) = sg.extra.column(name) {
                let whole = values.iter().all(|x| x.fract() == 0.0 && *x >= 0.0);
                let kind = if whole && values.iter().any(|&x| x > 1.0) {
                    LayerKind::Label
                } else {
                    LayerKind::Scalar
                };
                v.layers.push(Layer { name: name.clone(), scene: s, kind, values });
                found = true;
                break;
            }
        }
        if !found {
            bail!("--layer {name}: no scene has a per-Gaussian property of that name");
        }
    }
    v.cameras = match &cams {
        Some((c, _)) => c.iter().map(|c| (c.clone(), Role::Train)).collect(),
        None => vec![(overview_camera(&g), Role::Train)],
    };
    let html = transsplat_viewer::page(&v).map_err(|e| anyhow::anyhow!("{}: {e}", scene_path.display()))?;
    atomic::write_bytes(&a.out, html.as_bytes())?;
    tracing::info!("wrote {} ({:.1} MB)", a.out.display(), html.len() as f64 / 1e6);
    Ok(())
}

/// A 1280×720 camera looking along +z at the centre of the scene's central 98 %,
/// far enough back to see it whole (for scenes without cameras).
fn overview_camera(g: &Gaussians) -> Camera {
    let pct = |a: usize, p: f64| {
        let mut v: Vec<f32> = g.means.iter().map(|m| m[a]).collect();
        v.sort_by(|x, y| x.total_cmp(y));
        v[((v.len() - 1) as f64 * p).round() as usize]
    };
    let lo: [f32; 3] = std::array::from_fn(|a| pct(a, 0.01));
    let hi: [f32; 3] = std::array::from_fn(|a| pct(a, 0.99));
    let centre: [f32; 3] = std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]));
    let radius = (0..3).map(|a| hi[a] - lo[a]).fold(0.0f32, f32::max).max(1e-3);
    let (w, h) = (1280u32, 720u32);
    let f = 0.9 * w as f32;
    let eye = [centre[0], centre[1], centre[2] - 1.2 * radius * f / w as f32 * 2.0];
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    Camera::from_c2w("overview".into(), w, h, f, f, w as f32 / 2.0, h as f32 / 2.0, identity, eye)
}

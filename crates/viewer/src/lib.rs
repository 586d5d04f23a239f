//! The interactive 3D viewer of transsplat: one self-contained HTML section (WebGL2,
//! no network, no external scripts) that flies around a scene or a before/after pair,
//! draws the cameras, and colours the Gaussians by per-Gaussian maps such as the gate
//! γ, the transported support or the ground-truth target label.
//!
//! The page's data is compact and quantised: each scene is embedded as the PlayCanvas
//! compressed PLY ([`transsplat_scene::ply::compressed`], SH cut to degree 1, about
//! 25 bytes a Gaussian), each map as one byte a Gaussian, all base64 in
//! `<script type="application/octet-stream">` blocks that `assets/viewer.js` decodes.
//! When the data would pass the size budget ([`Viewer::max_bytes`]), the least
//! important Gaussians (smallest opacity × volume) are dropped, and the page says how
//! many (docs/formats.md#viewer).
//!
//! [`section`] writes the fragment that `report.html` embeds; [`page`] wraps it in a
//! whole document (`transsplat view`).

use serde::Serialize;
use transsplat_scene::ply::compressed;
use transsplat_scene::{sigmoid, Camera, Gaussians};

const VIEWER_JS: &str = include_str!("../assets/viewer.js");
const VIEWER_CSS: &str = include_str!("../assets/viewer.css");

/// SH degree kept in the page (the viewer evaluates degree 1 per view direction).
pub const SH_DEGREE: u32 = 1;
/// Default size budget for the embedded data, in bytes of page text.
pub const DEFAULT_MAX_BYTES: usize = 38_000_000;

/// A viewer error.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    #[error("scene '{0}' has no Gaussians; there is nothing to show")]
    Empty(String),
    #[error("scene '{scene}': Gaussian {index} has an invalid {what}")]
    NonFinite { scene: String, index: usize, what: &'static str },
    #[error("map '{name}' has {got} values for {want} Gaussians of scene '{scene}'")]
    LayerLength { name: String, scene: String, got: usize, want: usize },
    #[error("the viewer shows one or two scenes, got {0}")]
    SceneCount(usize),
    #[error("map '{0}' refers to a scene that does not exist")]
    LayerScene(String),
}

/// How a per-Gaussian map is coloured.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum LayerKind {
    /// A value in [0, 1], shown with a heat colour map.
    Scalar,
    /// A class id (0, 1, ...), shown with distinct colours.
    Label,
}

/// A per-Gaussian map of one scene.
#[derive(Clone, Debug)]
pub struct Layer {
    pub name: String,
    /// Index into [`Viewer::scenes`].
    pub scene: usize,
    pub kind: LayerKind,
    /// One value per Gaussian of the scene ([0, 1] for scalars, small integers for labels).
    pub values: Vec<f32>,
}

/// What a camera was used for, drawn in its own colour.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    Train,
    Edit,
    Test,
}

/// Everything the page shows.
pub struct Viewer<'a> {
    pub title: String,
    /// Render background, as in the renders it is compared with.
    pub background: [f32; 3],
    /// One scene, or the before/after pair (first is "before").
    pub scenes: Vec<(String, &'a Gaussians)>,
    pub layers: Vec<Layer>,
    pub cameras: Vec<(Camera, Role)>,
    /// Camera the page starts at (clamped to the list).
    pub start_camera: usize,
    /// Budget for the embedded data (page text bytes).
    pub max_bytes: usize,
}

impl<'a> Viewer<'a> {
    /// A viewer with no maps or cameras and the default budget.
    pub fn new(title: &str, background: [f32; 3], scenes: Vec<(String, &'a Gaussians)>) -> Self {
        Viewer {
            title: title.to_string(),
            background,
            scenes,
            layers: Vec::new(),
            cameras: Vec::new(),
            start_camera: 0,
            max_bytes: DEFAULT_MAX_BYTES,
        }
    }
}

#[derive(Serialize)]
struct MetaScene {
    name: String,
    blob: usize,
    count: usize,
    dropped: usize,
}

#[derive(Serialize)]
struct MetaLayer {
    name: String,
    scene: usize,
    blob: usize,
    kind: LayerKind,
}

#[derive(Serialize)]
struct MetaCamera {
    name: String,
    width: u32,
    height: u32,
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    rotation: [[f32; 3]; 3],
    translation: [f32; 3],
    role: Role,
}

#[derive(Serialize)]
struct Meta {
    title: String,
    background: [f32; 3],
    scenes: Vec<MetaScene>,
    shared_geometry: bool,
    layers: Vec<MetaLayer>,
    cameras: Vec<MetaCamera>,
    start_camera: usize,
    notes: Vec<String>,
}

/// The section with the viewer, its styles, data and script.
pub fn section(v: &Viewer) -> Result<String, ViewerError> {
    check(v)?;
    let shared = v.scenes.len() == 2 && same_geometry(v.scenes[0].1, v.scenes[1].1);
    let keep = kept(v, shared);
    let mut blobs: Vec<Vec<u8>> = Vec::new();
    let mut scenes = Vec::new();
    let mut orders: Vec<Vec<u32>> = Vec::new();
    let mut notes = Vec::new();
    for (s, (name, g)) in v.scenes.iter().enumerate() {
        let order = if shared && s == 1 { orders[0].clone() } else { keep_and_order(g, keep[s]) };
        let mut sub = g.select(&order);
        sub.truncate_sh(SH_DEGREE);
        sub.extra = Default::default();
        blobs.push(compressed::to_bytes(&sub));
        let dropped = g.len() - order.len();
        if dropped > 0 {
            notes.push(format!(
                "{name}: {dropped} of {} Gaussians (the least opaque and smallest) are not shown, to keep the page under {:.0} MB",
                g.len(),
                v.max_bytes as f64 / 1e6
            ));
        }
        scenes.push(MetaScene { name: name.clone(), blob: s, count: order.len(), dropped });
        orders.push(order);
    }
    let mut layers = Vec::new();
    for l in &v.layers {
        let bytes: Vec<u8> = orders[l.scene]
            .iter()
            .map(|&i| {
                let x = l.values[i as usize];
                match l.kind {
                    LayerKind::Scalar => (x.clamp(0.0, 1.0) * 255.0).round() as u8,
                    LayerKind::Label => x.round().clamp(0.0, 255.0) as u8,
                }
            })
            .collect();
        layers.push(MetaLayer { name: l.name.clone(), scene: l.scene, blob: blobs.len(), kind: l.kind });
        blobs.push(bytes);
    }
    let cameras = v
        .cameras
        .iter()
        .map(|(c, role)| MetaCamera {
            name: c.stem(),
            width: c.width,
            height: c.height,
            fx: c.fx,
            fy: c.fy,
            cx: c.cx,
            cy: c.cy,
            rotation: c.rotation,
            translation: c.translation,
            role: *role,
        })
        .collect::<Vec<_>>();
    let meta = Meta {
        title: v.title.clone(),
        background: v.background,
        start_camera: v.start_camera.min(cameras.len().saturating_sub(1)),
        scenes,
        shared_geometry: shared,
        layers,
        cameras,
        notes,
    };
    let json = serde_json::to_string(&meta).expect("viewer metadata serialises").replace("</", "<\\/");
    let mut out = String::with_capacity(blobs.iter().map(|b| b.len() * 4 / 3 + 100).sum::<usize>() + 200_000);
    out += "<style>\n";
    out += VIEWER_CSS;
    out += "</style>\n<div class=\"ts-viewer\">\n<script type=\"application/json\" class=\"ts-meta\">";
    out += &json;
    out += "</script>\n";
    for (k, b) in blobs.iter().enumerate() {
        out += &format!("<script type=\"application/octet-stream\" class=\"ts-blob\" data-blob=\"{k}\">");
        base64_into(b, &mut out);
        out += "</script>\n";
    }
    out += "<noscript>The 3D viewer needs JavaScript.</noscript>\n</div>\n<script>\n";
    out += VIEWER_JS;
    out += "\n</script>\n";
    Ok(out)
}

/// A whole HTML document holding the viewer.
pub fn page(v: &Viewer) -> Result<String, ViewerError> {
    let body = section(v)?;
    Ok(format!(
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{}</title>\n\
         <style>body{{margin:0;font-family:system-ui,sans-serif;background:#1b1b1f;color:#ddd}}</style>\n\
         </head>\n<body>\n{body}</body>\n</html>\n",
        escape(&v.title)
    ))
}

/// HTML-escapes text.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

fn check(v: &Viewer) -> Result<(), ViewerError> {
    if v.scenes.is_empty() || v.scenes.len() > 2 {
        return Err(ViewerError::SceneCount(v.scenes.len()));
    }
    for (name, g) in &v.scenes {
        if g.is_empty() {
            return Err(ViewerError::Empty(name.clone()));
        }
        if let Some((index, what)) = g.first_non_finite() {
            return Err(ViewerError::NonFinite { scene: name.clone(), index, what });
        }
    }
    for l in &v.layers {
        let (scene, g) = v.scenes.get(l.scene).ok_or_else(|| ViewerError::LayerScene(l.name.clone()))?;
        if l.values.len() != g.len() {
            return Err(ViewerError::LayerLength {
                name: l.name.clone(),
                scene: scene.clone(),
                got: l.values.len(),
                want: g.len(),
            });
        }
    }
    Ok(())
}

/// True when two scenes hold the same Gaussians in the same places (only colours,
/// opacities or SH differ), as after a colour edit with frozen geometry.
fn same_geometry(a: &Gaussians, b: &Gaussians) -> bool {
    a.len() == b.len() && a.means == b.means && a.log_scales == b.log_scales && a.rotations == b.rotations
}

/// Page bytes a Gaussian costs in scene `g`: the compressed record, its SH bytes,
/// one byte per map, a chunk's share, all as base64 (4/3).
fn bytes_per_gaussian(g: &Gaussians, maps: usize) -> f64 {
    let rest = (transsplat_scene::sh_coeffs(g.sh_degree.min(SH_DEGREE)) - 1) * 3;
    (16 + rest + maps) as f64 * 4.0 / 3.0 + 72.0 / 256.0 * 4.0 / 3.0
}

/// How many Gaussians of each scene fit the budget (all of them when they fit).
fn kept(v: &Viewer, shared: bool) -> Vec<usize> {
    let fixed = VIEWER_JS.len() + VIEWER_CSS.len() + 1000 * v.cameras.len() + 64 * 1024;
    let budget = v.max_bytes.saturating_sub(fixed) as f64;
    let maps = |s: usize| v.layers.iter().filter(|l| l.scene == s).count();
    let need: f64 =
        v.scenes.iter().enumerate().map(|(s, (_, g))| g.len() as f64 * bytes_per_gaussian(g, maps(s))).sum();
    let fraction = if need <= budget { 1.0 } else { budget / need };
    let mut keep: Vec<usize> = v
        .scenes
        .iter()
        .map(|(_, g)| ((g.len() as f64 * fraction).floor() as usize).clamp(1, g.len()))
        .collect();
    if shared {
        keep[1] = keep[0];
    }
    keep
}

/// The `keep` most important Gaussians (opacity × volume), in Morton order.
fn keep_and_order(g: &Gaussians, keep: usize) -> Vec<u32> {
    let mut chosen: Vec<u32> = (0..g.len() as u32).collect();
    if keep < g.len() {
        let importance = |i: u32| {
            let i = i as usize;
            let s = g.log_scales[i];
            sigmoid(g.opacity_logits[i]) as f64 * ((s[0] + s[1] + s[2]) as f64).exp()
        };
        chosen.sort_by(|&a, &b| importance(b).total_cmp(&importance(a)));
        chosen.truncate(keep);
        chosen.sort_unstable();
    }
    compressed::morton_sort(&g.means, &mut chosen);
    chosen
}

/// Standard base64 (RFC 4648, with padding), appended to `out`.
fn base64_into(bytes: &[u8], out: &mut String) {
    const TABLE: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    out.reserve(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let b = [c[0], *c.get(1).unwrap_or(&0), *c.get(2).unwrap_or(&0)];
        let n = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
        for k in 0..4 {
            if k <= c.len() {
                out.push(TABLE[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
}

#[cfg(test)]
mod tests;

//! The built-in scenes and their description.
//!
//! - `tabletop`: a ball, a crate, a vase and a cone on a wood-grain table in front of
//!   a striped wallpaper backdrop, on a tiled floor. Suggested target: the ball.
//! - `occluded`: a ball half hidden behind a crate, and a thin stem (a 2.4 cm thick
//!   pole with a small knob). Suggested target: the ball (partly occluded); the stem is
//!   the thin-structure target.
//! - `garden`: an apple, a tomato of a close orange-red (the distractor), a lamp post
//!   (a 3.6 cm thick pole with a lamp head) and a white fence of thin rails, on a wide
//!   lawn with a gravel path, in front of a far hedge-and-sky backdrop, seen from a
//!   wider and farther orbit (3.4 m, 150°) with a wider lens. Different statistics
//!   from the tabletop scenes: the background covers most of every view and is far,
//!   the thin structures are one to two pixels wide, and the target has a look-alike.
//!   Suggested target: the apple.
//!
//! Open surroundings ([`SceneConfig::open`], tabletop and occluded): the floor and
//! walls around the table give way to a checkerboard floor reaching 20 m, sampled more
//! coarsely with distance, under a sky dome 30 m away, and the cameras orbit the full
//! 360° at 6–26° elevation: a large, far background that covers most of every view, as an outdoor or
//! big-room capture gives a trainer (the floater study of the trainer issue).
//!
//! World frame: z up, metres, label 0 is the background, objects are 1.... Tabletop
//! scenes: the table top at z = 0, the floor at z = −0.75, the backdrop at y = +1.3
//! (label 0: floor, wall, table). Garden: the lawn at z = 0, the backdrop walls at
//! y = +3.5 and x = ±4.5 (label 0: lawn, path, hedge and sky).

use crate::build::Builder;
use crate::rig::{is_test, Rig};
use crate::texture::{checker, fbm, mix_rgb, shade, stripes, wood_grain};
use crate::Error;
use transsplat_scene::{Camera, Extra, Gaussians};

/// Names accepted by [`build`].
pub const SCENE_NAMES: &[&str] = &["tabletop", "occluded", "garden"];

/// Name of the per-Gaussian label property in the written PLY.
pub const LABEL_PROPERTY: &str = "label";

/// How a scene is generated.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneConfig {
    /// Seed of the sampling jitter, SH noise and texture noise.
    pub seed: u64,
    /// Multiplies the number of Gaussians (1 = default density, ~40k Gaussians for
    /// `tabletop`; 0.1 gives a ~5k scene for tests). Clamped to [0.01, 32].
    pub detail: f32,
    pub width: u32,
    pub height: u32,
    /// Number of cameras.
    pub views: usize,
    /// Open surroundings instead of the enclosing floor and walls (module doc).
    pub open: bool,
}

impl Default for SceneConfig {
    fn default() -> Self {
        SceneConfig { seed: 0, detail: 1.0, width: 256, height: 192, views: 32, open: false }
    }
}

impl SceneConfig {
    /// A small variant for tests and `--quick`: ~5k Gaussians, 16 views of 128×96.
    pub fn quick() -> Self {
        SceneConfig { seed: 0, detail: 0.12, width: 128, height: 96, views: 16, open: false }
    }

    fn check(&self) -> Result<(), Error> {
        if !(self.detail.is_finite() && self.detail > 0.0) {
            return Err(Error::Invalid(format!("detail must be a positive number, got {}", self.detail)));
        }
        if self.width == 0 || self.height == 0 || self.width > 8192 || self.height > 8192 {
            return Err(Error::Invalid(format!(
                "image size {}x{} is not in 1..=8192 a side",
                self.width, self.height
            )));
        }
        if self.views == 0 || self.views > 1000 {
            return Err(Error::Invalid(format!("views must be in 1..=1000, got {}", self.views)));
        }
        Ok(())
    }
}

/// One labelled object of a scene.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SceneObject {
    /// Name used in instructions ("ball").
    pub name: String,
    /// Label id (1..); 0 is the background.
    pub label: u32,
    /// Base colour in words ("red").
    pub colour: String,
    /// Base colour as linear RGB in [0, 1] (before texture).
    pub base_rgb: [f32; 3],
    /// Shape in words ("sphere", "box", "surface of revolution").
    pub shape: String,
    /// Centre of the object's bounding box.
    pub centre: [f32; 3],
}

/// A built-in scene: Gaussians with a label each, the labelled objects and cameras.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    pub name: String,
    pub description: String,
    /// The Gaussians (no extra properties; see [`Scene::gaussians_with_labels`]).
    pub gaussians: Gaussians,
    /// Per-Gaussian label: 0 background, otherwise an object's `label`.
    pub labels: Vec<u32>,
    /// Objects in label order (labels 1, 2, ...).
    pub objects: Vec<SceneObject>,
    pub cameras: Vec<Camera>,
    /// The object a demo edit should target.
    pub target: String,
    /// Background colour of the renders.
    pub background: [f32; 3],
    pub config: SceneConfig,
}

impl Scene {
    /// Number of labels including the background (max label + 1).
    pub fn num_labels(&self) -> usize {
        self.objects.iter().map(|o| o.label as usize).max().unwrap_or(0) + 1
    }

    /// Label names indexed by label id ("background" for 0).
    pub fn label_names(&self) -> Vec<String> {
        let mut names = vec![String::new(); self.num_labels()];
        names[0] = "background".into();
        for o in &self.objects {
            names[o.label as usize] = o.name.clone();
        }
        names
    }

    /// The object called `name` (case-insensitive).
    pub fn object(&self, name: &str) -> Option<&SceneObject> {
        self.objects.iter().find(|o| o.name.eq_ignore_ascii_case(name.trim()))
    }

    /// The object with label `label`.
    pub fn object_by_label(&self, label: u32) -> Option<&SceneObject> {
        self.objects.iter().find(|o| o.label == label)
    }

    /// The label of `name`, or an error listing the objects.
    pub fn label_of(&self, name: &str) -> Result<u32, Error> {
        self.object(name)
            .map(|o| o.label)
            .ok_or_else(|| Error::UnknownObject { name: name.to_string(), objects: self.object_list() })
    }

    pub(crate) fn object_list(&self) -> String {
        self.objects.iter().map(|o| o.name.as_str()).collect::<Vec<_>>().join(", ")
    }

    /// Number of Gaussians per label (index = label id).
    pub fn label_counts(&self) -> Vec<usize> {
        let mut c = vec![0usize; self.num_labels()];
        for &l in &self.labels {
            if let Some(v) = c.get_mut(l as usize) {
                *v += 1;
            }
        }
        c
    }

    /// Indices of the test views (every 8th camera).
    pub fn test_views(&self) -> Vec<usize> {
        (0..self.cameras.len()).filter(|&i| is_test(i)).collect()
    }

    /// Indices of the training views.
    pub fn train_views(&self) -> Vec<usize> {
        (0..self.cameras.len()).filter(|&i| !is_test(i)).collect()
    }

    /// The Gaussians with the label as an extra property `label` (for the PLY).
    pub fn gaussians_with_labels(&self) -> Gaussians {
        with_labels(&self.gaussians, &self.labels)
    }
}

/// A copy of `g` with `labels` appended as the extra property [`LABEL_PROPERTY`]
/// (replacing an existing one).
pub fn with_labels(g: &Gaussians, labels: &[u32]) -> Gaussians {
    let mut out = g.clone();
    let w = g.extra.width();
    let keep: Vec<usize> = (0..w).filter(|&k| g.extra.names[k] != LABEL_PROPERTY).collect();
    let mut names: Vec<String> = keep.iter().map(|&k| g.extra.names[k].clone()).collect();
    names.push(LABEL_PROPERTY.into());
    let mut values = Vec::with_capacity(g.len() * names.len());
    for (i, &l) in labels.iter().enumerate().take(g.len()) {
        values.extend(keep.iter().map(|&k| g.extra.values[i * w + k]));
        values.push(l as f32);
    }
    out.extra = Extra { names, values };
    out
}

/// Reads the per-Gaussian labels back from the `label` extra property, if present.
pub fn labels_from_extra(g: &Gaussians) -> Option<Vec<u32>> {
    g.extra
        .column(LABEL_PROPERTY)?
        .into_iter()
        .map(|v| (v.is_finite() && v >= 0.0 && v.fract() == 0.0 && v < 65536.0).then_some(v as u32))
        .collect()
}

/// Builds the scene `name` (one of [`SCENE_NAMES`]); an unknown name is an error that
/// lists the available ones.
pub fn build(name: &str, config: &SceneConfig) -> Result<Scene, Error> {
    config.check()?;
    match name.trim().to_ascii_lowercase().as_str() {
        "tabletop" => Ok(tabletop(config)),
        "occluded" => Ok(occluded(config)),
        "garden" if config.open => Err(Error::Invalid(
            "open surroundings are built for tabletop and occluded; garden has its own far backdrop".into(),
        )),
        "garden" => Ok(garden(config)),
        _ => Err(Error::UnknownScene {
            name: name.to_string(),
            available: SCENE_NAMES.iter().map(|s| s.to_string()).collect(),
        }),
    }
}

/// Sample spacings (metres) at detail 1.
struct Spacing {
    background: f32,
    table: f32,
    object: f32,
}

impl Spacing {
    fn new(detail: f32) -> Self {
        let k = 1.0 / detail.clamp(0.01, 32.0).sqrt();
        Spacing { background: 0.045 * k, table: 0.018 * k, object: 0.0105 * k }
    }
}

const TABLE_HALF: [f32; 2] = [0.8, 0.5];
const TABLE_THICK: f32 = 0.04;
const FLOOR_Z: f32 = -0.75;
const WALL_Y: f32 = 1.3;

/// How far the open floor reaches (metres from the table) and the sky dome's radius.
const FLOOR_REACH: f32 = 20.0;
const SKY_RADIUS: f32 = 30.0;

/// Floor, backdrop walls (or open surroundings, [`SceneConfig::open`]) and table (label 0).
fn background(b: &mut Builder, sp: &Spacing, seed: u64, open: bool) {
    let floor = move |p: [f32; 3]| {
        let tile = checker([p[0], p[1], 0.0], 0.5);
        let base = mix_rgb([0.36, 0.36, 0.38], [0.5, 0.49, 0.47], tile);
        shade(base, 0.85 + 0.3 * fbm(seed ^ 1, [p[0] * 4.0, p[1] * 4.0, 0.0], 3))
    };
    if open {
        open_surroundings(b, sp, &floor);
        table(b, sp, seed);
        return;
    }
    let wall = move |p: [f32; 3]| {
        let band = stripes([0.0, 0.0, p[0]], 0.3);
        let base = mix_rgb([0.78, 0.72, 0.6], [0.62, 0.68, 0.72], band);
        shade(base, 0.88 + 0.2 * fbm(seed ^ 2, [p[0] * 3.0, 0.0, p[2] * 3.0], 4))
    };
    let old_opacity = b.opacity;
    b.view_dependence = 0.015;
    b.rect([-2.6, -2.4, FLOOR_Z], [5.2, 0.0, 0.0], [0.0, 2.4 + WALL_Y, 0.0], sp.background, &floor, 0);
    b.rect([-2.6, WALL_Y, FLOOR_Z], [0.0, 0.0, 3.0], [5.2, 0.0, 0.0], sp.background, &wall, 0);
    // side walls, so that the oblique views see a backdrop everywhere
    let side = 1.2 + WALL_Y;
    b.rect([2.6, WALL_Y - side, FLOOR_Z], [0.0, 0.0, 3.0], [0.0, side, 0.0], sp.background, &wall, 0);
    b.rect([-2.6, WALL_Y - side, FLOOR_Z], [0.0, side, 0.0], [0.0, 0.0, 3.0], sp.background, &wall, 0);
    b.opacity = old_opacity;
    table(b, sp, seed);
}

/// The checkerboard floor out to [`FLOOR_REACH`] (a square, then square rings each
/// twice as wide and twice as coarsely sampled: the sampling follows what a pixel
/// covers at that distance) and a sky dome of radius [`SKY_RADIUS`] (label 0).
fn open_surroundings(b: &mut Builder, sp: &Spacing, floor: crate::build::Texture) {
    b.view_dependence = 0.015;
    let (mut inner, mut spacing) = (2.6f32, sp.background);
    b.rect([-inner, -inner, FLOOR_Z], [2.0 * inner, 0.0, 0.0], [0.0, 2.0 * inner, 0.0], spacing, floor, 0);
    while inner < FLOOR_REACH {
        let (outer, width) = (2.0 * inner, inner);
        spacing *= 2.0;
        let along_x = [2.0 * outer, 0.0, 0.0];
        b.rect([-outer, -outer, FLOOR_Z], along_x, [0.0, width, 0.0], spacing, floor, 0);
        b.rect([-outer, inner, FLOOR_Z], along_x, [0.0, width, 0.0], spacing, floor, 0);
        let along_y = [0.0, 2.0 * inner, 0.0];
        b.rect([-outer, -inner, FLOOR_Z], [width, 0.0, 0.0], along_y, spacing, floor, 0);
        b.rect([inner, -inner, FLOOR_Z], [width, 0.0, 0.0], along_y, spacing, floor, 0);
        inner = outer;
    }
    // Pale at the horizon, deeper blue overhead; a grey haze below the floor's edge.
    let sky = |p: [f32; 3]| {
        let up = (p[2] - FLOOR_Z) / SKY_RADIUS;
        if up < 0.0 {
            [0.62, 0.63, 0.6]
        } else {
            mix_rgb([0.8, 0.86, 0.92], [0.33, 0.52, 0.84], up.sqrt())
        }
    };
    b.view_dependence = 0.0;
    b.sphere([0.0, 0.0, FLOOR_Z], SKY_RADIUS, 20.0 * sp.background, &sky, 0);
}

/// The table on its four legs (label 0).
fn table(b: &mut Builder, sp: &Spacing, seed: u64) {
    let top = move |p: [f32; 3]| shade([0.58, 0.37, 0.2], wood_grain(seed ^ 3, p, 0.05));
    let leg = move |p: [f32; 3]| shade([0.4, 0.25, 0.13], wood_grain(seed ^ 4, [p[2], p[1], p[0]], 0.03));
    let old_opacity = b.opacity;
    b.view_dependence = 0.03;
    let [hx, hy] = TABLE_HALF;
    b.cuboid([0.0, 0.0, -TABLE_THICK / 2.0], [hx, hy, TABLE_THICK / 2.0], sp.table, &top, 0, false);
    let leg_h = (-TABLE_THICK - FLOOR_Z) / 2.0;
    for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        let c = [sx * (hx - 0.07), sy * (hy - 0.07), FLOOR_Z + leg_h];
        b.cuboid(c, [0.035, 0.035, leg_h], sp.table, &leg, 0, true);
    }
    b.opacity = old_opacity;
}

fn object(
    name: &str,
    label: u32,
    colour: &str,
    base_rgb: [f32; 3],
    shape: &str,
    centre: [f32; 3],
) -> SceneObject {
    SceneObject { name: name.into(), label, colour: colour.into(), base_rgb, shape: shape.into(), centre }
}

fn finish(
    name: &str,
    description: &str,
    target: &str,
    b: Builder,
    mut objects: Vec<SceneObject>,
    config: &SceneConfig,
    rig: Rig,
) -> Scene {
    // centres from the Gaussians themselves (bounding-box centre per label)
    for o in objects.iter_mut() {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for (p, &l) in b.g.means.iter().zip(&b.labels) {
            if l == o.label {
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
            }
        }
        if lo[0].is_finite() {
            o.centre = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
        }
    }
    Scene {
        name: name.into(),
        description: description.into(),
        gaussians: b.g,
        labels: b.labels,
        objects,
        // Open surroundings: a full orbit, lower, so the far floor and the sky fill the views.
        cameras: if config.open {
            Rig { azimuth_span_deg: 360.0, elevations_deg: vec![6.0, 15.0, 26.0], ..rig }
        } else {
            rig
        }
        .cameras(config.views, config.width, config.height),
        target: target.into(),
        background: [0.0; 3],
        config: config.clone(),
    }
}

fn default_rig() -> Rig {
    Rig {
        target: [0.0, 0.0, 0.1],
        distance: 2.3,
        elevations_deg: vec![20.0, 32.0, 45.0],
        azimuth_span_deg: 120.0,
        fov_x_deg: 50.0,
    }
}

fn lum_noise(seed: u64, p: [f32; 3], freq: f32, amount: f32) -> f32 {
    1.0 - amount + 2.0 * amount * fbm(seed, p.map(|v| v * freq), 3)
}

/// Textures of the objects, shared by the scenes.
struct Looks;

impl Looks {
    fn ball(seed: u64, centre: [f32; 3], rgb: [f32; 3]) -> impl Fn([f32; 3]) -> [f32; 3] {
        move |p| {
            // speckles plus two darker seams (a tennis-ball-like curve)
            let d = crate::build::normalize(crate::build::sub(p, centre));
            let seam = ((d[0] * 3.0).sin() * 0.4 - d[2]).abs() < 0.06;
            let f = lum_noise(seed, p, 30.0, 0.15) * if seam { 0.7 } else { 1.0 };
            shade(rgb, f)
        }
    }
    fn crate_(seed: u64, centre: [f32; 3], half: f32, rgb: [f32; 3]) -> impl Fn([f32; 3]) -> [f32; 3] {
        move |p| {
            // planks: dark gaps every quarter of the height, grain along them
            let rel = (p[2] - (centre[2] - half)) / (2.0 * half);
            let gap = (rel * 4.0).fract();
            let g = if !(0.06..=0.94).contains(&gap) { 0.6 } else { 1.0 };
            shade(rgb, g * wood_grain(seed, [p[2] * 0.2, p[0], p[1]], 0.02))
        }
    }
    fn vase(seed: u64, rgb: [f32; 3]) -> impl Fn([f32; 3]) -> [f32; 3] {
        move |p| {
            let band = 0.8 + 0.3 * (p[2] * 60.0).sin().max(0.0);
            shade(rgb, band * lum_noise(seed, p, 25.0, 0.08))
        }
    }
    fn cone(seed: u64, centre: [f32; 3], rgb: [f32; 3]) -> impl Fn([f32; 3]) -> [f32; 3] {
        move |p| {
            let phi = (p[1] - centre[1]).atan2(p[0] - centre[0]);
            let spiral = ((phi * 3.0 + p[2] * 40.0).sin() > 0.0) as i32 as f32;
            shade(rgb, (0.78 + 0.35 * spiral) * lum_noise(seed, p, 20.0, 0.06))
        }
    }
    fn stem(seed: u64, rgb: [f32; 3]) -> impl Fn([f32; 3]) -> [f32; 3] {
        move |p| shade(rgb, lum_noise(seed, [p[0], p[1], p[2] * 4.0], 20.0, 0.2))
    }
}

/// `tabletop`: ball, crate, vase, cone.
fn tabletop(config: &SceneConfig) -> Scene {
    let seed = config.seed;
    let sp = Spacing::new(config.detail);
    let mut b = Builder::new(seed);
    background(&mut b, &sp, seed, config.open);

    let ball_c = [-0.42, 0.05, 0.15];
    let ball_rgb = [0.85, 0.16, 0.12];
    b.sphere(ball_c, 0.15, sp.object, &Looks::ball(seed ^ 11, ball_c, ball_rgb), 1);

    let crate_half = 0.13;
    let crate_c = [0.02, 0.2, crate_half];
    let crate_rgb = [0.76, 0.58, 0.33];
    let tex = Looks::crate_(seed ^ 12, crate_c, crate_half, crate_rgb);
    b.cuboid(crate_c, [crate_half; 3], sp.object, &tex, 2, true);

    let vase_base = [0.44, -0.02, 0.0];
    let vase_rgb = [0.16, 0.32, 0.82];
    let profile = [
        (0.07, 0.0),
        (0.11, 0.06),
        (0.12, 0.13),
        (0.09, 0.22),
        (0.05, 0.3),
        (0.055, 0.36),
        (0.065, 0.38),
        (0.0, 0.372),
    ];
    let tex = Looks::vase(seed ^ 13, vase_rgb);
    b.revolution(vase_base, &profile, sp.object, &tex, 3);

    let cone_base = [0.02, -0.28, 0.0];
    let cone_rgb = [0.22, 0.66, 0.25];
    let tex = Looks::cone(seed ^ 14, cone_base, cone_rgb);
    b.revolution(cone_base, &[(0.09, 0.0), (0.0, 0.24)], sp.object, &tex, 4);

    let objects = vec![
        object("ball", 1, "red", ball_rgb, "sphere", ball_c),
        object("crate", 2, "light wood brown", crate_rgb, "box", crate_c),
        object("vase", 3, "blue", vase_rgb, "surface of revolution", vase_base),
        object("cone", 4, "green", cone_rgb, "cone", cone_base),
    ];
    finish(
        "tabletop",
        "a red ball, a wooden crate, a blue vase and a green cone on a wood-grain table in front of a \
         striped wallpaper backdrop, on a tiled floor",
        "ball",
        b,
        objects,
        config,
        default_rig(),
    )
}

/// `occluded`: a crate in front of a partly hidden ball, and a thin stem.
fn occluded(config: &SceneConfig) -> Scene {
    let seed = config.seed.wrapping_add(0x0CC1);
    let sp = Spacing::new(config.detail);
    let mut b = Builder::new(seed);
    background(&mut b, &sp, seed, config.open);

    let crate_half = 0.14;
    let crate_c = [-0.05, -0.08, crate_half];
    let crate_rgb = [0.7, 0.52, 0.3];
    let tex = Looks::crate_(seed ^ 21, crate_c, crate_half, crate_rgb);
    b.cuboid(crate_c, [crate_half; 3], sp.object, &tex, 1, true);

    let ball_c = [0.1, 0.26, 0.14];
    let ball_rgb = [0.88, 0.2, 0.14];
    b.sphere(ball_c, 0.14, sp.object, &Looks::ball(seed ^ 22, ball_c, ball_rgb), 2);

    // thin stem: radius 12 mm, finer sampling so it stays a closed tube
    let stem_base = [0.42, 0.0, 0.0];
    let stem_rgb = [0.85, 0.75, 0.15];
    let tex = Looks::stem(seed ^ 23, stem_rgb);
    let fine = (sp.object * 0.6).min(0.012);
    b.revolution(stem_base, &[(0.012, 0.0), (0.012, 0.5), (0.0, 0.5)], fine, &tex, 3);
    b.sphere([stem_base[0], stem_base[1], 0.52], 0.03, fine, &tex, 3);

    let objects = vec![
        object("crate", 1, "light wood brown", crate_rgb, "box", crate_c),
        object("ball", 2, "red", ball_rgb, "sphere", ball_c),
        object("stem", 3, "yellow", stem_rgb, "thin pole", stem_base),
    ];
    finish(
        "occluded",
        "a red ball half hidden behind a wooden crate, and a thin yellow stem, on a wood-grain table in \
         front of a striped wallpaper backdrop",
        "ball",
        b,
        objects,
        config,
        default_rig(),
    )
}

/// Half extent of the garden's lawn in x, its y range, and the backdrop height.
const GARDEN_HALF_X: f32 = 4.5;
const GARDEN_Y: [f32; 2] = [-4.5, 3.5];
const GARDEN_WALL_H: f32 = 3.5;

/// The garden's background (label 0): the lawn with a gravel path, and a U of hedge
/// and sky walls. Its Gaussians are sparser than the tabletop background's (1.45× and
/// 2.2× the spacing) so that the much larger area keeps a comparable count.
fn garden_background(b: &mut Builder, sp: &Spacing, seed: u64) {
    let lawn = move |p: [f32; 3]| {
        let path = (p[1] + 1.45 + 0.15 * (p[0] * 1.3).sin()).abs() < 0.28;
        if path {
            shade([0.62, 0.57, 0.47], 0.8 + 0.4 * fbm(seed ^ 5, [p[0] * 9.0, p[1] * 9.0, 0.0], 3))
        } else {
            let base = mix_rgb([0.24, 0.42, 0.14], [0.38, 0.53, 0.2], fbm(seed ^ 6, [p[0], p[1], 0.0], 3));
            shade(base, 0.8 + 0.4 * fbm(seed ^ 7, [p[0] * 7.0, p[1] * 7.0, 0.0], 2))
        }
    };
    let backdrop = move |p: [f32; 3]| {
        // a hedge up to about 1.6 m with a ragged top, sky above it
        let top = 1.6 + 0.25 * fbm(seed ^ 8, [p[0] * 1.5, p[1] * 1.5, 0.0], 3);
        if p[2] < top {
            shade([0.13, 0.3, 0.11], 0.7 + 0.6 * fbm(seed ^ 9, [p[0] * 5.0, p[1] * 5.0, p[2] * 5.0], 3))
        } else {
            let t = ((p[2] - top) / (GARDEN_WALL_H - top)).clamp(0.0, 1.0);
            let sky = mix_rgb([0.68, 0.79, 0.92], [0.42, 0.58, 0.86], t);
            let cloud = fbm(seed ^ 10, [p[0] * 0.8, p[1] * 0.8, p[2] * 2.0], 3);
            mix_rgb(sky, [0.93, 0.94, 0.95], (cloud - 0.55).max(0.0) * 2.0)
        }
    };
    let (ground, wall) = (1.45 * sp.background, 2.2 * sp.background);
    let (hx, [y0, y1], h) = (GARDEN_HALF_X, GARDEN_Y, GARDEN_WALL_H);
    let old_opacity = b.opacity;
    b.view_dependence = 0.015;
    b.rect([-hx, y0, 0.0], [2.0 * hx, 0.0, 0.0], [0.0, y1 - y0, 0.0], ground, &lawn, 0);
    b.rect([-hx, y1, 0.0], [0.0, 0.0, h], [2.0 * hx, 0.0, 0.0], wall, &backdrop, 0);
    b.rect([hx, y0, 0.0], [0.0, 0.0, h], [0.0, y1 - y0, 0.0], wall, &backdrop, 0);
    b.rect([-hx, y0, 0.0], [0.0, y1 - y0, 0.0], [0.0, 0.0, h], wall, &backdrop, 0);
    b.view_dependence = 0.03;
    b.opacity = old_opacity;
}

fn garden_rig() -> Rig {
    Rig {
        target: [0.0, 0.05, 0.3],
        distance: 3.4,
        elevations_deg: vec![12.0, 24.0, 36.0],
        azimuth_span_deg: 150.0,
        fov_x_deg: 55.0,
    }
}

/// `garden`: apple, tomato (the look-alike), lamp post, fence.
fn garden(config: &SceneConfig) -> Scene {
    let seed = config.seed.wrapping_add(0x6A4D);
    let sp = Spacing::new(config.detail);
    let mut b = Builder::new(seed);
    garden_background(&mut b, &sp, seed);

    let apple_c = [-0.32, -0.08, 0.13];
    let apple_rgb = [0.8, 0.12, 0.1];
    let apple = move |p: [f32; 3]| {
        // faint vertical streaks around the axis, fine speckle
        let phi = (p[1] - apple_c[1]).atan2(p[0] - apple_c[0]);
        shade(apple_rgb, (0.95 + 0.05 * (phi * 9.0).sin()) * lum_noise(seed ^ 31, p, 28.0, 0.1))
    };
    b.sphere(apple_c, 0.13, sp.object, &apple, 1);

    let tomato_c = [0.24, -0.3, 0.095];
    let tomato_rgb = [0.92, 0.3, 0.1];
    let tomato = move |p: [f32; 3]| shade(tomato_rgb, lum_noise(seed ^ 32, p, 22.0, 0.08));
    b.sphere(tomato_c, 0.095, sp.object, &tomato, 2);

    // lamp post: a 18 mm radius iron pole on a foot, a glass head; finer sampling
    let lamp_base = [0.8, 0.35, 0.0];
    let (iron, glass) = ([0.16, 0.17, 0.16], [0.95, 0.88, 0.55]);
    let lamp = move |p: [f32; 3]| {
        let c = if p[2] > 1.19 { glass } else { iron };
        shade(c, lum_noise(seed ^ 33, [p[0], p[1], p[2] * 3.0], 20.0, 0.1))
    };
    let fine = (sp.object * 0.6).min(0.012);
    let profile = [(0.05, 0.0), (0.05, 0.06), (0.018, 0.09), (0.018, 1.2), (0.0, 1.2)];
    b.revolution(lamp_base, &profile, fine, &lamp, 3);
    b.sphere([lamp_base[0], lamp_base[1], 1.26], 0.07, fine, &lamp, 3);

    // fence: two 25 mm rails on three posts, behind the fruit
    let fence_rgb = [0.9, 0.89, 0.84];
    let fence =
        move |p: [f32; 3]| shade(fence_rgb, lum_noise(seed ^ 34, [p[0] * 3.0, p[1], p[2]], 15.0, 0.08));
    let rail = sp.object.min(0.02);
    let fence_y = 0.8;
    for z in [0.22, 0.45] {
        b.cuboid([0.0, fence_y, z], [0.9, 0.0125, 0.0125], rail, &fence, 4, false);
    }
    for x in [-0.85, 0.0, 0.85] {
        b.cuboid([x, fence_y, 0.28], [0.02, 0.02, 0.28], rail, &fence, 4, true);
    }

    let objects = vec![
        object("apple", 1, "red", apple_rgb, "sphere", apple_c),
        object("tomato", 2, "orange-red", tomato_rgb, "sphere", tomato_c),
        object("lamp", 3, "black iron with a yellow glass head", iron, "thin pole", lamp_base),
        object("fence", 4, "white", fence_rgb, "thin rails on posts", [0.0, fence_y, 0.28]),
    ];
    finish(
        "garden",
        "a red apple, an orange-red tomato, a thin lamp post and a white rail fence on a wide lawn with a \
         gravel path, in front of a far hedge and sky",
        "apple",
        b,
        objects,
        config,
        garden_rig(),
    )
}

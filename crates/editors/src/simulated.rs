//! The simulated editor: ground-truth edits of a built-in scene, corrupted per view the
//! way 2D editors fail, at a chosen severity. It exists to measure leakage and
//! consistency against ground truth; it is not a substitute for a real editor.
//!
//! **Instructions** name exactly one of the scene's objects (whole words,
//! case-insensitive, plurals accepted: "balls") and one colour ([`COLOURS`]) or one
//! material ([`Material`]): "make the ball blue", "paint the vase red", "turn the crate
//! into marble", "make the ball look like gold". A colour or material word directly in
//! front of an object name describes it and is ignored when another one names the
//! change ("turn the red ball blue"), and is the change otherwise ("a grey vase").
//! A colour becomes [`transsplat_scenes::recolor`], a material
//! [`transsplat_scenes::retexture`].
//!
//! **Corruption model** (severity s ≥ 0; s = 0 returns the ground-truth render exactly,
//! s = 1 is meant to look like a typical InstructPix2Pix run). D is the image diagonal,
//! m the target's blend weight per pixel, c_e the edit's mean colour. Every random draw
//! comes from a generator seeded by (seed, view index), so the result does not depend
//! on the order or number of views.
//!
//! 1. Colour inconsistency inside the target: a per-view gain 1 + 0.12 s·N(0,1) and
//!    offset 0.05 s·N(0,1) per channel, applied in proportion to m. The view's edit
//!    colour c_v = gain·c_e + offset is used by the spill and the blobs below.
//! 2. Spill: around the target mask, within a ring of radius ρ = s·U(0.02, 0.08)·D
//!    (at most 0.3 D), the colour bleeds towards c_v with strength
//!    β·(1 − d/ρ)², β = min(0.9, s·U(0.25, 0.5)), d the distance to the mask.
//! 3. Spurious blobs: ⌊U·(3s + 1)⌋ (at most 8) Gaussian blobs of radius
//!    U(0.02, 0.05)·D centred outside the target and its spill ring, blending towards
//!    c_v with peak strength min(1, s·U(0.35, 0.7)).
//! 4. Attention: max(m, spill, blobs), blurred with σ = 0.01 s·D, times
//!    (1 + 0.25 s·n₁) plus 0.04 s·max(n₂, 0), clamped at 0; n₁, n₂ are smooth unit
//!    noise fields (white noise blurred at σ = 2 px, renormalised).
//!
//! No mask is returned unless [`SimulatedEditor::with_mask`] asks for one: a SAM-like
//! mask, the target's pixel mask dilated by max(1, 0.01 D) px.
//!
//! After [`Editor::edit`] the ground truth is available for evaluation:
//! [`SimulatedEditor::ground_truth`], [`SimulatedEditor::target_label`],
//! [`SimulatedEditor::describe`].

use crate::features::gaussian_blur;
use crate::{EditedView, Editor, Error, SourceView};
use rayon::prelude::*;
use transsplat_scene::rng::SplitMix64;
use transsplat_scene::Gaussians;
use transsplat_scenes::{edit::dc_colour, render_labels, Material, Scene};

/// Named colours of instructions, sRGB in [0, 1].
pub const COLOURS: &[(&str, [f32; 3])] = &[
    ("red", [0.85, 0.10, 0.10]),
    ("green", [0.10, 0.65, 0.20]),
    ("blue", [0.10, 0.20, 0.90]),
    ("yellow", [0.95, 0.85, 0.10]),
    ("orange", [1.00, 0.50, 0.05]),
    ("purple", [0.50, 0.15, 0.70]),
    ("violet", [0.55, 0.35, 0.90]),
    ("pink", [1.00, 0.50, 0.70]),
    ("magenta", [0.85, 0.10, 0.75]),
    ("cyan", [0.10, 0.80, 0.85]),
    ("teal", [0.00, 0.50, 0.50]),
    ("navy", [0.05, 0.10, 0.40]),
    ("brown", [0.45, 0.27, 0.10]),
    ("white", [0.95, 0.95, 0.95]),
    ("black", [0.05, 0.05, 0.05]),
    ("grey", [0.50, 0.50, 0.50]),
    ("gray", [0.50, 0.50, 0.50]),
    ("silver", [0.75, 0.75, 0.78]),
];

/// The colour called `name` (case-insensitive).
pub fn colour_from_name(name: &str) -> Option<[f32; 3]> {
    let n = name.trim().to_ascii_lowercase();
    COLOURS.iter().find(|(c, _)| *c == n).map(|(_, rgb)| *rgb)
}

/// What an instruction asks for.
#[derive(Clone, Debug, PartialEq)]
pub enum EditKind {
    /// A new colour: its name and sRGB value.
    Recolor { colour: String, rgb: [f32; 3] },
    /// A new material.
    Retexture(Material),
}

/// A parsed instruction.
#[derive(Clone, Debug, PartialEq)]
pub struct Instruction {
    /// The target object's name and label.
    pub object: String,
    pub label: u32,
    pub kind: EditKind,
}

impl Instruction {
    /// "recolor ball to blue (0.10, 0.20, 0.90)" or "retexture crate with marble".
    pub fn describe(&self) -> String {
        match &self.kind {
            EditKind::Recolor { colour, rgb } => {
                format!("recolor {} to {colour} ({:.2}, {:.2}, {:.2})", self.object, rgb[0], rgb[1], rgb[2])
            }
            EditKind::Retexture(m) => format!("retexture {} with {}", self.object, m.name()),
        }
    }
}

fn words(s: &str) -> Vec<String> {
    s.split(|c: char| !c.is_alphanumeric()).filter(|w| !w.is_empty()).map(|w| w.to_lowercase()).collect()
}

/// True if `word` is `name` or a plural of it.
fn matches_noun(word: &str, name: &str) -> bool {
    if word == name {
        return true;
    }
    let plural = |suffix: &str| word.strip_suffix(suffix) == Some(name);
    plural("s")
        || plural("es")
        || (name.ends_with('y') && word.strip_suffix("ies") == Some(&name[..name.len() - 1]))
}

/// Parses `prompt` over `scene`'s objects (see the module doc).
pub fn parse_instruction(scene: &Scene, prompt: &str) -> Result<Instruction, Error> {
    let tokens = words(prompt);
    if tokens.is_empty() {
        return Err(Error::Instruction("empty instruction".into()));
    }
    let objects = scene.objects.iter().map(|o| o.name.as_str()).collect::<Vec<_>>().join(", ");
    // object mentions: (object index, first token, one past the last token)
    let mut mentions = Vec::new();
    for (k, o) in scene.objects.iter().enumerate() {
        let name = words(&o.name);
        if name.is_empty() || name.len() > tokens.len() {
            continue;
        }
        for s in 0..=tokens.len() - name.len() {
            let last = name.len() - 1;
            let hit =
                (0..last).all(|j| tokens[s + j] == name[j]) && matches_noun(&tokens[s + last], &name[last]);
            if hit {
                mentions.push((k, s, s + name.len()));
            }
        }
    }
    let mut named: Vec<usize> = mentions.iter().map(|m| m.0).collect();
    named.sort_unstable();
    named.dedup();
    let object = match named[..] {
        [k] => &scene.objects[k],
        [] => {
            return Err(Error::Instruction(format!(
                "the instruction {prompt:?} names none of the scene's objects ({objects})"
            )))
        }
        _ => {
            let names: Vec<&str> = named.iter().map(|&k| scene.objects[k].name.as_str()).collect();
            return Err(Error::Instruction(format!(
                "the instruction {prompt:?} names several objects ({}); name exactly one",
                names.join(", ")
            )));
        }
    };
    // modifiers: (word, edit, directly in front of an object name)
    let mut found: Vec<(String, EditKind, bool)> = Vec::new();
    for (j, t) in tokens.iter().enumerate() {
        if mentions.iter().any(|&(_, s, e)| (s..e).contains(&j)) {
            continue;
        }
        let adjective = mentions.iter().any(|&(_, s, _)| s == j + 1);
        let kind = if let Some(rgb) = colour_from_name(t) {
            EditKind::Recolor { colour: t.clone(), rgb }
        } else if let Some(m) = Material::from_name(t) {
            EditKind::Retexture(m)
        } else {
            continue;
        };
        found.push((t.clone(), kind, adjective));
    }
    // adjectives describe the object as it is, unless nothing else names a change
    let any_free = found.iter().any(|f| !f.2);
    let mut kinds: Vec<(String, EditKind)> = Vec::new();
    for (word, kind, adjective) in found {
        if (!adjective || !any_free) && !kinds.iter().any(|(_, k)| *k == kind) {
            kinds.push((word, kind));
        }
    }
    match kinds.len() {
        1 => Ok(Instruction { object: object.name.clone(), label: object.label, kind: kinds.remove(0).1 }),
        0 => {
            let colours: Vec<&str> = COLOURS.iter().map(|c| c.0).collect();
            let materials: Vec<&str> = Material::ALL.iter().map(|m| m.name()).collect();
            Err(Error::Instruction(format!(
                "the instruction {prompt:?} names the {} but no colour or material; colours: {}; materials: {}",
                object.name,
                colours.join(", "),
                materials.join(", ")
            )))
        }
        _ => {
            let names: Vec<&str> = kinds.iter().map(|k| k.0.as_str()).collect();
            Err(Error::Instruction(format!(
                "the instruction {prompt:?} asks for several changes ({}); give one colour or material",
                names.join(", ")
            )))
        }
    }
}

/// The per-view generator: SplitMix64 seeded by (seed, view index).
fn view_rng(seed: u64, index: usize) -> SplitMix64 {
    let mut r = SplitMix64::new(seed ^ (index as u64).wrapping_add(1).wrapping_mul(0xD1B5_4A32_D192_ED03));
    r.next_u64();
    r
}

/// Squared Euclidean distance transform of one line (Felzenszwalb & Huttenlocher):
/// `d[q] = min_p (q − p)² + f[p]`.
fn edt_line(f: &[f64], d: &mut [f64]) {
    let n = f.len();
    if n == 0 {
        return;
    }
    let mut v = vec![0usize; n];
    let mut z = vec![0.0f64; n + 1];
    let mut k = 0usize;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    let inter = |q: usize, p: usize| {
        ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * q as f64 - 2.0 * p as f64)
    };
    for q in 1..n {
        let mut s = inter(q, v[k]);
        while s <= z[k] {
            k -= 1;
            s = inter(q, v[k]);
        }
        k += 1;
        v[k] = q;
        z[k] = s;
        z[k + 1] = f64::INFINITY;
    }
    k = 0;
    for (q, dq) in d.iter_mut().enumerate() {
        while z[k + 1] < q as f64 {
            k += 1;
        }
        let p = v[k];
        *dq = (q as f64 - p as f64).powi(2) + f[p];
    }
}

/// Euclidean distance (pixels) from every pixel to the nearest `true` of `mask`;
/// `None` when the mask is empty.
pub fn distance_to(mask: &[bool], w: usize, h: usize) -> Option<Vec<f32>> {
    if !mask.iter().any(|&m| m) {
        return None;
    }
    const FAR: f64 = 1e18;
    let mut g: Vec<f64> = mask.iter().map(|&m| if m { 0.0 } else { FAR }).collect();
    let mut line = vec![0.0f64; w.max(h)];
    let mut out = vec![0.0f64; w.max(h)];
    for y in 0..h {
        line[..w].copy_from_slice(&g[y * w..(y + 1) * w]);
        edt_line(&line[..w], &mut out[..w]);
        g[y * w..(y + 1) * w].copy_from_slice(&out[..w]);
    }
    for x in 0..w {
        for y in 0..h {
            line[y] = g[y * w + x];
        }
        edt_line(&line[..h], &mut out[..h]);
        for y in 0..h {
            g[y * w + x] = out[y];
        }
    }
    Some(g.into_iter().map(|v| v.min(FAR).sqrt() as f32).collect())
}

/// A smooth noise field with zero mean and unit standard deviation.
fn smooth_noise(rng: &mut SplitMix64, w: usize, h: usize) -> Vec<f32> {
    let white: Vec<f32> = (0..w * h).map(|_| rng.normal()).collect();
    let mut n = gaussian_blur(&white, w, h, 2.0);
    let len = n.len().max(1) as f64;
    let mean = n.iter().map(|&v| v as f64).sum::<f64>() / len;
    let var = n.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / len;
    let sd = var.sqrt().max(1e-9);
    for v in n.iter_mut() {
        *v = ((*v as f64 - mean) / sd) as f32;
    }
    n
}

/// The corrupted output of one view before features are added.
struct Corrupted {
    image: Vec<f32>,
    attention: Vec<f32>,
    mask: Option<Vec<f32>>,
}

/// Applies the corruption model of the module doc to one ground-truth render.
/// `weight`: the target's blend weight per pixel; `target`: its pixel mask.
#[allow(clippy::too_many_arguments)]
fn corrupt(
    gt: &[f32],
    weight: &[f32],
    target: &[bool],
    w: usize,
    h: usize,
    edit_colour: [f32; 3],
    severity: f32,
    rng: &mut SplitMix64,
    want_mask: bool,
) -> Corrupted {
    let n = w * h;
    let s = severity.max(0.0);
    let diag = ((w * w + h * h) as f32).sqrt();
    let m: Vec<f32> = weight.iter().map(|v| v.clamp(0.0, 1.0)).collect();
    let dist = distance_to(target, w, h);
    let mask = want_mask.then(|| {
        let r = (0.01 * diag).round().max(1.0);
        match &dist {
            Some(d) => d.iter().map(|&d| if d <= r { 1.0 } else { 0.0 }).collect(),
            None => vec![0.0; n],
        }
    });
    if s == 0.0 {
        return Corrupted { image: gt.to_vec(), attention: m, mask };
    }

    // 1. per-view colour inconsistency
    let gain: [f32; 3] = std::array::from_fn(|_| (1.0 + 0.12 * s * rng.normal()).max(0.0));
    let offset: [f32; 3] = std::array::from_fn(|_| 0.05 * s * rng.normal());
    let cv: [f32; 3] = std::array::from_fn(|c| (gain[c] * edit_colour[c] + offset[c]).clamp(0.0, 1.0));
    let mut img = gt.to_vec();
    for (px, &mi) in img.chunks_exact_mut(3).zip(&m) {
        if mi > 0.0 {
            for c in 0..3 {
                px[c] = (px[c] + mi * (px[c] * (gain[c] - 1.0) + offset[c])).clamp(0.0, 1.0);
            }
        }
    }

    // 2. spill around the target
    let rho = (s * rng.range(0.02, 0.08) * diag).min(0.3 * diag);
    let beta = (s * rng.range(0.25, 0.5)).min(0.9);
    let mut spill = vec![0.0f32; n];
    if let Some(d) = &dist {
        if rho >= 0.5 {
            for (sp, &di) in spill.iter_mut().zip(d) {
                if di < rho {
                    *sp = beta * (1.0 - di / rho).powi(2);
                }
            }
        }
    }

    // 3. spurious blobs outside the target and its spill ring
    let count = ((rng.uniform() * (3.0 * s + 1.0)).floor() as usize).min(8);
    let mut blobs = vec![0.0f32; n];
    for _ in 0..count {
        let r = rng.range(0.02, 0.05) * diag;
        let strength = (s * rng.range(0.35, 0.7)).min(1.0);
        let mut centre = None;
        for _ in 0..20 {
            let (x, y) = (rng.uniform() * w as f32, rng.uniform() * h as f32);
            let i = (y as usize).min(h - 1) * w + (x as usize).min(w - 1);
            let clear = match &dist {
                Some(d) => d[i] > rho.max(1.0) + r,
                None => true,
            };
            if clear {
                centre = Some((x, y));
                break;
            }
        }
        let Some((cx, cy)) = centre else { continue };
        let reach = 3.0 * r;
        let (x0, x1) =
            ((cx - reach).floor().max(0.0) as usize, ((cx + reach).ceil().max(0.0) as usize).min(w));
        let (y0, y1) =
            ((cy - reach).floor().max(0.0) as usize, ((cy + reach).ceil().max(0.0) as usize).min(h));
        for y in y0..y1 {
            for x in x0..x1 {
                let (dx, dy) = (x as f32 + 0.5 - cx, y as f32 + 0.5 - cy);
                let v = strength * (-0.5 * (dx * dx + dy * dy) / (r * r)).exp();
                let b = &mut blobs[y * w + x];
                *b = b.max(v);
            }
        }
    }
    for (i, px) in img.chunks_exact_mut(3).enumerate() {
        let t = spill[i].max(blobs[i]) * (1.0 - m[i]);
        if t > 0.0 {
            for c in 0..3 {
                px[c] += t * (cv[c] - px[c]);
            }
        }
    }

    // 4. noisy attention
    let base: Vec<f32> = (0..n).map(|i| m[i].max(spill[i]).max(blobs[i])).collect();
    let sigma = 0.01 * s * diag;
    let blurred = if sigma >= 0.3 { gaussian_blur(&base, w, h, sigma) } else { base };
    let n1 = smooth_noise(rng, w, h);
    let n2 = smooth_noise(rng, w, h);
    let attention = (0..n)
        .map(|i| (blurred[i] * (1.0 + 0.25 * s * n1[i]) + 0.04 * s * n2[i].max(0.0)).max(0.0))
        .collect();
    Corrupted { image: img, attention, mask }
}

/// The simulated editor of a built-in scene (see the module doc).
#[derive(Clone, Debug)]
pub struct SimulatedEditor {
    scene: Scene,
    severity: f32,
    seed: u64,
    want_mask: bool,
    /// The last instruction carried out, its ground-truth scene and mean edit colour.
    current: Option<(Instruction, Gaussians, [f32; 3])>,
}

impl SimulatedEditor {
    /// An editor over `scene` at `severity` (0 = the ground truth; 1 = typical; negative
    /// or NaN is read as 0) seeded by `seed`.
    pub fn new(scene: &Scene, severity: f32, seed: u64) -> Self {
        let severity = if severity.is_finite() { severity.max(0.0) } else { 0.0 };
        SimulatedEditor { scene: scene.clone(), severity, seed, want_mask: false, current: None }
    }

    /// Also return a SAM-like mask per view (the target mask slightly dilated).
    pub fn with_mask(mut self, on: bool) -> Self {
        self.want_mask = on;
        self
    }

    pub fn severity(&self) -> f32 {
        self.severity
    }

    /// Parses `prompt` and prepares its ground truth (done by [`Editor::edit`] too);
    /// lets an evaluation read the ground truth before or without editing.
    pub fn instruct(&mut self, prompt: &str) -> Result<&Instruction, Error> {
        let ins = parse_instruction(&self.scene, prompt)?;
        let fresh = self.current.as_ref().map(|c| &c.0) != Some(&ins);
        if fresh {
            let gt = match &ins.kind {
                EditKind::Recolor { rgb, .. } => self.scene.recolor(ins.label, *rgb)?,
                EditKind::Retexture(m) => self.scene.retexture(ins.label, *m)?,
            };
            let mut sum = [0.0f64; 3];
            let mut count = 0usize;
            for (i, &l) in self.scene.labels.iter().enumerate() {
                if l == ins.label && i < gt.len() {
                    let c = dc_colour(&gt, i);
                    for k in 0..3 {
                        sum[k] += c[k].clamp(0.0, 1.0) as f64;
                    }
                    count += 1;
                }
            }
            let mean = sum.map(|v| (v / count.max(1) as f64) as f32);
            self.current = Some((ins, gt, mean));
        }
        Ok(&self.current.as_ref().expect("set above").0)
    }

    /// The ground-truth edited scene of the last instruction (the unedited scene before
    /// any instruction).
    pub fn ground_truth(&self) -> &Gaussians {
        self.current.as_ref().map_or(&self.scene.gaussians, |c| &c.1)
    }

    /// Label of the last instruction's target object (0 before any instruction).
    pub fn target_label(&self) -> u32 {
        self.current.as_ref().map_or(0, |c| c.0.label)
    }

    /// The last instruction in words, e.g. "recolor ball to blue (0.10, 0.20, 0.90)".
    pub fn describe(&self) -> String {
        self.current.as_ref().map_or_else(|| "no instruction yet".into(), |c| c.0.describe())
    }

    /// The scene this editor works on.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }
}

impl Editor for SimulatedEditor {
    fn name(&self) -> &str {
        "simulated"
    }

    fn edit(&mut self, views: &[SourceView], prompt: &str) -> Result<Vec<Option<EditedView>>, Error> {
        for v in views {
            v.check()?;
        }
        self.instruct(prompt)?;
        let (ins, gt, colour) = self.current.as_ref().expect("set by instruct");
        let num_labels = self.scene.num_labels();
        let (seed, severity, want_mask) = (self.seed, self.severity, self.want_mask);
        let scene = &self.scene;
        // views in parallel; each has its own generator, so the order does not matter
        let out: Vec<Option<EditedView>> = views
            .par_iter()
            .map(|v| {
                let (w, h) = v.size();
                let r = render_labels(gt, &scene.labels, num_labels, v.camera, scene.background);
                let target: Vec<bool> = r.labels.iter().map(|&l| l == ins.label).collect();
                let mut rng = view_rng(seed, v.index);
                let weight = r.weight(ins.label);
                let c = corrupt(&r.rgb, &weight, &target, w, h, *colour, severity, &mut rng, want_mask);
                Some(EditedView::new(c.image, w, h, c.attention, c.mask))
            })
            .collect();
        tracing::debug!(
            "simulated editor: {} on {} views at severity {}",
            ins.describe(),
            views.len(),
            self.severity
        );
        Ok(out)
    }
}

#[cfg(test)]
mod tests;

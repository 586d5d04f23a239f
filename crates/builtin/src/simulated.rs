//! The simulated editor: ground-truth edits of a built-in scene, corrupted per view the
//! way 2D editors fail, at a chosen severity. It exists to measure leakage and
//! consistency against ground truth; it is not a substitute for a real editor.
//!
//! **Instructions** name one or more of the scene's objects (whole words,
//! case-insensitive, plurals accepted: "balls") and one colour ([`COLOURS`]) or one
//! material ([`Material`]): "make the ball blue", "paint the vase red", "turn the crate
//! into marble", "make the ball look like gold", "make the ball and the cone blue"
//! (every named object gets the same change). A colour or material word directly in
//! front of an object name describes it and is ignored when another one names the
//! change ("turn the red ball blue"), and is the change otherwise ("a grey vase"). An
//! instruction that names a style ([`Style`]) and no object is a **global edit** of
//! the whole scene, background included: "make it autumn", "give the scene a winter
//! look", "make everything sepia". A colour becomes [`transsplat_builtin::recolor`] of
//! each named object, a material [`transsplat_builtin::retexture`] of each, a style
//! [`transsplat_builtin::restyle`]. An instruction that asks for several changes, names
//! a style together with objects, or names neither an object nor a style is refused.
//!
//! **Target**: the labels the edit changes ([`Instruction::labels`]): the named
//! objects', or every label of the scene (0, the background, included) for a global
//! edit. Per view the target's blend weight is m = min(1, Σ_{l ∈ target} w_l) (w_l the
//! label's rendered blend weight) and its pixel mask the pixels whose label is in the
//! target; for a global edit m = 1 everywhere.
//!
//! **Corruption model** (severity s ≥ 0; s = 0 returns the ground-truth render exactly,
//! s = 1 is meant to look like a typical InstructPix2Pix run). D is the image diagonal,
//! c_e the edit's mean colour (over the target's Gaussians in the ground truth), p a
//! pixel's colour. Every random draw comes from a generator seeded by (seed, view
//! index), so the result does not depend on the order or number of views; the draws
//! are made in a fixed order (gain, offset, hue angle, cast, distractor, wrong object,
//! spill, blobs, noise fields) whether or not they are used.
//!
//! 1. Colour inconsistency inside the target: a per-view gain g = 1 + 0.12 s·N(0,1) and
//!    offset b = 0.05 s·N(0,1) per channel and the hue rotation R of item 8; a pixel
//!    becomes clamp(p + m·(R(g ⊙ p + b) − p), 0, 1). The view's edit colour
//!    c_v = clamp(R(g ⊙ c_e + b), 0, 1) is used by items 2, 3, 5 and 6.
//! 2. Spill: around the target mask, within a ring of radius ρ = s·U(0.02, 0.08)·D
//!    (at most 0.3 D), the colour bleeds towards c_v with strength
//!    β·(1 − d/ρ)², β = min(0.9, s·U(0.25, 0.5)), d the distance to the mask.
//! 3. Spurious blobs: ⌊U·(3s + 1)⌋ (at most 8) Gaussian blobs of radius
//!    U(0.02, 0.05)·D centred outside the target and its spill ring, blending towards
//!    c_v with peak strength min(1, s·U(0.35, 0.7)).
//! 4. Attention: max(m, spill, blobs, distractor), blurred with σ = 0.01 s·D, times
//!    (1 + 0.25 s·n₁) plus 0.04 s·max(n₂, 0), clamped at 0; n₁, n₂ are smooth unit
//!    noise fields (white noise blurred at σ = 2 px, renormalised).
//! 5. Distractor attention: with probability min(1, 0.25 s) the attention also fires on
//!    the distractor, the non-target object whose mean source colour is closest (RGB
//!    distance) to the target's mean source colour: with a = min(0.8, s·U(0.2, 0.4))
//!    and w_d its blend weight, its pixels blend towards c_v with strength a·w_d and
//!    its attention is a·w_d. Spill, blobs and distractor blend as one:
//!    p ← p + max(spill, blobs, a·w_d)·(1 − m)·(c_v − p).
//! 6. Wrong-object view: with probability min(0.4, 0.1 s) the editor misses the target
//!    in this view. With probability ½ it edits another object o instead, drawn
//!    uniformly from the non-target objects: the image is the source render with
//!    p ← p + w_o·(c_v − p) and the attention's base (item 4) is w_o; otherwise (or
//!    when there is no other object) it returns the source render unchanged and the
//!    base is 0, so its attention is item 4's noise only (near zero). Items 1–3 and 5
//!    do not apply to such a view; 4 and 7 do.
//! 7. Global colour cast: every pixel, background included, becomes clamp(k ⊙ p, 0, 1)
//!    with a per-view gain k = 1 + 0.03 s·N(0,1) per channel; attention unchanged.
//! 8. Hue disagreement: R rotates colours by θ = 12°·s·N(0,1) about the grey axis
//!    u = (1, 1, 1)/√3 (Rodrigues: R = cos θ·I + sin θ·[u]× + (1 − cos θ)·u uᵀ), which
//!    keeps a colour's mean (r + g + b)/3 and its distance from the grey axis, and turns
//!    red to green at θ = 120° ([`hue_rotation`]).
//!
//! A global edit gets items 7 and 8 only, on the whole image (nothing lies outside it):
//! p ← clamp(k ⊙ clamp(R p, 0, 1), 0, 1), attention 1 everywhere.
//!
//! No mask is returned unless [`SimulatedEditor::with_mask`] asks for one: a SAM-like
//! mask, the target's pixel mask dilated by max(1, 0.01 D) px.
//!
//! After [`Editor::edit`] the ground truth is available for evaluation:
//! [`SimulatedEditor::ground_truth`], [`SimulatedEditor::target_labels`],
//! [`SimulatedEditor::describe`].

use crate::masks::distance_to;
use crate::{edit::dc_colour, recolor, render_labels, retexture, LabelRender, Material, Scene, Style};
use rayon::prelude::*;
use transsplat_editors::features::gaussian_blur;
use transsplat_editors::{EditedView, Editor, Error, SourceView};
use transsplat_scene::rng::SplitMix64;
use transsplat_scene::Gaussians;

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
    /// A global style of the whole scene.
    Restyle(Style),
}

/// A parsed instruction.
#[derive(Clone, Debug, PartialEq)]
pub struct Instruction {
    /// The named objects, in label order (empty for a global edit).
    pub objects: Vec<String>,
    /// The labels the edit changes: the named objects' labels, or every label of the
    /// scene (the background 0 included) for a global edit; ascending.
    pub labels: Vec<u32>,
    pub kind: EditKind,
}

impl Instruction {
    /// True for a global edit (a style of the whole scene).
    pub fn is_global(&self) -> bool {
        matches!(self.kind, EditKind::Restyle(_))
    }

    /// "recolor ball to blue (0.10, 0.20, 0.90)", "recolor ball and cone to blue (...)",
    /// "retexture crate with marble" or "restyle the whole scene as autumn".
    pub fn describe(&self) -> String {
        let objects = join_and(&self.objects);
        match &self.kind {
            EditKind::Recolor { colour, rgb } => {
                format!("recolor {objects} to {colour} ({:.2}, {:.2}, {:.2})", rgb[0], rgb[1], rgb[2])
            }
            EditKind::Retexture(m) => format!("retexture {objects} with {}", m.name()),
            EditKind::Restyle(s) => format!("restyle the whole scene as {}", s.name()),
        }
    }
}

/// "a", "a and b", "a, b and c".
fn join_and(names: &[String]) -> String {
    match names {
        [] => String::new(),
        [one] => one.clone(),
        [rest @ .., last] => format!("{} and {last}", rest.join(", ")),
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

/// Object mentions in `tokens`: (object index, first token, one past the last token).
fn object_mentions(scene: &Scene, tokens: &[String]) -> Vec<(usize, usize, usize)> {
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
    mentions
}

/// The changes `tokens` ask for, with the word that asks: colours, materials and
/// styles outside the object mentions; a word directly in front of a mention is an
/// adjective and counts only when no other word names a change. Duplicates dropped.
fn changes(tokens: &[String], mentions: &[(usize, usize, usize)]) -> Vec<(String, EditKind)> {
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
        } else if let Some(s) = Style::from_name(t) {
            EditKind::Restyle(s)
        } else {
            continue;
        };
        found.push((t.clone(), kind, adjective));
    }
    let any_free = found.iter().any(|f| !f.2);
    let mut kinds: Vec<(String, EditKind)> = Vec::new();
    for (word, kind, adjective) in found {
        if (!adjective || !any_free) && !kinds.iter().any(|(_, k)| *k == kind) {
            kinds.push((word, kind));
        }
    }
    kinds
}

/// Parses `prompt` over `scene`'s objects (see the module doc).
pub fn parse_instruction(scene: &Scene, prompt: &str) -> Result<Instruction, Error> {
    let tokens = words(prompt);
    if tokens.is_empty() {
        return Err(Error::Instruction("empty instruction".into()));
    }
    let mentions = object_mentions(scene, &tokens);
    let mut named: Vec<usize> = mentions.iter().map(|m| m.0).collect();
    named.sort_unstable();
    named.dedup();
    let names: Vec<String> = named.iter().map(|&k| scene.objects[k].name.clone()).collect();
    let mut kinds = changes(&tokens, &mentions);
    let object_list = scene.objects.iter().map(|o| o.name.as_str()).collect::<Vec<_>>().join(", ");
    let style_list = Style::ALL.map(|s| s.name()).join(", ");
    let names_none = || {
        Error::Instruction(format!(
            "the instruction {prompt:?} names none of the scene's objects ({object_list}) and no style of the \
             whole scene ({style_list})"
        ))
    };
    if kinds.len() > 1 {
        let words: Vec<&str> = kinds.iter().map(|k| k.0.as_str()).collect();
        return Err(Error::Instruction(format!(
            "the instruction {prompt:?} asks for several changes ({}); give one colour, material or style",
            words.join(", ")
        )));
    }
    let Some((word, kind)) = kinds.pop() else {
        if names.is_empty() {
            return Err(names_none());
        }
        let colours: Vec<&str> = COLOURS.iter().map(|c| c.0).collect();
        let materials: Vec<&str> = Material::ALL.iter().map(|m| m.name()).collect();
        return Err(Error::Instruction(format!(
            "the instruction {prompt:?} names the {} but no colour or material; colours: {}; materials: {}",
            join_and(&names),
            colours.join(", "),
            materials.join(", ")
        )));
    };
    match (&kind, names.is_empty()) {
        (EditKind::Restyle(_), true) => {
            Ok(Instruction { objects: Vec::new(), labels: (0..scene.num_labels() as u32).collect(), kind })
        }
        (EditKind::Restyle(_), false) => Err(Error::Instruction(format!(
            "the instruction {prompt:?} asks for the {word} style, which changes the whole scene, and names \
             objects ({}); leave out the objects, or give a colour or material",
            names.join(", ")
        ))),
        (_, true) => Err(names_none()),
        (_, false) => {
            let labels = named.iter().map(|&k| scene.objects[k].label).collect();
            Ok(Instruction { objects: names, labels, kind })
        }
    }
}

/// The per-view generator: SplitMix64 seeded by (seed, view index).
fn view_rng(seed: u64, index: usize) -> SplitMix64 {
    let mut r = SplitMix64::new(seed ^ (index as u64).wrapping_add(1).wrapping_mul(0xD1B5_4A32_D192_ED03));
    r.next_u64();
    r
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

/// The hue rotation by `theta` radians about the grey axis (module doc, item 8):
/// cos θ·I + (1 − cos θ)/3·J + sin θ/√3·[[0, −1, 1], [1, 0, −1], [−1, 1, 0]], J the
/// all-ones matrix. Row-major; rows are the output channels.
pub fn hue_rotation(theta: f32) -> [[f32; 3]; 3] {
    let (c, s) = (theta.cos(), theta.sin());
    let (a, b) = ((1.0 - c) / 3.0, s / 3f32.sqrt());
    [[c + a, a - b, a + b], [a + b, c + a, a - b], [a - b, a + b, c + a]]
}

fn mat_vec(m: &[[f32; 3]; 3], p: [f32; 3]) -> [f32; 3] {
    std::array::from_fn(|r| m[r][0] * p[0] + m[r][1] * p[1] + m[r][2] * p[2])
}

fn clamp01(p: [f32; 3]) -> [f32; 3] {
    p.map(|v| v.clamp(0.0, 1.0))
}

fn rgb(px: &[f32]) -> [f32; 3] {
    [px[0], px[1], px[2]]
}

/// The per-view scalar draws of items 1, 8, 7, 5 and 6 of the module doc, made in this
/// order for every view.
#[derive(Clone, Debug)]
struct Draws {
    gain: [f32; 3],
    offset: [f32; 3],
    /// R, the hue rotation of item 8.
    hue: [[f32; 3]; 3],
    /// k, the colour cast of item 7.
    cast: [f32; 3],
    /// a, the distractor's strength, when its attention fires in this view.
    distractor: Option<f32>,
    /// Set when the editor misses the target in this view (item 6).
    wrong: Option<Wrong>,
}

/// What the editor does instead of the edit in a wrong-object view.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Wrong {
    /// Edits the non-target object with this index in the candidates.
    Other(usize),
    /// Returns the source render unchanged.
    Nothing,
}

fn draw(rng: &mut SplitMix64, s: f32, others: usize) -> Draws {
    let gain = std::array::from_fn(|_| (1.0 + 0.12 * s * rng.normal()).max(0.0));
    let offset = std::array::from_fn(|_| 0.05 * s * rng.normal());
    let hue = hue_rotation((12.0 * s * rng.normal()).to_radians());
    let cast = std::array::from_fn(|_| (1.0 + 0.03 * s * rng.normal()).max(0.0));
    let fires = rng.uniform() < (0.25 * s).min(1.0);
    let strength = (s * rng.range(0.2, 0.4)).min(0.8);
    let misses = rng.uniform() < (0.1 * s).min(0.4);
    let other = rng.uniform() < 0.5;
    let pick = rng.uniform();
    let wrong = misses.then(|| match (other, others) {
        (true, n) if n > 0 => Wrong::Other(((pick * n as f32) as usize).min(n - 1)),
        _ => Wrong::Nothing,
    });
    Draws { gain, offset, hue, cast, distractor: fires.then_some(strength), wrong }
}

/// What the corruption of every view of one edit shares: the module doc's items 1–8 for
/// one target, edit colour and severity. The simulated editor makes one per instruction;
/// a truth that comes from elsewhere (a capture rendered from meshes, with its object
/// labels, `bench quality --captures`) is corrupted by the same model through
/// [`Corruption::edit_view`].
#[derive(Clone, Debug)]
pub struct Corruption {
    /// The target labels.
    pub labels: Vec<u32>,
    /// A global edit (items 7 and 8 only, on the whole image).
    pub global: bool,
    /// c_e, the edit's mean colour.
    pub colour: [f32; 3],
    /// The distractor of item 5, if there is one.
    pub distractor: Option<u32>,
    /// The non-target objects' labels (the candidates of a wrong-object view, item 6).
    pub others: Vec<u32>,
    /// s ≥ 0 (0: the truth exactly).
    pub severity: f32,
    /// Also return the SAM-like mask (the target's pixel mask slightly dilated).
    pub want_mask: bool,
    /// Seeds every view's generator together with the view's index.
    pub seed: u64,
}

impl Corruption {
    /// The corrupted edit of view `index`, whose ground-truth render is `truth` and whose
    /// source render (the editor's input, `H × W × 3`) is `source`; depends on the view's
    /// index and the seed only, not on the order of the calls.
    pub fn edit_view(&self, truth: &LabelRender, source: &[f32], index: usize) -> EditedView {
        let c = corrupt(truth, source, self, &mut view_rng(self.seed, index));
        EditedView::new(c.image, truth.width, truth.height, c.attention, c.mask)
    }
}

/// One view's ground-truth render and its target.
struct ViewTarget<'a> {
    r: &'a LabelRender,
    /// m, the target's blend weight.
    m: Vec<f32>,
    /// Distance (px) to the target's pixel mask; `None` when the target is not seen.
    dist: Option<Vec<f32>>,
    diag: f32,
}

/// The corrupted output of one view before features are added.
struct Corrupted {
    image: Vec<f32>,
    attention: Vec<f32>,
    mask: Option<Vec<f32>>,
}

/// Applies the corruption model of the module doc to the ground-truth render `r` of
/// one view whose source render (the editor's input) is `source`.
fn corrupt(r: &LabelRender, source: &[f32], set: &Corruption, rng: &mut SplitMix64) -> Corrupted {
    let (w, h) = (r.width, r.height);
    let n = w * h;
    let s = set.severity.max(0.0);
    let diag = ((w * w + h * h) as f32).sqrt();
    let target = if set.global { vec![true; n] } else { r.mask_of(&set.labels) };
    let m = if set.global { vec![1.0; n] } else { r.weight_of(&set.labels) };
    let dist = distance_to(&target, w, h);
    let mask = set.want_mask.then(|| {
        let reach = (0.01 * diag).round().max(1.0);
        match &dist {
            Some(d) => d.iter().map(|&d| if d <= reach { 1.0 } else { 0.0 }).collect(),
            None => vec![0.0; n],
        }
    });
    if s == 0.0 {
        return Corrupted { image: r.rgb.clone(), attention: m, mask };
    }
    let d = draw(rng, s, set.others.len());
    if set.global {
        // 8 then 7 on every pixel; attention 1 everywhere
        let image = r.rgb.chunks_exact(3).flat_map(|p| cast(&d, clamp01(mat_vec(&d.hue, rgb(p))))).collect();
        return Corrupted { image, attention: m, mask };
    }
    // c_v = clamp(R(g ⊙ c_e + b))
    let cv = clamp01(mat_vec(&d.hue, std::array::from_fn(|c| d.gain[c] * set.colour[c] + d.offset[c])));
    let view = ViewTarget { r, m, dist, diag };
    let (image, base) = match d.wrong {
        Some(wrong) => wrong_view(source, r, &set.others, wrong, cv),
        None => target_view(&view, set, &d, cv, rng),
    };
    let image = image.chunks_exact(3).flat_map(|p| cast(&d, rgb(p))).collect();
    let attention = noisy_attention(&base, w, h, s, diag, rng);
    Corrupted { image, attention, mask }
}

/// Item 7: clamp(k ⊙ p, 0, 1).
fn cast(d: &Draws, p: [f32; 3]) -> [f32; 3] {
    std::array::from_fn(|c| (p[c] * d.cast[c]).clamp(0.0, 1.0))
}

/// Items 1, 2, 3 and 5: the edited image of a view that edits the target, and the
/// attention's base max(m, spill, blobs, distractor).
fn target_view(
    v: &ViewTarget,
    set: &Corruption,
    d: &Draws,
    cv: [f32; 3],
    rng: &mut SplitMix64,
) -> (Vec<f32>, Vec<f32>) {
    let s = set.severity;
    let n = v.m.len();
    // 1. gain, offset and hue inside the target
    let mut img = v.r.rgb.clone();
    for (px, &mi) in img.chunks_exact_mut(3).zip(&v.m) {
        if mi > 0.0 {
            let q = mat_vec(&d.hue, std::array::from_fn(|c| d.gain[c] * px[c] + d.offset[c]));
            for c in 0..3 {
                px[c] = (px[c] + mi * (q[c] - px[c])).clamp(0.0, 1.0);
            }
        }
    }
    // 2. spill around the target
    let rho = (s * rng.range(0.02, 0.08) * v.diag).min(0.3 * v.diag);
    let beta = (s * rng.range(0.25, 0.5)).min(0.9);
    let mut spill = vec![0.0f32; n];
    if let Some(dist) = &v.dist {
        if rho >= 0.5 {
            for (sp, &di) in spill.iter_mut().zip(dist) {
                if di < rho {
                    *sp = beta * (1.0 - di / rho).powi(2);
                }
            }
        }
    }
    // 3. spurious blobs
    let blobs = blobs(v, s, rho, rng);
    // 5. the distractor
    let distractor = match (d.distractor, set.distractor) {
        (Some(a), Some(label)) => v.r.weight(label).iter().map(|w| a * w.clamp(0.0, 1.0)).collect(),
        _ => vec![0.0f32; n],
    };
    let mut base = v.m.clone();
    for (i, px) in img.chunks_exact_mut(3).enumerate() {
        let t = spill[i].max(blobs[i]).max(distractor[i]);
        base[i] = base[i].max(t);
        let t = t * (1.0 - v.m[i]);
        if t > 0.0 {
            for c in 0..3 {
                px[c] += t * (cv[c] - px[c]);
            }
        }
    }
    (img, base)
}

/// Item 3: the blobs' blend strength per pixel.
fn blobs(v: &ViewTarget, s: f32, rho: f32, rng: &mut SplitMix64) -> Vec<f32> {
    let (w, h, diag) = (v.r.width, v.r.height, v.diag);
    let count = ((rng.uniform() * (3.0 * s + 1.0)).floor() as usize).min(8);
    let mut blobs = vec![0.0f32; w * h];
    for _ in 0..count {
        let r = rng.range(0.02, 0.05) * diag;
        let strength = (s * rng.range(0.35, 0.7)).min(1.0);
        let mut centre = None;
        for _ in 0..20 {
            let (x, y) = (rng.uniform() * w as f32, rng.uniform() * h as f32);
            let i = (y as usize).min(h - 1) * w + (x as usize).min(w - 1);
            let clear = match &v.dist {
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
                let b = &mut blobs[y * w + x];
                *b = b.max(strength * (-0.5 * (dx * dx + dy * dy) / (r * r)).exp());
            }
        }
    }
    blobs
}

/// Item 6: the image of a view where the editor misses the target, from the source
/// render, and the attention's base (w_o, or 0).
fn wrong_view(
    source: &[f32],
    r: &LabelRender,
    others: &[u32],
    wrong: Wrong,
    cv: [f32; 3],
) -> (Vec<f32>, Vec<f32>) {
    let mut img = source.to_vec();
    let base = match wrong {
        Wrong::Other(k) => r.weight(others[k]).into_iter().map(|w| w.clamp(0.0, 1.0)).collect(),
        Wrong::Nothing => vec![0.0f32; r.width * r.height],
    };
    for (px, &wo) in img.chunks_exact_mut(3).zip(&base) {
        if wo > 0.0 {
            for c in 0..3 {
                px[c] += wo * (cv[c] - px[c]);
            }
        }
    }
    (img, base)
}

/// Item 4: the attention from its base.
fn noisy_attention(base: &[f32], w: usize, h: usize, s: f32, diag: f32, rng: &mut SplitMix64) -> Vec<f32> {
    let sigma = 0.01 * s * diag;
    let blurred = if sigma >= 0.3 { gaussian_blur(base, w, h, sigma) } else { base.to_vec() };
    let n1 = smooth_noise(rng, w, h);
    let n2 = smooth_noise(rng, w, h);
    (0..w * h).map(|i| (blurred[i] * (1.0 + 0.25 * s * n1[i]) + 0.04 * s * n2[i].max(0.0)).max(0.0)).collect()
}

/// An instruction prepared for editing: its ground truth and what the corruption needs.
#[derive(Clone, Debug)]
struct Prepared {
    ins: Instruction,
    truth: Gaussians,
    /// c_e, the mean ground-truth colour of the target's Gaussians.
    colour: [f32; 3],
    distractor: Option<u32>,
    /// The non-target objects' labels.
    others: Vec<u32>,
}

fn prepare(scene: &Scene, ins: Instruction) -> Result<Prepared, Error> {
    let truth = ground_truth_of(scene, &ins)?;
    let colour = mean_colour(&truth, &scene.labels, &ins.labels);
    let others: Vec<u32> =
        scene.objects.iter().map(|o| o.label).filter(|l| !ins.labels.contains(l)).collect();
    let distractor = nearest_in_colour(scene, &ins.labels, &others);
    Ok(Prepared { ins, truth, colour, distractor, others })
}

/// The ground-truth edited Gaussians of `ins`: the recolour or retexture applied to
/// each target label in turn (each touches only its own label), or the style.
fn ground_truth_of(scene: &Scene, ins: &Instruction) -> Result<Gaussians, Error> {
    let mut g = match &ins.kind {
        EditKind::Restyle(style) => return Ok(scene.restyle(*style)?),
        _ => scene.gaussians.clone(),
    };
    for &label in &ins.labels {
        g = match &ins.kind {
            EditKind::Recolor { rgb, .. } => recolor(&g, &scene.labels, label, *rgb)?,
            EditKind::Retexture(m) => retexture(&g, &scene.labels, label, *m)?,
            EditKind::Restyle(_) => unreachable!("returned above"),
        };
    }
    Ok(g)
}

/// Mean diffuse colour (each clamped to [0, 1]) of the Gaussians of `g` whose label
/// (`gaussian_labels`) is one of `labels`; 0 when there are none.
pub fn mean_colour(g: &Gaussians, gaussian_labels: &[u32], labels: &[u32]) -> [f32; 3] {
    let mut sum = [0.0f64; 3];
    let mut count = 0usize;
    for (i, l) in gaussian_labels.iter().enumerate().take(g.len()) {
        if labels.contains(l) {
            let c = dc_colour(g, i);
            for k in 0..3 {
                sum[k] += c[k].clamp(0.0, 1.0) as f64;
            }
            count += 1;
        }
    }
    sum.map(|v| (v / count.max(1) as f64) as f32)
}

/// The label among `candidates` whose mean source colour is nearest (RGB distance) to
/// the mean source colour of the `target` labels; `None` without candidates.
pub fn nearest_in_colour(scene: &Scene, target: &[u32], candidates: &[u32]) -> Option<u32> {
    let t = mean_colour(&scene.gaussians, &scene.labels, target);
    let dist = |l: u32| {
        let c = mean_colour(&scene.gaussians, &scene.labels, &[l]);
        (0..3).map(|k| (c[k] - t[k]).powi(2)).sum::<f32>()
    };
    candidates.iter().copied().min_by(|&a, &b| dist(a).total_cmp(&dist(b)))
}

/// The simulated editor of a built-in scene (see the module doc).
#[derive(Clone, Debug)]
pub struct SimulatedEditor {
    scene: Scene,
    severity: f32,
    seed: u64,
    want_mask: bool,
    /// The last instruction carried out, prepared.
    current: Option<Prepared>,
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
        if self.current.as_ref().map(|c| &c.ins) != Some(&ins) {
            self.current = Some(prepare(&self.scene, ins)?);
        }
        Ok(&self.current.as_ref().expect("set above").ins)
    }

    /// The ground-truth edited scene of the last instruction (the unedited scene before
    /// any instruction).
    pub fn ground_truth(&self) -> &Gaussians {
        self.current.as_ref().map_or(&self.scene.gaussians, |c| &c.truth)
    }

    /// Labels the last instruction changes (empty before any instruction): the named
    /// objects', or every label, the background 0 included, for a global edit.
    pub fn target_labels(&self) -> &[u32] {
        self.current.as_ref().map_or(&[], |c| &c.ins.labels)
    }

    /// The last instruction's distractor (module doc, item 5), if it has one.
    pub fn distractor(&self) -> Option<u32> {
        self.current.as_ref().and_then(|c| c.distractor)
    }

    /// The last instruction in words, e.g. "recolor ball to blue (0.10, 0.20, 0.90)".
    pub fn describe(&self) -> String {
        self.current.as_ref().map_or_else(|| "no instruction yet".into(), |c| c.ins.describe())
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
        let p = self.current.as_ref().expect("set by instruct");
        let set = Corruption {
            labels: p.ins.labels.clone(),
            global: p.ins.is_global(),
            colour: p.colour,
            distractor: p.distractor,
            others: p.others.clone(),
            severity: self.severity,
            want_mask: self.want_mask,
            seed: self.seed,
        };
        let scene = &self.scene;
        let num_labels = scene.num_labels();
        // views in parallel; each has its own generator, so the order does not matter
        let out: Vec<Option<EditedView>> = views
            .par_iter()
            .map(|v| {
                let r = render_labels(&p.truth, &scene.labels, num_labels, v.camera, scene.background);
                Some(set.edit_view(&r, v.image, v.index))
            })
            .collect();
        tracing::debug!(
            "simulated editor: {} on {} views at severity {}",
            p.ins.describe(),
            views.len(),
            self.severity
        );
        Ok(out)
    }
}

#[cfg(test)]
mod tests;

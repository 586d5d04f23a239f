//! Ground-truth edits of a labelled scene: what a perfect editor would do to the
//! Gaussians of one object. They return a new [`Gaussians`] and never modify the input;
//! Gaussians with another label are copied bit for bit.
//!
//! - [`recolor`]: the object's diffuse colour becomes `rgb`, its texture kept as
//!   luminance variation (each Gaussian's luminance relative to the object's mean,
//!   clamped to [0.6, 1.4]); the view-dependent SH of the object is zeroed.
//! - [`retexture`]: the object's colour becomes a procedural [`Material`] evaluated at
//!   each Gaussian's position relative to the object's bounding box; view-dependent SH
//!   zeroed except for `gold`, which gets a small uniform sheen.
//!
//! There is no instruction parser here; the simulated editor maps words to these calls.

use crate::build::SH_C0;
use crate::texture::{checker, fbm, marble_vein, mix_rgb, shade, stripes, wood_grain};
use crate::Error;
use transsplat_scene::Gaussians;

/// Procedural materials for [`retexture`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Material {
    /// White marble with grey veins.
    Marble,
    /// Warm wood grain.
    Wood,
    /// Polished gold (yellow, slightly noisy, with a small view-dependent sheen).
    Gold,
    /// Black and white 3D checker.
    Checker,
    /// Red and white horizontal stripes.
    Stripes,
}

impl Material {
    /// Every material.
    pub const ALL: [Material; 5] =
        [Material::Marble, Material::Wood, Material::Gold, Material::Checker, Material::Stripes];

    /// Lower-case name ("marble").
    pub fn name(self) -> &'static str {
        match self {
            Material::Marble => "marble",
            Material::Wood => "wood",
            Material::Gold => "gold",
            Material::Checker => "checker",
            Material::Stripes => "stripes",
        }
    }

    /// The material called `name` (case-insensitive; "golden", "wooden", "striped",
    /// "checkered" also accepted).
    pub fn from_name(name: &str) -> Option<Material> {
        match name.trim().to_ascii_lowercase().as_str() {
            "marble" => Some(Material::Marble),
            "wood" | "wooden" => Some(Material::Wood),
            "gold" | "golden" => Some(Material::Gold),
            "checker" | "checkers" | "checkered" | "checkerboard" => Some(Material::Checker),
            "stripes" | "striped" | "stripe" => Some(Material::Stripes),
            _ => None,
        }
    }

    /// Colour at `p`, a position normalised to the object (about [-1, 1]³, z up).
    pub fn colour(self, p: [f32; 3]) -> [f32; 3] {
        match self {
            Material::Marble => {
                let v = marble_vein(0x4D41, p, 0.8);
                let base = shade([0.93, 0.92, 0.89], 0.95 + 0.07 * fbm(0x4D42, p.map(|x| x * 6.0), 3));
                mix_rgb(base, [0.42, 0.43, 0.46], 0.85 * v)
            }
            Material::Wood => shade([0.62, 0.4, 0.2], wood_grain(0x574F, p, 0.25)),
            Material::Gold => shade([0.95, 0.72, 0.2], 0.85 + 0.25 * fbm(0x474C, p.map(|x| x * 5.0), 3)),
            Material::Checker => {
                let c = checker(p, 0.5);
                mix_rgb([0.08, 0.08, 0.08], [0.95, 0.95, 0.95], c)
            }
            Material::Stripes => mix_rgb([0.9, 0.12, 0.1], [0.95, 0.95, 0.95], stripes(p, 0.5)),
        }
    }
}

fn check(g: &Gaussians, labels: &[u32], label: u32) -> Result<Vec<usize>, Error> {
    g.validate().map_err(Error::Invalid)?;
    if labels.len() != g.len() {
        return Err(Error::Invalid(format!("{} labels for {} Gaussians", labels.len(), g.len())));
    }
    let idx: Vec<usize> = (0..g.len()).filter(|&i| labels[i] == label).collect();
    if idx.is_empty() {
        return Err(Error::Invalid(format!("no Gaussian has label {label}")));
    }
    Ok(idx)
}

/// Diffuse (DC) colour of Gaussian `i`: `SH_C0 * f_dc + 0.5`.
pub fn dc_colour(g: &Gaussians, i: usize) -> [f32; 3] {
    let s = g.sh_of(i);
    [s[0] * SH_C0 + 0.5, s[1] * SH_C0 + 0.5, s[2] * SH_C0 + 0.5]
}

fn set_colour(g: &mut Gaussians, i: usize, rgb: [f32; 3], keep_rest: f32) {
    let k = g.sh_coeffs() * 3;
    let s = &mut g.sh[i * k..(i + 1) * k];
    for c in 0..3 {
        s[c] = (rgb[c].clamp(0.0, 1.0) - 0.5) / SH_C0;
    }
    for v in s[3..].iter_mut() {
        *v *= keep_rest;
    }
}

fn luminance(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

/// Recolours the Gaussians with label `label` to `rgb` (linear RGB in [0, 1]), keeping
/// their texture as luminance variation. Errors: `labels` not matching `g`, no Gaussian
/// with that label, a colour outside [0, 1].
pub fn recolor(g: &Gaussians, labels: &[u32], label: u32, rgb: [f32; 3]) -> Result<Gaussians, Error> {
    if !rgb.iter().all(|c| c.is_finite() && (0.0..=1.0).contains(c)) {
        return Err(Error::Invalid(format!("colour {rgb:?} is not RGB in [0, 1]")));
    }
    let idx = check(g, labels, label)?;
    let lum: Vec<f32> = idx.iter().map(|&i| luminance(dc_colour(g, i).map(|v| v.clamp(0.0, 1.0)))).collect();
    let mean = (lum.iter().map(|&v| v as f64).sum::<f64>() / lum.len() as f64).max(1e-3) as f32;
    let mut out = g.clone();
    for (&i, &l) in idx.iter().zip(&lum) {
        let f = (l / mean).clamp(0.6, 1.4);
        set_colour(&mut out, i, shade(rgb, f), 0.0);
    }
    Ok(out)
}

/// Retextures the Gaussians with label `label` with a procedural material.
pub fn retexture(g: &Gaussians, labels: &[u32], label: u32, material: Material) -> Result<Gaussians, Error> {
    let idx = check(g, labels, label)?;
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for &i in &idx {
        for k in 0..3 {
            lo[k] = lo[k].min(g.means[i][k]);
            hi[k] = hi[k].max(g.means[i][k]);
        }
    }
    let centre: [f32; 3] = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
    let half = (0..3).map(|k| 0.5 * (hi[k] - lo[k])).fold(1e-3f32, f32::max);
    let mut out = g.clone();
    for &i in &idx {
        let p: [f32; 3] = std::array::from_fn(|k| (g.means[i][k] - centre[k]) / half);
        set_colour(&mut out, i, material.colour(p), 0.0);
        if material == Material::Gold {
            // a uniform sheen on the degree-1 terms: brighter when seen from above
            let k = out.sh_coeffs() * 3;
            if k >= 12 {
                let s = &mut out.sh[i * k..(i + 1) * k];
                for c in 0..3 {
                    s[3 + 3 + c] = -0.08; // coefficient 2 (∝ z of the view direction)
                }
            }
        }
    }
    Ok(out)
}

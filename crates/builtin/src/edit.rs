//! Ground-truth edits of a labelled scene: what a perfect editor would do to the
//! Gaussians of one object, or to the whole scene. They return a new [`Gaussians`] and
//! never modify the input; [`recolor`] and [`retexture`] copy the Gaussians with another
//! label bit for bit.
//!
//! - [`recolor`]: the object's diffuse colour becomes `rgb`, its texture kept as
//!   luminance variation (each Gaussian's luminance relative to the object's mean,
//!   clamped to [0.6, 1.4]); the view-dependent SH of the object is zeroed.
//! - [`retexture`]: the object's colour becomes a procedural [`Material`] evaluated at
//!   each Gaussian's position relative to the object's bounding box; view-dependent SH
//!   zeroed except for `gold`, which gets a small uniform sheen.
//! - [`restyle`]: a global colour transform of every Gaussian (background included), a
//!   [`Style`] given by a fixed 3×3 matrix M and offset o on the colour the renderer
//!   shows, c = SH_C0·f_dc + 0.5 (display RGB, as every colour of the built-in scenes):
//!   c' = clamp(M·clamp(c, 0, 1) + o, 0, 1). The view-dependent SH coefficients are
//!   kept and transformed by M (without the offset): colour is linear in the SH
//!   coefficients, so a view's colour becomes M·c(view) + o before clamping, i.e. the
//!   scene's view dependence is restyled rather than removed.
//!
//! There is no instruction parser here; the simulated editor maps words to these calls.

use crate::texture::{checker, fbm, marble_vein, mix_rgb, shade, stripes, wood_grain};
use crate::Error;
use transsplat_scene::{Gaussians, SH_C0};

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

/// Global colour styles for [`restyle`]: each a fixed affine colour transform
/// c' = M·c + o (see [`Style::transform`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Style {
    /// Warm: greens pulled towards olive and orange, blue reduced, reds kept.
    Autumn,
    /// Cold: half desaturated towards the luminance Y, then a blue tint and a lift.
    Winter,
    /// Old photograph: the classic sepia-tone matrix (no offset).
    Sepia,
}

impl Style {
    /// Every style.
    pub const ALL: [Style; 3] = [Style::Autumn, Style::Winter, Style::Sepia];

    /// Lower-case name ("autumn").
    pub fn name(self) -> &'static str {
        match self {
            Style::Autumn => "autumn",
            Style::Winter => "winter",
            Style::Sepia => "sepia",
        }
    }

    /// The style called `name` (case-insensitive; "autumnal", "wintry", "wintery" also
    /// accepted).
    pub fn from_name(name: &str) -> Option<Style> {
        match name.trim().to_ascii_lowercase().as_str() {
            "autumn" | "autumnal" => Some(Style::Autumn),
            "winter" | "wintry" | "wintery" => Some(Style::Winter),
            "sepia" => Some(Style::Sepia),
            _ => None,
        }
    }

    /// The style's matrix M (row-major, rows = output R, G, B) and offset o:
    ///
    /// - autumn: M = [[0.85, 0.50, 0.00], [0.15, 0.55, 0.10], [0.05, 0.10, 0.50]],
    ///   o = (0.03, 0.02, 0); green (0.1, 0.65, 0.2) → (0.44, 0.41, 0.17).
    /// - winter: M = diag(0.92, 0.98, 1.10)·(½·I + ½·1·yᵀ) with the luminance weights
    ///   y = (0.2126, 0.7152, 0.0722), rounded to 3 decimals, o = (0.04, 0.05, 0.08).
    /// - sepia: M = [[0.393, 0.769, 0.189], [0.349, 0.686, 0.168], [0.272, 0.534, 0.131]],
    ///   o = 0.
    pub fn transform(self) -> ([[f32; 3]; 3], [f32; 3]) {
        match self {
            Style::Autumn => {
                ([[0.85, 0.50, 0.00], [0.15, 0.55, 0.10], [0.05, 0.10, 0.50]], [0.03, 0.02, 0.0])
            }
            Style::Winter => {
                ([[0.558, 0.329, 0.033], [0.104, 0.840, 0.035], [0.117, 0.393, 0.590]], [0.04, 0.05, 0.08])
            }
            Style::Sepia => {
                ([[0.393, 0.769, 0.189], [0.349, 0.686, 0.168], [0.272, 0.534, 0.131]], [0.0, 0.0, 0.0])
            }
        }
    }

    /// The style applied to one colour: clamp(M·clamp(c, 0, 1) + o, 0, 1).
    pub fn apply(self, c: [f32; 3]) -> [f32; 3] {
        let (m, o) = self.transform();
        let c = c.map(|v| v.clamp(0.0, 1.0));
        std::array::from_fn(|r| (m[r][0] * c[0] + m[r][1] * c[1] + m[r][2] * c[2] + o[r]).clamp(0.0, 1.0))
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

/// Restyles every Gaussian of `g` (see the module doc): the DC colour becomes
/// [`Style::apply`] of it, each higher SH coefficient triple f becomes M·f.
pub fn restyle(g: &Gaussians, style: Style) -> Result<Gaussians, Error> {
    g.validate().map_err(Error::Invalid)?;
    let (m, _) = style.transform();
    let mut out = g.clone();
    let k = out.sh_coeffs() * 3;
    for i in 0..g.len() {
        let c = style.apply(dc_colour(g, i));
        let s = &mut out.sh[i * k..(i + 1) * k];
        for (v, ch) in s[..3].iter_mut().zip(c) {
            *v = (ch - 0.5) / SH_C0;
        }
        for f in s[3..].chunks_exact_mut(3) {
            let x = [f[0], f[1], f[2]];
            for (r, v) in f.iter_mut().enumerate() {
                *v = m[r][0] * x[0] + m[r][1] * x[1] + m[r][2] * x[2];
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two Gaussians of SH degree 1 with the given DC colours and rest coefficients.
    fn two(c: [[f32; 3]; 2], rest: f32) -> Gaussians {
        let mut g = Gaussians { sh_degree: 1, ..Default::default() };
        for (i, rgb) in c.into_iter().enumerate() {
            g.means.push([i as f32, 0.0, 0.0]);
            g.log_scales.push([-3.0; 3]);
            g.rotations.push([1.0, 0.0, 0.0, 0.0]);
            g.opacity_logits.push(2.0);
            g.sh.extend(rgb.map(|v| (v - 0.5) / SH_C0));
            g.sh.extend([rest, 0.0, 0.0, 0.0, rest, 0.0, 0.0, 0.0, rest]);
        }
        g
    }

    #[test]
    fn styles_by_hand() {
        // sepia of white: the row sums (1.351, 1.203, 0.937), clamped
        let w = Style::Sepia.apply([1.0, 1.0, 1.0]);
        assert_eq!(w[0], 1.0);
        assert_eq!(w[1], 1.0);
        assert!((w[2] - 0.937).abs() < 1e-6, "{w:?}");
        // sepia of mid grey 0.5: half the row sums
        let g = Style::Sepia.apply([0.5; 3]);
        assert!((g[0] - 0.6755).abs() < 1e-6 && (g[2] - 0.4685).abs() < 1e-6, "{g:?}");
        // autumn of the scenes' green: (0.1, 0.65, 0.2) → (0.44, 0.4125, 0.17)
        let a = Style::Autumn.apply([0.1, 0.65, 0.2]);
        for (x, y) in a.iter().zip([0.085 + 0.325 + 0.03, 0.015 + 0.3575 + 0.02 + 0.02, 0.005 + 0.065 + 0.1])
        {
            assert!((x - y).abs() < 1e-6, "{a:?}");
        }
        // winter of black is its offset; of a grey it stays nearly grey and bluer
        assert_eq!(Style::Winter.apply([0.0; 3]), [0.04, 0.05, 0.08]);
        let b = Style::Winter.apply([0.4; 3]);
        assert!(b[2] > b[1] && b[1] > b[0], "{b:?}");
        // the winter matrix is diag(0.92, 0.98, 1.1)·(I/2 + 1yᵀ/2) to 3 decimals
        let y = [0.2126f32, 0.7152, 0.0722];
        let (m, _) = Style::Winter.transform();
        for (r, gain) in [0.92f32, 0.98, 1.1].into_iter().enumerate() {
            for c in 0..3 {
                let want = gain * (0.5 * (r == c) as u8 as f32 + 0.5 * y[c]);
                assert!((m[r][c] - want).abs() < 6e-4, "M[{r}][{c}] = {} vs {want}", m[r][c]);
            }
        }
        for s in Style::ALL {
            assert_eq!(Style::from_name(s.name()), Some(s));
        }
        assert_eq!(Style::from_name(" Wintry"), Some(Style::Winter));
        assert_eq!(Style::from_name("spring"), None);
    }

    #[test]
    fn restyle_changes_every_gaussian_and_maps_the_sh_rest_by_the_matrix() {
        let g = two([[0.1, 0.65, 0.2], [0.5, 0.5, 0.5]], 0.1);
        let out = restyle(&g, Style::Autumn).unwrap();
        assert_eq!(out.means, g.means);
        assert_eq!(out.opacity_logits, g.opacity_logits);
        for i in 0..2 {
            let want = Style::Autumn.apply(dc_colour(&g, i));
            let got = dc_colour(&out, i);
            for c in 0..3 {
                assert!((got[c] - want[c]).abs() < 1e-5, "Gaussian {i}: {got:?} vs {want:?}");
            }
        }
        // rest coefficient k = 1 was (0.1, 0, 0): it becomes the first column of M times 0.1
        let (m, _) = Style::Autumn.transform();
        let rest = &out.sh[3..6];
        for r in 0..3 {
            assert!((rest[r] - 0.1 * m[r][0]).abs() < 1e-7, "{rest:?}");
        }
        assert!(restyle(
            &Gaussians { sh_degree: 1, means: vec![[0.0; 3]], ..Default::default() },
            Style::Sepia
        )
        .is_err());
    }
}

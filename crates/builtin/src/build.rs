//! Surface-sampled Gaussians: the primitives the scenes are made of.
//!
//! Every surface is sampled on a jittered grid that is close to area-uniform
//! (rectangles on a uv grid; spheres and surfaces of revolution ring by ring, with a
//! number of points per ring proportional to its circumference), one Gaussian per
//! sample. Each Gaussian is a flat disc: its tangential standard deviation is a
//! fraction of the sample spacing so that neighbours overlap into a closed surface,
//! its normal-direction standard deviation is small, and its rotation maps the
//! local frame (tangent, bitangent, normal) onto the Gaussian's axes. The colour comes
//! from a closure of the position (the texture); a small random degree-1 SH term gives
//! some view dependence.

use crate::rng::{seeded, Rng};
use transsplat_raster::project::quat_from_matrix;
use transsplat_scene::{Gaussians, SH_C0};

/// SH degree of every built-in scene.
pub const SH_DEGREE: u32 = 1;

/// Tangential σ as a fraction of the sample spacing.
const TANGENT_FRACTION: f32 = 0.62;
/// Normal σ as a fraction of the sample spacing (flattened discs).
const NORMAL_FRACTION: f32 = 0.06;

pub(crate) type Texture<'a> = &'a dyn Fn([f32; 3]) -> [f32; 3];

pub(crate) fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
pub(crate) fn add(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
pub(crate) fn scale(a: [f32; 3], s: f32) -> [f32; 3] {
    a.map(|v| v * s)
}
pub(crate) fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
pub(crate) fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
pub(crate) fn norm(a: [f32; 3]) -> f32 {
    dot(a, a).sqrt()
}
pub(crate) fn normalize(a: [f32; 3]) -> [f32; 3] {
    let n = norm(a);
    if n > 0.0 {
        scale(a, 1.0 / n)
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// A unit vector orthogonal to `n`.
fn any_tangent(n: [f32; 3]) -> [f32; 3] {
    let a = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    normalize(cross(a, n))
}

/// Accumulates Gaussians and their labels.
pub(crate) struct Builder {
    pub(crate) g: Gaussians,
    pub(crate) labels: Vec<u32>,
    rng: Rng,
    /// Magnitude of the random degree-1 SH coefficients.
    pub(crate) view_dependence: f32,
    pub(crate) opacity: f32,
}

impl Builder {
    pub(crate) fn new(seed: u64) -> Self {
        Builder {
            g: Gaussians { sh_degree: SH_DEGREE, ..Default::default() },
            labels: Vec::new(),
            rng: seeded(seed),
            view_dependence: 0.03,
            opacity: 0.97,
        }
    }

    /// One flat Gaussian at `pos` with unit `normal` and unit `tangent` (⊥ normal).
    pub(crate) fn disc(
        &mut self,
        pos: [f32; 3],
        normal: [f32; 3],
        tangent: [f32; 3],
        spacing: f32,
        rgb: [f32; 3],
        label: u32,
    ) {
        let n = normalize(normal);
        let t = normalize(sub(tangent, scale(n, dot(tangent, n))));
        let t = if norm(t) > 0.5 { t } else { any_tangent(n) };
        let b = cross(n, t);
        // Columns (t, b, n): a right-handed frame (b = n × t).
        let r = [[t[0], b[0], n[0]], [t[1], b[1], n[1]], [t[2], b[2], n[2]]];
        let jitter = 1.0 + 0.08 * self.rng.signed();
        let st = (spacing * TANGENT_FRACTION * jitter).ln();
        let sn = (spacing * NORMAL_FRACTION).max(1e-4).ln();
        self.g.means.push(pos);
        self.g.log_scales.push([st, st, sn]);
        self.g.rotations.push(quat_from_matrix(r));
        let o = (self.opacity + 0.02 * self.rng.signed()).clamp(0.05, 0.995);
        self.g.opacity_logits.push((o / (1.0 - o)).ln());
        for c in rgb {
            self.g.sh.push((c.clamp(0.0, 1.0) - 0.5) / SH_C0);
        }
        for _ in 1..transsplat_scene::sh_coeffs(SH_DEGREE) {
            let common = self.view_dependence * self.rng.signed();
            for _ in 0..3 {
                let v = common + 0.3 * self.view_dependence * self.rng.signed();
                self.g.sh.push(v);
            }
        }
        self.labels.push(label);
    }

    /// A rectangle `origin + s·u + t·v`, s, t ∈ [0, 1], facing `cross(u, v)`.
    pub(crate) fn rect(
        &mut self,
        origin: [f32; 3],
        u: [f32; 3],
        v: [f32; 3],
        spacing: f32,
        tex: Texture,
        label: u32,
    ) {
        let (lu, lv) = (norm(u), norm(v));
        let nu = ((lu / spacing).round() as usize).max(1);
        let nv = ((lv / spacing).round() as usize).max(1);
        let h = (lu * lv / (nu * nv) as f32).sqrt();
        let normal = normalize(cross(u, v));
        let tangent = normalize(u);
        for j in 0..nv {
            for i in 0..nu {
                let s = (i as f32 + 0.5 + 0.35 * self.rng.signed()) / nu as f32;
                let t = (j as f32 + 0.5 + 0.35 * self.rng.signed()) / nv as f32;
                let p = add(origin, add(scale(u, s), scale(v, t)));
                let rgb = tex(p);
                self.disc(p, normal, tangent, h, rgb, label);
            }
        }
    }

    /// An axis-aligned box; `skip_bottom` leaves out the face at −z (resting on a surface).
    pub(crate) fn cuboid(
        &mut self,
        centre: [f32; 3],
        half: [f32; 3],
        spacing: f32,
        tex: Texture,
        label: u32,
        skip_bottom: bool,
    ) {
        let [hx, hy, hz] = half;
        let c = centre;
        let o = |dx: f32, dy: f32, dz: f32| [c[0] + dx, c[1] + dy, c[2] + dz];
        // (origin, u, v) with cross(u, v) pointing outwards.
        let faces = [
            (o(-hx, -hy, hz), [2.0 * hx, 0.0, 0.0], [0.0, 2.0 * hy, 0.0]), // +z
            (o(-hx, -hy, -hz), [0.0, 2.0 * hy, 0.0], [2.0 * hx, 0.0, 0.0]), // -z
            (o(hx, -hy, -hz), [0.0, 2.0 * hy, 0.0], [0.0, 0.0, 2.0 * hz]), // +x
            (o(-hx, -hy, -hz), [0.0, 0.0, 2.0 * hz], [0.0, 2.0 * hy, 0.0]), // -x
            (o(-hx, hy, -hz), [0.0, 0.0, 2.0 * hz], [2.0 * hx, 0.0, 0.0]), // +y
            (o(-hx, -hy, -hz), [2.0 * hx, 0.0, 0.0], [0.0, 0.0, 2.0 * hz]), // -y
        ];
        for (k, (origin, u, v)) in faces.into_iter().enumerate() {
            if skip_bottom && k == 1 {
                continue;
            }
            self.rect(origin, u, v, spacing, tex, label);
        }
    }

    /// A sphere sampled ring by ring (equal arc spacing in the polar angle).
    pub(crate) fn sphere(&mut self, centre: [f32; 3], radius: f32, spacing: f32, tex: Texture, label: u32) {
        let rows = ((std::f32::consts::PI * radius / spacing).round() as usize).max(2);
        for k in 0..rows {
            let theta = (k as f32 + 0.5) / rows as f32 * std::f32::consts::PI;
            let ring = radius * theta.sin();
            let count = ((std::f32::consts::TAU * ring / spacing).round() as usize).max(3);
            let offset = self.rng.uniform();
            for j in 0..count {
                let phi =
                    (j as f32 + offset + 0.3 * self.rng.signed()) / count as f32 * std::f32::consts::TAU;
                let th = theta + 0.3 * self.rng.signed() * std::f32::consts::PI / rows as f32;
                let n = [th.sin() * phi.cos(), th.sin() * phi.sin(), th.cos()];
                let p = add(centre, scale(n, radius));
                let tangent = [-phi.sin(), phi.cos(), 0.0];
                let rgb = tex(p);
                self.disc(p, n, tangent, spacing, rgb, label);
            }
        }
    }

    /// A surface of revolution about the vertical axis through `base`: the profile is
    /// a polyline of (radius, height) points, sampled every `spacing` of arc length.
    pub(crate) fn revolution(
        &mut self,
        base: [f32; 3],
        profile: &[(f32, f32)],
        spacing: f32,
        tex: Texture,
        label: u32,
    ) {
        for seg in profile.windows(2) {
            let ((r0, z0), (r1, z1)) = (seg[0], seg[1]);
            let len = ((r1 - r0).powi(2) + (z1 - z0).powi(2)).sqrt();
            if len <= 0.0 {
                continue;
            }
            // Outward normal in the (radial, z) plane for a profile walked upwards.
            let (nr, nz) = ((z1 - z0) / len, -(r1 - r0) / len);
            let rows = ((len / spacing).round() as usize).max(1);
            for k in 0..rows {
                let s = (k as f32 + 0.5 + 0.3 * self.rng.signed()) / rows as f32;
                let (r, z) = (r0 + (r1 - r0) * s, z0 + (z1 - z0) * s);
                let count = ((std::f32::consts::TAU * r / spacing).round() as usize).max(1);
                let offset = self.rng.uniform();
                for j in 0..count {
                    let phi =
                        (j as f32 + offset + 0.3 * self.rng.signed()) / count as f32 * std::f32::consts::TAU;
                    let (c, sn) = (phi.cos(), phi.sin());
                    let p = add(base, [r * c, r * sn, z]);
                    let n = [nr * c, nr * sn, nz];
                    let tangent = [-sn, c, 0.0];
                    let rgb = tex(p);
                    self.disc(p, n, tangent, spacing, rgb, label);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quat_to_matrix(q: [f32; 4]) -> [[f32; 3]; 3] {
        let [w, x, y, z] = q;
        [
            [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
            [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
            [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
        ]
    }

    #[test]
    fn disc_rotation_maps_the_third_axis_to_the_normal() {
        let mut b = Builder::new(1);
        let normals =
            [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [-0.3, 0.8, -0.52], [0.0, -1.0, 0.0]];
        for n in normals {
            b.disc([0.0; 3], n, [1.0, 0.0, 0.0], 0.01, [0.5; 3], 0);
        }
        for (q, n) in b.g.rotations.iter().zip(normals) {
            let r = quat_to_matrix(*q);
            let col = [r[0][2], r[1][2], r[2][2]];
            let n = normalize(n);
            assert!(dot(col, n) > 0.9999, "{col:?} vs {n:?}");
        }
        // flattened: normal σ much smaller than tangential σ
        let s = b.g.log_scales[0];
        assert!(s[2] < s[0] - 2.0);
        assert_eq!(b.g.sh.len(), 5 * 12);
        assert!(b.g.validate().is_ok());
    }

    #[test]
    fn sampling_density_follows_area() {
        let tex = |_p: [f32; 3]| [0.5; 3];
        let mut b = Builder::new(2);
        b.sphere([0.0; 3], 0.1, 0.01, &tex, 1);
        let sphere = b.labels.len() as f32;
        let want = 4.0 * std::f32::consts::PI * 0.01 / 1e-4;
        assert!((sphere / want - 1.0).abs() < 0.1, "{sphere} vs {want}");
        for p in &b.g.means {
            assert!((norm(*p) - 0.1).abs() < 1e-5);
        }
    }
}

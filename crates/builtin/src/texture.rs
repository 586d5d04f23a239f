//! Procedural textures evaluated at a 3D position: lattice value noise, fractal noise
//! and the patterns the scenes and the retexture edit use (wood grain, marble veins,
//! checker, stripes, tiles). Every function is pure and deterministic.

use crate::rng::mix;

fn lattice(seed: u64, x: i32, y: i32, z: i32) -> f32 {
    let h = mix(seed
        ^ (x as u32 as u64).wrapping_mul(0x9E37_79B1)
        ^ (y as u32 as u64).wrapping_mul(0x85EB_CA77) << 21
        ^ (z as u32 as u64).wrapping_mul(0xC2B2_AE3D) << 42);
    (h >> 40) as f32 / (1u64 << 24) as f32
}

fn smooth(t: f32) -> f32 {
    t * t * (3.0 - 2.0 * t)
}

/// Value noise in [0, 1] with unit lattice spacing (trilinear, smoothstep-weighted).
pub fn value_noise(seed: u64, p: [f32; 3]) -> f32 {
    let f = p.map(f32::floor);
    let (ix, iy, iz) = (f[0] as i32, f[1] as i32, f[2] as i32);
    let t = [smooth(p[0] - f[0]), smooth(p[1] - f[1]), smooth(p[2] - f[2])];
    let mut acc = 0.0;
    for corner in 0..8 {
        let (dx, dy, dz) = (corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
        let w = (if dx == 1 { t[0] } else { 1.0 - t[0] })
            * (if dy == 1 { t[1] } else { 1.0 - t[1] })
            * (if dz == 1 { t[2] } else { 1.0 - t[2] });
        acc += w * lattice(seed, ix + dx, iy + dy, iz + dz);
    }
    acc
}

/// Fractal (fBm) value noise in [0, 1]: `octaves` octaves, frequency doubling.
pub fn fbm(seed: u64, p: [f32; 3], octaves: u32) -> f32 {
    let (mut sum, mut amp, mut norm, mut freq) = (0.0, 1.0, 0.0, 1.0);
    for o in 0..octaves {
        sum += amp * value_noise(seed.wrapping_add(o as u64 * 7919), p.map(|v| v * freq));
        norm += amp;
        amp *= 0.5;
        freq *= 2.0;
    }
    sum / norm
}

/// Linear interpolation between two colours.
pub fn mix_rgb(a: [f32; 3], b: [f32; 3], t: f32) -> [f32; 3] {
    std::array::from_fn(|k| a[k] + (b[k] - a[k]) * t)
}

/// Scales a colour by a luminance factor and clamps to [0, 1].
pub fn shade(c: [f32; 3], f: f32) -> [f32; 3] {
    c.map(|v| (v * f).clamp(0.0, 1.0))
}

/// Wood grain: rings around an axis parallel to x, distorted by noise; `scale` is the
/// ring spacing in world units. Returns a factor in about [0.7, 1.15].
pub fn wood_grain(seed: u64, p: [f32; 3], scale: f32) -> f32 {
    let n = fbm(seed, [p[0] * 1.5, p[1] * 6.0, p[2] * 6.0], 3);
    let r = (p[1] * p[1] + p[2] * p[2]).sqrt() + 0.6 * n * scale * 4.0 + 0.02 * p[0];
    let ring = (r / scale).fract();
    let grain = fbm(seed ^ 0xA5, [p[0] * 40.0, p[1] * 3.0, p[2] * 3.0], 2);
    0.72 + 0.3 * smooth(ring) * (1.0 - smooth(ring)) * 4.0 * 0.8 + 0.12 * grain
}

/// Marble veins: a factor in [0, 1], 1 on the veins.
pub fn marble_vein(seed: u64, p: [f32; 3], scale: f32) -> f32 {
    let turb = fbm(seed, p.map(|v| v / scale * 2.0), 4);
    let s = ((p[0] + p[1] * 0.7 + p[2] * 0.4) / scale * 3.0 + 8.0 * turb).sin();
    (1.0 - s.abs()).powi(6)
}

/// 3D checker: 0 or 1 with cells of side `cell`.
pub fn checker(p: [f32; 3], cell: f32) -> f32 {
    let s: i64 = p.iter().map(|v| (v / cell).floor() as i64).sum();
    (s.rem_euclid(2)) as f32
}

/// Horizontal stripes (along the world up axis z): 0 or 1, period `period`.
pub fn stripes(p: [f32; 3], period: f32) -> f32 {
    if (p[2] / period).rem_euclid(1.0) < 0.5 {
        1.0
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_bounded_continuous_and_seeded() {
        let mut prev = value_noise(3, [0.0, 0.3, 0.7]);
        for i in 1..200 {
            let p = [i as f32 * 0.01, 0.3, 0.7];
            let v = value_noise(3, p);
            assert!((0.0..=1.0).contains(&v));
            assert!((v - prev).abs() < 0.1, "jump at {p:?}");
            prev = v;
        }
        assert_ne!(value_noise(3, [0.5, 0.5, 0.5]), value_noise(4, [0.5, 0.5, 0.5]));
        assert_eq!(fbm(9, [1.2, -3.4, 5.6], 4), fbm(9, [1.2, -3.4, 5.6], 4));
    }

    #[test]
    fn checker_and_stripes_alternate() {
        assert_ne!(checker([0.05, 0.05, 0.05], 0.1), checker([0.15, 0.05, 0.05], 0.1));
        assert_ne!(stripes([0.0, 0.0, 0.01], 0.1), stripes([0.0, 0.0, 0.06], 0.1));
    }
}

//! Real spherical harmonics up to degree 3 in the 3DGS / gsplat ordering and signs,
//! with the Jacobian of the basis for the view-direction → mean gradient path.

use crate::lanes::Real;
use transsplat_scene::SH_C0 as C0;
const C1: f32 = 0.488_602_5;
const C2: [f32; 5] = [1.092_548_4, -1.092_548_4, 0.315_391_57, -1.092_548_4, 0.546_274_2];
const C3: [f32; 7] =
    [-0.590_043_6, 2.890_611_4, -0.457_045_8, 0.373_176_33, -0.457_045_8, 1.445_305_7, -0.590_043_6];

/// The SH basis `Y_k(d)` for a unit direction `d`, `k < (degree+1)²`; generic over
/// [`Real`] (one direction or eight in lanes, the same bits per lane).
#[inline(always)]
pub fn basis<T: Real>(degree: u32, d: [T; 3]) -> [T; 16] {
    let c = T::from;
    let [x, y, z] = d;
    let mut b = [c(0.0); 16];
    b[0] = c(C0);
    if degree >= 1 {
        b[1] = c(-C1) * y;
        b[2] = c(C1) * z;
        b[3] = c(-C1) * x;
    }
    if degree >= 2 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        b[4] = c(C2[0]) * x * y;
        b[5] = c(C2[1]) * y * z;
        b[6] = c(C2[2]) * (c(2.0) * zz - xx - yy);
        b[7] = c(C2[3]) * x * z;
        b[8] = c(C2[4]) * (xx - yy);
        if degree >= 3 {
            b[9] = c(C3[0]) * y * (c(3.0) * xx - yy);
            b[10] = c(C3[1]) * x * y * z;
            b[11] = c(C3[2]) * y * (c(4.0) * zz - xx - yy);
            b[12] = c(C3[3]) * z * (c(2.0) * zz - c(3.0) * xx - c(3.0) * yy);
            b[13] = c(C3[4]) * x * (c(4.0) * zz - xx - yy);
            b[14] = c(C3[5]) * z * (xx - yy);
            b[15] = c(C3[6]) * x * (xx - c(3.0) * yy);
        }
    }
    b
}

/// `Σ_k g_k ∇Y_k(d)`: the gradient with respect to the (unit) direction of
/// `Σ_k g_k Y_k(d)`, for per-coefficient weights `g_k`; generic as [`basis`].
#[inline(always)]
pub fn basis_vjp<T: Real>(degree: u32, d: [T; 3], g: &[T; 16]) -> [T; 3] {
    let c = T::from;
    let [x, y, z] = d;
    let mut v = [c(0.0); 3];
    let mut add = |k: usize, gx: T, gy: T, gz: T| {
        v[0] += g[k] * gx;
        v[1] += g[k] * gy;
        v[2] += g[k] * gz;
    };
    let zero = c(0.0);
    if degree >= 1 {
        add(1, zero, c(-C1), zero);
        add(2, zero, zero, c(C1));
        add(3, c(-C1), zero, zero);
    }
    if degree >= 2 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        // Constant factors are folded as the scalar source folds them (`-2.0 * C2[2]`).
        add(4, c(C2[0]) * y, c(C2[0]) * x, zero);
        add(5, zero, c(C2[1]) * z, c(C2[1]) * y);
        add(6, c(-2.0 * C2[2]) * x, c(-2.0 * C2[2]) * y, c(4.0 * C2[2]) * z);
        add(7, c(C2[3]) * z, zero, c(C2[3]) * x);
        add(8, c(2.0 * C2[4]) * x, c(-2.0 * C2[4]) * y, zero);
        if degree >= 3 {
            add(9, c(C3[0] * 6.0) * x * y, c(C3[0] * 3.0) * (xx - yy), zero);
            add(10, c(C3[1]) * y * z, c(C3[1]) * x * z, c(C3[1]) * x * y);
            add(
                11,
                c(C3[2] * -2.0) * x * y,
                c(C3[2]) * (c(4.0) * zz - xx - c(3.0) * yy),
                c(C3[2] * 8.0) * y * z,
            );
            add(
                12,
                c(C3[3] * -6.0) * x * z,
                c(C3[3] * -6.0) * y * z,
                c(C3[3]) * (c(6.0) * zz - c(3.0) * xx - c(3.0) * yy),
            );
            add(
                13,
                c(C3[4]) * (c(4.0) * zz - c(3.0) * xx - yy),
                c(C3[4] * -2.0) * x * y,
                c(C3[4] * 8.0) * x * z,
            );
            add(14, c(C3[5] * 2.0) * x * z, c(C3[5] * -2.0) * y * z, c(C3[5]) * (xx - yy));
            add(15, c(C3[6] * 3.0) * (xx - yy), c(C3[6] * -6.0) * x * y, zero);
        }
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vjp_matches_finite_differences() {
        let d = [0.3f32, -0.5, 0.81];
        let g: [f32; 16] = std::array::from_fn(|k| ((k * 7 % 5) as f32 - 2.0) * 0.3);
        let f = |d: [f32; 3]| -> f64 {
            let b = basis(3, d);
            (0..16).map(|k| (b[k] * g[k]) as f64).sum()
        };
        let v = basis_vjp(3, d, &g);
        for a in 0..3 {
            let h = 1e-3f32;
            let (mut p, mut m) = (d, d);
            p[a] += h;
            m[a] -= h;
            let fd = (f(p) - f(m)) / (2.0 * h as f64);
            assert!((fd - v[a] as f64).abs() < 2e-3, "axis {a}: fd {fd} vs {}", v[a]);
        }
    }

    #[test]
    fn basis_is_orthonormal_on_the_sphere() {
        // Monte Carlo-free check: a Fibonacci sphere quadrature of Y_j Y_k ≈ δ_jk / (4π) * 4π.
        let n = 20000;
        let mut gram = [[0.0f64; 16]; 16];
        for i in 0..n {
            let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let phi = i as f64 * std::f64::consts::PI * (3.0 - 5f64.sqrt());
            let b = basis(3, [(r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32]);
            for j in 0..16 {
                for k in 0..16 {
                    gram[j][k] += (b[j] * b[k]) as f64 * 4.0 * std::f64::consts::PI / n as f64;
                }
            }
        }
        for (j, row) in gram.iter().enumerate() {
            for (k, &v) in row.iter().enumerate() {
                let want = if j == k { 1.0 } else { 0.0 };
                assert!((v - want).abs() < 1e-3, "gram[{j}][{k}] = {v}");
            }
        }
    }
}

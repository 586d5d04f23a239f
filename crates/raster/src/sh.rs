//! Real spherical harmonics up to degree 3 in the 3DGS / gsplat ordering and signs,
//! with the Jacobian of the basis for the view-direction → mean gradient path.

use transsplat_scene::SH_C0 as C0;
const C1: f32 = 0.488_602_5;
const C2: [f32; 5] = [1.092_548_4, -1.092_548_4, 0.315_391_57, -1.092_548_4, 0.546_274_2];
const C3: [f32; 7] =
    [-0.590_043_6, 2.890_611_4, -0.457_045_8, 0.373_176_33, -0.457_045_8, 1.445_305_7, -0.590_043_6];

/// The SH basis `Y_k(d)` for a unit direction `d`, `k < (degree+1)²`.
#[inline(always)]
pub fn basis(degree: u32, d: [f32; 3]) -> [f32; 16] {
    let [x, y, z] = d;
    let mut b = [0.0f32; 16];
    b[0] = C0;
    if degree >= 1 {
        b[1] = -C1 * y;
        b[2] = C1 * z;
        b[3] = -C1 * x;
    }
    if degree >= 2 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        b[4] = C2[0] * x * y;
        b[5] = C2[1] * y * z;
        b[6] = C2[2] * (2.0 * zz - xx - yy);
        b[7] = C2[3] * x * z;
        b[8] = C2[4] * (xx - yy);
        if degree >= 3 {
            b[9] = C3[0] * y * (3.0 * xx - yy);
            b[10] = C3[1] * x * y * z;
            b[11] = C3[2] * y * (4.0 * zz - xx - yy);
            b[12] = C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
            b[13] = C3[4] * x * (4.0 * zz - xx - yy);
            b[14] = C3[5] * z * (xx - yy);
            b[15] = C3[6] * x * (xx - 3.0 * yy);
        }
    }
    b
}

/// `Σ_k g_k ∇Y_k(d)`: the gradient with respect to the (unit) direction of
/// `Σ_k g_k Y_k(d)`, for per-coefficient weights `g_k`.
pub fn basis_vjp(degree: u32, d: [f32; 3], g: &[f32; 16]) -> [f32; 3] {
    let [x, y, z] = d;
    let mut v = [0.0f32; 3];
    let mut add = |k: usize, gx: f32, gy: f32, gz: f32| {
        v[0] += g[k] * gx;
        v[1] += g[k] * gy;
        v[2] += g[k] * gz;
    };
    if degree >= 1 {
        add(1, 0.0, -C1, 0.0);
        add(2, 0.0, 0.0, C1);
        add(3, -C1, 0.0, 0.0);
    }
    if degree >= 2 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        add(4, C2[0] * y, C2[0] * x, 0.0);
        add(5, 0.0, C2[1] * z, C2[1] * y);
        add(6, -2.0 * C2[2] * x, -2.0 * C2[2] * y, 4.0 * C2[2] * z);
        add(7, C2[3] * z, 0.0, C2[3] * x);
        add(8, 2.0 * C2[4] * x, -2.0 * C2[4] * y, 0.0);
        if degree >= 3 {
            add(9, C3[0] * 6.0 * x * y, C3[0] * 3.0 * (xx - yy), 0.0);
            add(10, C3[1] * y * z, C3[1] * x * z, C3[1] * x * y);
            add(11, C3[2] * -2.0 * x * y, C3[2] * (4.0 * zz - xx - 3.0 * yy), C3[2] * 8.0 * y * z);
            add(12, C3[3] * -6.0 * x * z, C3[3] * -6.0 * y * z, C3[3] * (6.0 * zz - 3.0 * xx - 3.0 * yy));
            add(13, C3[4] * (4.0 * zz - 3.0 * xx - yy), C3[4] * -2.0 * x * y, C3[4] * 8.0 * x * z);
            add(14, C3[5] * 2.0 * x * z, C3[5] * -2.0 * y * z, C3[5] * (xx - yy));
            add(15, C3[6] * 3.0 * (xx - yy), C3[6] * -6.0 * x * y, 0.0);
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

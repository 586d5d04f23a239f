//! Canonical barycentric edit field (paper Sec. 3.4, Theorem 1; appendix A.3).
//!
//! For Gaussian i with supported views V(i), ω_i^v = w_i^v / (Σ_{v'} w_i^{v'} + δ) and
//! z_i* = argmin_z Σ_v ω_i^v ‖z − y_i^v‖² + ρ ‖z − s_i‖²
//!      = (Σ_v ω_i^v y_i^v + ρ s_i) / (Σ_v ω_i^v + ρ)            (Theorem 1, eq. (closedform)).
//! Across transport rounds the target is smoothed: z̄ ← μ z̄ + (1 − μ) z*
//! (docs/method.md#m5-canonical-fusion).

use crate::view::ViewTransport;

/// A view counts as supporting Gaussian i when w_i^v > `min_support` · a_i^v.
pub fn is_supported(w: f32, a: f32, min_support: f32) -> bool {
    w > 0.0 && w > min_support * a
}

/// Per-Gaussian cross-view sums: Σ_v w_i^v and Σ_v w_i^v y_i^v over supported views.
#[derive(Clone, Debug)]
pub struct Accumulated {
    pub d: usize,
    pub sum_w: Vec<f32>,
    pub sum_wy: Vec<f32>,
}

/// Accumulates the supported views of every Gaussian (`n` Gaussians, latent size `d`).
pub fn accumulate(n: usize, d: usize, views: &[ViewTransport], min_support: f32) -> Accumulated {
    let mut acc = Accumulated { d, sum_w: vec![0.0; n], sum_wy: vec![0.0; n * d] };
    for v in views {
        for (k, &i) in v.idx.iter().enumerate() {
            let (w, a) = (v.w[k], v.a[k]);
            if !is_supported(w, a, min_support) {
                continue;
            }
            let i = i as usize;
            acc.sum_w[i] += w;
            for j in 0..d {
                acc.sum_wy[i * d + j] += w * v.y[k * d + j];
            }
        }
    }
    acc
}

/// Theorem 1's closed form for one Gaussian: z* = (Σ ω y + ρ s)/(Σ ω + ρ), given
/// Σ_v ω_v y_v (`wy`) and Σ_v ω_v (`w`). With no support and ρ = 0, z* = s.
pub fn closed_form(wy: &[f32], w: f32, s: &[f32], rho: f32, out: &mut [f32]) {
    let den = w + rho;
    for j in 0..s.len() {
        out[j] = if den > 0.0 { (wy[j] + rho * s[j]) / den } else { s[j] };
    }
}

/// The canonical targets z* of every Gaussian (`n × d`), from the accumulated views
/// and the current latents `s`. ω is normalised per Gaussian with δ = 1e-8.
pub fn canonical_targets(acc: &Accumulated, s: &[f32], rho: f32) -> Vec<f32> {
    let d = acc.d;
    let mut z = vec![0.0f32; s.len()];
    for i in 0..acc.sum_w.len() {
        let sw = acc.sum_w[i];
        let norm = sw + 1e-8;
        let wy: Vec<f32> = acc.sum_wy[i * d..(i + 1) * d].iter().map(|v| v / norm).collect();
        let w = if sw > 0.0 { sw / norm } else { 0.0 };
        closed_form(&wy, w, &s[i * d..(i + 1) * d], rho, &mut z[i * d..(i + 1) * d]);
    }
    z
}

/// EMA across transport rounds: z̄ ← μ z̄ + (1 − μ) z*; `None` (first round) takes z*.
pub fn ema(prev: Option<&[f32]>, z: &[f32], mu: f32) -> Vec<f32> {
    match prev {
        None => z.to_vec(),
        Some(p) => p.iter().zip(z).map(|(a, b)| mu * a + (1.0 - mu) * b).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Objective of Theorem 1 for one Gaussian.
    fn objective(z: &[f32], ys: &[Vec<f32>], om: &[f32], s: &[f32], rho: f32) -> f32 {
        let d2 = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f32>();
        ys.iter().zip(om).map(|(y, &o)| o * d2(z, y)).sum::<f32>() + rho * d2(z, s)
    }

    #[test]
    fn closed_form_minimises_the_objective_and_obeys_the_stability_bound() {
        let ys = vec![vec![1.0, 0.0, 2.0], vec![0.0, 1.0, -1.0], vec![0.5, 0.5, 0.5]];
        let om = [0.5, 0.3, 0.2];
        let s = [0.1, -0.2, 0.3];
        let rho = 0.7;
        let wy: Vec<f32> = (0..3).map(|j| ys.iter().zip(&om).map(|(y, o)| o * y[j]).sum()).collect();
        let mut z = [0.0; 3];
        closed_form(&wy, om.iter().sum(), &s, rho, &mut z);
        // Direct minimisation by gradient descent from far away reaches the same point.
        let mut x = [10.0f32, -10.0, 5.0];
        for _ in 0..2000 {
            let mut g = [0.0f32; 3];
            for j in 0..3 {
                g[j] = ys.iter().zip(&om).map(|(y, o)| 2.0 * o * (x[j] - y[j])).sum::<f32>()
                    + 2.0 * rho * (x[j] - s[j]);
            }
            for j in 0..3 {
                x[j] -= 0.1 * g[j];
            }
        }
        for j in 0..3 {
            assert!((x[j] - z[j]).abs() < 1e-4, "{x:?} vs {z:?}");
        }
        let f = objective(&z, &ys, &om, &s, rho);
        for k in 0..3 {
            let mut zp = z;
            zp[k] += 1e-2;
            assert!(objective(&zp, &ys, &om, &s, rho) > f);
        }
        // Stability bound (eq. (stability)): perturb observations and the latent.
        let yt = vec![vec![1.2, 0.1, 2.0], vec![0.0, 0.7, -1.0], vec![0.5, 0.5, 0.9]];
        let st = [0.0, -0.2, 0.5];
        let wyt: Vec<f32> = (0..3).map(|j| yt.iter().zip(&om).map(|(y, o)| o * y[j]).sum()).collect();
        let mut zt = [0.0; 3];
        closed_form(&wyt, om.iter().sum(), &st, rho, &mut zt);
        let norm = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f32>().sqrt();
        let lhs = norm(&z, &zt);
        let rhs = (ys.iter().zip(&yt).zip(&om).map(|((y, t), o)| o * norm(y, t)).sum::<f32>()
            + rho * norm(&s, &st))
            / (om.iter().sum::<f32>() + rho);
        assert!(lhs <= rhs + 1e-6, "{lhs} > {rhs}");
        assert!(lhs > 0.2 * rhs, "bound far from tight: the test would not notice a wrong formula");
    }

    #[test]
    fn unsupported_gaussians_keep_their_latent_and_ema_mixes() {
        let acc = Accumulated { d: 2, sum_w: vec![0.0, 2.0], sum_wy: vec![0.0, 0.0, 2.0, 4.0] };
        let s = [0.5, 0.5, 0.0, 0.0];
        let z = canonical_targets(&acc, &s, 1.0);
        assert_eq!(&z[..2], &[0.5, 0.5]);
        // Gaussian 1: ω y = (1, 2), Σ ω = 1, ρ = 1, s = 0 → z = (0.5, 1).
        assert!((z[2] - 0.5).abs() < 1e-6 && (z[3] - 1.0).abs() < 1e-6);
        let e = ema(Some(&[1.0, 1.0, 1.0, 1.0]), &z, 0.75);
        assert!((e[3] - (0.75 + 0.25)).abs() < 1e-6 && (e[2] - (0.75 + 0.125)).abs() < 1e-6);
        assert_eq!(ema(None, &z, 0.9), z);
    }
}

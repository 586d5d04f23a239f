//! Gradients of the TransSplat regularisers (paper Sec. 3.5, eqs. for L_sem, L_uot,
//! L_leak; docs/method.md#m7-losses). L_img is the trainer's photometric loss.

use rayon::prelude::*;

/// L_sem = Σ_i γ_i ‖s_i − sg(z̄_i)‖²: returns the loss and adds λ ∂L/∂s into `grad`.
pub fn semantic(s: &[f32], z: &[f32], gamma: &[f32], d: usize, lambda: f32, grad: &mut [f32]) -> f64 {
    let d = d.max(1);
    let loss: f64 = (s.par_chunks(d), z.par_chunks(d), gamma.par_iter(), grad.par_chunks_mut(d))
        .into_par_iter()
        .with_min_len(4096)
        .map(|(s, z, &g, grad)| {
            let mut loss = 0.0f64;
            for j in 0..s.len() {
                let diff = s[j] - z[j];
                loss += (g * diff * diff) as f64;
                grad[j] += lambda * 2.0 * g * diff;
            }
            loss
        })
        .sum();
    lambda as f64 * loss
}

/// L_leak = (1/N) Σ_{i: γ_i < open} (1 − γ_i) ‖c_i − c_i⁽⁰⁾‖₁ over all SH coefficients
/// (`k` values per Gaussian): returns λ L and adds λ ∂L/∂c into `grad`. The mean over
/// the N Gaussians (not the paper's plain sum) keeps λ independent of the scene size:
/// the per-Gaussian image-loss gradient it competes with also scales like 1/N.
/// Gaussians in the gated region {γ ≥ `open`} are left free (the colour gate,
/// docs/method.md#m7-losses); `open` > 1 anchors every Gaussian (the paper). Only the
/// Gaussians `rows` are visited: any set holding every i with c_i ≠ c_i⁽⁰⁾ gives the
/// same result, as the others add nothing.
#[allow(clippy::too_many_arguments)]
pub fn leakage(
    c: &[f32],
    c0: &[f32],
    gamma: &[f32],
    open: f32,
    k: usize,
    lambda: f32,
    rows: impl Iterator<Item = usize>,
    grad: &mut [f32],
) -> f64 {
    let mut loss = 0.0f64;
    let inv_n = 1.0 / gamma.len().max(1) as f32;
    for (i, g) in rows.map(|i| (i, gamma[i])).filter(|&(_, g)| g < open) {
        let wgt = (1.0 - g) * inv_n;
        for j in i * k..(i + 1) * k {
            let diff = c[j] - c0[j];
            loss += (wgt * diff.abs()) as f64;
            grad[j] += lambda
                * wgt
                * if diff > 0.0 {
                    1.0
                } else if diff < 0.0 {
                    -1.0
                } else {
                    0.0
                };
        }
    }
    lambda as f64 * loss
}

/// ∂⟨C, T*⟩/∂s_i through the semantic cost term at fixed T* (envelope theorem):
/// with ŝ = s/‖s‖, unit e_m and P_i = Σ_m T_im e_m,
/// Σ_m T_im λ_sem ∂(1 − cos(s_i, e_m))/∂s_i = −λ_sem (P_i − (ŝ·P_i) ŝ) / ‖s_i‖.
/// Adds `lambda · that` into `grad` for the Gaussians `idx` (rows of `plan_e`).
pub fn transport_semantic(
    s: &[f32],
    idx: &[u32],
    plan_e: &[f32],
    d: usize,
    lambda_sem: f32,
    lambda: f32,
    grad: &mut [f32],
) {
    for (k, &i) in idx.iter().enumerate() {
        let i = i as usize;
        let si = &s[i * d..(i + 1) * d];
        let p = &plan_e[k * d..(k + 1) * d];
        let n = si.iter().map(|v| v * v).sum::<f32>().sqrt();
        if n <= 1e-12 {
            continue;
        }
        let sp = si.iter().zip(p).map(|(a, b)| a * b).sum::<f32>() / n;
        for j in 0..d {
            grad[i * d + j] += -lambda * lambda_sem * (p[j] - sp * si[j] / n) / n;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn semantic_and_leak_gradients_match_finite_differences() {
        let s = [0.3f32, -0.2, 0.9, 0.1];
        let z = [0.0f32, 0.5, 1.0, 1.0];
        let gamma = [0.8f32, 0.1];
        let mut g = [0.0f32; 4];
        let l0 = semantic(&s, &z, &gamma, 2, 2.0, &mut g);
        for j in 0..4 {
            let mut sp = s;
            sp[j] += 1e-3;
            let mut dummy = [0.0; 4];
            let l1 = semantic(&sp, &z, &gamma, 2, 2.0, &mut dummy);
            assert!(((l1 - l0) / 1e-3 - g[j] as f64).abs() < 1e-2, "{j}");
        }
        let c = [0.5f32, -0.5, 0.2];
        let c0 = [0.4f32, -0.1, 0.2];
        let mut c2 = c.to_vec();
        c2.extend_from_slice(&c0);
        let mut c02 = c0.to_vec();
        c02.extend_from_slice(&c0);
        let mut gc = [0.0f32; 6];
        // Two Gaussians (N = 2): the second is unchanged.
        let l = leakage(&c2, &c02, &[0.25, 0.0], 2.0, 3, 4.0, 0..2, &mut gc);
        assert!((l - 4.0 * 0.75 * 0.5 / 2.0).abs() < 1e-6, "{l}");
        assert_eq!(gc, [1.5, -1.5, 0.0, 0.0, 0.0, 0.0]);
        // With the gated region open at γ ≥ 0.2 the first Gaussian is free.
        let mut gc = [0.0f32; 6];
        assert_eq!(leakage(&c2, &c02, &[0.25, 0.0], 0.2, 3, 4.0, 0..2, &mut gc), 0.0);
        // Visiting only the changed Gaussian gives the same as visiting both.
        let mut g1 = [0.0f32; 6];
        assert_eq!(leakage(&c2, &c02, &[0.25, 0.0], 2.0, 3, 4.0, [0].into_iter(), &mut g1), l);
        assert_eq!(g1, [1.5, -1.5, 0.0, 0.0, 0.0, 0.0]);
        assert_eq!(gc, [0.0; 6]);
    }

    #[test]
    fn transport_gradient_matches_finite_differences_of_the_cost() {
        let e = [[1.0f32, 0.0, 0.0], [0.0, 0.6, 0.8]];
        let t = [0.3f32, 0.7];
        let s = [0.2f32, -0.4, 0.5];
        let cost = |s: &[f32]| -> f32 {
            let n = s.iter().map(|v| v * v).sum::<f32>().sqrt();
            e.iter()
                .zip(&t)
                .map(|(em, tm)| tm * 1.5 * (1.0 - s.iter().zip(em).map(|(a, b)| a * b).sum::<f32>() / n))
                .sum()
        };
        let p: Vec<f32> = (0..3).map(|j| t[0] * e[0][j] + t[1] * e[1][j]).collect();
        let mut g = [0.0f32; 3];
        transport_semantic(&s, &[0], &p, 3, 1.5, 1.0, &mut g);
        for j in 0..3 {
            let (mut a, mut b) = (s, s);
            a[j] += 1e-3;
            b[j] -= 1e-3;
            let fd = (cost(&a) - cost(&b)) / 2e-3;
            assert!((fd - g[j]).abs() < 1e-3, "{j}: {fd} vs {}", g[j]);
        }
    }
}

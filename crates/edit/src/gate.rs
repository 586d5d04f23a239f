//! Transport residual and the leakage gate (paper Sec. 3.5; docs/method.md#m6-residual-and-gate).
//!
//! Relative residual per view r_i^v = [1 − w_i^v / a_i^v]_+ ∈ [0, 1] (the paper's
//! absolute residual scales with 1/|visible set|, which would tie τ_r to the scene).
//! Across views: over the supported views V(i) the residual is ω-weighted; every
//! visible view without support counts as r = 1, in proportion to the source mass the
//! Gaussian has there (a view where it is barely visible weighs little):
//! r_i = f_i Σ_{v∈V(i)} ω_i^v r_i^v + (1 − f_i),  f_i = Σ_{v∈V(i)} a_i^v / Σ_{v∈Vis(i)} a_i^v,
//! so a Gaussian seen but never supported is suppressed. γ_i = exp(−r_i / τ_r).
//! Gaussians visible in no view get r = 1.

use crate::fusion::is_supported;
use crate::view::ViewTransport;

/// Per-Gaussian aggregated relative residual r_i ∈ [0, 1].
pub fn residuals(n: usize, views: &[ViewTransport], min_support: f32) -> Vec<f32> {
    let mut sum_w = vec![0.0f32; n];
    let mut sum_wr = vec![0.0f32; n];
    let mut seen = vec![0.0f32; n];
    let mut supported = vec![0.0f32; n];
    for v in views {
        for (k, &i) in v.idx.iter().enumerate() {
            let i = i as usize;
            let (w, a) = (v.w[k], v.a[k]);
            seen[i] += a;
            if is_supported(w, a, min_support) {
                supported[i] += a;
                let r = (1.0 - w / a).max(0.0);
                sum_w[i] += w;
                sum_wr[i] += w * r;
            }
        }
    }
    (0..n)
        .map(|i| {
            if seen[i] <= 0.0 {
                return 1.0;
            }
            let frac = supported[i] / seen[i];
            let rs = if sum_w[i] > 0.0 { sum_wr[i] / sum_w[i] } else { 1.0 };
            (frac * rs + (1.0 - frac)).clamp(0.0, 1.0)
        })
        .collect()
}

/// γ_i = exp(−r_i / τ_r) (paper eq. for γ_i).
pub fn gate(residual: &[f32], tau_r: f32) -> Vec<f32> {
    residual.iter().map(|&r| (-r / tau_r.max(1e-12)).exp()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(idx: Vec<u32>, a: Vec<f32>, w: Vec<f32>) -> ViewTransport {
        ViewTransport { idx, a, w, ..Default::default() }
    }

    #[test]
    fn residual_by_hand() {
        // Gaussian 0: two views, both supported: w/a = 1 (r 0, w 0.2) and 0.5 (r 0.5, w 0.1)
        //   → r = (0.2·0 + 0.1·0.5)/0.3 = 1/6.
        // Gaussian 1: visible in both with mass 0.1 each, supported in one with r = 0
        //   → f = 0.5, r = 0.5·0 + 0.5 = 0.5.
        // Gaussian 2: never visible → 1. Gaussian 3: visible, never supported → 1.
        let v1 = view(vec![0, 1, 3, 4], vec![0.2, 0.1, 0.3, 0.3], vec![0.2, 0.3, 0.0, 0.4]);
        let v2 = view(vec![0, 1, 4], vec![0.2, 0.1, 0.1], vec![0.1, 0.0, 0.0]);
        let r = residuals(5, &[v1, v2], 1e-3);
        // Gaussian 4: supported (r = 0) where its mass is 0.3, unsupported where 0.1 → r = 0.25.
        let want = [1.0 / 6.0, 0.5, 1.0, 1.0, 0.25];
        for (a, b) in r.iter().zip(want) {
            assert!((a - b).abs() < 1e-6, "{r:?}");
        }
        let g = gate(&r, 0.5);
        assert!((g[0] - (-1.0f32 / 3.0).exp()).abs() < 1e-6);
        assert!((g[2] - (-2.0f32).exp()).abs() < 1e-6);
    }
}

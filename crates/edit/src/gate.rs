//! Transport residual and the leakage gate (paper Sec. 3.5; docs/method.md#m6-residual-and-gate).
//!
//! Relative residual per view r_i^v = [1 − w_i^v / a_i^v]_+ ∈ [0, 1] (the paper's
//! absolute residual scales with 1/|visible set|, which would tie τ_r to the scene).
//! Two ways to aggregate it across views ([`Agreement`]):
//!
//! - [`Agreement::Visibility`] (default): every view that sees the Gaussian has a say
//!   in proportion to its blend weight W_i^v = Σ_p T_i(p) α_i(p) there (the weight
//!   L_img gives the view; [`ViewWeight`]),
//!   r_i = 1 − Σ_{v∈Vis(i)} σ̃_i^v W_i^v / Σ_{v∈Vis(i)} W_i^v, with σ̃ the view's
//!   support ([`ViewTransport::view_support`]: the plan's relative support, bounded
//!   by the Gaussian's coverage with `fusion.coverage`),
//!   so support in one view cannot outvote the views that see the Gaussian well and
//!   leave it unsupported (a 2D editor's spill or blob lands on different Gaussians in
//!   different views; the target is supported wherever it is seen).
//! - [`Agreement::Transport`] (the paper's App. A.4: "the same normalized weights as
//!   the canonical fusion"): over the supported views V(i) the residual is ω-weighted,
//!   ω ∝ w, and every visible view without support counts as r = 1 in proportion to
//!   its source mass: r_i = f_i Σ_{v∈V(i)} ω_i^v r_i^v + (1 − f_i),
//!   f_i = Σ_{v∈V(i)} a_i^v / Σ_{v∈Vis(i)} a_i^v. Weighting by w lets the one view that
//!   supports a Gaussian most decide for it.
//!
//! γ_i = exp(−r_i / τ_r). Gaussians visible in no view get r = 1.

use crate::fusion::is_supported;
use crate::view::ViewTransport;
use serde::{Deserialize, Serialize};

/// How per-view residuals are combined across views (see the module doc).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Agreement {
    /// Every view that sees the Gaussian has its say ([`ViewWeight`]).
    #[default]
    Visibility,
    /// Weighted by the transported mass over the supported views (the paper).
    Transport,
}

/// How much say a view has in [`Agreement::Visibility`] (`fusion.view_weight`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ViewWeight {
    /// The Gaussian's source mass a_i^v in the view (its visibility × opacity as a
    /// share of the view's).
    Mass,
    /// The Gaussian's blend weight in the view, Σ_p T_i(p) α_i(p) over its pixels: the
    /// weight the image loss gives the view when it recolours the Gaussian. The default:
    /// the colour gate opens L_img on a Gaussian, so the views that carry most of
    /// L_img's pull on it must support it (docs/method.md#m6-residual-and-gate).
    #[default]
    Blend,
}

/// How the residual is aggregated: the fusion settings it reads (`fusion.agreement`,
/// `fusion.coverage`, `fusion.min_support`, `fusion.view_weight`).
#[derive(Clone, Copy, Debug)]
pub struct Aggregation {
    pub agreement: Agreement,
    pub coverage: bool,
    pub min_support: f32,
    pub view_weight: ViewWeight,
}

/// Per-Gaussian aggregated relative residual r_i ∈ [0, 1].
pub fn residuals(n: usize, views: &[ViewTransport], how: Aggregation) -> Vec<f32> {
    match how.agreement {
        Agreement::Visibility => visibility_residuals(n, views, how.coverage, how.view_weight),
        Agreement::Transport => transport_residuals(n, views, how.min_support),
    }
}

/// r_i = [1 − Σ_v σ̃_i^v ϖ_i^v / Σ_v ϖ_i^v]_+ over the views that see i (σ̃ the view's
/// support, bounded by coverage when `coverage`; ϖ the view's say, [`ViewWeight`]: the
/// source mass a, or the blend weight where every view knows it); 1 if none does.
pub fn visibility_residuals(
    n: usize,
    views: &[ViewTransport],
    coverage: bool,
    weight: ViewWeight,
) -> Vec<f32> {
    let (mut w, mut a) = (vec![0.0f64; n], vec![0.0f64; n]);
    // Blend weights only where every view knows them (a plan from an older checkpoint
    // does not), so the views' says stay in one unit.
    let blend = weight == ViewWeight::Blend && views.iter().all(|v| v.blend.len() == v.a.len());
    for v in views {
        let say: &[f32] = if blend { &v.blend } else { &v.a };
        for ((&i, &sk), &ak) in v.idx.iter().zip(&v.view_support(coverage)).zip(say) {
            if (i as usize) < n {
                w[i as usize] += (sk * ak) as f64;
                a[i as usize] += ak as f64;
            }
        }
    }
    w.iter()
        .zip(&a)
        .map(|(&w, &a)| if a > 0.0 { (1.0 - w / a).clamp(0.0, 1.0) as f32 } else { 1.0 })
        .collect()
}

/// The paper's ω-weighted aggregation over supported views (module doc).
fn transport_residuals(n: usize, views: &[ViewTransport], min_support: f32) -> Vec<f32> {
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

    /// A view whose plan hands out exactly its target mass (Σ w = B_v).
    fn view(idx: Vec<u32>, a: Vec<f32>, w: Vec<f32>) -> ViewTransport {
        let target_mass = w.iter().sum();
        ViewTransport { idx, a, w, target_mass, ..Default::default() }
    }

    #[test]
    fn a_view_has_its_say_by_mass_or_by_blend_weight() {
        // Gaussian 0: view A supports it (σ = 1: the only source, ρ = 1 = t) where its
        // mass is 0.1 and its blend weight 9; view B leaves it unsupported (σ = 0: source
        // 1 alone holds B's evidence mass) where its mass is 0.45 and its blend weight 1.
        let mut va = view(vec![0], vec![0.1], vec![0.1]);
        va.blend = vec![9.0].into();
        let mut vb = view(vec![0, 1], vec![0.45, 0.45], vec![0.0, 0.45]);
        vb.blend = vec![1.0, 4.0].into();
        let how = |view_weight| Aggregation {
            agreement: Agreement::Visibility,
            coverage: false,
            min_support: 1e-3,
            view_weight,
        };
        // By mass: r = 1 − 0.1 / 0.55; by blend weight: r = 1 − 9 / 10.
        let r = residuals(2, &[va.clone(), vb.clone()], how(ViewWeight::Mass));
        assert!((r[0] - (1.0 - 0.1 / 0.55)).abs() < 1e-6, "{r:?}");
        let r = residuals(2, &[va.clone(), vb.clone()], how(ViewWeight::Blend));
        assert!((r[0] - 0.1).abs() < 1e-6 && r[1].abs() < 1e-6, "{r:?}");
        // A view that does not know its blend weights (an older checkpoint's plan): every
        // view has its say by mass.
        vb.blend = Default::default();
        let r = residuals(2, &[va, vb], how(ViewWeight::Blend));
        assert!((r[0] - (1.0 - 0.1 / 0.55)).abs() < 1e-6, "{r:?}");
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
        let fusion = |agreement, coverage| Aggregation {
            agreement,
            coverage,
            min_support: 1e-3,
            view_weight: ViewWeight::Mass,
        };
        let r = residuals(5, &[v1.clone(), v2.clone()], fusion(Agreement::Transport, true));
        // Gaussian 4: supported (r = 0) where its mass is 0.3, unsupported where 0.1 → r = 0.25.
        let want = [1.0 / 6.0, 0.5, 1.0, 1.0, 0.25];
        for (a, b) in r.iter().zip(want) {
            assert!((a - b).abs() < 1e-6, "{r:?}");
        }
        // By visibility, with the relative support σ of each view:
        // view A: a (0.5, 0.3, 0.2), w (1.0, 0.3, 0.05), B 0.5 → ρ (2, 1, 0.25); the
        //   best-ranked source alone holds B, so t = 2 and σ = (1, 0.5, 0.125);
        // view B: Gaussians 0 and 2 with a (0.4, 0.6), w (0, 0.6), B 0.6 → t = 1, σ = (0, 1).
        // r = 1 − Σ σa / Σ a: G0 1 − 0.5/0.9; G1 1 − 0.15/0.3; G2 1 − 0.625/0.8; G3 unseen 1.
        let mut va = view(vec![0, 1, 2], vec![0.5, 0.3, 0.2], vec![1.0, 0.3, 0.05]);
        va.target_mass = 0.5;
        let vb = view(vec![0, 2], vec![0.4, 0.6], vec![0.0, 0.6]);
        let r = residuals(4, &[va.clone(), vb.clone()], fusion(Agreement::Visibility, false));
        let want = [1.0 - 0.5 / 0.9, 0.5, 1.0 - 0.625 / 0.8, 1.0];
        for (a, b) in r.iter().zip(want) {
            assert!((a - b).abs() < 1e-6, "{r:?}");
        }
        // A plan that moved less than its target mass: σ depends only on the ranking.
        let mut v3 = view(vec![0, 1], vec![0.4, 0.6], vec![0.1, 0.0]);
        v3.target_mass = 0.2;
        let r = residuals(2, &[v3], fusion(Agreement::Visibility, false));
        assert!(r[0].abs() < 1e-6 && (r[1] - 1.0).abs() < 1e-6, "{r:?}");
        // Coverage: view A's sources cover ω = (1, 0.25, 0.5) of their footprint with
        // its support, view B's (0.16, 1); σ is A (1, 0.5, 0.125), B (0, 1), so
        // σ̃ = min(σ, ω) is A (1, 0.25, 0.125), B (0, 1); without ω known (empty) a view
        // keeps σ.
        va.coverage = vec![1.0, 0.25, 0.5].into();
        let mut vb_cov = vb.clone();
        vb_cov.coverage = vec![0.16, 1.0].into();
        let r = residuals(4, &[va.clone(), vb_cov], fusion(Agreement::Visibility, true));
        let want = [1.0 - 0.5 / 0.9, 0.75, 1.0 - (0.2 * 0.125 + 0.6) / 0.8, 1.0];
        for (a, b) in r.iter().zip(want) {
            assert!((a - b).abs() < 1e-6, "{r:?}");
        }
        let r = residuals(4, &[va, vb], fusion(Agreement::Visibility, true));
        assert!((r[2] - (1.0 - (0.2 * 0.125 + 0.6 * 1.0) / 0.8)).abs() < 1e-6, "{r:?}");
        let g = gate(&[1.0 / 6.0, 0.0, 1.0], 0.5);
        assert!((g[0] - (-1.0f32 / 3.0).exp()).abs() < 1e-6);
        assert!((g[2] - (-2.0f32).exp()).abs() < 1e-6);
    }
}

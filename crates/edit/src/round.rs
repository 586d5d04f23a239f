//! One transport round (paper Sec. 3.3–3.5; docs/method.md#m9-the-edit-loop): per
//! view the source side (visible Gaussians, masses, projected means, appearance
//! descriptors), the view-wise UOT against the view's prototypes ([`crate::view`]),
//! then canonical fusion with EMA ([`crate::fusion`]) and the gate
//! ([`crate::gate`]). Views are solved in parallel.

use crate::error::EditError;
use crate::fusion::{accumulate, canonical_targets, ema};
use crate::prototypes::Prototypes;
use crate::view::{self, TransportConfig, ViewTransport};
use crate::{gate, EditConfig};
use rayon::prelude::*;
use transsplat_raster::{gaussian_stats_capped, Splats};
use transsplat_scene::{sigmoid, Camera, Gaussians};

/// Statistics of one transport round.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct RoundStats {
    pub round: usize,
    pub step: usize,
    /// The views with a plan: those with prototypes and those under the attention floor.
    pub views: usize,
    pub objective: f64,
    pub dual: f64,
    pub gap: f64,
    pub transported_mass: f64,
    pub mean_gate: f64,
    pub seconds: f64,
}

/// One edit view as a transport round sees it: its camera, appearance plane Φ_v,
/// evidence plane ([`crate::prototypes::evidence_plane`], `H × W`; empty: unknown) and prototypes (empty when the view carries no
/// evidence).
pub struct RoundView<'a> {
    pub cam: &'a Camera,
    pub appearance: &'a [f32],
    pub d_app: usize,
    pub support: &'a [f32],
    pub prototypes: &'a Prototypes,
    /// The view's attention stayed under the floor ([`crate::prototypes::below_floor`]):
    /// it has no prototypes, and takes part in the gate as a view that sees its
    /// Gaussians and supports none of them.
    pub unedited: bool,
}

/// The source side of one view's transport: visible Gaussians, masses a_i^v,
/// projected means, normalised appearance descriptors φ_i^v and each one's coverage
/// ω_i^v, the evidence plane splatted back (empty when it is unknown).
#[derive(Clone, Debug, Default)]
pub struct ViewSources {
    pub idx: Vec<u32>,
    pub a: Vec<f32>,
    pub m2d: Vec<[f32; 2]>,
    pub phi: Vec<f32>,
    pub omega: std::sync::Arc<[f32]>,
    /// Each source's blend weight in the view, Σ_p T_i(p) α_i(p); kept only when
    /// `fusion.view_weight = "blend"` reads it (empty otherwise).
    pub blend: std::sync::Arc<[f32]>,
}

/// The appearance plane with the evidence plane appended as one more channel, so one splat-back
/// pass lifts both.
fn with_support(appearance: &[f32], d_app: usize, support: &[f32]) -> Vec<f32> {
    let mut out = Vec::with_capacity(support.len() * (d_app + 1));
    for (p, &o) in support.iter().enumerate() {
        out.extend_from_slice(&appearance[p * d_app..(p + 1) * d_app]);
        out.push(o);
    }
    out
}

/// The source side of every view (empty for views without prototypes, unless the view
/// is under the attention floor, [`RoundView::unedited`]), from one
/// splat-back pass per view (docs/method.md#m1-visibility-and-source-masses); each
/// source's blend weight is kept with `keep_blend`.
pub fn view_sources(g: &Gaussians, views: &[RoundView], keep_blend: bool) -> Vec<ViewSources> {
    let opacity: Vec<f32> = g.opacity_logits.iter().map(|&o| sigmoid(o)).collect();
    let splats = Splats::new(g);
    views
        .par_iter()
        .map(|v| {
            if v.prototypes.is_empty() && !v.unedited {
                return ViewSources::default();
            }
            let has_support = !v.support.is_empty();
            let plane = has_support.then(|| with_support(v.appearance, v.d_app, v.support));
            let (img, ch) = match &plane {
                Some(p) => (p.as_slice(), v.d_app + 1),
                None => (v.appearance, v.d_app),
            };
            // The evidence channel is splatted back capped: ω_i = Σ_p min(w_i(p), E(p)) / Σ_p w_i(p).
            let st = gaussian_stats_capped(&splats, v.cam, Some((img, ch)), has_support as usize);
            let (idx, a) = view::source_masses(&st.visibility, &opacity);
            let m2d: Vec<[f32; 2]> = idx.iter().map(|&i| st.means2d[i as usize]).collect();
            let mut phi: Vec<f32> = Vec::with_capacity(idx.len() * v.d_app);
            let mut omega = Vec::new();
            for &i in &idx {
                let row = &st.splat[i as usize * ch..(i as usize + 1) * ch];
                let mut p = row[..v.d_app].to_vec();
                crate::normalize(&mut p, 1e-8);
                phi.extend(p);
                if has_support {
                    omega.push(row[v.d_app]);
                }
            }
            let blend: Vec<f32> = if keep_blend {
                idx.iter().map(|&i| st.weight_sum[i as usize]).collect()
            } else {
                Vec::new()
            };
            ViewSources { idx, a, m2d, phi, omega: omega.into(), blend: blend.into() }
        })
        .collect()
}

/// The view-wise transport of every view with prototypes, against the current
/// semantic latents `s` (`N × d`), and the zero plan ([`unsupported`]) of every view
/// under the attention floor; `views` and `sources` are aligned, and each result
/// carries its view's camera index from `cam_index`.
pub fn solve_views(
    s: &[f32],
    d: usize,
    views: &[RoundView],
    cam_index: &[usize],
    sources: &[ViewSources],
    cfg: &TransportConfig,
) -> Result<Vec<ViewTransport>, EditError> {
    let diag = |c: &Camera| ((c.width as f32).powi(2) + (c.height as f32).powi(2)).sqrt();
    views
        .par_iter()
        .zip(sources)
        .zip(cam_index)
        .filter(|((v, _), _)| !v.prototypes.is_empty() || v.unedited)
        .map(|((v, src), &cam)| {
            if v.prototypes.is_empty() {
                return Ok(unsupported(src, cam, d, cfg.delta));
            }
            let sv: Vec<f32> = src
                .idx
                .iter()
                .flat_map(|&i| s[i as usize * d..(i as usize + 1) * d].iter().copied())
                .collect();
            let b = view::evidence_masses(&src.a, &src.omega, &src.m2d, v.prototypes, cfg);
            let mut t = view::transport(
                src.idx.clone(),
                src.a.clone(),
                &src.m2d,
                &sv,
                &src.phi,
                v.prototypes,
                &b,
                diag(v.cam),
                cfg,
            )?;
            t.view = cam;
            t.coverage = std::sync::Arc::clone(&src.omega);
            t.blend = std::sync::Arc::clone(&src.blend);
            Ok(t)
        })
        .collect()
}

/// The plan of a view below the attention floor ([`RoundView::unedited`]): it sees its
/// sources and moves no mass to any of them, so in the gate each is a visible view
/// without support (σ = 0; in the paper's aggregation r = 1), and fusion and L_uot
/// get nothing from it.
fn unsupported(src: &ViewSources, cam: usize, d: usize, delta: f32) -> ViewTransport {
    let n = src.idx.len();
    ViewTransport {
        view: cam,
        idx: src.idx.clone(),
        a: src.a.clone(),
        w: vec![0.0; n],
        y: vec![0.0; n * d],
        delta,
        coverage: vec![0.0; n].into(),
        blend: std::sync::Arc::clone(&src.blend),
        ..Default::default()
    }
}

/// What the transport rounds carry from one round to the next.
#[derive(Clone, Debug)]
pub struct TransportState {
    /// Gate γ_i (1 before the first round).
    pub gamma: Vec<f32>,
    /// EMA of the canonical targets z̄_i (`N × d`), `None` before the first round.
    pub zbar: Option<Vec<f32>>,
    /// The last round's view plans (for L_uot).
    pub cached: Vec<ViewTransport>,
}

impl TransportState {
    pub fn new(n: usize) -> Self {
        TransportState { gamma: vec![1.0; n], zbar: None, cached: Vec::new() }
    }

    /// The transported support of each Gaussian over the last round's views,
    /// `Σ_v ŵ_i^v / Σ_v a_i^v` in [0, 1] (0 where no view saw it; ŵ the evidence
    /// shares, [`ViewTransport::evidence_shares`]): 1 − the visibility-weighted
    /// residual of [`gate`].
    pub fn support(&self, coverage: bool, weight: gate::ViewWeight) -> Vec<f32> {
        let r = gate::visibility_residuals(self.gamma.len(), &self.cached, coverage, weight);
        r.iter().map(|r| 1.0 - r).collect()
    }

    /// Fuses this round's view plans into z̄ and γ (Theorem 1, EMA, gate) for the
    /// latents `s` (`N × d`) and returns the round's statistics (`round` left 0).
    pub fn update(&mut self, plans: Vec<ViewTransport>, s: &[f32], d: usize, cfg: &EditConfig) -> RoundStats {
        let n = self.gamma.len();
        let f = &cfg.fusion;
        let acc = accumulate(n, d, &plans, f.min_support);
        let z = canonical_targets(&acc, s, f.rho);
        self.zbar = Some(ema(self.zbar.as_deref(), &z, f.ema));
        let how = gate::Aggregation {
            agreement: f.agreement,
            coverage: f.coverage,
            min_support: f.min_support,
            view_weight: f.view_weight,
        };
        self.gamma = gate::gate(&gate::residuals(n, &plans, how), f.tau_r);
        self.cached = plans;
        let v = &self.cached;
        RoundStats {
            views: v.len(),
            objective: v.iter().map(|v| v.objective).sum(),
            dual: v.iter().map(|v| v.dual).sum(),
            gap: v.iter().map(|v| v.gap).sum(),
            transported_mass: v.iter().map(|v| v.transported_mass).sum(),
            mean_gate: self.gamma.iter().map(|&x| x as f64).sum::<f64>() / n.max(1) as f64,
            ..Default::default()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gate::{residuals, Aggregation, Agreement, ViewWeight};

    /// A view under the attention floor sees Gaussians 0 and 2 and supports neither: by
    /// hand, with a view that fully supports Gaussian 0 (σ = 1, blend weight 2) beside it
    /// (blend weight 2 there too), r_0 = 1 − (1·2 + 0·2)/(2 + 2) = 0.5, where without it r_0
    /// = 0; Gaussian 2, seen by it alone, gets r = 1. In the paper's aggregation its view
    /// counts as visible and unsupported: r_0 = (0.3 / 0.8)·1 = 0.375. Fusion gets nothing
    /// from it.
    #[test]
    fn a_view_under_the_floor_rejects_what_it_sees() {
        let edited = ViewTransport {
            idx: vec![0, 1],
            a: vec![0.5, 0.5],
            w: vec![0.5, 0.0],
            y: vec![1.0; 4],
            target_mass: 0.5,
            blend: vec![2.0, 1.0].into(),
            ..Default::default()
        };
        let src = ViewSources {
            idx: vec![0, 2],
            a: vec![0.3, 0.7],
            blend: vec![2.0, 1.0].into(),
            ..Default::default()
        };
        let unedited = unsupported(&src, 7, 2, 1e-8);
        assert_eq!((unedited.view, unedited.w.as_slice(), unedited.y.len()), (7, &[0.0f32, 0.0][..], 4));
        let how = |agreement| Aggregation {
            agreement,
            coverage: true,
            min_support: 1e-3,
            view_weight: ViewWeight::Blend,
        };
        let alone = residuals(4, std::slice::from_ref(&edited), how(Agreement::Visibility));
        assert_eq!(alone, vec![0.0, 1.0, 1.0, 1.0]);
        let both = [edited, unedited];
        assert_eq!(residuals(4, &both, how(Agreement::Visibility)), vec![0.5, 1.0, 1.0, 1.0]);
        let paper = residuals(4, &both, how(Agreement::Transport));
        assert!((paper[0] - 0.375).abs() < 1e-6 && paper[2] == 1.0, "{paper:?}");
        let with = crate::fusion::accumulate(4, 2, &both, 1e-3);
        let without = crate::fusion::accumulate(4, 2, &both[..1], 1e-3);
        assert_eq!((with.sum_w, with.sum_wy), (without.sum_w, without.sum_wy));
    }

    /// `solve_views` makes the zero plan for a view without prototypes only when it is
    /// under the floor, with that view's camera index; otherwise the view has no plan.
    #[test]
    fn only_a_view_under_the_floor_gets_a_plan_without_prototypes() {
        let cam = crate::edits::tests::camera("a");
        let none = Prototypes::default();
        let src = ViewSources { idx: vec![0, 2], a: vec![0.3, 0.7], ..Default::default() };
        let plans = |unedited| {
            let view =
                RoundView { cam: &cam, appearance: &[], d_app: 0, support: &[], prototypes: &none, unedited };
            solve_views(&[0.0; 6], 2, &[view], &[5], std::slice::from_ref(&src), &TransportConfig::default())
                .unwrap()
        };
        let p = plans(true);
        assert_eq!(p.len(), 1);
        assert_eq!((p[0].view, &p[0].idx, &p[0].w), (5, &vec![0, 2], &vec![0.0, 0.0]));
        assert!(plans(false).is_empty());
    }
}

//! View-wise unbalanced semantic transport (paper Sec. 3.3, eq. (5); appendix A.2).
//!
//! Sources are the Gaussians visible in the view with masses a_i ∝ ν_i α_i; targets
//! are the view's prototypes with masses b_m. The cost is
//! C_im = λ_geo ‖Π(x_i) − u_m‖² / diag² + λ_sem (1 − cos(s_i, e_m)) + λ_app (1 − cos(φ_i, ψ_m)),
//! geometric term normalised by the image diagonal
//! (docs/method.md#m3-transport-cost-and-features). The transport crate solves it;
//! this module turns the plan into w_i, y_i and the statistics.

use crate::prototypes::Prototypes;
use transsplat_transport::{solve, Params, Problem};

/// Weights and solver settings of the view-wise transport.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TransportConfig {
    /// λ_geo (on coordinates divided by the image diagonal).
    pub lambda_geo: f32,
    /// λ_sem, semantic cosine term.
    pub lambda_sem: f32,
    /// λ_app, appearance cosine term.
    pub lambda_app: f32,
    /// Entropic regularisation ε.
    pub eps: f64,
    /// Source marginal relaxation τ_s.
    pub tau_s: f64,
    /// Target marginal relaxation τ_t.
    pub tau_t: f64,
    /// Sinkhorn sweeps.
    pub iters: usize,
    /// Each prototype keeps its k cheapest Gaussians; 0 = dense (the default; the
    /// paper's 128 is available).
    pub top_k: usize,
    /// δ in y_i = Σ T e / (Σ T + δ).
    pub delta: f32,
    /// Evidence-mass balancing ([`evidence_masses`]; docs/method.md#m4-the-uot-solver):
    /// each prototype's mass is the source mass its region covers, instead of its share
    /// of the attention with Σ b = 1 (the paper's App. A.1 normalisation).
    pub evidence_mass: bool,
}

impl Default for TransportConfig {
    fn default() -> Self {
        TransportConfig {
            lambda_geo: 40.0,
            lambda_sem: 1.0,
            lambda_app: 1.0,
            eps: 0.05,
            tau_s: 0.5,
            tau_t: 10.0,
            iters: 30,
            // Dense by default: top-k starves the target (each prototype reaches only its
            // k cheapest Gaussians, so most target Gaussians get no support and the gate
            // closes on them). See docs/cli.md, "Transport support".
            top_k: 0,
            delta: 1e-8,
            evidence_mass: true,
        }
    }
}

/// Source masses a_i^v = ν_i α_i / Σ_j ν_j α_j over the visible set (appendix A.2,
/// eq. for a_i^v; docs/method.md#m1-visibility-and-source-masses). Returns (visible
/// indices, masses); Gaussians with zero visibility or opacity are not part of the
/// visible set.
pub fn source_masses(visibility: &[f32], opacity: &[f32]) -> (Vec<u32>, Vec<f32>) {
    let mut idx = Vec::new();
    let mut a = Vec::new();
    for (i, (&v, &o)) in visibility.iter().zip(opacity).enumerate() {
        let m = v * o;
        if m > 0.0 && m.is_finite() {
            idx.push(i as u32);
            a.push(m);
        }
    }
    let s: f64 = a.iter().map(|&x| x as f64).sum();
    if s > 0.0 {
        for x in a.iter_mut() {
            *x = (*x as f64 / s) as f32;
        }
    }
    (idx, a)
}

/// Adds `lambda` (1 − cos(x, y_j)) to `row[j]` for every unit row y_j of `yt`
/// (stored transposed: `yt[k * m + j]` = y_j[k]), accumulating the dot products in
/// `dot` (`m` long) so they vectorise over the prototypes; 1 − cos is 1 for x = 0.
#[inline(always)]
fn add_cosine_distances(row: &mut [f32], lambda: f32, x: &[f32], yt: &[f32], dot: &mut [f32]) {
    let n = x.iter().map(|v| v * v).sum::<f32>().sqrt();
    if n.is_nan() || n <= 0.0 {
        row.iter_mut().for_each(|c| *c += lambda * if n.is_nan() { n } else { 1.0 });
        return;
    }
    let m = row.len();
    dot.fill(0.0);
    for (k, &xk) in x.iter().enumerate() {
        for (dj, &yj) in dot.iter_mut().zip(&yt[k * m..(k + 1) * m]) {
            *dj += xk * yj;
        }
    }
    for (c, &dj) in row.iter_mut().zip(dot.iter()) {
        *c += lambda * (1.0 - dj / n);
    }
}

/// `rows × cols` row-major → `cols × rows`.
fn transposed(v: &[f32], rows: usize, cols: usize) -> Vec<f32> {
    let mut t = vec![0.0f32; v.len()];
    for r in 0..rows {
        for c in 0..cols {
            t[c * rows + r] = v[r * cols + c];
        }
    }
    t
}

/// The three-term cost (paper eq. (4) / appendix eq. for C_im^v), row-major
/// `n × m` for the `n` visible Gaussians given by their projected means (pixels),
/// semantic latents `s` (`n × d`) and appearance descriptors `phi` (`n × d_a`).
pub fn cost(
    means2d: &[[f32; 2]],
    s: &[f32],
    phi: &[f32],
    protos: &Prototypes,
    diag: f32,
    cfg: &TransportConfig,
) -> Vec<f32> {
    use rayon::prelude::*;
    let m = protos.len();
    let rows = CostRows {
        means2d,
        s,
        phi,
        protos,
        et: transposed(&protos.e, m, protos.d),
        psit: transposed(&protos.psi, m, protos.d_app),
        inv: 1.0 / (diag * diag),
        cfg,
    };
    let avx2 = transsplat_scene::cpu::has_avx2();
    const CHUNK: usize = 256;
    let mut c = vec![0.0f32; means2d.len() * m];
    c.par_chunks_mut((CHUNK * m).max(1)).enumerate().for_each_init(
        || vec![0.0f32; m],
        |dot, (k, chunk)| {
            #[cfg(target_arch = "x86_64")]
            if avx2 {
                // SAFETY: AVX2 and FMA detected at run time.
                return unsafe { rows.run_avx2(k * CHUNK, chunk, dot) };
            }
            rows.run(k * CHUNK, chunk, dot)
        },
    );
    c
}

/// [`cost`] over a chunk of rows; the prototypes' semantics and appearances are stored
/// transposed (`et`, `psit`) so each row's dot products vectorise over the prototypes.
struct CostRows<'a> {
    means2d: &'a [[f32; 2]],
    s: &'a [f32],
    phi: &'a [f32],
    protos: &'a Prototypes,
    et: Vec<f32>,
    psit: Vec<f32>,
    inv: f32,
    cfg: &'a TransportConfig,
}

impl CostRows<'_> {
    /// Rows `i0..` of the cost into `c` (whole rows of `m` entries).
    #[inline(always)]
    fn run(&self, i0: usize, c: &mut [f32], dot: &mut [f32]) {
        let (m, d, da, cfg) = (self.protos.len(), self.protos.d, self.protos.d_app, self.cfg);
        for (r, row) in c.chunks_exact_mut(m.max(1)).enumerate() {
            let i = i0 + r;
            let p = self.means2d[i];
            for (cij, u) in row.iter_mut().zip(&self.protos.u) {
                let du = [p[0] - u[0], p[1] - u[1]];
                *cij = cfg.lambda_geo * (du[0] * du[0] + du[1] * du[1]) * self.inv;
            }
            if cfg.lambda_sem != 0.0 {
                add_cosine_distances(row, cfg.lambda_sem, &self.s[i * d..(i + 1) * d], &self.et, dot);
            }
            if cfg.lambda_app != 0.0 {
                add_cosine_distances(row, cfg.lambda_app, &self.phi[i * da..(i + 1) * da], &self.psit, dot);
            }
            // NaN stays NaN so the transport crate reports it; rounding below 0 is clipped.
            for cij in row.iter_mut() {
                if !cij.is_nan() {
                    *cij = cij.max(0.0);
                }
            }
        }
    }

    /// [`Self::run`] compiled for AVX2 (the same operations, no fused multiply-adds, so
    /// the same values).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn run_avx2(&self, i0: usize, c: &mut [f32], dot: &mut [f32]) {
        self.run(i0, c, dot)
    }
}

/// The outcome of one view's transport, per visible Gaussian.
#[derive(Clone, Debug, Default)]
pub struct ViewTransport {
    /// Camera index of the view (set by the caller; 0 by default).
    pub view: usize,
    /// Global indices of the visible Gaussians (the sources).
    pub idx: Vec<u32>,
    /// Source masses a_i^v.
    pub a: Vec<f32>,
    /// Transported support w_i^v = Σ_m T_im (appendix eq. for w_i^v).
    pub w: Vec<f32>,
    /// View targets y_i^v = Σ_m T_im e_m / (Σ_m T_im + δ), `n × d`.
    pub y: Vec<f32>,
    /// The δ of `y` ([`TransportConfig::delta`]), so the plan rows P_i can be
    /// recovered ([`Self::plan_row`]).
    pub delta: f32,
    pub objective: f64,
    pub dual: f64,
    pub gap: f64,
    pub transported_mass: f64,
    /// The prototypes' total mass B_v = Σ_m b_m ([`evidence_masses`]).
    pub target_mass: f32,
    /// Each source's coverage ω_i^v ∈ [0, 1]: the share of its blend weight inside the
    /// view's evidence (the splat-back of [`crate::prototypes::evidence_plane`]; empty when unknown),
    /// shared with the round's source side (the same values for every round while the
    /// geometry is frozen).
    pub coverage: std::sync::Arc<[f32]>,
    /// Each source's blend weight in the view, Σ_p T_i(p) α_i(p) (empty when unknown;
    /// `fusion.view_weight = "blend"`).
    pub blend: std::sync::Arc<[f32]>,
}

impl ViewTransport {
    /// Source `k`'s plan row P_k = Σ_m T_km e_m = y_k (w_k + δ) (for the L_uot gradient)
    /// into `out` (`d` long), computed from `y` and `w` rather than stored: the same
    /// values as forming it beside `y`, at half the memory per cached plan.
    #[inline]
    pub fn plan_row(&self, k: usize, out: &mut [f32]) {
        let d = out.len();
        let s = self.w[k] + self.delta;
        for (o, &v) in out.iter_mut().zip(&self.y[k * d..(k + 1) * d]) {
            *o = v * s;
        }
    }

    /// Each source's support relative to the view's evidence, σ_i^v ∈ [0, 1]. The
    /// view claims the source mass B_v ([`evidence_masses`]); the plan ranks the sources
    /// by their relative support ρ_i = w_i / a_i. The threshold t_v is the ρ at which
    /// the best-ranked sources' cumulative mass reaches B_v, and σ_i = min(1, ρ_i / t_v):
    /// 1 for the sources that together hold the claimed mass, less in proportion for
    /// the rest. Unlike raw ρ this does not depend on how much mass the relaxed
    /// marginals let the plan move, nor on how much it smears at a given ε: only on
    /// the plan's ranking and the evidence's mass. With B_v ≥ Σ a every source gets 1
    /// (a global edit).
    pub fn relative_support(&self) -> Vec<f32> {
        let rho: Vec<f32> =
            self.w.iter().zip(&self.a).map(|(&w, &a)| if a > 0.0 { w / a } else { 0.0 }).collect();
        let mut order: Vec<usize> = (0..rho.len()).collect();
        order.sort_by(|&i, &j| rho[j].total_cmp(&rho[i]));
        let (mut cum, mut t) = (0.0f64, 0.0f32);
        for &i in &order {
            t = rho[i];
            cum += self.a[i] as f64;
            if cum >= self.target_mass as f64 {
                break;
            }
        }
        if t <= 0.0 {
            return rho.iter().map(|&r| if r > 0.0 { 1.0 } else { 0.0 }).collect();
        }
        rho.iter().map(|&r| (r / t).min(1.0)).collect()
    }

    /// The view's support of each source: the relative support σ_i
    /// ([`Self::relative_support`]), and with `coverage` (and ω known) bounded by the
    /// source's coverage ω_i: min(σ_i, ω_i) (`fusion.coverage`;
    /// docs/method.md#m6-residual-and-gate).
    ///
    /// *Why:* σ ranks whole Gaussians, so a Gaussian whose footprint only touches the
    /// evidence (a table Gaussian at the edited object's silhouette, or half inside a
    /// spill ring) can hold full support; ω says how much of it the view's evidence
    /// accounts for. A view supports a Gaussian as far as both say so (a fuzzy "and"):
    /// with σ = 1 a Gaussian a quarter inside the evidence has support 0.25, not the
    /// geometric mean's 0.5, which let such Gaussians through the majority colour gate.
    /// The geometric mean was chosen when ω failed on the target itself (holes a noisy
    /// attention leaves in Ω, partly covered pixels at its edges); the closing of Ā
    /// ([`crate::prototypes::grey_closing`]) and the capped splat-back of ω
    /// ([`transsplat_raster::gaussian_stats_capped`]) fix those where they arise.
    pub fn view_support(&self, coverage: bool) -> Vec<f32> {
        let mut s = self.relative_support();
        if coverage && self.coverage.len() == s.len() {
            for (s, &o) in s.iter_mut().zip(self.coverage.iter()) {
                *s = s.min(o.clamp(0.0, 1.0));
            }
        }
        s
    }
}
/// The prototypes' masses under evidence-mass balancing: b_m = Σ_{i→m} a_i^v ω_i^v,
/// the source mass that prototype m's region covers. ω_i^v ∈ [0, 1] is Gaussian i's
/// coverage (the splat-back of [`crate::prototypes::evidence_plane`]: its blend
/// weight's share inside the support Ω, each pixel weighted by its evidence) and i → m
/// assigns each covered source to the prototype with the nearest centre u_m (the
/// regions are the k-means cells of Ω). A prototype that covers no source keeps
/// 10⁻⁶ of the total. Returns the paper's b (Σ b = 1, App. A.1) when balancing is off
/// or the coverage is unknown (`omega` empty).
///
/// *Why:* a_i is a share of the view's Gaussians (visibility × opacity), b_m a share of
/// the attention's pixels: the units differ, and with Σ a = Σ b = 1 and a nearly hard
/// target marginal the plan must draw a whole unit of mass from the sources however
/// little of the scene the edit covers. When the edited object holds 5% of the source
/// mass, the rest is pulled from its neighbours, and prototypes over sparse regions
/// (a spill ring on a table of large Gaussians) pull hardest: leakage made by the
/// marginals. With b in source mass the plan can be nearly balanced region by region,
/// and a global edit (Ω everywhere) keeps b ≈ a.
pub fn evidence_masses(
    a: &[f32],
    omega: &[f32],
    means2d: &[[f32; 2]],
    protos: &Prototypes,
    cfg: &TransportConfig,
) -> Vec<f32> {
    if !cfg.evidence_mass || omega.is_empty() || protos.is_empty() {
        return protos.b.clone();
    }
    let mut b = vec![0.0f64; protos.len()];
    for ((&ai, &oi), p) in a.iter().zip(omega).zip(means2d) {
        if oi <= 0.0 {
            continue;
        }
        let d2 = |u: &[f32; 2]| (p[0] - u[0]).powi(2) + (p[1] - u[1]).powi(2);
        let nearest = (0..protos.len()).min_by(|&j, &k| d2(&protos.u[j]).total_cmp(&d2(&protos.u[k])));
        b[nearest.expect("prototypes exist")] += ai as f64 * oi.min(1.0) as f64;
    }
    let total: f64 = b.iter().sum();
    if total <= 0.0 {
        return protos.b.clone();
    }
    b.iter().map(|&x| x.max(1e-6 * total) as f32).collect()
}

/// Solves view v's transport (paper eq. (5)) and returns w, y and the statistics.
/// `means2d`, `s`, `phi` are per visible Gaussian (aligned with `idx`, `a`); `b` are
/// the prototypes' masses ([`evidence_masses`]).
#[allow(clippy::too_many_arguments)]
pub fn transport(
    idx: Vec<u32>,
    a: Vec<f32>,
    means2d: &[[f32; 2]],
    s: &[f32],
    phi: &[f32],
    protos: &Prototypes,
    b: &[f32],
    diag: f32,
    cfg: &TransportConfig,
) -> Result<ViewTransport, transsplat_transport::Error> {
    let d = protos.d;
    let n = idx.len();
    if n == 0 || protos.is_empty() {
        return Ok(ViewTransport {
            idx,
            w: vec![0.0; n],
            y: vec![0.0; n * d],
            delta: cfg.delta,
            a,
            ..Default::default()
        });
    }
    let c = cost(means2d, s, phi, protos, diag, cfg);
    let p = Problem::top_k(&a, b, &c, cfg.top_k)?;
    let mut params = Params::new(cfg.eps, cfg.tau_s, cfg.tau_t);
    params.max_iters = cfg.iters;
    let sol = solve(&p, &params)?;
    let (y, w) = sol.target_means(&p, &protos.e, d, cfg.delta);
    Ok(ViewTransport {
        view: 0,
        idx,
        a,
        w,
        y,
        delta: cfg.delta,
        objective: sol.stats.objective,
        dual: sol.stats.dual,
        gap: sol.stats.gap,
        transported_mass: sol.stats.transported_mass,
        target_mass: b.iter().sum(),
        coverage: Default::default(),
        blend: Default::default(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn masses_are_visibility_times_opacity_normalised() {
        let (idx, a) = source_masses(&[1.0, 0.0, 0.5, 0.25], &[0.5, 0.9, 1.0, 0.0]);
        assert_eq!(idx, vec![0, 2]);
        assert!((a[0] - 0.5).abs() < 1e-6 && (a[1] - 0.5).abs() < 1e-6);
    }

    #[test]
    fn evidence_masses_by_hand() {
        // Prototypes at x = 0 and x = 10 (paper masses 0.9, 0.1). Sources at x = 1, 2, 9, 20
        // with a = (0.1, 0.2, 0.3, 0.4) and coverage ω = (1, 0.5, 1, 0): the first two go
        // to prototype 0 (0.1 + 0.1), the third to prototype 1 (0.3), the last is uncovered.
        let protos = Prototypes { u: vec![[0.0, 0.0], [10.0, 0.0]], b: vec![0.9, 0.1], ..Default::default() };
        let a = [0.1, 0.2, 0.3, 0.4];
        let m2d = [[1.0, 0.0], [2.0, 0.0], [9.0, 0.0], [20.0, 0.0]];
        let omega = [1.0, 0.5, 1.0, 0.0];
        let cfg = TransportConfig::default();
        let b = evidence_masses(&a, &omega, &m2d, &protos, &cfg);
        assert!((b[0] - 0.2).abs() < 1e-6 && (b[1] - 0.3).abs() < 1e-6, "{b:?}");
        // Off, or without coverage: the paper's masses.
        let off = TransportConfig { evidence_mass: false, ..Default::default() };
        assert_eq!(evidence_masses(&a, &omega, &m2d, &protos, &off), vec![0.9, 0.1]);
        assert_eq!(evidence_masses(&a, &[], &m2d, &protos, &cfg), vec![0.9, 0.1]);
    }

    #[test]
    fn cost_terms_by_hand() {
        let protos = Prototypes {
            u: vec![[3.0, 4.0]],
            e: vec![1.0, 0.0],
            d: 2,
            psi: vec![0.0, 1.0],
            d_app: 2,
            b: vec![1.0],
        };
        let cfg = TransportConfig { lambda_geo: 2.0, lambda_sem: 3.0, lambda_app: 5.0, ..Default::default() };
        // Gaussian at the origin: geo = 2 · 25 / 10² = 0.5; s = (1, 1): 1 − 1/√2; φ = (1, 0): 1.
        let c = cost(&[[0.0, 0.0]], &[1.0, 1.0], &[1.0, 0.0], &protos, 10.0, &cfg);
        let want = 0.5 + 3.0 * (1.0 - std::f32::consts::FRAC_1_SQRT_2) + 5.0;
        assert!((c[0] - want).abs() < 1e-5, "{} vs {want}", c[0]);
    }

    #[test]
    fn near_gaussians_receive_the_support_and_far_ones_do_not() {
        // Two prototypes at x = 10 and x = 90 of a 100-pixel image; Gaussians near each
        // and one far away. All semantics and appearances agree.
        let protos = Prototypes {
            u: vec![[10.0, 50.0], [90.0, 50.0]],
            e: vec![1.0, 0.0, 0.0, 1.0],
            d: 2,
            psi: vec![1.0, 1.0],
            d_app: 1,
            b: vec![0.5, 0.5],
        };
        let m2d = [[11.0, 50.0], [89.0, 50.0], [50.0, 0.0]];
        let s = [1.0, 0.0, 0.0, 1.0, 1.0, 1.0];
        let phi = [1.0, 1.0, 1.0];
        let a = vec![1.0 / 3.0; 3];
        let cfg = TransportConfig { top_k: 0, ..Default::default() };
        let vt = transport(vec![0, 1, 2], a, &m2d, &s, &phi, &protos, &protos.b, 141.4, &cfg).unwrap();
        assert!(vt.w[0] > 0.2 && vt.w[1] > 0.2, "{:?}", vt.w);
        assert!(vt.w[2] < 0.01 * vt.w[0], "{:?}", vt.w);
        // y of Gaussian 0 points to prototype 0's semantics.
        assert!(vt.y[0] > 0.99 && vt.y[1] < 0.01, "{:?}", vt.y);
        assert!(vt.objective.is_finite() && vt.gap.is_finite());
    }
}

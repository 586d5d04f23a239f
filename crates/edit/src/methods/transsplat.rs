//! TransSplat (paper Sec. 3): prompt-aware prototypes per view, a transport round
//! every `schedule.transport_every` steps ([`crate::round`]), and per step
//! L_sem + L_uot + L_leak ([`crate::losses`]) on top of L_img, with densification
//! only among gated Gaussians (docs/method.md#m7-losses, #m9-the-edit-loop).
//!
//! Its ablations are settings of this one part: pixel-level prototypes
//! (`no_prototype`), no gated densification with λ_leak = 0 (`no_leaksup`), and the
//! geometric cost alone (`geometric`, through the implied transport weights).

use super::{archive_error, Context, EditMethod};
use crate::config::EditConfig;
use crate::edits::ViewData;
use crate::error::EditError;
use crate::losses;
use crate::optimise::{geometry_frozen, StepLosses};
use crate::prototypes::{self, Prototypes, ViewEvidence};
use crate::round::{self, RoundStats, RoundView, TransportState, ViewSources};
use crate::view::ViewTransport;
use std::time::Instant;
use transsplat_raster::Grads;
use transsplat_scene::archive::{Archive, Writer};
use transsplat_scene::Gaussians;
use transsplat_train::{Reindex, Trainer};

/// How a view's evidence becomes transport targets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Prototyping {
    /// Weighted k-means regions of the support (appendix A.1).
    Regions,
    /// A seeded subsample of support pixels, one prototype each (`no_prototype`).
    Pixels,
}

/// TransSplat's state.
pub struct TransSplat {
    cfg: EditConfig,
    prototyping: Prototyping,
    /// Densify only where γ ≥ `schedule.densify_gate` (off for `no_leaksup`).
    gated_densify: bool,
    /// Prototypes of each usable view.
    prototypes: Vec<Prototypes>,
    /// Support Ω of each usable view (for evidence-mass balancing).
    supports: Vec<Vec<bool>>,
    /// The leakage reference c⁽⁰⁾: every SH coefficient of the source scene, `kc`
    /// values per Gaussian.
    sh0: Vec<f32>,
    kc: usize,
    transport: TransportState,
    /// A round is due at the next step (the model was rearranged).
    force_round: bool,
    /// Source sides of the last round, reused while the geometry cannot change.
    sources: Vec<ViewSources>,
}

impl TransSplat {
    pub fn new(cfg: &EditConfig, prototyping: Prototyping, gated_densify: bool) -> Self {
        TransSplat {
            cfg: cfg.clone(),
            prototyping,
            gated_densify,
            prototypes: Vec::new(),
            supports: Vec::new(),
            sh0: Vec::new(),
            kc: 0,
            transport: TransportState::new(0),
            force_round: false,
            sources: Vec::new(),
        }
    }

    /// True at the steps that run a transport round.
    fn round_due(&self, step: usize) -> bool {
        step.is_multiple_of(self.cfg.schedule.transport_every) || self.force_round
    }

    /// The transport round: source sides (recomputed unless the geometry is frozen),
    /// the view plans, fusion and the gate.
    fn round(&mut self, tr: &Trainer, ctx: &Context) -> Result<RoundStats, EditError> {
        let views: Vec<RoundView> = ctx
            .views
            .iter()
            .zip(self.prototypes.iter().zip(&self.supports))
            .map(|(v, (p, sup))| RoundView {
                cam: &ctx.cameras[v.cam],
                appearance: &v.appearance,
                d_app: v.d_app,
                support: sup,
                prototypes: p,
            })
            .collect();
        if !geometry_frozen(&self.cfg) || self.sources.len() != views.len() {
            self.sources = round::view_sources(&tr.model.gaussians, &views);
        }
        let cams: Vec<usize> = ctx.views.iter().map(|v| v.cam).collect();
        let d = tr.model.num_features;
        let plans =
            round::solve_views(&tr.model.features, d, &views, &cams, &self.sources, &self.cfg.transport)?;
        Ok(self.transport.update(plans, &tr.model.features, d, &self.cfg))
    }
}

impl EditMethod for TransSplat {
    fn add_view(&mut self, cam: usize, ev: &ViewEvidence) -> usize {
        let seed = self.cfg.seed.wrapping_mul(1_000_003).wrapping_add(cam as u64);
        let p = &self.cfg.prototypes;
        let protos = match self.prototyping {
            Prototyping::Regions => prototypes::extract(ev, p, seed),
            Prototyping::Pixels => prototypes::pixels(ev, p, self.cfg.pixel_samples, seed),
        };
        let count = protos.len();
        self.prototypes.push(protos);
        // The support plane 1_Ω, for evidence-mass balancing.
        let needed = self.cfg.transport.evidence_mass && count > 0;
        let omega = if needed { prototypes::view_support(ev, p).0 } else { Vec::new() };
        self.supports.push(omega);
        count
    }

    fn start(&mut self, g: &Gaussians, _ctx: &Context) -> Result<(), EditError> {
        if self.prototypes.iter().all(Prototypes::is_empty) {
            return Err(EditError::NoEvidence);
        }
        self.sh0 = g.sh.clone();
        self.kc = g.sh_coeffs() * 3;
        self.transport = TransportState::new(g.len());
        Ok(())
    }

    fn before_step(
        &mut self,
        step: usize,
        tr: &Trainer,
        ctx: &Context,
    ) -> Result<Option<RoundStats>, EditError> {
        if !self.round_due(step) {
            return Ok(None);
        }
        self.force_round = false;
        let t = Instant::now();
        let mut stats = self.round(tr, ctx)?;
        stats.step = step;
        stats.seconds = t.elapsed().as_secs_f64();
        Ok(Some(stats))
    }

    /// The colour gradients of L_img kept only in the gated region (γ ≥
    /// `loss.colour_gate`, when on), then L_sem towards z̄ (after the first round),
    /// L_uot through the step view's plan (one view per step like L_img: an unbiased
    /// estimate of the mean over views), and L_leak towards the source colours.
    fn add_gradients(&self, tr: &Trainer, view: &ViewData, grads: &mut Grads, rec: &mut StepLosses) {
        let (s, d) = (&tr.model.features, tr.model.num_features);
        let (t, l) = (&self.transport, &self.cfg.loss);
        if l.colour_gate > 0.0 {
            gate_colour_gradients(&mut grads.sh, &t.gamma, self.kc, l.colour_gate);
        }
        if let Some(z) = &t.zbar {
            rec.sem = losses::semantic(s, z, &t.gamma, d, l.sem, &mut grads.features);
        }
        if let Some(v) = t.cached.iter().find(|t| t.view == view.cam) {
            let lambda_sem = self.cfg.transport.lambda_sem;
            losses::transport_semantic(s, &v.idx, &v.plan_e, d, lambda_sem, l.uot, &mut grads.features);
            rec.uot = l.uot as f64 * v.objective;
        }
        if l.leak > 0.0 {
            // With the colour gate, L_leak anchors only the Gaussians outside the gated region.
            let open = if l.colour_gate > 0.0 { l.colour_gate } else { f32::INFINITY };
            let sh = &tr.model.gaussians.sh;
            rec.leak = losses::leakage(sh, &self.sh0, &t.gamma, open, self.kc, l.leak, &mut grads.sh);
        }
    }

    fn densify_mask(&self) -> Option<Vec<bool>> {
        let gate = self.cfg.schedule.densify_gate;
        self.gated_densify.then(|| self.transport.gamma.iter().map(|&g| g >= gate).collect())
    }

    fn reindex(&mut self, r: &Reindex) {
        let t = &mut self.transport;
        t.gamma = r.gather(&t.gamma, 1);
        self.sh0 = r.gather(&self.sh0, self.kc);
        t.zbar = t.zbar.take().map(|z| r.gather(&z, self.cfg.semantic_dim));
        t.cached.clear();
        self.sources.clear();
        self.force_round = true;
    }

    fn save<'a>(&'a self, w: &mut Writer<'a>) {
        let t = &self.transport;
        w.f32("sh0", &self.sh0[..]).f32("gamma", &t.gamma[..]).scalar("force_round", self.force_round as u64);
        if let Some(z) = &t.zbar {
            w.f32("zbar", &z[..]);
        }
        w.scalar("cached", t.cached.len() as u64);
        for (k, v) in t.cached.iter().enumerate() {
            w.scalar(format!("cached.{k}.view"), v.view as u64)
                .u32(format!("cached.{k}.idx"), &v.idx[..])
                .f32(format!("cached.{k}.a"), &v.a[..])
                .f32(format!("cached.{k}.w"), &v.w[..])
                .f32(format!("cached.{k}.y"), &v.y[..])
                .f32(format!("cached.{k}.plan_e"), &v.plan_e[..])
                .f64(
                    format!("cached.{k}.stats"),
                    vec![v.objective, v.dual, v.gap, v.transported_mass, v.target_mass as f64],
                );
        }
    }

    fn load(&mut self, a: &Archive, n: usize, d: usize, views: usize) -> Result<(), EditError> {
        let f = |name: &str, len: usize| a.f32_len(name, len).map(<[f32]>::to_vec).map_err(archive_error);
        self.sh0 = f("sh0", n * self.kc)?;
        self.transport.gamma = f("gamma", n)?;
        self.transport.zbar = if a.has("zbar") { Some(f("zbar", n * d)?) } else { None };
        self.force_round = a.scalar("force_round").map_err(archive_error)? != 0;
        let count = a.scalar("cached").map_err(archive_error)? as usize;
        if count > views {
            return Err(archive_error(a.err(format!("{count} cached view plans for {views} views"))));
        }
        self.transport.cached = (0..count).map(|k| load_plan(a, k, n, d)).collect::<Result<_, _>>()?;
        Ok(())
    }

    fn support(&self) -> Option<Vec<f32>> {
        Some(self.transport.support())
    }

    fn gate(self: Box<Self>) -> Option<Vec<f32>> {
        Some(self.transport.gamma)
    }
}

/// Zeroes the colour (SH) gradients of the Gaussians outside the gated region
/// {γ_i ≥ `open`} (`k` values per Gaussian): the image loss may recolour only what the
/// transport supports (docs/method.md#m7-losses).
///
/// *Why:* a soft L_leak is a penalty the image loss can outweigh: with an L1 image
/// loss every view that shows the spill pushes with constant force, and Adam rescales
/// both forces alike, so a Gaussian the gate calls 0.2 still drifts towards the
/// spilled colour. The paper's γ is meant to make weakly supported Gaussians "more
/// conservative"; a Gaussian outside the gated region now does not respond to the
/// edit at all, and L_leak still anchors the partly supported ones inside it.
pub fn gate_colour_gradients(grad_sh: &mut [f32], gamma: &[f32], k: usize, open: f32) {
    for (g, &gm) in grad_sh.chunks_mut(k.max(1)).zip(gamma) {
        if gm < open {
            g.fill(0.0);
        }
    }
}

/// Reads cached view plan `k` written by [`TransSplat::save`].
fn load_plan(a: &Archive, k: usize, n: usize, d: usize) -> Result<ViewTransport, EditError> {
    let e = |m: String| archive_error(a.err(m));
    let p = |s: &str| format!("cached.{k}.{s}");
    let f = |name: &str, len: usize| a.f32_len(name, len).map(<[f32]>::to_vec).map_err(archive_error);
    let idx = a.u32(&p("idx")).map_err(archive_error)?.to_vec();
    if idx.iter().any(|&i| i as usize >= n) {
        return Err(e(format!("cached view plan {k} refers to a Gaussian out of range")));
    }
    let m = idx.len();
    let stats = a.f64(&p("stats")).map_err(archive_error)?;
    let &[objective, dual, gap, transported_mass, target_mass] = stats else {
        return Err(e(format!("cached view plan {k}: bad statistics")));
    };
    Ok(ViewTransport {
        view: a.scalar(&p("view")).map_err(archive_error)? as usize,
        a: f(&p("a"), m)?,
        w: f(&p("w"), m)?,
        y: f(&p("y"), m * d)?,
        plan_e: f(&p("plan_e"), m * d)?,
        idx,
        objective,
        dual,
        gap,
        transported_mass,
        target_mass: target_mass as f32,
    })
}

#[cfg(test)]
mod tests {
    use super::gate_colour_gradients;

    #[test]
    fn colour_gate_keeps_only_the_gated_region() {
        let mut g = vec![1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0];
        gate_colour_gradients(&mut g, &[0.49, 0.5, 0.9], 2, 0.5);
        assert_eq!(g, vec![0.0, 0.0, 3.0, 4.0, 5.0, 6.0]);
    }
}

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
use crate::latents::{Latents, Terms};
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
    /// The evidence plane of each usable view ([`prototypes::evidence_plane`]; empty when
    /// neither evidence-mass balancing nor the coverage bound needs it).
    supports: Vec<Vec<f32>>,
    /// Whether each usable view's attention stayed under the floor
    /// ([`prototypes::below_floor`]).
    unedited: Vec<bool>,
    /// The leakage reference c⁽⁰⁾: every SH coefficient of the source scene, `kc`
    /// values per Gaussian.
    sh0: Vec<f32>,
    kc: usize,
    transport: TransportState,
    /// A round is due at the next step (the model was rearranged).
    force_round: bool,
    /// Source sides of the last round, reused while the geometry cannot change.
    sources: Vec<ViewSources>,
    /// The semantic latents' optimiser, which steps record into (they move only
    /// under L_sem and L_uot; the trainer does not step them).
    latents: Latents,
    /// With the colour gate: the gated region {support ≥ `loss.colour_gate`}, where L_img
    /// may recolour ([`EditMethod::colour_mask`]); empty without the gate.
    open: Vec<bool>,
    /// With the colour gate: the rows L_leak visits until the next round
    /// ([`changeable`]), ascending; `None`: every row.
    leak_rows: Option<Vec<u32>>,
}

impl TransSplat {
    pub fn new(cfg: &EditConfig, prototyping: Prototyping, gated_densify: bool) -> Self {
        TransSplat {
            cfg: cfg.clone(),
            prototyping,
            gated_densify,
            prototypes: Vec::new(),
            supports: Vec::new(),
            unedited: Vec::new(),
            sh0: Vec::new(),
            kc: 0,
            transport: TransportState::new(0),
            force_round: false,
            sources: Vec::new(),
            open: Vec::new(),
            leak_rows: None,
            latents: Latents::default(),
        }
    }

    /// Follows a change of γ: the gated region, and the rows L_leak must visit
    /// (`trainer`: the model now; `None` when it is not at hand, then every row).
    ///
    /// The colour gate (docs/method.md#m7-losses): L_img recolours only the gated
    /// region, where the aggregated support 1 − r_i is at least `loss.colour_gate` (γ
    /// at least [`EditConfig::colour_gate_gamma`]), the colour mask the loop applies.
    /// *Why:* a soft L_leak is a penalty the image loss can outweigh: with an L1 image
    /// loss every view that shows the spill pushes with constant force, and Adam rescales
    /// both forces alike, so a Gaussian the gate calls 0.2 still drifts towards the
    /// spilled colour. The paper's γ is meant to make weakly supported Gaussians "more
    /// conservative"; a Gaussian outside the gated region now does not respond to the
    /// edit at all. The default threshold, support ≥ 1/2, is a majority vote of the
    /// views that see the Gaussian (each by `fusion.view_weight`).
    fn gate_changed(&mut self, trainer: Option<&Trainer>) {
        let Some(open) = self.cfg.colour_gate_gamma() else { return };
        self.open = self.transport.gamma.iter().map(|&g| g >= open).collect();
        self.leak_rows = trainer.map(|trainer| {
            let c = changeable(&trainer.model.gaussians.sh, &self.sh0, &self.open, self.kc);
            (0..c.len() as u32).filter(|&i| c[i as usize]).collect()
        });
    }

    /// True at the steps that run a transport round.
    fn round_due(&self, step: usize) -> bool {
        step.is_multiple_of(self.cfg.schedule.transport_every) || self.force_round
    }

    /// The transport round: source sides (recomputed unless the geometry is frozen),
    /// the view plans, fusion and the gate.
    fn round(&mut self, trainer: &Trainer, ctx: &Context) -> Result<RoundStats, EditError> {
        let views: Vec<RoundView> = ctx
            .views
            .iter()
            .zip(self.prototypes.iter().zip(&self.supports).zip(&self.unedited))
            .map(|(v, ((p, sup), &unedited))| RoundView {
                cam: &ctx.cameras[v.cam],
                appearance: &v.appearance,
                d_app: v.d_app,
                support: sup,
                prototypes: p,
                unedited,
            })
            .collect();
        let t = Instant::now();
        if !geometry_frozen(&self.cfg) || self.sources.len() != views.len() {
            let keep_blend = self.cfg.fusion.view_weight == crate::gate::ViewWeight::Blend;
            self.sources = round::view_sources(&trainer.model.gaussians, &views, keep_blend);
        }
        let sources_s = t.elapsed().as_secs_f64();
        let cams: Vec<usize> = ctx.views.iter().map(|v| v.cam).collect();
        let d = trainer.model.num_features;
        // The last round's plans are not read by this one: free them first (a plan per
        // view and visible Gaussian; at a million Gaussians about a gigabyte).
        self.transport.cached = Vec::new();
        let plans = round::solve_views(
            &trainer.model.features,
            d,
            &views,
            &cams,
            &self.sources,
            &self.cfg.transport,
        )?;
        let solve_s = t.elapsed().as_secs_f64() - sources_s;
        let stats = self.transport.update(plans, &trainer.model.features, d, &self.cfg);
        tracing::debug!(
            "transport round: source sides {sources_s:.2} s, view plans {solve_s:.2} s, fusion and gate {:.2} s",
            t.elapsed().as_secs_f64() - sources_s - solve_s
        );
        Ok(stats)
    }
}

impl EditMethod for TransSplat {
    fn add_view(&mut self, cam: usize, ev: &ViewEvidence) -> usize {
        let seed = self.cfg.seed.wrapping_mul(1_000_003).wrapping_add(cam as u64);
        let p = &self.cfg.prototypes;
        let sup = prototypes::view_support(ev, p);
        let protos = match self.prototyping {
            Prototyping::Regions => prototypes::extract(ev, &sup, p, seed),
            Prototyping::Pixels => prototypes::pixels(ev, &sup, self.cfg.pixel_samples, seed),
        };
        let count = protos.len();
        self.prototypes.push(protos);
        self.unedited.push(count == 0 && prototypes::below_floor(ev, p.threshold));
        // The evidence plane, for evidence-mass balancing and the coverage bound.
        let needed = (self.cfg.transport.evidence_mass || self.cfg.fusion.coverage) && count > 0;
        self.supports.push(if needed { prototypes::evidence_plane(&sup) } else { Vec::new() });
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
        trainer: &mut Trainer,
        losses: &mut [StepLosses],
        ctx: &Context,
    ) -> Result<Option<RoundStats>, EditError> {
        if !self.round_due(step) {
            return Ok(None);
        }
        // The round reads the latents and replaces what their steps used.
        let t = Instant::now();
        self.sync(trainer, losses)?;
        tracing::debug!("semantic latents advanced in {:.2} s", t.elapsed().as_secs_f64());
        self.force_round = false;
        let mut stats = self.round(trainer, ctx)?;
        self.gate_changed(Some(trainer));
        stats.step = step;
        stats.seconds = t.elapsed().as_secs_f64();
        Ok(Some(stats))
    }

    /// (The colour gradients of L_img are kept only in the gated region by the loop,
    /// through [`EditMethod::colour_mask`].)
    /// L_sem towards z̄ (after the first round) and L_uot through the step view's plan
    /// (one view per step like L_img: an unbiased estimate of the mean over views)
    /// move only the semantic latents: the step is recorded and the latents advanced
    /// at the next [`EditMethod::sync`] ([`crate::latents`]). L_leak pulls the colours
    /// towards the source colours.
    fn add_gradients(&mut self, trainer: &Trainer, view: &ViewData, grads: &mut Grads, rec: &mut StepLosses) {
        let (t, l) = (&self.transport, &self.cfg.loss);
        let n = t.gamma.len();
        let plan = t.cached.iter().position(|t| t.view == view.cam);
        if let Some(p) = plan {
            rec.uot = l.uot as f64 * t.cached[p].objective;
        }
        self.latents.record(rec.step, plan);
        if l.leak > 0.0 {
            // With the colour gate, L_leak anchors only the Gaussians outside the gated region.
            let open = self.cfg.colour_gate_gamma().unwrap_or(f32::INFINITY);
            let sh = &trainer.model.gaussians.sh;
            let k = self.kc;
            rec.leak = match &self.leak_rows {
                Some(r) => {
                    let rows = r.iter().map(|&i| i as usize);
                    losses::leakage(sh, &self.sh0, &t.gamma, open, k, l.leak, rows, &mut grads.sh)
                }
                None => losses::leakage(sh, &self.sh0, &t.gamma, open, k, l.leak, 0..n, &mut grads.sh),
            };
        }
    }

    /// Advances the semantic latents through the recorded steps and fills in their
    /// λ L_sem; a latent that became NaN or infinite stops the edit naming the step.
    fn sync(&mut self, trainer: &mut Trainer, losses: &mut [StepLosses]) -> Result<(), EditError> {
        if self.latents.pending() == 0 {
            return Ok(());
        }
        let (t, l) = (&self.transport, &self.cfg.loss);
        let terms = Terms {
            zbar: t.zbar.as_deref(),
            gamma: &t.gamma,
            plans: &t.cached,
            l_sem: l.sem,
            l_uot: l.uot,
            cost_sem: self.cfg.transport.lambda_sem,
        };
        let (d, adam) =
            (trainer.model.num_features, (trainer.adam.betas.0, trainer.adam.betas.1, trainer.adam.eps));
        let sem = self.latents.advance(&mut trainer.model.features, d, &terms, self.cfg.lr.semantic, adam);
        let sem = sem.map_err(|step| {
            EditError::Train(format!(
                "step {}: the features (semantic latents) became NaN or infinite; lower the learning rates or check the inputs",
                step + 1
            ))
        })?;
        for (step, v) in sem {
            if let Some(r) = losses.iter_mut().rev().find(|r| r.step == step) {
                r.sem = v;
                crate::optimise::check_losses(r, step as u64 + 1)?;
            }
        }
        Ok(())
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
        assert_eq!(self.latents.pending(), 0, "the latents are synced before a rearrangement");
        let d = self.cfg.semantic_dim;
        if !self.latents.m.is_empty() {
            self.latents.m = r.gather_fresh_zero(&self.latents.m, d, 0.0);
            self.latents.v = r.gather_fresh_zero(&self.latents.v, d, 0.0);
        }
        self.gate_changed(None);
        self.force_round = true;
    }

    fn save<'a>(&'a self, w: &mut Writer<'a>) {
        let t = &self.transport;
        assert_eq!(self.latents.pending(), 0, "the latents are synced before a checkpoint");
        w.f32("sh0", &self.sh0[..]).f32("gamma", &t.gamma[..]).scalar("force_round", self.force_round as u64);
        w.f32("latents.m", &self.latents.m[..]).f32("latents.v", &self.latents.v[..]);
        w.scalar("latents.step", self.latents.step);
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
                .f32(format!("cached.{k}.coverage"), &v.coverage[..])
                .f64(
                    format!("cached.{k}.stats"),
                    vec![v.objective, v.dual, v.gap, v.transported_mass, v.target_mass as f64],
                );
            if !v.blend.is_empty() {
                w.f32(format!("cached.{k}.blend"), &v.blend[..]);
            }
        }
    }

    fn load(&mut self, a: &Archive, n: usize, d: usize, views: usize) -> Result<(), EditError> {
        let f = |name: &str, len: usize| a.f32_len(name, len).map(<[f32]>::to_vec).map_err(archive_error);
        self.sh0 = f("sh0", n * self.kc)?;
        self.transport.gamma = f("gamma", n)?;
        let (m, v) = (a.f32("latents.m").map_err(archive_error)?, a.f32("latents.v").map_err(archive_error)?);
        if m.len() != v.len() || !(m.is_empty() || m.len() == n * d) {
            return Err(archive_error(a.err(format!("latent moments do not match {n} Gaussians"))));
        }
        self.latents.m = m.to_vec();
        self.latents.v = v.to_vec();
        self.latents.step = a.scalar("latents.step").map_err(archive_error)?;
        self.transport.zbar = if a.has("zbar") { Some(f("zbar", n * d)?) } else { None };
        self.force_round = a.scalar("force_round").map_err(archive_error)? != 0;
        let count = a.scalar("cached").map_err(archive_error)? as usize;
        if count > views {
            return Err(archive_error(a.err(format!("{count} cached view plans for {views} views"))));
        }
        self.transport.cached =
            (0..count).map(|k| load_plan(a, k, n, d, self.cfg.transport.delta)).collect::<Result<_, _>>()?;
        self.gate_changed(None);
        Ok(())
    }

    fn support(&self) -> Option<Vec<f32>> {
        Some(self.transport.support(self.cfg.fusion.coverage, self.cfg.fusion.view_weight))
    }

    fn colour_mask(&self) -> Option<&[bool]> {
        (!self.open.is_empty()).then_some(&self.open[..])
    }

    fn gate(self: Box<Self>) -> Option<Vec<f32>> {
        Some(self.transport.gamma)
    }
}

/// The Gaussians whose colour can change until the next round under the colour
/// gate: the gated region `open`, where L_img may recolour, and those whose colour
/// already differs from the source (`c`, `c0`: `k` SH values each), where L_leak
/// pulls back. Every other one gets no colour gradient and keeps its source colour,
/// so L_leak need not visit it (docs/method.md#m10-speed).
pub fn changeable(c: &[f32], c0: &[f32], open: &[bool], k: usize) -> Vec<bool> {
    use rayon::prelude::*;
    let k = k.max(1);
    (c.par_chunks(k), c0.par_chunks(k), open.par_iter())
        .into_par_iter()
        .with_min_len(4096)
        .map(|(c, c0, &o)| o || c != c0)
        .collect()
}

/// Reads cached view plan `k` written by [`TransSplat::save`]; `delta` is the run's
/// δ (the run id fixes the settings of a resumed run).
fn load_plan(a: &Archive, k: usize, n: usize, d: usize, delta: f32) -> Result<ViewTransport, EditError> {
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
    // Empty when the view's support was unknown.
    let coverage: std::sync::Arc<[f32]> = a.f32(&p("coverage")).map_err(archive_error)?.into();
    if !(coverage.is_empty() || coverage.len() == m) {
        return Err(e(format!("cached view plan {k}: {} coverage values for {m} sources", coverage.len())));
    }
    // Present only when the run weighed views by blend weight.
    let blend: std::sync::Arc<[f32]> = match a.has(&p("blend")) {
        true => a.f32(&p("blend")).map_err(archive_error)?.into(),
        false => Default::default(),
    };
    if !(blend.is_empty() || blend.len() == m) {
        return Err(e(format!("cached view plan {k}: {} blend weights for {m} sources", blend.len())));
    }
    Ok(ViewTransport {
        view: a.scalar(&p("view")).map_err(archive_error)? as usize,
        a: f(&p("a"), m)?,
        w: f(&p("w"), m)?,
        y: f(&p("y"), m * d)?,
        delta,
        idx,
        objective,
        dual,
        gap,
        transported_mass,
        target_mass: target_mass as f32,
        coverage,
        blend,
    })
}

#[cfg(test)]
mod tests {
    use super::changeable;

    #[test]
    fn changeable_are_the_gated_region_and_the_changed() {
        let c0 = [0.1f32, 0.2, 0.3, 0.4, 0.5, 0.6];
        let c = [0.1f32, 0.2, 0.3, 0.45, 0.5, 0.6];
        assert_eq!(changeable(&c, &c0, &[true, false, false], 2), vec![true, true, false]);
    }
}

//! The masklift baseline (GaussianEditor style): each view's 2D target mask (the
//! editor's mask, else the attention support Ω) is lifted onto the Gaussians
//! ([`crate::lift`]) and thresholded; colour gradients are zeroed outside the lifted
//! mask, and only Gaussians inside it may be densified. No transport.

use super::{archive_error, Context, EditMethod};
use crate::config::EditConfig;
use crate::edits::ViewData;
use crate::error::EditError;
use crate::lift::lift;
use crate::optimise::StepLosses;
use crate::prototypes::{view_support, PrototypeConfig, ViewEvidence};
use transsplat_raster::Grads;
use transsplat_scene::archive::{Archive, Writer};
use transsplat_scene::Gaussians;
use transsplat_train::{Reindex, Trainer};

/// The masklift baseline's state.
pub struct Masklift {
    prototypes: PrototypeConfig,
    threshold: f32,
    /// Each usable view's 2D mask (until [`EditMethod::start`] lifts them).
    masks: Vec<Vec<f32>>,
    /// The lifted mask before the threshold (reported as the gate), and after it.
    lifted: Vec<f32>,
    inside: Vec<bool>,
}

impl Masklift {
    pub fn new(cfg: &EditConfig) -> Self {
        Masklift {
            prototypes: cfg.prototypes.clone(),
            threshold: cfg.masklift_threshold,
            masks: Vec::new(),
            lifted: Vec::new(),
            inside: Vec::new(),
        }
    }
}

/// The 2D target mask of a view: the editor's mask (> 0.5), else the support Ω.
pub fn view_mask(ev: &ViewEvidence, cfg: &PrototypeConfig) -> Vec<f32> {
    if let Some(m) = ev.mask {
        return m.iter().map(|&v| if v > 0.5 { 1.0 } else { 0.0 }).collect();
    }
    view_support(ev, cfg).omega.iter().map(|&o| if o { 1.0 } else { 0.0 }).collect()
}

impl EditMethod for Masklift {
    fn add_view(&mut self, _cam: usize, ev: &ViewEvidence) -> usize {
        self.masks.push(view_mask(ev, &self.prototypes));
        0
    }

    fn start(&mut self, g: &Gaussians, ctx: &Context) -> Result<(), EditError> {
        let masks = std::mem::take(&mut self.masks);
        if !masks.iter().any(|m| m.iter().any(|&v| v > 0.0)) {
            return Err(EditError::NoEvidence);
        }
        let cams: Vec<_> = ctx.views.iter().map(|v| &ctx.cameras[v.cam]).collect();
        let planes: Vec<&[f32]> = masks.iter().map(|m| m.as_slice()).collect();
        self.lifted = lift(g, &cams, &planes, 1);
        self.inside = self.lifted.iter().map(|&x| x >= self.threshold).collect();
        Ok(())
    }

    /// Nothing of its own: the colour gradients are masked outside the lifted mask by
    /// the loop ([`EditMethod::colour_mask`]).
    fn add_gradients(&mut self, _tr: &Trainer, _view: &ViewData, _grads: &mut Grads, _rec: &mut StepLosses) {}

    fn densify_mask(&self) -> Option<Vec<bool>> {
        Some(self.inside.clone())
    }

    fn colour_mask(&self) -> Option<&[bool]> {
        Some(&self.inside)
    }

    fn reindex(&mut self, r: &Reindex) {
        self.inside = r.gather(&self.inside, 1);
        self.lifted = r.gather(&self.lifted, 1);
    }

    fn save<'a>(&'a self, w: &mut Writer<'a>) {
        w.u32("masklift.inside", self.inside.iter().map(|&b| b as u32).collect::<Vec<_>>())
            .f32("masklift.lifted", &self.lifted[..]);
    }

    fn load(&mut self, a: &Archive, n: usize, _d: usize, _views: usize) -> Result<(), EditError> {
        let inside = a.u32("masklift.inside").map_err(archive_error)?;
        if inside.len() != n {
            return Err(archive_error(
                a.err(format!("lifted mask has {} entries for {n} Gaussians", inside.len())),
            ));
        }
        self.inside = inside.iter().map(|&b| b != 0).collect();
        self.lifted = a.f32_len("masklift.lifted", n).map_err(archive_error)?.to_vec();
        Ok(())
    }

    fn gate(self: Box<Self>) -> Option<Vec<f32>> {
        Some(self.lifted)
    }
}

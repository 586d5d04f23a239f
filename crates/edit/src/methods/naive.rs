//! The naive baseline (Instruct-GS2GS / Instruct-NeRF2NeRF style): L_img only, every
//! Gaussian free, no gate.

use super::{Context, EditMethod};
use crate::edits::ViewData;
use crate::error::EditError;
use crate::optimise::StepLosses;
use transsplat_raster::Grads;
use transsplat_scene::Gaussians;
use transsplat_train::Trainer;

/// The naive baseline: adds nothing to the image loss.
pub struct Naive;

impl EditMethod for Naive {
    fn start(&mut self, _g: &Gaussians, _ctx: &Context) -> Result<(), EditError> {
        Ok(())
    }

    fn add_gradients(&mut self, _tr: &Trainer, _view: &ViewData, _grads: &mut Grads, _rec: &mut StepLosses) {}
}

//! The method of an edit as one pluggable part: TransSplat and its ablations, and
//! the baselines, each an [`EditMethod`] in its own module. The edit loop
//! ([`crate::engine`]) calls the same hooks whichever method runs; adding a method is
//! a module, a variant of [`Method`] (a setting, in [`crate::config`]) and its arm in
//! [`part`].
//!
//! - [`transsplat`]: the full method (transport rounds, L_sem, L_uot, L_leak, the
//!   colour gate, gated densification), its ablations `no_leaksup`, `no_prototype`,
//!   `geometric`, and `paper`, the paper's own formulation of the gate.
//! - [`naive`]: L_img only, every Gaussian free (Instruct-GS2GS / IN2N style).
//! - [`masklift`]: GaussianEditor style: the 2D masks lifted and thresholded, colour
//!   gradients masked outside.

pub mod masklift;
pub mod naive;
pub mod transsplat;

use crate::config::{EditConfig, Method};
use crate::edits::ViewData;
use crate::error::EditError;
use crate::optimise::StepLosses;
use crate::prototypes::ViewEvidence;
use crate::round::RoundStats;
use transsplat_raster::Grads;
use transsplat_scene::archive::{Archive, Writer};
use transsplat_scene::{Camera, Gaussians};
use transsplat_train::{Reindex, Trainer};

/// The part of the method `cfg.method` in the loop, for the run's settings `cfg`.
pub fn part(cfg: &EditConfig) -> Box<dyn EditMethod> {
    use transsplat::{Prototyping, TransSplat};
    match cfg.method {
        Method::Transsplat | Method::Paper | Method::Geometric => {
            Box::new(TransSplat::new(cfg, Prototyping::Regions, true))
        }
        Method::NoLeaksup => Box::new(TransSplat::new(cfg, Prototyping::Regions, false)),
        Method::NoPrototype => Box::new(TransSplat::new(cfg, Prototyping::Pixels, true)),
        Method::Naive => Box::new(naive::Naive),
        Method::Masklift => Box::new(masklift::Masklift::new(cfg)),
    }
}

/// What a method sees of the run besides the trainer: the scene's cameras and the
/// usable edit views.
pub struct Context<'a> {
    pub cameras: &'a [Camera],
    pub views: &'a [ViewData],
}

/// A method's part in the edit loop. The loop calls, in order: [`add_view`] for
/// each usable edit view, [`start`] once, then per step [`before_step`],
/// [`colour_mask`] and [`add_gradients`] after the image gradient, [`sync`] and
/// [`densify_mask`] when densification is due and [`reindex`] after the model was
/// rearranged; [`sync`] then [`save`] / [`load`] at checkpoints, and [`sync`] then
/// [`gate`] at the end.
///
/// [`add_view`]: EditMethod::add_view
/// [`start`]: EditMethod::start
/// [`before_step`]: EditMethod::before_step
/// [`add_gradients`]: EditMethod::add_gradients
/// [`colour_mask`]: EditMethod::colour_mask
/// [`densify_mask`]: EditMethod::densify_mask
/// [`reindex`]: EditMethod::reindex
/// [`sync`]: EditMethod::sync
/// [`save`]: EditMethod::save
/// [`load`]: EditMethod::load
/// [`gate`]: EditMethod::gate
pub trait EditMethod {
    /// Takes in the evidence of one usable edit view (camera index `cam`); returns the
    /// number of prototypes made of it (0 for methods without prototypes).
    fn add_view(&mut self, _cam: usize, _ev: &ViewEvidence) -> usize {
        0
    }

    /// Sets up the method's state on the source scene `g`; errors with
    /// [`EditError::NoEvidence`] when the evidence leaves nothing to edit.
    fn start(&mut self, g: &Gaussians, ctx: &Context) -> Result<(), EditError>;

    /// Runs at the top of step `step`, before its view is rendered (e.g. a transport
    /// round, whose statistics it returns); `losses` are the records of the steps so
    /// far, for [`EditMethod::sync`].
    fn before_step(
        &mut self,
        _step: usize,
        _tr: &mut Trainer,
        _losses: &mut [StepLosses],
        _ctx: &Context,
    ) -> Result<Option<RoundStats>, EditError> {
        Ok(None)
    }

    /// Adds the method's terms to the gradients of the step's view and records their
    /// losses (a term the method defers is recorded by [`EditMethod::sync`]).
    fn add_gradients(&mut self, trainer: &Trainer, view: &ViewData, grads: &mut Grads, rec: &mut StepLosses);

    /// Brings what the method defers into the model and into the loss records of the
    /// steps so far: TransSplat advances the semantic latents through the steps since
    /// the last sync ([`crate::latents`]). The loop calls it before the model is read
    /// or rearranged: before a checkpoint, before densification and at the end
    /// (TransSplat syncs itself before a round).
    fn sync(&mut self, _tr: &mut Trainer, _losses: &mut [StepLosses]) -> Result<(), EditError> {
        Ok(())
    }

    /// The Gaussians that densification may touch (`None`: all).
    fn densify_mask(&self) -> Option<Vec<bool>> {
        None
    }

    /// Follows a rearrangement of the model (densification, pruning).
    fn reindex(&mut self, _r: &Reindex) {}

    /// Writes the method's state into a checkpoint.
    fn save<'a>(&'a self, _w: &mut Writer<'a>) {}

    /// Restores the state [`EditMethod::save`] wrote, for a model of `n` Gaussians
    /// with `d` semantic channels and `views` usable views.
    fn load(&mut self, _a: &Archive, _n: usize, _d: usize, _views: usize) -> Result<(), EditError> {
        Ok(())
    }

    /// The per-Gaussian share of source mass the last transport round moved, if the
    /// method transports ([`crate::round::TransportState::support`]).
    fn support(&self) -> Option<Vec<f32>> {
        None
    }

    /// The colour mask: the Gaussians whose colour L_img may change at this step
    /// (`None`: all). The loop keeps L_img's colour gradients only there. The method's
    /// own terms may move colours only of Gaussians whose colour already differs from
    /// the source; then no other Gaussian ever changes colour, and with frozen
    /// geometry a step renders the change of those alone ([`crate::delta`]).
    fn colour_mask(&self) -> Option<&[bool]> {
        None
    }

    /// The per-Gaussian map reported as the gate (γ, or masklift's lifted mask), if any.
    fn gate(self: Box<Self>) -> Option<Vec<f32>> {
        None
    }
}

/// A checkpoint error naming the file.
pub(crate) fn archive_error(e: transsplat_scene::Error) -> EditError {
    EditError::Checkpoint(e.to_string())
}

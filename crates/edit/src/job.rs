//! What an edit works on ([`EditJob`]), what it gives back ([`EditResult`]) and what it
//! reports while it runs ([`Progress`]).

use crate::optimise::{StageTimes, StepLosses};
use crate::round::RoundStats;
use crate::semantic::SemanticFn;
use transsplat_editors::EditedView;
use transsplat_scene::{Camera, Gaussians};

/// What the edit works on.
pub struct EditJob<'a> {
    /// The source scene.
    pub gaussians: &'a Gaussians,
    /// All cameras of the scene.
    pub cameras: &'a [Camera],
    /// Indices of the cameras used for editing (the training views).
    pub edit_views: Vec<usize>,
    pub background: [f32; 3],
    pub prompt: &'a str,
    /// The semantic feature model E_v, applied to the source renders and to the
    /// edited images alike ([`crate::semantic::builtin`] without weights).
    pub semantic: &'a SemanticFn,
}

/// Wall-clock split of an edit.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Timing {
    pub total: f64,
    pub editor: f64,
    /// Transport rounds: statistics, prototypes, costs, UOT, fusion, gate.
    pub transport: f64,
    pub optimise: f64,
    /// The optimisation steps by stage (this process's steps; a resumed run's earlier
    /// steps are in `total` only).
    pub stages: StageTimes,
}

/// The outcome of an edit.
#[derive(Clone, Debug, Default)]
pub struct EditResult {
    /// The edited scene; semantic latents as extra properties `sem_0..`.
    pub gaussians: Gaussians,
    /// Per-Gaussian gate γ (transport methods), the lifted mask (masklift), or
    /// `None` (naive).
    pub gate: Option<Vec<f32>>,
    /// Per-Gaussian transported support (transport methods), else `None`.
    pub support: Option<Vec<f32>>,
    pub rounds: Vec<RoundStats>,
    pub losses: Vec<StepLosses>,
    pub timing: Timing,
    /// The editor's outputs, aligned with `EditJob::edit_views`.
    pub edited: Vec<Option<EditedView>>,
    /// Number of prototypes per edit view (0 = no evidence, or a method without
    /// prototypes).
    pub prototypes: Vec<usize>,
}

/// Progress reports from the loop.
#[derive(Clone, Debug)]
pub enum Progress<'a> {
    Edited { views: usize, seconds: f64 },
    Step { step: usize, steps: usize, loss: f64 },
    Round(&'a RoundStats),
}

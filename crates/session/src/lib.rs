//! The one place a transsplat job runs, from its inputs to a committed output folder.
//!
//! A front (the `transsplat` CLI, the Python package, the Ray driver, the demo) parses
//! its arguments into a request and presents what comes back; everything between is
//! here, so every front keeps the same guarantees: the output rule (never write an
//! input), staging (the output appears only when complete, whatever the failure), the
//! held-out view split, errors that name the path the user gave, progress,
//! cancellation and checkpoints.
//!
//! - [`edit`]: an edit job ([`edit::EditRequest`]: a scene, cameras, an instruction, an
//!   editor described by [`edit::EditorSpec`], settings, an optional output folder).
//! - [`train`]: a training job ([`train::TrainRequest`]: a dataset and settings into an
//!   INRIA output folder with `train.json`).
//! - [`edit_folder`]: the output folder of an edit (scene, renders, `transport.json`,
//!   `report.html`), also written per method by the demo.
//! - [`checkpoints`]: the checkpoint folder beside an output, resume and the message
//!   after a stop.
//! - [`inputs`]: a job's scene and cameras, read and checked.
//! - [`views`]: which views the 2D editor edits (`--views`).
//! - [`output`]: the output rule and staging of a job's folder.
//! - [`report`], [`heatmap`]: the HTML report page and per-Gaussian heat maps.

pub mod checkpoints;
pub mod edit;
pub mod edit_folder;
pub mod editor_views;
pub mod heatmap;
pub mod inputs;
pub mod output;
pub mod report;
pub mod train;
pub mod views;

pub use checkpoints::Checkpoints;
pub use output::Output;

/// Why a job stopped. Every message names the file, setting or output it is about.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// A bad input or request (a missing editor folder, a camera that does not fit).
    #[error("{0}")]
    Input(String),
    /// Reading an input or writing the output failed (the path is the user's).
    #[error(transparent)]
    Io(#[from] transsplat_scene::Error),
    /// The edit engine refused or failed.
    #[error(transparent)]
    Edit(#[from] transsplat_edit::EditError),
    /// Training refused or failed.
    #[error(transparent)]
    Train(#[from] transsplat_train::TrainError),
    /// A model (InstructPix2Pix, DINOv2) could not be loaded.
    #[error("{0}")]
    Model(String),
    /// Stopped by Ctrl-C or a test stop: the message says where the checkpoint is and
    /// how to continue, and that nothing was written to the output.
    #[error("{message}")]
    Interrupted { step: u64, message: String },
    /// The job failed after it started; nothing was written to the output (the
    /// message says so and where the last checkpoint is).
    #[error("{0}")]
    Failed(String),
}

//! 3D Gaussian Splatting training on a CPU, following INRIA 3DGS
//! (Kerbl et al. 2023, `graphdeco-inria/gaussian-splatting`) where it is specified.
//!
//! - [`model`]: the trainable [`Model`] (Gaussians, carried extras, learnable
//!   feature channels) and [`Reindex`], the one rearrangement that keeps every
//!   per-Gaussian array, Adam moment and statistic aligned.
//! - [`adam`]: Adam per parameter group with INRIA's learning rates and the
//!   exponential position schedule.
//! - [`loss`]: `0.8 L1 + 0.2 D-SSIM` with its exact image gradient; PSNR.
//! - [`densify`]: clone / split / prune / opacity reset on INRIA's schedule, with
//!   an optional per-Gaussian mask; [`mcmc`]: the MCMC strategy (relocation of dead
//!   Gaussians under a fixed budget, position noise), chosen by [`Strategy`];
//!   [`filter3d`]: Mip-Splatting's 3D smoothing filter, an option.
//! - [`trainer`]: [`Trainer`], one optimisation step as a library call, split into
//!   `begin_step` / `forward_backward` / `finish_step` so other crates can add
//!   their own gradient terms before the Adam step.
//! - [`dataset`], [`points`], [`init`], [`fit`](mod@fit): COLMAP / transforms.json / INRIA
//!   folders at a chosen downscale, point-cloud initialisation (k-d tree nearest
//!   neighbours) or random points in the cameras' view, the training loop with test
//!   PSNR and its checkpoints, and the INRIA output folder.
//! - [`checkpoint`]: checkpoints of long runs (bit-identical resume), the run's
//!   identity, and [`Control`] (Ctrl-C, checkpoint interval, deterministic stop).
//!
//! Everything random is seeded (ChaCha8).

// Per-Gaussian loops index several arrays in lockstep; `!(x >= t)` is used on
// purpose where NaN must take the rejecting branch.
#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord)]

pub mod adam;
pub mod checkpoint;
pub mod dataset;
pub mod densify;
pub mod diagnose;
pub mod filter3d;
pub mod fit;
pub mod init;
pub mod linalg;
pub mod loss;
pub mod mcmc;
pub mod model;
pub mod points;
pub mod trainer;

pub use adam::{Adam, AdamRule, Group, LearningRates, NonFinite, Update};
pub use checkpoint::{Checkpointer, Control, RunId};
pub use dataset::{Dataset, LoadOptions, View};
pub use densify::{Bounds, DensifyConfig, DensifyCounts, DensifyStats};
pub use fit::{
    evaluate, fit, fit_with, initial_model, start, write_output, Eval, FitOptions, FitState, InitSource,
    Progress, ViewScore,
};
pub use loss::{image_loss, psnr, ssim, ImageLoss};
pub use mcmc::McmcConfig;
pub use model::{Model, Reindex};
pub use points::PointCloud;
pub use trainer::{
    apply_reindex, camera_centre, scene_extent, Downscale, StepReport, Strategy, TrainConfig, TrainError,
    Trainer, ViewPass,
};

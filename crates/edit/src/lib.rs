//! The TransSplat edit engine (paper Sec. 3, appendices A–B; the decisions the paper
//! leaves open are in docs/method.md).
//!
//! The loop, [`engine`], reads as the pipeline; each stage is a module over plain data:
//!
//! 1. [`edits`]: render the edit views, edit them once with the 2D editor, check
//!    the outputs, gather each view's evidence.
//! 2. [`semantic`]: the one owner of the features E_v (the job's model, for source
//!    and edited views alike) and Φ_v, the PCA semantic space ([`pca`]) and the
//!    initial semantic latents lifted onto the Gaussians ([`lift`]).
//! 3. [`prototypes`]: prompt-aware prototypes of one edited view (appendix A.1).
//! 4. [`round`]: one transport round: per view the source side and [`view`]'s
//!    view-wise unbalanced transport (Sec. 3.3), then [`fusion`] (Theorem 1, EMA)
//!    and [`gate`] (docs/method.md#m6-residual-and-gate).
//! 5. [`optimise`]: the trainer, the view order, L_img of a step (a full render, or
//!    with frozen geometry and a colour mask only the colour change of the Gaussians
//!    that can change, [`delta`]); [`losses`]: the gradients of L_sem, L_uot (through
//!    the cost at fixed T*) and L_leak.
//!
//! The method is one pluggable part, [`methods`]: TransSplat with its ablations, and
//! the baselines. [`config`] holds every hyperparameter with the paper's defaults;
//! [`checkpoint`] saves and restores a run; [`job`] is what goes in and comes out.

pub mod checkpoint;
pub mod config;
pub mod delta;
pub mod edits;
pub mod engine;
pub mod error;
pub mod fusion;
pub mod gate;
pub mod job;
pub mod latents;
pub mod lift;
pub mod losses;
pub mod methods;
pub mod optimise;
pub mod pca;
pub mod prototypes;
pub mod round;
pub mod semantic;
pub mod view;

pub use config::EditConfig;
pub use config::Method;
pub use engine::{run, run_with};
pub use error::EditError;
pub use job::{EditJob, EditResult, Progress, Timing};
pub use optimise::StepLosses;
pub use round::RoundStats;
pub use semantic::SemanticFn;
pub use transsplat_raster::ClampGrad;

/// L2-normalises `v` in place (leaves a zero vector as is); returns the norm.
pub fn normalize(v: &mut [f32], eps: f32) -> f32 {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    if n > 0.0 {
        for x in v.iter_mut() {
            *x /= n + eps;
        }
    }
    n
}

//! The TransSplat edit engine (paper Sec. 3, appendices A–B; SPEC "Method").
//!
//! Each step of the method is a function over plain data, in pipeline order:
//!
//! 1. [`prototypes`]: prompt-aware prototypes of one edited view (appendix A.1).
//! 2. [`view`]: source masses, the three-term cost and the view-wise unbalanced
//!    transport (Sec. 3.3), giving per-Gaussian support w and targets y.
//! 3. [`fusion`]: canonical barycentric fusion (Theorem 1) with EMA across rounds.
//! 4. [`gate`]: relative transport residual and the leakage gate γ (SPEC Method 6).
//! 5. [`losses`]: L_sem, L_uot (through the cost at fixed T*) and L_leak gradients.
//!
//! [`config`] holds every hyperparameter with the paper's defaults; [`engine`] runs
//! the edit loop, which [`checkpoint`] saves and restores.

pub mod checkpoint;
pub mod config;
pub mod engine;
pub mod fusion;
pub mod gate;
pub mod losses;
pub mod pca;
pub mod prototypes;
pub mod view;

pub use config::EditConfig;

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

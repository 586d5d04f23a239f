//! Errors for bad input. The solver itself never fails on valid input: numerical
//! trouble is handled by re-stabilisation and log-sum-exp fallbacks.

/// What was wrong with a transport problem.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Error {
    /// A vector or matrix has the wrong length.
    #[error("shape mismatch: {what} has {got} entries, expected {expected}")]
    Shape { what: &'static str, got: usize, expected: usize },
    /// A mass is negative, NaN or infinite.
    #[error("{which} mass {index} is {value} (masses must be finite and >= 0)")]
    BadMass { which: &'static str, index: usize, value: f32 },
    /// A cost is negative or NaN (+inf is allowed: the entry is excluded from the support).
    #[error(
        "cost at source {source_index}, target {target} is {value} (costs must be >= 0 or +inf, not NaN)"
    )]
    BadCost { source_index: usize, target: usize, value: f32 },
    /// `eps` must be finite and > 0.
    #[error("eps must be finite and > 0, got {0}")]
    BadEps(f64),
    /// `tau` must be > 0 (+inf allowed: hard marginal).
    #[error("tau_{side} must be > 0 (or inf for a hard marginal), got {value}")]
    BadTau { side: &'static str, value: f64 },
    /// A tolerance that is not finite and > 0.
    #[error("tolerance must be finite and > 0, got {0}")]
    BadTol(f64),
    /// A sparse support entry is out of range or repeated.
    #[error("sparse support: {0}")]
    BadSupport(String),
    /// A warm start with NaN potentials.
    #[error("warm start: {0}")]
    BadWarmStart(String),
    /// With a hard marginal (tau = inf) some mass cannot be transported at all.
    #[error("infeasible: tau_{side} = inf but {which} {index} (mass {mass}) has no finite-cost entry to any positive-mass {other}")]
    Infeasible { side: &'static str, which: &'static str, index: usize, mass: f32, other: &'static str },
    /// Both marginals hard but the totals differ.
    #[error("balanced problem (tau_s = tau_t = inf) needs equal total masses, got {a} and {b}")]
    MassMismatch { a: f64, b: f64 },
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

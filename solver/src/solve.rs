//! Newton options and failure causes, and Newton's method at one load (the corrector of
//! [`crate::continuation`], which follows load paths).
//!
//! Every loop is bounded; no NaN leaves the solver: a non-finite residual, an inverted element or
//! a non-positive-definite tangent is a recorded failure with its cause, and the caller keeps the
//! last converged state.

use crate::element::ElementError;
use crate::model::{Assembled, Factor, Loads, Model};

/// Newton options.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct NewtonOptions {
    pub max_iter: usize,
    /// Converged when ‖r‖ ≤ rtol · max(‖f_int‖, ‖f_ext‖) …
    pub rtol: f64,
    /// … or ‖r‖ ≤ atol (force units).
    pub atol: f64,
    /// Below ‖r‖ ≤ stagnation_rtol · scale, stop when the residual stops decreasing (round-off).
    pub stagnation_rtol: f64,
    /// Give up (divergence) when the residual is still above `stall_ratio` × its initial value
    /// after this many iterations, or above 1e-6 of it after twice as many.
    pub stall_iterations: usize,
    /// See `stall_iterations`: 1 for a solve from far (a cold start may take many globalised
    /// iterations); the path follower's steps use 0.1 (their predictors are close).
    pub stall_ratio: f64,
    /// Energy criterion: converged when |Δq·r| ≤ etol · |Δq₀·r₀| (first iteration of the solve)
    /// and ‖r‖ ≤ stagnation_rtol · scale.
    pub etol: f64,
    pub line_search: bool,
    /// Use LU instead of Cholesky (indefinite tangents, e.g. past a limit point under displacement control).
    pub indefinite: bool,
    /// Keep the residual norms of every iteration (for logs/tests).
    pub log: bool,
}

impl Default for NewtonOptions {
    fn default() -> Self {
        NewtonOptions { max_iter: 25, rtol: 1e-10, atol: 1e-13, stagnation_rtol: 1e-7, stall_iterations: 8, stall_ratio: 1.0, etol: 1e-22, line_search: true, indefinite: false, log: false }
    }
}

/// Why a Newton solve failed.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum NewtonFailure {
    NotPositiveDefinite,
    Inversion,
    Divergence,
    IterationLimit,
}

/// Statistics of a converged Newton solve.
#[derive(Clone, Debug, Default)]
pub struct NewtonStats {
    pub iterations: usize,
    pub residual_norms: Vec<f64>,
}

/// Solve r(q) = 0 at fixed loads starting from q (updated in place on success, restored on
/// failure): Newton's method of the path follower ([`crate::continuation::correct`]) at one
/// load. On success the returned assembly holds the tangent at the converged state. A converged
/// state whose tangent is not positive definite is unstable and reported as
/// `NotPositiveDefinite` (unless `opts.indefinite`).
pub fn newton(model: &Model, q: &mut Vec<f64>, loads: &Loads, opts: &NewtonOptions) -> Result<(NewtonStats, Assembled), NewtonFailure> {
    newton_factored(model, q, loads, opts).map(|(s, a, _)| (s, a))
}

/// As [`newton`], also returning the factor of the tangent at the converged state (Cholesky, or
/// an indefinite factorisation with `opts.indefinite`).
pub fn newton_factored(model: &Model, q: &mut Vec<f64>, loads: &Loads, opts: &NewtonOptions) -> Result<(NewtonStats, Assembled, Factor), NewtonFailure> {
    let lp = crate::continuation::LoadPath::new(model, loads.clone(), loads.clone(), Vec::new());
    match crate::continuation::correct(&lp, q, 0.0, None, opts, false, None, false) {
        Ok(s) if s.stable || opts.indefinite => {
            let a = model.assemble(&s.q, loads, true).map_err(elem_fail)?;
            *q = s.q;
            Ok((NewtonStats { iterations: s.iterations, residual_norms: s.residual_norms }, a, s.factor))
        }
        Ok(_) => Err(NewtonFailure::NotPositiveDefinite),
        Err((f, _)) => Err(f),
    }
}

fn elem_fail(e: ElementError) -> NewtonFailure {
    match e {
        ElementError::Inverted(_) | ElementError::BadReference(_) | ElementError::Penetration(_) => NewtonFailure::Inversion,
        ElementError::NonFinite(_) | ElementError::Setup => NewtonFailure::Divergence,
    }
}

/// Why a load path ended before its end.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum FailureCause {
    /// The tangent lost positive definiteness (pressure maximum / instability).
    LimitPoint,
    /// An element inverted (det F ≤ 0) at every step size tried.
    Inversion,
    /// Newton diverged at the smallest step.
    Divergence,
    /// Newton hit its iteration limit at the smallest step.
    IterationLimit,
    /// The step count limit was reached.
    StepLimit,
}

impl FailureCause {
    pub fn as_str(self) -> &'static str {
        match self {
            FailureCause::LimitPoint => "limit-point",
            FailureCause::Inversion => "inversion",
            FailureCause::Divergence => "divergence",
            FailureCause::IterationLimit => "iteration-limit",
            FailureCause::StepLimit => "step-limit",
        }
    }
}

//! Derivatives: path-space gradients of the speckle estimators (ARCHITECTURE.md, Derivatives).
//!
//! Paths are drawn from a fixed *proposal* medium and re-weighted to the *target* parameters θ:
//! an event contributes `w_θ a_θ a_θᴴ` with `w_θ = c_θ(x) / q_proposal(x)`. For fixed random numbers
//! the estimate is then a smooth function of θ (the objective an optimiser sees), and its gradient is
//! `(∂c_θ/∂θ)(x) / q(x)`, evaluated analytically factor by factor (attenuation, amplitude functions,
//! coefficients) and contracted with a loss adjoint `∂L/∂C` per event, so memory does not grow with
//! the number of covariance entries.

pub mod bridge;
pub mod covariance;
pub mod ops;
pub mod render_op;
pub mod trace_op;

pub use covariance::{CovarianceGradient, Reweighted, ReweightedCovariance};
pub use ops::{CovarianceEvaluation, CovarianceOp, MeanOp, Proposal, medium_at};
pub use render_op::{RenderEvaluation, RenderOp};
pub use trace_op::{ExitGradients, ExitVjp, TraceOp};

pub use crate::medium::params::Param;

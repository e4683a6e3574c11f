//! Derivatives: path-space gradients of the speckle estimators (DESIGN.md, Derivatives).
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
pub mod trace_op;

pub use covariance::{CovarianceGradient, Reweighted, ReweightedCovariance};
pub use ops::{CovarianceOp, MeanOp, Proposal, medium_at};
pub use trace_op::TraceOp;

use crate::medium::{Medium, PhaseFunction};

/// A differentiable parameter of a homogeneous medium.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Param {
    /// Scattering coefficient `σ_s`.
    SigmaS,
    /// Absorption coefficient `σ_a`.
    SigmaA,
    /// Henyey–Greenstein `g` of mixture component `c` (0 for a single type).
    G(usize),
    /// Value at node `k` of the tabulated phase function of component `c` (normalisation kept).
    Bin(usize, usize),
    /// Share `β_c` of σ_s of particle type `c` (paper 001, Eq. 44); the shares stay normalised, so
    /// this is the derivative with respect to `c`'s unnormalised weight at `Σ = 1`.
    Weight(usize),
}

impl Param {
    pub fn name(&self) -> String {
        match self {
            Param::SigmaS => "sigma_s".into(),
            Param::SigmaA => "sigma_a".into(),
            Param::G(0) => "g".into(),
            Param::G(c) => format!("g[{c}]"),
            Param::Bin(c, k) => format!("bin[{c}][{k}]"),
            Param::Weight(c) => format!("weight[{c}]"),
        }
    }

    /// The parameter's value in `m` (`None` if `m` has no such parameter).
    pub fn get(&self, m: &Medium) -> Option<f64> {
        match self {
            Param::SigmaS => Some(m.sigma_s),
            Param::SigmaA => Some(m.sigma_a),
            Param::G(c) => match m.scattering.components().get(*c).map(|x| &x.1) {
                Some(PhaseFunction::HenyeyGreenstein { g }) => Some(*g),
                _ => None,
            },
            Param::Bin(c, k) => match m.scattering.components().get(*c).map(|x| &x.1) {
                Some(PhaseFunction::Tabulated(t)) => t.node_value(*k),
                _ => None,
            },
            Param::Weight(c) => m.scattering.components().get(*c).map(|x| x.0),
        }
    }

    /// `∂ log ρ_kind(μ) / ∂θ` for phase-function parameters of component `kind` (0 for others).
    #[inline]
    pub fn dlog_phase(&self, kind: usize, phase: &PhaseFunction, mu: f64) -> f64 {
        match (self, phase) {
            (Param::G(c), PhaseFunction::HenyeyGreenstein { .. }) if *c == kind => {
                phase.dlog_rho_dg(mu).unwrap_or(0.0)
            }
            (Param::Bin(c, k), PhaseFunction::Tabulated(t)) if *c == kind => {
                t.dlog_rho_dnode(mu, *k)
            }
            _ => 0.0,
        }
    }

    /// Whether this is a phase-function parameter (enters at vertices, not through coefficients).
    pub fn is_phase(&self) -> bool {
        matches!(self, Param::G(_) | Param::Bin(..))
    }

    /// A copy of `m` with this parameter set to `v`.
    pub fn set(&self, m: &Medium, v: f64) -> Medium {
        let mut out = m.clone();
        match self {
            Param::SigmaS => out.sigma_s = v,
            Param::SigmaA => out.sigma_a = v,
            Param::Weight(c) => {
                let comps = m
                    .scattering
                    .components()
                    .iter()
                    .enumerate()
                    .map(|(i, (w, p))| (if i == *c { v } else { *w }, p.clone()))
                    .collect();
                out.scattering = crate::medium::Scattering::mixture(comps);
            }
            Param::G(c) | Param::Bin(c, _) => {
                let comps = m
                    .scattering
                    .components()
                    .iter()
                    .enumerate()
                    .map(|(i, (w, p))| {
                        let q = match (self, p) {
                            (Param::G(_), _) if i == *c => PhaseFunction::HenyeyGreenstein { g: v },
                            (Param::Bin(_, k), PhaseFunction::Tabulated(t)) if i == *c => t
                                .with_node_value(*k, v)
                                .map(PhaseFunction::Tabulated)
                                .unwrap_or_else(|_| p.clone()),
                            _ => p.clone(),
                        };
                        (*w, q)
                    })
                    .collect();
                out.scattering = crate::medium::Scattering::mixture(comps);
            }
        }
        out
    }
}

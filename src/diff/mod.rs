//! Derivatives: path-space gradients of the speckle estimators (DESIGN.md, Derivatives).
//!
//! Paths are drawn from a fixed *proposal* medium and re-weighted to the *target* parameters θ:
//! an event contributes `w_θ a_θ a_θᴴ` with `w_θ = c_θ(x) / q_proposal(x)`. For fixed random numbers
//! the estimate is then a smooth function of θ (the objective an optimiser sees), and its gradient is
//! `(∂c_θ/∂θ)(x) / q(x)`, evaluated analytically factor by factor (attenuation, amplitude functions,
//! coefficients) and contracted with a loss adjoint `∂L/∂C` per event, so memory does not grow with
//! the number of covariance entries.

pub mod covariance;

pub use covariance::{CovarianceGradient, Reweighted, ReweightedCovariance};

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
}

impl Param {
    pub fn name(&self) -> String {
        match self {
            Param::SigmaS => "sigma_s".into(),
            Param::SigmaA => "sigma_a".into(),
            Param::G(0) => "g".into(),
            Param::G(c) => format!("g[{c}]"),
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
        }
    }

    /// A copy of `m` with this parameter set to `v`.
    pub fn set(&self, m: &Medium, v: f64) -> Medium {
        let mut out = m.clone();
        match self {
            Param::SigmaS => out.sigma_s = v,
            Param::SigmaA => out.sigma_a = v,
            Param::G(c) => {
                let comps = m
                    .scattering
                    .components()
                    .iter()
                    .enumerate()
                    .map(|(i, (w, p))| {
                        (
                            *w,
                            if i == *c {
                                PhaseFunction::HenyeyGreenstein { g: v }
                            } else {
                                p.clone()
                            },
                        )
                    })
                    .collect();
                out.scattering = crate::medium::Scattering::mixture(comps);
            }
        }
        out
    }
}
